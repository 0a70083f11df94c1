"""The workbench on logs from a generator other than its own: the core plant's effects (FrankaSim's command
delay, joint armature, an undeclared payload), torque read straight after each step (no time alignment), the
sim's own scalar torque noise, and a plain multi-sine trajectory."""

from __future__ import annotations

import numpy as np
import pytest

from franka_vs_gym.control.computed_torque import ComputedTorque
from franka_vs_gym.model import params
from franka_vs_gym.model.config import ModelConfig, RigidBody
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.sim.robot import FORCE_TORQUE, JOINT_STATE, FrankaSim
from franka_vs_gym.validation.compare import compare
from franka_vs_gym.validation.diagnose import diagnose
from franka_vs_gym.validation.fitting import fit_effects
from franka_vs_gym.validation.logs import MeasurementLog
from franka_vs_gym.validation.signals import clean


def _foreign_log(plant: ModelConfig, payload: RigidBody | None = None, seed: int = 0,
                 duration: float = 10.0) -> MeasurementLog:
    rng = np.random.default_rng(seed)
    qc = params.as_array(params.Q_NEUTRAL)
    amp = rng.uniform(0.2, 0.35, 7)
    freq = rng.uniform(0.15, 0.45, 7) * 2 * np.pi  # rad/s
    phase = rng.uniform(0, 2 * np.pi, 7)

    def traj(t):
        s, c = np.sin(freq * t + phase), np.cos(freq * t + phase)
        return qc + amp * s, amp * freq * c, -amp * freq ** 2 * s

    sim = FrankaSim(model=plant, camera=False, table=False, undeclared_payload=payload, torque_noise=0.15,
                    seed=seed)
    q0, dq0, _ = traj(0.0)
    sim.reset(q0, dq0)
    sim.set_robot_state(FORCE_TORQUE)
    ctrl = ComputedTorque(FrankaModel(ModelConfig()))
    n = int(duration * 1000)
    t = np.arange(n) * 1e-3
    rows = {k: np.empty((n, 7)) for k in ("q", "dq", "tau", "cmd", "qd", "dqd", "ddqd")}
    for k in range(n):
        q, dq = sim.get_position(), sim.get_velocity()
        qd, dqd, ddqd = traj(t[k])
        cmd = ctrl(t[k], q, dq, qd, dqd, ddqd)
        sim.set_force_torque(JOINT_STATE, cmd)
        sim.step()
        for key, v in zip(("q", "dq", "cmd", "qd", "dqd", "ddqd"), (q, dq, cmd, qd, dqd, ddqd), strict=True):
            rows[key][k] = v
        rows["tau"][k] = sim.get_force_torque()
    return MeasurementLog(t, rows["q"], rows["dq"], rows["tau"], tau_J_d=rows["cmd"], q_d=rows["qd"],
                          dq_d=rows["dqd"], ddq_d=rows["ddqd"], tool="franka_hand",
                          # what its plant had, as franka-vs serve's recordings state it: FrankaSim's default ideal
                          # torque source, no motors between command and link (the torque replay needs to know)
                          controller={"rotor_inertia_kgm2": [0.0] * 7})


def test_foreign_no_effect_is_none():
    d = diagnose(_foreign_log(ModelConfig(), seed=1))
    assert d.verdict == "none", [(c.effect, round(c.score, 1)) for c in d.ranking[:3]]


def test_foreign_command_delay_is_found_on_the_command_channel():
    data = clean(_foreign_log(ModelConfig(delay=0.015), seed=2))
    d = diagnose(data)
    assert d.verdict == "delay"
    top = d.ranking[0]
    assert top.params["channel"] == "command"
    assert top.params["delay_s"] == pytest.approx(0.015, rel=0.15)
    f = fit_effects(data, ["delay"])
    assert f.after.delay == pytest.approx(0.015, rel=0.15)
    assert f.after.delay_channel == "command"
    # the plant built from the calibrated file delays its commands: the controller replay gets closer
    before, after = compare(data, None), compare(data, f.after)
    assert after.replay.rmse_tau.sum() < before.replay.rmse_tau.sum()


@pytest.mark.parametrize("effect", ["armature", "payload"])
def test_foreign_plant_effects(effect):
    if effect == "armature":
        log = _foreign_log(ModelConfig(armature=np.full(7, 0.2)), seed=3)
    else:
        log = _foreign_log(ModelConfig(), payload=RigidBody(1.2, [0.0, 0.01, 0.06], np.eye(3) * 1e-3), seed=4)
    data = clean(log)
    d = diagnose(data, select=False)
    assert d.verdict == effect, [(c.effect, round(c.score, 1)) for c in d.ranking[:3]]
    f = fit_effects(data, [effect])
    assert np.all(f.rmse_after <= 1.2 * f.noise_floor)
