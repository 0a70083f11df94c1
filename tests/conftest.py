import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def random_q(rng, n=1, margin=0.05):
    from franka_vs_gym.model import params

    lo, hi = params.as_array(params.Q_MIN) + margin, params.as_array(params.Q_MAX) - margin
    return rng.uniform(lo, hi, size=(n, 7))
