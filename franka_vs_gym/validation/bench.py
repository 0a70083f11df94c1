"""Timing of the workbench on a simulated log (used by ``scripts/bench.py``)."""

from __future__ import annotations

import time


def bench_compare_diagnose(seconds: float = 30.0, seed: int = 0, replay: bool = True,
                           effect: str = "payload") -> dict[str, float]:
    """Time compare and diagnose on ``seconds`` of 1 kHz data with a hidden ``effect`` (default a payload; a
    compound such as "coulomb_friction+gravity_tilt+armature" works too).

    Returns wall-clock seconds of each stage (log generation excluded from the total): ``clean``, ``compare``
    (inverse dynamics + concentration table, on the cleaned log), ``replay`` (controller replay in the plant),
    ``diagnose`` (the whole library, in-context selection with backward pass, the structure test), ``total`` =
    clean + compare + replay + diagnose, ``diagnose_cpu_s`` the CPU time of diagnose (run with one BLAS thread it is the
    one-core cost even on a loaded machine), ``budget_s`` = 5 (the target on one core), and whether the selected set
    is the hidden one and the residual explained.
    """
    from franka_vs_gym.validation.compare import compare
    from franka_vs_gym.validation.compare import replay as run_replay
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.hidden import make_hidden_effect_log
    from franka_vs_gym.validation.signals import clean

    t0 = time.perf_counter()
    log, _ = make_hidden_effect_log(effect, seed, duration=seconds)
    t1 = time.perf_counter()
    data = clean(log)
    t2 = time.perf_counter()
    res = compare(data, do_replay=False)
    t3 = time.perf_counter()
    if replay:
        res.replay = run_replay(data, res.config)
    t4 = time.perf_counter()
    c4 = time.process_time()
    d = diagnose(data)
    t5 = time.perf_counter()
    cpu = time.process_time() - c4  # CPU seconds of this process: robust to other load on a shared machine
    return {"samples": float(data.n), "generate_s": t1 - t0, "clean_s": t2 - t1, "compare_s": t3 - t2,
            "replay_s": t4 - t3, "diagnose_s": t5 - t4, "diagnose_cpu_s": cpu, "total_s": t5 - t1, "budget_s": 5.0,
            "selected_right": float(sorted(d.selected) == sorted(effect.split("+"))), "explained": float(d.explained)}
