"""The speed check of ``scripts/bench.py --check``: names each speed figure that got worse.

Two kinds of figures, each compared where it can be compared honestly on a shared machine:

- **Ratios** (a cost over the raw ``mujoco.mj_step`` cost of the same physics, both timed in alternating blocks of
  one run, in CPU time, the fastest block of each side kept): every registered env's step over its raw physics,
  the native vector env of 64 robots (one batch thread) per robot step over one robot's raw physics (1 / its share
  of the one-core raw-physics limit), an image-observation step (64x48) over its raw physics, and
  ``FrankaSim.step`` over ``mj_step``. They are compared with stored baselines (``scripts/bench_baselines.json``,
  refreshed by ``python scripts/bench.py --refresh-baselines``): a figure more than ``TOLERANCE`` worse is
  measured once more, and named a regression only if the better of its two measurements is still worse.
- **Absolute figures** (``franka-vs serve --lockstep`` commands per second with a pylibfranka torque client in its
  own process, and the server's CPU time per command; ``franka-vs diagnose --json`` on 30 s of 1 kHz data, the
  whole process, wall and CPU seconds) are compared with the previous landed commit (``--against``, default
  ``HEAD^``) checked out beside this tree as a git worktree and timed in the same run, A B A B (this tree first),
  the best of each side kept; a figure more than ``ABS_TOLERANCE`` worse gets one more A B pair before it is named.
  A clone without that commit (shallow, or the first commit) says so and checks the ratios only.

The exit status of ``bench.py --check`` is 1 when a figure is named, else 0.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
BASELINES = Path(__file__).with_name("bench_baselines.json")
TOLERANCE = 0.15  # a ratio more than 15 % worse than its baseline is a regression (noise in CPU-time ratios: < 5 %)
ABS_TOLERANCE = 0.20  # an absolute figure more than 20 % worse than the previous commit's, timed beside it
SERVE_COMMANDS = 4000  # control cycles of one serve run
IMAGE_SIZE = (64, 48)


# ------------------------------------------------------------------ the comparison (pure; tested)
def cost_change(base: float, now: float, higher_is_better: bool = False) -> float:
    """The relative increase of cost from ``base`` to ``now`` (0.3: 30 % more time per unit of work). For a rate
    (``higher_is_better``) the cost is its inverse."""
    if not (math.isfinite(base) and math.isfinite(now)) or base <= 0 or now <= 0:
        return math.nan
    return base / now - 1.0 if higher_is_better else now / base - 1.0


def compare(base: dict[str, float], now: dict[str, float], tolerance: float,
            higher_is_better: frozenset[str] | set[str] = frozenset()) -> list[dict[str, Any]]:
    """One row per figure of ``now``: its baseline, its value, the cost change and whether it is worse than the
    tolerance allows (``worse``). A figure without a baseline (new) or not measured (nan) is never worse; it says
    so in ``note``."""
    rows = []
    for name, value in now.items():
        b = base.get(name, math.nan)
        ch = cost_change(b, value, name in higher_is_better)
        note = ""
        if name not in base:
            note = "no baseline (new figure)"
        elif not math.isfinite(value):
            note = "not measured"
        rows.append({"figure": name, "baseline": b, "now": value, "change": ch,
                     "worse": bool(math.isfinite(ch) and ch > tolerance), "note": note})
    return rows


def check_with_rerun(measure: Callable[[list[str]], dict[str, float]], names: list[str], base: dict[str, float],
                     tolerance: float, higher_is_better: frozenset[str] | set[str] = frozenset(),
                     log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Measure ``names``, compare with ``base``; the figures worse than ``tolerance`` are measured once more and
    keep the better of their two values, and only those still worse are named (``worse``)."""
    now = measure(names)
    rows = compare(base, now, tolerance, higher_is_better)
    again = [r["figure"] for r in rows if r["worse"]]
    if again:
        log(f"worse than the tolerance on the first run, measured again: {', '.join(again)}")
        second = measure(again)
        for name, v in second.items():
            if math.isfinite(v):
                better = max if name in higher_is_better else min
                now[name] = better(now[name], v) if math.isfinite(now[name]) else v
        rows = compare(base, now, tolerance, higher_is_better)
        for r in rows:
            r["rerun"] = r["figure"] in again
    return rows


def format_rows(rows: list[dict[str, Any]], tolerance: float, label_base: str = "baseline") -> str:
    lines = [f"| figure | {label_base} | now | cost change | verdict (tolerance {tolerance:.0%}) |",
             "|---|---|---|---|---|"]
    for r in rows:
        ch = r["change"]
        verdict = "WORSE" if r["worse"] else (r["note"] or ("ok" if math.isfinite(ch) else "-"))
        if r.get("rerun"):
            verdict += " (after a rerun)"
        lines.append(f"| {r['figure']} | {r['baseline']:.4g} | {r['now']:.4g} | "
                     f"{f'{ch:+.1%}' if math.isfinite(ch) else '-'} | {verdict} |")
    return "\n".join(lines)


# ------------------------------------------------------------------ ratio figures (measured in this process)
def _cpu() -> float:
    return time.process_time()


def _env_kwargs(env_id: str) -> dict[str, Any]:
    return {} if env_id == "FrankaTorqueTracking-v0" else {"observation_type": "features"}


def env_step_ratio(env_id: str, n_steps: int = 300) -> float:
    """An env step (``gymnasium.make``, zero action, limiter and reflexes on as by default) over the raw
    ``mj_step`` calls of its substeps, CPU time of alternating blocks (``envs.benchmark._time_env``)."""
    from franka_vs_gym.envs.benchmark import _time_env

    return float(_time_env(env_id, n_steps, 0, _env_kwargs(env_id))["ratio_cpu"])


def vector_ratio(env_id: str, num_envs: int = 64, rounds: int = 6, per_round: int = 3, **kwargs: Any) -> float:
    """The native vector env of ``num_envs`` robots (``gymnasium.make_vec``, one batch thread, zero actions):
    process CPU time per robot step over the CPU time of one robot's raw ``mj_step`` substeps (on a copy of robot
    0's state), alternating blocks, fastest of each. Its inverse is the share of the one-core raw-physics limit."""
    import gymnasium as gym
    import mujoco

    import franka_vs_gym  # noqa: F401

    venv = gym.make_vec(env_id, num_envs=num_envs, nthread=1, **_env_kwargs(env_id), **kwargs)
    try:
        venv.reset(seed=0)
        a = np.zeros(venv.action_space.shape, dtype=venv.action_space.dtype)
        venv.step(a)
        e0 = venv.envs[0]
        m = e0.world.model
        d = mujoco.MjData(m)
        n_sub = e0.n_substeps
        best_env = best_raw = math.inf
        for _ in range(rounds):
            mujoco.mj_copyData(d, m, e0.world.data)
            c = _cpu()
            for _ in range(num_envs * per_round):
                mujoco.mj_step(m, d, n_sub)
            best_raw = min(best_raw, (_cpu() - c) / (num_envs * per_round))
            c = _cpu()
            for _ in range(per_round):
                venv.step(a)
            best_env = min(best_env, (_cpu() - c) / (num_envs * per_round))
    finally:
        venv.close()
    return best_env / best_raw


def image_step_ratio(env_id: str = "FrankaIBVS-v0", rounds: int = 6, block: int = 10) -> float:
    """An image-observation env step (64x48, MuJoCo's renderer as installed) over its raw physics: process CPU
    time (the renderer's threads included) of alternating blocks, fastest of each."""
    import gymnasium as gym
    import mujoco

    import franka_vs_gym  # noqa: F401

    w, h = IMAGE_SIZE
    env = gym.make(env_id, observation_type="image", image_width=w, image_height=h)
    try:
        u = env.unwrapped
        a = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
        env.reset(seed=0)
        env.step(a)
        m = u.world.model
        d = mujoco.MjData(m)
        best_env = best_raw = math.inf
        for _ in range(rounds):
            c = _cpu()
            for _ in range(block):
                if any(env.step(a)[2:4]):
                    env.reset()
            best_env = min(best_env, (_cpu() - c) / block)
            mujoco.mj_copyData(d, m, u.world.data)
            c = _cpu()
            for _ in range(block):
                mujoco.mj_step(m, d, u.n_substeps)
            best_raw = min(best_raw, (_cpu() - c) / block)
    finally:
        env.close()
    return best_env / best_raw


def frankasim_step_ratio(reflexes: bool = True, rounds: int = 10, block: int = 400) -> float:
    """``FrankaSim.step`` (torque mode, friction, limiter off, reflexes as given) over ``mj_step`` on a copy of
    its state, CPU time of alternating blocks."""
    import mujoco

    from franka_vs_gym.sim import FORCE_TORQUE, FrankaSim

    sim = FrankaSim(camera=False, reflexes=reflexes)
    sim.set_robot_state(FORCE_TORQUE)
    m, d = sim.world.model, sim.world.data
    d_raw = mujoco.MjData(m)
    mujoco.mj_copyData(d_raw, m, d)
    best_sim = best_raw = math.inf
    for _ in range(rounds):
        c = _cpu()
        for _ in range(block):
            sim.step()
        best_sim = min(best_sim, _cpu() - c)
        c = _cpu()
        for _ in range(block):
            mujoco.mj_step(m, d_raw)
        best_raw = min(best_raw, _cpu() - c)
    return best_sim / best_raw


def ratio_figures() -> dict[str, Callable[[], float]]:
    """Every ratio figure of the check, by name (lower is better: a cost over raw physics)."""
    import franka_vs_gym  # noqa: F401
    from franka_vs_gym.envs.registration import ENVS

    figs: dict[str, Callable[[], float]] = {}
    for env_id in ENVS:
        figs[f"env step / raw physics: {env_id}"] = lambda e=env_id: env_step_ratio(e)
    for env_id in ENVS:
        figs[f"vector env N=64 (1 thread) / raw physics: {env_id}"] = lambda e=env_id: vector_ratio(e)
    # with resets: every robot's episode ends every 20 steps (time limit 0.2 s), so each timed block of 20 steps holds
    # one reset of all robots (what a reset costs the batch: the robots' models read again, their states loaded)
    figs["vector env N=64 (1 thread), 20-step episodes / raw physics: FrankaTorqueTracking-v0"] = \
        lambda: vector_ratio("FrankaTorqueTracking-v0", rounds=4, per_round=20, time_limit=0.2)
    figs[f"image step {IMAGE_SIZE[0]}x{IMAGE_SIZE[1]} / raw physics: FrankaIBVS-v0"] = image_step_ratio
    figs["FrankaSim.step / mj_step (reflexes on)"] = frankasim_step_ratio
    return figs


def measure_ratios(names: list[str], log: Callable[[str], None] = print) -> dict[str, float]:
    figs = ratio_figures()
    out: dict[str, float] = {}
    for name in names:
        if name not in figs:
            out[name] = math.nan
            continue
        t0 = time.perf_counter()
        try:
            out[name] = float(figs[name]())
        except Exception as e:  # a figure that cannot be measured is reported, not a crash of the whole check
            log(f"  {name}: not measured ({type(e).__name__}: {e})")
            out[name] = math.nan
            continue
        log(f"  {name}: {out[name]:.3f} ({time.perf_counter() - t0:.1f} s)")
    return out


def load_baselines(path: Path = BASELINES) -> dict[str, Any]:
    if not path.exists():
        return {"figures": {}}
    return json.loads(path.read_text())


def refresh_baselines(path: Path = BASELINES, runs: int = 2, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Measure every ratio figure ``runs`` times (interleaved: all figures, then all again) and store the median
    (with 2 runs their mean) as the baselines, with the load and the machine they were measured on."""
    names = list(ratio_figures())
    load0 = os.getloadavg()
    values: dict[str, list[float]] = {n: [] for n in names}
    for k in range(runs):
        log(f"run {k + 1} of {runs}")
        for n, v in measure_ratios(names, log).items():
            values[n].append(v)
    data = {
        "about": "Speed ratios checked by scripts/bench.py --check (cost over raw mujoco.mj_step of the same "
                 "physics, CPU time of alternating blocks; lower is better). Refresh: python scripts/bench.py "
                 "--refresh-baselines",
        "measured": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "commit": _git(["rev-parse", "--short", "HEAD"]) or "unknown",
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, {platform.python_implementation()} "
                   f"{platform.python_version()}",
        "load_average": [round(x, 2) for x in (*load0, *os.getloadavg())],
        "tolerance": TOLERANCE,
        "figures": {n: round(float(np.nanmedian(v)), 4) for n, v in values.items() if np.isfinite(v).any()},
        "runs": {n: [round(x, 4) for x in v] for n, v in values.items()},
    }
    path.write_text(json.dumps(data, indent=2) + "\n")
    return data


# ------------------------------------------------------------------ absolute figures, this tree vs the previous commit
def _git(args: list[str], cwd: Path | None = None) -> str | None:
    try:
        r = subprocess.run(["git", *args], cwd=ROOT if cwd is None else cwd, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def previous_tree(ref: str, dest: Path, log: Callable[[str], None] = print) -> tuple[Path | None, str]:
    """``ref`` checked out (detached) as a git worktree at ``dest`` with the compiled plant (copied from this tree
    when the C sources are the same, else built there). Returns (path or None, what was done or why not)."""
    if _git(["rev-parse", "--git-dir"]) is None:
        return None, f"{ROOT} is not a git checkout: the absolute figures are measured, not compared"
    rev = _git(["rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}"])
    if not rev:
        shallow = _git(["rev-parse", "--is-shallow-repository"]) == "true"
        why = "this is a shallow clone (git fetch --unshallow, or --depth 2, gives it)" if shallow else \
            "there is no such commit (the first commit?)"
        return None, f"no commit {ref!r} to compare with: {why}; the absolute figures are measured, not compared"
    r = subprocess.run(["git", "worktree", "add", "--detach", "--quiet", str(dest), rev], cwd=ROOT,
                       capture_output=True, text=True)
    if r.returncode != 0:
        return None, f"git worktree add failed: {r.stderr.strip()[-300:]}"
    sources = ["franka_vs_gym/sim/_plant.c", "franka_vs_gym/sim/_task.c", "franka_vs_gym/sim/_task.h"]
    same_c = subprocess.run(["git", "diff", "--quiet", rev, "--", *sources], cwd=ROOT).returncode == 0
    built = _built_plant()
    if same_c and built is not None:
        shutil.copy2(built, dest / "franka_vs_gym" / "sim" / built.name)
        how = "compiled plant copied (same C sources)"
    else:
        log(f"building the compiled plant of {rev[:10]} ...")
        b = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=dest,
                           capture_output=True, text=True)
        if b.returncode != 0:
            return dest, f"the compiled plant of {rev[:10]} did not build: {b.stderr.strip()[-300:]}"
        how = "compiled plant built there"
    subject = _git(["log", "-1", "--format=%h %s", rev]) or rev[:10]
    return dest, f"{ref} = {subject[:100]} ({how})"


def _built_plant() -> Path | None:
    """This tree's compiled plant (in the source tree, or where an editable install put it), if any."""
    import importlib.util

    sim_dir = ROOT / "franka_vs_gym" / "sim"
    for f in [*sim_dir.glob("_plant*.so"), *sim_dir.glob("_plant*.pyd")]:
        return f
    try:
        spec = importlib.util.find_spec("franka_vs_gym.sim._plant")
    except ImportError:
        return None
    return Path(spec.origin) if spec is not None and spec.origin else None


def remove_tree(dest: Path) -> None:
    subprocess.run(["git", "worktree", "remove", "--force", str(dest)], cwd=ROOT, capture_output=True)
    shutil.rmtree(dest, ignore_errors=True)


# the caller's environment, before importing franka_vs_gym set its defaults (MUJOCO_GL, LP_NUM_THREADS) in this
# process: each tree's processes get the defaults of their own code
_USER_ENV = dict(os.environ)


def _env_for(tree: Path) -> dict[str, str]:
    env = dict(_USER_ENV)
    env["PYTHONPATH"] = str(tree) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def _process_cpu_s(pid: int) -> float:
    """CPU seconds of all threads of a running process (Linux /proc schedstat: nanoseconds), nan elsewhere."""
    total, found = 0, False
    try:
        for t in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{t}/schedstat") as f:
                total += int(f.read().split()[0])
                found = True
    except OSError:
        return math.nan
    return total * 1e-9 if found else math.nan


_HOSTS = iter(f"127.0.35.{k}" for k in range(10, 250))


def serve_figures(tree: Path, n: int = SERVE_COMMANDS) -> dict[str, float]:
    """``franka-vs serve --lockstep`` (CLI defaults) of ``tree`` in its own process and this tree's pylibfranka
    torque client (``franka_vs_gym.fci.bench_client``) in another: commands per wall second (timed in the client)
    and the server's CPU time per command (the client's connection included)."""
    host = next(_HOSTS)
    srv = subprocess.Popen([sys.executable, "-m", "franka_vs_gym.cli", "serve", "--lockstep", "--host", host],
                           env=_env_for(tree), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        t_end = time.monotonic() + 120
        line = ""
        while time.monotonic() < t_end:
            line = srv.stdout.readline()
            if "ready at" in line or not line:
                break
        if "ready at" not in line:
            raise RuntimeError(f"franka-vs serve did not start: {line.strip()}")
        cpu0 = _process_cpu_s(srv.pid)
        c = subprocess.run([sys.executable, "-m", "franka_vs_gym.fci.bench_client", host, str(n)],
                           env=_env_for(ROOT), capture_output=True, text=True, timeout=600)
        cpu1 = _process_cpu_s(srv.pid)
        if c.returncode != 0:
            raise RuntimeError(f"the pylibfranka client failed: {c.stderr.strip()[-300:]}")
        res = json.loads(c.stdout.strip().splitlines()[-1])
    finally:
        srv.send_signal(2)  # Ctrl-C: the server's own clean stop
        try:
            srv.wait(20)
        except subprocess.TimeoutExpired:
            srv.kill()
            srv.wait()
    return {"serve --lockstep, pylibfranka torque client: commands/s": res["cycles"] / res["wall_s"],
            "serve --lockstep: server CPU us per command": (cpu1 - cpu0) / n * 1e6}


def diagnose_figures(tree: Path, log_path: Path) -> dict[str, float]:
    """``franka-vs diagnose LOG --json`` of ``tree``, the whole process with the CLI's defaults: wall and CPU
    seconds (the child's user + system time, its threads included)."""
    import resource

    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "franka_vs_gym.cli", "diagnose", str(log_path), "--json"],
                       env=_env_for(tree), capture_output=True, text=True, timeout=900)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise RuntimeError(f"franka-vs diagnose exited {p.returncode}: {p.stderr.strip()[-300:]}")
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"diagnose 30 s at 1 kHz (whole process): wall s": wall,
            "diagnose 30 s at 1 kHz (whole process): CPU s": cpu}


ABS_HIGHER_IS_BETTER = frozenset({"serve --lockstep, pylibfranka torque client: commands/s"})
# figures of wall time: judged only when the machine was not overloaded during the run (1-minute load average at
# most its CPU count), since beyond that a process waits for a core for most of its time (measured: diagnose 49 to
# 87 s wall for 7.3 to 8.3 s of CPU at load 14 on 2 CPUs); their CPU-time companions are judged always
WALL_FIGURES = frozenset({"serve --lockstep, pylibfranka torque client: commands/s",
                          "diagnose 30 s at 1 kHz (whole process): wall s"})


# CPU time of separate processes run at different moments is steady up to a few processes per core; beyond that
# (measured: the same diagnose 7.1 to 9.7 CPU s at load 14 on 2 CPUs) it is not judged either
CPU_JUDGED_LOAD_PER_CPU = 3.0


def judge_wall(rows: list[dict[str, Any]], max_load: float, cpus: int) -> list[dict[str, Any]]:
    """The wall-time figures of ``rows`` left unjudged (``worse`` False, a note) when the load went above ``cpus``,
    and the CPU-time ones when it went above ``CPU_JUDGED_LOAD_PER_CPU`` per CPU."""
    for r in rows:
        limit = cpus if r["figure"] in WALL_FIGURES else CPU_JUDGED_LOAD_PER_CPU * cpus
        if r["worse"] and max_load > limit:
            r["worse"] = False
            r["note"] = f"not judged: load {max_load:.1f} on {cpus} CPUs"
    return rows


def _have_pylibfranka() -> bool:
    import importlib.util

    return importlib.util.find_spec("pylibfranka") is not None


def measure_pair(trees: dict[str, Path], kinds: list[str], log_path: Path, pairs: int,
                 log: Callable[[str], None] = print) -> dict[str, dict[str, list[float]]]:
    """Each of ``kinds`` ("serve", "diagnose") timed on every tree in turn (A B A B ...), ``pairs`` times.
    Returns {tree label: {figure: [values]}}; a run that fails is logged and leaves its figures out."""
    out: dict[str, dict[str, list[float]]] = {k: {} for k in trees}
    for kind in kinds:
        for _ in range(pairs):
            for label, tree in trees.items():
                out[label].setdefault("_load", []).append(os.getloadavg()[0])
                try:
                    vals = serve_figures(tree) if kind == "serve" else diagnose_figures(tree, log_path)
                except Exception as e:
                    log(f"  {kind} on {label}: failed ({type(e).__name__}: {e})")
                    continue
                log(f"  {kind} on {label}: " + ", ".join(f"{k.split(': ')[-1]} {v:.4g}" for k, v in vals.items()))
                for k, v in vals.items():
                    out[label].setdefault(k, []).append(v)
    return out


def _bests(runs: dict[str, list[float]]) -> dict[str, float]:
    """The best value of each figure of one tree's runs (the load samples, "_load", left out)."""
    return {k: _best(v, k in ABS_HIGHER_IS_BETTER) for k, v in runs.items() if not k.startswith("_")}


def _best(values: list[float], higher: bool) -> float:
    v = [x for x in values if math.isfinite(x)]
    return (max(v) if higher else min(v)) if v else math.nan


def absolute_check(ref: str, log: Callable[[str], None] = print) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The absolute figures of this tree (A) and of ``ref`` (B) timed A B A B; B is the baseline. Returns (rows,
    info); rows is empty of verdicts (``worse`` False) when B could not be checked out."""
    from franka_vs_gym.validation.hidden import make_hidden_effect_log
    from franka_vs_gym.validation.logs import save_log

    kinds = ["diagnose"] + (["serve"] if _have_pylibfranka() else [])
    info: dict[str, Any] = {"against": ref}
    if "serve" not in kinds:
        log("pylibfranka is not installed (pip install -e '.[fci]'): the serve figures are left out")
    with tempfile.TemporaryDirectory(prefix="bench-check-") as tmp:
        tmp_p = Path(tmp)
        log_path = save_log(make_hidden_effect_log("payload", 0, duration=30.0)[0], tmp_p / "payload30.csv")
        trees = {"this tree": ROOT}
        prev, msg = (None, "comparison switched off (--against none)") if ref.lower() == "none" else \
            previous_tree(ref, tmp_p / "previous", log)
        info["previous"] = msg
        log(f"previous commit: {msg}")
        usable = prev is not None and "did not build" not in msg
        if usable:
            trees["previous"] = prev
        try:
            runs = measure_pair(trees, kinds, log_path, 2, log)
            cpus = os.cpu_count() or 1

            def max_load() -> float:
                return max(max(v.get("_load", [0.0])) for v in runs.values())

            a, b = _bests(runs["this tree"]), _bests(runs.get("previous", {}))
            rows = judge_wall(compare(b, a, ABS_TOLERANCE, ABS_HIGHER_IS_BETTER), max_load(), cpus) if usable else \
                [{"figure": k, "baseline": math.nan, "now": v, "change": math.nan, "worse": False,
                  "note": "not compared"} for k, v in a.items()]
            again = sorted({r["figure"] for r in rows if r["worse"]})
            if again:
                log(f"worse than the previous commit beyond {ABS_TOLERANCE:.0%}, one more A B pair: "
                    f"{', '.join(again)}")
                kinds2 = sorted({"serve" if "serve" in f else "diagnose" for f in again})
                more = measure_pair(trees, kinds2, log_path, 1, log)
                for label in runs:
                    for k, v in more[label].items():
                        runs[label].setdefault(k, []).extend(v)
                a, b = _bests(runs["this tree"]), _bests(runs["previous"])
                rows = judge_wall(compare(b, a, ABS_TOLERANCE, ABS_HIGHER_IS_BETTER), max_load(), cpus)
                for r in rows:
                    r["rerun"] = r["figure"] in again
            info["runs"] = runs
            info["max_load"] = max_load()
        finally:
            if prev is not None:
                remove_tree(prev)
    return rows, info


def ratios_of_tree(tree: Path, names: list[str] | None = None) -> dict[str, float]:
    """The ratio figures of ``tree``'s code, measured in a process of its own (this script, ``--measure-ratios``)."""
    with tempfile.NamedTemporaryFile(suffix=".json") as f:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--measure-ratios", f.name, *(names or [])]
        p = subprocess.run(cmd, env=_env_for(tree), capture_output=True, text=True, timeout=1800)
        if p.returncode != 0:
            raise RuntimeError(f"ratio figures of {tree} not measured: {p.stderr.strip()[-300:]}")
        return json.loads(Path(f.name).read_text())


def ratios_before_after(ref: str, rounds: int = 2, log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Every ratio figure of this tree (A) and of ``ref`` (B), each side in its own processes, A B A B
    (``rounds`` pairs), the best of each side kept: the before/after table of a speed change in one run."""
    with tempfile.TemporaryDirectory(prefix="bench-ab-") as tmp:
        prev, msg = previous_tree(ref, Path(tmp) / "previous", log)
        log(f"before: {msg}")
        if prev is None:
            return []
        try:
            names = list(ratio_figures())
            runs: dict[str, dict[str, list[float]]] = {"after": {}, "before": {}}
            for k in range(rounds):
                for label, tree in (("after", ROOT), ("before", prev)):
                    log(f"round {k + 1}: {label} ...")
                    for n, v in ratios_of_tree(tree, names).items():
                        runs[label].setdefault(n, []).append(v)
        finally:
            remove_tree(prev)
    before = {n: _best(v, False) for n, v in runs["before"].items()}
    after = {n: _best(v, False) for n, v in runs["after"].items()}
    return compare(before, after, TOLERANCE)


# ------------------------------------------------------------------ the whole check
def run_check(ref: str = "HEAD^", json_path: str | None = None, only: str = "all",
              log: Callable[[str], None] = print) -> int:
    """The check: ratio figures against the baselines, absolute figures against ``ref``. Prints both tables and
    the names of the figures that got worse; returns the exit status (1 when any did)."""
    t_start = time.perf_counter()
    load0 = os.getloadavg()
    log(f"speed check: load average {', '.join(f'{x:.2f}' for x in load0)} on {os.cpu_count()} CPUs")
    base = load_baselines()
    worse: list[str] = []
    result: dict[str, Any] = {"load_average_before": load0}
    if only in ("all", "ratios"):
        if not base["figures"]:
            log(f"no baselines in {BASELINES}: run python scripts/bench.py --refresh-baselines")
        names = list(ratio_figures())
        rows = check_with_rerun(lambda ns: measure_ratios(ns, log), names, base["figures"], TOLERANCE, log=log)
        log(f"\n## Ratios (CPU time, cost over raw physics; lower is better) vs {BASELINES.name} "
            f"(measured {base.get('measured', '?')} at load {base.get('load_average', '?')})\n")
        log(format_rows(rows, TOLERANCE))
        worse += [r["figure"] for r in rows if r["worse"]]
        result["ratios"] = rows
    if only in ("all", "absolute"):
        rows, info = absolute_check(ref, log)
        log(f"\n## Absolute figures, this tree vs {info['previous']}, timed A B A B in this run (best of each)\n")
        log(format_rows(rows, ABS_TOLERANCE, label_base="previous commit"))
        worse += [r["figure"] for r in rows if r["worse"]]
        result["absolute"] = rows
        result["absolute_info"] = info
    load1 = os.getloadavg()
    result["load_average_after"] = load1
    result["worse"] = worse
    log(f"\nload average after: {', '.join(f'{x:.2f}' for x in load1)}; check took "
        f"{time.perf_counter() - t_start:.0f} s")
    if json_path:
        Path(json_path).write_text(json.dumps(result, indent=2, default=str) + "\n")
    if worse:
        log("\nSPEED REGRESSION: " + "; ".join(worse))
        return 1
    log("\nspeed check passed: no figure got worse beyond its tolerance")
    return 0


if __name__ == "__main__":  # (the entry point is scripts/bench.py --check; this is the ratio side of a tree)
    if len(sys.argv) >= 3 and sys.argv[1] == "--measure-ratios":
        res = measure_ratios(sys.argv[3:] or list(ratio_figures()), lambda s: print(s, file=sys.stderr, flush=True))
        Path(sys.argv[2]).write_text(json.dumps(res))
    else:
        sys.exit("usage: python scripts/bench.py --check | --refresh-baselines | --before-after REF")


__all__ = ["compare", "check_with_rerun", "cost_change", "run_check", "refresh_baselines", "previous_tree",
           "ratios_before_after"]
