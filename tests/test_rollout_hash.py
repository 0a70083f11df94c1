"""scripts/rollout_hash.py, the before/after check of speed work: a digest of a seeded rollout is reproducible and
changes with any output bit."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

_path = Path(__file__).parents[1] / "scripts" / "rollout_hash.py"
_spec = importlib.util.spec_from_file_location("rollout_hash", _path)
rollout_hash = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rollout_hash)


@pytest.mark.parametrize("env_id", ["FrankaTorqueTracking-v0", "FrankaIBVS-v0"])
def test_digest_is_reproducible_and_sees_every_change(env_id):
    d = rollout_hash.rollout_digest
    a = d(env_id, {}, 0, 15)
    assert a == d(env_id, {}, 0, 15)  # same code, same seed: same bits
    assert a != d(env_id, {}, 1, 15)  # another seed
    # a reward scale changed by 1e-10 (relative): only the low bits of the float64 rewards move
    scale = 0.1 if env_id == "FrankaTorqueTracking-v0" else 1.0
    assert a != d(env_id, {"error_scale": scale * (1 + 1e-10)}, 0, 15)
