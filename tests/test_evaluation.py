"""The locked evaluation (docs/evaluation.md): the scoring words on hand-made answers, the split's properties, the
binomial intervals against published Clopper-Pearson values, and scripts/evaluation.py on a tiny subset (skipped
when the shared data are absent)."""

import importlib.util
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import SHARED_DATA

from franka_vs_gym.validation.results import Ambiguity, ModelChange, Selected
from franka_vs_gym.validation.scoring import AMBIGUOUS, CONFIDENT_WRONG, FLAGGED, MISSED, RIGHT, score_case
from franka_vs_gym.validation.structure import Finding, Unexplained

ROOT = Path(__file__).resolve().parents[1]
NOISE = np.full(7, 0.2)


def _evaluation():
    sys.path.insert(0, str(ROOT / "scripts"))
    spec = importlib.util.spec_from_file_location("evaluation", ROOT / "scripts" / "evaluation.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def answer(named=(), ambiguous=(), findings=(), changes=()):
    """A Diagnosis-like answer: named = [(effect, joints, params)], ambiguous = [(candidates, joints)],
    findings = [(joint, removed_rms)], changes = [(t, what)], read through the real result types."""
    sel = [Selected(e, list(js), dict(p), np.zeros(7), 1.0) for e, js, p in named]
    amb = [Ambiguity(list(c), list(js), {x: 0.0 for x in c}, "") for c, js in ambiguous]
    fs = [Finding(j, "q", r, 10.0) for j, r in findings]
    un = Unexplained(not fs, np.full(7, 0.3), NOISE.copy(), fs)
    ch = [ModelChange(t, what, {}, {}) for t, what in changes]
    return SimpleNamespace(selection=sel, ambiguous=amb, unexplained=un, changes=ch, noise_floor=NOISE.copy(),
                           explained=un.explained)


OFFSET3 = [{"effect": "torque_offset", "joints": [3], "offset_Nm": 0.5}]
BASE = answer(named=[("coulomb_friction", [1], {})])


@pytest.mark.parametrize("d, truth, word", [
    # the injected offset named on its joint, the untouched answer kept (a step law changed within its family)
    (answer(named=[("sigmoid_friction", [1], {}), ("torque_offset", [3], {})]), OFFSET3, RIGHT),
    # a wrong law on the injected joint, neither flagged nor said to be ambiguous: the example
    (answer(named=[("coulomb_friction", [1], {}), ("viscous_friction", [3], {})]), OFFSET3, CONFIDENT_WRONG),
    # the same name, but the answer says it cannot tell it from the offset there
    (answer(named=[("coulomb_friction", [1], {}), ("viscous_friction", [3], {})],
            ambiguous=[(["viscous_friction", "torque_offset"], [3])]), OFFSET3, AMBIGUOUS),
    # an "ambiguity" of four candidates does not count: the wrong name stands
    (answer(named=[("coulomb_friction", [1], {}), ("viscous_friction", [3], {})],
            ambiguous=[(["viscous_friction", "torque_offset", "armature", "delay"], [3])]), OFFSET3,
     CONFIDENT_WRONG),
    # the wrong name on a joint the answer flags as unexplained is not confident
    (answer(named=[("coulomb_friction", [1], {}), ("viscous_friction", [3], {})], findings=[(3, 0.2)]), OFFSET3,
     FLAGGED),
    # a finding no larger than the untouched copy's margin (0.25 noise floors) flags nothing
    (answer(named=[("coulomb_friction", [1], {}), ("viscous_friction", [3], {})], findings=[(3, 0.04)]), OFFSET3,
     CONFIDENT_WRONG),
    # nothing said at all
    (answer(named=[("coulomb_friction", [1], {})]), OFFSET3, MISSED),
    # the offset named, and a payload besides it: a shared effect named where none was injected
    (answer(named=[("coulomb_friction", [1], {}), ("torque_offset", [3], {}), ("payload", [0, 1, 2, 3], {})]),
     OFFSET3, CONFIDENT_WRONG),
    # a payload named with the injected mass (within 50 %) is right, with a third of it is not named right
    (answer(named=[("coulomb_friction", [1], {}), ("payload", [1, 3], {"mass_kg": 0.55})]),
     [{"effect": "payload", "joints": [1, 3], "mass_kg": 0.6}], RIGHT),
    (answer(named=[("coulomb_friction", [1], {}), ("payload", [1, 3], {"mass_kg": 0.2})]),
     [{"effect": "payload", "joints": [1, 3], "mass_kg": 0.6}], MISSED),
    # outside the library: flagged on its joint is the right answer; a library law in its place unflagged is not
    (answer(named=[("coulomb_friction", [1], {})], findings=[(5, 0.3)]),
     [{"effect": "cogging", "joints": [5]}], FLAGGED),
    (answer(named=[("coulomb_friction", [1], {}), ("torque_offset", [5], {})]),
     [{"effect": "cogging", "joints": [5]}], CONFIDENT_WRONG),
    # a grasp reported as a model change at its time, with a payload, is right
    (answer(named=[("coulomb_friction", [1], {}), ("payload", [1], {"mass_kg": 0.5})],
            changes=[(5.2, "a payload of 0.5 kg appears")]),
     [{"effect": "grasp", "joints": [1, 3], "t_s": 5.0, "mass_kg": 0.5}], RIGHT),
])
def test_scoring_words_on_hand_made_answers(d, truth, word):
    assert score_case(BASE, d, truth)["outcome"] == word


def test_binomial_intervals_are_clopper_pearson():
    """Exact (Clopper-Pearson) 95 % intervals: 3 of 10 -> 6.7-65.2 %, 0 of 12 -> 0-26.5 % (the rule of three's
    exact form 1 - 0.025^(1/12))."""
    ev = _evaluation()
    assert ev.interval(3, 10) == "3 (7-65 %)"
    assert ev.interval(0, 12) == f"0 (0-{100 * (1 - 0.025 ** (1 / 12)):.0f} %)"
    rows = [{"part": "locked", "recording": "r", "robot": "fr3", "rate": "30 Hz", "library": True,
             "outcome": o} for o in [RIGHT] * 3 + [MISSED] * 7]
    assert "| locked | r | fr3 | 30 Hz | library | 10 | 3 (7-65 %) |" in ev.table(rows)


def test_split_locks_two_labs_and_both_robots_apart_from_tuning():
    ev = _evaluation()
    split = json.loads((ROOT / "scripts" / "evaluation_split.json").read_text())
    rec = split["recordings"]

    def keys(part):
        return {(rec[e["recording"]]["path"], rec[e["recording"]].get("half"), r, s)
                for e in split["parts"][part] for r in e["rates"] for s in e["seeds"]}

    assert not keys("tuning") & keys("locked")
    locked = [rec[e["recording"]] for e in split["parts"]["locked"]]
    assert {r["robot"] for r in locked} == {"fer", "fr3"} and len({r["lab"] for r in locked}) >= 2
    assert any(r["path"].endswith("run_162853.csv") for r in locked)
    assert any(r["path"].endswith("joint_states.bag") and r.get("half") == "second" for r in locked)
    todo = ev.cases(split, ["tuning", "locked"], None, None, None, 1)  # first seeds only, seed-major
    assert {c["seed"] for c in todo} == {0, 1000} and {c["part"] for c in todo} == {"tuning", "locked"}


def test_evaluation_refuses_an_existing_output(tmp_path, capsys):
    out = tmp_path / "before.jsonl"
    out.write_text("kept\n")
    with pytest.raises(SystemExit) as e:
        _evaluation().main(["-o", str(out), "--max-seeds", "1"])
    assert e.value.code == 2 and out.read_text() == "kept\n"
    assert "exists" in capsys.readouterr().err


@pytest.mark.skipif(not (SHARED_DATA / "fer_joint_states_ros1" / "joint_states.bag").is_file(),
                    reason="the ROS 1 bag of the shared data is not available")
def test_evaluation_scores_a_small_subset(tmp_path, capsys):
    """One injected copy of the tuning half of the ROS 1 bag, end to end: an untouched line, a scored line."""
    out = tmp_path / "e.jsonl"
    assert _evaluation().main(["-o", str(out), "--parts", "tuning", "--recordings", "ros1_first", "--kinds",
                               "offset", "--max-seeds", "1", "--cpu-budget", "120"]) == 0
    rows = [json.loads(x) for x in out.read_text().splitlines()]
    assert [r["kind"] for r in rows] == ["untouched", "offset"]
    assert rows[1]["outcome"] in (RIGHT, AMBIGUOUS, CONFIDENT_WRONG, FLAGGED, MISSED)
    assert rows[1]["robot"] == "fer" and rows[1]["truth"][0]["effect"] == "torque_offset"
    assert "| tuning | ros1_first | fer | 30 Hz | library | 1 |" in capsys.readouterr().out
