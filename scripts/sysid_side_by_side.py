"""The workbench side by side with MuJoCo's own system identification (``mujoco.sysid``, shipped with mujoco).

Both fit the same physical parameters to the same torque log, on the first 75 % of it, and predict the last 25 %:

- **workbench**: the joint linear least-squares fit of the effects (``validation.selection.Engine``) with the
  intervals of ``validation.uncertainty`` (HAC sandwich, delta method);
- **mujoco.sysid**: its ``Parameter`` / ``ParameterDict``, its optimiser (``mujoco.sysid.optimize``, scipy backend)
  and its intervals (``mujoco.sysid.calculate_intervals``: ``s^2 (J^T J)^-1`` with a Student quantile, infinite
  where an eigen-direction is null). The residual it minimises is MuJoCo's own inverse dynamics: the logged
  torque's baseline residual minus the change of ``mj_inverse`` when the parameters are written into the MuJoCo
  model of the FER (``dof_damping`` = viscous friction, ``dof_armature`` = armature, a body welded to link 7 =
  payload mass and centre of mass).

Logs: ``A`` (tests/independent_logs.py: analytic, open loop, white noise), ``H`` (validation.hidden: the MuJoCo
plant under computed-torque control, a closed loop), ``Gaz`` (the real FER log of Gaz et al. 2019, no truth).
Prints a Markdown table: held-out RMSE, median interval half-width, coverage of the truth, wall time.

Usage: python scripts/sysid_side_by_side.py [--gaz /work/shared/data/gaz2019_traj1] [--seeds 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def mujoco_model():
    """The FER with the Franka Hand as the simulator builds it, plus a massless body at link 7's origin whose mass
    and centre of mass stand for a payload."""
    from franka_vs_gym.assets.mjcf import SceneSpec, scene_xml

    spec = mujoco.MjSpec.from_string(scene_xml(SceneSpec(table=False)))
    link7 = spec.body("r0_link7")
    link7.add_body(name="sysid_payload", pos=[0, 0, 0], mass=1e-9, ipos=[0, 0, 0.107],
                   inertia=[1e-9, 1e-9, 1e-9], explicitinertial=True)
    m = spec.compile()
    return m, mujoco.MjData(m), m.body("sysid_payload").id


class MujocoInverse:
    """tau = mj_inverse(q, dq, ddq) on the samples of a processed log, for parameter values written into the
    model (returns the change from the nominal model, (n, 7))."""

    def __init__(self, data, idx: np.ndarray) -> None:
        self.m, self.d, self.pid = mujoco_model()
        self.q, self.dq, self.ddq = data.q[idx], data.dq[idx], data.ddq[idx]
        self.nominal = self.run({})

    def run(self, p: dict) -> np.ndarray:
        m, d = self.m, self.d
        m.dof_damping[:7] = p.get("damping", np.zeros(7))
        m.dof_armature[:7] = p.get("armature", np.zeros(7))
        m.body_mass[self.pid] = float(np.ravel(p.get("mass", 1e-9))[0])
        m.body_ipos[self.pid] = p.get("com7", np.array([0, 0, 0.107]))
        out = np.empty((len(self.q), 7))
        for k in range(len(self.q)):
            d.qpos[:7], d.qvel[:7], d.qacc[:7] = self.q[k], self.dq[k], self.ddq[k]
            mujoco.mj_inverse(m, d)
            out[k] = d.qfrc_inverse[:7]
        return out if not hasattr(self, "nominal") else out - self.nominal


PARAMS = {"viscous_friction": ("damping", 7, 0.0, 0.0, 5.0), "armature": ("armature", 7, 0.0, 0.0, 2.0),
          "payload": ("mass", 1, 0.5, 0.0, 5.0)}


def sysid_fit(data, y: np.ndarray, train: np.ndarray, test: np.ndarray, effects: list[str]):
    """mujoco.sysid on the residual y (n, 7): parameters, their interval half-widths, held-out RMSE, seconds."""
    from mujoco import sysid

    t0 = time.perf_counter()
    pd = sysid.ParameterDict()
    for e in effects:
        name, n, nom, lo, hi = PARAMS[e]
        pd.add(sysid.Parameter(name, np.full(n, nom), np.full(n, lo), np.full(n, hi)))
        if e == "payload":
            pd.add(sysid.Parameter("com7", np.array([0.0, 0.0, 0.15]), np.array([-0.3, -0.3, -0.2]),
                                   np.array([0.3, 0.3, 0.5])))
    inv = MujocoInverse(data, train)
    w = 1.0 / np.maximum(np.asarray(data.noise), 1e-3)  # each joint weighted by its noise floor

    def values(params) -> dict:
        return {k: params[k].value for k in params.keys()}

    def residual_fn(x, params):
        params.update_from_vector(x)
        r = (y[train] - inv.run(values(params))) * w
        return [r.ravel()], None, None

    opt, res = sysid.optimize(pd, residual_fn, optimizer="scipy", verbose=False, max_iters=60)
    r_star = residual_fn(res.x, opt)[0]
    _, half = sysid.calculate_intervals(r_star, res.jac)
    secs = time.perf_counter() - t0
    inv_test = MujocoInverse(data, test)
    pred = inv_test.run(values(opt))
    rmse = float(np.sqrt(np.mean((y[test] - pred) ** 2)))
    names = [f"{k}[{i}]" for k in opt.keys() for i in range(opt[k].size)]
    return dict(zip(names, res.x, strict=True)), dict(zip(names, half, strict=True)), rmse, secs


def workbench_fit(ctx, y: np.ndarray, train: np.ndarray, test: np.ndarray, effects: list[str]):
    """The workbench on the same residual: joint least squares on the training samples, intervals, held-out RMSE."""
    from franka_vs_gym.validation.effects import get_effect
    from franka_vs_gym.validation.selection import Engine, Term
    from franka_vs_gym.validation.uncertainty import confidence

    t0 = time.perf_counter()
    es = [get_effect(e) for e in effects]
    eng = Engine(ctx, y, [train])
    terms = [Term(e, e.shape(ctx, y), list(range(7)) if e.per_joint else None) for e in es]
    sf = eng.fit(terms, cv=False)
    yt = np.zeros_like(y)
    yt[train] = y[train]  # the intervals from the training samples' residual only
    sub = ctx.data.subset(train)
    from franka_vs_gym.validation.effects import Context

    ctx_t = Context(sub, ctx.config)
    conf = confidence(ctx_t, es, sf.fits, y[train])
    secs = time.perf_counter() - t0
    pred = sum((e.contribution(ctx, f) for e, f in zip(es, sf.fits, strict=True)), np.zeros_like(y))
    rmse = float(np.sqrt(np.mean((y[test] - pred[test]) ** 2)))
    params = {e.name: e.public(f) for e, f in zip(es, sf.fits, strict=True)}
    return params, dict(zip([e.name for e in es], conf.params_ci95, strict=True)), rmse, secs


def _inside(ci, t) -> tuple[int, int]:
    return (int(ci[0] <= t <= ci[1]), 1) if ci is not None else (0, 1)


def compare_case(label: str, log, effects: list[str], truth: dict | None) -> dict:
    from franka_vs_gym.validation.compare import as_processed, baseline_config
    from franka_vs_gym.validation.diagnose import _split
    from franka_vs_gym.validation.effects import Context

    data = as_processed(log)
    ctx = Context(data, baseline_config(data.log, None, False))
    y = ctx.residual
    train, test = _split(ctx.n)
    wp, wci, wr, ws = workbench_fit(ctx, y, train, test, effects)
    sp, shalf, sr, ss = sysid_fit(data, y, train, test, effects)
    row = {"case": label, "effects": effects, "rmse_baseline": float(np.sqrt(np.mean(y[test] ** 2))),
           "rmse_workbench": wr, "rmse_sysid": sr, "s_workbench": ws, "s_sysid": ss, "cover_w": [0, 0],
           "cover_s": [0, 0], "hw_w": [], "hw_s": []}
    keys = {"viscous_friction": ("viscous_Nms_per_rad", "damping"), "armature": ("armature_kgm2", "armature"),
            "payload": ("mass_kg", "mass")}
    for e in effects:
        wk, sk = keys[e]
        wv, wc = wp[e][wk], wci[e][wk]
        wv, wc = (wv, wc) if isinstance(wv, list) else ([wv], [wc])
        for i, (v, c) in enumerate(zip(wv, wc, strict=True)):
            sv, sh = sp[f"{sk}[{i}]"], shalf[f"{sk}[{i}]"]
            if c is not None:
                row["hw_w"].append((c[1] - c[0]) / 2)
            row["hw_s"].append(sh)
            if truth is not None and e in truth:
                t = truth[e][i] if isinstance(truth[e], list) else truth[e]
                a, n = _inside(c, t)
                row["cover_w"][0] += a
                row["cover_w"][1] += n
                row["cover_s"][0] += int(abs(sv - t) <= sh)
                row["cover_s"][1] += 1
    return row


def coloured(log, seed: int, rho: float = 0.998, sd: float = 0.15):
    """The log with a slowly wandering torque error (AR(1) at 1 kHz, time constant 0.5 s; 0.15 Nm on joints 0-3,
    less on the wrist), the kind of coloured error a real torque sensor and an imperfect model leave."""
    from dataclasses import replace

    rng = np.random.default_rng(1000 + seed)
    n = len(log.time)
    e = np.zeros((n, 7))
    w = rng.normal(0, sd * np.sqrt(1 - rho ** 2), (n, 7))
    e[0] = rng.normal(0, sd, 7)
    for k in range(1, n):
        e[k] = rho * e[k - 1] + w[k]
    return replace(log, tau_J=log.tau_J + e * np.array([1, 1, 1, 1, 0.4, 0.4, 0.2]))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--duration", type=float, default=8.0)
    p.add_argument("--gaz", default=None, help="the Gaz et al. 2019 log folder (optional)")
    args = p.parse_args(argv)
    import independent_logs as ga

    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    rows = []
    for s in range(args.seeds):
        log, t = ga.make_log(["viscous", "payload"], s, duration=args.duration)
        tr = {"viscous_friction": t["params"]["viscous"]["b"], "payload": t["params"]["payload"]["mass"]}
        rows.append(compare_case(f"A seed {s} (open loop, white noise)", log, ["viscous_friction", "payload"], tr))
        print(rows[-1], file=sys.stderr)
        rows.append(compare_case(f"A seed {s} + coloured torque error", coloured(log, s), ["viscous_friction",
                                                                                          "payload"], tr))
        print(rows[-1], file=sys.stderr)
        log, ans = make_hidden_effect_log("payload+armature", s, duration=args.duration)
        tr = {"armature": ans["params"]["armature"]["armature_kgm2"], "payload": ans["params"]["payload"]["mass_kg"]}
        rows.append(compare_case(f"H seed {s} (closed loop, MuJoCo plant)", log, ["armature", "payload"], tr))
        print(rows[-1], file=sys.stderr)
    if args.gaz:
        from franka_vs_gym.validation.logs import load_log

        rows.append(compare_case("Gaz 2019 traj. 1 (real FER)", load_log(args.gaz), ["viscous_friction", "armature"],
                                 None))
        print(rows[-1], file=sys.stderr)
    print("| log | parameters | held-out RMSE (Nm): baseline / workbench / sysid | median 95% half-width: workbench "
          "/ sysid | truth covered: workbench / sysid | wall s: workbench / sysid |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        cw = f"{r['cover_w'][0]}/{r['cover_w'][1]}" if r["cover_w"][1] else "-"
        cs = f"{r['cover_s'][0]}/{r['cover_s'][1]}" if r["cover_s"][1] else "-"
        print(f"| {r['case']} | {' + '.join(r['effects'])} | {r['rmse_baseline']:.4f} / {r['rmse_workbench']:.4f} / "
              f"{r['rmse_sysid']:.4f} | {np.median(r['hw_w']):.3g} / {np.median(r['hw_s']):.3g} | {cw} / {cs} | "
              f"{r['s_workbench']:.2f} / {r['s_sysid']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
