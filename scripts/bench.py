#!/usr/bin/env python
"""Speed benchmarks of franka_vs_gym, printed as tables.

Absolute times on shared machines are noisy, so every simulator figure is given next to a reference measured in
the same run (raw ``mujoco.mj_step`` on the same model) as a ratio. Each timing is the best of several repeats.

    python scripts/bench.py [--quick] [--only core,vision,envs,validation,fci,large_log]
"""

from __future__ import annotations

import argparse
import timeit

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


def bench_core(quick: bool) -> None:
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
        ("FrankaSim.step()", step, step / raw, "<= 2 " + ("yes" if step / raw <= 2 else "NO")),
        ("set_force_torque + step (one 1 kHz loop iteration)", full, full / raw, "-"),
    ], ("what", "us", "ratio to raw", "target"))


def bench_vision(quick: bool) -> None:
    from franka_vs_gym import vision

    res = vision.bench(quick=quick)
    table("Vision (one core)", [(k, v) for k, v in res.items()], ("what", "value"))


def bench_envs(quick: bool) -> None:
    from franka_vs_gym import envs

    res = envs.bench(n_steps=100 if quick else 500, async_steps=100 if quick else 500)
    rows = []
    for env_id, r in res["envs"].items():
        rows.append((env_id, r["steps_per_s"], r["us_per_step"], r["substeps"], r["physics_us_per_step"], r["ratio"],
                     "<= 1.5 " + ("yes" if r["ratio"] <= 1.5 else "NO"), r["robot_step_us_per_step"],
                     r["ratio_vs_robot_step"]))
    table("Environments (features observations): env step vs the raw mujoco.mj_step substeps it contains, and vs "
          "FrankaSim stepping (mj_step + the plant's friction law), same run",
          rows, ("env", "steps/s", "us/step", "substeps", "raw mj_step us", "ratio to raw", "target",
                 "FrankaSim stepping us", "ratio to FrankaSim stepping"))
    if "async" in res:
        table("AsyncVectorEnv", [(k, v) for k, v in res["async"].items()], ("what", "value"))


def bench_validation(quick: bool) -> None:
    from franka_vs_gym import validation

    res = validation.bench_compare_diagnose(seconds=30)
    table("Workbench: compare + diagnose on 30 s of 1 kHz data (one core)", [(k, v) for k, v in res.items()],
          ("what", "value"))


def bench_fci(quick: bool) -> None:
    import importlib.util

    if importlib.util.find_spec("pylibfranka") is None:
        print("\n## FCI server: skipped (pip install -e '.[fci]' for pylibfranka)")
        return
    from franka_vs_gym.fci.bench import bench_fci as run

    res = run(quick)
    table("FCI server (franka-vs serve) with a pylibfranka client in its own process",
          [(k, v) for k, v in res.items()], ("what", "value"))


def _time_v(cmd: list[str]) -> tuple[float, float, int]:
    """(wall s, max resident MB, exit status) of a command under /usr/bin/time -v."""
    import re
    import subprocess

    r = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True)
    wall = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)", r.stderr)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    h, m, sec = (float(x) if x else 0.0 for x in wall.groups()) if wall else (0.0, 0.0, float("nan"))
    return 3600 * h + 60 * m + sec, (int(rss.group(1)) / 1024 if rss else float("nan")), r.returncode


def bench_large_log(quick: bool) -> None:
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
            ("load_log", env_py + ["-c", f"from franka_vs_gym.validation.logs import load_log; load_log({str(p)!r})"]),
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


SECTIONS = {"core": bench_core, "vision": bench_vision, "envs": bench_envs, "validation": bench_validation,
            "fci": bench_fci, "large_log": bench_large_log}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions (a smoke run)")
    ap.add_argument("--only", default=",".join(SECTIONS), help="comma-separated sections: " + ",".join(SECTIONS))
    args = ap.parse_args()
    for name in args.only.split(","):
        if name not in SECTIONS:
            raise SystemExit(f"unknown section {name!r}; choose from {', '.join(SECTIONS)}")
        SECTIONS[name](args.quick)


if __name__ == "__main__":
    main()
