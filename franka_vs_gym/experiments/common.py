"""Helpers shared by the experiments: run folders that never overwrite, progress bars, JSON metrics."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.io import atomic_write, track_run


def make_run_dir(name: str, out: str | Path | None = None, root: str | Path = "runs") -> Path:
    """Create a fresh output folder: ``out`` if given (it must not exist yet, or be empty), else
    ``<root>/<name>-<YYYYmmdd-HHMMSS UTC>`` (suffixed -2, -3... if taken). Nothing existing is overwritten.
    The folder is tracked as an unfinished run: if the command is interrupted it is renamed ``...-incomplete``
    (or removed when still empty)."""
    if out is not None:
        p = Path(out)
        if p.exists() and (not p.is_dir() or any(p.iterdir())):
            raise FileExistsError(f"output folder {p} exists and is not empty; choose another --out")
        p.mkdir(parents=True, exist_ok=True)
        track_run(p)
        return p
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise ValueError(f"{root} exists and is not a folder")
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    base = root / f"{name}-{stamp}"
    for k in range(1, 1000):
        p = base if k == 1 else base.with_name(f"{base.name}-{k}")
        try:
            p.mkdir(parents=True, exist_ok=False)
            track_run(p)
            return p
        except FileExistsError:
            continue
    raise FileExistsError(f"could not create a new run folder next to {base}")


def progress(total: int, desc: str, disable: bool = False):
    """A tqdm progress bar on stderr."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="step", file=sys.stderr, disable=disable, mininterval=0.5,
                dynamic_ncols=True)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def write_json(path: str | Path, data: dict[str, Any]) -> Path:
    return atomic_write(path, json.dumps(_jsonable(data), indent=2))
