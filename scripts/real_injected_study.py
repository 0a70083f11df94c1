#!/usr/bin/env python
"""Score ``diagnose`` on a real FER recording with a known effect added (franka_vs_gym.validation.injected): the
Gaz et al. 2019 log (exciting trajectory 1, ../shared/data/gaz2019_traj1) at its own ~1 kHz and as every 10th and
every 33rd row (100 Hz and 30 Hz, as a ROS recording gives). Each injected copy is scored as the *difference* from
the untouched copy's answer at the same rate:

- library effects: **right** when the effect is named on the joints it touches (an accepted law: a Coulomb step may
  be named Coulomb, sigmoid or asymmetric friction; for an effect the untouched copy already names, its fitted
  change must match: a tilt within 50 % of the injected change of the gravity vector, a payload's mass within
  50 %) and nothing else new is named; **flagged** when it is not, but the answer says so on a touched joint
  (``ambiguous`` with an accepted candidate, a new unexplained finding, a reported model change);
  **confident wrong** otherwise when something wrong or nothing was said.
- outside effects: **flagged** (the right answer) when a touched joint gets a new unexplained finding, an ambiguity
  or (a grasp) a model change; **right** for a grasp when the change is reported within 1 s with a payload and the
  effects of the untouched copy are still named; **confident wrong** when a library effect is newly named on a
  touched joint with nothing flagged; **missed** when nothing changed.
- a law newly named on a joint where the answer also says it is ambiguous with another (``ambiguous`` listing it
  on that joint) is not counted as a confident name.
- ``others``: cases whose answer changed on joints the effect does not touch (laws named or dropped there).

A second source (``--source serve``): recordings made through ``franka-vs serve --lockstep --record`` by a real
client, the pylibfranka script ``franka-vs excite`` writes (the payload + viscous compound also by its franky
script), with the effect hidden in the plant (``serve --truth``: the robot's own model does not know it), sized on
the untouched recording's motion exactly as the injections into the Gaz log (``injected.truth_effects``); white
torque noise of ``--serve-noise`` Nm, the same noise sequence in every recording. Scored the same way, against the
untouched recording's answer at the same rate.

    python scripts/real_injected_study.py --cases 1 -o study.json        # about 5 min on one core
    python scripts/real_injected_study.py --source serve                 # about 6-15 min (10 recordings of 15 s)
    python scripts/real_injected_study.py --source serve --recordings rec/   # keeps them: run again to score the
                                                                         # same recordings (another workbench)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from franka_vs_gym.io import atomic_write  # noqa: E402
from franka_vs_gym.validation.diagnose import diagnose  # noqa: E402
from franka_vs_gym.validation.injected import KINDS, LIBRARY_KINDS, every_kth, inject, truth_effects  # noqa: E402
from franka_vs_gym.validation.logs import load_log  # noqa: E402
from franka_vs_gym.validation.signals import clean  # noqa: E402

GAZ = ROOT.parent / "shared" / "data" / "gaz2019_traj1"
RATES = {"1 kHz": 1, "100 Hz": 10, "50 Hz": 20, "30 Hz": 33}  # (50 Hz: by name in --rates)
STEP = {"coulomb_friction", "sigmoid_friction", "asymmetric_friction", "stribeck_friction"}
ACCEPT = {"payload": {"payload"}, "gravity_tilt": {"gravity_tilt"}, "torque_offset": {"torque_offset"},
          "viscous_friction": {"viscous_friction"}, "coulomb_friction": STEP, "armature": {"armature"},
          "delay": {"delay"}}
SHARED = {"payload", "gravity_tilt", "delay", "link_inertials", "link_mass"}
SERVE_KINDS = ("payload", "tilt", "offset", "viscous", "coulomb", "armature", "delay", "payload+viscous")
FRANKY_KINDS = {"payload+viscous"}  # played by the franky script (the others by the pylibfranka script)


def canon(name: str) -> str:
    """The step-friction laws (Coulomb, sigmoid, asymmetric, Stribeck) are one family: a real joint's friction
    differs from the model's and the log decides which of them fits it best, so a change among them on a joint
    is not a new name."""
    return "step_friction" if name in STEP else name


def named(d, raw: bool = False) -> dict[str, set[int]]:
    """Effect name (family) -> joints (shared effects: every joint, the name is what counts)."""
    out: dict[str, set[int]] = {}
    for s in d.selection:
        n = s.effect if raw else canon(s.effect)
        out.setdefault(n, set()).update(set(range(7)) if s.effect in SHARED else set(s.joints))
    return out


def params(d, name):
    return next((s.params for s in d.selection if s.effect == name), None)


def flagged_joints(base, d) -> set[int]:
    """Joints the injected copy's answer flags that the untouched copy's did not: unexplained findings (beyond
    the untouched ones on that joint), ambiguities, lack-of-fit."""
    def findings(x):
        out = {}
        if x.unexplained is not None:
            for f in x.unexplained.findings:
                out[f.joint] = max(out.get(f.joint, 0.0), f.removed_rms)
        return out

    fb, fd = findings(base), findings(d)
    noise = d.noise_floor
    out = {j for j, r in fd.items() if r > fb.get(j, 0.0) + 0.25 * noise[j]}
    old = {(tuple(a.candidates), j) for a in getattr(base, "ambiguous", []) or [] for j in a.joints}
    for a in getattr(d, "ambiguous", []) or []:
        out |= {j for j in a.joints if (tuple(a.candidates), j) not in old}
    return out


def ambiguous_with(d, accepted: set[str], joints: set[int]) -> bool:
    for a in getattr(d, "ambiguous", []) or []:  # an ambiguity naming an accepted law on a touched joint
        if set(a.candidates) & accepted and (set(a.joints) & joints or not a.joints):
            return True
    return False


def score_case(base, d, truth: list[dict]) -> dict:
    nb, nd = named(base), named(d)
    touched = set().union(*[set(t["joints"]) for t in truth])
    lib = [t for t in truth if t["effect"] in ACCEPT]
    outside = [t for t in truth if t["effect"] not in ACCEPT]
    ok_names = {canon(n) for t in lib for n in ACCEPT[t["effect"]]}
    # new (name, joint) pairs
    new = {(n, j) for n, js in nd.items() for j in js if j not in nb.get(n, set())}
    gone = {(n, j) for n, js in nb.items() for j in js if j not in nd.get(n, set())}
    # a law named on a joint together with an ambiguity that lists it there is not a confident name
    said = {(canon(c), j) for a in getattr(d, "ambiguous", []) or [] for c in a.candidates for j in a.joints}
    new_confident = {(n, j) for n, j in new if (n, j) not in said}
    spurious = {(n, j) for n, j in new_confident if n not in ok_names or (n not in SHARED and j not in touched)}
    if outside:
        spurious_touch = {(n, j) for n, j in new_confident if n not in ok_names and (n in SHARED or j in touched)}
    rb, rd = named(base, raw=True), named(d, raw=True)
    raw_new = {(n, j) for n, js in rd.items() for j in js if j not in rb.get(n, set())}
    raw_gone = {(n, j) for n, js in rb.items() for j in js if j not in rd.get(n, set())}
    others = {(n, j) for n, j in raw_new | raw_gone if n not in SHARED and j not in touched}
    flags = flagged_joints(base, d) & (touched or set(range(7)))
    changes = getattr(d, "changes", []) or []
    res = {"named": {n: sorted(js) for n, js in nd.items()}, "new": sorted(map(list, new)),
           "gone": sorted(map(list, gone)), "others_changed": bool(others), "flagged_joints": sorted(flags),
           "ambiguous": [[a.candidates, a.joints] for a in getattr(d, "ambiguous", []) or []],
           "changes": [{"t": c.t, "what": c.what} for c in changes], "explained": bool(d.explained)}
    if lib and not outside:
        hit = True
        for t in lib:
            acc = ACCEPT[t["effect"]]
            if t["effect"] in SHARED:
                if not {canon(a) for a in acc} & set(nd):
                    hit = False
                elif t["effect"] == "gravity_tilt" and "gravity_tilt" in nb:
                    dg = np.subtract(params(d, "gravity_tilt")["delta_gravity_m_per_s2"],
                                     params(base, "gravity_tilt")["delta_gravity_m_per_s2"])
                    hit &= bool(np.linalg.norm(dg - t["delta_gravity_m_per_s2"])
                                < 0.5 * np.linalg.norm(t["delta_gravity_m_per_s2"]))
                elif t["effect"] == "payload":
                    m = params(d, "payload").get("mass_kg", 0.0) - (params(base, "payload") or {}).get("mass_kg", 0)
                    hit &= bool(abs(m - t["mass_kg"]) < 0.5 * t["mass_kg"])
            else:
                hit &= all(any(j in nd.get(canon(a), set()) for a in acc) for j in t["joints"])
        amb = any(ambiguous_with(d, ACCEPT[t["effect"]], set(t["joints"])) for t in lib)
        if hit and not spurious:
            res["outcome"] = "right"
        elif amb or flags:
            res["outcome"] = "flagged"
        else:
            res["outcome"] = "confident wrong"
        return res
    # outside the library (possibly with a library effect)
    if truth[0]["effect"] == "grasp" and changes:
        t_ok = any(abs(c.t - truth[0]["t_s"]) < 1.0 and "payload" in c.what for c in changes)
        kept = set(nb) - {"payload", "link_inertials"} <= set(nd) | {"payload"}  # the effects present all along
        res["outcome"] = "right" if t_ok and kept and not spurious_touch else "flagged"
        return res
    if flags:
        res["outcome"] = "flagged"
    elif spurious_touch:
        res["outcome"] = "confident wrong"
    else:
        res["outcome"] = "missed"
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(GAZ), help="the Gaz et al. 2019 folder (exciting trajectory 1)")
    ap.add_argument("--cases", type=int, default=1, help="injected copies per kind (seeds 0..cases-1)")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--rates", default="1 kHz,100 Hz,30 Hz", help=f"comma-separated, of {', '.join(RATES)}")
    ap.add_argument("--band", action="store_true", help="diagnose with band_evidence (= --evidence band_only)")
    ap.add_argument("--evidence", default=None, choices=("band", "band_only", "full"),
                    help="diagnose(evidence=...): band (the default: the motion band with its rules), band_only "
                         "(the motion band, the information criterion alone) or full (every sample counted, the "
                         "default before); omitted: diagnose's default")
    ap.add_argument("--source", default="gaz", help="gaz (the Gaz et al. 2019 log), serve (recordings through "
                                                    "franka-vs serve by real clients) or gaz,serve")
    ap.add_argument("--serve-duration", type=float, default=15.0, help="length of the served excitation, s")
    ap.add_argument("--serve-noise", type=float, default=0.1, help="white torque noise of the served plant, Nm")
    ap.add_argument("--host", default="127.0.22.1", help="loopback address the study's server uses")
    ap.add_argument("--recordings", default=None, metavar="DIR",
                    help="keep the served recordings (and the design) in DIR and reuse those already there, so two "
                         "versions of the workbench are scored on the same recordings (default: a temporary folder)")
    ap.add_argument("-o", "--output", default=None, help="write the per-case results as JSON")
    ap.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                    help="print the table of earlier runs' JSON outputs (e.g. one run per rate) instead of running")
    args = ap.parse_args()
    if args.merge:
        rows = [r for p in args.merge for r in json.loads(Path(p).read_text())]
        rates = [r for r in RATES if any(x["rate"] == r for x in rows)]
        for src in dict.fromkeys(r.get("source", "gaz") for r in rows):
            sub = [x for x in rows if x.get("source", "gaz") == src]
            print(f"\n### {src}")
            table(sub, list(dict.fromkeys(r["kind"] for r in sub)), rates, args.cases)
        return 0
    if args.output and Path(args.output).exists():  # checked before the long run, not after it
        ap.error(f"-o {args.output} exists; choose another file name")
    kinds = [k for k in args.kinds.split(",") if k]
    rates = [r for r in args.rates.split(",") if r]
    if not set(rates) <= set(RATES):
        ap.error(f"--rates {args.rates}: choose from {', '.join(RATES)}")
    sources = [s for s in args.source.split(",") if s]
    if not set(sources) <= {"gaz", "serve"}:
        ap.error(f"--source {args.source}: gaz, serve or gaz,serve")
    opts = {"band_evidence": args.band, "evidence": args.evidence}
    t_start = time.time()
    rows = []
    if "gaz" in sources:
        rows += gaz_rows(args, kinds, rates, opts)
    if "serve" in sources:
        rows += serve_rows(args, [k for k in kinds if k in SERVE_KINDS], rates, opts)
    print(f"\n{len(rows)} injected copies, {time.time() - t_start:.0f} s")
    for src in sources:
        sub = [x for x in rows if x["source"] == src]
        print(f"\n### {src}")
        table(sub, list(dict.fromkeys(x["kind"] for x in sub)), rates, args.cases)
    if args.output:
        atomic_write(args.output, json.dumps(rows, indent=1, default=float))
    return 0


def report(rows: list[dict], res: dict, kind: str, seed: int, rate: str, truth: list[dict], cpu: float,
           source: str) -> None:
    res.update(kind=kind, seed=seed, rate=rate, truth=truth, cpu_s=round(cpu, 2), source=source)
    rows.append(res)
    print(f"{source:5s} {kind:16s} seed {seed} {rate:6s}: {res['outcome']:16s} new {res['new']} gone {res['gone']} "
          f"flags {res['flagged_joints']} amb {res['ambiguous']} changes {res['changes']} "
          f"truth {[(t['effect'], t['joints']) for t in truth]}", file=sys.stderr, flush=True)


def gaz_rows(args, kinds: list[str], rates: list[str], opts: dict) -> list[dict]:
    log = load_log(args.data)
    noise = clean(log).noise
    base = {}
    for r in rates:
        base[r] = diagnose(every_kth(log, RATES[r]), tool="none", **opts)
        print(f"gaz untouched {r}: {sorted(named(base[r]).items())} explained {base[r].explained}", file=sys.stderr)
    rows: list[dict] = []
    for kind in kinds:
        for seed in range(args.cases):
            inj, truth = inject(log, kind, seed, noise=noise)
            for r in rates:
                t0 = time.process_time()
                d = diagnose(every_kth(inj, RATES[r]), tool="none", **opts)
                report(rows, score_case(base[r], d, truth), kind, seed, r, truth, time.process_time() - t0, "gaz")
    return rows


def record(design: Path, truth: dict, out: Path, host: str, client: str, reuse: bool = False) -> Path:
    """One recording through ``franka-vs serve --lockstep --record`` with ``truth`` hidden in the plant: the
    script ``franka-vs excite`` wrote for ``client`` (pylibfranka or franky) plays the design in its own process,
    then the server is stopped (SIGTERM) and writes the log. ``reuse``: an existing recording made with the same
    truth and client is returned as it is."""
    tf = out.with_suffix(".truth.json")
    said = json.dumps({**truth, "client": client})
    if reuse and out.exists() and tf.exists() and tf.read_text() == said:
        return out
    atomic_write(tf, said)  # (serve --truth ignores the client key)
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    srv = subprocess.Popen([sys.executable, "-m", "franka_vs_gym.cli", "serve", "--lockstep", "--no-camera", "--tool",
                            "none", "--scene", "empty", "--host", host, "--truth", str(tf), "--record", str(out)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        said = ""
        while "ready" not in said:
            line = srv.stdout.readline()
            if not line:
                raise RuntimeError(f"franka-vs serve did not start: {said}")
            said += line
        r = subprocess.run([sys.executable, str(design / f"play_excitation_{client}.py"), host], capture_output=True,
                           text=True, timeout=600, env=env)
        if r.returncode != 0:
            raise RuntimeError(f"the {client} script failed: {r.stderr[-2000:]}")
    finally:
        srv.send_signal(signal.SIGTERM)
        srv.communicate(timeout=120)
    if not out.exists():
        raise RuntimeError(f"franka-vs serve wrote no log {out}")
    return out


def serve_rows(args, kinds: list[str], rates: list[str], opts: dict) -> list[dict]:
    keep = args.recordings is not None
    tmp = Path(args.recordings) if keep else Path(tempfile.mkdtemp(prefix="real_injected_serve_"))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        design = tmp / "design"
        if keep and (design / "excite.json").exists():
            print(f"serve: reusing the design and recordings in {tmp}", file=sys.stderr)
        else:
            print(f"serve: designing a {args.serve_duration:g} s excitation (franka-vs excite)", file=sys.stderr)
            subprocess.run([sys.executable, "-m", "franka_vs_gym.cli", "excite", "--effects",
                            "payload,gravity_tilt,viscous_friction,armature,torque_offset", "--duration",
                            str(args.serve_duration), "--rest", "0.5", "--evaluations", "60", "--time-budget", "60",
                            "-o", str(design), "--quiet"], check=True, capture_output=True, text=True,
                           env={**os.environ, "PYTHONPATH": str(ROOT)})
        noise_truth = {"torque_noise_Nm": args.serve_noise, "seed": 0}
        clients = ["pylibfranka"] + (["franky"] if set(kinds) & FRANKY_KINDS else [])
        log0, base = {}, {}
        for client in clients:  # each client's untouched recording: its own motion and timing
            log0[client] = load_log(record(design, {"effects": [], **noise_truth}, tmp / f"untouched_{client}.npz",
                                           args.host, client, keep))
            for r in rates:
                base[client, r] = diagnose(every_kth(log0[client], RATES[r]), **opts)
                print(f"serve untouched ({client}) {r}: {sorted(named(base[client, r]).items())} explained "
                      f"{base[client, r].explained}", file=sys.stderr)
        noise = clean(log0["pylibfranka"]).noise
        rows: list[dict] = []
        for kind in kinds:
            for seed in range(args.cases):
                effects, truth = truth_effects(log0["pylibfranka"], kind, seed, noise=noise)
                client = "franky" if kind in FRANKY_KINDS else "pylibfranka"
                log = load_log(record(design, {"effects": effects, **noise_truth},
                                      tmp / f"{kind.replace('+', '_')}_{seed}.npz", args.host, client, keep))
                for r in rates:
                    t0 = time.process_time()
                    d = diagnose(every_kth(log, RATES[r]), **opts)
                    res = score_case(base[client, r], d, truth)
                    res["client"] = client
                    report(rows, res, kind, seed, r, truth, time.process_time() - t0, "serve")
        return rows
    finally:
        if not keep:
            shutil.rmtree(tmp, ignore_errors=True)


def table(rows: list[dict], kinds: list[str], rates: list[str], cases: int) -> None:
    outcomes = ("right", "flagged", "confident wrong", "missed")
    print(f"\n{len(rows)} injected copies ({cases} per kind and rate)\n")
    print("| kind | " + " | ".join(f"{r}: right / flagged / confident wrong / missed" for r in rates) + " |")
    print("|---|" + "---|" * len(rates))
    groups = [(k, [k]) for k in kinds]
    groups.append(("**library, all**", [k for k in kinds if all(p in LIBRARY_KINDS for p in k.split("+"))]))
    groups.append(("**outside, all**", [k for k in kinds if not all(p in LIBRARY_KINDS for p in k.split("+"))]))
    for name, ks in groups:
        cells = []
        for r in rates:
            sub = [x for x in rows if x["kind"] in ks and x["rate"] == r]
            cells.append(" / ".join(str(sum(x["outcome"] == o for x in sub)) for o in outcomes)
                         + (f" ({sum(x['others_changed'] for x in sub)} others changed)" if sub else ""))
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    raise SystemExit(main())
