#!/usr/bin/env python
"""Write a measurement log of the simulated FER with one hidden physical effect.

The plant runs the computed-torque controller of eq. (2) (with the default model) on a finite-Fourier-series exciting
trajectory, with realistic sensor noise; the hidden effect is in the plant only (see
``franka_vs_gym.validation.hidden`` for the effects and their sizes).

    python scripts/make_hidden_effect_data.py --effect payload --seed 3 -o runs/payload.csv
    python scripts/make_hidden_effect_data.py --effect random --seed 7 -o runs/mystery.csv
        # -> runs/mystery.csv, runs/mystery.csv.json (sidecar, no answer), runs/mystery.csv.answer.json

Then: ``franka-vs diagnose runs/mystery.csv --json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from franka_vs_gym.errors import is_user_error, one_line
from franka_vs_gym.io import atomic_write
from franka_vs_gym.validation.hidden import check_arguments, injecting_effects, make_hidden_effect_log
from franka_vs_gym.validation.logs import save_log


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--effect", required=True, choices=list(injecting_effects()) + ["none", "random"],
                   help="the hidden effect; 'random' draws effect and magnitude from the seed")
    p.add_argument("--seed", type=int, default=0, help="seed of trajectory, effect parameters and noise")
    p.add_argument("-o", "--output", required=True, help="log to write (.csv or .npz); sidecar <log>.json")
    p.add_argument("--duration", type=float, default=20.0, help="seconds of 1 kHz data (default 20)")
    p.add_argument("--magnitude", type=float, default=1.0, help="size of the effect relative to the documented one")
    p.add_argument("--noise-scale", type=float, default=1.0, help="multiplies the sensor noise levels")
    p.add_argument("--answer", default=None,
                   help="answer file (default: <log>.answer.json with --effect random, none otherwise)")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    args = p.parse_args(argv)
    out = Path(args.output)
    answer_path = Path(args.answer) if args.answer else (
        out.with_name(out.name + ".answer.json") if args.effect == "random" else None)
    for f in (out, out.with_name(out.name + ".json"), answer_path):
        if f is not None and f.exists() and not args.force:
            print(f"error: {f} exists; pass --force to replace it", file=sys.stderr)
            return 2
    if out.suffix.lower() not in (".csv", ".npz"):
        print(f"error: {out}: use a .csv or .npz file name", file=sys.stderr)
        return 2
    # a bad value (a negative or NaN duration, a NaN magnitude ...) or a full disk: one line, exit 2, and the files
    # already there untouched (the log and its sidecar appear together; the answer is written atomically after them)
    try:
        check_arguments(args.duration, args.magnitude, args.noise_scale, args.seed)
        print(f"simulating {args.duration:g} s ...", file=sys.stderr)
        log, answer = make_hidden_effect_log(args.effect, args.seed, duration=args.duration,
                                             magnitude=args.magnitude, noise_scale=args.noise_scale)
        save_log(log, out, overwrite=args.force)
        if answer_path is not None:
            atomic_write(answer_path, json.dumps(answer, indent=2), force=args.force, what="answer file")
            print(f"answer written to {answer_path}", file=sys.stderr)
    except Exception as e:
        if not is_user_error(e):
            raise
        print(f"error: {one_line(e)}", file=sys.stderr)
        return 2
    print(f"log written to {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
