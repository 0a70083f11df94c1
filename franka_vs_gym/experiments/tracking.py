"""Experiment IV-A of the FrankaSim paper, replicated: joint trajectory tracking with computed torque, eq. (2).

From q0 = [0, -pi/4, 0, -3pi/4, 0, pi/2, pi/4] (rad), joints 1, 3 and 4 (indices 0, 2, 3) follow sinusoids for 15 s
while the others hold q0; eq. (2) runs at 1 kHz with the ViSP Franka tutorial stiffness (Kp 400, 900 on joint 7),
Kd and Ki placed by :func:`pid_gains` (Kd 36.8 / 56.5 1/s, Ki 1075 / 2760 1/s^3) and the smooth start
mu = 4 1/s. The plant is :class:`~franka_vs_gym.sim.FrankaSim` with the published FER dynamics and friction;
the controller's model is either exact or deliberately wrong (``model_error``: no friction, or an unknown 1 kg
payload in the gripper), to show what each effect costs.

Outputs (:func:`write_tracking`): ``positions.png`` (desired vs simulated joint positions, Fig. 4 in form),
``torques.png`` (commanded and measured joint torques, Fig. 5 in form), ``errors.png``, ``metrics.json`` (RMSE per
joint, rad), a measurement log in the workbench format (``log.npz`` or ``log.csv`` + JSON sidecar, libfranka field
names) so a simulated run can be compared with a real one, and optionally ``video.mp4``.
"""

from __future__ import annotations

import json
import math
import sys
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.model.config import Friction, ModelConfig, RigidBody
from franka_vs_gym.model.description import GRAVITY
from franka_vs_gym.model.franka_model import FrankaModel

Q0 = np.array([0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4])
# Sinusoids on joints 1, 3, 4 (indices 0, 2, 3): amplitude (rad) and frequency (Hz).
AMPLITUDE = np.array([0.5, 0.0, 0.5, 0.4, 0.0, 0.0, 0.0])
FREQUENCY = np.array([0.2, 0.0, 0.25, 0.3, 0.0, 0.0, 0.0])
KP = np.array([400.0] * 6 + [900.0])
MU = 4.0


def pid_gains(kp: Any, integral_rate: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Kd and Ki (each (7,)) for a given Kp placing the closed-loop error poles at ``-a`` and a critically damped
    pair ``-w, -w``: ``(s + a)(s + w)^2 = s^3 + Kd s^2 + Kp s + Ki`` with ``w = sqrt(a^2 + Kp) - a``, so
    ``Kd = a + 2w`` and ``Ki = a w^2``. With a = 4 1/s (= mu) the integral forgets the start-up transient within a
    second or two instead of lingering as a slow pole (a small Ki with Kd = 2 sqrt(Kp) leaves one at -Ki/Kp).
    """
    kp = np.broadcast_to(np.asarray(kp, dtype=np.float64), (7,))
    a = float(integral_rate)
    if not (a >= 0 and math.isfinite(a)) or (kp < 0).any():
        raise ValueError(f"integral_rate and kp must be >= 0, got {a}, {kp}")
    w = np.sqrt(a * a + kp) - a
    return a + 2.0 * w, a * w * w


KD, KI = pid_gains(KP)
MODEL_ERRORS = ("none", "no-friction", "payload")
UNKNOWN_PAYLOAD = RigidBody(1.0, np.array([0.0, 0.0, 0.08]), np.diag([2e-3, 2e-3, 1e-3]))


def desired_trajectory(t: float, q0: np.ndarray = Q0, amplitude: np.ndarray = AMPLITUDE,
                       frequency: np.ndarray = FREQUENCY) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q_d = q0 + A sin(2 pi f t) per joint, with its first two derivatives: three (7,) arrays (rad, /s, /s^2)."""
    w = 2.0 * math.pi * frequency
    s, c = np.sin(w * t), np.cos(w * t)
    return q0 + amplitude * s, amplitude * w * c, -amplitude * w**2 * s


@dataclass
class TrackingResult:
    """Time series of one tracking run, sampled at every control tick (1 kHz).

    time (N,) s; q, dq, q_d, dq_d, ddq_d (N, 7) rad, rad/s, rad/s^2; tau_cmd (N, 7) Nm gravity-free command;
    tau_J (N, 7) Nm measured joint torque (gravity included); rmse (7,) rad over the whole run; rmse_steady (7,) rad
    after the first second (the smooth-start transient); settings: what was run.
    """

    time: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    q_d: np.ndarray
    dq_d: np.ndarray
    ddq_d: np.ndarray
    tau_cmd: np.ndarray
    tau_J: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def error(self) -> np.ndarray:
        """q_d - q, (N, 7) rad."""
        return self.q_d - self.q

    @property
    def rmse(self) -> np.ndarray:
        return np.sqrt(np.mean(self.error**2, axis=0))

    @property
    def rmse_steady(self) -> np.ndarray:
        sel = self.time >= self.time[0] + 1.0
        if not sel.any():
            return self.rmse
        return np.sqrt(np.mean(self.error[sel] ** 2, axis=0))

    def metrics(self) -> dict[str, Any]:
        e = self.error
        return {
            "experiment": "tracking (FrankaSim paper IV-A replica)",
            "duration_s": float(self.time[-1] - self.time[0] + (self.time[1] - self.time[0])),
            "rate_hz": float(round(1.0 / (self.time[1] - self.time[0]))),
            "rmse_rad": self.rmse.tolist(),
            "rmse_after_1s_rad": self.rmse_steady.tolist(),
            "max_abs_error_rad": np.max(np.abs(e), axis=0).tolist(),
            "rmse_deg": np.degrees(self.rmse).tolist(),
            "max_abs_torque_cmd_nm": np.max(np.abs(self.tau_cmd), axis=0).tolist(),
            "settings": self.settings,
        }


def plant_and_controller_configs(model_error: str = "none",
                                 plant: ModelConfig | None = None) -> tuple[ModelConfig, ModelConfig,
                                                                            RigidBody | None]:
    """(plant config, controller config, undeclared payload) for a model-error case.

    "none": the controller's model is the plant's. "no-friction": the controller ignores joint friction.
    "payload": the gripper holds a 1 kg object that neither the controller nor the robot's gravity compensation
    knows about (an undeclared payload in the plant).
    """
    if model_error not in MODEL_ERRORS:
        raise ValueError(f"model_error must be one of {MODEL_ERRORS}, got {model_error!r}")
    plant = ModelConfig() if plant is None else plant
    ctrl = plant.copy()
    undeclared = None
    if model_error == "no-friction":
        ctrl = plant.copy(friction=Friction.none())
    elif model_error == "payload":
        undeclared = UNKNOWN_PAYLOAD
    return plant, ctrl, undeclared


def run_tracking(duration: float = 15.0, *, model_error: str = "none", plant: ModelConfig | None = None,
                 kp: Any = KP, kd: Any = KD, ki: Any = KI, mu: float = MU, torque_noise: float = 0.0,
                 seed: int = 0, progress: bool = True, video: str | Path | None = None, video_fps: int = 25,
                 video_size: tuple[int, int] = (480, 360)) -> TrackingResult:
    """Run the tracking experiment and return its time series.

    duration in s (> 0); model_error one of MODEL_ERRORS; plant the true robot (default: published FER + hand);
    gains as :class:`~franka_vs_gym.control.ComputedTorque`; torque_noise (Nm) on the measured torques; video: an
    .mp4 path to record the overview camera, or None.
    """
    from franka_vs_gym.control.computed_torque import ComputedTorque
    from franka_vs_gym.sim.robot import FORCE_TORQUE, JOINT_STATE, FrankaSim

    if not (duration > 0 and math.isfinite(duration)):
        raise ValueError(f"duration must be a finite number > 0 s, got {duration}")
    plant_cfg, ctrl_cfg, undeclared = plant_and_controller_configs(model_error, plant)
    sim = FrankaSim(plant_cfg, camera=False, q0=Q0, undeclared_payload=undeclared, torque_noise=torque_noise,
                    seed=seed)
    ctrl = ComputedTorque(FrankaModel(ctrl_cfg), kp=kp, kd=kd, ki=ki, mu=mu)
    sim.set_robot_state(FORCE_TORQUE)
    n = int(round(duration / sim.dt))
    if n < 2:
        raise ValueError(f"duration {duration} s is shorter than two control ticks of {sim.dt} s")
    T = np.zeros(n)
    Q, DQ, QD, DQD, DDQD, TAU, TAUJ = (np.zeros((n, 7)) for _ in range(7))
    writer = _video_writer(video, video_fps) if video else None
    frame_every = max(1, int(round(1.0 / (video_fps * sim.dt))))
    t0 = sim.time
    ctrl_time = 0.0  # wall-clock seconds spent in the controller (to show it fits a 1 kHz loop)
    try:
        from tqdm import tqdm

        for k in tqdm(range(n), desc="tracking", unit="tick", file=sys.stderr, disable=not progress,
                      mininterval=0.5, unit_scale=True):
            t = sim.time - t0
            q, dq = sim.get_position(), sim.get_velocity()
            q_d, dq_d, ddq_d = desired_trajectory(t)
            c0 = _time.perf_counter()
            tau = ctrl(t, q, dq, q_d, dq_d, ddq_d)
            ctrl_time += _time.perf_counter() - c0
            sim.set_force_torque(JOINT_STATE, tau)
            T[k], Q[k], DQ[k], QD[k], DQD[k], DDQD[k], TAU[k] = t, q, dq, q_d, dq_d, ddq_d, tau
            if writer is not None and k % frame_every == 0:
                writer.append_data(sim.world.render("overview", *video_size))
            sim.step()
            # tau_J of this tick: the torque the joints applied during the step (gravity included)
            TAUJ[k] = sim.get_force_torque(JOINT_STATE)
    finally:
        if writer is not None:
            writer.close()
        sim.world.close()
    settings = {"controller_wall_time_us_per_tick": 1e6 * ctrl_time / n, "model_error": model_error,
                "kp": np.broadcast_to(kp, 7).tolist(),
                "kd": np.broadcast_to(kd, 7).tolist(), "ki": np.broadcast_to(ki, 7).tolist(), "mu": mu,
                "q0": Q0.tolist(), "amplitude_rad": AMPLITUDE.tolist(), "frequency_hz": FREQUENCY.tolist(),
                "torque_noise_nm": torque_noise, "seed": seed, "plant_friction": "Gaz et al. 2019 sigmoid",
                "unknown_payload_kg": UNKNOWN_PAYLOAD.mass if undeclared is not None else 0.0}
    return TrackingResult(T, Q, DQ, QD, DQD, DDQD, TAU, TAUJ, settings)


def _video_writer(path: str | Path, fps: int):
    import imageio.v2 as imageio

    p = Path(path)
    if p.exists():
        raise FileExistsError(f"{p} exists; not overwriting it")
    return imageio.get_writer(str(p), fps=fps, codec="libx264", quality=7, macro_block_size=8)


def to_measurement_log(result: TrackingResult):
    """The run as a :class:`~franka_vs_gym.validation.logs.MeasurementLog` (libfranka field names)."""
    from franka_vs_gym.validation.logs import MeasurementLog

    s = result.settings
    return MeasurementLog(
        time=result.time, q=result.q, dq=result.dq, tau_J=result.tau_J, tau_J_d=result.tau_cmd, q_d=result.q_d,
        dq_d=result.dq_d, ddq_d=result.ddq_d, tool="franka_hand", gravity=np.array(GRAVITY, dtype=np.float64),
        controller={"law": "computed_torque_eq2", "kp": s.get("kp"), "kd": s.get("kd"), "ki": s.get("ki"),
                    "mu": s.get("mu"), "model_error": s.get("model_error")},
        extra={"origin": "franka_vs_gym simulation (FrankaSim), experiment tracking",
               "unknown_payload_kg": s.get("unknown_payload_kg", 0.0)})


def plot_tracking(result: TrackingResult, folder: Path) -> list[Path]:
    """positions.png, torques.png and errors.png in folder; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result.time
    out = []
    fig, axes = plt.subplots(4, 2, figsize=(11, 10), sharex=True)
    for i, ax in enumerate(axes.flat[:7]):
        ax.plot(t, result.q_d[:, i], "k--", lw=1.2, label="desired")
        ax.plot(t, result.q[:, i], "C0", lw=1.0, label="simulated")
        ax.set_ylabel(f"q{i + 1} [rad]")
        ax.grid(alpha=0.3)
    axes.flat[0].legend(loc="upper right", fontsize=8)
    axes.flat[7].axis("off")
    axes.flat[7].text(0.02, 0.5, "RMSE [mrad]\n" + "\n".join(
        f"joint {i + 1}: {1e3 * r:.3f}" for i, r in enumerate(result.rmse)), family="monospace", va="center")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"Joint positions, desired vs simulated (model error: {result.settings.get('model_error')})")
    fig.tight_layout()
    out.append(folder / "positions.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(4, 2, figsize=(11, 10), sharex=True)
    for i, ax in enumerate(axes.flat[:7]):
        ax.plot(t, result.tau_J[:, i], "C1", lw=1.0, label="measured tau_J (with gravity)")
        ax.plot(t, result.tau_cmd[:, i], "C2", lw=1.0, label="command (gravity-free)")
        ax.set_ylabel(f"tau{i + 1} [Nm]")
        ax.grid(alpha=0.3)
    axes.flat[0].legend(loc="upper right", fontsize=8)
    axes.flat[7].axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle("Joint torques")
    fig.tight_layout()
    out.append(folder / "torques.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(9, 4))
    for i in range(7):
        ax.plot(t, 1e3 * result.error[:, i], lw=1.0, label=f"joint {i + 1}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("q_d - q [mrad]")
    ax.grid(alpha=0.3)
    ax.legend(ncol=4, fontsize=8)
    fig.tight_layout()
    out.append(folder / "errors.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)
    return out


def write_tracking(result: TrackingResult, folder: str | Path, log_format: str = "npz") -> dict[str, Path]:
    """Write plots, metrics.json and the measurement log into an existing folder; returns what was written."""
    from franka_vs_gym.validation.logs import save_log

    folder = Path(folder)
    if log_format not in ("npz", "csv"):
        raise ValueError(f"log_format must be 'npz' or 'csv', got {log_format!r}")
    written: dict[str, Path] = {}
    for p in plot_tracking(result, folder):
        written[p.stem] = p
    written["log"] = save_log(to_measurement_log(result), folder / f"log.{log_format}")
    metrics = folder / "metrics.json"
    if metrics.exists():
        raise FileExistsError(f"{metrics} exists; not overwriting it")
    metrics.write_text(json.dumps(result.metrics(), indent=2))
    written["metrics"] = metrics
    return written


__all__ = ["AMPLITUDE", "FREQUENCY", "KD", "KI", "KP", "MODEL_ERRORS", "MU", "Q0", "TrackingResult",
           "desired_trajectory", "pid_gains", "plant_and_controller_configs", "plot_tracking", "run_tracking",
           "to_measurement_log", "write_tracking"]
