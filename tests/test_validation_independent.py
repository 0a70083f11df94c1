"""The workbench judged on an independent generator (tests/independent_logs.py: inverse dynamics of its own
trajectories, its own effect laws, its own noise; randomised magnitudes): the right set of effects for single and
compound library-type effects, ``explained: false`` for effects outside the library, ``none`` on clean logs.
The larger study (more seeds, low rates) is scripts/workbench_study.py; its table is in docs/workbench/evidence.md."""

from __future__ import annotations

import numpy as np
import pytest
from independent_logs import ACCEPT, make_log, score

from franka_vs_gym.validation.diagnose import diagnose

CLEAN = [0, 1]
LIBRARY = [["viscous"], ["coulomb"], ["armature"], ["offset"], ["payload"], ["tilt"], ["delay"],
           ["payload", "viscous"], ["coulomb", "tilt", "armature"], ["offset", "delay"]]
OUTSIDE = [["cogging"], ["drift"], ["disturbance"], ["cogging", "viscous"]]


@pytest.mark.parametrize("seed", CLEAN)
def test_clean_logs_give_none_and_explained(seed):
    d = diagnose(make_log([], seed, duration=8.0)[0])
    assert d.verdict == "none" and d.selection == [] and d.explained, d.unexplained.text


@pytest.mark.parametrize("effects", LIBRARY, ids=["+".join(e) for e in LIBRARY])
def test_library_type_effects_are_all_named_and_fit_to_the_floor(effects):
    log, truth = make_log(effects, 3, duration=8.0)
    d = diagnose(log)
    s = score(effects, d)
    assert s["ok"], (s, d.notes)
    assert np.all(d.rmse_tau_selected <= 1.1 * d.noise_floor), d.rmse_tau_selected / d.noise_floor
    assert d.explained, d.unexplained.text
    # the verdict is one of the hidden effects, and each selected effect removes error where it acts
    assert any(d.verdict in ACCEPT[e] for e in effects)
    assert all(s_.contribution.max() > 0 for s_ in d.selection)


@pytest.mark.parametrize("effects", OUTSIDE, ids=["+".join(e) for e in OUTSIDE])
def test_effects_outside_the_library_are_reported_unexplained(effects):
    log, truth = make_log(effects, 4, duration=8.0)
    d = diagnose(log)
    s = score(effects, d)
    assert s["ok"], (s, d.unexplained.text)
    text = " ".join(d.unexplained.text)
    js = d.unexplained.joints
    assert js and "above the noise floor" in text
    if effects[0] in ("cogging", "disturbance"):
        # the joints it names are joints where the effect acts, and it says what the residual follows
        assert set(js) & set(truth["params"][effects[0]]["joints"])
        expect = "periodic function of the joint position" if effects[0] == "cogging" else "periodic disturbance"
        assert expect in text
    if effects[0] == "drift":
        assert "drifts over time" in text
