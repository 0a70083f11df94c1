#!/usr/bin/env python
"""Score ``diagnose`` on real recordings with a known effect added (franka_vs_gym.validation.injected): the
Gaz et al. 2019 log (exciting trajectory 1, ../shared/data/gaz2019_traj1) at its own ~1 kHz and as every 10th, 20th
and 33rd row (100, 50 and 30 Hz, as a ROS recording gives); ``--source fr3``: the tuning FR3 teleoperation run (FR3,
Franka Hand on; 1 kHz, 100 Hz, 30 Hz); ``--source ros1``: the first half by time of the 30 Hz ROS 1 bag (FER, hand
on; slow, so only its static kinds). The recordings and their rates are those of the evaluation split
(scripts/evaluation_split.json); their locked twins are scored only by scripts/evaluation.py. Each injected copy is
scored as the *difference* from the untouched copy's answer at the same rate, in the evaluation's words
(franka_vs_gym.validation.scoring: right, ambiguous, confident wrong, flagged, missed); ``others``: cases whose
answer changed on joints the effect does not touch (laws named or dropped there).

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
from franka_vs_gym.model.config import ModelConfig, Tool  # noqa: E402
from franka_vs_gym.model.description import robot_description  # noqa: E402
from franka_vs_gym.validation.diagnose import diagnose  # noqa: E402
from franka_vs_gym.validation.injected import KINDS, LIBRARY_KINDS, every_kth, inject, truth_effects  # noqa: E402
from franka_vs_gym.validation.loading import load_log  # noqa: E402
from franka_vs_gym.validation.logs import MeasurementLog  # noqa: E402
from franka_vs_gym.validation.scoring import OUTCOMES, named, score_case  # noqa: E402
from franka_vs_gym.validation.signals import clean  # noqa: E402

SHARED_DATA = ROOT.parent / "shared" / "data"
GAZ = SHARED_DATA / "gaz2019_traj1"
SPLIT = Path(__file__).resolve().parent / "evaluation_split.json"
RATES = {"1 kHz": 1, "100 Hz": 10, "50 Hz": 20, "30 Hz": 33}  # (50 Hz: by name in --rates)
SERVE_KINDS = ("payload", "tilt", "offset", "viscous", "coulomb", "armature", "delay", "payload+viscous")
FRANKY_KINDS = {"payload+viscous"}  # played by the franky script (the others by the pylibfranka script)


def read_log(path: Path) -> MeasurementLog:
    """A recording read through the workbench's own reader (:func:`load_log`). A CSV whose time column is named
    ``t`` (the FR3 teleoperation runs) is read through the same reader from a temporary copy with that column named
    ``time``, while the reader does not know the name ``t``."""
    try:
        return load_log(path)
    except ValueError as e:
        header = path.read_text().split("\n", 1)[0].split(",") if path.suffix == ".csv" else []
        if "no time field" not in str(e) or "t" not in [c.strip() for c in header]:
            raise
    with tempfile.TemporaryDirectory(prefix="real_injected_") as tmp:
        head, rest = path.read_text().split("\n", 1)
        copy = Path(tmp) / path.name
        copy.write_text(",".join("time" if c.strip() == "t" else c for c in head.split(",")) + "\n" + rest)
        log = load_log(copy)
    log.source = str(path)
    return log


def read_recording(spec: dict, data: Path = SHARED_DATA) -> tuple[MeasurementLog, ModelConfig, dict]:
    """One recording of the evaluation split (scripts/evaluation_split.json): the log (its ``half`` by time if
    given), the model the injected effects change (the recording's robot and tool, the log's gravity) and the
    keywords ``diagnose`` is called with (the same robot and tool)."""
    log = read_log(Path(data) / spec["path"])
    if spec.get("half"):
        i = int(np.searchsorted(log.time, log.time[0] + 0.5 * log.duration))
        log = log.slice(0, i) if spec["half"] == "first" else log.slice(i, log.n)
    robot = robot_description(spec.get("robot", "fer"))
    tool = spec.get("tool", "none")
    cfg = ModelConfig(robot=robot, tool=Tool.franka_hand() if tool == "franka_hand" else Tool.none(),
                      gravity=log.gravity)
    return log, cfg, {"tool": tool, "robot": robot.name}


def split_kinds(split: dict, entry: dict) -> list[str]:
    k = entry.get("kinds", "all")
    return list(KINDS) if k == "all" else list(split["static_kinds"]) if k == "static" else list(k)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(GAZ), help="the Gaz et al. 2019 folder (exciting trajectory 1)")
    ap.add_argument("--shared-data", default=str(SHARED_DATA),
                    help="the shared data folder the fr3 and ros1 sources read (paths of evaluation_split.json)")
    ap.add_argument("--cases", type=int, default=1, help="injected copies per kind (seeds 0..cases-1)")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--rates", default="1 kHz,100 Hz,30 Hz", help=f"comma-separated, of {', '.join(RATES)}")
    ap.add_argument("--band", action="store_true", help="diagnose with band_evidence (= --evidence band_only)")
    ap.add_argument("--evidence", default=None, choices=("band", "band_only", "full"),
                    help="diagnose(evidence=...): band (the default: the motion band with its rules), band_only "
                         "(the motion band, the information criterion alone) or full (every sample counted, the "
                         "default before); omitted: diagnose's default")
    ap.add_argument("--source", default="gaz",
                    help="comma-separated: gaz (the Gaz et al. 2019 log), fr3 and ros1 (the tuning recordings of "
                         "scripts/evaluation_split.json: the FR3 run and the first half of the ROS 1 bag, at their "
                         "rates there; their locked twins are scored by scripts/evaluation.py only), serve "
                         "(recordings through franka-vs serve by real clients)")
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
    if not set(sources) <= {"gaz", "fr3", "ros1", "serve"}:
        ap.error(f"--source {args.source}: comma-separated of gaz, fr3, ros1, serve")
    opts = {"band_evidence": args.band, "evidence": args.evidence}
    t_start = time.time()
    rows = []
    if "gaz" in sources:
        rows += gaz_rows(args, kinds, rates, opts)
    split = json.loads(SPLIT.read_text())
    for src in ("fr3", "ros1"):
        if src in sources:
            for entry in split["parts"]["tuning"]:
                if entry["recording"].startswith(src):
                    spec = split["recordings"][entry["recording"]]
                    log, cfg, kw = read_recording(spec, Path(args.shared_data))
                    rows += recording_rows(src, log, cfg, kw, [k for k in kinds if k in split_kinds(split, entry)],
                                           range(args.cases), entry["rates"], opts)
    if "serve" in sources:
        rows += serve_rows(args, [k for k in kinds if k in SERVE_KINDS], rates, opts)
    print(f"\n{len(rows)} injected copies, {time.time() - t_start:.0f} s")
    for src in sources:
        sub = [x for x in rows if x["source"] == src]
        print(f"\n### {src}")
        table(sub, list(dict.fromkeys(x["kind"] for x in sub)), list(dict.fromkeys(x["rate"] for x in sub)),
              args.cases)
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
    cfg = ModelConfig(tool=Tool.none(), gravity=log.gravity)
    return recording_rows("gaz", log, cfg, {"tool": "none"}, kinds, range(args.cases), {r: RATES[r] for r in rates},
                          opts)


def recording_rows(source: str, log: MeasurementLog, cfg: ModelConfig, kw: dict, kinds: list[str], seeds,
                   rates: dict[str, int], opts: dict) -> list[dict]:
    """Inject each kind and seed into ``log`` (effects of the model ``cfg``, sized on the log's noise floor), diagnose
    every ``rates`` copy (name -> every k-th distinct row) with ``kw`` (tool, robot) and ``opts``, and score it
    against the untouched copy's answer at that rate."""
    noise = clean(log).noise
    base = {}
    for r, k in rates.items():
        base[r] = diagnose(every_kth(log, k), **kw, **opts)
        print(f"{source} untouched {r}: {sorted(named(base[r]).items())} explained {base[r].explained}",
              file=sys.stderr)
    rows: list[dict] = []
    for kind in kinds:
        for seed in seeds:
            inj, truth = inject(log, kind, seed, config=cfg, noise=noise)
            for r, k in rates.items():
                t0 = time.process_time()
                d = diagnose(every_kth(inj, k), **kw, **opts)
                report(rows, score_case(base[r], d, truth), kind, seed, r, truth, time.process_time() - t0, source)
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
    outcomes = OUTCOMES
    print(f"\n{len(rows)} injected copies ({cases} per kind and rate)\n")
    print("| kind | " + " | ".join(f"{r}: {' / '.join(outcomes)}" for r in rates) + " |")
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
