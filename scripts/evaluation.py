#!/usr/bin/env python
"""Score the workbench on its locked evaluation: real recordings with known effects injected, split into a tuning
part and a locked part by recording, rate and seed (scripts/evaluation_split.json, docs/evaluation.md). Each
injected copy is diagnosed and judged against the untouched copy's answer at the same rate in the evaluation's words
(franka_vs_gym.validation.scoring: right, ambiguous, confident wrong, flagged, missed); the table gives each part,
recording and rate separately, library and outside effects apart, with 95 % binomial (Clopper-Pearson) intervals.

    python scripts/evaluation.py -o before.jsonl                    # both parts, every seed (about 30-40 CPU-min)
    python scripts/evaluation.py -o quick.jsonl --max-seeds 1 --cpu-budget 600
    python scripts/evaluation.py --table before.jsonl               # the table of an earlier run

The output (JSON lines: one line per untouched copy and per injected copy) is written as the run goes, so a run cut
short keeps what it scored; an existing output is refused before anything runs. Decisions may be tuned on the
tuning part only: the locked part is scored, never fitted on.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parent
sys.path.insert(0, str(SCRIPTS.parent))
sys.path.insert(0, str(SCRIPTS))

from real_injected_study import SHARED_DATA, SPLIT, read_recording, split_kinds  # noqa: E402
from scipy.stats import binomtest  # noqa: E402

from franka_vs_gym.validation.injected import KINDS, LIBRARY_KINDS, every_kth, inject  # noqa: E402
from franka_vs_gym.validation.scoring import OUTCOMES, named, score_case  # noqa: E402

PARTS = ("tuning", "locked")


def cases(split: dict, parts: list[str], recordings: list[str] | None, rates: list[str] | None,
          kinds: list[str] | None, max_seeds: int | None) -> list[dict]:
    """The injected copies to score, seed-major (every entry's first seed before any second seed), so a run cut by
    the CPU budget has scored a balanced subset."""
    out = []
    entries = [(p, e) for p in parts for e in split["parts"][p]
               if recordings is None or e["recording"] in recordings]
    depth = max((len(e["seeds"]) for _, e in entries), default=0)
    for i in range(depth if max_seeds is None else min(depth, max_seeds)):
        for part, e in entries:
            if i >= len(e["seeds"]):
                continue
            for kind in split_kinds(split, e):
                if kinds is not None and kind not in kinds:
                    continue
                for rate, k in e["rates"].items():
                    if rates is None or rate in rates:
                        out.append({"part": part, "recording": e["recording"], "rate": rate, "every": int(k),
                                    "kind": kind, "seed": int(e["seeds"][i])})
    return out


def is_library(kind: str) -> bool:
    return all(p in LIBRARY_KINDS for p in kind.split("+"))


def run(args, split: dict, todo: list[dict], out) -> int:
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.signals import clean

    opts = {} if args.evidence is None else {"evidence": args.evidence}
    logs, base, injected = {}, {}, {}
    cpu0, t0 = time.process_time(), time.time()
    done = 0
    for n, c in enumerate(todo):
        used = time.process_time() - cpu0
        if args.cpu_budget is not None and used > args.cpu_budget:
            print(f"CPU budget of {args.cpu_budget:g} s spent ({used:.0f} s): {len(todo) - n} of {len(todo)} "
                  "injected copies not scored", file=sys.stderr)
            break
        rec = c["recording"]
        if rec not in logs:
            log, cfg, kw = read_recording(split["recordings"][rec], Path(args.data))
            logs[rec] = (log, cfg, kw, clean(log).noise)
        log, cfg, kw, noise = logs[rec]
        spec = split["recordings"][rec]
        key = (c["part"], rec, c["rate"])
        if key not in base:
            b = diagnose(every_kth(log, c["every"]), **kw, **opts)
            base[key] = b
            out.write(json.dumps({**{k: c[k] for k in ("part", "recording", "rate")}, "kind": "untouched",
                                  "robot": spec.get("robot", "fer"), "named": {k: sorted(v) for k, v in
                                                                               named(b).items()},
                                  "ambiguous": [a.candidates for a in b.ambiguous], "explained": bool(b.explained)})
                      + "\n")
        ik = (rec, c["kind"], c["seed"])
        if ik not in injected:
            injected.clear()  # one injected copy at a time: every rate of it comes next
            injected[ik] = inject(log, c["kind"], c["seed"], config=cfg, noise=noise)
        inj, truth = injected[ik]
        t = time.process_time()
        try:
            res = score_case(base[key], diagnose(every_kth(inj, c["every"]), **kw, **opts), truth)
        except Exception as e:  # noqa: BLE001 - a failure is a result of the evaluation, recorded and counted
            res = {"outcome": "error", "error": f"{type(e).__name__}: {e}"}
        res.update(c, robot=spec.get("robot", "fer"), library=is_library(c["kind"]), truth=truth,
                   cpu_s=round(time.process_time() - t, 2))
        out.write(json.dumps(res, default=float) + "\n")
        out.flush()
        done += 1
        spent = time.process_time() - cpu0
        eta = spent / done * (len(todo) - done)
        print(f"[{done}/{len(todo)}] {c['part']:6s} {rec:11s} {c['rate']:6s} {c['kind']:16s} seed {c['seed']:4d}: "
              f"{res['outcome']:15s} {res['cpu_s']:5.1f} s CPU (wall {time.time() - t0:.0f} s, about {eta:.0f} "
              "CPU-s to go)", file=sys.stderr, flush=True)
    return done


def interval(k: int, n: int) -> str:
    """``k`` of ``n`` with its 95 % Clopper-Pearson interval in percent."""
    if n == 0:
        return "-"
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95)
    return f"{k} ({100 * ci.low:.0f}-{100 * ci.high:.0f} %)"


def table(rows: list[dict]) -> str:
    """Markdown: one line per part, recording, rate and class (library / outside effects), each outcome as a count
    with its 95 % binomial interval of the share; errors (a diagnose that raised) counted apart."""
    rows = [r for r in rows if r.get("kind") != "untouched"]
    lines = ["| part | recording | robot | rate | effects | n | " + " | ".join(OUTCOMES) + " | errors |",
             "|---|---|---|---|---|---|" + "---|" * (len(OUTCOMES) + 1)]
    keys = list(dict.fromkeys((r["part"], r["recording"], r["rate"], r["library"]) for r in rows))
    keys.sort(key=lambda x: (PARTS.index(x[0]), x[1], x[2], not x[3]))
    for part, rec, rate, lib in keys:
        sub = [r for r in rows if (r["part"], r["recording"], r["rate"], r["library"]) == (part, rec, rate, lib)]
        n = len(sub)
        cells = [interval(sum(r["outcome"] == o for r in sub), n) for o in OUTCOMES]
        lines.append(f"| {part} | {rec} | {sub[0]['robot']} | {rate} | {'library' if lib else 'outside'} | {n} | "
                     + " | ".join(cells) + f" | {sum(r['outcome'] == 'error' for r in sub)} |")
    for part in PARTS:  # each part's totals per class
        for lib in (True, False):
            sub = [r for r in rows if r["part"] == part and r["library"] == lib]
            if sub:
                cells = [interval(sum(r["outcome"] == o for r in sub), len(sub)) for o in OUTCOMES]
                lines.append(f"| **{part}** | all | | all | {'library' if lib else 'outside'} | {len(sub)} | "
                             + " | ".join(cells) + f" | {sum(r['outcome'] == 'error' for r in sub)} |")
    return "\n".join(lines)


def read_rows(paths: list[str]) -> list[dict]:
    return [json.loads(line) for p in paths for line in Path(p).read_text().splitlines() if line.strip()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default=str(SPLIT), help="the split definition (default: scripts/evaluation_split.json)")
    ap.add_argument("--data", default=str(SHARED_DATA), help="the shared data folder the split's paths are in")
    ap.add_argument("--parts", default="tuning,locked", help="comma-separated, of tuning, locked")
    ap.add_argument("--recordings", default=None, help="comma-separated recording names of the split (default all)")
    ap.add_argument("--rates", default=None, help="comma-separated rate names (default: each recording's rates)")
    ap.add_argument("--kinds", default=None, help=f"comma-separated, of {', '.join(KINDS)} (default: the split's)")
    ap.add_argument("--max-seeds", type=int, default=None, help="score only each entry's first N seeds")
    ap.add_argument("--cpu-budget", type=float, default=None, metavar="S",
                    help="start no new injected copy once this many CPU seconds are spent")
    ap.add_argument("--evidence", default=None, choices=("band", "band_only", "full"),
                    help="diagnose(evidence=...); omitted: diagnose's default")
    ap.add_argument("-o", "--output", default=None, help="the per-case results, JSON lines (must not exist)")
    ap.add_argument("--table", nargs="+", default=None, metavar="JSONL", help="print the table of earlier outputs")
    args = ap.parse_args(argv)
    if args.table:
        missing = [p for p in args.table if not Path(p).is_file()]
        if missing:
            ap.error(f"--table: no such file {missing[0]}")
        print(table(read_rows(args.table)))
        return 0
    if not args.output:
        ap.error("-o/--output is required (or --table)")
    if Path(args.output).exists():  # before anything runs: nothing already written is lost
        ap.error(f"-o {args.output} exists; choose another file name")
    split = json.loads(Path(args.split).read_text())
    parts = [p for p in args.parts.split(",") if p]
    if not set(parts) <= set(PARTS):
        ap.error(f"--parts {args.parts}: comma-separated of {', '.join(PARTS)}")
    recs = None if args.recordings is None else [r for r in args.recordings.split(",") if r]
    if recs is not None and not set(recs) <= set(split["recordings"]):
        ap.error(f"--recordings {args.recordings}: choose from {', '.join(split['recordings'])}")
    kinds = None if args.kinds is None else [k for k in args.kinds.split(",") if k]
    if kinds is not None and not set(kinds) <= set(KINDS):
        ap.error(f"--kinds {args.kinds}: choose from {', '.join(KINDS)}")
    rates = None if args.rates is None else [r for r in args.rates.split(",") if r]
    if args.max_seeds is not None and args.max_seeds < 1:
        ap.error("--max-seeds must be at least 1")
    todo = cases(split, parts, recs, rates, kinds, args.max_seeds)
    if not todo:
        ap.error("no injected copies in this selection (check --parts, --recordings, --rates, --kinds)")
    missing = {split["recordings"][c["recording"]]["path"] for c in todo
               if not (Path(args.data) / split["recordings"][c["recording"]]["path"]).exists()}
    if missing:
        ap.error(f"recording(s) not found under {args.data}: {', '.join(sorted(missing))}")
    print(f"{len(todo)} injected copies to score", file=sys.stderr)
    with open(args.output, "x") as out:
        done = run(args, split, todo, out)
    print(table(read_rows([args.output])))
    print(f"\n{done} of {len(todo)} injected copies scored; per case: {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
