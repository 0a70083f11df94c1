#!/usr/bin/env python
"""Speed benchmarks of franka_vs_gym, printed as tables.

Absolute times on shared machines are noisy, so every simulator figure is given next to a reference measured in
the same run (raw ``mujoco.mj_step`` on the same model) as a ratio. Each timing is the best of several repeats.

    python scripts/bench.py [--quick] [--only core,vision,envs,throughput,validation,fci,large_log] [--json FILE|-]
    python scripts/bench.py --check [--against REF|none] [--check-only ratios|absolute] [--json FILE]
    python scripts/bench.py --refresh-baselines

``--json`` writes every figure (one object per section) to FILE, or to stdout with ``-`` (the tables then go to
stderr).

``--check`` is the speed check CI runs after the tests (``scripts/bench_check.py``): every registered env's step,
the native vector env of 64 robots, an image-observation step and FrankaSim's step, each as a CPU-time ratio to
its raw physics, against the stored baselines (``scripts/bench_baselines.json``, 15 % tolerance); ``franka-vs serve
--lockstep`` with a pylibfranka client and ``franka-vs diagnose`` against the previous commit (``--against``,
default ``HEAD^``) checked out beside this tree and timed A B A B in the same run (20 % tolerance). A figure beyond
its tolerance is measured once more; the check names each figure still worse and exits 1.
``--refresh-baselines`` measures the ratio figures (twice) and rewrites the baselines.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import timeit
from pathlib import Path

import numpy as np


def best_us(fn, number: int, repeat: int = 5) -> float:
    """Best-of-``repeat`` mean time of one call, in microseconds."""
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e6


def table(title: str, rows: list[tuple], headers: tuple[str, ...]) -> None:
    print(f"\n## {title}\n")
    print("| " + " | ".join(headers) + " |")
    print("|" + "|".join("---" for _ in headers) + "|")
    for r in rows:
        print("| " + " | ".join(f"{x:.3g}" if isinstance(x, float) else str(x) for x in r) + " |")


def bench_core(quick: bool) -> dict:
    import mujoco

    from franka_vs_gym.model import FrankaModel
    from franka_vs_gym.sim import FORCE_TORQUE, JOINT_STATE, FrankaSim

    n = 2000 if quick else 20000
    m = FrankaModel()
    rng = np.random.default_rng(0)
    lim = m.limits()
    q = rng.uniform(lim["q_min"], lim["q_max"])
    dq = rng.uniform(-1, 1, 7)
    rows = []
    for name, fn, target in [
        ("mass_matrix B(q)", lambda: m.mass_matrix(q), 10.0),
        ("coriolis_matrix C(q, dq)", lambda: m.coriolis_matrix(q, dq), 10.0),
        ("gravity g(q)", lambda: m.gravity(q), 10.0),
        ("fJe(q)", lambda: m.fJe(q), 10.0),
        ("friction(dq)", lambda: m.friction(dq), None),
        ("inverse_dynamics", lambda: m.inverse_dynamics(q, dq, dq), None),
        ("fMe(q)", lambda: m.fMe(q), None),
    ]:
        t = best_us(fn, n)
        rows.append((name, t, "-" if target is None else f"<= {target:g}", "-" if target is None else
                     ("yes" if t <= target else "NO")))
    table("Model library (per call from Python)", rows, ("call", "us", "target", "met"))

    sim = FrankaSim(camera=False)
    sim.set_robot_state(FORCE_TORQUE)
    mm, dd = sim.world.model, sim.world.data
    z = np.zeros(7)

    def loop():
        sim.set_force_torque(JOINT_STATE, z)
        sim.step()

    ns = 3000 if quick else 20000
    raw = best_us(lambda: mujoco.mj_step(mm, dd), ns)
    step = best_us(sim.step, ns)
    full = best_us(loop, ns)
    raw2 = best_us(lambda: mujoco.mj_step(mm, dd), ns)
    raw = min(raw, raw2)
    table("FrankaSim torque-mode step (1 ms, friction on) vs raw mujoco.mj_step, same model, same run", [
        ("raw mujoco.mj_step", raw, 1.0, "-"),
        ("FrankaSim.step()", step, step / raw, "<= 1.2 " + ("yes" if step / raw <= 1.2 else "NO")),
        ("set_force_torque + step (one 1 kHz loop iteration)", full, full / raw, "-"),
    ], ("what", "us", "ratio to raw", "target"))
    from franka_vs_gym.sim import plant

    return {"model_us": {r[0]: r[1] for r in rows}, "mj_step_us": raw, "frankasim_step_us": step,
            "frankasim_step_ratio": step / raw, "set_force_torque_step_us": full,
            "set_force_torque_step_ratio": full / raw, "compiled_plant": plant.NATIVE}


def bench_vision(quick: bool) -> dict:
    from franka_vs_gym import vision

    res = vision.bench(quick=quick)
    res["render + detect + PnP per frame, median (ms), target <= 10"] = _median_frame_ms(20 if quick else 100)
    table("Vision (one core)", [(k, v) for k, v in res.items()], ("what", "value"))
    return res


def _median_frame_ms(n: int) -> float:
    """Median time (ms) of rendering one 320x240 wrist frame and detecting the tag with PnP, over ``n`` frames of
    an IBVS episode's start views (different seeds, so different views)."""
    import time

    import gymnasium as gym

    import franka_vs_gym  # noqa: F401
    from franka_vs_gym.vision import TagDetector, WristCamera, detected_measurement

    env = gym.make("FrankaIBVS-v0", observation_type="features").unwrapped
    cam, det, times = None, TagDetector(), []
    try:
        for seed in range(n):
            env.reset(seed=seed)
            if cam is None:
                cam = WristCamera(env.sim, env.intrinsics)
            t0 = time.perf_counter()
            img = cam.render()
            detected_measurement(img, det, env.tag_id, env.tag_size, env.intrinsics)
            times.append(time.perf_counter() - t0)
    finally:
        env.close()
    return float(np.median(times) * 1e3)


def bench_envs(quick: bool) -> dict:
    import os

    from franka_vs_gym import envs

    load_before = os.getloadavg()
    res = envs.bench(n_steps=100 if quick else 500, async_steps=100 if quick else 500)
    res["load_average"] = {"before": load_before, "after": os.getloadavg()}
    print(f"\nload average (1, 5, 15 min) before {', '.join(f'{x:.2f}' for x in load_before)}, after "
          f"{', '.join(f'{x:.2f}' for x in res['load_average']['after'])} on {os.cpu_count()} cores")
    for r in res["envs"].values():
        r["target"] = 1.25 if r["substeps"] >= 50 else 1.5
    rows = []
    for env_id, r in res["envs"].items():
        rows.append((env_id, r["steps_per_s"], r["us_per_step"], r["substeps"], r["physics_us_per_step"], r["ratio"],
                     f"<= {r['target']:g} " + ("yes" if r["ratio"] <= r["target"] else "NO"),
                     r["ratio_cpu"], r["robot_step_us_per_step"],
                     r["ratio_vs_robot_step"]))
    table("Environments (features observations): env step vs the raw mujoco.mj_step substeps it contains (wall "
          "clock, and the thread's CPU time of the same blocks), and vs FrankaSim stepping (mj_step + the plant's "
          "friction law), same run",
          rows, ("env", "steps/s", "us/step", "substeps", "raw mj_step us", "ratio to raw", "target",
                 "ratio to raw (CPU time)", "FrankaSim stepping us", "ratio to FrankaSim stepping"))
    from franka_vs_gym.envs.benchmark import bench_step_parts

    res["parts"] = {env_id: bench_step_parts(env_id, rounds=3 if quick else 7) for env_id in res["envs"]}
    names = list(dict.fromkeys(k for p in res["parts"].values() for k in p["parts"]))
    table("Where an env step's time goes besides its physics: each part alone, as a share of the step's raw "
          "mj_step time (same run, alternating blocks)",
          [(env_id, p["substeps"], p["physics_us"], p["ratio"],
            *(p["parts"][k]["share"] if k in p["parts"] else "-" for k in names))
           for env_id, p in res["parts"].items()],
          ("env", "substeps", "physics us", "step / physics", *names))
    if "async" in res:
        a = res["async"]
        table(f"gymnasium AsyncVectorEnv of {a['n_envs']} {a['env_id']} / one plain env, env steps/s, same run",
              [(a["env_id"], a["single_steps_per_s"], a["env_steps_per_s"], a["ratio_to_single"])],
              ("env", "plain env steps/s", "async env steps/s", "ratio"))
    return res


def bench_throughput(quick: bool) -> dict:
    """Many robots per process: the batched vector env against the raw-physics limit, the vector modes against one
    plain env, and image envs' frames per second per core."""
    from franka_vs_gym.envs.benchmark import bench_batched, bench_image_batched, bench_vector_modes

    out: dict = {"batched": [], "vector_modes": [], "image": None}
    ns = (1, 8, 64) if quick else (1, 8, 64, 256)
    for env_id in ("FrankaIBVS-v0", "FrankaTorqueTracking-v0"):
        for n in ns:
            for th in (1, 2):
                if th > n:
                    continue
                r = bench_batched(env_id, n, th, seconds=0.5 if quick else 2.0)
                out["batched"].append(r)
                print(f"  {env_id} N={n} threads={th}: {r['env_steps_per_s']:.0f} env steps/s, ratio to the "
                      f"raw-physics limit {r['ratio']:.2f}", file=sys.stderr, flush=True)
    table("Batched vector env (gymnasium.make_vec, mujoco.batch): env steps/s vs the raw-physics limit "
          "(threads / raw mj_step time of one env step's substeps), same run",
          [(r["env_id"], r["num_envs"], r["nthread"], r["env_steps_per_s"], r["limit_steps_per_s"], r["ratio"],
            ">= 0.85 " + ("yes" if r["ratio"] >= 0.85 else "NO") if r["num_envs"] == 64 else "-",
            r["batch_physics_ratio"], r["ratio_to_batch_physics"],
            1e6 / r["env_steps_per_s"] - 1e6 / r["batch_physics_steps_per_s"]) for r in out["batched"]],
          ("env", "N", "threads", "env steps/s", "raw-physics limit", "ratio", "target",
           "Batch.step alone / limit", "env steps / Batch.step alone", "rest per robot-step (us)"))
    for env_id in ("FrankaTorqueTracking-v0", "FrankaIBVS-v0"):
        out["vector_modes"].append(bench_vector_modes(env_id, 2, 100 if quick else 400))
    table("gymnasium.make_vec(id, 2, mode) / one plain env, env steps per second, same run",
          [(r["env_id"], r["single_steps_per_s"], r["async_ratio"], r["sync_ratio"], r["native_ratio"])
           for r in out["vector_modes"]], ("env", "plain env steps/s", "async", "sync", "native (batched)"))
    out["image"] = []
    for w, h in ((128, 96), (320, 240)):
        for n in ((4,) if quick else (8, 64)):
            img = bench_image_batched(num_envs=n, n_steps=max(2, (80 if w == 128 else 40) // n), width=w, height=h)
            out["image"].append(img)
            print(f"  image {w}x{h} N={n}: {img['frames_per_s']:.0f} frames/s", file=sys.stderr, flush=True)
    table("Image observations (FrankaIBVS-v0, observation_type='image') on the batched env, one batch thread: camera "
          "frames per second, per core (process CPU time, the OpenGL rasteriser's threads included), and one frame "
          "drawn alone", [(f"{r['width']}x{r['height']}", r["num_envs"], r["frames_per_s"], r["frames_per_s_per_core"],
                           r["cpu_cores_busy"], r["render_ms"]) for r in out["image"]],
          ("image", "N", "frames/s", "frames/s per core", "cores busy", "render alone ms"))
    return out


def bench_validation(quick: bool) -> dict:
    from franka_vs_gym import validation

    out = {}
    for effect in ("payload", "coulomb_friction+gravity_tilt+armature"):
        res = validation.bench_compare_diagnose(seconds=30, effect=effect)
        table(f"Workbench: compare + diagnose on 30 s of 1 kHz data, hidden {effect} (one core)",
              [(k, v) for k, v in res.items()], ("what", "value"))
        out[effect] = res
    return out


def bench_fci(quick: bool) -> dict | None:
    import importlib.util

    if importlib.util.find_spec("pylibfranka") is None:
        print("\n## FCI server: skipped (pip install -e '.[fci]' for pylibfranka)")
        return None
    from franka_vs_gym.fci.bench import bench_fci as run

    res = run(quick)
    table("FCI server (franka-vs serve) with a pylibfranka client in its own process",
          [(k, v) for k, v in res.items()], ("what", "value"))
    return res


def _time_v(cmd: list[str]) -> tuple[float, float, int]:
    """(wall s, max resident MB, exit status) of a command under /usr/bin/time -v."""
    import re
    import subprocess

    r = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True)
    wall = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)", r.stderr)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    h, m, sec = (float(x) if x else 0.0 for x in wall.groups()) if wall else (0.0, 0.0, float("nan"))
    return 3600 * h + 60 * m + sec, (int(rss.group(1)) / 1024 if rss else float("nan")), r.returncode


def bench_large_log(quick: bool) -> dict:
    """A 200 MB CSV log (20 MB with --quick): load, compare and diagnose, each in its own process under
    /usr/bin/time -v (wall time and peak memory). Targets: compare within 60 s and under 1 GB."""
    import os
    import sys
    import tempfile
    from pathlib import Path

    from franka_vs_gym.validation.hidden import make_hidden_effect_log
    from franka_vs_gym.validation.logs import MeasurementLog, save_log

    target_mb = 20 if quick else 200
    base, _ = make_hidden_effect_log("viscous_friction", 3, duration=60.0)
    with tempfile.TemporaryDirectory() as d:
        # tile the minute of data (time continued) until the file has the target size
        row_bytes = save_log(base, Path(d) / "base.csv").stat().st_size / base.n
        reps = max(1, int(round(target_mb * 1e6 / row_bytes / base.n)))
        dt = float(np.median(np.diff(base.time)))
        kw = {f: np.tile(getattr(base, f), (reps, 1)) for f in base.fields()}
        t = np.concatenate([base.time + k * (base.time[-1] - base.time[0] + dt) for k in range(reps)])
        big = MeasurementLog(t, **kw, tool=base.tool, gravity=base.gravity, controller=base.controller)
        p = save_log(big, Path(d) / "big.csv")
        mb = p.stat().st_size / 1e6
        env_py = [sys.executable]
        rows = []
        for what, cmd in [
            ("load_log", env_py + ["-c", "from franka_vs_gym.validation.loading import load_log; "
                                         f"load_log({str(p)!r})"]),
            ("franka-vs compare --no-replay", env_py + ["-m", "franka_vs_gym.cli", "compare", str(p), "--json",
                                                        "--quiet", "--no-replay"]),
            ("franka-vs compare (with replay)", env_py + ["-m", "franka_vs_gym.cli", "compare", str(p), "--json",
                                                          "--quiet"]),
            ("franka-vs fit --add viscous_friction", env_py + ["-m", "franka_vs_gym.cli", "fit", str(p), "--add",
                                                               "viscous_friction", "-o", os.path.join(d, "m.json"),
                                                               "--quiet"]),
        ]:
            wall, rss, rc = _time_v(cmd)
            rows.append((what, wall, rss, "ok" if rc == 0 else f"exit {rc}"))
        table(f"Large log: {mb:.0f} MB CSV, {big.n} samples ({big.duration / 60:.1f} min at 1 kHz); one process "
              "each, /usr/bin/time -v", rows, ("command", "wall s", "peak MB", "status"))
        return {"log_mb": mb, "samples": big.n,
                **{r[0]: {"wall_s": r[1], "peak_mb": r[2], "status": r[3]} for r in rows}}


SECTIONS = {"core": bench_core, "vision": bench_vision, "envs": bench_envs, "throughput": bench_throughput,
            "validation": bench_validation, "fci": bench_fci, "large_log": bench_large_log}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions (a smoke run)")
    ap.add_argument("--only", default=",".join(SECTIONS), help="comma-separated sections: " + ",".join(SECTIONS))
    ap.add_argument("--json", metavar="FILE", help="also write every figure as JSON to FILE ('-': stdout, tables "
                    "to stderr); an existing FILE is not overwritten")
    ap.add_argument("--check", action="store_true", help="the speed check: ratios vs the stored baselines, serve and "
                    "diagnose vs the previous commit timed beside this tree; exit 1 naming each figure that got worse")
    ap.add_argument("--against", default="HEAD^", metavar="REF", help="--check: the commit the absolute figures are "
                    "compared with (default HEAD^; 'none': measured only)")
    ap.add_argument("--check-only", choices=("all", "ratios", "absolute"), default="all",
                    help="--check: one half of the check only")
    ap.add_argument("--refresh-baselines", action="store_true", help="measure the check's ratio figures and rewrite "
                    "scripts/bench_baselines.json")
    ap.add_argument("--before-after", metavar="REF", help="the check's ratio figures of this tree and of REF (checked "
                    "out beside it), each in its own processes, A B A B: a before/after table in one run")
    args = ap.parse_args()
    if args.before_after:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import bench_check

        print(f"load average {', '.join(f'{x:.2f}' for x in __import__('os').getloadavg())}")
        rows = bench_check.ratios_before_after(args.before_after)
        print(bench_check.format_rows(rows, bench_check.TOLERANCE, label_base=f"before ({args.before_after})"))
        print(f"load average {', '.join(f'{x:.2f}' for x in __import__('os').getloadavg())}")
        return
    if args.check or args.refresh_baselines:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import bench_check

        if args.refresh_baselines:
            data = bench_check.refresh_baselines()
            print(json.dumps(data["figures"], indent=2))
            print(f"baselines written to {bench_check.BASELINES}")
            return
        if args.json and args.json != "-" and Path(args.json).exists():
            raise SystemExit(f"{args.json} exists; choose another file name")
        raise SystemExit(bench_check.run_check(args.against, None if args.json == "-" else args.json,
                                               args.check_only))
    names = args.only.split(",")
    for name in names:
        if name not in SECTIONS:
            raise SystemExit(f"unknown section {name!r}; choose from {', '.join(SECTIONS)}")
    if args.json and args.json != "-" and Path(args.json).exists():
        raise SystemExit(f"{args.json} exists; choose another file name")  # checked before the long run
    results = {}
    with contextlib.redirect_stdout(sys.stderr) if args.json == "-" else contextlib.nullcontext():
        for name in names:
            results[name] = SECTIONS[name](args.quick)
    if args.json:
        text = json.dumps(results, indent=2, default=str)
        if args.json == "-":
            print(text)
        else:
            from franka_vs_gym.io import atomic_write

            atomic_write(args.json, text + "\n")  # never replaces a file


if __name__ == "__main__":
    main()
