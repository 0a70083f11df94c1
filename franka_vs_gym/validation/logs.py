"""Measurement logs of a FER: the data class, the file formats, and their validation.

A :class:`MeasurementLog` holds what libfranka's ``RobotState`` gives at each control tick, with its field names:

=========================  ========  ==========================================================================
field                      unit      meaning
=========================  ========  ==========================================================================
``time``                   s         (N,) sample times, non-decreasing (repeats are allowed in raw logs)
``q``                      rad       (N, 7) measured joint positions
``dq``                     rad/s     (N, 7) measured joint velocities
``tau_J``                  Nm        (N, 7) measured link-side joint torques, gravity included
``tau_J_d``                Nm        (N, 7) optional: commanded joint torques, gravity-free (as sent to libfranka)
``q_d``, ``dq_d``          rad, /s   (N, 7) optional: desired trajectory
``ddq_d``                  rad/s^2   (N, 7) optional: desired acceleration
``tau_ext_hat_filtered``   Nm        (N, 7) optional: the robot's external-torque estimate
=========================  ========  ==========================================================================

plus metadata: ``tool`` (``"franka_hand"``, ``None`` for no tool, or a ``{"mass", "com", "inertia"}`` dict in the
flange frame), ``gravity`` (3,) in the base frame (m/s^2), ``controller`` (a free-form dict, e.g. eq. (2) and its
gains) and ``extra`` (any other JSON-able metadata).

File formats (read by :func:`~franka_vs_gym.validation.loading.load_log`, written by :func:`save_log`):

- CSV with a header row. Columns ``time``, then ``q[i]``, ``dq[i]``, ``tau_J[i]`` for i = 0..6, and optionally the
  other fields with the same ``name[i]`` pattern. ``name_i`` is accepted instead of ``name[i]`` when reading.
  Metadata lives in a JSON sidecar next to the log: ``<log>.json`` (``run.csv`` -> ``run.csv.json``); the sidecar
  ``run.json`` is accepted too when reading.
- NPZ with arrays ``time`` (N,) and ``q``, ``dq``, ``tau_J`` ... (N, 7); metadata in the same JSON sidecar, or in an
  array ``meta`` holding a JSON string.
- The text folder of Gaz et al. 2019 (``exciting_traj_time.txt``, ``exciting_traj_positions.txt``,
  ``exciting_traj_velocity.txt``, ``exciting_traj_torques.txt``; values sample-major, one or more per line). No
  tool is declared for these logs.

Loading never modifies the input file. Malformed input raises ``ValueError`` naming the problem: missing columns,
wrong joint count, NaN/inf values, decreasing time, implausible units (degrees, milliseconds, mNm).
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym import io
from franka_vs_gym.model.description import FER, GRAVITY

REQUIRED = ("q", "dq", "tau_J")
OPTIONAL = ("tau_J_d", "q_d", "dq_d", "ddq_d", "tau_ext_hat_filtered")
JOINT_FIELDS = REQUIRED + OPTIONAL
GAZ_FILES = {"time": "exciting_traj_time.txt", "q": "exciting_traj_positions.txt",
             "dq": "exciting_traj_velocity.txt", "tau_J": "exciting_traj_torques.txt"}
_COL = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*?)(?:\[(\d+)\]|_(\d+))\s*$")
_TOOL_DEFAULT = "franka_hand"


@dataclass
class MeasurementLog:
    """One measurement log of a FER (see the module docstring for fields, units and frames).

    Attributes
    ----------
    time : (N,) s
    q, dq, tau_J : (N, 7) rad, rad/s, Nm (tau_J includes gravity)
    tau_J_d, q_d, dq_d, ddq_d, tau_ext_hat_filtered : (N, 7) or None
    tool : "franka_hand", None (no tool) or dict(mass, com, inertia) in the flange frame
    gravity : (3,) m/s^2 in the base frame
    controller : dict or None (e.g. ``{"law": "computed_torque_eq2", "kp": [...], "kd": [...]}``)
    extra : dict of any other JSON-able metadata
    source : where the log was read from ("" for logs built in memory)
    """

    time: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau_J: np.ndarray
    tau_J_d: np.ndarray | None = None
    q_d: np.ndarray | None = None
    dq_d: np.ndarray | None = None
    ddq_d: np.ndarray | None = None
    tau_ext_hat_filtered: np.ndarray | None = None
    tool: Any = _TOOL_DEFAULT
    gravity: np.ndarray = field(default_factory=lambda: np.array(GRAVITY, dtype=np.float64))
    controller: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    tool_declared: bool = True

    def __post_init__(self) -> None:
        self.time = np.array(self.time, dtype=np.float64)
        if self.time.ndim != 1:
            raise ValueError(f"time must be a 1-D array, got shape {self.time.shape}")
        n = len(self.time)
        if n < 2:
            raise ValueError(f"a log needs at least 2 samples, got {n}")
        for name in JOINT_FIELDS:
            v = getattr(self, name)
            if v is None:
                if name in REQUIRED:
                    raise ValueError(f"missing required field {name!r}")
                continue
            a = np.array(v, dtype=np.float64)
            if a.ndim != 2 or a.shape[0] != n:
                raise ValueError(f"{name} must have shape ({n}, 7), got {a.shape}")
            if a.shape[1] != 7:
                raise ValueError(f"{name} has {a.shape[1]} joints; the FER has 7 (expected shape ({n}, 7))")
            setattr(self, name, a)
        self.gravity = np.array(self.gravity, dtype=np.float64)
        if self.gravity.shape != (3,) or not np.isfinite(self.gravity).all():
            raise ValueError(f"gravity must be a finite 3-vector (m/s^2, base frame), got {self.gravity}")
        validate(self)

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.time)

    @property
    def duration(self) -> float:
        """Time span of the log, s."""
        return float(self.time[-1] - self.time[0])

    def fields(self) -> list[str]:
        """Names of the joint fields present, required first."""
        return [f for f in JOINT_FIELDS if getattr(self, f) is not None]

    def metadata(self) -> dict[str, Any]:
        """The sidecar content (JSON-able)."""
        tool = self.tool
        if isinstance(tool, dict):
            tool = {k: np.asarray(v).tolist() if not isinstance(v, str) else v for k, v in tool.items()}
        return {"tool": tool, "gravity": self.gravity.tolist(), "controller": self.controller, **self.extra}

    def slice(self, start: int, stop: int) -> MeasurementLog:
        """A new log with samples [start, stop)."""
        kw = {f: (None if getattr(self, f) is None else getattr(self, f)[start:stop].copy()) for f in JOINT_FIELDS}
        return MeasurementLog(self.time[start:stop].copy(), **kw, tool=self.tool, gravity=self.gravity.copy(),
                              controller=self.controller, extra=dict(self.extra), source=self.source,
                              tool_declared=self.tool_declared)


#: the longest median time step read as seconds: 2 Hz. A step of 1 (a sample index, or milliseconds at 1 kHz) is
#: not seconds; one of 0.05-0.5 s is a slow recording (a ROS topic at 2-20 Hz), not milliseconds (2-20 kHz)
MAX_STEP_S = 0.5
Q_RANGE_MARGIN = 0.5  # rad beyond the joint range that no arm reaches (its hard stops are a few degrees out): refused
Q_RANGE_WARN = 0.05  # rad beyond the range that is warned about (a position past the soft limits)


def joint_range() -> tuple[np.ndarray, np.ndarray]:
    """The widest joint range of the registered robots (FER, FR3, ...), (7,) rad each: where a logged arm can be."""
    from franka_vs_gym.model.description import ROBOTS

    lo = np.min([np.asarray(r.limits.q_min, dtype=float) for r in ROBOTS.values()], axis=0)
    hi = np.max([np.asarray(r.limits.q_max, dtype=float) for r in ROBOTS.values()], axis=0)
    return lo, hi


def validate(log: MeasurementLog) -> None:
    """Raise ValueError naming the first problem found: NaN/inf, decreasing time, implausible units."""
    t = log.time
    bad = ~np.isfinite(t)
    if bad.any():
        raise ValueError(f"time contains NaN or inf (first at row {int(np.argmax(bad))})")
    dt = np.diff(t)
    if (dt < 0).any():
        i = int(np.argmax(dt < 0))
        raise ValueError(f"time is not monotonic: it decreases from {t[i]:.6g} s to {t[i + 1]:.6g} s at row {i + 1}")
    if t[-1] - t[0] <= 0:
        raise ValueError("time does not advance: all timestamps are equal")
    for name in log.fields():
        a = getattr(log, name)
        bad = ~np.isfinite(a)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise ValueError(f"{name}[{c}] contains NaN or inf (first at row {r}, time {t[r]:.6g} s)")
    pos = dt[dt > 0]
    med = float(np.median(pos)) if len(pos) else 0.0
    if med >= MAX_STEP_S:
        raise ValueError(f"time step is {med:.3g} (median): the time column looks like milliseconds or a "
                         "sample index, it must be in seconds (about 0.001 s at 1 kHz)")
    for name in ("q", "q_d"):
        a = getattr(log, name)
        if a is not None and np.abs(a).max() > 2 * math.pi:
            j = int(np.argmax(np.abs(a).max(axis=0)))
            raise ValueError(f"{name}[{j}] reaches {np.abs(a[:, j]).max():.4g}: joint positions must be in rad "
                             f"(the FER joint range is within [{FER.limits.q_min[j]}, {FER.limits.q_max[j]}] rad); "
                             "degrees?")
    lo, hi = joint_range()
    for name in ("q", "q_d"):  # the arm cannot be there: another robot, an encoder offset, or columns mixed up
        a = getattr(log, name)
        if a is None:
            continue
        out = (a < lo - Q_RANGE_MARGIN) | (a > hi + Q_RANGE_MARGIN)
        if out.any():
            r, j = (int(x) for x in np.argwhere(out)[0])
            raise ValueError(f"{name}[{j}] is {a[r, j]:.4g} rad at row {r} (time {t[r]:.6g} s), outside the joint's "
                             f"range [{lo[j]:.4g}, {hi[j]:.4g}] rad (every registered robot's): an encoder offset, "
                             "another robot's log, or the joint columns in another order?")
    dq_max = FER.limit_arrays()["dq_max"]
    for name in ("dq", "dq_d"):
        a = getattr(log, name)
        if a is not None and (np.abs(a) > 3 * dq_max).any():
            j = int(np.argmax((np.abs(a) / dq_max).max(axis=0)))
            raise ValueError(f"{name}[{j}] reaches {np.abs(a[:, j]).max():.4g}: joint velocities must be in rad/s "
                             f"(FER limit {dq_max[j]} rad/s); degrees/s?")
    tau_max = FER.limit_arrays()["tau_max"]
    for name in ("tau_J", "tau_J_d"):
        a = getattr(log, name)
        if a is not None and (np.abs(a) > 5 * tau_max).any():
            j = int(np.argmax((np.abs(a) / tau_max).max(axis=0)))
            raise ValueError(f"{name}[{j}] reaches {np.abs(a[:, j]).max():.4g}: torques must be in Nm "
                             f"(FER limit {tau_max[j]} Nm); mNm?")


# ----------------------------------------------------------------------------------------------- reading
def sidecar_path(path: str | os.PathLike) -> Path:
    """The JSON sidecar of a log file: ``<log>.json``."""
    p = Path(path)
    return p.with_name(p.name + ".json")


def metadata_file(log: MeasurementLog) -> str:
    """The file a log's metadata was read from, for messages: its sidecar when there is one, else the log."""
    if not log.source:
        return "the log's metadata"
    p = Path(log.source)
    for s in (sidecar_path(p), p.with_suffix(".json"), p / "log.json"):
        if s != p and os.path.isfile(s):
            return str(s)
    return str(p)


def _meta_where(p: Path) -> str:
    """The sidecar a log's metadata was read from (for messages), else the log itself."""
    q = p / "log" if p.is_dir() and not os.path.isfile(p / "metadata.yaml") else p
    for s in (sidecar_path(q), q.with_suffix(".json")):
        if s != p and os.path.isfile(s):
            return str(s)
    return str(p)


def _read_sidecar(path: Path) -> dict[str, Any]:
    for s in (sidecar_path(path), path.with_suffix(".json")):
        if os.path.lexists(s) and s != path:
            try:
                d = io.loads_json(io.read_text(s, what="sidecar"), f"sidecar {s}")
            except json.JSONDecodeError as e:
                raise ValueError(f"sidecar {s} is not valid JSON: {e}") from None
            if not isinstance(d, dict):
                if s != sidecar_path(path):  # run.json next to run.pkl may be a dump of robot states, not metadata
                    continue
                raise ValueError(f"sidecar {s} must hold a JSON object")
            return d
    return {}


# the tool in words: the Franka Hand (its names in Franka's documents and ROS packages) or no tool at all
_HAND_WORDS = ("franka hand", "franka gripper", "panda hand", "fer hand", "fr3 hand", "hand", "gripper", "franka_hand")
_NO_TOOL_WORDS = ("none", "no tool", "no hand", "no gripper", "without tool", "without hand", "without gripper",
                  "nothing", "null", "bare flange", "flange only", "no end effector", "")


def tool_from_words(text: str) -> str | None | bool:
    """``"franka_hand"`` for the Franka Hand named in words ("Franka Hand", "hand", "gripper", any case, inside a
    longer phrase), None for no tool ("none", "no tool", "without gripper" ...), False when neither (or both)."""
    w = " " + " ".join(re.split(r"[\s_\-/.,;:()\[\]]+", text.lower())).strip() + " "
    none = any(f" {x} " in w for x in _NO_TOOL_WORDS if x) or not w.strip()
    hand = any(f" {x} " in w for x in _HAND_WORDS)
    if none:
        return None  # "no gripper" names the gripper too: the negation decides
    return "franka_hand" if hand else False


def _meta_kwargs(meta: dict[str, Any], where: str = "the log metadata") -> dict[str, Any]:
    from franka_vs_gym.model import checks
    from franka_vs_gym.model.config import RigidBody

    meta = dict(meta)
    kw: dict[str, Any] = {}
    kw["tool_declared"] = "tool" in meta
    kw["tool"] = meta.pop("tool", _TOOL_DEFAULT)
    if isinstance(kw["tool"], str):
        words = tool_from_words(kw["tool"])
        if words is False:
            raise ValueError(f"{where}: unknown tool {kw['tool']!r} in 'tool': it names neither the Franka Hand "
                             "nor no tool; write \"franka_hand\", null, or an object with mass, com, inertia; or "
                             "pass --tool (franka_hand, none, unknown)")
        if kw["tool"] not in ("franka_hand", "none"):
            meta["tool_declared_as"] = kw["tool"]
        kw["tool"] = words
    if kw["tool"] is not None and not isinstance(kw["tool"], (str, dict)):
        raise ValueError(f"tool in the log metadata must be 'franka_hand', null, or an object with mass, com, "
                         f"inertia; got {type(kw['tool']).__name__}")
    if isinstance(kw["tool"], dict):
        missing = {"mass", "com", "inertia"} - set(kw["tool"])
        if missing:
            raise ValueError(f"tool in the log metadata lacks {sorted(missing)}")
        try:  # physical plausibility where the numbers enter (mass range, inertia, com)
            body = RigidBody(kw["tool"]["mass"], kw["tool"]["com"], kw["tool"]["inertia"])
        except ValueError as e:
            raise ValueError(f"tool in the log metadata: {e}") from None
        if body.mass > checks.MAX_FLANGE_LOAD:
            raise ValueError(f"tool in the log metadata: mass {body.mass:.4g} kg is not plausible for the FER "
                             f"(rated payload 3 kg; refused above {checks.MAX_FLANGE_LOAD:g} kg); grams?")
        if np.linalg.norm(body.com) > checks.MAX_LOAD_COM:
            raise ValueError(f"tool in the log metadata: com {body.com.tolist()} m is over {checks.MAX_LOAD_COM:g} m "
                             "from the flange; mm?")
    if "gravity" in meta:
        g = checks.as_vector(meta.pop("gravity"), 3, "gravity in the log metadata")
        if meta.get("check_gravity", True) is not False:
            checks.check_gravity(g, "gravity in the log metadata")
        kw["gravity"] = g
    kw["controller"] = meta.pop("controller", None)
    if kw["controller"] is not None and not isinstance(kw["controller"], dict):
        raise ValueError(f"controller in the log metadata must be an object or null, got "
                         f"{type(kw['controller']).__name__}")
    for gain in ("kp", "kd", "ki"):  # one number for every joint, or 7
        v = (kw["controller"] or {}).get(gain)
        if v is None:
            continue
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"controller.{gain} in the log metadata must be a number or 7 numbers, "
                             f"got {v!r}") from None
        if a.shape not in ((), (7,)) or not np.isfinite(a).all():
            raise ValueError(f"controller.{gain} in the log metadata must be a finite number or 7 numbers (one per "
                             f"joint), got {np.shape(a)[0] if a.ndim == 1 else np.shape(a)} values: {v!r}")
    kw["extra"] = meta
    return kw


# ----------------------------------------------------------------------------------------------- writing
def save_log(log: MeasurementLog, path: str | os.PathLike, overwrite: bool = False) -> Path:
    """Write ``log`` as CSV (``.csv``) or NPZ (``.npz``) plus the JSON sidecar ``<path>.json``.

    Both files appear together or not at all (:class:`franka_vs_gym.io.OutputSet`: staged next to their targets,
    then renamed). Refuses to overwrite an existing log or sidecar unless ``overwrite``, and never writes over an
    input of the running command. Returns the path written.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".csv", ".npz"):
        raise ValueError(f"{p}: unknown log format {p.suffix!r} (use .csv or .npz)")
    with io.OutputSet(force=overwrite) as out:
        tmp = out.file(p, what="log")
        side = out.file(sidecar_path(p), what="sidecar")
        if suffix == ".csv":
            cols = ["time"] + [f"{f}[{i}]" for f in log.fields() for i in range(7)]
            data = np.column_stack([log.time] + [getattr(log, f) for f in log.fields()])
            with open(tmp, "w", newline="") as fh:
                fh.write(",".join(cols) + "\n")
                np.savetxt(fh, data, delimiter=",", fmt="%.10g")
        else:
            arrays = {f: getattr(log, f) for f in log.fields()}
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, time=log.time, **arrays)
        side.write_text(json.dumps(log.metadata(), indent=2))
    return p


__all__ = ["MeasurementLog", "metadata_file", "save_log", "sidecar_path", "tool_from_words", "validate",
           "JOINT_FIELDS", "REQUIRED", "OPTIONAL"]
