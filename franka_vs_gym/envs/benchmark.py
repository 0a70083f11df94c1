"""Speed of the environments, measured as ratios within one run (``scripts/bench.py`` calls :func:`bench`).

For each environment (features observations; state for the torque-tracking task) we time environment steps of a
zero action (made with ``gymnasium.make``) and, in alternating blocks, the raw ``mujoco.mj_step`` calls those steps
contain (``n_substeps`` per step) on a copy of the same MuJoCo model state; the fastest block of each side is kept.
``ratio`` = env step / raw physics is the price of everything that is not MuJoCo's integrator: FrankaSim's
per-physics-step hooks (plant friction, torque delay), observations, reward, checks and Gymnasium's wrappers
(target <= 1.5). ``ratio_vs_robot_step`` compares with FrankaSim's own stepping (mj_step + hooks) instead.
``ratio_cpu`` is the same ratio in the thread's CPU time (``time.thread_time``) of the same blocks: time the process
spends descheduled while other processes run does not count, so on a loaded machine it is the steadier figure.
Resets (inverse kinematics of the start pose) are timed separately."""

from __future__ import annotations

import math
import time
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np


def _time_env(env_id: str, n_steps: int, seed: int, kwargs: dict[str, Any], block: int = 25) -> dict[str, Any]:
    """Env steps and raw physics timed in alternating blocks; the fastest block of each is kept, so load from
    other processes on the machine (which only ever slows a block down) affects both sides alike."""
    env = gym.make(env_id, **kwargs)
    u = env.unwrapped
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    env.reset(seed=seed)
    env.step(action)  # the first step runs Gymnasium's passive checker: leave it out of the timing
    m = u.world.model
    d_raw = mujoco.MjData(m)  # raw physics on a copy of the env's state, so the env's episode is not disturbed
    mujoco.mj_copyData(d_raw, m, u.world.data)
    n_sub = u.n_substeps
    mj_step = mujoco.mj_step
    best_env = best_raw = best_robot = best_env_cpu = best_raw_cpu = math.inf
    resets, reset_time, done_steps = 0, 0.0, 0
    clock, cpu = time.perf_counter, time.thread_time
    while done_steps < n_steps:
        t0, c0 = clock(), cpu()
        for _ in range(block):
            _, _, term, trunc, _ = env.step(action)
            if term or trunc:  # rare with a zero action: only the time limit; timed apart
                t1, c1 = clock(), cpu()
                env.reset()
                t2, c2 = clock(), cpu()
                reset_time += t2 - t1
                t0 += t2 - t1
                c0 += c2 - c1
                resets += 1
        best_env = min(best_env, (clock() - t0) / block)
        best_env_cpu = min(best_env_cpu, (cpu() - c0) / block)
        t0, c0 = clock(), cpu()
        for _ in range(block * n_sub):
            mj_step(m, d_raw)
        best_raw = min(best_raw, (clock() - t0) / block)
        best_raw_cpu = min(best_raw_cpu, (cpu() - c0) / block)
        mujoco.mj_copyData(d_raw, m, u.world.data)
        done_steps += block
    # FrankaSim's stepping (mj_step + the robot's per-physics-step friction/command hooks), on the env itself
    for _ in range(max(1, n_steps // block)):
        t0 = time.perf_counter()
        u.world.step(block * n_sub)
        best_robot = min(best_robot, (time.perf_counter() - t0) / block)
    env.close()
    us, raw_us, robot_us = best_env * 1e6, best_raw * 1e6, best_robot * 1e6
    return {
        "steps_per_s": 1.0 / best_env,
        "us_per_step": us,
        "substeps": n_sub,
        "control_period_s": u.control_period,
        "mj_step_us": raw_us / n_sub,
        "physics_us_per_step": raw_us,
        "robot_step_us_per_step": robot_us,
        "ratio": us / raw_us,
        "us_per_step_cpu": best_env_cpu * 1e6,
        "physics_us_per_step_cpu": best_raw_cpu * 1e6,
        "ratio_cpu": best_env_cpu / best_raw_cpu,
        "overhead_pct": 100.0 * (us / raw_us - 1.0),
        "ratio_vs_robot_step": us / robot_us,
        "reset_ms": 1e3 * reset_time / resets if resets else float("nan"),
    }


def bench(env_ids: list[str] | None = None, n_steps: int = 300, seed: int = 0, async_envs: int = 2,
          async_steps: int = 300, async_env_id: str = "FrankaIBVS-v0", verbose: bool = False) -> dict[str, Any]:
    """Environment steps/s next to the raw ``mj_step`` cost of the same steps, and AsyncVectorEnv throughput.

    Returns ``{"envs": {env_id: {"steps_per_s", "us_per_step", "substeps", "mj_step_us", "physics_us_per_step",
    "robot_step_us_per_step", "ratio", "overhead_pct", "reset_ms", ...}}, "async": {...}}``; ``ratio`` is the env
    step time over the raw physics time of its substeps (1.5 = 50 % overhead). ``"async"`` is
    :func:`bench_vector_modes` for Gymnasium's AsyncVectorEnv of ``async_envs`` envs (``async_envs=0`` skips it).
    """
    import franka_vs_gym  # noqa: F401
    from franka_vs_gym.envs.registration import ENVS

    if n_steps < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    ids = list(ENVS) if env_ids is None else list(env_ids)
    out: dict[str, Any] = {"envs": {}}
    for env_id in ids:
        if env_id not in ENVS:
            raise ValueError(f"unknown environment id {env_id!r} (have {list(ENVS)})")
        kwargs = {} if env_id == "FrankaTorqueTracking-v0" else {"observation_type": "features"}
        r = _time_env(env_id, n_steps, seed, kwargs)
        out["envs"][env_id] = r
        if verbose:
            print(f"{env_id:26s} {r['steps_per_s']:7.0f} steps/s  {r['us_per_step']:7.1f} us/step  "
                  f"{r['substeps']:3d} x mj_step = {r['physics_us_per_step']:7.1f} us (ratio {r['ratio']:.2f})  "
                  f"robot step {r['robot_step_us_per_step']:7.1f} us (ratio {r['ratio_vs_robot_step']:.2f})",
                  flush=True)
    if async_envs:
        a = bench_vector_modes(async_env_id, async_envs, async_steps, seed, modes=("async",))
        out["async"] = {"env_id": async_env_id, "n_envs": async_envs, "env_steps_per_s": a["async_steps_per_s"],
                        "vector_steps_per_s": a["async_steps_per_s"] / async_envs,
                        "single_steps_per_s": a["single_steps_per_s"], "ratio_to_single": a["async_ratio"]}
        if verbose:
            print(f"AsyncVectorEnv({async_envs}) {async_env_id}: {a['async_steps_per_s']:.0f} env steps/s "
                  f"({a['async_ratio']:.2f} x one plain env)", flush=True)
    return out


def _raw_us(env: Any, reps: int = 100) -> float:
    """Best-of-3 time (us) of the raw ``mj_step`` calls of one env step (its substeps, one call) on a copy of the
    env's state."""
    m = env.world.model
    d = mujoco.MjData(m)
    best = math.inf
    for _ in range(3):
        mujoco.mj_copyData(d, m, env.world.data)
        t0 = time.perf_counter()
        for _ in range(reps):
            mujoco.mj_step(m, d, env.n_substeps)
        best = min(best, (time.perf_counter() - t0) / reps)
    return best * 1e6


def bench_batched(env_id: str, num_envs: int, nthread: int, seconds: float = 1.0, seed: int = 0,
                  kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """Env steps per second of the batched vector env (``gymnasium.make_vec``) next to the raw-physics limit
    ``nthread / (raw mj_step time of one env step's substeps)``, timed in alternating blocks in one run.

    Returns ``{"env_id", "num_envs", "nthread", "env_steps_per_s", "raw_us_per_env_step", "limit_steps_per_s",
    "ratio", "batch_physics_steps_per_s", "batch_physics_ratio", "ratio_to_batch_physics"}``: ratio =
    env_steps_per_s / limit_steps_per_s (1 would be physics only); batch_physics_* time ``Batch.step`` alone on the
    same states and threads, which shows what the machine's cores deliver (threads > 1 on a machine whose cores are
    shared reach less than the limit even without any Python)."""
    import franka_vs_gym  # noqa: F401

    kw = dict(kwargs if kwargs is not None else ({} if env_id == "FrankaTorqueTracking-v0"
                                                 else {"observation_type": "features"}))
    venv = gym.make_vec(env_id, num_envs=num_envs, nthread=nthread, **kw)
    try:
        venv.reset(seed=seed)
        actions = np.zeros(venv.action_space.shape, dtype=venv.action_space.dtype)
        venv.step(actions)
        env0 = venv.envs[0]
        raw = _raw_us(env0)
        per_block = max(1, int(round(0.05 / (raw * 1e-6 * num_envs / nthread))))
        best, best_phys, t_end = math.inf, math.inf, time.perf_counter() + seconds
        b, n_sub = venv.batch, env0.n_substeps
        blocks = 0
        while True:
            blocks += 1
            t0 = time.perf_counter()
            for _ in range(per_block):
                venv.step(actions)
            best = min(best, (time.perf_counter() - t0) / (per_block * num_envs))
            raw = min(raw, _raw_us(env0, 20))
            # the batch's physics alone on the same states and threads (the rows are reloaded at the next step)
            t0 = time.perf_counter()
            for _ in range(per_block):
                b.step(nstep=n_sub)
            best_phys = min(best_phys, (time.perf_counter() - t0) / (per_block * num_envs))
            if time.perf_counter() > t_end and blocks >= 5:
                break
    finally:
        venv.close()
    limit = nthread / (raw * 1e-6)
    return {"env_id": env_id, "num_envs": num_envs, "nthread": nthread, "env_steps_per_s": 1.0 / best,
            "raw_us_per_env_step": raw, "limit_steps_per_s": limit, "ratio": (1.0 / best) / limit,
            "batch_physics_steps_per_s": 1.0 / best_phys, "batch_physics_ratio": (1.0 / best_phys) / limit,
            "ratio_to_batch_physics": best_phys / best}


def _interleaved(steps: dict[str, Any], per_block: dict[str, int], rounds: int) -> dict[str, float]:
    """Seconds per call of each ``steps[name]()``, timed in ``rounds`` alternating blocks of ``per_block[name]``
    calls; the fastest block of each is kept, so load from other processes (which only ever slows a block down)
    affects every side alike."""
    best = dict.fromkeys(steps, math.inf)
    for _ in range(rounds):
        for name, step in steps.items():
            n = per_block[name]
            t0 = time.perf_counter()
            for _ in range(n):
                step()
            best[name] = min(best[name], (time.perf_counter() - t0) / n)
    return best


def bench_vector_modes(env_id: str, num_envs: int = 2, n_steps: int = 200, seed: int = 0,
                       modes: tuple[str, ...] = ("async", "sync", "vector_entry_point")) -> dict[str, Any]:
    """Env steps/s of ``gymnasium.make_vec(env_id, num_envs, mode)`` for each mode (Gymnasium's async and sync
    vector envs, the native batched env), each as a ratio to one plain env (``gymnasium.make``): all of them built
    first, then timed in alternating blocks of the same run (``n_steps`` calls of ``step`` per side in all), the
    fastest block of each kept.

    Returns ``{"env_id", "num_envs", "single_steps_per_s", "<mode>_steps_per_s", "<mode>_ratio", ...}`` with
    ``native`` for the batched env."""
    import franka_vs_gym  # noqa: F401

    kw = {} if env_id == "FrankaTorqueTracking-v0" else {"observation_type": "features"}
    envs: dict[str, Any] = {"single": gym.make(env_id, **kw)}
    try:
        for mode in modes:
            envs["native" if mode == "vector_entry_point" else mode] = gym.make_vec(
                env_id, num_envs=num_envs, vectorization_mode=mode, **kw)
        steps: dict[str, Any] = {}
        for name, e in envs.items():
            e.reset(seed=seed)
            a = np.zeros(e.action_space.shape, dtype=e.action_space.dtype)
            e.step(a)  # the first step runs Gymnasium's passive checker: not timed
            if name == "single":
                def step(e=e, a=a):
                    if any(e.step(a)[2:4]):
                        e.reset()
            else:  # vector envs reset their robots themselves
                def step(e=e, a=a):
                    e.step(a)
            steps[name] = step
        rounds = 5
        per_block = dict.fromkeys(steps, max(1, n_steps // rounds))  # vector steps: num_envs env steps each
        t = _interleaved(steps, per_block, rounds)
    finally:
        for e in envs.values():
            e.close()
    single = 1.0 / t["single"]
    out: dict[str, Any] = {"env_id": env_id, "num_envs": num_envs, "single_steps_per_s": single}
    for name in envs:
        if name != "single":
            rate = num_envs / t[name]
            out[f"{name}_steps_per_s"] = rate
            out[f"{name}_ratio"] = rate / single
    return out


def bench_image_batched(env_id: str = "FrankaIBVS-v0", num_envs: int = 8, n_steps: int = 30, seed: int = 0,
                        width: int = 128, height: int = 96, nthread: int = 1, blocks: int = 3) -> dict[str, Any]:
    """Camera frames per second, and per core (CPU time of the process, OpenGL's rasteriser threads included), of
    an image-observation env (``observation_type="image"``, ``width`` x ``height``) on the batched vector env: the
    physics on the batch (``nthread`` threads), each robot's wrist image drawn through the robots' shared OpenGL
    context. The fastest of ``blocks`` blocks of ``n_steps`` env steps is kept.

    Returns ``{"env_id", "num_envs", "width", "height", "frames_per_s", "frames_per_s_per_core", "cpu_cores_busy",
    "render_ms"}``; ``render_ms`` is one robot's frame drawn alone (best of 20), the rest of a frame's cost being
    its physics and the environment's Python."""
    import franka_vs_gym  # noqa: F401

    venv = gym.make_vec(env_id, num_envs=num_envs, nthread=nthread, observation_type="image", image_width=width,
                        image_height=height)
    try:
        venv.reset(seed=seed)
        a = np.zeros(venv.action_space.shape, dtype=venv.action_space.dtype)
        venv.step(a)
        best = (math.inf, math.inf)
        for _ in range(blocks):
            cpu0, t0 = time.process_time(), time.perf_counter()
            for _ in range(n_steps):
                venv.step(a)
            best = min(best, (time.perf_counter() - t0, time.process_time() - cpu0))
        e = venv.envs[0]
        frames_per_step = e.control_period / e.camera_period
        render = math.inf
        for _ in range(20):
            t0 = time.perf_counter()
            e.world.render(e.sim.camera_name(), width, height)
            render = min(render, time.perf_counter() - t0)
    finally:
        venv.close()
    wall, cpu = best
    frames = num_envs * n_steps * frames_per_step
    return {"env_id": env_id, "num_envs": num_envs, "width": width, "height": height, "frames_per_s": frames / wall,
            "frames_per_s_per_core": frames / cpu, "cpu_cores_busy": cpu / wall, "render_ms": render * 1e3}


def bench_step_parts(env_id: str, n: int | None = None, rounds: int = 7, seed: int = 0) -> dict[str, Any]:
    """Where an environment step's time goes besides its physics: the parts of ``FrankaEnv.step`` (a zero action)
    called on their own, each timed in blocks alternating with the raw ``mj_step`` calls of one step (on a copy of
    the env's state) and with the whole ``env.step`` (``gymnasium.make``, so with Gymnasium's wrappers), fastest
    block of each.

    Returns ``{"env_id", "substeps", "physics_us", "step_us", "ratio", "parts": {part: {"us", "share"}}}`` where a
    share is the part's time over the physics time. The parts overlap the step only partly (the camera frame is taken
    at camera frames only), so they need not add up to ``step_us - physics_us``."""
    import franka_vs_gym  # noqa: F401

    kw = {} if env_id == "FrankaTorqueTracking-v0" else {"observation_type": "features"}
    env = gym.make(env_id, **kw)
    u = env.unwrapped
    try:
        a = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
        env.reset(seed=seed)
        env.step(a)
        m = u.world.model
        d_raw = mujoco.MjData(m)
        mujoco.mj_copyData(d_raw, m, u.world.data)
        n_sub = u.n_substeps
        checked = u._check_action(a)

        def step() -> None:
            if any(env.step(a)[2:4]):
                env.reset()

        fns: dict[str, Any] = {
            "step": step,
            "physics": lambda: mujoco.mj_step(m, d_raw, n_sub),
        }
        plan = getattr(u, "_plan", None)
        if plan is not None and plan.fast and plan.eligible(u):
            # the compiled step (franka_vs_gym.envs.compiled): its two calls around the physics, then the Python
            # that ends the step (reward, checks, info, observation dict)
            from franka_vs_gym.sim import plant

            out = np.empty(plan.size, dtype=np.float32)
            views = plan._cmd_views  # (the torque or joint velocity command's arrays)
            obs = u._last_obs
            fns.update({
                "compiled command": lambda: plant.visual_pre(plan.P, plan.I, plan.d_addr, a, *views),
                "compiled period end (reflexes, task, observation)": lambda: plan.post(out),
                # (the IBVS tasks end a compiled step in one call, FrankaIBVSEnv._end_compiled)
                "reward, info (Python)": ((lambda: u._end_compiled(obs, 0)) if getattr(plan, "task_end", False)
                                          else (lambda: u._finish_step(obs, False))),
                "observation dict (Python)": ((lambda: {k: out[sl] for k, sl in plan.flat_views})
                                              if getattr(plan, "flat_views", None) is not None
                                              else (lambda: {k: out[sl] if sh is None else out[sl].reshape(sh)
                                                             for k, sl, sh in plan.views})),
            })
        else:
            fns.update({
                "action check and command": lambda: u._step_begin(a),
                "reflex check after the period": u.sim.check_reflexes,
                "observation": u._get_obs,
                "reward and task checks": lambda: u._evaluate(checked),
                "joint limits and contacts": u._robot_failure,
            })
            if hasattr(u, "_capture"):
                def frame() -> None:
                    u._truth_k = -1  # the ground truth computed again, as for a frame taken at a new state
                    u._capture()

                fns["camera frame"] = frame
        n = n if n is not None else (60 if n_sub >= 50 else 300)
        t = _interleaved(fns, dict.fromkeys(fns, n), rounds)
    finally:
        env.close()
    phys, st = t.pop("physics") * 1e6, t.pop("step") * 1e6
    return {"env_id": env_id, "substeps": n_sub, "physics_us": phys, "step_us": st, "ratio": st / phys,
            "parts": {k: {"us": v * 1e6, "share": v * 1e6 / phys} for k, v in t.items()}}
