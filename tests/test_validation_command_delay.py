"""The workbench's command-delay check (validation/effects/timing.py) on logs recorded by ``franka-vs serve --record``
from a real pylibfranka client, with the robot's effective armature on (as ``franka-vs serve`` runs by default).

On a robot with link-side torque sensors, ``tau_J - g(q) - tau_J_d`` is not zero without a delay: it holds the
motors' reflected inertia (``-I_r ddq``; RobotDescription.rotor_inertia, 0.195 / 0.074 kg m^2 here) and motor-side
friction. The check must remove those before it tests ``tau_J_d`` against ``tau_J`` for a lag: no delay named on
the log without one, the known command delay named, within its interval, on the log with one.
"""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

if importlib.util.find_spec("pylibfranka") is None:
    pytest.skip("pylibfranka is not installed (pip install -e '.[fci]')", allow_module_level=True)

from conftest import CLIENTS, log_context, record_served  # noqa: E402

from franka_vs_gym.model.description import FER  # noqa: E402
from franka_vs_gym.validation.diagnose import diagnose  # noqa: E402
from franka_vs_gym.validation.effects.base import MIN_DELAY, Context  # noqa: E402
from franka_vs_gym.validation.effects.inertial import Armature  # noqa: E402
from franka_vs_gym.validation.effects.timing import CommandDelay  # noqa: E402

DELAY = 0.004  # s: the known command delay of the second log (whole 1 ms steps in the plant)
SECONDS = "6"  # of the client's PD sine motion (libfranka's joint-impedance law, K 600..50, D 50..5)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Two recordings of the same client: the plant without and with a command delay (``--truth``)."""
    out = {}
    for name, truth in (("none", None), ("delayed", [{"effect": "delay", "delay_s": DELAY, "channel": "command"}])):
        d = tmp_path_factory.mktemp(name)
        tp = None
        if truth is not None:
            tp = d / "truth.json"
            tp.write_text(json.dumps(truth))
        log = d / "session.npz"
        srv = record_served(CLIENTS / "record_pylibfranka.py", [str(d), SECONDS], log, 44, timeout=600, truth=tp)
        assert srv.sim.rotor_inertia.max() > 0  # the motors are in the plant
        out[name] = log
    return out


def _command_delay(ctx: Context) -> float:
    """The command-channel delay fitted on the whole log, s (reported or not)."""
    return float(CommandDelay().fit(ctx, ctx.cmd_residual, np.arange(ctx.n)).theta["coef"][0])


def test_motor_term_is_not_taken_for_a_delay(logs):
    """Without a delay: the log does carry the motor term (the effective armature read from it independently, by
    Armature.effective's regression of tau_J_d + g - tau_J on ddq, is the robot's 0.195 / 0.074 kg m^2; a delay fit
    on the raw difference takes it for a command delay of several ms), yet diagnose names no delay and the
    command-channel fit is below the 1.5 ms the check reports."""
    ctx = log_context(logs["none"])
    armature = np.array(Armature.effective(ctx)["effective_armature_kgm2"])
    assert np.allclose(armature, FER.rotor_inertia, rtol=0.05), armature
    # what the check did before: the delay fitted on the raw difference, the motor term still in it
    raw = ctx.data.tau - ctx.ev.gravity - ctx.data.optional["tau_J_d"]
    raw = raw - raw.mean(axis=0)
    x = -ctx.dcmd
    naive = float(np.sum(x * raw) / np.sum(x * x))
    assert naive > MIN_DELAY, naive  # the motor term looks like a delay of several ms
    d0 = _command_delay(ctx)
    assert abs(d0) < MIN_DELAY, d0
    d = diagnose(str(logs["none"]), effects=["delay"])
    assert not any(s.effect == "delay" for s in d.selection), [(s.effect, s.channel, s.params) for s in d.selection]
    assert d.verdict == "none"


def test_known_command_delay_is_named_within_its_interval(logs):
    """With a 4 ms command delay: diagnose names the delay on the command channel, and its 95 % interval contains
    the plant's delay: the 4 ms added plus the sub-step alignment the same plant shows without a delay (the command
    held over a 1 ms physics step, the torque read at its end: +0.2 ms on this log, measured on the first log)."""
    d0 = _command_delay(log_context(logs["none"]))
    d = diagnose(str(logs["delayed"]), effects=["delay"])
    s = next((s for s in d.selection if s.effect == "delay"), None)
    assert s is not None and s.channel == "command", [(c.effect, c.ok, c.params) for c in d.ranking]
    lo, hi = s.params_ci95["delay_s"]
    assert lo < DELAY + d0 < hi, (lo, hi, d0)
    assert abs(s.params["delay_s"] - d0 - DELAY) < 2e-4, (s.params, d0)
    assert hi - lo < 1e-3
