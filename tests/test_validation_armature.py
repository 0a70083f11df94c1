"""The workbench identifies the effective armature (the motors' inertia felt through the torque loop) from a log
with the commanded torque tau_J_d, and says it cannot from tau_J alone."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from franka_vs_gym.model import ModelConfig
from franka_vs_gym.model.description import FER
from franka_vs_gym.validation.effects import Armature, NotApplicable
from franka_vs_gym.validation.effects.base import Context
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.signals import clean


@pytest.fixture(scope="module")
def log():
    return make_hidden_effect_log("none", seed=1, duration=5.0)[0]  # the FER plant, torque-controlled


def test_effective_armature_from_the_commanded_torque(log):
    """The simulated FER carries FER.rotor_inertia between command and link: the fit recovers it per joint."""
    out = Armature.effective(Context(clean(log), ModelConfig()))
    np.testing.assert_allclose(out["effective_armature_kgm2"], FER.rotor_inertia, rtol=0.1)
    assert min(out["explained"]) > 0.8


def test_tau_J_only_log_is_refused_with_the_reason(log):
    bare = replace(log, tau_J_d=None)
    with pytest.raises(NotApplicable, match="tau_J_d"):
        Armature.effective(Context(clean(bare), ModelConfig()))
