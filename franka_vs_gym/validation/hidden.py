"""Measurement logs with a hidden physical effect, generated in the MuJoCo plant.

The plant (``FrankaSim``) is built from the default FER model plus ONE hidden effect the log does not declare; the
computed-torque controller of eq. (2), using the default model (what the experimenter believes), tracks an exciting
trajectory (a finite Fourier series per joint, as in Gaz et al. 2019); the log records what the robot measures,
with realistic sensor noise. The workbench, run with the default model, must find the hidden effect.

Effects and their size at ``magnitude = 1`` (each value scaled per joint by a seeded factor in [0.7, 1.3]):

=====================  ================================================================================
``viscous_friction``   extra viscous friction [0.5, 0.5, 0.4, 0.4, 0.15, 0.15, 0.08] Nm s/rad
``coulomb_friction``   extra Coulomb friction [0.8, 0.8, 0.6, 0.6, 0.25, 0.25, 0.15] Nm, v_c 0.05 rad/s
``sigmoid_friction``   Gaz sigmoid heights x (1 + 0.8 m), widths phi2 x [0.6, 1.4]
``torque_offset``      torque-sensor bias of random sign, [0.6, 0.6, 0.5, 0.5, 0.2, 0.2, 0.1] Nm
``armature``           rotor inertia [0.25, 0.25, 0.2, 0.2, 0.06, 0.06, 0.03] kg m^2
``payload``            undeclared 0.8 m kg body, centre of mass 3-10 cm beyond the flange
``gravity_tilt``       base tilted by 4 m degrees about a random horizontal axis
``delay``              measured torque lagging the motion by 10 m ms
``stribeck_friction``  Stribeck hump [0.8, 0.8, 0.6, 0.6, 0.25, 0.25, 0.15] Nm, v_s 0.1 rad/s, v_c 0.05 rad/s
                       (not in the random draw; ``link_inertials`` neither)
``none``               nothing hidden
=====================  ================================================================================

Sensor noise: white, torque [0.25, 0.25, 0.2, 0.2, 0.08, 0.08, 0.05] Nm (the Gaz data show 0.26-0.35 Nm on joints
1-4), velocity 2e-3 rad/s, position 1e-5 rad; the controller sees the noisy measurements.

Time alignment: the plant's torque at step k produces the acceleration over [t_k, t_k + dt]; the logged tau_J[k] is
the mean of the torques of steps k-1 and k, so that q, dq and tau_J of a row describe the same instant t_k (to second
order), as a real robot's state does.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.description import FER
from franka_vs_gym.validation.logs import MeasurementLog

TORQUE_NOISE = np.array([0.25, 0.25, 0.2, 0.2, 0.08, 0.08, 0.05])
DQ_NOISE = 2e-3
Q_NOISE = 1e-5


def _effects() -> tuple[str, ...]:
    from franka_vs_gym.validation.effects import REGISTRY

    return tuple(REGISTRY.injectable())


EFFECTS = _effects()  # every registered effect that can inject itself into a plant (read from the registry)


def injecting_effects() -> tuple[str, ...]:
    """Every registered effect that can inject itself: EFFECTS (the random draw) plus those kept out of the draw
    so that existing seeds keep drawing the same effects (``injectable`` False, e.g. ``stribeck_friction``)."""
    from franka_vs_gym.validation.effects import REGISTRY, Effect

    return tuple(n for n in REGISTRY if type(REGISTRY.get(n)).inject is not Effect.inject)


def fourier_trajectory(rng: np.random.Generator, duration: float, f0: float = 0.1, harmonics: int = 5,
                       v_peak: float = 0.9):
    """A random exciting trajectory: per joint ``q = q_c + sum_l a_l sin(2 pi f0 l t) + b_l cos(...)`` within the
    joint limits (0.15 rad margin) with peak speed about v_peak rad/s. Returns a function t -> (q, dq, ddq) (7,)."""
    lim = FER.limit_arrays()
    q_min, q_max = lim["q_min"] + 0.15, lim["q_max"] - 0.15
    qn = FER.neutral()
    qc = np.clip(qn + rng.uniform(-0.3, 0.3, 7), q_min + 0.3, q_max - 0.3)
    w = 2 * math.pi * f0 * np.arange(1, harmonics + 1)  # (L,)
    a = rng.normal(0, 1, (7, harmonics)) / np.arange(1, harmonics + 1)
    b = rng.normal(0, 1, (7, harmonics)) / np.arange(1, harmonics + 1)
    # scale: peak velocity bound sum |c_l| w_l = v_peak, and amplitude bound within the limits
    vbound = (np.abs(a) + np.abs(b)) @ w
    abound = (np.abs(a) + np.abs(b)).sum(axis=1)
    room = np.minimum(qc - q_min, q_max - qc)
    s = np.minimum(v_peak / vbound, room / abound)
    a *= s[:, None]
    b *= s[:, None]

    def traj(t: float):
        sn, cs = np.sin(w * t), np.cos(w * t)
        q = qc + a @ sn + b @ cs
        dq = a @ (w * cs) - b @ (w * sn)
        ddq = -(a @ (w ** 2 * sn) + b @ (w ** 2 * cs))
        return q, dq, ddq

    return traj


def _draw(effect: str, magnitude: float, rng: np.random.Generator):
    """Plant change and answer parameters for ``effect`` (one registered effect, or several joined by '+')."""
    from franka_vs_gym.validation.effects import REGISTRY, Effect, PlantChange

    plant = PlantChange(ModelConfig())
    rng.uniform(0.7, 1.3, 7)  # keeps the trajectories and noise of each seed as in earlier versions
    ans: dict[str, Any] = {}
    if effect == "none":
        return plant, ans
    for name in effect.split("+"):
        if name not in REGISTRY or type(REGISTRY.get(name)).inject is Effect.inject:
            raise ValueError(f"unknown effect {name!r}: choose from {', '.join(injecting_effects())}, none or random")
        e = REGISTRY.get(name)
        ans[e.name] = e.inject(plant, rng, magnitude)
    return plant, ans


MAX_DURATION = 3600.0  # s: the longest generated log (an hour at 1 kHz is 3.6 M samples)
MAX_MAGNITUDE = 10.0  # the largest effect size, in multiples of its typical size


def _number(v: Any, name: str) -> float:
    if isinstance(v, bool):
        raise ValueError(f"{name} must be a number, got {v!r}")
    try:
        return float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {v!r}") from None


def check_arguments(duration: Any, magnitude: Any, noise_scale: Any, seed: Any) -> None:
    """Raise ValueError (one line) for arguments :func:`make_hidden_effect_log` cannot use: a duration outside (2,
    MAX_DURATION] s, a magnitude outside (0, MAX_MAGNITUDE], NaN or inf anywhere, a negative noise scale or seed."""
    duration, magnitude, noise_scale = (_number(duration, "duration"), _number(magnitude, "magnitude"),
                                        _number(noise_scale, "noise_scale"))
    if not 2.0 < duration <= MAX_DURATION:  # NaN fails every comparison: refused here too
        raise ValueError(f"duration must be in (2, {MAX_DURATION:g}] s, got {duration}")
    if not 0 < magnitude <= MAX_MAGNITUDE:
        raise ValueError(f"magnitude must be in (0, {MAX_MAGNITUDE:g}] (1: the effect's typical size), got {magnitude}")
    if not (math.isfinite(noise_scale) and noise_scale >= 0):
        raise ValueError(f"noise_scale must be a finite number >= 0 (1: the FER's torque noise), got {noise_scale}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")


def make_hidden_effect_log(effect: str, seed: int = 0, *, duration: float = 20.0, magnitude: float = 1.0,
                           noise_scale: float = 1.0) -> tuple[MeasurementLog, dict[str, Any]]:
    """Simulate the FER with one hidden effect (or "none", or "random": effect and magnitude drawn from the seed,
    or several effects joined by "+", whose answer parameters are then keyed by effect). Each effect injects itself
    into the plant through its class (:meth:`Effect.inject`).

    Returns the log (1 kHz; declared tool the Franka Hand, declared gravity vertical, controller eq. (2) with its
    gains and model) and the answer ``{"effect", "magnitude", "params", "seed"}``.
    """
    from franka_vs_gym.control.computed_torque import ComputedTorque
    from franka_vs_gym.model.franka_model import FrankaModel
    from franka_vs_gym.sim.robot import FORCE_TORQUE, JOINT_STATE, FrankaSim

    check_arguments(duration, magnitude, noise_scale, seed)
    duration, magnitude, noise_scale = float(duration), float(magnitude), float(noise_scale)
    rng = np.random.default_rng(seed)
    if effect == "random":
        effect = str(rng.choice(list(_effects()) + ["none"]))
        magnitude = float(rng.uniform(1.0, 2.0))
    plant, ans = _draw(effect, magnitude, rng)
    plant_cfg, payload, delay = plant.config, plant.payload, plant.measurement_delay
    if "+" not in effect and effect != "none":
        ans = ans[effect]
    traj = fourier_trajectory(rng, duration)
    sig_tau = TORQUE_NOISE * noise_scale * rng.uniform(0.8, 1.2, 7)
    sim = FrankaSim(model=plant_cfg, camera=False, table=False, undeclared_payload=payload)
    q0, dq0, _ = traj(0.0)
    sim.reset(q0, dq0)
    sim.set_robot_state(FORCE_TORQUE)
    believed = ModelConfig()
    ctrl = ComputedTorque(FrankaModel(believed), mu=4.0)
    dt = sim.dt
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    q = np.empty((n, 7))
    dq = np.empty((n, 7))
    tau = np.empty((n, 7))
    cmd = np.empty((n, 7))
    qd = np.empty((n, 7))
    dqd = np.empty((n, 7))
    ddqd = np.empty((n, 7))
    for k in range(n):
        q[k] = sim.get_position() + rng.normal(0, Q_NOISE * noise_scale, 7)
        dq[k] = sim.get_velocity() + rng.normal(0, DQ_NOISE * noise_scale, 7)
        qd[k], dqd[k], ddqd[k] = traj(t[k])
        cmd[k] = ctrl(float(t[k]), q[k], dq[k], qd[k], dqd[k], ddqd[k])
        sim.set_force_torque(JOINT_STATE, cmd[k])
        sim.step()
        tau[k] = sim.get_force_torque()
    tau_mid = tau.copy()
    tau_mid[1:] = 0.5 * (tau[1:] + tau[:-1])
    if delay > 0:  # the measured torque lags the motion
        tau_mid = np.column_stack([np.interp(t - delay, t, tau_mid[:, j]) for j in range(7)])
    tau_meas = tau_mid + rng.normal(0, 1, (n, 7)) * sig_tau
    controller = {"law": "computed_torque_eq2", "kp": ctrl.kp.tolist(), "kd": ctrl.kd.tolist(),
                  "ki": ctrl.ki.tolist(), "mu": ctrl.mu, "friction": True, "model": None}
    log = MeasurementLog(t, q, dq, tau_meas, tau_J_d=cmd, q_d=qd, dq_d=dqd, ddq_d=ddqd, tool="franka_hand",
                         controller=controller, extra={"generator": "franka_vs_gym.validation.hidden"})
    answer = {"effect": effect, "magnitude": magnitude, "params": ans, "seed": seed,
              "torque_noise_Nm": sig_tau.tolist()}
    return log, answer


__all__ = ["EFFECTS", "check_arguments", "fourier_trajectory", "injecting_effects", "make_hidden_effect_log"]
