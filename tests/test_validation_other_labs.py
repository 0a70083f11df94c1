"""Logs as other labs write them: the robot and the tool named in words in a sidecar, the time and joint columns
of ROS tools and of common dumps, and every flag a message suggests: doing what it says works.

The logs here are made up (inverse dynamics of a known motion, so every reading can be checked against the arrays
written); the real recordings in ../shared/data are read by tests/test_validation_userpath.py."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from franka_vs_gym.cli import main as cli
from franka_vs_gym.model import FrankaModel
from franka_vs_gym.model.description import FER, robot_description, robot_from_words
from franka_vs_gym.validation.loading import load_log
from franka_vs_gym.validation.logs import MeasurementLog, save_log, tool_from_words


def _log(n: int = 2400, rate: float = 400.0, robot: str = "fer", q6: float = 1.6) -> MeasurementLog:
    """A smooth multi-sine about the neutral pose (sixth joint at ``q6``) with the exact inverse-dynamics torque
    of ``robot`` without a tool, plus 0.02 Nm of noise."""
    rng = np.random.default_rng(1)
    m = FrankaModel(robot=robot, tool=None)
    t = np.arange(n) / rate
    w = 2 * np.pi * np.array([0.3, 0.4, 0.5, 0.35, 0.6, 0.45, 0.7])
    q0 = np.array(FER.q_neutral)
    q0[5] = q6
    q = q0 + 0.25 * np.sin(np.outer(t, w))
    dq = 0.25 * w * np.cos(np.outer(t, w))
    ddq = -0.25 * w**2 * np.sin(np.outer(t, w))
    tau = np.array([m.inverse_dynamics(q[k], dq[k], ddq[k]) for k in range(n)]) + rng.normal(0, 0.02, (n, 7))
    return MeasurementLog(t, q, dq, tau, tool=None)


@pytest.fixture(scope="module")
def fer_csv(tmp_path_factory) -> Path:
    return save_log(_log(), tmp_path_factory.mktemp("fer") / "run.csv")


def _with_sidecar(src: Path, d: Path, meta: dict, name: str = "run.csv") -> Path:
    p = d / name
    p.write_bytes(src.read_bytes())
    Path(str(p) + ".json").write_text(json.dumps(meta))
    return p


def _cli(capsys, argv: list[str]) -> tuple[int, str, str]:
    rc = cli(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line_error(capsys, argv: list[str]) -> str:
    rc, _, err = _cli(capsys, argv)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, (rc, err)
    assert lines[0].startswith(f"franka-vs {argv[0]}: error: "), lines[0]
    return lines[0]


# ----------------------------------------------------------------------------------------------- the robot in words
@pytest.mark.parametrize("text, robot", [
    ("FER", "fer"), ("Panda", "fer"), ("Franka Emika Robot", "fer"), ("Franka Emika Panda", "fer"),
    ("FER (Franka Emika Robot, aka Panda)", "fer"), ("fer", "fer"), ("PANDA arm in lab 3", "fer"),
    ("FR3", "fr3"), ("Franka Research 3", "fr3"), ("franka_fr3", "fr3"), ("fr3", "fr3"), ("fR3", "fr3"),
    ("a Franka Research 3 (FR3) with the hand", "fr3"),
])
def test_a_robot_named_in_words_is_recognised(text, robot):
    assert robot_from_words(text) == robot
    assert robot_description(text).name == robot


@pytest.mark.parametrize("text", ["KUKA LBR iiwa 14", "Franka Emika", "UR5e", "my robot"])
def test_a_phrase_naming_no_registered_robot_is_none(text):
    assert robot_from_words(text) is None
    with pytest.raises(ValueError, match="unknown robot"):
        robot_description(text)


def test_a_phrase_naming_two_robots_is_ambiguous():
    with pytest.raises(ValueError, match="more than one robot"):
        robot_from_words("FER or FR3")


def test_a_sidecar_naming_the_robot_in_words_is_read_and_said(fer_csv, tmp_path):
    from franka_vs_gym.validation.compare import compare

    p = _with_sidecar(fer_csv, tmp_path, {"robot": "FER (Franka Emika Robot, aka Panda)", "tool": None})
    res = compare(load_log(p), do_replay=False)
    a = res.assumptions()
    assert a["robot"] == "fer" and a["robot_source"].startswith("declared by the log"), a["robot_source"]
    assert "Franka Emika Robot, aka Panda" in a["robot_source"]
    assert np.max(res.rmse_tau) < 0.05  # the FER's own dynamics: the 0.02 Nm noise is what is left
    # franka_ros's arm_id says the same
    q = _with_sidecar(fer_csv, tmp_path, {"arm_id": "panda", "tool": None}, "arm_id.csv")
    assert compare(load_log(q), do_replay=False).assumptions()["robot"] == "fer"


@pytest.mark.parametrize("name, why", [("KUKA LBR iiwa 14", "not a registered robot"),
                                       ("FER or FR3", "names more than one robot")])
def test_an_unknown_robot_is_one_line_naming_key_and_file_and_its_flag_works(fer_csv, tmp_path, capsys, name,
                                                                            why):
    p = _with_sidecar(fer_csv, tmp_path, {"robot": name, "tool": None})
    side = f"{p}.json"
    for cmd in (["compare", str(p), "--no-replay"], ["diagnose", str(p)],
                ["fit", str(p), "--add", "torque_offset", "-o", str(tmp_path / "m.json")]):
        line = _one_line_error(capsys, [*cmd, "--quiet"])
        assert side in line and "'robot'" in line and why in line and "pass --robot" in line, line
    # doing what it says works, in every command that reads a log
    for cmd in (["compare", str(p), "--no-replay"], ["diagnose", str(p)]):
        rc, out, err = _cli(capsys, [*cmd, "--robot", "fer", "--quiet", "--json"])
        assert rc == 0, err
        assert json.loads(out)["assumptions"]["robot_source"] == "--robot"


def test_fit_add_auto_keeps_the_robot_it_was_given(fer_csv, tmp_path, capsys):
    """The automatic selection inside fit_effects diagnoses with the robot given by --robot (it used to read the
    log's declaration again and fail on a name in words); the report's comparison too."""
    p = _with_sidecar(fer_csv, tmp_path, {"robot": "our lab's arm", "tool": None})
    out = tmp_path / "m.json"
    rc, text, err = _cli(capsys, ["fit", str(p), "--robot", "fer", "--add", "auto", "-o", str(out), "--quiet",
                                  "--report", str(tmp_path / "rep")])
    assert rc == 0, err
    assert json.loads(out.read_text())["robot"] == "fer" and (tmp_path / "rep" / "report.html").is_file()
    # the next command it suggests carries --robot, and works
    nxt = next(ln for ln in text.splitlines() if ln.startswith("next: "))[len("next: "):]
    argv = shlex.split(nxt)[1:]
    assert argv[0] == "diagnose" and "--robot" in argv, nxt
    argv[argv.index("--report") + 1] = str(tmp_path / "after")
    rc, _, err = _cli(capsys, [*argv, "--quiet"])
    assert rc == 0, err


def test_the_fr3_declared_in_words_is_the_fr3(tmp_path):
    from franka_vs_gym.validation.diagnose import diagnose

    p = save_log(_log(rate=250.0, n=2000, robot="fr3", q6=4.1), tmp_path / "fr3.csv")
    Path(str(p) + ".json").write_text(json.dumps({"robot": "Franka Research 3", "tool": None}))
    d = diagnose(load_log(p), select=False)
    assert d.assumptions["robot"] == "fr3" and np.max(d.rmse_tau) < 0.05, (d.assumptions, d.rmse_tau)


def test_the_hint_to_pass_robot_fr3_works(tmp_path, capsys):
    """An undeclared log beyond the FER's range gets '--robot fr3' in its assumptions; passing it gives the FR3."""
    p = save_log(_log(rate=250.0, n=2000, robot="fr3", q6=4.1), tmp_path / "fr3.csv")
    rc, out, err = _cli(capsys, ["compare", str(p), "--no-replay", "--quiet", "--json"])
    assert rc == 0, err
    src = json.loads(out)["assumptions"]["robot_source"]
    flag = re.search(r"\(--robot (\w+)\)", src)
    assert flag and flag.group(1) == "fr3", src
    rc, out, err = _cli(capsys, ["compare", str(p), "--no-replay", "--quiet", "--json", "--robot", flag.group(1)])
    assert rc == 0 and json.loads(out)["assumptions"]["robot"] == "fr3", err
    assert max(json.loads(out)["rmse_tau"]) < 0.05


# ----------------------------------------------------------------------------------------------- the tool in words
@pytest.mark.parametrize("text, tool", [
    ("Franka Hand", "franka_hand"), ("hand", "franka_hand"), ("gripper", "franka_hand"),
    ("franka_hand", "franka_hand"), ("the Franka Hand (fingers closed)", "franka_hand"),
    ("Franka Gripper", "franka_hand"),
    ("none", None), ("no tool", None), ("None", None), ("no gripper", None), ("without hand", None), ("", None),
])
def test_a_tool_named_in_words_is_recognised(text, tool):
    assert tool_from_words(text) == tool


def test_the_tool_in_words_reaches_the_model_and_an_unknown_one_is_one_line(fer_csv, tmp_path, capsys):
    from franka_vs_gym.validation.compare import compare

    p = _with_sidecar(fer_csv, tmp_path, {"robot": "fer", "tool": "Franka Hand"})
    res = compare(load_log(p), do_replay=False)
    assert res.config.tool.name == "franka_hand" and "'Franka Hand'" in res.assumptions()["tool_source"]
    q = _with_sidecar(fer_csv, tmp_path, {"robot": "fer", "tool": "no tool"}, "none.csv")
    res = compare(load_log(q), do_replay=False)
    assert res.config.tool.body.mass == 0 and np.max(res.rmse_tau) < 0.05  # the log has no tool: exact
    r = _with_sidecar(fer_csv, tmp_path, {"robot": "fer", "tool": "Robotiq 2F-85"}, "robotiq.csv")
    line = _one_line_error(capsys, ["compare", str(r), "--no-replay", "--quiet"])
    assert f"{r}.json" in line and "'tool'" in line and "unknown tool" in line and "--tool" in line, line
    # doing what it says works: --tool replaces the declaration, which is then not read
    rc, out, err = _cli(capsys, ["compare", str(r), "--no-replay", "--quiet", "--json", "--tool", "none"])
    assert rc == 0, err
    a = json.loads(out)["assumptions"]
    assert a["tool"] == "none" and "Robotiq 2F-85" in a["tool_source"], a["tool_source"]
    assert max(json.loads(out)["rmse_tau"]) < 0.05


# ----------------------------------------------------------------------------------------------- time columns
def _table(log: MeasurementLog, tname: str, scale: float, offset: float, layout: str = "q0") -> str:
    t = log.time * scale + offset
    if layout == "q0":
        head = [tname] + [f"{f}{i}" for f in ("q", "dq", "tau_J") for i in range(7)]
        rows = [[f"{t[k]:.17g}"] + [f"{x:.17g}" for x in np.r_[log.q[k], log.dq[k], log.tau_J[k]]]
                for k in range(log.n)]
    else:  # whole lists in one cell each
        head = [tname, "position", "velocity", "effort"]
        rows = [[f"{t[k]:.17g}"] + ['"' + json.dumps(a[k].tolist()) + '"' for a in (log.q, log.dq, log.tau_J)]
                for k in range(log.n)]
    return ",".join(head) + "\n" + "\n".join(",".join(r) for r in rows) + "\n"


@pytest.mark.parametrize("tname, scale, offset, unit", [
    ("t", 1.0, 0.0, "seconds"), ("timestamp", 1.0, 1.7e9, "seconds"), ("stamp", 1e3, 0.0, "milliseconds"),
    ("time_ns", 1e9, 0.0, "nanoseconds"), ("header.stamp", 1e9, 1.7e18, "nanoseconds"),
    ("%time", 1e9, 1.7e18, "nanoseconds"), ("Time", 1.0, 0.0, "seconds"), ("timestamp", 1e9, 0.0, "nanoseconds"),
])
def test_common_time_columns_are_read_with_their_unit_stated(tmp_path, tname, scale, offset, unit):
    log = _log(n=400)
    p = tmp_path / "log.csv"
    p.write_text(_table(log, tname, scale, offset))
    back = load_log(p)
    tol = 1e-6 if offset else 1e-9  # an epoch in float64: 0.24 us resolution in s, 256 ns in ns
    np.testing.assert_allclose(back.time, log.time, atol=tol)
    np.testing.assert_array_equal(back.q, log.q)
    np.testing.assert_array_equal(back.tau_J, log.tau_J)
    assert f"time from {tname!r} in {unit}" in back.extra["read_as"], back.extra["read_as"]


@pytest.mark.parametrize("sec, nsec", [("header.stamp.sec", "header.stamp.nanosec"),
                                       ("field.header.stamp.secs", "field.header.stamp.nsecs")])
def test_a_stamp_in_two_columns_is_one_time(tmp_path, sec, nsec):
    """ROS 2's builtin_interfaces/Time (sec, nanosec) and ROS 1's (secs, nsecs) as two columns of integers."""
    log = _log(n=300, rate=30.0)
    ns = 1692348750 * 10**9 + np.round(log.time * 1e9).astype(np.int64)
    text = _table(log, "x", 1.0, 0.0).splitlines()
    rows = [f"{sec},{nsec}," + text[0].split(",", 1)[1]]
    rows += [f"{v // 10**9},{v % 10**9}," + line.split(",", 1)[1] for v, line in zip(ns.tolist(), text[1:],
                                                                                      strict=True)]
    p = tmp_path / "split.csv"
    p.write_text("\n".join(rows) + "\n")
    back = load_log(p)
    np.testing.assert_allclose(back.time, log.time, atol=1e-6)
    assert f"time from '{sec} + {nsec}' in nanoseconds" in back.extra["read_as"], back.extra["read_as"]


def test_a_time_in_microseconds_must_say_so_in_its_name(tmp_path):
    log = _log(n=400)
    p = tmp_path / "us.csv"
    p.write_text(_table(log, "t", 1e6, 0.0))
    with pytest.raises(ValueError, match=r"cannot tell the unit of 't'.*time_us"):
        load_log(p)
    p.write_text(_table(log, "time_us", 1e6, 0.0))
    np.testing.assert_allclose(load_log(p).time, log.time, atol=1e-9)


def _rostopic_csv(log: MeasurementLog, stamps: bool = True) -> str:
    """``rostopic echo -p /joint_states`` of a FER with the hand: %time and field.header.stamp in ns, then the
    names and the position, velocity and effort of 7 arm joints plus 2 fingers (the fingers first here)."""
    names = ["panda_finger_joint1", "panda_finger_joint2"] + [f"panda_joint{i + 1}" for i in range(7)]
    head = ["%time", "field.header.seq", "field.header.stamp", "field.header.frame_id"]
    head += [f"field.name{i}" for i in range(9)]
    head += [f"field.{f}{i}" for f in ("position", "velocity", "effort") for i in range(9)]
    rows = []
    t0 = 1692348750 * 10**9
    for k in range(log.n):
        stamp = t0 + int(round(log.time[k] * 1e9))
        recv = stamp + 400_000 + 1000 * (k % 7)  # the receive time: later, jittered
        vals = []
        for a, fingers in ((log.q, [0.004, 0.004]), (log.dq, [0.0, 0.0]), (log.tau_J, [0.0, 0.0])):
            vals += [repr(x) for x in fingers] + [repr(float(x)) for x in a[k]]
        rows.append([str(recv), str(k), str(stamp if stamps else 0), ""] + names + vals)
    return ",".join(head) + "\n" + "\n".join(",".join(r) for r in rows) + "\n"


def test_rostopic_echo_p_joint_states_are_read_by_joint_name(tmp_path):
    log = _log(n=300, rate=30.0)
    p = tmp_path / "joint_states.csv"
    p.write_text(_rostopic_csv(log))
    back = load_log(p)
    np.testing.assert_array_equal(back.q, log.q)
    np.testing.assert_array_equal(back.dq, log.dq)
    np.testing.assert_array_equal(back.tau_J, log.tau_J)
    np.testing.assert_allclose(back.time, log.time, atol=1e-6)
    r = back.extra["read_as"]
    assert "'field.header.stamp' in nanoseconds (detected" in r and "panda_joint1" in r, r
    # zero header stamps (a publisher that does not stamp): the receive time %time is used, and that is said
    q = tmp_path / "unstamped.csv"
    q.write_text(_rostopic_csv(log, stamps=False))
    back = load_log(q)
    assert "'field.header.stamp' does not advance: passed over" in back.extra["read_as"]
    assert "time from '%time' in nanoseconds" in back.extra["read_as"]
    np.testing.assert_allclose(back.time, log.time, atol=2e-5)


def test_joint_state_list_cells_are_read(tmp_path):
    log = _log(n=300)
    p = tmp_path / "lists.csv"
    p.write_text(_table(log, "timestamp", 1.0, 1.7e9, layout="lists"))
    back = load_log(p)
    np.testing.assert_array_equal(back.q, log.q)
    np.testing.assert_array_equal(back.tau_J, log.tau_J)
    assert "JointState columns position/velocity/effort read as q/dq/tau_J" in back.extra["read_as"]


def test_joint_state_without_names_and_nine_joints_is_refused(tmp_path):
    log = _log(n=50)
    text = _rostopic_csv(log)
    lines = [ln.split(",") for ln in text.splitlines()]
    keep = [i for i, h in enumerate(lines[0]) if not h.startswith("field.name")]
    p = tmp_path / "nonames.csv"
    p.write_text("\n".join(",".join(r[i] for i in keep) for r in lines) + "\n")
    with pytest.raises(ValueError, match="no joint names say which are the arm's seven"):
        load_log(p)


# ----------------------------------------------------------------------------------------------- diagnose-folder
def test_diagnose_folder_takes_robot_and_tool(fer_csv, tmp_path, capsys):
    from franka_vs_gym.cli import build_parser
    from franka_vs_gym.scale import diagnose_folder

    args = build_parser("diagnose-folder").parse_args(["diagnose-folder", str(tmp_path), "--robot", "fr3", "--tool",
                                                       "none"])
    assert args.robot == "fr3" and args.tool == "none"
    _with_sidecar(fer_csv, tmp_path, {"robot": "our lab's arm", "tool": "Robotiq 2F-85"})
    res = diagnose_folder(tmp_path, use_ray=False)
    assert "error" in res[0] and "pass --tool" in res[0]["error"], res  # the log's names are refused...
    res = diagnose_folder(tmp_path, use_ray=False, tool="none")
    assert "error" in res[0] and "pass --robot" in res[0]["error"], res
    res = diagnose_folder(tmp_path, use_ray=False, robot="fer", tool="none")  # ...and the flags override them
    assert "error" not in res[0], res
    a = res[0]["diagnosis"]["assumptions"]
    assert a["robot"] == "fer" and a["robot_source"] == "--robot" and a["tool"] == "none"
    assert res[0]["diagnosis"]["rmse_tau_total"] < 0.05
    with pytest.raises(ValueError, match="unknown robot"):
        diagnose_folder(tmp_path, use_ray=False, robot="kuka")


# ----------------------------------------------------------------------------------------------- other suggestions
def test_the_max_gap_it_suggests_works(tmp_path, capsys):
    log = _log(n=2400)
    keep = np.r_[0:1000, 1100:2400]  # a 0.25 s hole
    p = save_log(MeasurementLog(log.time[keep], log.q[keep], log.dq[keep], log.tau_J[keep], tool=None),
                 tmp_path / "gap.csv")
    line = _one_line_error(capsys, ["compare", str(p), "--no-replay", "--quiet"])
    gap = re.search(r"a ([\d.]+) ms gap", line)
    assert gap and "allow it with --max-gap" in line, line
    rc, out, err = _cli(capsys, ["compare", str(p), "--no-replay", "--quiet", "--json", "--max-gap",
                                 str(1.01 * float(gap.group(1)) / 1000)])
    assert rc == 0, err


def test_the_tool_it_estimates_can_be_said_with_the_flags_it_names(fer_csv, tmp_path, capsys):
    """A log that declares no tool: the tool is estimated and 'use --tool to say which' is said; --tool none and
    --tool unknown (named by the hints) both run, and --tool none is exact on this log (it has no tool)."""
    p = tmp_path / "undeclared.csv"
    p.write_bytes(fer_csv.read_bytes())
    Path(str(p) + ".json").write_text(json.dumps({"robot": "fer"}))
    rc, out, err = _cli(capsys, ["compare", str(p), "--no-replay", "--quiet", "--json"])
    assert rc == 0 and "--tool" in json.loads(out)["assumptions"]["tool_source"], err
    for tool in ("none", "unknown", "franka_hand"):
        rc, out, err = _cli(capsys, ["diagnose", str(p), "--quiet", "--json", "--tool", tool, "--effects",
                                     "payload"])
        assert rc == 0, err
        if tool == "none":
            assert max(json.loads(out)["rmse_tau"]) < 0.05


def test_the_next_command_of_diagnose_carries_its_options_and_works(fer_csv, tmp_path, capsys):
    p = _with_sidecar(fer_csv, tmp_path, {"robot": "lab arm 2", "tool": "none"})
    rc, out, err = _cli(capsys, ["diagnose", str(p), "--robot", "fer", "--rate", "200", "--quiet"])
    assert rc == 0, err
    nxt = next(ln for ln in out.splitlines() if ln.startswith("next: "))[len("next: "):]
    argv = shlex.split(nxt)[1:]
    assert "--robot" in argv and "--rate" in argv, nxt
    argv[argv.index("--report") + 1] = str(tmp_path / "next_report")
    if "-o" in argv:
        argv[argv.index("-o") + 1] = str(tmp_path / "next.json")
    rc, _, err = _cli(capsys, [*argv, "--quiet"])
    assert rc == 0, err


# ----------------------------------------------------------------------------------------------- the last bad inputs
def _blob_csv(src: Path, d: Path, column: int, name: str) -> Path:
    lines = src.read_text().splitlines()[:400]
    cells = lines[10].split(",")
    cells[column] = "1" * 20_000_000  # a 20 MB number: float() makes it inf
    lines[10] = ",".join(cells)
    p = d / name
    p.write_text("\n".join(lines) + "\n")
    return p


def test_a_20_mb_field_is_named_by_its_line_and_column(fer_csv, tmp_path, capsys):
    p = _blob_csv(fer_csv, tmp_path, 0, "blob.csv")
    line = _one_line_error(capsys, ["compare", str(p), "--no-replay", "--quiet"])
    assert "line 11 of the file" in line and "time contains NaN or inf" in line and "20000000 characters" in line, line
    p = _blob_csv(fer_csv, tmp_path, 5, "blob_q.csv")
    line = _one_line_error(capsys, ["compare", str(p), "--no-replay", "--quiet"])
    assert "q[4] contains NaN or inf" in line and "line 11 of the file" in line, line
    # the same in a table of another layout (t, q0...): its line and its column
    log = _log(n=400)
    q = tmp_path / "t.csv"
    q.write_text(_table(log, "t", 1.0, 0.0))
    r = _blob_csv(q, tmp_path, 0, "blob_t.csv")
    line = _one_line_error(capsys, ["compare", str(r), "--no-replay", "--quiet"])
    assert "line 11, column 't'" in line and "20000000 characters" in line, line


def _enospc(*_a, **_k):
    import errno

    raise OSError(errno.ENOSPC, "No space left on device")


def test_disk_full_mid_write_of_the_model_keeps_the_older_model(fer_csv, tmp_path, capsys, monkeypatch):
    """The model file is staged beside its target and renamed in only when complete: a write that fills the disk
    half way leaves the older model of the same name byte-identical and no staged file behind."""
    import errno

    from franka_vs_gym.model.config import ModelConfig

    p = _with_sidecar(fer_csv, tmp_path, {"robot": "fer", "tool": None})
    out = tmp_path / "cal.json"
    out.write_text("the older model")

    def half(self, path, overwrite=False):
        with open(path, "w") as fh:
            fh.write('{"format": "franka')
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(ModelConfig, "save", half)
    line = _one_line_error(capsys, ["fit", str(p), "--add", "torque_offset", "-o", str(out), "--force", "--quiet"])
    assert "No space left on device" in line and "nothing was replaced" in line, line
    assert out.read_text() == "the older model"
    assert sorted(f.name for f in tmp_path.iterdir()) == ["cal.json", "run.csv", "run.csv.json"]


class _FillsUp:
    """A file on a disk that fills after ``room`` bytes: the write that passes it raises ENOSPC."""

    def __init__(self, fh, room: int) -> None:
        self.fh, self.room = fh, room

    def write(self, b) -> int:
        import errno

        n = len(memoryview(b).cast("B"))
        if n > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.room -= n
        return self.fh.write(b)

    def __getattr__(self, name):
        return getattr(self.fh, name)


@pytest.mark.parametrize("where", ["html", "markdown", "mcap", "mcap_library"])
def test_disk_full_during_the_report_is_one_line_and_loses_nothing(fer_csv, tmp_path, capsys, monkeypatch, where):
    import franka_vs_gym.validation.report as report

    p = _with_sidecar(fer_csv, tmp_path, {"robot": "fer", "tool": None})
    out = tmp_path / "cal.json"
    out.write_text("the older model")
    (tmp_path / "rep").mkdir()
    (tmp_path / "rep" / "report.md").write_text("the older report")
    argv = ["fit", str(p), "--add", "torque_offset", "-o", str(out), "--force", "--quiet", "--report",
            str(tmp_path / "rep")]
    if where == "mcap":  # the disk fills part way through the MCAP file
        import builtins

        import franka_vs_gym.validation.report.mcap as mcap

        monkeypatch.setattr(mcap, "open", lambda *a, **k: _FillsUp(builtins.open(*a, **k), 100_000), raising=False)
        argv += ["--mcap", str(tmp_path / "run.mcap")]
    elif where == "mcap_library":  # the MCAP library says a failed write as a RuntimeError; the disk is full
        import os

        import foxglove

        class Full:
            def write_metadata(self, *a):
                raise RuntimeError("FoxgloveError: MCAP error: I/O error from writing, or reading a compression stream")

            def close(self):
                raise RuntimeError("FoxgloveError: MCAP error: attempted another write after a write method failed")

        monkeypatch.setattr(foxglove, "open_mcap", lambda *a, **k: Full())
        monkeypatch.setattr(os, "statvfs", lambda d: os.statvfs_result((4096, 4096, 100, 0, 0, 100, 0, 0, 0, 255)))
        argv += ["--mcap", str(tmp_path / "run.mcap")]
    else:
        monkeypatch.setattr(report, f"{where}_report", _enospc)
        monkeypatch.setattr("franka_vs_gym.validation.cli_common.alongside", lambda work: (work(), lambda: None)[1])
    line = _one_line_error(capsys, argv)
    assert "No space left on device" in line, line
    assert out.read_text() == "the older model" and (tmp_path / "rep" / "report.md").read_text() == "the older report"
    assert not (tmp_path / "run.mcap").exists()
    assert not [f for f in tmp_path.rglob("*") if "partial" in f.name]


def _generator_main():
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_hidden_effect_data", Path(__file__).resolve().parents[1] /
                                                  "scripts" / "make_hidden_effect_data.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.main


@pytest.mark.parametrize("argv, match", [
    (["--duration", "-5"], "duration must be in"), (["--duration", "nan"], "duration must be in"),
    (["--magnitude", "nan"], "magnitude must be in"), (["--seed", "-1"], "seed must be an integer"),
])
def test_the_hidden_effect_generator_refuses_bad_values_in_one_line(tmp_path, capsys, argv, match):
    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    out = tmp_path / "h.csv"
    out.write_text("an older log")
    rc = _generator_main()(["--effect", "payload", "-o", str(out), "--force", *argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and match in lines[0] and "Traceback" not in err, err
    assert out.read_text() == "an older log" and sorted(f.name for f in tmp_path.iterdir()) == ["h.csv"]
    kw = {"--duration": "duration", "--magnitude": "magnitude"}
    if argv[0] in kw:  # the API says the same
        with pytest.raises(ValueError, match=match):
            make_hidden_effect_log("payload", **{kw[argv[0]]: float(argv[1])})


def test_excite_designs_for_the_robot_its_log_declares_in_words_and_robot_overrides(tmp_path, capsys):
    from franka_vs_gym.model.description import FR3

    p = save_log(_log(rate=250.0, n=2000, robot="fr3", q6=4.1), tmp_path / "fr3.csv")
    Path(str(p) + ".json").write_text(json.dumps({"robot": "Franka Research 3", "tool": None}))
    base = ["excite", "--effects", "payload", "--log", str(p), "--duration", "6", "--rest", "0.5", "--evaluations",
            "2", "--time-budget", "30", "--quiet", "--json"]
    rc, out, err = _cli(capsys, [*base, "-o", str(tmp_path / "a")])
    assert rc == 0, err
    assert json.loads(out)["limits"]["robot_limits"]["q_max_rad"] == list(FR3.limits.q_max)
    rc, out, err = _cli(capsys, [*base, "-o", str(tmp_path / "b"), "--robot", "fer"])
    assert rc == 0, err
    assert json.loads(out)["limits"]["robot_limits"]["q_max_rad"] == list(FER.limits.q_max)


def test_a_model_of_another_robot_than_declared_and_the_robot_flag_it_names(tmp_path, capsys):
    """A log declared as the FR3 with a FER model file: one line saying to give a model of that robot or --robot to
    override the log; --robot fer then compares the FER model with it."""
    from franka_vs_gym.model.config import ModelConfig

    p = save_log(_log(rate=250.0, n=2000, robot="fr3", q6=3.0), tmp_path / "fr3.csv")
    Path(str(p) + ".json").write_text(json.dumps({"robot": "Franka Research 3", "tool": None}))
    model = ModelConfig(robot="fer").save(tmp_path / "fer_model.json")
    line = _one_line_error(capsys, ["compare", str(p), "--model", str(model), "--no-replay", "--quiet"])
    assert "--robot to override the log" in line, line
    rc, out, err = _cli(capsys, ["compare", str(p), "--model", str(model), "--no-replay", "--quiet", "--json",
                                 "--robot", "fer"])
    assert rc == 0 and json.loads(out)["assumptions"]["robot"] == "fer", err


def test_an_existing_output_says_force_and_force_replaces_it(fer_csv, tmp_path, capsys):
    p = _with_sidecar(fer_csv, tmp_path, {"robot": "fer", "tool": None})
    out = tmp_path / "cal.json"
    out.write_text("an older model")
    argv = ["fit", str(p), "--add", "torque_offset", "-o", str(out), "--quiet"]
    line = _one_line_error(capsys, argv)
    assert "pass --force to replace it" in line and out.read_text() == "an older model", line
    rc, _, err = _cli(capsys, [*argv, "--force"])
    assert rc == 0 and json.loads(out.read_text())["robot"] == "fer", err
