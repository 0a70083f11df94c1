#!/usr/bin/env python
"""Score the evidence criterion (franka_vs_gym.validation.criterion) on the locked evaluation before it is wired
into diagnose: the same script, options and output as scripts/evaluation.py, with diagnose's default selection
(evidence "band") replaced in-process by criterion.EvidenceSelector.

    OMP_NUM_THREADS=1 nice -n 10 python scripts/criterion_eval.py -o after.jsonl --parts tuning --max-seeds 1
    OMP_NUM_THREADS=1 nice -n 10 python scripts/criterion_eval.py --log-ratio 10 -o lr10.jsonl --parts tuning

``--log-ratio X`` sets the criterion's one threshold ln B (nats; default criterion.LOG_RATIO = ln 20) for a study
of it on the tuning part. The comparison with diagnose's rules is in docs/workbench/method.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parent
sys.path.insert(0, str(SCRIPTS.parent))
sys.path.insert(0, str(SCRIPTS))

import evaluation  # noqa: E402

import franka_vs_gym.validation.diagnose  # noqa: E402, F401

dg = sys.modules["franka_vs_gym.validation.diagnose"]
import franka_vs_gym.validation.criterion as criterion  # noqa: E402
from franka_vs_gym.validation.criterion import EvidenceSelector  # noqa: E402

_OLD = dg._Selector


def _selector(ctx, eng, noise, effects, verbose, many_test=False):
    if many_test:  # diagnose's default evidence: the decision goes to the criterion
        return EvidenceSelector(ctx, eng, noise, effects, verbose)
    return _OLD(ctx, eng, noise, effects, verbose, many_test)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--log-ratio" in argv:  # a study of the one threshold: ln B in nats (default criterion.LOG_RATIO)
        i = argv.index("--log-ratio")
        criterion.LOG_RATIO = float(argv[i + 1])
        del argv[i:i + 2]
    dg._Selector = _selector
    return evaluation.main(argv)


if __name__ == "__main__":
    raise SystemExit(main())
