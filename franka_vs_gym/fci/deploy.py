"""Play a torque policy built in simulation on a Franka robot through pylibfranka: FrankaTorqueTracking-v0's
episodes on the robot (``franka-vs serve`` or a real one).

What the policy sees and does is what it saw and did in the environment:

- its observation is built from the robot's ``RobotState``: ``q``, ``dq`` (measured), the episode's desired
  trajectory ``q_desired``, ``dq_desired``, ``ddq_desired`` at the episode time, and ``time``, as float32, every
  ``control_period`` (10 ms: the env's default);
- its action (a gravity-free torque, Nm, or a normalized action times ``action_scale``) is held between two
  observations, as the env holds it, and sent at the robot's 1 kHz through libfranka's torque rate limiter
  (``limitRate``, 1000 Nm/s: what the env's ``limit_rate=True`` and libfranka's callback control apply; pylibfranka's
  ``start_torque_control`` does not apply it itself);
- "gravity-free" keeps its meaning: in simulation the robot compensates the gravity of the model the policy was
  built on (``model``: the default, a calibrated or any model file); on the robot the runner adds, every 1 ms cycle,
  that model's gravity minus what the robot compensates itself (libfranka's ``Model.gravity(state)``: the robot's
  own model and the load it was told with ``setLoad``). The runner tells the robot no load: the payload a model
  file carries is compensated through this term, so the same run works with any model and the robot's own
  settings stay as the user left them.

An episode is FrankaTorqueTracking-v0's episode of a seed (``reset(seed)``: the start posture q0, the amplitudes
and frequencies): the robot first moves to q0 with a smooth joint position motion (its internal joint impedance
controller), then the torque episode runs for ``duration`` s with the reference ``q_d(t) = q_s + A (1 - cos w t)``
started at the measured posture q_s where the move left the arm (within a few mrad of q0). The tracking error is
FrankaTorqueTracking-v0's ``rms_error``: the RMS over the episode's control steps of ``||q - q_d||`` (rad).

    python -m franka_vs_gym.fci.deploy HOST --policy computed_torque --model calibrated.json --seeds 0,1,2

prints one JSON object (per episode: seed, rms and max error, success, failure). ``play_tracking`` is the same
from Python. Needs pylibfranka (``pip install -e '.[fci]'``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Any

import numpy as np

from franka_vs_gym.errors import UserError

#: The controllers ``--policy`` names (franka_vs_gym.policies), in Nm (physical actions)
CONTROLLERS = ("computed_torque", "joint_impedance")
MOVE_SPEED = 0.4  # rad/s: the peak joint speed of the move to an episode's start
#: tries of an episode whose robot state stopped arriving (libfranka's UDP timeout on a starved machine): the runner
#: reconnects and plays the episode again from its start; the count is in the result (``network_retries``)
NETWORK_ATTEMPTS = 3


def tracking_episode(seed: int, robot: str = "fer", **env_kwargs: Any) -> dict[str, np.ndarray]:
    """FrankaTorqueTracking-v0's episode of ``seed``: ``q0``, ``A`` (rad) and ``w`` (rad/s), (7,) each."""
    import gymnasium as gym

    import franka_vs_gym  # noqa: F401  (registers the ids)

    env = gym.make("FrankaTorqueTracking-v0", robot=robot, **env_kwargs)
    try:
        env.reset(seed=int(seed))
        u = env.unwrapped
        return {"q0": u._q0.copy(), "A": u._A.copy(), "w": u._w.copy()}
    finally:
        env.close()


def make_policy(name: str, model: Any, robot: str = "fer") -> Any:
    """A scripted torque controller by name (``computed_torque``, ``joint_impedance``: their defaults, physical
    actions in Nm) on ``model``."""
    from franka_vs_gym.policies import ComputedTorquePolicy, JointImpedancePolicy

    if name == "computed_torque":
        return ComputedTorquePolicy(model, robot=robot)
    if name == "joint_impedance":
        return JointImpedancePolicy(model, robot=robot)
    raise UserError(f"--policy {name!r}: choose from {', '.join(CONTROLLERS)}")


def _move(robot: Any, pylibfranka: Any, q_goal: np.ndarray) -> None:
    """A smooth joint position motion (cosine profile, peak speed MOVE_SPEED) to q_goal through the robot's
    internal joint impedance controller, then a short rest."""
    control = robot.start_joint_position_control(pylibfranka.ControllerMode.JointImpedance)
    t, q_start, T = 0.0, None, 1.0
    while True:
        state, period = control.readOnce()
        if q_start is None:
            q_start = np.array(state.q_d)
            T = max(1.0, math.pi / 2 * float(np.max(np.abs(q_goal - q_start))) / MOVE_SPEED)
        t += period.to_sec()
        s = 0.5 * (1 - math.cos(math.pi * min(t / T, 1.0)))
        cmd = pylibfranka.JointPositions((q_start + s * (q_goal - q_start)).tolist())
        cmd.motion_finished = t >= T + 0.5
        control.writeOnce(cmd)
        if cmd.motion_finished:
            return


def play_tracking(host: str, policy: Any, episodes: list[dict[str, np.ndarray]], *, model: Any = None,
                  robot: str = "fer", action_scale: Any = None, control_period: float = 0.01,
                  duration: float = 5.0, success_threshold: float = 0.02, progress: Any = None) -> list[dict]:
    """Run ``episodes`` (:func:`tracking_episode`'s dicts) on the robot at ``host`` with ``policy`` (an object with
    ``predict(obs) -> (action, state)`` and optionally ``reset()``), built on ``model`` (a model file, ModelConfig,
    FrankaModel or None: the robot's default). ``action_scale`` (7,) Nm per action unit, or None: actions in Nm.
    Returns one dict per episode: ``seed``, ``rms_error``, ``max_error`` (rad), ``success`` (rms below
    ``success_threshold``, as the env), ``failure`` (a reflex's message or None), ``steps``, ``seconds`` (wall)."""
    import pylibfranka

    from franka_vs_gym.policies.torque import _as_model

    fm = _as_model(model, robot)
    lim = fm.limits()["tau_max"]
    dtau_max = fm.limits()["dtau_max"]
    scale = None if action_scale is None else np.asarray(action_scale, dtype=np.float64)
    n_hold = int(round(control_period / 0.001))
    if n_hold < 1 or abs(n_hold * 0.001 - control_period) > 1e-9:
        raise UserError(f"control_period must be a whole number of 1 ms cycles, got {control_period}")
    n_steps = int(round(duration / control_period))
    connection: list[Any] = []

    def connect() -> None:
        connection[:] = []  # (the old connection closes first)
        rob = pylibfranka.Robot(host, pylibfranka.RealtimeConfig.kIgnore)
        connection[:] = [rob, rob.load_model()]

    connect()
    out = []
    for k, ep in enumerate(episodes):
        for attempt in range(NETWORK_ATTEMPTS):
            try:
                out.append(_episode(pylibfranka, *connection, policy, ep, fm, lim, dtau_max, scale, n_hold,
                                    n_steps, success_threshold))
                out[-1]["network_retries"] = attempt
                break
            except pylibfranka.NetworkException:  # the robot's state did not arrive in time: not the policy's doing
                if attempt == NETWORK_ATTEMPTS - 1:
                    raise
                time.sleep(1.0)
                connect()
        if progress is not None:
            progress(k, out[-1])
    return out


def _episode(pylibfranka: Any, rob: Any, rmodel: Any, policy: Any, ep: dict, fm: Any, lim: np.ndarray,
             dtau_max: np.ndarray, scale: np.ndarray | None, n_hold: int, n_steps: int,
             success_threshold: float) -> dict[str, Any]:
    """One episode of :func:`play_tracking` on the connected robot."""
    from franka_vs_gym.sim.rate_limit import limit_torque_rate

    t_wall = time.perf_counter()
    _move(rob, pylibfranka, np.asarray(ep["q0"], dtype=np.float64))
    if hasattr(policy, "reset"):
        policy.reset()
    A, w = np.asarray(ep["A"], dtype=np.float64), np.asarray(ep["w"], dtype=np.float64)
    errors: list[float] = []
    failure = None
    q_s = None
    tau_hold = np.zeros(7)
    control = rob.start_torque_control()
    cycle = 0
    try:
        while True:
            state, _ = control.readOnce()
            q, dq = np.array(state.q), np.array(state.dq)
            if q_s is None:
                q_s = q.copy()
                last = np.array(state.tau_J_d)  # (the rate limiter starts from the robot's last command)
            t = cycle * 0.001
            if cycle % n_hold == 0:
                c, s = np.cos(w * t), np.sin(w * t)
                q_d = q_s + A * (1 - c)
                if cycle > 0:
                    errors.append(float(np.linalg.norm(q - q_d)))
                obs = {"q": q.astype(np.float32), "dq": dq.astype(np.float32),
                       "q_desired": q_d.astype(np.float32), "dq_desired": (A * w * s).astype(np.float32),
                       "ddq_desired": (A * w * w * c).astype(np.float32),
                       "time": np.array([t], dtype=np.float32)}
                a = np.asarray(policy.predict(obs)[0], dtype=np.float64)
                tau_hold = a if scale is None else a * scale
            # the policy's gravity-free torque on top of its model's gravity, less what the robot compensates
            tau = tau_hold + fm.gravity(q) - np.array(rmodel.gravity(state))
            last = limit_torque_rate(np.clip(tau, -lim, lim), last, dtau_max)
            cmd = pylibfranka.Torques(last.tolist())
            cmd.motion_finished = cycle >= n_steps * n_hold
            control.writeOnce(cmd)
            cycle += 1
            if cmd.motion_finished:
                break
    except pylibfranka.ControlException as e:
        failure = str(e).splitlines()[0][:300]
    finally:
        del control  # (its end releases the robot for the next motion)
    if failure is not None:
        rob.automatic_error_recovery()
    e = np.asarray(errors) if errors else np.array([np.inf])
    rms = float(np.sqrt(np.mean(e ** 2)))
    return {"seed": ep.get("seed"), "rms_error": rms, "max_error": float(e.max()),
                "success": failure is None and len(errors) == n_steps and rms < success_threshold,
                "failure": failure, "steps": len(errors), "seconds": round(time.perf_counter() - t_wall, 2),
                "errors": [round(x, 7) for x in errors]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("host", help="the robot's address (a real robot or franka-vs serve)")
    ap.add_argument("--policy", default="computed_torque",
                    help=f"a controller ({', '.join(CONTROLLERS)}) or a shipped agent's name (load_agent)")
    ap.add_argument("--model", default=None, metavar="FILE",
                    help="the model the policy was built on (a calibrated model file; default the robot's; an agent: "
                         "the plant model of its training, from its sidecar)")
    ap.add_argument("--robot", default="fer", help="the arm: fer (default) or fr3")
    ap.add_argument("--seeds", default="0", help="FrankaTorqueTracking-v0 episode seeds, comma-separated")
    ap.add_argument("--duration", type=float, default=5.0, help="seconds per episode (default 5, the env's)")
    args = ap.parse_args(argv)
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--seeds must be integers separated by commas, got {args.seeds!r}")
    if not seeds:
        ap.error("--seeds: at least one seed")
    if not (math.isfinite(args.duration) and 0 < args.duration <= 60):
        ap.error(f"--duration must be in (0, 60] s, got {args.duration}")
    try:
        scale = None  # (the controllers and AgentPolicy give physical actions, Nm)
        if args.policy in CONTROLLERS:
            policy = make_policy(args.policy, args.model, args.robot)
        else:
            from franka_vs_gym.policies import load_agent

            policy = load_agent(args.policy)  # (physical actions out)
            if getattr(policy, "env_id", None) != "FrankaTorqueTracking-v0":
                raise UserError(f"--policy {args.policy}: an agent of {getattr(policy, 'env_id', '?')}; the runner "
                                "plays FrankaTorqueTracking-v0 torque agents")
            if getattr(policy, "robot", args.robot) != args.robot:
                raise UserError(f"--policy {args.policy}: an agent of the {policy.robot}, played with --robot "
                                f"{args.robot}")
            if hasattr(policy, "base"):  # a residual torque agent: its base is built on the model it was trained
                if args.model is None:  # on, which is also the model whose gravity the runner adds
                    args.model = policy.env_kwargs.get("model")
                elif args.model != policy.env_kwargs.get("model"):
                    raise UserError(f"--model {args.model}: the agent {args.policy} was trained on the plant model "
                                    f"{policy.env_kwargs.get('model')}; play it with that model (or no --model)")
        eps = [dict(tracking_episode(s, args.robot), seed=s) for s in seeds]
        res = play_tracking(args.host, policy, eps, model=args.model, robot=args.robot, action_scale=scale,
                            duration=args.duration,
                            progress=lambda k, r: print(f"episode {k + 1}/{len(eps)}: rms {r['rms_error']:.5f} rad"
                                                        + (f", {r['failure']}" if r["failure"] else ""),
                                                        file=sys.stderr, flush=True))
    except (UserError, ValueError, FileNotFoundError) as e:
        print(f"franka_vs_gym.fci.deploy: {e}", file=sys.stderr)
        return 2
    except Exception as e:  # libfranka's own (no robot at the address, a network failure): one line
        if type(e).__module__.startswith("pylibfranka"):
            print(f"franka_vs_gym.fci.deploy: {args.host}: {str(e).splitlines()[0]}", file=sys.stderr)
            return 1
        raise
    print(json.dumps({"policy": args.policy, "model": args.model, "robot": args.robot, "episodes": res}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
