"""Columns of a robot-state table read as a measurement log's fields: names (``q_0``, ``q[0]``, ``state.q0``, a
ROS JointState's position/velocity/effort), the time column and its unit, and the tool the robot declared in its
state. Shared by the readers of pylibfranka/franky dumps (:mod:`.robot_states`) and of ROS bags (:mod:`.rosbag`).

Field names are libfranka's (``q``, ``dq``, ``tau_J``, ...). The time is ``time`` or ``robot_time`` (also
``time_s``, ``time_ms``: the unit from the name); otherwise its unit is detected from the median step (s: below
0.5, 2 Hz or faster; ms: 0.5-500; anything else is refused), converted to seconds from the first sample, and stated
in the log's ``extra["read_as"]``, which every workbench output repeats under ``assumptions``. Missing or malformed
fields raise ``ValueError`` in one line naming what is missing and what was found.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

JOINT_FIELDS = ("q", "dq", "tau_J", "tau_J_d", "q_d", "dq_d", "ddq_d", "tau_ext_hat_filtered")
REQUIRED = ("q", "dq", "tau_J")
# time columns in the order they are preferred, each with its unit (None: detected from the median step). The robot's
# or the message's own time first, then a header stamp (rostopic echo -p's ``field.header.stamp``, ns), then common
# generic names, then a bag's receive time (rostopic's ``%time``, ns); one that does not advance (zero stamps) is
# passed over. Names are matched in any case, after any prefix (``field.``, ``header.``, ``state.``).
TIME_NAMES = {"time": None, "robot_time": None, "time_s": "s", "time_sec": "s", "time_ms": "ms", "time_msec": "ms",
              "robot_time_ms": "ms", "robot_time_s": "s", "time_us": "us", "time_ns": "ns", "stamp": None,
              "timestamp": None, "timestamp_s": "s", "timestamp_ms": "ms", "timestamp_ns": "ns", "t": None,
              "%time": None}
#: a ROS JointState's fields, read as the log's fields when the columns carry no libfranka names
JOINT_STATE_FIELDS = {"position": "q", "velocity": "dq", "effort": "tau_J"}
#: unit -> (factor to s, its name, the median step range read as this unit when the name does not say it)
_UNITS = {"s": (1.0, "seconds"), "ms": (1e-3, "milliseconds"), "us": (1e-6, "microseconds"),
          "ns": (1e-9, "nanoseconds")}
SIDECAR_KEYS = {"tool", "gravity", "controller"}
TOOL_FIELDS = ("m_total", "F_x_Ctotal", "I_total", "m_ee", "F_x_Cee", "I_ee", "m_load", "F_x_Cload", "I_load",
               "O_ddP_O")
# column name -> (base name, joint index or None): prefixes such as "state." or "robot_state/" are dropped
_NAME = re.compile(r"^(?:[A-Za-z_][A-Za-z0-9_]*[./:])*(?P<base>[A-Za-z_][A-Za-z0-9_]*?)"
                   r"(?:\[(?P<a>\d+)\]|[._](?P<b>\d+)|(?P<c>\d+))?$")
_JOINT = re.compile(r"^(?:.*?[_/])?joint[_]?([1-7])$")


def joint_index(name: str) -> int | None:
    """FER joint index 0..6 of a JointState name (``fer_joint1`` -> 0), or None (fingers, other joints)."""
    n = name.strip().lower()
    if "finger" in n:
        return None
    m = _JOINT.match(n)
    return int(m.group(1)) - 1 if m else None


def tool_from_state(s: dict[str, Any]) -> tuple[Any, str]:
    """The tool the robot declared in its state: end effector plus load (``m_total``, ``F_x_Ctotal``, ``I_total``,
    or their ``_ee``/``_load`` parts), flange frame, inertia about the centre of mass (libfranka's 3x3 arrays are
    column-major). Returns ``(tool, where it came from)``: ``"franka_hand"`` when it is the Franka Hand, None when
    the mass is zero, else a ``{"mass", "com", "inertia"}`` dict; ``"franka_hand"`` (assumed) when the state has
    none of these fields."""
    from franka_vs_gym.model.config import Tool
    from franka_vs_gym.model.geometry import combine_inertials

    def body(suffix: str):
        m, c, inertia = (s.get(k + suffix) for k in ("m_", "F_x_C", "I_"))
        if m is None or c is None or inertia is None:
            return None
        c, inertia = np.asarray(c, float).ravel(), np.asarray(inertia, float).ravel()
        if c.size != 3 or inertia.size != 9:
            return None
        return float(np.ravel(m)[0]), c, inertia.reshape(3, 3, order="F")

    b = body("total")
    if b is None and body("ee") is not None:
        parts = [p for p in (body("ee"), body("load")) if p is not None]
        b = combine_inertials(parts)
        where = "the robot state's m_ee/m_load (end effector + load)"
    else:
        where = "the robot state's m_total, F_x_Ctotal, I_total (end effector + load)"
    if b is None:
        return "franka_hand", "not in the robot state: the Franka Hand assumed"
    m, c, inertia = b
    if m <= 0:
        return None, where + ": no tool"
    hand = Tool.franka_hand().body
    if (abs(m - hand.mass) < 1e-4 and np.abs(c - hand.com).max() < 1e-4
            and np.abs(inertia - hand.inertia).max() < 1e-5):
        return "franka_hand", where + ": the Franka Hand"
    return {"mass": m, "com": c.tolist(), "inertia": inertia.tolist()}, where


# ------------------------------------------------------------------------------------------------- columns
def parse_name(name: str) -> tuple[str, int | None] | None:
    """``state.q[3]`` -> ("q", 3), ``q_3``/``q.3``/``q3`` -> ("q", 3), ``q`` -> ("q", None); rostopic's ``%time`` ->
    ("%time", None); None if no match."""
    if name.strip() == "%time":
        return "%time", None
    m = _NAME.match(name.strip())
    if not m:
        return None
    idx = next((m.group(g) for g in "abc" if m.group(g) is not None), None)
    return m.group("base"), (None if idx is None else int(idx))


def time_to_seconds(t: np.ndarray, name: str, unit: str | None, where: str) -> tuple[np.ndarray, str]:
    """Time column -> seconds from the first sample, and a sentence saying how it was read."""
    t = np.asarray(t, dtype=np.float64)
    if not np.isfinite(t).all():
        raise ValueError(f"{where}: {name!r} contains NaN or inf (first at row {int(np.argmax(~np.isfinite(t)))})")
    steps = np.diff(t)
    pos = steps[steps > 0]
    med = float(np.median(pos)) if len(pos) else 0.0
    how = "from its name"
    if unit is None:
        from franka_vs_gym.validation.logs import MAX_STEP_S

        how = f"detected from its median step {med:.4g}"
        if 0 < med < MAX_STEP_S:  # 2 Hz or faster in seconds; in ms that would be 2 kHz or faster
            unit = "s"
        elif MAX_STEP_S <= med < 1e3 * MAX_STEP_S:  # 2 kHz to 2 Hz in milliseconds
            unit = "ms"
        elif 1e6 * MAX_STEP_S <= med < 1e9 * MAX_STEP_S:  # 2 kHz to 2 Hz in nanoseconds (ROS stamps, time_ns)
            unit = "ns"
        else:  # between: microseconds, or a sample index times a constant; the name must say it (time_us)
            raise ValueError(f"{where}: cannot tell the unit of {name!r} (median step {med:.4g}): expected seconds "
                             f"(step < {MAX_STEP_S:g}, 2 Hz or faster), milliseconds (step {MAX_STEP_S:g}-"
                             f"{1e3 * MAX_STEP_S:g}) or nanoseconds (step {1e6 * MAX_STEP_S:g}-{1e9 * MAX_STEP_S:g}); "
                             "name the column time_s, time_ms, time_us or time_ns to say it")
    scale, word = _UNITS[unit]
    out = (t - t[0]) * scale
    text = (f"time from {name!r} in {word} ({how}), converted to s from its first sample ({t[0] * scale:.6g} s)")
    return out, text


def table_to_fields(cols: dict[str, np.ndarray], where: str, kind: str) -> tuple[dict[str, np.ndarray],
                                                                                  dict[str, Any]]:
    """Arrays of a log (``time`` in s, joint fields (N, 7)) from named columns of any of the dump layouts.

    ``cols`` maps column names to (N,) or (N, k) float arrays (or, for unneeded columns, anything). Returns the
    arrays and metadata (``read_as``, ``source_format``, the declared tool when the columns carry it)."""
    groups: dict[str, dict[int | None, tuple[str, Any]]] = {}
    for name, v in cols.items():
        parsed = parse_name(name)
        if parsed is None:
            continue
        base, idx = parsed
        slot = groups.setdefault(base, {})
        if idx in slot:
            prev = slot[idx][0]
            # keep the state's own value over a command's (logToCSV-like "state.x" and "cmd.x")
            if not re.match(r"^(?:cmd|command|c)[./]", name, re.I) and re.match(r"^(?:cmd|command|c)[./]", prev,
                                                                                   re.I):
                slot[idx] = (name, v)
                continue
            if re.match(r"^(?:cmd|command|c)[./]", name, re.I):
                continue
            raise ValueError(f"{where}: columns {prev!r} and {name!r} both give {base}"
                             f"{'' if idx is None else f'[{idx}]'}")
        slot[idx] = (name, v)
    found = sorted(groups)
    notes: list[str] = []
    _joint_state_columns(groups, where, notes)
    _split_stamp(groups, where)
    times = [(k, g) for name in TIME_NAMES for k, g in groups.items() if k.lower() == name and None in g]
    if not times:
        raise ValueError(f"{where}: no time field (looked for 'time' or 'robot_time', in s or ms); also looked for "
                         f"{', '.join(repr(k) for k in list(TIME_NAMES)[8:])}; found {_short(found)}")
    n = None
    out: dict[str, np.ndarray] = {}
    for f in JOINT_FIELDS:
        g = groups.get(f)
        if not g:
            if f in REQUIRED:
                item = "array" if kind.startswith("NPZ") else "field"
                raise ValueError(f"{where}: no {_WHAT[f]} {f!r} (missing {item} {f!r}; looked for {f}, {f}[0], "
                                 f"{f}_0, {f}0, {f}.0 ...); found {_short(found)}")
            continue
        if None in g:
            a = _floats(g[None][1], g[None][0], where)
            if a.ndim != 2:
                raise ValueError(f"{where}: {g[None][0]!r} holds one value per sample; {f} needs 7 (one per joint)")
            if a.shape[1] != 7:
                raise ValueError(f"{where}: {g[None][0]!r} has {a.shape[1]} values per sample; the FER has 7 joints")
        else:
            idx = sorted(k for k in g if k is not None)
            if idx == list(range(1, 8)):
                notes.append(f"{f} columns numbered 1..7 read as joints 0..6")
                idx_map = {i: i + 1 for i in range(7)}
            elif idx == list(range(7)):
                idx_map = {i: i for i in range(7)}
            else:
                base = 1 if idx and idx[0] == 1 else 0
                missing = [f"{f}[{i}]" for i in range(base, base + 7) if i not in idx]
                raise ValueError(f"{where}: {f} has joints {idx}; the FER has 7 joints (indices 0..6 or 1..7)"
                                 + (f"; missing {missing}" if missing else ""))
            a = np.column_stack([_floats(g[idx_map[i]][1], g[idx_map[i]][0], where).ravel() for i in range(7)])
        if n is None:
            n = len(a)
        elif len(a) != n:
            raise ValueError(f"{where}: {f} has {len(a)} samples, the other fields {n}")
        out[f] = a
    for k, (base, g) in enumerate(times):
        tname, unit = g[None][0], TIME_NAMES[base.lower()]
        t = _floats(g[None][1], tname, where)
        if t.ndim == 2 and t.shape[1] == 1:
            t = t[:, 0]
        if t.ndim != 1 or len(t) != n:
            raise ValueError(f"{where}: {tname!r} must hold one number per sample ({n}), got shape {t.shape}")
        if k + 1 < len(times) and np.isfinite(t).all() and not (np.diff(t) > 0).any():
            notes.append(f"{tname!r} does not advance: passed over")
            continue
        break
    out["time"], read_as = time_to_seconds(t, tname, unit, where)
    meta: dict[str, Any] = {"source_format": kind, "read_as": "; ".join([f"{kind}: {read_as}"] + notes)}
    state = {}
    for k in TOOL_FIELDS:
        g = groups.get(k)
        if g and None in g:
            try:
                state[k] = np.asarray(_floats(g[None][1], k, where))[0]
            except ValueError:
                pass
    if state:
        tool, src = tool_from_state(state)
        if not src.startswith("not in"):
            meta["tool"] = tool
            meta["tool_source"] = src
        if "O_ddP_O" in state and np.linalg.norm(state["O_ddP_O"]) > 0:
            meta["gravity"] = np.asarray(state["O_ddP_O"], float).ravel().tolist()
    return out, meta


_WHAT = {"q": "joint positions", "dq": "joint velocities", "tau_J": "measured joint torques"}


#: a stamp written as two columns: ROS 2's builtin_interfaces/Time (sec, nanosec), ROS 1's time (secs, nsecs)
_STAMP_PARTS = (("sec", "nanosec"), ("secs", "nsecs"))


def _split_stamp(groups: dict[str, dict[int | None, tuple[str, Any]]], where: str) -> None:
    """``header.stamp.sec`` + ``header.stamp.nanosec`` (or ``secs`` + ``nsecs``) -> one ``stamp`` column in ns,
    named after both (when no column is a stamp already). Changes ``groups`` in place."""
    if any(k.lower() == "stamp" for k in groups):
        return
    for s_name, ns_name in _STAMP_PARTS:
        a, b = groups.get(s_name, {}).get(None), groups.get(ns_name, {}).get(None)
        if a is not None and b is not None:
            sec, nsec = _floats(a[1], a[0], where), _floats(b[1], b[0], where)
            if sec.shape == nsec.shape and sec.ndim == 1:
                groups["stamp"] = {None: (f"{a[0]} + {b[0]}", sec * 1e9 + nsec)}
                return


def _names_of(g: dict[int | None, tuple[str, Any]]) -> list[str]:
    """The joint names of a JointState ``name`` column: one list cell (``"['panda_joint1', ...]"``) or one column
    per joint (rostopic's ``field.name0``...), read from the first sample."""
    if None in g:
        v = g[None][1]
        first = v[0] if isinstance(v, (list, np.ndarray)) and len(v) else v
        if isinstance(first, (list, tuple)):
            return [str(x) for x in first]
        return [x.strip(" '\"") for x in re.split(r"[,;\s]+", str(first).strip().strip("[]()")) if x.strip(" '\"")]
    return [str(g[i][1][0]).strip(" '\"") for i in sorted(k for k in g if k is not None)]


def _joint_state_columns(groups: dict[str, dict[int | None, tuple[str, Any]]], where: str, notes: list[str]) -> None:
    """A ROS JointState written as a table (rostopic echo -p: ``field.position0``..., ``field.name0``...; or whole
    ``position``/``velocity``/``effort`` list cells): read as q, dq, tau_J when no libfranka-named columns are there,
    the arm's seven joints picked by their names (the hand's fingers left out). Changes ``groups`` in place."""

    present = [s for s in JOINT_STATE_FIELDS if s in groups]
    if not present or any(f in groups for f in REQUIRED):
        return
    names = _names_of(groups["name"]) if "name" in groups else None
    pick = None
    if names:
        idx = [joint_index(x) for x in names]
        pick = [idx.index(j) if idx.count(j) == 1 else None for j in range(7)]
        if None in pick:
            raise ValueError(f"{where}: the joint names {names} do not name the arm's seven joints once each (e.g. "
                             "panda_joint1..7, fr3_joint1..7)")
    for s in present:
        g = groups.pop(s)
        if None in g:
            a = _floats(g[None][1], g[None][0], where)
            if a.ndim == 2 and pick is not None and a.shape[1] == len(names):
                a = a[:, pick]
            elif a.ndim == 2 and a.shape[1] != 7:
                raise ValueError(f"{where}: {g[None][0]!r} has {a.shape[1]} values per sample and no joint names "
                                 "say which are the arm's seven")
            groups[JOINT_STATE_FIELDS[s]] = {None: (g[None][0], a)}
        else:
            cols = sorted(k for k in g if k is not None)
            if pick is not None:
                if cols != list(range(len(names))):
                    raise ValueError(f"{where}: {s} has columns {cols} but there are {len(names)} joint names")
                g = {j: g[pick[j]] for j in range(7)}
            elif len(cols) != 7:
                raise ValueError(f"{where}: {s} has {len(cols)} joint columns and no joint names say which are the "
                                 "arm's seven")
            groups[JOINT_STATE_FIELDS[s]] = g
    notes.append("JointState columns " + "/".join(present) + " read as " + "/".join(JOINT_STATE_FIELDS[s]
                                                                                      for s in present)
                 + (f", the arm's joints by name ({', '.join(names[i] for i in pick)})" if pick else ""))


def _short(names: list[str], k: int = 12) -> str:
    return ("[" + ", ".join(names[:k]) + (", ..." if len(names) > k else "") + "]") if names else "nothing usable"


def _floats(v: Any, name: str, where: str) -> np.ndarray:
    if isinstance(v, np.ndarray) and v.dtype.kind in "fiub":
        return v.astype(np.float64, copy=False)
    if isinstance(v, list) and v and isinstance(v[0], str):
        return _parse_cells(v, name, where)
    try:
        return np.array(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name!r} is not numeric (or its rows have different lengths)") from None


_SPLIT = re.compile(r"[\s,;]+")


def _parse_cells(cells: list[str], name: str, where: str) -> np.ndarray:
    """CSV cells of one column: numbers, or whole lists (``[0.1, 0.2]``, ``[0.1 0.2]``, ``(0.1, 0.2)``)."""
    rows = []
    width = None
    for r, c in enumerate(cells):
        s = c.strip().strip("[]()")
        if len(s) > 100_000:  # no list of seven numbers is this long: a blob in the column or a corrupt file
            raise ValueError(f"{where}: line {r + 2}: column {name!r} holds a value of {len(s)} characters "
                             f"({s[:16]}...), not a number or a list of numbers (a blob or a corrupt file?)")
        try:
            vals = [float(x) for x in _SPLIT.split(s.strip()) if x] if s.strip() else []
        except ValueError:
            raise ValueError(f"{where}: line {r + 2}: column {name!r} holds {c.strip()[:40]!r}, not a number or a "
                             "list of numbers") from None
        if width is None:
            width = len(vals)
        elif len(vals) != width:
            raise ValueError(f"{where}: line {r + 2}: column {name!r} has {len(vals)} values, line 2 has {width}")
        rows.append(vals)
    a = np.array(rows, dtype=np.float64)
    return a[:, 0] if a.ndim == 2 and a.shape[1] == 1 and not cells[0].strip().startswith(("[", "(")) else a


__all__ = ["JOINT_FIELDS", "REQUIRED", "TIME_NAMES", "TOOL_FIELDS", "joint_index", "parse_name", "table_to_fields",
           "time_to_seconds", "tool_from_state"]
