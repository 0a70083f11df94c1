"""Lack-of-fit test of the selected effects (franka_vs_gym/validation/lackfit.py), on the independent generator
(tests/independent_logs.py): a law that does not have the shape its own variable shows is kept only as the closest
library effect (``lack_of_fit`` in the JSON, ``explained: false``); a correct law plus noise is not flagged."""

from __future__ import annotations

import pytest
from independent_logs import make_log

from franka_vs_gym.validation.diagnose import diagnose


def test_a_law_of_the_wrong_shape_is_marked_as_lack_of_fit():
    # a Coulomb step offered only a viscous line: the line is the closest candidate, not the answer
    log, _ = make_log(["coulomb"], 0, duration=8.0)
    d = diagnose(log, effects=["viscous_friction"])
    assert d.selected == ["viscous_friction"]
    assert not d.explained
    lof = d.to_dict()["selected"][0]["lack_of_fit"]
    assert lof["status"] == "closest library effect, lack of fit"
    assert len(lof["joints"]) >= 3 and all(t["score"] > t["threshold"] for t in lof["tests"])
    assert any("viscous_friction is only the closest library effect" in s for s in d.unexplained.text)


@pytest.mark.parametrize("effects", [["viscous"], ["coulomb"], ["payload"], ["delay"], []])
def test_correct_laws_plus_noise_are_not_flagged(effects):
    d = diagnose(make_log(effects, 1, duration=8.0)[0])
    assert all(not s.lack_of_fit for s in d.selection), [s.to_dict() for s in d.selection]
    assert "lack_of_fit" not in str(d.to_dict()["selected"])
