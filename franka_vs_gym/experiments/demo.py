"""``franka-vs demo [torque|ibvs|pbvs]``: the main job.

- ``torque`` (default): a short computed-torque motion (eq. (2) of the FrankaSim paper) of the simulated FER through
  a few joint-space waypoints; writes plots of joint positions and torques, a rendered image, a short video and
  ``metrics.json`` under ``runs/demo-torque-<time>/``.
- ``ibvs`` / ``pbvs``: visual servoing of the wrist camera onto an AprilTag with rendering and detection in the loop
  (see :mod:`franka_vs_gym.experiments.servo`).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from franka_vs_gym.experiments.common import make_run_dir, progress, write_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("kind", nargs="?", default="torque", choices=["torque", "ibvs", "pbvs"],
                   help="which demo (default: torque)")
    p.add_argument("--out", default=None, help="output folder (default: runs/demo-<kind>-<time>)")
    p.add_argument("--seed", type=int, default=0, help="random seed (servo demos: initial pose)")
    p.add_argument("--duration", type=float, default=None, help="simulated duration, s")
    p.add_argument("--no-video", action="store_true", help="skip the video")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--robot", default=None, help="the simulated arm: fer (default) or fr3")
    try:
        from franka_vs_gym.experiments import servo
    except ImportError:  # the servo demo's own options are added when its module is available
        return
    servo.add_arguments(p)


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.model.description import robot_description

    try:
        args.robot = robot_description(args.robot)
    except ValueError as e:
        from franka_vs_gym.errors import UserError

        raise UserError(f"--robot: {e}") from None
    if args.kind in ("ibvs", "pbvs"):
        from franka_vs_gym.experiments import servo

        return servo.main(args, args.kind)
    return run_torque_demo(args)


def quintic(q0: np.ndarray, q1: np.ndarray, T: float, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest-to-rest quintic from q0 to q1 in T seconds: (q, dq, ddq) at time t."""
    s = min(max(t / T, 0.0), 1.0)
    p = 10 * s**3 - 15 * s**4 + 6 * s**5
    dp = (30 * s**2 - 60 * s**3 + 30 * s**4) / T
    ddp = (60 * s - 180 * s**2 + 120 * s**3) / T**2
    d = q1 - q0
    return q0 + d * p, d * dp, d * ddp


def run_torque_demo(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from franka_vs_gym.control import ComputedTorque
    from franka_vs_gym.errors import UserError
    from franka_vs_gym.sim import FORCE_TORQUE, JOINT_STATE, FrankaSim
    from franka_vs_gym.sim.reflexes import position_profile_time

    duration = 3.0 if args.duration is None else float(args.duration)
    if not (duration > 0 and math.isfinite(duration)):
        raise ValueError(f"--duration must be > 0 s, got {duration}")
    out = make_run_dir("demo-torque", args.out)  # (an unfinished run folder is removed or renamed by the CLI)
    sim = FrankaSim(camera=False, robot=getattr(args, "robot", None))
    ctrl = ComputedTorque(sim.model)
    q_start = sim.model.robot.neutral()
    waypoints = [q_start,
                 q_start + np.array([0.5, 0.3, -0.3, 0.4, 0.4, -0.3, 0.6]),
                 q_start + np.array([-0.4, -0.2, 0.3, -0.3, -0.4, 0.3, -0.5]),
                 q_start]
    seg = duration / (len(waypoints) - 1)
    # the FER's reflexes stop a faster motion: refuse a duration whose quintic segments need more than 90 % of
    # the joint velocity, acceleration or jerk limits
    lim = sim.model.robot.limit_arrays()
    seg_min = max(position_profile_time(b - a, 0.9 * lim["dq_max"], 0.9 * lim["ddq_max"], 0.9 * lim["dddq_max"])
                  for a, b in zip(waypoints[:-1], waypoints[1:], strict=True))
    if seg < seg_min:
        raise UserError(f"--duration {duration:g} s is too fast for the FER: the demo trajectory would exceed its "
                        f"joint velocity/acceleration limits; use --duration >= {seg_min * (len(waypoints) - 1):.2f}")
    n = int(round(duration / sim.dt))
    fps, frames, video_every = 25, [], int(round(1 / 25 / sim.dt))
    log = {k: np.zeros((n, 7)) for k in ("q", "q_d", "tau", "tau_J")}
    t_log = np.zeros(n)
    sim.set_robot_state(FORCE_TORQUE)
    wall = time.perf_counter()
    with progress(n, "torque demo", disable=args.quiet) as bar:
        for k in range(n):
            t = sim.time
            i = min(int(t // seg), len(waypoints) - 2)
            q_d, dq_d, ddq_d = quintic(waypoints[i], waypoints[i + 1], seg, t - i * seg)
            q, dq = sim.get_position(), sim.get_velocity()
            tau = ctrl(t, q, dq, q_d, dq_d, ddq_d)
            sim.set_force_torque(JOINT_STATE, tau)
            sim.step()
            t_log[k], log["q"][k], log["q_d"][k], log["tau"][k] = t, q, q_d, tau
            log["tau_J"][k] = sim.get_force_torque()
            if not args.no_video and k % video_every == 0:
                frames.append(sim.world.render("overview", 480, 360))
            bar.update()
    wall = time.perf_counter() - wall
    err = log["q_d"] - log["q"]
    rmse = np.sqrt(np.mean(err[int(0.5 / sim.dt):] ** 2, axis=0))  # after the smooth start
    fig, axes = plt.subplots(7, 2, figsize=(11, 13), sharex=True)
    for j in range(7):
        axes[j, 0].plot(t_log, log["q_d"][:, j], "k--", lw=1, label="desired")
        axes[j, 0].plot(t_log, log["q"][:, j], lw=1.2, label="simulated")
        axes[j, 0].set_ylabel(f"q[{j}] (rad)")
        axes[j, 1].plot(t_log, log["tau"][:, j], lw=1, label="command (gravity-free)")
        axes[j, 1].plot(t_log, log["tau_J"][:, j], lw=1, label="measured tau_J")
        axes[j, 1].set_ylabel(f"tau[{j}] (Nm)")
    axes[0, 0].legend(fontsize=8)
    axes[0, 1].legend(fontsize=8)
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 1].set_xlabel("time (s)")
    fig.suptitle(f"Computed-torque motion of the simulated {sim.model.robot.name.upper()} (eq. 2, 1 kHz)")
    fig.tight_layout()
    fig.savefig(out / "joints_and_torques.png", dpi=90)
    plt.close(fig)
    image = sim.world.render("overview", 640, 480)
    import imageio.v2 as imageio

    imageio.imwrite(out / "final_view.png", image)
    if frames:
        imageio.mimsave(out / "motion.mp4", frames, fps=fps, macro_block_size=8)
    metrics = {"duration_s": duration, "control_rate_hz": 1 / sim.dt, "rmse_q_rad": rmse,
               "max_abs_error_rad": np.abs(err).max(axis=0), "wall_time_s": wall,
               "real_time_factor": duration / wall}
    write_json(out / "metrics.json", metrics)
    print(f"demo torque: RMSE per joint (rad) {np.array2string(rmse, precision=5)}; outputs in {out}",
          file=sys.stderr)
    print(out)
    return 0
