"""The shipped pixel agent (franka_vs_gym/policies/agents/ibvs_pixels): it loads as every agent does, succeeds from
the camera image on seeded episodes it was neither trained nor selected on, and fails when the image is taken away."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

ROOT = Path(__file__).resolve().parents[1]
AGENT = ROOT / "franka_vs_gym" / "policies" / "agents" / "ibvs_pixels.zip"
SEEDS = 30_000  # not the held-out seeds 10000-10099 the checkpoint was chosen on, nor the training resets
N = 8


@pytest.fixture(scope="module")
def agent():
    import torch

    from franka_vs_gym.policies import load_agent

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a 16-keypoint CNN: one thread is fastest, and 10x faster than two on a busy machine
    yield load_agent("ibvs_pixels")
    torch.set_num_threads(threads)


def test_shipped_files_and_record():
    meta = json.loads(AGENT.with_suffix(".json").read_text())
    assert AGENT.stat().st_size < 5e6
    assert meta["observation_layout"] == "image-q-dq/1" and meta["env_kwargs"]["observation_type"] == "image"
    assert meta["evaluation"]["n_episodes"] == 100 and meta["evaluation"]["seed"] == 10_000
    assert "train_pixels.py" in meta["command"]
    assert meta["curve"] and meta["training"]["wall_s"] > 0


def test_sees_only_image_and_joints(agent):
    from franka_vs_gym.envs.pixels import IMAGE_KEYS

    assert set(agent.model.observation_space.spaces) == set(IMAGE_KEYS)
    with pytest.raises(ValueError, match="observation_type='image'"):
        agent.predict({"q": np.zeros(7), "dq": np.zeros(7), "features": np.zeros(8)})


def test_succeeds_from_the_image(agent):
    import franka_vs_gym

    r = franka_vs_gym.evaluate(agent, agent.env_id, N, SEEDS, env_kwargs=agent.env_kwargs)
    assert r["success_rate"] >= 0.75, r["failures"]


def test_fails_without_the_image(agent):
    """The same agent, the same episodes, the image replaced by a uniform grey frame: q and dq alone do not say
    where the tag is, so it must fail (the check above is about the image, not about the starting poses)."""
    import franka_vs_gym

    def blind(obs):
        return agent.predict(dict(obs, image=np.full_like(obs["image"], 128)))

    r = franka_vs_gym.evaluate(blind, agent.env_id, N, SEEDS, env_kwargs=agent.env_kwargs)
    assert r["success_rate"] <= 0.25


def test_spatial_softmax_is_the_expected_position():
    """One strongly peaked map per channel: the expected position is that pixel's centre on the [-1, 1] grid
    (numpy's linspace, an independent computation)."""
    import torch

    from franka_vs_gym.envs.pixels import SpatialSoftmax

    h, w = 24, 32
    rows, cols = [0, 5, 23], [31, 10, 0]
    x = torch.full((1, 3, h, w), -50.0)
    for c, (r, k) in enumerate(zip(rows, cols, strict=True)):
        x[0, c, r, k] = 50.0
    out = SpatialSoftmax(h, w)(x)[0].numpy()
    np.testing.assert_allclose(out[:3], np.linspace(-1, 1, w)[cols], atol=1e-5)
    np.testing.assert_allclose(out[3:], np.linspace(-1, 1, h)[rows], atol=1e-5)
