"""Robot states of the real FCI clients (pylibfranka, franky): a recorder for control loops, and readers for the
dumps users make of them.

**Recording.** :class:`StateRecorder` takes the ``RobotState`` objects of pylibfranka (``control.readOnce()``) or
franky (a motion callback) inside a 1 kHz control loop. It is duck-typed (neither package is imported): a state is
anything with ``time`` (a libfranka ``Duration``: ``to_sec()``/``to_msec()``) and the (7,) arrays ``q``, ``dq``,
``tau_J`` and, when present, ``tau_J_d``, ``q_d``, ``dq_d``, ``ddq_d``, ``tau_ext_hat_filtered``. Buffers are
allocated once; a tick copies seven small arrays and nothing else is allocated (a full buffer counts the ticks it
drops instead of growing). :meth:`StateRecorder.save` writes the workbench's log format (CSV or NPZ + sidecar,
through :func:`franka_vs_gym.validation.logs.save_log`: atomic, never overwriting), with the tool and gravity the
robot itself declared in the first state (``m_total``, ``F_x_Ctotal``, ``I_total``: end effector plus load, flange
frame; ``O_ddP_O``: the gravity vector), so the workbench does not have to assume them.

**Reading dumps** (:func:`read_dump`, called by :func:`franka_vs_gym.validation.loading.load_log`; the format is
detected from the content, not the file name):

- JSON lines (one ``{"time": ..., "q": [...], ...}`` object per tick), a JSON list of such objects (possibly under
  one key of an object, e.g. ``{"states": [...]}``), or one JSON object of columns (``{"time": [...], "q": [[...],
  ...]}``). Per-tick objects may nest the state under any key (``{"robot_state": {"q": ...}}``).
- CSV whose array fields are flattened (``q_0``, ``q0``, ``q.0``, ``q[0]``, ``state.q[0]``; ``q1..q7`` is read as
  1-based) or kept whole in one cell (``"[0.1, 0.2, ...]"``, numpy's ``"[0.1 0.2 ...]"``); other columns (robot
  mode, poses, a pandas index) are ignored.
- NumPy: ``.npz`` of stacked arrays (``q`` (N, 7) or ``q_0``...), ``.npy`` of a structured array with named fields.
- Pickles of franky ``RobotState`` lists (franky's own type): read with an unpickler that only builds franky's and
  numpy's types (nothing else in a pickle is executed); needs franky installed.

The columns are read as the log's fields by :mod:`.fields` (names, the time and its unit, the declared tool).
"""

from __future__ import annotations

import csv
import io as _pyio
import json
import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym import io
from franka_vs_gym.validation.readers.fields import (
    _STAMP_PARTS,
    JOINT_FIELDS,
    JOINT_STATE_FIELDS,
    REQUIRED,
    SIDECAR_KEYS,
    TIME_NAMES,
    TOOL_FIELDS,
    parse_name,
    table_to_fields,
    tool_from_state,
)


# ------------------------------------------------------------------------------------------------- recording
def _duration_s(t: Any) -> float:
    """Seconds of a libfranka Duration (pylibfranka: ``to_sec``; franky: ``to_sec``/``to_msec``) or a number (s)."""
    if hasattr(t, "to_sec"):
        return float(t.to_sec())
    if hasattr(t, "to_msec"):
        return float(t.to_msec()) * 1e-3
    return float(t)


class StateRecorder:
    """Records pylibfranka / franky ``RobotState`` objects at 1 kHz into preallocated buffers.

    Parameters
    ----------
    seconds : capacity in seconds of robot time at ``rate`` (default 120 s).
    rate : control rate, Hz (libfranka: 1000).
    fields : the (7,) joint fields to record; the optional ones a state does not have are skipped.

    Use it as the callback itself (franky: ``motion.register_callback(rec)``; its extra arguments are ignored) or
    call ``rec(state)`` after each ``control.readOnce()`` (pylibfranka). ``rec.n`` ticks are kept; ticks beyond the
    capacity are counted in ``rec.dropped`` (the buffers never grow inside the control loop). :meth:`log` gives a
    :class:`~franka_vs_gym.validation.logs.MeasurementLog` (time in s from the first tick; joint fields (N, 7) in
    rad, rad/s, Nm), :meth:`save` writes it with its sidecar.
    """

    def __init__(self, seconds: float = 120.0, rate: float = 1000.0, fields: tuple[str, ...] = JOINT_FIELDS) -> None:
        cap = int(math.ceil(float(seconds) * float(rate)))
        if cap < 2:
            raise ValueError(f"recorder capacity {cap} samples: seconds * rate must give at least 2")
        bad = [f for f in fields if f not in JOINT_FIELDS]
        if bad or not set(REQUIRED) <= set(fields):
            raise ValueError(f"fields must include {list(REQUIRED)} and be among {list(JOINT_FIELDS)}; got "
                             f"{list(fields)}")
        self.capacity = cap
        self.n = 0
        self.dropped = 0
        self._t = np.empty(cap)
        self._buf = {f: np.empty((cap, 7)) for f in fields}
        self._fields: tuple[str, ...] | None = None  # the fields the states have, fixed at the first tick
        self.first_state: dict[str, Any] = {}

    def __call__(self, state: Any, *_: Any) -> None:
        """Record one state (extra arguments, e.g. franky's time step and control signal, are ignored)."""
        i = self.n
        if i >= self.capacity:
            self.dropped += 1
            return
        if self._fields is None:
            self._start(state)
        self._t[i] = _duration_s(state.time)
        for f in self._fields:  # type: ignore[union-attr]
            self._buf[f][i] = getattr(state, f)
        self.n = i + 1

    record = __call__

    def _start(self, state: Any) -> None:
        missing = [f for f in REQUIRED if not hasattr(state, f)]
        if missing or not hasattr(state, "time"):
            raise ValueError(f"not a robot state: {type(state).__name__} has no {missing or ['time']}")
        self._fields = tuple(f for f in self._buf if hasattr(state, f))
        for k in TOOL_FIELDS:
            if hasattr(state, k):
                self.first_state[k] = _plain(getattr(state, k))
        self.first_state["client"] = type(state).__module__.split(".")[0]

    def clear(self) -> None:
        """Forget the recorded ticks (the buffers are kept)."""
        self.n, self.dropped, self._fields, self.first_state = 0, 0, None, {}

    def log(self, tool: Any = "state", gravity: Any = "state", controller: dict | None = None):
        """The recorded ticks as a MeasurementLog.

        ``tool``: ``"state"`` (default: what the robot declared, see :func:`tool_from_state`), ``"franka_hand"``,
        None or a ``{"mass", "com", "inertia"}`` dict (flange frame). ``gravity``: ``"state"`` (``O_ddP_O``) or a
        (3,) vector, m/s^2, base frame.
        """
        from franka_vs_gym.validation.logs import MeasurementLog

        if self.n < 2:
            raise ValueError(f"the recorder holds {self.n} ticks; a log needs at least 2")
        n = self.n
        t = self._t[:n] - self._t[0]
        arrays = {f: self._buf[f][:n].copy() for f in (self._fields or ())}
        extra: dict[str, Any] = {"source_format": f"{self.first_state.get('client', 'robot')} RobotState recorder",
                                 "time_origin_s": float(self._t[0]), "ticks_recorded": n,
                                 "ticks_dropped": self.dropped}
        kw: dict[str, Any] = {}
        if isinstance(tool, str) and tool == "state":
            tool, src = tool_from_state(self.first_state)
            extra["tool_source"] = src
        kw["tool"] = tool
        if isinstance(gravity, str) and gravity == "state":
            g = self.first_state.get("O_ddP_O")
            if g is not None and np.isfinite(g).all() and np.linalg.norm(g) > 0:
                kw["gravity"] = np.asarray(g, dtype=float)
        else:
            kw["gravity"] = np.asarray(gravity, dtype=float)
        if self.dropped:
            extra["warning"] = (f"the recorder was full: {self.dropped} ticks after {n} were not recorded "
                                "(give StateRecorder a larger seconds=)")
        return MeasurementLog(t, **arrays, controller=controller, extra=extra, **kw)

    def save(self, path: str | Path, overwrite: bool = False, **kw: Any) -> Path:
        """Write the log (``.csv`` or ``.npz``) and its sidecar ``<path>.json`` atomically; refuses to replace
        existing files unless ``overwrite``. Keywords go to :meth:`log`."""
        from franka_vs_gym.validation.logs import save_log

        return save_log(self.log(**kw), path, overwrite=overwrite)


def _plain(v: Any) -> Any:
    """A state attribute as a float or a float array (franky's Affine has ``matrix``)."""
    if hasattr(v, "matrix"):
        v = v.matrix
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError):
        return None
    return float(a) if a.ndim == 0 else a.ravel()


# ------------------------------------------------------------------------------------------------- formats
def sniff(path: Path) -> str:
    """The format of a file from its first bytes: "npz", "npy", "pickle", "json" or "text"."""
    with io.open_input(path, "rb", what="log") as fh:
        head = fh.read(512)
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz"
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head[:1] == b"\x80" and len(head) > 1 and 2 <= head[1] <= 5:
        return "pickle"
    s = head.lstrip(b"\xef\xbb\xbf").lstrip()
    if s[:1] in (b"{", b"["):
        return "json"
    return "text"


def read_json(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A JSON list of per-tick objects, JSON lines, or one object of columns (see the module docstring)."""
    text = io.read_text(path, what="log", max_bytes=io.MAX_INPUT_BYTES)
    where = str(path)
    try:
        doc = io.loads_json(text, where)
        kind = "JSON"
    except json.JSONDecodeError as e:
        if "Extra data" not in str(e):
            raise ValueError(f"{where}: not valid JSON: {e}") from None
        doc, kind = [], "JSON lines"
        for lineno, line in enumerate(text.splitlines(), start=1):
            if line.strip():
                try:
                    doc.append(io.loads_json(line, f"{where}: line {lineno}"))
                except json.JSONDecodeError as e2:
                    raise ValueError(f"{where}: line {lineno} is not a JSON object: {e2}") from None
    if isinstance(doc, dict) and doc and set(doc) <= SIDECAR_KEYS | {"source_format", "time_origin_s", "tool_source",
                                                                     "ticks_recorded", "ticks_dropped", "warning",
                                                                     "generator", "check_gravity"}:
        raise ValueError(f"{where}: this is a log's metadata sidecar (keys {sorted(doc)}), not a log; pass the log "
                         "it describes")
    if isinstance(doc, dict):
        lists = [k for k, v in doc.items() if isinstance(v, list) and v and isinstance(v[0], dict)]
        if len(lists) == 1 and parse_name(lists[0]) not in [(f, None) for f in JOINT_FIELDS]:
            doc = doc[lists[0]]
            kind += f" ({lists[0]!r}: a list of robot states)"
        else:
            flat: dict[str, Any] = {}
            _flatten(doc, "", flat)
            return table_to_fields(flat, where, kind + " object of columns")
    if not isinstance(doc, list) or not doc:
        raise ValueError(f"{where}: expected robot states (a list of objects with time, q, dq, tau_J), got "
                         f"{type(doc).__name__ if doc else 'nothing'}")
    return table_to_fields(_ticks_to_columns(doc, where), where, kind + " of robot states")


def _flatten(d: dict[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            _flatten(v, name + ".", out)
        else:
            out[name] = v


def _ticks_to_columns(ticks: list[Any], where: str) -> dict[str, Any]:
    cols: dict[str, list[Any]] = {}
    first: dict[str, Any] = {}
    for i, tick in enumerate(ticks):
        if not isinstance(tick, dict):
            raise ValueError(f"{where}: robot state {i} is a {type(tick).__name__}, not an object")
        flat: dict[str, Any] = {}
        _flatten(tick, "", flat)
        if i == 0:
            first = flat
            cols = {k: [] for k in flat}
        for k in cols:
            if k not in flat:
                cols[k].append(None)
            else:
                cols[k].append(flat[k])
    out: dict[str, Any] = {}
    for k, v in cols.items():
        if any(x is None for x in v):
            missing = v.index(None)
            base = parse_name(k)
            if base is not None and (base[0] in REQUIRED or base[0].lower() in TIME_NAMES):
                raise ValueError(f"{where}: robot state {missing} has no {k!r} (state 0 has it)")
            continue
        if isinstance(first[k], (str, bool)) or first[k] is None:
            continue
        out[k] = v
    return out


def _wanted(base: str) -> bool:
    """Whether a column of this base name is read (joint fields, time, the declared tool, a JointState's fields)."""
    return (base in JOINT_FIELDS or base.lower() in TIME_NAMES or base in TOOL_FIELDS or base in JOINT_STATE_FIELDS
            or base == "name" or any(base in pair for pair in _STAMP_PARTS))


def read_csv_dump(path: Path, first_line: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A CSV whose array fields are flattened in any common way or kept whole in one cell."""
    with io.open_input(path, "r", what="log", newline="") as fh:
        text = fh.read()
    try:
        dialect = csv.Sniffer().sniff(first_line, delimiters=",;\t")
        delim = dialect.delimiter
    except csv.Error:
        delim = "," if "," in first_line else None
    if delim is None:  # whitespace-separated: no list cells possible
        rows = [ln.split() for ln in text.splitlines() if ln.strip()]
    else:
        reader = csv.reader(_pyio.StringIO(text), delimiter=delim)
        try:
            rows = [r for r in reader if r]
        except csv.Error as e:  # e.g. a field over csv's limit (128 KiB): name the line and the column
            line = text.splitlines()[reader.line_num - 1] if reader.line_num else ""
            cells = line.split(delim)
            head = first_line.rstrip("\r\n").split(delim)
            c = max(range(len(cells)), key=lambda k: len(cells[k])) if cells else 0
            col = f", column {head[c].strip()!r}" if c < len(head) else ""
            size = len(cells[c]) if cells else 0
            raise ValueError(f"{path}: line {reader.line_num}{col}: a cell of over 128 KiB ({size} characters; {e}): "
                             "a blob in the column or a corrupt file?") from None
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    if not body:
        raise ValueError(f"{path}: no data rows")
    for k, r in enumerate(body):
        if len(r) != len(header):
            raise ValueError(f"{path}: line {k + 2} has {len(r)} values, the header has {len(header)} columns")
    needed = {}
    for c, h in enumerate(header):
        p = parse_name(h)
        if p is not None and _wanted(p[0]):
            needed[h] = [r[c] for r in body]
    return table_to_fields(needed, str(path), "CSV")


def read_npz_dump(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    z = io.load_npz(path, what="log")
    cols = {}
    for k in z:
        p = parse_name(k)
        if p is not None and _wanted(p[0]) and p[0] != "name":
            a = z[k]
            if a.dtype.kind not in "fiub":
                raise ValueError(f"{path}: array {k!r} is not numeric (dtype {a.dtype})")
            cols[k] = np.asarray(a, dtype=np.float64)
    return table_to_fields(cols, str(path), "NPZ")


def read_npy(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    with io.open_input(path, "rb", what="log") as fh:
        try:
            a = np.load(fh, allow_pickle=False)
        except ValueError as e:
            if "pickle" in str(e).lower():
                raise ValueError(f"{path}: holds Python objects (a pickled list or dict), which are not read; save "
                                 "arrays instead: np.savez(path, time=..., q=..., dq=..., tau_J=...)") from None
            raise ValueError(f"{path}: not a readable .npy file: {e}") from None
    if a.dtype.names is None:
        raise ValueError(f"{path}: a plain {a.shape} array has no field names; use a structured array (fields time, "
                         "q, dq, tau_J) or an .npz of named arrays")
    cols = {k: a[k] for k in a.dtype.names}
    return table_to_fields(cols, str(path), "NPY structured array")


class _StateUnpickler(pickle.Unpickler):
    """Builds only franky's and pylibfranka's types, numpy arrays and plain containers."""

    _NUMPY = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
              ("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.multiarray", "scalar"),
              ("numpy._core.multiarray", "scalar")}
    _BUILTINS = {("builtins", "list"), ("builtins", "dict"), ("builtins", "tuple"), ("builtins", "set"),
                 ("builtins", "frozenset"), ("collections", "OrderedDict"), ("copyreg", "_reconstructor"),
                 ("builtins", "object")}

    # value types of a franky RobotState (no class that connects to a robot or opens a file)
    _STATE_TYPES = {"RobotState", "Affine", "Duration", "ElbowState", "Errors", "FlipDirection", "RobotMode", "Twist",
                    "TwistAcceleration", "JointState", "CartesianState", "RobotPose", "RobotVelocity", "GripperState",
                    "BrakeState"}

    def find_class(self, module: str, name: str) -> Any:
        if ((module.split(".")[0] in ("franky", "pylibfranka") and name in self._STATE_TYPES)
                or (module, name) in self._NUMPY | self._BUILTINS):
            try:
                return super().find_class(module, name)
            except ImportError as e:
                if "already registered" in str(e):  # franky and pylibfranka both bind libfranka's types: the
                    raise _BindingConflict(str(e)) from None  # one imported first keeps them (read in a new process)
                raise ValueError(f"the pickle holds {module}.{name}; reading it needs that package installed "
                                 "(pip install 'franka_vs_gym[fci]')") from None
        raise ValueError(f"the pickle holds {module}.{name}, which is not part of a robot state; only franky "
                         "states, numpy arrays and lists/dicts of them are read (nothing else is executed)")


class _BindingConflict(Exception):
    """The pickle's franky types cannot be imported here: this process has already imported pylibfranka, whose
    bindings register the same libfranka types (the two cannot be imported into one process)."""


def _read_pickle_elsewhere(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """:func:`read_pickle` in a fresh Python process (one that has not imported pylibfranka); its arrays and
    metadata come back as a pickle of numpy arrays and plain values only."""
    import subprocess
    import sys

    code = ("import pickle, sys; from franka_vs_gym.validation.readers.robot_states import read_pickle; "
            "sys.stdout.buffer.write(pickle.dumps(read_pickle(sys.argv[1])))")
    run = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, timeout=600)
    if run.returncode != 0:
        err = run.stderr.decode(errors="replace").strip().splitlines()
        raise ValueError(err[-1] if err else f"{path}: the pickle could not be read in a separate process")

    class _Plain(pickle.Unpickler):  # what read_pickle returns: numpy arrays and builtins, nothing else
        def find_class(self, module: str, name: str) -> Any:
            if (module, name) in _StateUnpickler._NUMPY | _StateUnpickler._BUILTINS:
                return super().find_class(module, name)
            raise ValueError(f"{path}: unexpected {module}.{name} from the separate reader")

    return _Plain(_pyio.BytesIO(run.stdout)).load()


def read_pickle(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A pickled list of franky RobotStates (or of dicts of arrays), read without executing anything else. In a
    process that has imported pylibfranka (franky's types then cannot be imported), it is read in a fresh one."""
    with io.open_input(path, "rb", what="log") as fh:
        try:
            obj = _StateUnpickler(fh).load()
        except _BindingConflict:
            return _read_pickle_elsewhere(Path(path))
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
        except Exception as e:  # a truncated or foreign pickle
            raise ValueError(f"{path}: not a readable pickle of robot states: {type(e).__name__}: {e}") from None
    if isinstance(obj, dict):
        lists = [v for v in obj.values() if isinstance(v, (list, tuple))]
        if len(lists) == 1:
            obj = lists[0]
    if not isinstance(obj, (list, tuple)) or not obj:
        raise ValueError(f"{path}: expected a list of robot states, got {type(obj).__name__}")
    if isinstance(obj[0], dict):
        return table_to_fields(_ticks_to_columns(list(obj), str(path)), str(path), "pickle of dicts")
    ticks = []
    names = JOINT_FIELDS + TOOL_FIELDS
    for i, s in enumerate(obj):
        if not hasattr(s, "q") or not hasattr(s, "time"):
            raise ValueError(f"{path}: item {i} ({type(s).__name__}) is not a robot state (no q or time)")
        tick = {"time_s": _duration_s(s.time)}
        for k in names:
            if hasattr(s, k):
                tick[k] = _plain(getattr(s, k)) if i == 0 or k in JOINT_FIELDS else None
        ticks.append({k: v for k, v in tick.items() if v is not None})
    kind = f"pickle of {type(obj[0]).__module__.split('.')[0]} {type(obj[0]).__name__}"
    cols = _ticks_to_columns([{k: v for k, v in t.items() if k in JOINT_FIELDS or k == "time_s"} for t in ticks],
                             str(path))
    cols.update({k: [v] for k, v in ticks[0].items() if k in TOOL_FIELDS})
    arrays, meta = table_to_fields(cols, str(path), kind)
    meta["read_as"] = meta["read_as"].replace("'time_s' in seconds (from its name)", "the states' time (Duration)")
    return arrays, meta


__all__ = ["StateRecorder", "read_csv_dump", "read_json", "read_npy", "read_npz_dump", "read_pickle", "sniff"]
