"""Coverage of the workbench's 95 % intervals: the share of injected true values inside the interval ``diagnose``
reports, per effect kind and log rate, on three generators with known truth:

- ``H``: ``franka_vs_gym.validation.hidden`` (the MuJoCo plant under computed-torque control, the library's own
  effect laws; 1 kHz, and the same log sampled down to 100 and 30 Hz);
- ``A``: ``tests/independent_logs.py`` (analytic inverse dynamics, white sensor noise, its own laws);
- ``B``: ``tests/independent_logs_b.py`` (coloured, 1/f and quantised sensor noise, its own laws and trajectories).

A true value counts when diagnose selected the effect (and, per joint, that joint); an interval ``None``
(unidentifiable) is counted apart. Step-friction laws of A and B differ from the library's (arctan, erf): their
rows say "other law". Run: ``python scripts/coverage_study.py --seeds 3`` (prints a Markdown table; ``--methods``
compares covariance estimators on the same fits).

``--redraws R`` separates bias from spread where a cell misses: generator B's log of each ``--redraw-seeds`` seed
(its trajectory style and effect values) with R independent draws of its sensor chain, the effect fitted on all
seven joints with the library (no selection), and per covariance method the coverage, the median fitted/true
ratio, and the errors in units of the standard deviation each interval claims (z = (fitted - true) / (half-width /
1.96)): a bias shows as a mean z away from 0, intervals too narrow as an RMS z above 1 (with a Student quantile
folded in, a correct interval has an RMS z below 1).

``--redraws R --redraw-generator H`` does the same for the hidden-effect generator's scalar parameters (``delay``,
``gravity_tilt``) through ``diagnose`` itself: the log of each seed simulated without sensor noise, its rows at
``--redraw-rate``, then R draws of the generator's sensor noise added to it (``--redraw-noise``: the torque's, the
position's and velocity's, or all; added after the simulation, so unlike the generator's own noise it does not pass
through the controller), each diagnosed. It prints the noise-free log's fit against the plant's value, then per
noise the coverage of the plant's value and of the noise-free fit, the median fitted / noise-free ratio and z =
(fitted - noise-free fit) / (half-width / 1.96): a noise that biases the fit shows as a mean z away from 0.

Usage: python scripts/coverage_study.py [--seeds N] [--first-seed K] [--duration S] [--rates 1000,100,30]
       [--methods hac,ewc,spectral,newey_west,ols] [--generators H,A,B] [--kinds armature]
       python scripts/coverage_study.py --redraws 40 [--redraw-seeds 0,1] [--redraw-effect armature]
       [--redraw-rate 30]
       python scripts/coverage_study.py --redraws 10 --redraw-generator H --redraw-effect delay --redraw-rate 30
       [--redraw-seeds 0,2] [--redraw-noise torque,velocity,all]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

# (generator, generated effect) -> [(library effect, public key, truth key, per joint, transform)]
G0 = np.array([0.0, 0.0, -9.81])
MAP = {
    "viscous": [("viscous_friction", "viscous_Nms_per_rad", "b", True)],
    "armature": [("armature", "armature_kgm2", "Ir", True)],
    "offset": [("torque_offset", "offset_Nm", "offset", True)],
    "payload": [("payload", "mass_kg", "mass", False), ("payload", "com_flange_m", "com", False)],
    "tilt": [("gravity_tilt", "tilt_deg", "tilt_deg", False)],
    "delay": [("delay", "delay_s", "delay_s", False)],
    "coulomb": [("coulomb_friction", "coulomb_Nm", "F", True)],
}
MAP_B = {**MAP, "armature": [("armature", "armature_kgm2", "I", True)],
         "loadfric": [("load_dependent_friction", "mu", "mu", True)],
         "coulomb": [("coulomb_friction", "coulomb_Nm", "dF", True)]}
MAP_H = {
    "viscous_friction": [("viscous_friction", "viscous_Nms_per_rad", "viscous_Nms_per_rad", True)],
    "coulomb_friction": [("coulomb_friction", "coulomb_Nm", "coulomb_Nm", True)],
    "torque_offset": [("torque_offset", "offset_Nm", "offset_Nm", True)],
    "armature": [("armature", "armature_kgm2", "armature_kgm2", True)],
    "payload": [("payload", "mass_kg", "mass_kg", False), ("payload", "com_flange_m", "com_flange_m", False)],
    "gravity_tilt": [("gravity_tilt", "tilt_deg", "tilt_deg", False)],
    "delay": [("delay", "delay_s", "delay_s", False)],
}
OTHER_LAW = {("A", "coulomb"), ("B", "coulomb")}


def cases(seeds: int, first: int = 0) -> list[tuple[str, tuple[str, ...], int]]:
    out = []
    for s in range(first, first + seeds):
        for e in MAP_H:
            out.append(("H", (e,), s))
        out.append(("H", ("coulomb_friction", "gravity_tilt", "armature"), 100 + s))
        for e in ("viscous", "armature", "offset", "payload", "tilt", "delay", "coulomb"):
            out.append(("A", (e,), s))
        out.append(("A", ("viscous", "payload", "offset"), 100 + s))
        for e in ("viscous", "armature", "offset", "payload", "tilt", "loadfric", "coulomb"):
            out.append(("B", (e,), s))
    return out


def logs_for(gen: str, effects: tuple[str, ...], seed: int, duration: float, rates: list[float]):
    """{rate: log} and the truth {generated effect: params}."""
    if gen == "H":
        from franka_vs_gym.validation.hidden import make_hidden_effect_log
        from franka_vs_gym.validation.logs import MeasurementLog

        log, ans = make_hidden_effect_log("+".join(effects), seed, duration=duration)
        truth = ans["params"] if len(effects) > 1 else {effects[0]: ans["params"]}
        out = {}
        for r in rates:
            k = int(round(1000 / r))
            sl = slice(0, len(log.time), k)
            out[r] = MeasurementLog(log.time[sl], log.q[sl], log.dq[sl], log.tau_J[sl], tool=log.tool,
                                    gravity=log.gravity, extra=dict(log.extra))
        return out, truth
    if gen == "A":
        import independent_logs as ga

        out = {}
        for r in rates:
            out[r], t = ga.make_log(list(effects), seed, duration=duration, rate=r)
        return out, t["params"]
    import independent_logs_b as gb

    logs, t = gb.make_logs(list(effects), seed, duration=duration, rates=tuple(rates))
    return logs, t["params"]


def score(gen: str, effects, truth: dict, sel_by_name: dict) -> list[dict]:
    """One row per (effect kind, parameter): inside / outside / unidentified / missed counts."""
    table = MAP_H if gen == "H" else (MAP if gen == "A" else MAP_B)
    from franka_vs_gym.validation.uncertainty import covered

    rows = []
    for e in effects:
        for lib, key, tkey, per_joint in table.get(e, []):
            tv = truth[e][tkey]
            s = sel_by_name.get(lib)
            n_true = 7 if per_joint else (len(tv) if isinstance(tv, list) else 1)
            kind = f"{e} ({'other law' if (gen, e) in OTHER_LAW else 'same law'})" if gen != "H" else e
            row = {"gen": gen, "kind": kind, "param": f"{lib}.{key}", "inside": 0, "outside": 0, "unid": 0,
                   "missed": 0, "halfwidth_rel": []}
            if s is None or key not in s["ci"]:
                row["missed"] = n_true
                rows.append(row)
                continue
            ci = s["ci"][key]
            joints = s["joints"] if per_joint else None
            if per_joint:
                tv = list(tv)
            elif isinstance(tv, list) and tv and isinstance(tv[0], (int, float)) and not isinstance(ci[0], list):
                pass
            i, o, u = covered(ci, tv, joints)
            row.update(inside=i, outside=o, unid=u, missed=(7 - len(joints)) if per_joint else 0)
            vals = s["params"][key]
            if not per_joint and isinstance(tv, (int, float)) and isinstance(vals, (int, float)):
                row.update(value=float(vals), ci=ci, truth=float(tv))  # (for bias studies on the --out rows)
            vlist = vals if isinstance(vals, list) else [vals]
            clist = ci if isinstance(vals, list) else [ci]
            for j, (v, c) in enumerate(zip(vlist, clist, strict=False)):
                if c is not None and v not in (None, 0) and (joints is None or j in joints):
                    row["halfwidth_rel"].append(abs(c[1] - c[0]) / 2 / max(abs(v), 1e-12))
            rows.append(row)
    return rows


def redraw_study(seeds: list[int], effect: str, redraws: int, duration: float, methods: list[str],
                 rate: float = 1000.0) -> None:
    """See the module docstring (``--redraws``)."""
    import independent_logs_b as gb
    from scipy import stats

    from franka_vs_gym.validation.compare import as_processed, baseline_config
    from franka_vs_gym.validation.effects import Context, get_effect
    from franka_vs_gym.validation.selection import Engine, Term
    from franka_vs_gym.validation.uncertainty import confidence

    lib, key, tkey, _ = MAP_B[effect][0]
    z975 = stats.norm.ppf(0.975)
    print("| generator B seed (style) | method | coverage | median fitted/true | mean z | RMS z | median +- |")
    print("|---|---|---|---|---|---|---|")
    for seed in seeds:
        res = {m: {"ins": 0, "n": 0, "ratio": [], "hw": [], "z": []} for m in methods}
        style = ""
        for r in range(redraws):
            log, truth = gb.make_log([effect], seed, duration=duration, rate=rate, noise_seed=r)
            style = truth["style"]
            tv = np.asarray(truth["params"][effect][tkey], dtype=float)
            data = as_processed(log)
            ctx = Context(data, baseline_config(data.log, None, False))
            e = get_effect(lib)
            sf = Engine(ctx, ctx.residual, [np.arange(ctx.n)]).fit([Term(e, e.shape(ctx, ctx.residual),
                                                                         list(range(7)))], cv=False)
            val = np.asarray(e.public(sf.fits[0])[key], dtype=float)
            for m in methods:
                ci = confidence(ctx, [e], sf.fits, ctx.residual, method=m, draws=50).params_ci95[0][key]
                for j in range(7):
                    if ci[j] is None or tv[j] == 0:
                        continue
                    res[m]["ins"] += int(ci[j][0] <= tv[j] <= ci[j][1])
                    res[m]["n"] += 1
                    res[m]["ratio"].append(val[j] / tv[j])
                    res[m]["hw"].append((ci[j][1] - ci[j][0]) / 2 / tv[j])
                    # the error in units of the standard deviation the interval claims (half-width / 1.96)
                    res[m]["z"].append((val[j] - tv[j]) / ((ci[j][1] - ci[j][0]) / 2 / z975))
        for m, v in res.items():
            ratio, hw, zz = np.array(v["ratio"]), np.array(v["hw"]), np.array(v["z"])
            print(f"| {seed} ({style}) | {m} | {v['ins']}/{v['n']} ({100 * v['ins'] / max(v['n'], 1):.0f}%) | "
                  f"{np.median(ratio):.3f} | {zz.mean():+.2f} +- {zz.std() / np.sqrt(len(zz)):.2f} | "
                  f"{np.sqrt(np.mean(zz ** 2)):.2f} | {100 * np.median(hw):.1f}% |")


H_SCALAR = ("delay", "gravity_tilt")  # the hidden-effect generator's kinds with one scalar parameter
NOISES = ("torque", "velocity", "all")


def redraw_study_h(seeds: list[int], effect: str, redraws: int, duration: float, rate: float,
                   noises: list[str]) -> None:
    """See the module docstring (``--redraws R --redraw-generator H``)."""
    from franka_vs_gym.validation import hidden
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.logs import MeasurementLog

    lib, key, tkey, _ = MAP_H[effect][0]
    step = int(round(1000 / rate))
    z975 = 1.959963984540054

    def fitted(log):
        sl = slice(0, len(log.time), step)
        rows = MeasurementLog(log.time[sl], log.q[sl], log.dq[sl], log.tau_J[sl], tool=log.tool,
                              gravity=log.gravity, extra=dict(log.extra))
        s = {x.effect: x for x in diagnose(rows, verbose=False).selection}.get(lib)
        return (None, None) if s is None or s.params_ci95.get(key) is None else (s.params[key], s.params_ci95[key])

    print(f"{effect} at {rate:g} Hz, {duration:g} s, {redraws} draws of each noise\n")
    print("| seed | noise | noise-free fit / plant | plant value inside | noise-free fit inside | "
          "median fitted / noise-free | mean z | RMS z | median +- (of the plant value) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in seeds:
        log, ans = hidden.make_hidden_effect_log(effect, seed, duration=duration, noise_scale=0.0)
        truth = float(ans["params"][tkey])
        ref, _ = fitted(log)
        if ref is None:
            print(f"| {seed} | - | not selected without noise | | | | | | |")
            continue
        n = len(log.time)
        for noise in noises:
            ins_t = ins_r = 0
            ratio, z, hw = [], [], []
            for r in range(redraws):
                rng = np.random.default_rng([seed, r])
                tau, q, dq = log.tau_J, log.q, log.dq
                if noise in ("torque", "all"):
                    tau = tau + rng.normal(size=(n, 7)) * hidden.TORQUE_NOISE * rng.uniform(0.8, 1.2, 7)
                if noise in ("velocity", "all"):
                    q = q + rng.normal(0.0, hidden.Q_NOISE, (n, 7))
                    dq = dq + rng.normal(0.0, hidden.DQ_NOISE, (n, 7))
                v, ci = fitted(MeasurementLog(log.time, q, dq, tau, tool=log.tool, gravity=log.gravity,
                                              extra=dict(log.extra)))
                if v is None:
                    continue
                ins_t += int(ci[0] <= truth <= ci[1])
                ins_r += int(ci[0] <= ref <= ci[1])
                ratio.append(v / ref)
                z.append((v - ref) / ((ci[1] - ci[0]) / 2 / z975))
                hw.append((ci[1] - ci[0]) / 2 / abs(truth))
            m = len(ratio)
            if not m:
                print(f"| {seed} | {noise} | {ref / truth:.3f} | not selected | | | | | |")
                continue
            zz = np.array(z)
            print(f"| {seed} | {noise} | {ref / truth:.3f} | {ins_t}/{m} | {ins_r}/{m} | {np.median(ratio):.3f} | "
                  f"{zz.mean():+.2f} +- {zz.std() / np.sqrt(m):.2f} | {np.sqrt(np.mean(zz ** 2)):.2f} | "
                  f"{100 * np.median(hw):.1f}% |", flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--first-seed", type=int, default=0, help="seeds first..first+seeds-1 (more draws of a cell)")
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--rates", default="1000,100,30")
    p.add_argument("--methods", default="hac",
                   help="covariance methods to compare (hac, ewc, spectral, newey_west, ols)")
    p.add_argument("--generators", default="H,A,B")
    p.add_argument("--kinds", default=None,
                   help="only the generated effects named (comma-separated, e.g. armature; default: all)")
    p.add_argument("--out", default=None, help="write the per-log rows as JSON here (refuses to overwrite)")
    p.add_argument("--redraws", type=int, default=0, help="bias-or-spread study: sensor-chain redraws per seed")
    p.add_argument("--redraw-seeds", default="0,1")
    p.add_argument("--redraw-effect", default="armature", choices=sorted(set(MAP_B) | set(H_SCALAR)))
    p.add_argument("--redraw-rate", type=float, default=1000.0, help="the rate (Hz) of the redrawn logs")
    p.add_argument("--redraw-generator", default="B", choices=("B", "H"))
    p.add_argument("--redraw-noise", default="torque,velocity,all",
                   help="generator H: which sensor noise each draw adds (torque, velocity, all)")
    args = p.parse_args(argv)
    if args.out and Path(args.out).exists():  # checked before the long run, not after it
        p.error(f"--out {args.out} exists; choose another file name")
    if args.redraws and args.redraw_generator == "H":
        noises = args.redraw_noise.split(",")
        if args.redraw_effect not in H_SCALAR:
            p.error(f"--redraw-generator H takes --redraw-effect {' or '.join(H_SCALAR)}, got {args.redraw_effect}")
        if not set(noises) <= set(NOISES):
            p.error(f"--redraw-noise takes {', '.join(NOISES)}, got {args.redraw_noise}")
        if not 0 < args.redraw_rate <= 1000:
            p.error(f"--redraw-rate must be in (0, 1000] Hz (rows of the 1 kHz log), got {args.redraw_rate:g}")
        redraw_study_h([int(x) for x in args.redraw_seeds.split(",")], args.redraw_effect, args.redraws,
                       args.duration, args.redraw_rate, noises)
        return 0
    if args.redraw_effect not in MAP_B:
        p.error(f"--redraw-effect {args.redraw_effect} is a generator H kind: add --redraw-generator H")
    if args.redraws:
        redraw_study([int(x) for x in args.redraw_seeds.split(",")], args.redraw_effect, args.redraws,
                     args.duration, args.methods.split(","), args.redraw_rate)
        return 0
    import importlib

    D = importlib.import_module("franka_vs_gym.validation.diagnose")
    from franka_vs_gym.validation.uncertainty import confidence

    captured: dict = {}
    orig = D.attach_confidence

    def capture(ctx, y, chosen, cur, selection):  # keep the fitted set to re-run other estimators on it
        captured.update(ctx=ctx, y=y, terms=list(chosen), fits=list(cur.fits))
        orig(ctx, y, chosen, cur, selection)

    D.attach_confidence = capture
    rates = [float(r) for r in args.rates.split(",")]
    methods = args.methods.split(",")
    gens = set(args.generators.split(","))
    rows = []
    t0 = time.time()
    kinds = set(args.kinds.split(",")) if args.kinds else None
    all_cases = [c for c in cases(args.seeds, args.first_seed) if c[0] in gens and (kinds is None or
                                                                                     set(c[1]) <= kinds)]
    n_logs = 0
    for i, (gen, effects, seed) in enumerate(all_cases):
        logs, truth = logs_for(gen, effects, seed, args.duration, rates)
        for r in rates:
            captured.clear()
            d = D.diagnose(logs[r], verbose=False)
            n_logs += 1
            chosen = d.selection
            for m in methods:
                if m == "hac":
                    by = {s.effect: {"ci": s.params_ci95, "params": s.params, "joints": s.joints} for s in chosen}
                else:  # the same fits, another covariance estimator
                    if not captured:
                        continue
                    terms, fits = captured["terms"], captured["fits"]
                    conf = confidence(captured["ctx"], [t.effect for t in terms], fits, captured["y"], method=m)
                    by = {t.effect.name: {"ci": c, "params": s.params, "joints": s.joints}
                          for t, c, s in zip(terms, conf.params_ci95, chosen, strict=False)}
                for row in score(gen, effects, truth, by):
                    rows.append({**row, "rate": r, "method": m, "seed": seed, "effects": list(effects)})
            print(f"[{i + 1}/{len(all_cases)} {gen} {'+'.join(effects)} s{seed} {r:.0f} Hz] selected {d.selected} "
                  f"({time.time() - t0:.0f} s)", file=sys.stderr)
    print(f"{n_logs} diagnoses of {len(all_cases)} generated logs ({args.duration:g} s each), "
          f"{time.time() - t0:.0f} s\n")
    for m in methods:
        print(f"### method {m}\n")
        print("| generator | effect kind | parameter | " + " | ".join(f"{r:.0f} Hz" for r in rates) + " |")
        print("|---|---|---|" + "---|" * len(rates))
        keys = sorted({(x["gen"], x["kind"], x["param"]) for x in rows if x["method"] == m})
        tot = {r: [0, 0, 0] for r in rates}
        for k in keys:
            cells = []
            for r in rates:
                sub = [x for x in rows if (x["gen"], x["kind"], x["param"]) == k and x["rate"] == r and
                       x["method"] == m]
                i = sum(x["inside"] for x in sub)
                o = sum(x["outside"] for x in sub)
                u = sum(x["unid"] for x in sub)
                hw = [h for x in sub for h in x["halfwidth_rel"]]
                if "other law" not in k[1]:
                    tot[r][0] += i
                    tot[r][1] += o
                    tot[r][2] += u
                cell = f"{i}/{i + o}" + (f" ({100 * i / (i + o):.0f}%)" if i + o else "")
                if u:
                    cell += f", {u} unid."
                if hw:
                    cell += f", +-{100 * float(np.median(hw)):.1f}%"
                cells.append(cell)
            print(f"| {k[0]} | {k[1]} | {k[2]} | " + " | ".join(cells) + " |")
        print("| all | same law | | " + " | ".join(
            f"**{tot[r][0]}/{tot[r][0] + tot[r][1]} ({100 * tot[r][0] / max(1, tot[r][0] + tot[r][1]):.0f}%)**"
            for r in rates) + " |\n")
    if args.out:
        from franka_vs_gym.io import atomic_write

        atomic_write(args.out, json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
