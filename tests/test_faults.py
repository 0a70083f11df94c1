"""Bad inputs and faults: every one gets a named one-line error, and no input file changes.

CLI cases run ``franka_vs_gym.cli.main`` in-process and assert exit status 2, exactly one line
``franka-vs <command>: error: ...`` on stderr naming the problem, and that every input file is byte-identical
afterwards (SHA-256 before/after). Library cases (log readers, model files, the robot API, the environments) assert
the exception type and its message. Signals and the determinism check spawn processes.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from franka_vs_gym.cli import main as cli
from franka_vs_gym.errors import UserError
from franka_vs_gym.model import FrankaModel
from franka_vs_gym.model.config import Friction, ModelConfig, RigidBody
from franka_vs_gym.model.description import FER
from franka_vs_gym.validation.loading import load_log
from franka_vs_gym.validation.logs import MeasurementLog, save_log

ROOT = Path(__file__).resolve().parents[1]
Q0 = np.array(FER.q_neutral)
COLS = ["time"] + [f"{f}[{i}]" for f in ("q", "dq", "tau_J") for i in range(7)]


# ----------------------------------------------------------------------------------------------- fixtures
def _motion_log(n: int = 1500) -> MeasurementLog:
    """A smooth 1 kHz motion with its exact inverse-dynamics torques (an independent, noise-free log)."""
    m = FrankaModel()
    t = np.arange(n) * 1e-3
    w = 2 * np.pi * np.array([0.3, 0.4, 0.5, 0.35, 0.6, 0.45, 0.7])
    q = Q0 + 0.2 * np.sin(np.outer(t, w))
    dq = 0.2 * w * np.cos(np.outer(t, w))
    ddq = -0.2 * w**2 * np.sin(np.outer(t, w))
    tau = np.array([m.inverse_dynamics(q[k], dq[k], ddq[k]) for k in range(n)])
    return MeasurementLog(t, q, dq, tau)


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    """A valid CSV log with its sidecar (never modified by any test: each test copies it)."""
    return save_log(_motion_log(), tmp_path_factory.mktemp("good") / "run.csv")


def _copy_log(good: Path, d: Path, name: str = "run.csv") -> Path:
    p = d / name
    p.write_bytes(good.read_bytes())
    Path(str(p) + ".json").write_bytes(Path(str(good) + ".json").read_bytes())
    return p


def _sha(p: Path) -> str | None:
    if p.is_file():
        return hashlib.sha256(p.read_bytes()).hexdigest()
    if p.is_dir():
        return "dir:" + ",".join(sorted(f"{q.name}={_sha(q)}" for q in p.iterdir()))
    return None


def _files(d: Path) -> dict[str, str | None]:
    """Hashes of every regular file and folder under d (FIFOs and device links by name only, never read)."""
    out: dict[str, str | None] = {}
    for p in sorted(d.rglob("*")):
        if p.is_symlink() or not (p.is_file() or p.is_dir()):
            out[str(p)] = "special"
        elif p.is_file():
            out[str(p)] = _sha(p)
        else:
            out[str(p)] = "dir"
    return out


def run_cli_error(capsys, argv: list[str], where: Path, match: str) -> str:
    """Run the CLI in-process: exit 2, one line naming the problem, every file under ``where`` unchanged."""
    before = _files(where)
    rc = cli(argv)
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, (rc, err)
    assert len(lines) == 1, err
    assert lines[0].startswith(f"franka-vs {argv[0]}: error: "), lines[0]
    assert match.lower() in lines[0].lower(), (match, lines[0])
    assert "Traceback" not in err
    assert _files(where) == before, "an input or existing file changed"
    return lines[0]


# ----------------------------------------------------------------------------------------------- log files
def _write_csv(p: Path, header: list[str], rows: list[list[object]]) -> None:
    p.write_text(",".join(header) + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))


def _rows(n: int = 50, **over) -> list[list[float]]:
    rows = []
    for k in range(n):
        r = [k * 1e-3] + list(Q0) + [0.0] * 7 + [0.0] * 7
        rows.append(r)
    for (k, c), v in over.items() if False else []:
        rows[k][c] = v
    return rows


def _npz(p: Path, **arrays) -> None:
    with open(p, "wb") as fh:
        np.savez(fh, **arrays)


def _good_arrays(n: int = 50) -> dict[str, np.ndarray]:
    return {"time": np.arange(n) * 1e-3, "q": np.tile(Q0, (n, 1)), "dq": np.zeros((n, 7)), "tau_J": np.zeros((n, 7))}


def _mk_empty(d, good):
    p = d / "run.csv"
    p.write_text("")
    return p


def _mk_header_only(d, good):
    p = d / "run.csv"
    p.write_text(",".join(COLS) + "\n")
    return p


def _mk_text_value(d, good):
    p = d / "run.csv"
    rows = _rows()
    rows[3][5] = "abc"
    _write_csv(p, COLS, rows)
    return p


def _mk_ragged(d, good):
    p = d / "run.csv"
    rows = _rows()
    rows[4] = rows[4][:-2]
    _write_csv(p, COLS, rows)
    return p


def _mk_missing_column(d, good):
    p = d / "run.csv"
    _write_csv(p, COLS[:-1], [r[:-1] for r in _rows()])
    return p


def _mk_degrees(d, good):
    p = d / "run.csv"
    rows = _rows()
    for r in rows:
        r[1] = 100.0
    _write_csv(p, COLS, rows)
    return p


def _mk_milliseconds(d, good):
    p = d / "run.csv"
    rows = _rows()
    for k, r in enumerate(rows):
        r[0] = float(k)
    _write_csv(p, COLS, rows)
    return p


def _mk_nan(d, good):
    p = d / "run.csv"
    rows = _rows()
    rows[7][9] = "nan"
    _write_csv(p, COLS, rows)
    return p


def _mk_decreasing(d, good):
    p = d / "run.csv"
    rows = _rows()
    rows[10][0] = 0.0
    _write_csv(p, COLS, rows)
    return p


def _mk_no_header(d, good):
    p = d / "run.csv"
    _write_csv(p, [str(x) for x in _rows()[0]], _rows()[1:])
    return p


def _mk_eight_joints(d, good):
    p = d / "run.csv"
    _write_csv(p, COLS + ["q[7]"], [r + [0.0] for r in _rows()])
    return p


def _mk_unknown_suffix(d, good):
    p = d / "run.parquet"
    p.write_bytes(b"PAR1")
    return p


def _mk_npz_empty(d, good):
    p = d / "run.npz"
    p.write_bytes(b"")
    return p


def _mk_npz_truncated(d, good):
    p = d / "run.npz"
    _npz(p, **_good_arrays(2000))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    return p


def _mk_npz_huge_shape(d, good):
    """An .npz whose q.npy header declares 10^9 x 7 values but holds 50 x 7 (a forged or corrupt file)."""
    import io as pyio
    import zipfile

    p = d / "run.npz"
    arrays = _good_arrays(50)
    with zipfile.ZipFile(p, "w") as z:
        for name, a in arrays.items():
            buf = pyio.BytesIO()
            if name == "q":
                h = np.lib.format.header_data_from_array_1_0(a)
                h["shape"] = (10**9, 7)
                np.lib.format.write_array_header_1_0(buf, h)
                buf.write(a.tobytes())
            else:
                np.lib.format.write_array(buf, a)
            z.writestr(name + ".npy", buf.getvalue())
    return p


def _mk_npz_object(d, good):
    p = d / "run.npz"
    arrays = _good_arrays()
    arrays["q"] = np.array([{"a": 1}] * 50, dtype=object)
    with open(p, "wb") as fh:
        np.savez(fh, **arrays)
    return p


def _mk_npz_missing_q(d, good):
    p = d / "run.npz"
    arrays = _good_arrays()
    del arrays["q"]
    _npz(p, **arrays)
    return p


def _mk_npz_text_array(d, good):
    p = d / "run.npz"
    arrays = _good_arrays()
    arrays["dq"] = np.array([["x"] * 7] * 50)
    _npz(p, **arrays)
    return p


def _mk_npz_meta_bad(d, good):
    p = d / "run.npz"
    _npz(p, **_good_arrays(), meta=np.array("{not json"))
    return p


def _mk_npz_wrong_shape(d, good):
    p = d / "run.npz"
    arrays = _good_arrays()
    arrays["tau_J"] = np.zeros((50, 6))
    _npz(p, **arrays)
    return p


def _mk_fifo(d, good):
    p = d / "run.csv"
    os.mkfifo(p)
    return p


def _mk_fifo_mcap(d, good):
    p = d / "run.mcap"
    os.mkfifo(p)
    return p


def _mk_dev_zero(d, good):
    p = d / "run.csv"
    p.symlink_to("/dev/zero")
    return p


def _mk_dir_csv(d, good):
    p = d / "run.csv"
    p.mkdir()
    return p


def _mk_missing(d, good):
    return d / "nope.csv"


def _sidecar(d: Path, good: Path, meta: object, raw: str | None = None) -> Path:
    p = _copy_log(good, d)
    Path(str(p) + ".json").write_text(raw if raw is not None else json.dumps(meta))
    return p


def _mk_sidecar_not_json(d, good):
    return _sidecar(d, good, None, "{tool: hand")


def _mk_sidecar_list(d, good):
    return _sidecar(d, good, [1, 2, 3])


def _tool(**kw):
    t = {"mass": 1.0, "com": [0, 0, 0.05], "inertia": [[1e-3, 0, 0], [0, 1e-3, 0], [0, 0, 1e-3]]}
    t.update(kw)
    return {"tool": t}


def _mk_tool_1e9(d, good):
    return _sidecar(d, good, _tool(mass=1e9))


def _mk_tool_25kg(d, good):
    return _sidecar(d, good, _tool(mass=25.0))


def _mk_tool_mass_string(d, good):
    return _sidecar(d, good, _tool(mass="heavy"))


def _mk_tool_mass_list(d, good):
    return _sidecar(d, good, _tool(mass=[1, 2]))


def _mk_tool_negative_mass(d, good):
    return _sidecar(d, good, _tool(mass=-1.0))


def _mk_tool_not_psd(d, good):
    return _sidecar(d, good, _tool(inertia=[[1e-3, 0, 0], [0, -1e-3, 0], [0, 0, 1e-3]]))


def _mk_tool_triangle(d, good):
    return _sidecar(d, good, _tool(inertia=[[1e-3, 0, 0], [0, 1e-3, 0], [0, 0, 5e-3]]))


def _mk_tool_asymmetric(d, good):
    return _sidecar(d, good, _tool(inertia=[[1e-3, 1e-4, 0], [0, 1e-3, 0], [0, 0, 1e-3]]))


def _mk_tool_com_far(d, good):
    return _sidecar(d, good, _tool(com=[0, 0, 50.0]))


def _mk_tool_com_short(d, good):
    return _sidecar(d, good, _tool(com=[0, 0]))


def _mk_tool_missing_inertia(d, good):
    t = _tool()
    del t["tool"]["inertia"]
    return _sidecar(d, good, t)


def _mk_tool_unknown_name(d, good):
    return _sidecar(d, good, {"tool": "robotiq"})


def _mk_tool_number(d, good):
    return _sidecar(d, good, {"tool": 5})


def _mk_gravity_zero(d, good):
    return _sidecar(d, good, {"gravity": [0, 0, 0]})


def _mk_gravity_big(d, good):
    return _sidecar(d, good, {"gravity": [0, 0, -98.1]})


def _mk_gravity_short(d, good):
    return _sidecar(d, good, {"gravity": [0, -9.81]})


def _mk_gravity_text(d, good):
    return _sidecar(d, good, {"gravity": ["a", "b", "c"]})


def _mk_gravity_nan(d, good):
    return _sidecar(d, good, None, '{"gravity": [0, 0, NaN]}')


def _mk_controller_list(d, good):
    return _sidecar(d, good, {"controller": [1, 2]})


def _mk_sidecar_fifo(d, good):
    p = _copy_log(good, d)
    side = Path(str(p) + ".json")
    side.unlink()
    os.mkfifo(side)
    return p


def _mk_sidecar_binary(d, good):
    p = _copy_log(good, d)
    Path(str(p) + ".json").write_bytes(b"\xff\xfe\x00garbage")
    return p


def _gaz_folder(d: Path, n: int = 60, layout: str = "sample") -> Path:
    g = d / "gaz"
    g.mkdir()
    t = np.arange(n) * 1e-3
    q = Q0 + 0.1 * np.sin(np.outer(t * 20, np.arange(1, 8)))
    (g / "exciting_traj_time.txt").write_text("\n".join(map(str, t)) + "\n")
    for name, a in (("positions", q), ("velocity", np.zeros((n, 7))), ("torques", np.zeros((n, 7)))):
        vals = a.ravel() if layout == "sample" else a.T.ravel()
        (g / f"exciting_traj_{name}.txt").write_text("\n".join(f"{v:.9g}" for v in vals) + "\n")
    return g


def _mk_gaz_missing_file(d, good):
    g = _gaz_folder(d)
    (g / "exciting_traj_torques.txt").unlink()
    return g


def _mk_gaz_count(d, good):
    g = _gaz_folder(d)
    with open(g / "exciting_traj_velocity.txt", "a") as fh:
        fh.write("0.5\n")
    return g


def _mk_gaz_text(d, good):
    g = _gaz_folder(d)
    with open(g / "exciting_traj_torques.txt", "a") as fh:
        fh.write("oops\n")
    return g


def _mk_gaz_noise(d, good):
    g = _gaz_folder(d)
    rng = np.random.default_rng(0)
    (g / "exciting_traj_positions.txt").write_text("\n".join(map(str, rng.uniform(-1, 1, 60 * 7))) + "\n")
    return g


def _mk_gaz_fifo_member(d, good):
    g = _gaz_folder(d)
    (g / "exciting_traj_time.txt").unlink()
    os.mkfifo(g / "exciting_traj_time.txt")
    return g


def _mk_blank_cell(d, good):
    p = d / "run.csv"
    rows = _rows()
    rows[3][1 + 7 + 2] = ""  # dq[2] blank: the message names dq[2], not its neighbour
    _write_csv(p, COLS, rows)
    return p


def _mk_binary_csv(d, good):
    p = d / "run.csv"
    p.write_bytes(bytes(range(256)) * 8)
    return p


def _mk_big_field(d, good):
    p = d / "run.csv"
    p.write_text(",".join(COLS) + ",note\n" + "".join(",".join(["0"] * 22) + ',"' + "x" * 20_000_000 + '"\n'
                                                     for _ in range(3)))
    return p


def _mk_duplicate_alias(d, good):
    p = d / "run.csv"
    rows = _rows()
    _write_csv(p, COLS + ["q_0"], [r + [r[1] + 0.5] for r in rows])  # q[0] and q_0 disagree
    return p


def _mk_q_outside_range(d, good):
    p = d / "run.csv"
    rows = _rows()
    for r in rows[20:]:
        r[1 + 3] = -3.6  # joint 3 (range about [-3.07, -0.07] rad)
    _write_csv(p, COLS, rows)
    return p


def _mk_sidecar_nested(d, good):
    return _sidecar(d, good, None, '{"controller": ' + "[" * 100_000 + "]" * 100_000 + "}")


def _mk_sidecar_short_kp(d, good):
    return _sidecar(d, good, {"controller": {"law": "computed_torque_eq2", "kp": [400, 400], "kd": 40}})


LOG_CASES = {
    "empty": (_mk_empty, "empty"),
    "header_only": (_mk_header_only, "no data rows"),
    "text_value": (_mk_text_value, "line 5: 'abc' is not a number"),
    "ragged_row": (_mk_ragged, "line 6 has 20 values"),
    "missing_column": (_mk_missing_column, "tau_J"),
    "degrees": (_mk_degrees, "degrees"),
    "milliseconds": (_mk_milliseconds, "milliseconds"),
    "nan": (_mk_nan, "NaN"),
    "decreasing_time": (_mk_decreasing, "not monotonic"),
    "no_header": (_mk_no_header, "header"),
    "eight_joints": (_mk_eight_joints, "7 joints (indices 0..6)"),
    "unknown_suffix": (_mk_unknown_suffix, "unknown log format"),
    "npz_empty": (_mk_npz_empty, "not a valid .npz"),
    "npz_truncated": (_mk_npz_truncated, "npz"),
    "npz_huge_shape": (_mk_npz_huge_shape, "declares shape"),
    "npz_object": (_mk_npz_object, "Python objects"),
    "npz_missing_q": (_mk_npz_missing_q, "missing array 'q'"),
    "npz_text_array": (_mk_npz_text_array, "not numeric"),
    "npz_meta_not_json": (_mk_npz_meta_bad, "not a JSON string"),
    "npz_wrong_shape": (_mk_npz_wrong_shape, "the FER has 7"),
    "fifo": (_mk_fifo, "FIFO"),
    "fifo_named_mcap": (_mk_fifo_mcap, "FIFO"),
    "dev_zero_link": (_mk_dev_zero, "character device"),
    "directory_named_csv": (_mk_dir_csv, "missing file exciting_traj_time.txt"),
    "missing": (_mk_missing, "not found"),
    "sidecar_not_json": (_mk_sidecar_not_json, "not valid JSON"),
    "sidecar_list": (_mk_sidecar_list, "JSON object"),
    "tool_1e9_kg": (_mk_tool_1e9, "mass"),
    "tool_25_kg": (_mk_tool_25kg, "not plausible"),
    "tool_mass_string": (_mk_tool_mass_string, "mass must be a number"),
    "tool_mass_list": (_mk_tool_mass_list, "mass must be a number"),
    "tool_negative_mass": (_mk_tool_negative_mass, "mass"),
    "tool_inertia_not_psd": (_mk_tool_not_psd, "positive semi-definite"),
    "tool_inertia_triangle": (_mk_tool_triangle, "triangle inequality"),
    "tool_inertia_asymmetric": (_mk_tool_asymmetric, "symmetric"),
    "tool_com_50_m": (_mk_tool_com_far, "com"),
    "tool_com_2d": (_mk_tool_com_short, "com must have shape (3,)"),
    "tool_missing_inertia": (_mk_tool_missing_inertia, "lacks ['inertia']"),
    "tool_unknown_name": (_mk_tool_unknown_name, "unknown tool"),
    "tool_number": (_mk_tool_number, "tool"),
    "gravity_zero": (_mk_gravity_zero, "norm 0"),
    "gravity_98": (_mk_gravity_big, "norm 98.1"),
    "gravity_2d": (_mk_gravity_short, "shape (3,)"),
    "gravity_text": (_mk_gravity_text, "gravity"),
    "gravity_nan": (_mk_gravity_nan, "NaN"),
    "controller_list": (_mk_controller_list, "controller"),
    "sidecar_fifo": (_mk_sidecar_fifo, "FIFO"),
    "sidecar_binary": (_mk_sidecar_binary, "UTF-8"),
    "gaz_missing_file": (_mk_gaz_missing_file, "missing file exciting_traj_torques.txt"),
    "gaz_count_mismatch": (_mk_gaz_count, "7 per sample"),
    "gaz_text": (_mk_gaz_text, "'oops' is not a number"),
    "gaz_ambiguous_layout": (_mk_gaz_noise, "sample-major"),
    "gaz_fifo_member": (_mk_gaz_fifo_member, "FIFO"),
    "blank_cell": (_mk_blank_cell, "line 5: '' is not a number (column dq[2])"),
    "binary_csv": (_mk_binary_csv, "run.csv: not a log: byte 128 is not UTF-8"),
    "big_field": (_mk_big_field, "a cell of over 128 KiB"),
    "duplicate_alias_conflict": (_mk_duplicate_alias, "'q[0]' and 'q_0' are the same column written twice"),
    "q_outside_range": (_mk_q_outside_range, "q[3] is -3.6 rad at row 20"),
    "sidecar_nested": (_mk_sidecar_nested, "run.csv.json: JSON nested too deeply"),
    "sidecar_short_kp": (_mk_sidecar_short_kp, "controller.kp in the log metadata must be a finite number or 7"),
}


@pytest.mark.parametrize("case", sorted(LOG_CASES))
def test_log_readers_name_the_problem(case, good, tmp_path):
    make, match = LOG_CASES[case]
    p = make(tmp_path, good)
    before = _files(tmp_path)
    with pytest.raises((ValueError, FileNotFoundError)) as e:
        load_log(p)
    assert match.lower() in str(e.value).lower(), str(e.value)
    assert "\n" not in str(e.value).strip()
    assert _files(tmp_path) == before


# the same files through the command line: one line, exit status 2 (a subset keeps the suite fast)
CLI_LOG_CASES = ["empty", "text_value", "npz_truncated", "npz_huge_shape", "fifo", "dev_zero_link",
                 "directory_named_csv", "missing", "tool_1e9_kg", "tool_mass_list", "gravity_zero", "sidecar_list",
                 "gaz_ambiguous_layout"]


@pytest.mark.parametrize("command", ["compare", "diagnose"])
@pytest.mark.parametrize("case", CLI_LOG_CASES)
def test_cli_log_errors_are_one_line(case, command, good, tmp_path, capsys):
    make, match = LOG_CASES[case]
    p = make(tmp_path, good)
    run_cli_error(capsys, [command, str(p), "--quiet"], tmp_path, match)


def test_a_1e9_kg_tool_is_refused_not_verdict_none(good, tmp_path, capsys):
    """The issue's case: a 1e9 kg tool in a sidecar must be refused, not give the verdict 'none'."""
    p = _mk_tool_1e9(tmp_path, good)
    line = run_cli_error(capsys, ["diagnose", str(p), "--json", "--quiet"], tmp_path, "1e+09 kg")
    assert "plausible" in line


def test_joint_major_gaz_folder_is_read_as_joint_major(tmp_path):
    a = load_log(_gaz_folder(tmp_path / "a" if (tmp_path / "a").mkdir() is None else tmp_path, layout="sample"))
    (tmp_path / "j").mkdir()
    b = load_log(_gaz_folder(tmp_path / "j", layout="joint"))
    np.testing.assert_array_equal(a.q, b.q)
    # one value per line is ambiguous by line structure; with 7 values per line or n per line it is decided by it
    (tmp_path / "rows").mkdir()
    g = _gaz_folder(tmp_path / "rows")
    q = a.q
    (g / "exciting_traj_positions.txt").write_text("\n".join(" ".join(map(str, r)) for r in q.T) + "\n")
    np.testing.assert_array_equal(load_log(g).q, q)


# ----------------------------------------------------------------------------------------------- outputs
def test_fit_never_writes_its_own_log(good, tmp_path, capsys):
    p = _copy_log(good, tmp_path)
    run_cli_error(capsys, ["fit", str(p), "--add", "payload", "-o", str(p), "--force", "--quiet"], tmp_path,
                  "inputs")
    side = Path(str(p) + ".json")
    run_cli_error(capsys, ["fit", str(p), "--add", "payload", "-o", str(side), "--force", "--quiet"], tmp_path,
                  "inputs")
    link = tmp_path / "alias.csv"
    os.link(p, link)
    run_cli_error(capsys, ["fit", str(p), "--add", "payload", "-o", str(link), "--force", "--quiet"], tmp_path,
                  "inputs")


def test_fit_model_is_an_input_too(good, tmp_path, capsys):
    p = _copy_log(good, tmp_path)
    model = tmp_path / "model.json"
    ModelConfig().save(model)
    run_cli_error(capsys, ["fit", str(p), "--add", "payload", "--model", str(model), "-o", str(model), "--force",
                           "--quiet"], tmp_path, "inputs")


@pytest.mark.parametrize("case", ["exists", "report_exists", "report_is_file", "parent_is_file", "out_is_dir",
                                  "unknown_effect", "empty_add", "report_is_log"])
def test_fit_output_faults(case, good, tmp_path, capsys):
    p = _copy_log(good, tmp_path)
    out = tmp_path / "cal.json"
    argv = ["fit", str(p), "--add", "payload", "-o", str(out), "--quiet"]
    match = {"exists": "exists", "report_exists": "exists", "report_is_file": "not a folder",
             "parent_is_file": "not a folder", "out_is_dir": "is a folder", "unknown_effect": "frobnication",
             "empty_add": "--add", "report_is_log": "inputs"}[case]
    if case == "exists":
        out.write_text("{}")
    elif case == "report_exists":
        (tmp_path / "rep").mkdir()
        (tmp_path / "rep" / "report.md").write_text("old")
        argv += ["--report", str(tmp_path / "rep")]
    elif case == "report_is_file":
        (tmp_path / "rep").write_text("x")
        argv += ["--report", str(tmp_path / "rep"), "--force"]
    elif case == "parent_is_file":
        (tmp_path / "f").write_text("x")
        argv[argv.index("-o") + 1] = str(tmp_path / "f" / "cal.json")
    elif case == "out_is_dir":
        out.mkdir()
        argv += ["--force"]
    elif case == "unknown_effect":
        argv[argv.index("--add") + 1] = "frobnication"
    elif case == "empty_add":
        argv[argv.index("--add") + 1] = ","
    elif case == "report_is_log":
        argv += ["--report", str(p), "--force"]
    run_cli_error(capsys, argv, tmp_path, match)
    if case not in ("exists", "out_is_dir"):
        assert not out.exists()
    assert not list(tmp_path.glob(".*partial"))  # no staging left behind


def test_fit_model_and_report_appear_together(good, tmp_path, capsys, monkeypatch):
    """A failing report step leaves neither the model nor the report."""
    import franka_vs_gym.validation.report as report

    p = _copy_log(good, tmp_path)

    def broken(*a, **k):
        raise ValueError("figure backend unavailable")

    monkeypatch.setattr(report, "markdown_report", broken)
    run_cli_error(capsys, ["fit", str(p), "--add", "payload", "-o", str(tmp_path / "cal.json"), "--report",
                           str(tmp_path / "rep"), "--quiet"], tmp_path, "figure backend")
    assert not (tmp_path / "cal.json").exists() and not (tmp_path / "rep").exists()


@pytest.mark.parametrize("case", ["report_exists", "report_is_file", "cutoff_negative", "rate_nan", "model_missing",
                                  "model_not_json", "model_is_dir", "model_is_log", "replay_mode"])
def test_compare_option_faults(case, good, tmp_path, capsys):
    p = _copy_log(good, tmp_path)
    argv = ["compare", str(p), "--quiet", "--no-replay"]
    match = {"report_exists": "exists", "report_is_file": "not a folder", "cutoff_negative": "cutoff",
             "rate_nan": "rate", "model_missing": "not found", "model_not_json": "not valid JSON",
             "model_is_dir": "folder", "model_is_log": "not valid JSON", "replay_mode": "invalid choice"}[case]
    if case == "report_exists":
        (tmp_path / "rep").mkdir()
        (tmp_path / "rep" / "fig.png").write_bytes(b"old figure")
        argv += ["--report", str(tmp_path / "rep")]
    elif case == "report_is_file":
        (tmp_path / "rep").write_text("x")
        argv += ["--report", str(tmp_path / "rep"), "--force"]
    elif case == "cutoff_negative":
        argv += ["--cutoff", "-1"]
    elif case == "rate_nan":
        argv += ["--rate", "nan"]
    elif case == "model_missing":
        argv += ["--model", str(tmp_path / "none.json")]
    elif case == "model_not_json":
        (tmp_path / "m.json").write_text("{oops")
        argv += ["--model", str(tmp_path / "m.json")]
    elif case == "model_is_dir":
        (tmp_path / "m").mkdir()
        argv += ["--model", str(tmp_path / "m")]
    elif case == "model_is_log":
        argv += ["--model", str(p)]
    elif case == "replay_mode":
        argv += ["--replay-mode", "teleport"]
    if case == "replay_mode":  # argparse's own error: one usage line plus the error, exit 2
        before = _files(tmp_path)
        with pytest.raises(SystemExit) as e:
            cli(argv)
        assert e.value.code == 2 and match in capsys.readouterr().err
        assert _files(tmp_path) == before
        return
    run_cli_error(capsys, argv, tmp_path, match)


# ----------------------------------------------------------------------------------------------- model files
def _model_file(d: Path, **changes) -> Path:
    data = ModelConfig().to_dict()
    for k, v in changes.items():
        if isinstance(v, dict) and isinstance(data.get(k), dict):
            data[k] = {**data[k], **v}
        else:
            data[k] = v
    p = d / "model.json"
    p.write_text(json.dumps(data))
    return p


MODEL_CASES = {
    "nan_friction": ({"friction": {"phi1": [float("nan")] + [0.5] * 6}}, "NaN"),
    "nan_coulomb_vel": ({"friction": {"coulomb_vel": float("nan")}}, "coulomb_vel"),
    "negative_phi2": ({"friction": {"phi2": [-5.0] + [5.0] * 6}}, "phi2"),
    "pushing_viscous": ({"friction": {"viscous": [-3.0] + [0.0] * 6}}, "not dissipative"),
    "zero_gravity": ({"gravity": [0, 0, 0]}, "norm 0"),
    "unknown_key": ({"colour": "red"}, "unknown keys"),
    "negative_payload": ({"payload": {"mass": -1.0, "com": [0, 0, 0], "inertia": [0, 0, 0]}}, "mass"),
    "heavy_tool": ({"tool": {"mass": 1e9, "com": [0, 0, 0], "inertia": [1, 1, 1]}}, "mass"),
    "tool_triangle": ({"tool": {"mass": 1.0, "com": [0, 0, 0], "inertia": [1e-3, 1e-3, 5e-3]}}, "triangle"),
    "delay_5_s": ({"delay": 5.0}, "delay"),
    "delay_negative": ({"delay": -0.001}, "delay"),
    "delay_text": ({"delay": "fast"}, "delay"),
    "armature_negative": ({"armature": [-1.0] + [0.0] * 6}, "armature"),
    "mass_scale_zero": ({"link_mass_scale": [0.0] + [1.0] * 6}, "link_mass_scale"),
    "offset_short": ({"torque_offset": [0.0] * 6}, "torque_offset"),
    "delay_channel": ({"delay_channel": "radio"}, "delay_channel"),
    "notes_list": ({"notes": [1]}, "notes"),
    "format": ({"format": "other/9"}, "format"),
    "friction_list": ({"friction": [1, 2]}, "friction"),
    "check_gravity_text": ({"check_gravity": "no"}, "check_gravity"),
}


@pytest.mark.parametrize("case", sorted(MODEL_CASES))
def test_model_files_are_validated(case, tmp_path):
    changes, match = MODEL_CASES[case]
    p = _model_file(tmp_path, **changes)
    before = _sha(p)
    with pytest.raises(ValueError) as e:
        ModelConfig.load(p)
    assert match.lower() in str(e.value).lower(), str(e.value)
    assert str(p) in str(e.value)
    assert _sha(p) == before


def test_gravity_check_can_be_opted_out(tmp_path):
    p = _model_file(tmp_path, gravity=[0, 0, -1.62], check_gravity=False)  # the Moon
    cfg = ModelConfig.load(p)
    assert cfg.gravity[2] == -1.62 and any("gravity check disabled" in w for w in cfg.plausibility_warnings())
    assert ModelConfig.from_dict(cfg.to_dict()).check_gravity is False


@pytest.mark.parametrize("case", sorted(MODEL_CASES)[:6])
def test_cli_model_file_errors(case, good, tmp_path, capsys):
    changes, match = MODEL_CASES[case]
    p = _copy_log(good, tmp_path)
    m = _model_file(tmp_path, **changes)
    run_cli_error(capsys, ["compare", str(p), "--model", str(m), "--quiet", "--no-replay"], tmp_path, match)


# ----------------------------------------------------------------------------------------------- programmatic
@pytest.mark.parametrize("make,match", [
    (lambda: RigidBody(float("nan")), "mass must be finite"),
    (lambda: RigidBody(1.0, inertia=[1e-3, 1e-3, 3e-3]), "triangle"),
    (lambda: RigidBody(0.0, inertia=[1e-3, 1e-3, 1e-3]), "no mass"),
    (lambda: RigidBody(1e6), "plausible range"),
    (lambda: RigidBody("1"), "number"),
    (lambda: RigidBody(1.0, inertia="big"), "inertia"),
    (lambda: ModelConfig(gravity=(0, 0, 0)), "norm 0"),
    (lambda: ModelConfig(gravity=(0, 0, -9.81 * 3)), "norm"),
    (lambda: ModelConfig(delay=2.0), "delay"),
    (lambda: ModelConfig(link_mass_scale=[1000.0] * 7), "link_mass_scale"),
    (lambda: ModelConfig(payload=RigidBody(30.0, inertia=[0.1, 0.1, 0.1])), "not plausible"),
    (lambda: ModelConfig(payload=RigidBody(1.0, com=(0, 0, 3.0))), "centre of mass"),
    (lambda: Friction(coulomb_vel=float("nan")), "finite"),
    (lambda: Friction(phi2=[-1.0] * 7), "phi2"),
    (lambda: FrankaModel().set_gravity([0, 0, 0]), "norm 0"),
    (lambda: FrankaModel().set_payload(-1.0), "mass"),
    (lambda: FrankaModel().set_tool(np.eye(4), 1e9), "mass"),
], ids=lambda x: x if isinstance(x, str) else "")
def test_model_values_are_checked(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_plausibility_warnings_for_what_a_user_may_mean():
    cfg = ModelConfig(payload=RigidBody(5.0, inertia=[0.01, 0.01, 0.01]))
    assert any("rated payload" in w for w in cfg.plausibility_warnings())
    assert ModelConfig().plausibility_warnings() == []


# ----------------------------------------------------------------------------------------------- robot API
@pytest.fixture(scope="module")
def sim():
    from franka_vs_gym.sim import FrankaSim

    return FrankaSim(camera=False)


def _pos(s):
    from franka_vs_gym.sim import POSITION

    s.set_robot_state(POSITION)


def _vel(s):
    from franka_vs_gym.sim import VELOCITY

    s.set_robot_state(VELOCITY)


def _tor(s):
    from franka_vs_gym.sim import FORCE_TORQUE

    s.set_robot_state(FORCE_TORQUE)


ROBOT_CASES = {
    "set_position_timeout_0": (_pos, lambda s: s.set_position(1, Q0, timeout=0), ValueError, "timeout"),
    "set_position_timeout_nan": (_pos, lambda s: s.set_position(1, Q0, timeout=float("nan")), ValueError,
                                 "timeout"),
    "set_position_timeout_text": (_pos, lambda s: s.set_position(1, Q0, timeout="1"), ValueError, "timeout"),
    "set_position_outside": (_pos, lambda s: s.set_position(1, Q0 + 10), ValueError, "limits"),
    "set_position_nan": (_pos, lambda s: s.set_position(1, Q0 * np.nan), ValueError, "NaN"),
    "positioning_velocity_tiny": (_pos, lambda s: (s.set_positioning_velocity(1e-9),
                                                   s.set_position(1, Q0 + 0.1)), ValueError, "more than timeout"),
    "positioning_velocity_0": (_pos, lambda s: s.set_positioning_velocity(0), ValueError, "positioning velocity"),
    "positioning_velocity_nan": (_pos, lambda s: s.set_positioning_velocity(float("nan")), ValueError,
                                 "positioning velocity"),
    "positioning_velocity_200": (_pos, lambda s: s.set_positioning_velocity(200), ValueError,
                                 "positioning velocity"),
    "velocity_nan": (_vel, lambda s: s.set_velocity(1, [np.nan] * 7), ValueError, "NaN"),
    "velocity_shape": (_vel, lambda s: s.set_velocity(1, [0.0] * 6), ValueError, "shape"),
    "twist_shape": (_vel, lambda s: s.set_velocity(3, [0.0] * 7), ValueError, "shape"),
    "torque_inf": (_tor, lambda s: s.set_force_torque(1, [np.inf] * 7), ValueError, "NaN or inf"),
    "torque_text": (_tor, lambda s: s.set_force_torque(1, "abc"), ValueError, "numeric"),
    "torque_wrong_state": (_vel, lambda s: s.set_force_torque(1, [0.0] * 7), RuntimeError, "FORCE_TORQUE"),
    "reset_outside": (_tor, lambda s: s.reset(Q0 + 10), ValueError, "joint limits"),
    "wait_negative": (_tor, lambda s: s.wait(-1), ValueError, "duration"),
    "wait_nan": (_tor, lambda s: s.wait(float("nan")), ValueError, "duration"),
    "eMc_not_rotation": (_tor, lambda s: s.set_eMc(np.diag([2.0, 1, 1, 1])), ValueError, "rotation"),
    "tool_1e9": (_tor, lambda s: s.set_tool(np.eye(4), 1e9), ValueError, "mass"),
    "tool_not_psd": (_tor, lambda s: s.set_tool(np.eye(4), 1.0, inertia=np.diag([1, -1, 1])), ValueError,
                     "positive semi-definite"),
    "command_rates": (_tor, lambda s: setattr(s, "command_rates", "sometimes"), ValueError, "command_rates"),
    "acceleration_state": (_tor, lambda s: s.set_robot_state(3), ValueError, "acceleration"),
}


@pytest.mark.parametrize("case", sorted(ROBOT_CASES))
def test_robot_api_faults(case, sim):
    prep, act, exc, match = ROBOT_CASES[case]
    sim.reset(Q0)
    sim.set_positioning_velocity(20)
    prep(sim)
    q = sim.get_position()
    t0 = time.perf_counter()
    with pytest.raises(exc, match=match):
        act(sim)
    assert time.perf_counter() - t0 < 5.0  # nothing hangs
    np.testing.assert_array_equal(sim.get_position(), q)  # a refused command does not move the robot


def test_timestep_zero_is_refused():
    from franka_vs_gym.sim import FrankaSim

    with pytest.raises(ValueError, match="timestep"):
        FrankaSim(camera=False, timestep=0.0)


# ----------------------------------------------------------------------------------------------- environments
ENV_CASES = {
    "nan_action": (lambda e: e.step(np.full(7, np.nan, np.float32)), ValueError, "NaN"),
    "wrong_shape": (lambda e: e.step(np.zeros(3, np.float32)), ValueError, "shape"),
    "text_action": (lambda e: e.step("go"), ValueError, "numeric"),
    "out_of_bounds": (lambda e: e.step(np.full(7, 1e4, np.float32)), ValueError, "outside the action space"),
}


@pytest.fixture(scope="module")
def env():
    import gymnasium as gym

    import franka_vs_gym.envs  # noqa: F401

    e = gym.make("FrankaTorqueTracking-v0")
    yield e
    e.close()


@pytest.mark.parametrize("case", sorted(ENV_CASES))
def test_environment_faults(case, env):
    env.reset(seed=0)
    act, exc, match = ENV_CASES[case]
    with pytest.raises(exc, match=match):
        act(env.unwrapped)


def test_environment_step_before_reset():
    import gymnasium as gym

    import franka_vs_gym.envs  # noqa: F401

    e = gym.make("FrankaTorqueTracking-v0").unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        e.step(np.zeros(7, np.float32))
    e.close()


@pytest.mark.parametrize("kwargs,match", [
    ({"control_period": -0.01}, "control_period"),
    ({"control_period": float("nan")}, "control_period"),
])
def test_environment_construction_faults(kwargs, match):
    import gymnasium as gym

    import franka_vs_gym.envs  # noqa: F401

    with pytest.raises(ValueError, match=match):
        gym.make("FrankaTorqueTracking-v0", **kwargs)


# ----------------------------------------------------------------------------------------------- evaluate, demo
@pytest.mark.parametrize("argv,match", [
    (["evaluate", "zero", "--env-kwargs", '{"colour": "red"}'], "takes no keyword 'colour'"),
    (["evaluate", "zero", "--env", "FrankaTeleport-v9"], "unknown environment"),
    (["evaluate", "zero", "--episodes", "0"], "--episodes"),
    (["evaluate", "zero", "--env-kwargs", "{oops"], "not valid JSON"),
    (["evaluate", "zero", "--env-kwargs", "[1, 2]"], "JSON object"),
    (["evaluate", "teleport"], "unknown policy"),
    (["evaluate", "ibvs", "--env-kwargs", '{"action_type": "torque"}'], "joint_velocity or cartesian_velocity"),
    (["demo", "--duration", "-1"], "--duration"),
    (["demo", "torque", "--duration", "0.6"], "too fast for the FER"),
    (["demo", "--duration", "nan"], "--duration"),
])
def test_cli_option_faults(argv, match, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run_cli_error(capsys, argv + (["--out", str(tmp_path / "run")] if argv[0] == "demo" else []), tmp_path, match)
    assert not (tmp_path / "run").exists() and not (tmp_path / "runs").exists()  # no half-made run folders


def test_evaluate_json_output_faults(tmp_path, capsys):
    (tmp_path / "r.json").write_text("{}")
    run_cli_error(capsys, ["evaluate", "zero", "--json", str(tmp_path / "r.json")], tmp_path, "exists")
    (tmp_path / "d").mkdir()
    run_cli_error(capsys, ["evaluate", "zero", "--json", str(tmp_path / "d"), "--force"], tmp_path, "folder")


def test_demo_out_not_empty(tmp_path, capsys):
    out = tmp_path / "demo"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    run_cli_error(capsys, ["demo", "--out", str(out), "--quiet", "--no-video"], tmp_path, "not empty")


# ----------------------------------------------------------------------------------------------- signals
def _spawn(args: list[str], cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-m", "franka_vs_gym.cli", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


#: how long an interrupted run may take to stop. What is tested is that it stops (exit 130, one line, the folder kept
#: as -incomplete) instead of running on: the run asked for below is 600 simulated seconds, minutes of work even on
#: a fast machine, so a limit of many seconds still tells the two apart, and holds on a loaded 2-core machine,
#: where the interpreter's own exit can take over a second.
STOP_LIMIT_S = 20.0


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_stops_the_run_promptly_and_keeps_the_partial_run(sig, tmp_path):
    p = _spawn(["experiment", "tracking", "--duration", "600", "--out", "runs", "--no-video"], tmp_path)
    deadline = time.time() + 300
    while time.time() < deadline and not list((tmp_path / "runs").glob("tracking-*")):
        time.sleep(0.1)
    assert list((tmp_path / "runs").glob("tracking-*")), "the experiment did not start"
    time.sleep(1.0)
    (run,) = list((tmp_path / "runs").glob("tracking-*"))
    (run / "marker.txt").write_text("partial")  # something in the folder, as a long run would have
    t0 = time.time()
    p.send_signal(sig)
    out, err = p.communicate(timeout=120)
    elapsed = time.time() - t0
    assert p.returncode == 130, err
    assert elapsed < STOP_LIMIT_S, elapsed
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("tracking: writing")
             and "it/s" not in ln and "step/s" not in ln and "%|" not in ln]
    assert len(lines) == 1 and lines[0].startswith("franka-vs experiment: interrupted"), err
    assert "Traceback" not in err
    assert not run.exists() and (run.parent / (run.name + "-incomplete")).is_dir()
    assert "incomplete" in lines[0]


# ----------------------------------------------------------------------------------------------- determinism
_TRAJ = """
import hashlib, numpy as np, gymnasium as gym, franka_vs_gym.envs
env = gym.make("FrankaTorqueTracking-v0", action_scale="physical")
obs, _ = env.reset(seed=7)
rng = np.random.default_rng(7)
h = hashlib.sha256()
for _ in range(60):
    obs, r, term, trunc, info = env.step(rng.uniform(-5, 5, 7).astype(np.float32))
    h.update(obs["q"].tobytes()); h.update(obs["dq"].tobytes()); h.update(np.float64(r).tobytes())
    if term or trunc:
        obs, _ = env.reset(seed=8)
print(h.hexdigest())
"""


def test_same_seed_same_trajectory_across_processes():
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    outs = [subprocess.run([sys.executable, "-c", _TRAJ], env=env, capture_output=True, text=True, timeout=120)
            for _ in range(2)]
    for o in outs:
        assert o.returncode == 0, o.stderr
    digests = [o.stdout.strip().splitlines()[-1] for o in outs]
    assert digests[0] == digests[1] and len(digests[0]) == 64


def test_user_error_is_a_value_error():
    assert issubclass(UserError, ValueError)
    assert math.isfinite(1.0)


def test_heavy_tool_is_warned_about_not_refused(good, tmp_path, capsys):
    """5 kg is beyond the FER's rated payload but a user may mean it: the result says so (JSON included)."""
    p = _sidecar(tmp_path, good, _tool(mass=5.0, inertia=[[0.02, 0, 0], [0, 0.02, 0], [0, 0, 0.02]]))
    assert cli(["compare", str(p), "--json", "--quiet", "--no-replay"]) == 0
    out, err = capsys.readouterr()
    d = json.loads(out)
    assert any("rated payload" in w for w in d["model_warnings"]), d["model_warnings"]
    assert "warning: tool + payload 5.73 kg" in err or "warning: tool + payload 5 kg" in err


# ----------------------------------------------------------------------------------------------- issue 22, section 4
def test_semicolon_csv_reads_the_same_as_comma(good, tmp_path):
    text = good.read_text()
    p = tmp_path / "semi.csv"
    p.write_text(text.replace(",", ";"))
    a, b = load_log(good), load_log(p)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.tau_J, b.tau_J)


def test_csv_named_file_holding_an_npz_is_read_as_npz(good, tmp_path):
    a = load_log(good)
    p = tmp_path / "run.csv"
    with open(p, "wb") as fh:
        np.savez(fh, time=a.time, q=a.q, dq=a.dq, tau_J=a.tau_J)
    b = load_log(p)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.time, b.time)


def test_duplicate_aliases_with_equal_values_are_one_column(good, tmp_path):
    p = tmp_path / "run.csv"
    rows = _rows()
    _write_csv(p, COLS + ["q_0"], [r + [r[1]] for r in rows])
    np.testing.assert_array_equal(load_log(p).q[:, 0], [r[1] for r in rows])


def test_nested_model_file_is_a_one_line_error(tmp_path):
    p = tmp_path / "model.json"
    p.write_text('{"friction": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(ValueError, match="model file .*model.json: JSON nested too deeply"):
        ModelConfig.load(p)


@pytest.mark.parametrize("argv,match", [
    (["--rate", "1e9"], "rate 1e+09 Hz is above 10000 Hz"),
    (["--cutoff", "1e-6"], "cutoff 1e-06 Hz is below 0.1 Hz"),
])
def test_compare_extreme_cleaning_options(argv, match, good, tmp_path, capsys):
    p = _copy_log(good, tmp_path)
    run_cli_error(capsys, ["compare", str(p), "--quiet", "--no-replay"] + argv, tmp_path, match)


def test_evaluate_negative_seed(tmp_path, capsys):
    run_cli_error(capsys, ["evaluate", "zero", "--seed", "-3", "--episodes", "1"], tmp_path, "--seed must be >= 0")


@pytest.mark.parametrize("kwargs,match", [
    (dict(duration=1e9), "duration must be in"),
    (dict(magnitude=1e6), "magnitude must be in"),
    (dict(magnitude=float("nan")), "magnitude must be in"),
    (dict(noise_scale=-1.0), "noise_scale must be a finite number >= 0"),
    (dict(noise_scale=float("inf")), "noise_scale must be a finite number >= 0"),
    (dict(seed=-1), "seed must be an integer >= 0"),
    (dict(seed=1.5), "seed must be an integer >= 0"),
])
def test_hidden_effect_generator_ranges(kwargs, match):
    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    with pytest.raises(ValueError, match=match):
        make_hidden_effect_log("payload", **kwargs)


def test_mass_matrix_of_a_list_equals_that_of_an_array():
    m = FrankaModel()
    q = [0.1, -0.6, 0.2, -2.2, 0.1, 1.6, 0.7]
    np.testing.assert_array_equal(m.mass_matrix(q), m.mass_matrix(np.array(q)))
    np.testing.assert_array_equal(m.gravity(q), m.gravity(np.array(q)))
    np.testing.assert_array_equal(m.inverse_dynamics(q, [0] * 7, [0] * 7),
                                  m.inverse_dynamics(np.array(q), np.zeros(7), np.zeros(7)))
    with pytest.raises(UserError, match="q must be 7 joint values, got shape \\(2,\\)"):
        m.mass_matrix([1.0, 2.0])


@pytest.mark.parametrize("value", [float("nan"), -0.1, float("inf")])
def test_torque_noise_must_be_finite_and_not_negative(value):
    from franka_vs_gym.sim.robot import FrankaSim

    with pytest.raises(ValueError, match="torque_noise must be a finite number >= 0 Nm"):
        FrankaSim(camera=False, table=False, torque_noise=value)


def test_experiment_negative_torque_noise_is_one_line(tmp_path, capsys):
    run_cli_error(capsys, ["experiment", "tracking", "--duration", "0.5", "--out", str(tmp_path), "--no-video",
                           "--quiet", "--torque-noise", "-1"], tmp_path, "--torque-noise must be a finite number >= 0")


def test_disk_full_during_fit_keeps_the_old_model(good, tmp_path, capsys, monkeypatch):
    """ENOSPC while the calibrated model is written: one line, exit 2, the old model file byte-identical."""
    import errno

    from franka_vs_gym.model.config import ModelConfig as MC

    p = _copy_log(good, tmp_path)
    out = tmp_path / "cal.json"
    out.write_text("old model")

    def full(self, path, overwrite=False):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(MC, "save", full)
    line = run_cli_error(capsys, ["fit", str(p), "--add", "torque_offset", "-o", str(out), "--force", "--quiet"],
                         tmp_path, "No space left on device while writing the outputs; nothing was replaced")
    assert out.read_text() == "old model" and "Traceback" not in line


def test_readers_never_see_a_log_missing_while_it_is_saved_again(good, tmp_path):
    """One thread saves the same log path over and over (overwrite=True); the path must exist at every read."""
    import threading

    log = load_log(good)
    p = tmp_path / "run.csv"
    save_log(log, p)
    stop = threading.Event()
    errors: list[BaseException] = []

    def writer():
        try:
            while not stop.is_set():
                save_log(log, p, overwrite=True)
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    th = threading.Thread(target=writer)
    th.start()
    missing = 0
    try:
        deadline = time.monotonic() + 3.0
        reads = 0
        while time.monotonic() < deadline:
            missing += not os.path.exists(p)
            missing += not os.path.exists(str(p) + ".json")
            reads += 1
    finally:
        stop.set()
        th.join()
    assert not errors, errors
    assert reads > 100 and missing == 0, (missing, reads)
