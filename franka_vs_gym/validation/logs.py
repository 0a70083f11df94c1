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

File formats (read by :func:`load_log`, written by :func:`save_log`):

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

import csv
import json
import math
import os
import re
import warnings
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


def _columns_to_fields(header: list[str], data: np.ndarray, where: str) -> dict[str, np.ndarray]:
    names = [h.strip() for h in header]
    if "time" not in names:
        raise ValueError(f"{where}: missing column 'time' (s)")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"{where}: duplicate columns {dup}")
    groups: dict[str, dict[int, int]] = {}
    for col, name in enumerate(names):
        m = _COL.match(name)
        if m:
            base, idx = m.group(1), int(m.group(2) if m.group(2) is not None else m.group(3))
            prev = groups.setdefault(base, {}).get(idx)
            if prev is not None:  # two spellings of one column (q[0] and q_0): equal values are one column
                if not np.array_equal(data[:, prev], data[:, col], equal_nan=True):
                    r = int(np.argmax(data[:, prev] != data[:, col]))
                    raise ValueError(f"{where}: columns {names[prev]!r} and {name!r} are the same column written "
                                     f"twice with different values (first at data row {r}: {data[r, prev]:g} vs "
                                     f"{data[r, col]:g}); keep one")
                continue
            groups[base][idx] = col
    out = {"time": data[:, names.index("time")]}
    for f in JOINT_FIELDS:
        g = groups.get(f)
        if g is None:
            if f in REQUIRED:
                raise ValueError(f"{where}: missing columns {f}[0]..{f}[6] ({f!r} is required)")
            continue
        idx = sorted(g)
        if idx != list(range(7)):
            missing = [f"{f}[{i}]" for i in range(7) if i not in g]
            extra = [f"{f}[{i}]" for i in idx if i >= 7]
            msg = f"{where}: {f} has joints {idx}; the FER has 7 joints (indices 0..6)"
            if missing:
                msg += f"; missing {missing}"
            if extra:
                msg += f"; unexpected {extra}"
            raise ValueError(msg)
        out[f] = data[:, [g[i] for i in range(7)]]
    return out


_LOADTXT_ROW = re.compile(r"at row (\d+)")
_LOADTXT_COLS = re.compile(r"number of columns changed from (\d+) to (\d+) at row (\d+)")
_LOADTXT_BAD = re.compile(r"could not convert string '(.*)' to float64 at row (\d+), column (\d+)")


def _load_csv(path: Path) -> dict[str, np.ndarray]:
    """Header with csv, values with numpy's C parser, straight into one float64 array (no per-value Python
    objects: a 200 MB log needs about its array's size in memory)."""
    with io.open_input(path, "r", what="log", newline="") as fh:
        first = fh.readline()
        if not first.strip():
            raise ValueError(f"{path}: empty file" if not first else f"{path}: the first line must be a header")
        header = next(csv.reader([first]))
        if all(_isfloat(h) for h in header):
            raise ValueError(f"{path}: the first line must be a header with column names (time, q[0], ...)")
        delimiter = "," if len(header) > 1 or "," in first else None
        try:
            with warnings.catch_warnings():  # "input contained no data": said below as "no data rows"
                warnings.simplefilter("ignore", UserWarning)
                data = np.loadtxt(fh, dtype=np.float64, delimiter=delimiter, ndmin=2, comments=None, encoding=None)
        except ValueError as e:
            msg = " ".join(str(e).split())
            m = _LOADTXT_BAD.search(msg)
            if m:  # numpy counts data rows from 0 and columns from 1; the file's lines start at 1 with the header
                col = int(m.group(3)) - 1
                msg = (f"line {int(m.group(2)) + 2}: {m.group(1)!r} is not a number (column "
                       f"{header[col].strip() if 0 <= col < len(header) else m.group(3)})")
            elif (m := _LOADTXT_COLS.search(msg)) is not None:  # here numpy counts data rows from 1
                msg = (f"line {int(m.group(3)) + 1} has {m.group(2)} values, the header has {len(header)} "
                       "columns")
            elif (m := _LOADTXT_ROW.search(msg)) is not None:
                msg = _LOADTXT_ROW.sub(f"at line {int(m.group(1)) + 2}", msg)
            raise ValueError(f"{path}: {msg}") from None
    if data.size == 0:
        raise ValueError(f"{path}: no data rows")
    if data.shape[1] != len(header):
        raise ValueError(f"{path}: rows have {data.shape[1]} values, the header has {len(header)} columns")
    bad = ~np.isfinite(data)
    if bad.any():  # named by its line and column here, where they are known (a NaN, or a huge number: a blob?)
        r, c = (int(x) for x in np.argwhere(bad)[0])
        raise ValueError(f"{path}: {header[c].strip()} contains NaN or inf (first at row {r}, line {r + 2} of the "
                         f"file: {_describe_cell(path, r + 2, c, delimiter)})")
    from franka_vs_gym.validation.readers import is_libfranka_csv, libfranka_columns

    if is_libfranka_csv(header):  # libfranka's logToCSV: state./cmd. prefixes, time in ms
        header, to_s = libfranka_columns(header)
        data[:, [h.strip() for h in header].index("time")] *= to_s
    return _columns_to_fields(header, data, str(path))


def _describe_cell(path: Path, lineno: int, col: int, delimiter: str | None) -> str:
    """What is wrong with the non-finite value at ``lineno`` (1-based, header included), column ``col``: the text of
    the cell read again from the file (a line at a time: a 20 MB field costs 20 MB once)."""
    with io.open_input(path, "r", what="log", newline="") as fh:
        for k, line in enumerate(fh, start=1):
            if k == lineno:
                cells = line.rstrip("\r\n").split(delimiter)
                text = cells[col].strip() if col < len(cells) else ""
                break
        else:
            return "not a finite number"
    if len(text) > 64:
        return f"a value of {len(text)} characters ({text[:16]}...): a blob in the column or a corrupt file?"
    return f"{text!r}"


def _isfloat(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _load_npz(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    z = io.load_npz(path, what="log")  # headers checked before reading; uncompressed arrays memory-mapped
    keys = set(z)

    def floats(name: str) -> np.ndarray:
        try:
            return np.array(z[name], dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{path}: array {name!r} is not numeric (dtype {z[name].dtype})") from None

    meta: dict[str, Any] = {}
    if "meta" in keys:
        try:
            meta = io.loads_json(str(np.asarray(z["meta"])), f"{path}: array 'meta'")
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: array 'meta' is not a JSON string: {e}") from None
        if not isinstance(meta, dict):
            raise ValueError(f"{path}: array 'meta' must hold a JSON object")
    if "time" not in keys:
        raise ValueError(f"{path}: missing array 'time' (s)")
    out = {"time": floats("time").ravel()}
    for f in JOINT_FIELDS:
        if f in keys:
            out[f] = floats(f)
        elif f in REQUIRED:
            # accept per-joint arrays q[0]..q[6] / q_0..q_6 as well
            cols = [next((k for k in (f"{f}[{i}]", f"{f}_{i}") if k in keys), None) for i in range(7)]
            if all(c is not None for c in cols):
                parts = [floats(c) for c in cols]  # type: ignore[arg-type]
                if len({p.shape for p in parts}) != 1 or parts[0].ndim != 1:
                    raise ValueError(f"{path}: per-joint arrays of {f!r} must be 1-D of equal length")
                out[f] = np.stack(parts, axis=1)
            else:
                raise ValueError(f"{path}: missing array {f!r} (shape (N, 7))")
    return out, meta


def _layout_score(x: np.ndarray) -> float:
    """How much (n, 7) samples look like 7 joints sampled in time: the typical difference between neighbouring
    columns (different joints) over the typical step in time (one sample). A misread layout puts consecutive
    samples of one joint side by side (ratio near 1) or interleaves joints along time (large steps)."""
    step = float(np.median(np.abs(np.diff(x, axis=0))))
    across = float(np.median(np.abs(np.diff(x, axis=1))))
    scale = float(np.abs(x).max()) + 1e-300
    return (across + 1e-12 * scale) / (step + 1e-12 * scale)


def _gaz_layout(files: dict[str, np.ndarray], lines: dict[str, list[int]], n: int, folder: Path) -> str:
    """"sample" (7 values per sample, in time order) or "joint" (all n samples of joint 0, then joint 1...) for
    the joint files of a Gaz folder. The line structure decides when it can (n lines of 7 values, or 7 lines of n
    values); otherwise the layout in which the columns look like 7 joints sampled in time wins, judged on the
    positions first (then velocities, torques); a folder where neither layout is clearly better is refused."""
    for f in ("q", "dq", "tau_J"):
        counts = lines[f]
        if len(counts) == n and all(k == 7 for k in counts):
            return "sample"
        if len(counts) == 7 and all(k == n for k in counts) and n != 7:
            return "joint"
    if n < 3:
        return "sample"
    for f in ("q", "dq", "tau_J"):
        v = files[f]
        if not np.isfinite(v).all() or np.ptp(v) == 0:
            continue
        s, j = _layout_score(v.reshape(n, 7)), _layout_score(v.reshape(7, n).T)
        if s >= 3 * j:
            return "sample"
        if j >= 3 * s:
            return "joint"
    raise ValueError(f"{folder}: cannot tell whether the values are sample-major (7 per sample) or joint-major (all "
                     "samples of joint 0 first): neither layout looks like 7 joints sampled in time")


def _read_gaz_file(p: Path) -> tuple[np.ndarray, list[int]]:
    with io.open_input(p, "r", what="Gaz log file") as fh:
        counts: list[int] = []
        chunks: list[np.ndarray] = []
        for lineno, line in enumerate(fh, start=1):
            parts = line.replace(",", " ").split()
            if not parts:
                continue
            try:
                chunks.append(np.array(parts, dtype=np.float64))
            except ValueError:
                bad = next(x for x in parts if not _isfloat(x))
                raise ValueError(f"{p}: line {lineno}: {bad!r} is not a number") from None
            counts.append(len(parts))
    if not chunks:
        raise ValueError(f"{p}: no values")
    return np.concatenate(chunks), counts


def _load_gaz(folder: Path) -> dict[str, np.ndarray]:
    out, lines = {}, {}
    for f, name in GAZ_FILES.items():
        p = folder / name
        if not os.path.lexists(p):
            raise ValueError(f"{folder}: missing file {name} (Gaz et al. 2019 log folder)")
        out[f], lines[f] = _read_gaz_file(p)
    n = len(out["time"])
    for f in ("q", "dq", "tau_J"):
        if out[f].size != 7 * n:
            raise ValueError(f"{folder / GAZ_FILES[f]}: {out[f].size} values for {n} timestamps; expected 7 per "
                             f"sample ({7 * n})")
    layout = _gaz_layout(out, lines, n, folder)
    for f in ("q", "dq", "tau_J"):
        out[f] = out[f].reshape(n, 7) if layout == "sample" else out[f].reshape(7, n).T.copy()
    return out


def _native_header(header: list[str]) -> bool:
    """Our CSV format (``time`` and ``field[i]``/``field_i`` columns of the log's fields only) or logToCSV's."""
    from franka_vs_gym.validation.readers import is_libfranka_csv

    if is_libfranka_csv(header):
        return True
    names = [h.strip() for h in header]
    if "time" not in names:
        return False
    for n in names:
        m = _COL.match(n)
        if n != "time" and not (m and m.group(1) in JOINT_FIELDS):
            return False
    return True


# suffixes under which a text table is expected; other text files (or a binary format we do not read, e.g. Parquet,
# HDF5, MATLAB) are refused by name rather than parsed as a table
_TEXT_SUFFIXES = frozenset({"", ".csv", ".tsv", ".txt", ".dat", ".log"})


def _load_file(p: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Arrays and metadata of a log file; the format is detected from the content (see :func:`load_log`)."""
    from franka_vs_gym.validation import robot_states as rs

    kind = rs.sniff(p)
    suffix = p.suffix.lower()
    if suffix == ".npz" and kind != "npz":
        raise ValueError(f"{p}: not a valid .npz archive (empty, truncated or another format)")
    if kind == "text" and suffix not in _TEXT_SUFFIXES:
        raise ValueError(f"{p}: unknown log format {p.suffix!r} (readable: CSV or other text tables, NPZ, NPY, JSON, "
                         "JSON lines, franky state pickles, ROS 1/ROS 2 bags, Gaz et al. 2019 folders)")
    if kind == "npz":
        z = io.load_npz(p, what="log")
        keys = set(z)
        native = {"time", *REQUIRED} <= keys and z["q"].ndim == 2
        if native:
            t = np.asarray(z["time"], dtype=np.float64).ravel()
            dt = np.diff(t)
            native = not (dt > 0).any() or float(np.median(dt[dt > 0])) < MAX_STEP_S
        return _load_npz(p) if native else rs.read_npz_dump(p)
    if kind == "npy":
        return rs.read_npy(p)
    if kind == "pickle":
        return rs.read_pickle(p)
    if kind == "json":
        return rs.read_json(p)
    with io.open_input(p, "r", what="log", newline="") as fh:
        first = fh.readline()
    if not first.strip():
        raise ValueError(f"{p}: empty file" if not first else f"{p}: the first line must be a header")
    header = next(csv.reader([first]))
    if len(header) == 1 and "," not in first:
        header = first.split()
    if all(_isfloat(h) for h in header):
        raise ValueError(f"{p}: the first line must be a header with column names (time, q[0], ...)")
    if _native_header(header):
        return _load_csv(p), {}
    return rs.read_csv_dump(p, first)


def _with_sidecar(meta: dict[str, Any], side: dict[str, Any]) -> dict[str, Any]:
    """The reader's metadata overridden by the sidecar's; a tool the sidecar declares replaces the one the file
    declared, and so does its stated source."""
    out = dict(meta)
    if "tool" in side:
        out.pop("tool_source", None)
    out.update(side)
    return out


def load_log(path: str | os.PathLike, topic: str | None = None, progress: bool = False,
             tool: str | None = None) -> MeasurementLog:
    """Read a log: a CSV file (ours or libfranka's logToCSV), an NPZ file, a ROS 1 or ROS 2 bag of Franka robot
    states or JointState messages (``topic`` chooses the topic, else it is chosen and the choice stated; see
    :mod:`franka_vs_gym.validation.readers`), a Gaz et al. 2019 text folder (see
    the module docstring), or a dump of pylibfranka/franky robot states (JSON, JSON lines, CSV with flattened or
    whole-list fields, NPZ/NPY, a pickle of franky states; see
    :mod:`franka_vs_gym.validation.readers.robot_states`). The format of a file is detected from its content.

    The sidecar ``<log>.json`` supplies tool, gravity and controller. ``progress`` shows a progress bar on stderr
    while a ROS bag is decoded. ``tool`` ("franka_hand", "none" or "unknown", as ``--tool``) replaces the tool the
    metadata declares, which is then not read (the declared text is kept in ``extra["tool_declared_as"]``). Raises
    FileNotFoundError when the path does
    not exist and ValueError when the content is malformed. The file is only read.
    """
    from franka_vs_gym.validation.readers import is_rosbag, read_rosbag

    p = Path(path)
    if not os.path.lexists(p):
        raise FileNotFoundError(f"log not found: {p}")
    if is_rosbag(p):
        if not p.is_dir():  # a bare .mcap/.db3: a regular file (a FIFO or device would hang the reader)
            io.check_input_file(p, what="ROS bag")
        arrays, meta = read_rosbag(p, topic, progress=progress)
        meta = _with_sidecar(meta, _read_sidecar(p))
    elif p.is_dir():
        arrays = _load_gaz(p)
        meta: dict[str, Any] = {"tool": None, "source_format": "gaz2019"}
        meta.update(_read_sidecar(p / "log"))
    else:
        try:
            arrays, meta = _load_file(p)
        except UnicodeDecodeError as e:  # a binary file of no format we read
            raise ValueError(f"{p}: not a log: byte {e.start} is not UTF-8 text, and the content is no NPZ, NPY, "
                             "pickle of robot states or ROS bag") from None
        except csv.Error as e:  # e.g. "field larger than field limit (131072)": a blob or a corrupt file
            raise ValueError(f"{p}: not a readable table: {e} (a cell of over 128 KiB; a blob in a column or a "
                             "corrupt file?)") from None
        meta = _with_sidecar(meta, _read_sidecar(p))
    if tool is not None:  # --tool: the declaration is overridden, not read (a name it cannot read is no error)
        if "tool" in meta and meta["tool"] not in ("franka_hand", None, "none"):
            meta["tool_declared_as"] = meta["tool"] if isinstance(meta["tool"], str) else "an object"
        meta["tool"] = "franka_hand" if tool == "franka_hand" else None
        meta["tool_source"] = "--tool"
    kw = _meta_kwargs(meta, _meta_where(p))
    t = arrays.pop("time")
    return MeasurementLog(t, **arrays, **kw, source=str(p))


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


__all__ = ["MeasurementLog", "load_log", "metadata_file", "save_log", "sidecar_path", "tool_from_words", "validate",
           "JOINT_FIELDS", "REQUIRED", "OPTIONAL"]
