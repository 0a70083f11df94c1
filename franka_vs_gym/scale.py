"""Past one machine: evaluation episodes and workbench logs spread over a Ray cluster (the ``[scale]`` extra).

Ray does the distribution; this module only cuts the work into independent pieces and gathers the results in the
order a serial run produces them, so a distributed run gives the same table as a serial one:

- :func:`evaluate_distributed`: episodes of a policy (seed ``seed + i``, randomised dynamics drawn from that seed
  as in :func:`franka_vs_gym.evaluate`) in chunks of consecutive seeds, one Ray task per chunk, each building its
  own policy and environment; the summary is :func:`franka_vs_gym.envs.evaluate.summarise` of the episodes in seed
  order. ``franka-vs evaluate ... --ray [ADDRESS]``.
- :func:`diagnose_folder`: the workbench's public ``diagnose`` (and, with ``fit=True``, ``fit_effects(log,
  ["auto"])``) on every log of a folder, one Ray task per log. ``franka-vs diagnose-folder FOLDER [--ray ADDRESS]``.

Without an address a local Ray instance is started (``num_cpus`` of this machine's CPUs) and stopped afterwards;
with one (``"auto"`` or ``"ray://head:10001"``) the work runs on that cluster, whose nodes need franka_vs_gym
installed (or a ``runtime_env``), as any Ray job does.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

# files the workbench reads as logs (load_log detects the format from the content); folders: rosbag2 bags and Gaz et
# al. 2019 text folders
LOG_SUFFIXES = (".csv", ".npz", ".npy", ".json", ".jsonl", ".ndjson", ".pkl", ".pickle", ".bag", ".mcap", ".db3")


def _ray():
    try:
        import ray
    except ImportError:
        from franka_vs_gym.errors import UserError

        raise UserError("distributed runs need Ray: pip install -e '.[scale]'") from None
    return ray


@contextlib.contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None) -> Iterator[Any]:
    """Connect to the Ray cluster at ``address``, or start a local instance (``num_cpus`` CPUs) when it is None;
    a session this function started is shut down at the end. An already initialised Ray is used as it is."""
    ray = _ray()
    if ray.is_initialized():
        yield ray
        return
    env = {"env_vars": {k: os.environ[k] for k in ("PYTHONPATH", "MUJOCO_GL") if k in os.environ}}
    if address:
        ray.init(address=address, runtime_env=env, log_to_driver=False)
    else:
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, runtime_env=env)
    try:
        yield ray
    finally:
        ray.shutdown()


def _episode_chunk(policy_factory: Callable[[], Any], env_id: str, env_kwargs: dict[str, Any],
                   seeds: list[int]) -> list[dict[str, Any]]:
    """Run the episodes of ``seeds`` in one process (a Ray task): one policy, one environment."""
    import gymnasium as gym

    import franka_vs_gym  # noqa: F401  (registers the ids in the worker)
    from franka_vs_gym.envs.evaluate import run_episodes

    policy = policy_factory()
    env = gym.make(env_id, **env_kwargs)
    try:
        return run_episodes(policy, env, seeds)
    finally:
        env.close()


def evaluate_distributed(policy_factory: Callable[[], Any], env_id: str, n_episodes: int = 20, seed: int = 0, *,
                         env_kwargs: dict[str, Any] | None = None, address: str | None = None,
                         num_cpus: int | None = None, chunk: int | None = None,
                         progress: bool = False) -> dict[str, Any]:
    """:func:`franka_vs_gym.evaluate` over a Ray cluster: the same summary and episodes as the serial run.

    Parameters
    ----------
    policy_factory : callable
        A picklable zero-argument function returning the policy (policies holding compiled models need not be
        picklable: each task builds its own).
    env_id, n_episodes, seed, env_kwargs :
        As :func:`franka_vs_gym.evaluate` (episode i is reset with seed ``seed + i``).
    address : str or None
        A Ray cluster address, or None for a local instance of ``num_cpus`` CPUs.
    chunk : int or None
        Episodes per task (default: the episodes split in about 4 tasks per CPU).
    """
    from franka_vs_gym.envs.evaluate import summarise

    if not isinstance(n_episodes, int) or n_episodes < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    if not isinstance(seed, int):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    seeds = [seed + i for i in range(n_episodes)]
    with ray_session(address, num_cpus) as ray:
        if chunk is None:
            cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
            chunk = max(1, math.ceil(n_episodes / (4 * cpus)))
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        task = ray.remote(num_cpus=1)(_episode_chunk)
        pieces = [seeds[i:i + chunk] for i in range(0, n_episodes, chunk)]
        refs = [task.remote(policy_factory, env_id, dict(env_kwargs or {}), p) for p in pieces]
        episodes: list[dict[str, Any]] = []
        pending = list(refs)
        done_count = 0
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            done_count += 1
            if progress:
                print(f"evaluate: {done_count}/{len(refs)} chunks done", flush=True)
        for ref in refs:  # in seed order, as the serial run
            episodes.extend(ray.get(ref))
    return summarise(episodes)


def find_logs(folder: str | os.PathLike) -> list[Path]:
    """The measurement logs directly in ``folder``, sorted by name: files with a suffix of :data:`LOG_SUFFIXES`
    (without the JSON metadata of another log: its sidecar ``<log>.json`` / ``<stem>.json`` or a generator's
    ``<log>.answer.json``), rosbag2 folders and Gaz et al. 2019 text folders."""
    from franka_vs_gym.validation.logs import GAZ_FILES
    from franka_vs_gym.validation.readers import is_rosbag

    p = Path(folder)
    if not p.is_dir():
        raise FileNotFoundError(f"not a folder: {p}")
    entries = sorted(p.iterdir())
    files = [f for f in entries if f.is_file() and f.suffix.lower() in LOG_SUFFIXES]
    data = [f for f in files if f.suffix.lower() != ".json"]
    meta = {f.name + ".json" for f in data} | {f.stem + ".json" for f in data}
    logs = [f for f in files if f.suffix.lower() != ".json"
            or not (f.name in meta or any(f.name.startswith(d.name + ".") for d in data))]
    logs += [d for d in entries if d.is_dir() and (is_rosbag(d) or (d / GAZ_FILES["time"]).is_file())]
    if not logs:
        raise FileNotFoundError(f"no measurement logs ({', '.join(LOG_SUFFIXES)}, ROS 2 bag or Gaz et al. folders) "
                                f"in {p}")
    return sorted(logs)


def _diagnose_one(path: str, model: Any, fit: bool, rigid_body: bool, robot: Any = None,
                  tool: str | None = None) -> dict[str, Any]:
    """The workbench's diagnose (and fit) of one log, as JSON-ready values (runs in a Ray task)."""
    from franka_vs_gym.errors import UserError
    from franka_vs_gym.validation import diagnose, fit_effects
    from franka_vs_gym.validation.loading import load_log

    try:
        log = load_log(path, tool=tool)
        d = diagnose(log, model, rigid_body=rigid_body, robot=robot, tool=tool)
        out: dict[str, Any] = {"log": path, "diagnosis": d.to_dict()}
        if fit:
            f = fit_effects(log, ["auto"], model, rigid_body=rigid_body, robot=robot, tool=tool)
            out["fit"] = f.to_dict() | {"config": f.after.to_dict()}
    except (ValueError, FileNotFoundError, UserError) as e:  # a log the workbench refuses: said, the folder goes on
        return {"log": path, "error": str(e)}
    return out


def diagnose_folder(folder: str | os.PathLike, model: Any = None, *, fit: bool = False, rigid_body: bool = False,
                    address: str | None = None, num_cpus: int | None = None, use_ray: bool = True,
                    progress: bool = False, robot: Any = None, tool: str | None = None) -> list[dict[str, Any]]:
    """Diagnose (and with ``fit`` also fit) every log of ``folder`` in parallel on Ray (``use_ray=False``: one after
    the other in this process, the same results); one result per log, in file-name order:
    ``{"log", "diagnosis": Diagnosis.to_dict(), "fit": FitResult.to_dict() + {"config"}}``, or ``{"log", "error"}``
    (the one-line reason) for a log the workbench refuses, so one bad file does not stop the folder. ``robot`` and
    ``tool`` are ``--robot`` and ``--tool`` of ``diagnose``: they override what each log declares."""
    if tool is not None:
        from franka_vs_gym.validation.compare import TOOLS

        if tool not in TOOLS:
            raise ValueError(f"unknown --tool {tool!r}: choose from {', '.join(TOOLS)}")
    if robot is not None:
        from franka_vs_gym.model.description import robot_description

        robot = robot_description(robot).name  # an unknown name is refused before any log is read
    logs = [str(p) for p in find_logs(folder)]
    if not use_ray:
        out = []
        for n, p in enumerate(logs):
            out.append(_diagnose_one(p, model, fit, rigid_body, robot, tool))
            if progress:
                print(f"diagnose: {n + 1}/{len(logs)} logs done", flush=True)
        return out
    with ray_session(address, num_cpus) as ray:
        task = ray.remote(num_cpus=1)(_diagnose_one)
        refs = [task.remote(p, model, fit, rigid_body, robot, tool) for p in logs]
        pending, n = list(refs), 0
        while pending:
            _, pending = ray.wait(pending, num_returns=1)
            n += 1
            if progress:
                print(f"diagnose: {n}/{len(refs)} logs done", flush=True)
        return [ray.get(r) for r in refs]


__all__ = ["diagnose_folder", "evaluate_distributed", "find_logs", "ray_session"]


# ---------------------------------------------------------------------- franka-vs diagnose-folder
def add_arguments(parser: Any) -> None:
    parser.add_argument("folder", help="folder of measurement logs (CSV, NPZ, robot-state dumps, ROS bags, Gaz et al. "
                        "folders)")
    parser.add_argument("--model", default=None, help="calibrated model file to start from (default: each log's "
                        "baseline)")
    parser.add_argument("--fit", action="store_true", help="also fit the diagnosed effects (fit --add auto)")
    parser.add_argument("--rigid-body", action="store_true", help="start from the rigid-body model (no friction)")
    parser.add_argument("--robot", default=None,
                        help="the robot every log comes from (fer, fr3, ...): overrides what the logs declare")
    parser.add_argument("--tool", choices=("franka_hand", "none", "unknown"), default=None,
                        help="the tool on the flange in every log (default: what each log declares); 'unknown' fits "
                             "the tool's mass, centre of mass and inertia")
    parser.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                        help="Ray cluster address; without one (or without --ray when Ray is installed) a local Ray "
                        "instance; without --ray and without Ray, the logs one after the other")
    parser.add_argument("--ray-cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")
    parser.add_argument("--json", default=None, help="write every log's result to this JSON file")
    parser.add_argument("--force", action="store_true", help="replace the --json file if it exists")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def main(args: Any) -> int:
    import json

    from franka_vs_gym.io import atomic_write, check_output

    if args.json:
        check_output(args.json, force=args.force)  # refuse an existing file before the work, not after
    import importlib.util

    use_ray = args.ray is not None or importlib.util.find_spec("ray") is not None
    res = diagnose_folder(args.folder, args.model, fit=args.fit, rigid_body=args.rigid_body,
                          address=args.ray or None, num_cpus=args.ray_cpus, use_ray=use_ray,
                          progress=not args.quiet, robot=args.robot, tool=args.tool)
    for r in res:
        if "error" in r:
            print(f"{Path(r['log']).name}: not diagnosed: {r['error']}")
            continue
        d = r["diagnosis"]
        line = f"{Path(r['log']).name}: verdict {d['verdict']}, RMSE {d['rmse_tau_total']:.3f} Nm"
        if "fit" in r:
            line += (f" -> {r['fit']['rmse_tau_total_after']:.3f} Nm after fitting "
                     f"{','.join(r['fit']['effects']) or 'nothing'}")
        print(line)
    if args.json:
        atomic_write(args.json, json.dumps(res, indent=2), force=args.force)
        print(f"wrote {args.json}")
    return 1 if any("error" in r for r in res) else 0
