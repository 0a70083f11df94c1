"""The workbench identifies the effective armature (the motors' inertia felt through the torque loop) from a log
with the commanded torque tau_J_d, and says it cannot from tau_J alone."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from franka_vs_gym.model import ModelConfig
from franka_vs_gym.model.description import FER
from franka_vs_gym.validation.effects import Armature, NotApplicable
from franka_vs_gym.validation.effects.base import Context
from franka_vs_gym.validation.signals import clean


@pytest.fixture(scope="module")
def log():
    """5 s of computed-torque tracking of an exciting trajectory on the FER with its motors (FrankaSim
    rotor_inertia=True), logged as libfranka would: q, dq, tau_J and the commanded tau_J_d."""
    from franka_vs_gym.control.computed_torque import ComputedTorque
    from franka_vs_gym.model import FrankaModel
    from franka_vs_gym.sim import FORCE_TORQUE, JOINT_STATE, FrankaSim
    from franka_vs_gym.validation.hidden import fourier_trajectory
    from franka_vs_gym.validation.logs import MeasurementLog

    rng = np.random.default_rng(1)
    traj = fourier_trajectory(rng, 5.0)
    sim = FrankaSim(camera=False, table=False, rotor_inertia=True)
    q0, dq0, _ = traj(0.0)
    sim.reset(q0, dq0)
    sim.set_robot_state(FORCE_TORQUE)
    ctrl = ComputedTorque(FrankaModel(ModelConfig(armature=np.array(FER.rotor_inertia))), mu=4.0)
    n = 5000
    t = np.arange(n) * sim.dt
    q, dq, tau, cmd = (np.empty((n, 7)) for _ in range(4))
    for k in range(n):
        q[k], dq[k] = sim.get_position(), sim.get_velocity()
        cmd[k] = ctrl(float(t[k]), q[k], dq[k], *traj(t[k]))
        sim.set_force_torque(JOINT_STATE, cmd[k])
        sim.step()
        tau[k] = sim.get_force_torque()
    return MeasurementLog(t, q, dq, tau, tau_J_d=cmd, tool="franka_hand")


def test_effective_armature_from_the_commanded_torque(log):
    """The simulated FER carries FER.rotor_inertia between command and link: the fit recovers it per joint."""
    out = Armature.effective(Context(clean(log), ModelConfig()))
    np.testing.assert_allclose(out["effective_armature_kgm2"], FER.rotor_inertia, rtol=0.1)
    assert min(out["explained"]) > 0.8


def test_tau_J_only_log_is_refused_with_the_reason(log):
    bare = replace(log, tau_J_d=None)
    with pytest.raises(NotApplicable, match="tau_J_d"):
        Armature.effective(Context(clean(bare), ModelConfig()))
