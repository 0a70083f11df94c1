"""Evaluate a scripted policy or a trained agent on an environment, with the same numbers for both."""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np


def _make_env(env_id_or_env: Any, env_kwargs: dict[str, Any] | None) -> tuple[gym.Env, bool]:
    if isinstance(env_id_or_env, str):
        import franka_vs_gym  # noqa: F401  (registers the ids)

        if env_id_or_env.split(":")[-1] not in gym.registry:  # "module:EnvId" imports module first
            ours = [k for k in gym.registry if k.startswith("Franka")]
            raise ValueError(f"unknown environment id {env_id_or_env!r} (franka_vs_gym registers {ours})")
        return gym.make(env_id_or_env, **(env_kwargs or {})), True
    if isinstance(env_id_or_env, gym.Env):
        if env_kwargs:
            raise ValueError("env_kwargs can only be used with an environment id, not an environment instance")
        return env_id_or_env, False
    raise TypeError(f"env_id_or_env must be a registered id or a gymnasium.Env, got {type(env_id_or_env).__name__}")


def _action_fn(policy: Any) -> Callable[[Any], Any]:
    """A callable obs -> action for: SB3 models (``predict(obs, deterministic=True) -> (action, state)``), scripted
    policies with ``predict(obs) -> action`` or ``__call__(obs)``, and plain functions."""
    predict = getattr(policy, "predict", None)
    if predict is None:
        if callable(policy):
            return policy
        raise TypeError(f"policy must have a predict(obs) method or be callable, got {type(policy).__name__}")
    try:
        takes_det = "deterministic" in inspect.signature(predict).parameters
    except (TypeError, ValueError):
        takes_det = False

    def act(obs: Any) -> Any:
        out = predict(obs, deterministic=True) if takes_det else predict(obs)
        # SB3 returns (action, hidden_state)
        if isinstance(out, tuple) and len(out) == 2 and not np.isscalar(out[0]):
            out = out[0]
        return out

    return act


def evaluate(policy: Any, env_id_or_env: Any, n_episodes: int = 20, seed: int = 0, *,
             env_kwargs: dict[str, Any] | None = None, progress: bool = False) -> dict[str, Any]:
    """Run ``n_episodes`` episodes of ``policy`` and summarise them.

    Parameters
    ----------
    policy :
        A stable-baselines3 model, a scripted policy with ``predict(obs) -> action`` (e.g.
        ``franka_vs_gym.policies.IBVSPolicy``; its ``reset()`` is called at each episode start if it has one), or a
        function ``obs -> action``.
    env_id_or_env :
        A registered id (made with ``env_kwargs`` and closed afterwards) or an environment instance (possibly
        wrapped, e.g. with the action/observation wrappers the agent was trained with; not closed).
    n_episodes : int
        Number of episodes. Episode i is reset with seed ``seed + i``, so two policies evaluated with the same seed
        face the same initial conditions.
    progress : bool
        Print one line per episode.

    Returns
    -------
    dict with
        ``success_rate`` (fraction of episodes whose last step reports ``info["is_success"]``),
        ``mean_time_to_converge`` (s, over successful episodes: simulated time of the first step with
        ``is_success``; NaN if none), ``mean_final_error`` and ``median_final_error`` (the task error
        ``info["error"]`` at the last step: feature error, pose error or tracking error, see the env docstring),
        ``mean_return``, ``mean_length`` (steps), ``failures`` (reason -> count; the reason's text before its first
        ':'), and ``episodes`` (per-episode dicts; with ``rms_error`` where the task reports one).
    """
    if not isinstance(n_episodes, (int, np.integer)) or n_episodes < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    if not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    env, owned = _make_env(env_id_or_env, env_kwargs)
    try:
        episodes = run_episodes(policy, env, [int(seed) + i for i in range(int(n_episodes))], progress=progress)
    finally:
        if owned:
            env.close()
    return summarise(episodes)


def bind_policy(policy: Any, env: gym.Env) -> Any:
    """The policy acting in ``env``'s action space: a scripted policy or agent with physical outputs
    (``action_scale`` None and a ``with_action_scale`` method: franka_vs_gym.policies, AgentPolicy) gets the
    normalized outputs of the environment's ``action_scale``; anything else is returned as is."""
    scale = getattr(env.unwrapped, "action_scale", None)
    if scale is not None and hasattr(policy, "with_action_scale") and getattr(policy, "action_scale", 0) is None:
        return policy.with_action_scale(scale)
    return policy


def run_episodes(policy: Any, env: gym.Env, seeds: list[int], progress: bool = False) -> list[dict[str, Any]]:
    """One episode of ``policy`` per seed (``env.reset(seed=s)``); the per-episode dicts of :func:`evaluate`.
    Scripted policies and agents act in the environment's action space (:func:`bind_policy`)."""
    policy = bind_policy(policy, env)
    act = _action_fn(policy)
    reset = getattr(policy, "reset", None)
    episodes: list[dict[str, Any]] = []
    for i, s in enumerate(seeds):
        if callable(reset):
            reset()
        obs, info = env.reset(seed=int(s))
        ret, length, t_conv = 0.0, 0, math.nan
        done = False
        while not done:
            action = act(obs)
            obs, r, terminated, truncated, info = env.step(action)
            ret += float(r)
            length += 1
            if info.get("is_success") and math.isnan(t_conv):
                t_conv = float(info.get("time", math.nan))
            done = terminated or truncated
        ep = {"seed": int(s), "success": bool(info.get("is_success", False)), "return": ret,
              "length": length, "time": float(info.get("time", math.nan)),
              "final_error": float(info.get("error", math.nan)),
              "time_to_converge": t_conv if info.get("is_success") else math.nan,
              "failure": info.get("failure")}
        if info.get("rms_error") is not None:  # the tracking task's RMS error over the episode
            ep["rms_error"] = float(info["rms_error"])
        episodes.append(ep)
        if progress:
            status = "success" if ep["success"] else (ep["failure"] or "time limit")
            print(f"episode {i + 1}/{len(seeds)} seed {ep['seed']}: {status}, {length} steps, "
                  f"final error {ep['final_error']:.4g}, return {ret:.3f}", flush=True)
    return episodes


def summarise(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """The summary of :func:`evaluate` from its per-episode dicts (in seed order)."""
    if not episodes:
        raise ValueError("no episodes to summarise")
    succ = [e for e in episodes if e["success"]]
    failures: dict[str, int] = {}
    for e in episodes:
        if e["failure"]:
            key = str(e["failure"]).split(":")[0]
            failures[key] = failures.get(key, 0) + 1
    errs = np.array([e["final_error"] for e in episodes])
    return {
        "n_episodes": len(episodes),
        "success_rate": len(succ) / len(episodes),
        "mean_time_to_converge": float(np.mean([e["time_to_converge"] for e in succ])) if succ else math.nan,
        "mean_final_error": float(np.nanmean(errs)) if np.isfinite(errs).any() else math.nan,
        "median_final_error": float(np.nanmedian(errs)) if np.isfinite(errs).any() else math.nan,
        "mean_return": float(np.mean([e["return"] for e in episodes])),
        "mean_length": float(np.mean([e["length"] for e in episodes])),
        "failures": failures,
        "episodes": episodes,
    }
