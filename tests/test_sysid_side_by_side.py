"""The closed-loop case of scripts/sysid_side_by_side.py: the replay with mujoco.sysid lines up with the log, and
both fits recover the hidden damping and armature of a joint-impedance closed loop."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sysid = pytest.importorskip("mujoco.sysid")
if not hasattr(sysid, "TimeSeries"):  # the module imports without its extras, and is then empty
    pytest.skip("mujoco.sysid needs its extras: pip install -e '.[sysid]'", allow_module_level=True)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import sysid_side_by_side as side  # noqa: E402


def test_replay_reproduces_a_noise_free_closed_loop_log_exactly():
    """mujoco.sysid's rollout of the impedance loop, with the true parameters, started from the first measured
    state, gives the logged joint positions to round-off (the rollout's state rows are the state after each step,
    stamped one step later: aligned with the log); without the hidden parameters it is far off."""
    log, truth = side.closed_loop_log(0, duration=3.0, noise=0.0)
    idx = np.arange(len(log.time))
    assert side.replay_rmse(log, idx, truth["damping"], truth["armature"]) < 1e-10
    assert side.replay_rmse(log, idx, np.zeros(7), np.zeros(7)) > 1e-4


def test_closed_loop_fits_recover_the_hidden_damping_and_armature():
    row = side.closed_loop_case(0, duration=6.0)
    base, wb, sy = row["torque"]
    assert wb < 0.9 * base and sy < 0.9 * base  # both explain the torque on the held-out quarter
    rb, rw, rs = row["replay"]
    assert rs < 0.05 * rb and rw < 0.05 * rb  # and the replayed motion
    assert row["err_s"] < 0.05 and row["err_w"] < 0.1  # median relative error of the 14 numbers
    assert row["cover_w"][0] >= 12, row["cover_w"]  # the workbench's HAC intervals hold the truth
