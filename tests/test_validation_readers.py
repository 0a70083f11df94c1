"""Logs from other tools and labs: ROS 2 bags (sqlite3 and MCAP) written with rosbags' own writer, libfranka's
logToCSV, a 30 Hz log with jitter, stale rows and short gaps; the tool assumption stated; a user's effect plug-in."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from franka_vs_gym.validation.diagnose import diagnose
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.loading import load_log
from franka_vs_gym.validation.logs import MeasurementLog
from franka_vs_gym.validation.readers import joint_index
from franka_vs_gym.validation.signals import clean

EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "my_effects.py"


@pytest.fixture(scope="module")
def source_log():
    log, _ = make_hidden_effect_log("none", 41, duration=8.0)
    return log


def _ros_rate(log: MeasurementLog, rate: float, seed: int = 0, stale: int = 10, gaps: int = 3):
    """Downsample to about ``rate`` Hz with jittered stamps, stale (repeated) rows and a few dropped samples."""
    rng = np.random.default_rng(seed)
    step = int(round(1000 / rate))
    idx = np.arange(0, log.n, step)
    drop = rng.choice(np.arange(5, len(idx) - 5), size=gaps, replace=False)
    idx = np.delete(idx, drop)
    t = log.time[idx] + rng.normal(0, 0.08 / rate, len(idx))
    t = np.maximum.accumulate(t)
    q, dq, tau = log.q[idx].copy(), log.dq[idx].copy(), log.tau_J[idx].copy()
    for k in rng.choice(np.arange(1, len(idx)), size=stale, replace=False):
        q[k], dq[k], tau[k] = q[k - 1], dq[k - 1], tau[k - 1]
    return t, q, dq, tau


def _write_bag(path: Path, t, q, dq, tau, storage: str, prefix: str = "fer_joint", topic: str = "/joint_states",
               extra_topic: bool = False) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    JointState = ts.types["sensor_msgs/msg/JointState"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    # names in a shuffled order plus the gripper's fingers: the reader must map by name
    names = [f"{prefix}{i}" for i in (3, 1, 2, 7, 5, 4, 6)] + ["fer_finger_joint1", "fer_finger_joint2"]
    order = [int(n[-1]) - 1 for n in names[:7]]
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conn = w.add_connection(topic, JointState.__msgtype__, typestore=ts)
        other = w.add_connection("/other_states", JointState.__msgtype__, typestore=ts) if extra_topic else None
        for k in range(len(t)):
            sec = int(t[k] + 100)
            ns = int(round((t[k] + 100 - sec) * 1e9))
            msg = JointState(Header(Time(sec, ns), "base"), names,
                             np.r_[q[k][order], 0.04, 0.04], np.r_[dq[k][order], 0.0, 0.0],
                             np.r_[tau[k][order], 0.0, 0.0])
            raw = ts.serialize_cdr(msg, JointState.__msgtype__)
            w.write(conn, int((t[k] + 100) * 1e9), raw)
            if other is not None:
                w.write(other, int((t[k] + 100) * 1e9), raw)


def test_joint_names_map_to_fer_joints():
    assert [joint_index(n) for n in ("fer_joint1", "panda_joint7", "fr3_joint4", "joint_2", "joint3")] == \
        [0, 6, 3, 1, 2]
    assert joint_index("fer_finger_joint1") is None and joint_index("wheel") is None


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros2_bag_at_30hz_reads_cleans_and_diagnoses(source_log, tmp_path, storage):
    t, q, dq, tau = _ros_rate(source_log, 30.0, seed=1)
    bag = tmp_path / f"run_{storage}"
    _write_bag(bag, t, q, dq, tau, storage, prefix="panda_joint" if storage == "mcap" else "fer_joint")
    log = load_log(bag)
    assert log.n == len(t) and not log.tool_declared
    keep = np.ones(len(t), bool)
    np.testing.assert_allclose(log.q[keep], q[keep], atol=1e-12)
    np.testing.assert_allclose(log.tau_J, tau, atol=1e-12)
    data = clean(log)
    # processed at the log's own rate; the 3 dropped samples (67 ms gaps) are bridged, not rejected
    assert data.settings.rate == pytest.approx(30.0)
    assert data.report.gaps_bridged >= 3 and data.report.stale_rows >= 9
    warnings = " ".join(data.report.warnings)
    assert "30 Hz" in warnings and "inertial effects" in warnings
    d = diagnose(data)
    js = json.loads(json.dumps(d.to_dict()))
    assert js["verdict"] == "none" and js["explained"] is True
    a = js["assumptions"]
    assert a["tool"] == "franka_hand" and "not declared" in a["tool_source"]
    assert a["log_rate_hz"] == pytest.approx(30.0, rel=0.05) and a["cleaning"]["stale_rows_dropped"] >= 9
    assert a["robot"] == "fer"


def test_ros2_bag_topic_choice_and_errors(source_log, tmp_path):
    t, q, dq, tau = _ros_rate(source_log, 100.0, seed=2)
    bag = tmp_path / "two_topics"
    _write_bag(bag, t, q, dq, tau, "sqlite3", topic="/franka/joint_states", extra_topic=True)
    with pytest.raises(ValueError, match="several JointState topics"):
        load_log(bag)
    assert load_log(bag, topic="/other_states").n == len(t)
    with pytest.raises(ValueError, match=r"no topic '/nope' in the bag; topics: \[/franka/joint_states"):
        load_log(bag, topic="/nope")
    # the CLI: --topic, and a clear one-line error for a gap longer than --max-gap
    cmd = [sys.executable, "-m", "franka_vs_gym.cli", "diagnose", str(bag), "--topic", "/franka/joint_states",
           "--json", "--quiet"]
    out = subprocess.run(cmd + ["--robot", "fr3"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    a = json.loads(out.stdout)["assumptions"]
    assert a["log_rate_hz"] == pytest.approx(100.0, rel=0.05) and a["robot"] == "fr3"
    out = subprocess.run(cmd + ["--max-gap", "0.015"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 2 and "max_gap" in out.stderr and "Traceback" not in out.stderr


def test_libfranka_logtocsv_format(source_log, tmp_path):
    n = 3000
    cols = (["time", "success_rate"] + [f"state.{f}[{i}]" for f in ("q", "q_d", "dq", "dq_d", "tau_J",
                                                                     "tau_ext_hat_filtered") for i in range(7)]
            + [f"cmd.{f}[{i}]" for f, k in (("q_d", 7), ("dq_d", 7), ("O_T_EE_d", 16), ("O_dP_EE_d", 6),
                                             ("tau_J_d", 7)) for i in range(k)])
    L = source_log
    rows = np.column_stack([L.time[:n] * 1000.0, np.ones(n), L.q[:n], L.q_d[:n], L.dq[:n], L.dq_d[:n],
                            L.tau_J[:n], np.zeros((n, 7)), L.q_d[:n], L.dq_d[:n], np.zeros((n, 22)),
                            L.tau_J_d[:n]])
    p = tmp_path / "franka_log.csv"
    with open(p, "w") as fh:
        fh.write(", ".join(cols) + "\n")
        np.savetxt(fh, rows, delimiter=",", fmt="%.10g")
    log = load_log(p)
    np.testing.assert_allclose(log.time, L.time[:n], atol=1e-9)  # milliseconds -> seconds
    np.testing.assert_allclose(log.tau_J_d, L.tau_J_d[:n], atol=1e-8)
    np.testing.assert_allclose(log.q, L.q[:n], atol=1e-9)


def test_tool_none_vs_declared_hand_is_stated_and_unknown_fits_it(tmp_path):
    """A log recorded without a tool: assuming the Hand is wrong (and said); --tool none is right; --tool unknown
    fits the missing tool's mass."""
    from franka_vs_gym.model.config import ModelConfig, Tool
    from franka_vs_gym.validation.compare import compare

    log, _ = make_hidden_effect_log("none", 42, duration=8.0)
    data = clean(log)
    hand = compare(data, do_replay=False)
    none = compare(data, ModelConfig(tool=Tool.none()), do_replay=False)
    assert np.all(hand.rmse_tau <= 1.05 * data.noise)  # the log was made with the Hand
    assert none.rmse_tau.max() > 3 * data.noise.max()
    d = diagnose(data, tool="unknown")
    assert d.selection and d.selection[0].effect == "payload"
    assert d.selection[0].params["mass_kg"] == pytest.approx(Tool.franka_hand().body.mass, rel=0.1)
    assert "unknown" in d.assumptions["tool_source"]
    assert np.all(d.rmse_tau_selected <= 1.05 * d.noise_floor)


def test_effect_plugin_from_a_user_file_is_ranked_with_the_library(tmp_path):
    from franka_vs_gym.validation.effects import REGISTRY, EffectRegistry, load_plugin
    from franka_vs_gym.validation.hidden import _draw

    reg = EffectRegistry()
    assert load_plugin(EXAMPLE, reg) == ["tool_mass_error"]
    with pytest.raises(ValueError, match="already registered"):
        load_plugin(EXAMPLE, reg)
    bad = tmp_path / "bad.py"
    bad.write_text("raise RuntimeError('boom')\n")
    with pytest.raises(ValueError, match="boom"):
        load_plugin(bad, reg)
    # a log whose Hand is 40-50% heavier than declared, made through the plug-in's own inject()
    names = load_plugin(EXAMPLE)  # into the library's registry, as --effects does
    try:
        plant, ans = _draw("tool_mass_error", 1.0, np.random.default_rng(3))
        assert plant.payload is not None and ans["tool_mass_error"]["mass_factor"] > 1.2
        log, answer = make_hidden_effect_log("tool_mass_error", 43, duration=8.0)
        d = diagnose(log)
        assert d.verdict == "tool_mass_error", [(c.effect, round(c.score, 1)) for c in d.ranking[:3]]
        got = d.selection[0].params["mass_factor"]
        assert got == pytest.approx(answer["params"]["mass_factor"], rel=0.05)
        assert d.explained
    finally:
        for n in names:
            REGISTRY.unregister(n)


def test_effects_from_an_installed_package_entry_point(monkeypatch):
    """An installed package declaring the entry-point group ``franka_vs_gym.effects`` gets its effect registered
    and ranked by diagnose (the group is read once per process)."""
    import importlib
    import importlib.metadata

    from franka_vs_gym.validation.effects import ENTRY_POINT_GROUP, REGISTRY, EffectRegistry, load_plugin

    dg = importlib.import_module("franka_vs_gym.validation.candidates")  # where diagnose finds its candidates
    reg_tmp = EffectRegistry()
    load_plugin(EXAMPLE, reg_tmp)
    cls = type(reg_tmp.get("tool_mass_error"))

    class FakeEntryPoint:
        name = "tool_mass_error"

        def load(self):
            return cls

    def fake_entry_points(group=None):
        return [FakeEntryPoint()] if group == ENTRY_POINT_GROUP else []

    monkeypatch.setattr(importlib.metadata, "entry_points", fake_entry_points)
    monkeypatch.setattr(dg, "_ENTRY_POINTS_LOADED", False)
    try:
        names = [e.name for e in dg.resolve_effects(None)]
        assert "tool_mass_error" in names and "payload" in names
    finally:
        if "tool_mass_error" in REGISTRY:
            REGISTRY.unregister("tool_mass_error")


def test_a_tool_heavier_than_the_real_one_is_corrected_not_misnamed():
    """The commonest real-log mistake: the model's tool is heavier than what the arm carries (here 1 kg too heavy;
    a log recorded without the Hand but compared with it is the same). The payload effect fits a negative mass,
    the corrected tool is physical, so it is selected (not a torque offset) and fit restores the real tool."""
    from franka_vs_gym.model.config import ModelConfig, RigidBody, Tool
    from franka_vs_gym.validation.fitting import fit_effects

    log, _ = make_hidden_effect_log("none", 5, duration=8.0)
    hand = Tool.franka_hand()
    heavy = Tool("custom", hand.flMe, RigidBody(hand.body.mass + 1.0, hand.body.com, hand.body.inertia))
    d = diagnose(log, ModelConfig(tool=heavy))
    assert d.selected == ["payload"] and d.explained, (d.selected, d.notes)
    assert d.selection[0].params["mass_kg"] == pytest.approx(-1.0, abs=0.05)
    f = fit_effects(log, ["payload"], ModelConfig(tool=heavy))
    assert f.after.tool.body.mass == pytest.approx(hand.body.mass, abs=0.05)
    np.testing.assert_allclose(f.after.tool.body.com, hand.body.com, atol=0.01)
    assert np.all(f.rmse_after <= 1.05 * f.noise_floor)
