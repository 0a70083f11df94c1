"""Timing of the workbench on a simulated log (used by ``scripts/bench.py``)."""

from __future__ import annotations

import time


def bench_compare_diagnose(seconds: float = 30.0, seed: int = 0, replay: bool = True) -> dict[str, float]:
    """Time compare and diagnose on ``seconds`` of 1 kHz data with a hidden payload.

    Returns wall-clock seconds of each stage (log generation excluded from the total): ``clean``, ``compare``
    (inverse dynamics + concentration table, on the cleaned log), ``replay`` (controller replay in the plant),
    ``diagnose`` (the whole library, groups and selection), ``total`` = clean + compare + replay + diagnose, and
    ``budget_s`` = 5 (the target on one core).
    """
    from franka_vs_gym.validation.compare import compare
    from franka_vs_gym.validation.compare import replay as run_replay
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.hidden import make_hidden_effect_log
    from franka_vs_gym.validation.signals import clean

    t0 = time.perf_counter()
    log, _ = make_hidden_effect_log("payload", seed, duration=seconds)
    t1 = time.perf_counter()
    data = clean(log)
    t2 = time.perf_counter()
    res = compare(data, do_replay=False)
    t3 = time.perf_counter()
    if replay:
        res.replay = run_replay(data, res.config)
    t4 = time.perf_counter()
    d = diagnose(data)
    t5 = time.perf_counter()
    return {"samples": float(data.n), "generate_s": t1 - t0, "clean_s": t2 - t1, "compare_s": t3 - t2,
            "replay_s": t4 - t3, "diagnose_s": t5 - t4, "total_s": t5 - t1, "budget_s": 5.0,
            "verdict_is_payload": float(d.verdict == "payload")}
