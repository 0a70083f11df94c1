"""The network of the pixel agent: the wrist camera image (and q, dq) in, a joint-velocity action out.

A stable-baselines3 features extractor (``MultiInputPolicy`` on the ``observation_type="image"`` observation:
``image`` (H, W, 3) uint8, ``q``, ``dq``), so the agent is saved, loaded and evaluated as any SB3 agent:

    image --gray--> conv 5x5/2 (8) --relu--> conv 3x3 (16) --relu--> conv 3x3 (K) --spatial softmax--> K keypoints
    keypoints --MLP--> estimated tag corners s^ (8, normalized coordinates) and corner depths Z^ (4, m)
    [4 e^, e^/(|e^| + 0.005), log10(|e^| + 0.001)/3, s^, 5 (Z^ - Z*), keypoints, q, 0.5 dq]   with e^ = s^ - s*

The spatial softmax (the expected image position of each keypoint map, Levine et al., "End-to-end training of
deep visuomotor policies", JMLR 17, 2016) gives positions finer than a pixel; the estimated corners are trained
against the true corners while the policy is trained (``baselines/train_pixels.py``: an auxiliary loss, labels used
at training time only), and the policy's MLP then reads the same error terms as the features agent
(:func:`franka_vs_gym.envs.wrappers.servo_vector`). At run time the agent sees only the image, q and dq. Needs the
``[rl]`` extra.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from franka_vs_gym.envs.wrappers import IMAGE_LAYOUT  # the layout recorded in the agent's JSON sidecar

IMAGE_KEYS = ("image", "q", "dq")
_GRAY = (0.299, 0.587, 0.114)  # ITU-R BT.601 luma weights


class SpatialSoftmax(nn.Module):
    """(B, C, H, W) maps -> (B, 2C) expected (x, y) of each channel's softmax, in [-1, 1] (pixel centres)."""

    def __init__(self, height: int, width: int) -> None:
        super().__init__()
        self.register_buffer("xs", torch.linspace(-1.0, 1.0, width), persistent=False)
        self.register_buffer("ys", torch.linspace(-1.0, 1.0, height), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, h, w = x.shape
        p = torch.softmax(x.reshape(b, c, h * w), dim=-1).reshape(b, c, h, w)
        return torch.cat([(p.sum(2) * self.xs).sum(-1), (p.sum(3) * self.ys).sum(-1)], dim=1)


class PixelServoExtractor(BaseFeaturesExtractor):
    """Image + q + dq -> the feature vector of the module docstring (see there).

    Parameters
    ----------
    observation_space : Dict with ``image`` (channel-first after SB3's transpose, or channel-last), ``q``, ``dq``
    goal_features : the desired corners s* (8,) of the environment (``env.unwrapped.features_desired``)
    goal_depth : the desired corner depth Z* (m)
    keypoints : number K of keypoint maps
    """

    def __init__(self, observation_space: spaces.Dict, goal_features: Any = None, goal_depth: float = 0.2,
                 keypoints: int = 16) -> None:
        if not isinstance(observation_space, spaces.Dict) or any(k not in observation_space.spaces
                                                                  for k in IMAGE_KEYS):
            raise ValueError(f"PixelServoExtractor needs a Dict observation space with keys {IMAGE_KEYS}")
        shape = observation_space["image"].shape
        if shape[0] == 3:
            h, w = shape[1], shape[2]
        elif shape[-1] == 3:
            h, w = shape[0], shape[1]
        else:
            raise ValueError(f"the image must have 3 channels, got shape {shape}")
        if goal_features is None or np.shape(goal_features) != (8,):
            raise ValueError("goal_features (the 8 desired corner coordinates) are needed")
        k = int(keypoints)
        super().__init__(observation_space, 8 + 8 + 1 + 8 + 4 + 2 * k + 14)
        self.register_buffer("gray", torch.tensor(_GRAY, dtype=torch.float32).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("s_star", torch.tensor(np.asarray(goal_features, np.float32)), persistent=False)
        self.z_star = float(goal_depth)
        self.conv = nn.Sequential(
            nn.Conv2d(1, 8, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(8, 16, 3, padding=1), nn.ReLU(),
            nn.Conv2d(16, k, 3, padding=1))
        self.softmax = SpatialSoftmax((h + 1) // 2, (w + 1) // 2)
        self.estimate = nn.Sequential(nn.Linear(2 * k, 128), nn.ReLU(), nn.Linear(128, 12))

    def parts(self, image: torch.Tensor, q: torch.Tensor, dq: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """(features, estimated corners (B, 8), estimated depths (B, 4)) from a channel-first image in [0, 1]."""
        g = (image * self.gray).sum(1, keepdim=True)
        kp = self.softmax(self.conv(g))
        out = self.estimate(kp)
        s = self.s_star + out[:, :8]
        z = self.z_star + 0.1 * out[:, 8:]
        e = s - self.s_star
        n = torch.sqrt((e * e).sum(1, keepdim=True) + 1e-12)
        feats = torch.cat([4.0 * e, e / (n + 0.005), torch.log10(n + 0.001) / 3.0, s, 5.0 * (z - self.z_star), kp,
                           q, 0.5 * dq], dim=1)
        return feats, s, z

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        image = observations["image"]
        if image.shape[1] != 3:  # channel-last (an observation space SB3 did not transpose)
            image = image.permute(0, 3, 1, 2)
        return self.parts(image, observations["q"], observations["dq"])[0]


def image_observation(obs: dict[str, Any]) -> dict[str, np.ndarray]:
    """The keys the pixel agent sees (image, q, dq) of a contract observation; a clear error if the image is
    missing."""
    if "image" not in obs:
        raise ValueError("the pixel agent needs the camera image: make the environment with "
                         "observation_type='image' (or 'features+image')")
    return {k: obs[k] for k in IMAGE_KEYS}


__all__ = ["IMAGE_KEYS", "IMAGE_LAYOUT", "PixelServoExtractor", "SpatialSoftmax", "image_observation"]
