"""Robot states of the real FCI clients: recorded with StateRecorder inside pylibfranka / franky control loops
against `franka-vs serve`, dumped the ways users save them, and read back by the workbench; malformed dumps give
one-line errors."""

from __future__ import annotations

import importlib.util
import json
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import record_with_client

from franka_vs_gym.validation import compare, load_log
from franka_vs_gym.validation.robot_states import StateRecorder

# below the smallest noise floor of a real FER's torque sensors (Gaz et al. 2019 log: 0.027 Nm on joint 6); the
# simulated robot behind the FCI server has no sensor noise, so the residual is the model-plant mismatch alone
FLOOR = 0.02


def _at_floor(res) -> bool:
    """Residual = the log's own noise (its estimated floor; franky's controller adds some) plus a model-plant mismatch
    below a real sensor's floor."""
    return bool((res.rmse_tau <= np.hypot(res.noise_floor, FLOOR)).all())






def _check_same(logs: dict[str, object], ref: str) -> None:
    L = logs[ref]
    for name, log in logs.items():
        assert log.n == L.n, name
        np.testing.assert_allclose(log.time, L.time, atol=2e-9, err_msg=name)
        for f in ("q", "dq", "tau_J"):
            np.testing.assert_allclose(getattr(log, f), getattr(L, f), atol=1e-8, err_msg=f"{name} {f}")


@pytest.mark.skipif(importlib.util.find_spec("pylibfranka") is None, reason="pylibfranka is not installed")
def test_pylibfranka_states_recorded_and_dumped_are_read_and_at_the_floor(tmp_path):
    out = record_with_client("record_pylibfranka.py", tmp_path, 31)
    assert out["n"] == out["ticks"] == 4002 and out["dropped"] == 0
    side = json.loads((tmp_path / "recorded.csv.json").read_text())
    assert side["tool"] == "franka_hand" and "m_total" in side["tool_source"]  # the robot's own declaration
    logs = {f: load_log(tmp_path / f) for f in ("recorded.csv", "states.jsonl", "flat.csv", "cells.csv", "states.npy")}
    _check_same(logs, "recorded.csv")
    assert logs["recorded.csv"].fields() == ["q", "dq", "tau_J", "tau_J_d", "q_d", "dq_d", "ddq_d",
                                             "tau_ext_hat_filtered"]
    assert logs["states.jsonl"].tool == "franka_hand" and logs["states.jsonl"].tool_declared  # from m_total etc.
    assert not logs["cells.csv"].tool_declared
    for name in ("states.jsonl", "flat.csv", "cells.csv", "states.npy"):
        assert "in seconds (detected" in logs[name].extra["read_as"], name
    np.testing.assert_allclose(logs["flat.csv"].tau_J_d, logs["recorded.csv"].tau_J_d, atol=1e-8)
    res = compare(logs["states.jsonl"])
    assert _at_floor(res), res.rmse_tau
    assert "JSON lines" in res.assumptions()["log_read_as"]
    # the command line reads the dump directly and states how
    r = subprocess.run([sys.executable, "-m", "franka_vs_gym.cli", "compare", str(tmp_path / "cells.csv"), "--json",
                        "--quiet"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert (np.array(d["rmse_tau"]) <= np.hypot(d["noise_floor"], FLOOR)).all()
    assert "CSV: time from 'time' in seconds" in d["assumptions"]["log_read_as"]


@pytest.mark.skipif(importlib.util.find_spec("franky") is None, reason="franky is not installed")
def test_franky_states_recorded_and_dumped_are_read_and_at_the_floor(tmp_path):
    out = record_with_client("record_franky.py", tmp_path, 32)
    assert out["n"] == out["ticks"] == 4200 and out["dropped"] == 0
    logs = {f: load_log(tmp_path / f) for f in ("recorded.npz", "states.json", "stacked.npz", "states.pkl")}
    _check_same(logs, "recorded.npz")
    for name in ("states.json", "stacked.npz"):  # franky's Duration.to_msec(): milliseconds, detected and stated
        assert "in milliseconds (detected from its median step 1)" in logs[name].extra["read_as"], name
    assert "robot_time" in logs["states.json"].extra["read_as"]
    assert "pickle of franky RobotState" in logs["states.pkl"].extra["read_as"]
    assert logs["states.pkl"].tool == "franka_hand" and logs["states.pkl"].tool_declared
    for name in ("recorded.npz", "states.pkl"):
        res = compare(logs[name])
        assert _at_floor(res), (name, res.rmse_tau, res.noise_floor)
    if importlib.util.find_spec("pylibfranka") is not None:
        # a process that has imported pylibfranka cannot import franky's types (both bind libfranka's): the pickle
        # is then read in a fresh process, with the same result
        code = ("import sys, json, pylibfranka; from franka_vs_gym.validation.loading import load_log; "
                "log = load_log(sys.argv[1]); print(json.dumps([log.n, float(abs(log.q).sum()), log.tool]))")
        run = subprocess.run([sys.executable, "-c", code, str(tmp_path / "states.pkl")], capture_output=True,
                             text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        n, qsum, tool = json.loads(run.stdout)
        ref = logs["states.pkl"]
        assert n == ref.n and abs(qsum - float(np.abs(ref.q).sum())) < 1e-9 * qsum and tool == ref.tool


def _states(n: int = 400, t0: float = 12.5):
    """Duck-typed robot states (time as a Duration in ms, as franky gives it)."""
    rng = np.random.default_rng(0)
    t = t0 + 0.001 * np.arange(n)
    q = np.array([0, -0.78, 0, -2.36, 0, 1.57, 0.78]) + 0.1 * np.sin(np.outer(t, np.arange(1, 8)))
    dq = 0.1 * np.arange(1, 8) * np.cos(np.outer(t, np.arange(1, 8)))
    tau = rng.normal(size=(n, 7))
    return [SimpleNamespace(time=SimpleNamespace(to_msec=lambda v=v: v * 1000.0), q=q[i], dq=dq[i], tau_J=tau[i],
                            m_total=0.0, F_x_Ctotal=np.zeros(3), I_total=np.zeros(9), O_ddP_O=np.array([0, 0, -9.81]))
            for i, v in enumerate(t)]


def test_recorder_preallocates_counts_overflow_and_never_overwrites(tmp_path):
    states = _states(400)
    rec = StateRecorder(seconds=0.3)
    bufs = [id(b) for b in rec._buf.values()]
    t = time.perf_counter()
    for s in states:
        rec(s, "time_step", "rel_time", "abs_time", "signal")  # franky's callback arguments
    per_tick = (time.perf_counter() - t) / len(states)
    assert per_tick < 2e-4  # well within a 1 ms control cycle (measured about 6 us)
    assert rec.n == 300 and rec.dropped == 100 and [id(b) for b in rec._buf.values()] == bufs
    log = rec.log()
    assert log.tool is None and log.tool_declared  # m_total = 0: the robot declared no tool
    np.testing.assert_allclose(log.time, 0.001 * np.arange(300), atol=1e-9)
    np.testing.assert_array_equal(log.q, np.array([s.q for s in states[:300]]))
    assert "100 ticks" in log.extra["warning"] and log.fields() == ["q", "dq", "tau_J"]
    p = rec.save(tmp_path / "run.csv")
    before = p.read_bytes()
    with pytest.raises(FileExistsError):
        rec.save(tmp_path / "run.csv")
    assert p.read_bytes() == before
    back = load_log(p)
    assert back.tool is None and back.extra["ticks_dropped"] == 100
    with pytest.raises(ValueError, match="not a robot state"):
        StateRecorder(1)(SimpleNamespace(time=0.0, q=np.zeros(7)))


def _jsonl(path: Path, ticks: list[dict]) -> Path:
    path.write_text("".join(json.dumps(t) + "\n" for t in ticks))
    return path


def _ticks(n: int = 50, step: float = 1.0):
    t = 1000.0 + step * np.arange(n)
    return [{"time": float(v), "q": [0.1 * i for i in range(7)], "dq": [0.0] * 7, "tau_J": [1.0] * 7} for v in t]


def test_dump_formats_and_their_errors_are_one_line(tmp_path):
    ok = load_log(_jsonl(tmp_path / "ok.jsonl", _ticks()))
    assert ok.n == 50 and ok.duration == pytest.approx(0.049) and "milliseconds" in ok.extra["read_as"]
    nested = [{"robot_state": t, "command": {"tau": [0.0] * 7}} for t in _ticks()]
    (tmp_path / "nested.json").write_text(json.dumps({"states": nested}))
    assert load_log(tmp_path / "nested.json").n == 50
    cols = {"time_s": list(0.001 * np.arange(50)), "q": [t["q"] for t in _ticks()], "dq": [[0.0] * 7] * 50,
            "tau_J": [[1.0] * 7] * 50}
    (tmp_path / "cols.json").write_text(json.dumps(cols))
    assert "from its name" in load_log(tmp_path / "cols.json").extra["read_as"]
    # CSV flattened 1-based (q1..q7), dot-indexed, with a pandas index and a text column
    hdr = ["", "time"] + [f"q{i + 1}" for i in range(7)] + [f"dq.{i}" for i in range(7)] + \
          [f"tau_J{i + 1}" for i in range(7)] + ["robot_mode"]
    rows = [[str(k), f"{0.001 * k:.3f}"] + [f"{0.1 * i + 0.001 * k}" for i in range(7)] + ["0"] * 7 + ["1"] * 7 +
            ["Move"] for k in range(50)]
    (tmp_path / "flat.csv").write_text("\n".join(",".join(r) for r in [hdr] + rows) + "\n")
    log = load_log(tmp_path / "flat.csv")
    assert log.q[3, 6] == pytest.approx(0.603) and "numbered 1..7" in log.extra["read_as"]

    def err(name: str, content, match: str):
        p = tmp_path / name
        if isinstance(content, bytes):
            p.write_bytes(content)
        elif isinstance(content, list):
            _jsonl(p, content)
        else:
            p.write_text(content)
        with pytest.raises(ValueError, match=match) as e:
            load_log(p)
        assert "\n" not in str(e.value), str(e.value)
        return str(e.value)

    bad = _ticks()
    for t in bad:
        del t["tau_J"]
    msg = err("no_tau.jsonl", bad, r"no measured joint torques 'tau_J'")
    assert "found [dq, q, time]" in msg
    bad = _ticks()
    for t in bad:
        t["q"] = t["q"][:6]
    err("six.jsonl", bad, r"'q' has 6 values per sample; the FER has 7 joints")
    bad = _ticks()
    del bad[3]["dq"]
    err("gap.jsonl", bad, r"robot state 3 has no 'dq'")
    bad = [{k: v for k, v in t.items() if k != "time"} for t in _ticks()]
    err("notime.jsonl", bad, r"no time field \(looked for 'time' or 'robot_time', in s or ms\)")
    err("unit.jsonl", _ticks(step=1000.0), r"cannot tell the unit of 'time' \(median step 1000\)")
    slow = load_log(_jsonl(tmp_path / "slow.jsonl", _ticks(step=0.2)))  # 5 Hz in seconds (in ms: 5 kHz)
    assert slow.duration == pytest.approx(9.8) and "in seconds (detected from its median step 0.2)" in \
        slow.extra["read_as"]
    err("cell.csv", "time,q,dq,tau_J\n0,\"[1, 2, 3, 4, 5, 6, 7]\",\"[0 0 0 0 0 0 0]\",abc\n",
        r"line 2: column 'tau_J' holds 'abc'")
    err("torn.jsonl", '{"time": 1, "q": [0]}\n{"time": 2, \n', r"line 2 is not a JSON object")
    buf = __import__("io").BytesIO()
    np.save(buf, np.array([{"q": 1}], dtype=object), allow_pickle=True)
    err("objects.npy", buf.getvalue(), r"holds Python objects")
    err("plain.npy", _npy(np.zeros((10, 22))), r"has no field names")
    err("run.csv.json", json.dumps({"tool": None, "gravity": [0, 0, -9.81], "controller": None}),
        r"metadata sidecar .* not a log")
    # a pickle that would run a command is refused without running it
    marker = tmp_path / "ran"
    evil = pickle.dumps(_Evil(str(marker)))
    err("evil.pkl", evil, r"posix.system|os.system|which is not part of a robot state")
    assert not marker.exists()


def _npy(a: np.ndarray) -> bytes:
    buf = __import__("io").BytesIO()
    np.save(buf, a)
    return buf.getvalue()


class _Evil:
    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (os.system, (f"touch {self.path}",))
