"""Readers for logs recorded by other tools: ROS 1 and ROS 2 bags, and libfranka's ``logToCSV``.

**ROS bags** (``rosbags`` package, the ``[ros]`` extra; read with its ``AnyReader``):

- ROS 1 bags (``.bag``, e.g. recorded with franka_ros on Noetic; a file with another name is recognised by its
  ``#ROSBAG V2.0`` header), a rosbag2 folder (``metadata.yaml`` with sqlite3 ``.db3`` or MCAP storage) or a bare
  ``.mcap``/``.db3`` file.
- Message types come from the definitions stored in the bag (ROS 1 connection headers, MCAP schemas, rosbag2
  ``message_definitions``), so the custom types of franka_ros and franka_ros2 need no installed ROS. A bag that stores
  no definitions at all (rosbag2 sqlite3 before format 8, e.g. Humble's) is read with the standard ROS 2 Humble types
  (ROS 1: Noetic), which know ``sensor_msgs/JointState`` but no ``franka_msgs``; such a topic is reported as
  *message definition missing from the bag*.

Two kinds of topic are read:

1. **Franka state** messages: franka_ros's ``franka_msgs/FrankaState`` (``/franka_state_controller/franka_states``:
   ``q``, ``dq``, ``tau_J``, ``tau_J_d``, ``q_d``, ``dq_d``, ``tau_ext_hat_filtered``, ``m_total``, ``F_x_Ctotal``,
   ``I_total``, ``time``, ...), franka_ros2's older ``franka_msgs/msg/FrankaState`` (the same fields in lower case,
   plus ``ddq_d``) and franka_ros2's ``franka_msgs/msg/FrankaRobotState`` (``measured_joint_state`` and
   ``desired_joint_state`` as nested ``sensor_msgs/JointState``: position/velocity/effort = q/dq/tau_J and
   q_d/dq_d/tau_J_d; ``ddq_d``; ``tau_ext_hat_filtered.effort``; ``inertia_total`` as ``geometry_msgs/Inertia``;
   ``time``). Recognised by their fields, not their names. The measured torque, the desired trajectory and the
   commanded torque fill the log's columns, and the tool the robot declared (end effector plus load: ``m_total``,
   ``F_x_Ctotal``, ``I_total``, flange frame) is the log's tool (see
   :func:`franka_vs_gym.validation.readers.fields.tool_from_state`). Time: the message's ``time`` field (the
   robot's own clock, s) when it advances, else the header stamp, else the bag's receive time.
2. ``sensor_msgs/JointState`` messages with the seven arm joints and their efforts (``effort`` = measured link-side
   torque tau_J, what franka_ros's and franka_ros2's state publishers put there). Joint names are mapped to joints
   0..6 by their trailing number: ``fer_joint1``, ``panda_joint1``, ``fr3_joint1``, ``joint1``, ``joint_1`` ... ->
   joint 0 (finger joints ignored, any order); messages without the seven arm joints (a gripper's own joint states
   merged into ``/joint_states``) are skipped. Time: the header stamp (the bag's receive time when stamps are zero).

**Topic choice**: ``topic`` if given; otherwise the Franka state topic, else the JointState topic with the seven arm
joints and efforts; among several such JointState topics, the one that carries only the arm joints (the robot
driver's own, e.g. ``/franka_state_controller/joint_states``) over one merged with finger joints and re-published
at another rate by a joint_state_publisher (``/joint_states``), else ``/joint_states``; several Franka state topics
(two arms) or several equal JointState topics are an error asking for ``--topic``. Which topic was read, why, the
other candidates and the time base are stated in the log's ``extra["read_as"]`` (every output repeats it under
``assumptions.log_read_as``). A bag with no usable topic, a topic without efforts, or a definition missing from the
bag is a one-line ``ValueError`` naming the problem and the topics found.

No gravity is declared by a bag; without a Franka state topic no tool either: the sidecar ``<bag>.json`` or
``--tool`` says which; otherwise the Franka Hand is assumed and every output says so.

**libfranka logToCSV**: the CSV ``franka::logToCSV`` writes (header ``time, success_rate, state.q[0], ...,
state.tau_J[0], ..., cmd.tau_J_d[0], ...``; ``time`` in milliseconds). ``state.X`` columns become ``X``,
``cmd.tau_J_d`` becomes ``tau_J_d`` and the time is converted to seconds.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.validation.readers.fields import joint_index

JOINTSTATE = "sensor_msgs/msg/JointState"
ROS1, ROS2 = "ROS 1", "ROS 2"
_ROS1_MAGIC = b"#ROSBAG V2.0"
_MCAP_MAGIC = b"\x89MCAP"
_SQLITE_MAGIC = b"SQLite format 3\x00"
_PROBE = 20  # messages looked at per JointState topic when choosing one
# optional log columns from a Franka state message: log name -> (flat field, nested JointState field and member)
_FLAT_OPTIONAL = {"tau_J_d": "tau_j_d", "q_d": "q_d", "dq_d": "dq_d", "ddq_d": "ddq_d",
                  "tau_ext_hat_filtered": "tau_ext_hat_filtered"}
_NESTED_OPTIONAL = {"q_d": ("desired_joint_state", "position"), "dq_d": ("desired_joint_state", "velocity"),
                    "tau_J_d": ("desired_joint_state", "effort"), "ddq_d": (None, "ddq_d"),
                    "tau_ext_hat_filtered": ("tau_ext_hat_filtered", "effort")}


def _storage_files(folder: Path) -> list[Path]:
    """The rosbag2 storage files (``.db3``, ``.mcap``) directly in ``folder`` (a bag folder whose metadata.yaml is
    missing, e.g. a recording that was interrupted or copied without it)."""
    try:
        return sorted(p for p in folder.iterdir() if p.suffix.lower() in (".db3", ".mcap") and not p.is_dir())
    except OSError:
        return []


def _bare_storage(folder: Path) -> Path:
    """The one storage file of a rosbag2 folder without metadata.yaml, read as a bare bag."""
    from franka_vs_gym import io

    files = _storage_files(folder)
    if len(files) != 1:
        raise ValueError(f"{folder}: a rosbag2 folder without metadata.yaml holding {len(files)} storage files "
                         f"{[f.name for f in files]}; pass one of them (each is read as a bare bag)")
    return io.check_input_file(files[0], what="ROS bag")


def bag_kind(path: Path) -> str | None:
    """``"ROS 1"`` for a ROS 1 bag (``.bag``, or a regular file starting with ``#ROSBAG V2.0``), ``"ROS 2"`` for a
    rosbag2 folder (with metadata.yaml) or a bare ``.mcap``/``.db3`` file (or a file with their magic bytes), else
    None."""
    path = Path(path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return ROS2
        return ROS2 if _storage_files(path) else None
    suffix = path.suffix.lower()
    if suffix == ".bag":
        return ROS1
    if suffix in (".mcap", ".db3"):
        return ROS2
    if not path.is_file():  # only regular files are sniffed (opening a FIFO would block)
        return None
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError:
        return None
    if head.startswith(_ROS1_MAGIC):
        return ROS1
    if head.startswith(_MCAP_MAGIC) or head.startswith(_SQLITE_MAGIC):
        return ROS2
    return None


def is_rosbag(path: Path) -> bool:
    """A ROS 1 bag, a rosbag2 folder (with metadata.yaml) or a bare .mcap / .db3 file (see :func:`bag_kind`)."""
    return bag_kind(path) is not None


@contextlib.contextmanager
def _open_bag(p: Path, kind: str) -> Iterator[Any]:
    """An open ``AnyReader`` on the bag, with standard types filled in for connections the bag has no definition
    of. rosbags tells ROS 1 from ROS 2 by the ``.bag`` suffix: a ROS 1 bag under another name is read through a
    temporary symbolic link (the file itself is never touched); likewise a bare MCAP or sqlite3 file."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    default = get_typestore(Stores.ROS1_NOETIC if kind == ROS1 else Stores.ROS2_HUMBLE)
    if p.is_dir() and not (p / "metadata.yaml").is_file():  # metadata.yaml missing: its storage file, bare
        p = _bare_storage(p)
    with contextlib.ExitStack() as stack:
        target = p
        want = ".bag" if kind == ROS1 else None
        if not p.is_dir() and want is None and p.suffix.lower() not in (".mcap", ".db3"):
            with open(p, "rb") as fh:
                want = ".mcap" if fh.read(5).startswith(_MCAP_MAGIC) else ".db3"
        if want is not None and p.suffix.lower() != want:
            tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="franka_vs_bag_")))
            target = tmp / f"bag{want}"
            os.symlink(p.resolve(), target)
        try:
            reader = AnyReader([target], default_typestore=default)
            reader.open()
        except Exception as exc:  # rosbags raises its own error types for malformed bags
            raise ValueError(f"{p}: not a readable {kind} bag: {' '.join(str(exc).split())}") from None
        stack.callback(reader.close)
        have = reader.typestore.fielddefs
        missing = {c.msgtype for c in reader.connections if c.msgtype not in have}
        add: dict[str, Any] = {}
        todo = [t for t in missing if t in default.fielddefs]
        while todo:  # the standard type and the types it uses, where the bag's own definitions left them out
            t = todo.pop()
            if t in add or t in have or t not in default.fielddefs:
                continue
            add[t] = default.fielddefs[t]
            todo.extend(_nested_types(default.fielddefs[t]))
        if add:
            with contextlib.suppress(Exception):
                reader.typestore.register(add)
        reader.filled_types = sorted(set(add) & missing)
        reader.bag_path = p
        yield reader


def _nested_types(fielddef: Any) -> list[str]:
    """Names of the message types a type's fields use (rosbags field descriptions: (node type, payload))."""
    def names(desc: Any) -> list[str]:
        node, payload = desc
        if int(node) == 2:  # a named message type
            return [payload]
        if int(node) in (3, 4):  # array, sequence: ((element description), size)
            return names(payload[0])
        return []

    return [n for _, desc in fielddef[1] for n in names(desc)]


def _fields(store: Any, msgtype: str) -> dict[str, Any]:
    """Field name (lower case) -> type description of a message type in the typestore."""
    return {name.lower(): desc for name, desc in store.fielddefs[msgtype][1]}


def _is_type(desc: Any, name: str) -> bool:
    return isinstance(desc, tuple) and len(desc) == 2 and desc[1] == name


def franka_layout(store: Any, msgtype: str) -> str | None:
    """``"flat"`` (franka_ros FrankaState: q, dq, tau_J arrays), ``"nested"`` (franka_ros2 FrankaRobotState:
    measured_joint_state as a JointState) or None for a message type that is not a Franka robot state."""
    if msgtype not in store.fielddefs or msgtype == JOINTSTATE:
        return None
    f = _fields(store, msgtype)
    if {"q", "dq", "tau_j"} <= set(f):
        return "flat"
    if _is_type(f.get("measured_joint_state"), JOINTSTATE):
        return "nested"
    return None


def _attr(msg: Any, name: str) -> Any:
    """A message field by its lower-case name (franka_ros writes ``tau_J``, franka_ros2 ``tau_j``), or None."""
    if hasattr(msg, name):
        return getattr(msg, name)
    for k in getattr(msg, "__dataclass_fields__", {}):
        if k.lower() == name:
            return getattr(msg, k)
    return None


def _stamp(msg: Any) -> float:
    h = getattr(msg, "header", None)
    s = getattr(h, "stamp", None)
    return 0.0 if s is None else s.sec + s.nanosec * 1e-9


def _arm_order(names: list[str]) -> list[int] | None:
    """Positions of joints 0..6 in a JointState's name list, or None when it lacks one of them."""
    return _arm_order_cached(tuple(names))


@functools.lru_cache(maxsize=64)
def _arm_order_cached(names: tuple[str, ...]) -> list[int] | None:
    idx: dict[int, int] = {}
    for k, name in enumerate(names):
        j = joint_index(name)
        if j is not None:
            idx[j] = k
    return [idx[j] for j in range(7)] if sorted(idx) == list(range(7)) else None


def _jointstate_row(msg: Any) -> tuple[str, Any]:
    """("ok", (q, dq, tau, arm_only)) or (problem, None) for one JointState message."""
    order = _arm_order(list(msg.name))
    if order is None:
        return "without the seven arm joints", None
    n = len(msg.name)
    pos, vel, eff = (np.asarray(v, dtype=float) for v in (msg.position, msg.velocity, msg.effort))
    if len(pos) < n or len(vel) < n:
        return "without velocities", None
    if len(eff) < n:
        return "without efforts (torques)", None
    return "ok", (pos[order], vel[order], eff[order], n == 7)


def _decode(reader: Any, conn: Any, raw: bytes) -> Any:
    """One message, or a one-line ValueError when its bytes do not fit the definition (a truncated message, a
    definition that is not the one it was recorded with)."""
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as exc:  # rosbags' serde errors, struct errors of a short buffer
        raise ValueError(f"{reader.bag_path}: a message on {conn.topic} cannot be decoded as {conn.msgtype} with "
                         f"the definition in the bag: {' '.join(str(exc).split()) or type(exc).__name__}") from None


def _probe_jointstate(reader: Any, conns: list[Any]) -> tuple[str | None, bool]:
    """(problem or None, arm joints only) from the first messages of a JointState topic."""
    problems: list[str] = []
    seen = 0
    for conn, _, raw in reader.messages(connections=conns):
        seen += 1
        what, row = _jointstate_row(_decode(reader, conn, raw))
        if what == "ok":
            return None, row[3]
        problems.append(what)
        if seen >= _PROBE:
            break
    if not seen:
        return "no messages", False
    worst = "without efforts (torques)" if "without efforts (torques)" in problems else problems[0]
    return f"its first {seen} messages {worst}", False


def _topic_list(topics: dict[str, Any]) -> str:
    return "[" + ", ".join(f"{t} ({c[0].msgtype})" for t, c in sorted(topics.items())) + "]"


def read_rosbag(path: str | Path, topic: str | None = None, progress: bool = False) -> tuple[dict[str, np.ndarray],
                                                                                             dict[str, Any]]:
    """Arrays (``time``, ``q``, ``dq``, ``tau_J`` and what else the topic gives) and metadata (``read_as``, the
    topic, the declared tool) read from a ROS 1 or ROS 2 bag (see the module docstring). ``progress`` shows a bar
    on stderr while the topic's messages are decoded (about 5 000-40 000 per second)."""
    try:
        import rosbags  # noqa: F401
    except ImportError:
        raise ValueError("reading ROS bags needs the 'rosbags' package: pip install 'franka_vs_gym[ros]'") from None
    p = Path(path)
    kind = bag_kind(p) or ROS2
    with _open_bag(p, kind) as reader:
        store = reader.typestore
        topics: dict[str, list[Any]] = {}
        for c in reader.connections:
            topics.setdefault(c.topic, []).append(c)
        found = _topic_list(topics)
        if not topics:
            raise ValueError(f"{p}: the {kind} bag holds no topics")
        layout: dict[str, str | None] = {}
        missing_def = []
        for t, cs in topics.items():
            mt = cs[0].msgtype
            if mt not in store.fielddefs:
                missing_def.append(t)
                layout[t] = None
            else:
                layout[t] = "jointstate" if mt == JOINTSTATE else franka_layout(store, mt)
        defs_note = ("the bag stores no message definitions" if not any(
            c.msgdef.data for cs in topics.values() for c in cs) else "")
        franka = sorted(t for t, lay in layout.items() if lay in ("flat", "nested"))
        joint = sorted(t for t, lay in layout.items() if lay == "jointstate")

        def missing_msg(t: str) -> str:
            return (f"{p}: topic {t} ({topics[t][0].msgtype}): message definition missing from the bag"
                    f"{' (' + defs_note + ', e.g. a rosbag2 sqlite3 bag before format 8)' if defs_note else ''}; "
                    f"record with MCAP storage or a newer rosbag2 (they embed definitions), or read a "
                    f"sensor_msgs/JointState topic with --topic; topics: {found}")

        notes: list[str] = []
        usable: dict[str, bool] = {}  # JointState topics with arm joints and efforts -> carries the arm joints only
        problems: dict[str, str] = {}
        for t in joint:
            problem, arm_only = _probe_jointstate(reader, topics[t])
            if problem is None:
                usable[t] = arm_only
            else:
                problems[t] = problem
        candidates = franka + sorted(usable)
        if topic is not None:
            if topic not in topics:
                raise ValueError(f"{p}: no topic {topic!r} in the bag; topics: {found}")
            if topic in missing_def:
                raise ValueError(missing_msg(topic))
            if layout[topic] is None:
                raise ValueError(f"{p}: topic {topic} is {topics[topic][0].msgtype}, neither a Franka robot state "
                                 f"(franka_msgs FrankaState/FrankaRobotState) nor sensor_msgs/JointState; topics: "
                                 f"{found}")
            if "without efforts" in problems.get(topic, ""):
                raise ValueError(f"{p}: topic {topic} carries no efforts (measured joint torques), so the model "
                                 f"cannot be compared on it ({problems[topic]}); topics: {found}")
            chosen, why = topic, "chosen with --topic"
        else:
            if len(franka) > 1:
                raise ValueError(f"{p}: several Franka state topics {franka} (several robots?); choose one with "
                                 f"--topic; topics: {found}")
            if franka:
                chosen = franka[0]
                why = ("the robot's own state (measured tau_J, desired trajectory, commanded torque, declared load), "
                       "preferred over " + (f"the JointState topics {sorted(usable)}" if usable else
                                            "JointState topics"))
            else:
                if not usable:
                    if missing_def:
                        raise ValueError(missing_msg(missing_def[0]))
                    detail = "; ".join(f"{t}: {w}" for t, w in sorted(problems.items()))
                    detail = f" ({detail})" if detail else ""
                    raise ValueError(f"{p}: no usable topic: neither a Franka robot state nor a sensor_msgs/JointState "
                                     f"with the seven arm joints and their efforts{detail}; topics: {found}")
                own = sorted(t for t, arm in usable.items() if arm)
                if len(usable) == 1:
                    chosen = candidates[0]
                    why = "the only topic with the seven arm joints and their efforts"
                elif len(own) == 1:
                    chosen = own[0]
                    why = (f"it carries only the arm joints (the driver's own), preferred over "
                           f"{[t for t in candidates if t != chosen]}, which merge other joints and re-publish them")
                elif "/joint_states" in usable:
                    chosen = "/joint_states"
                    why = f"several equal JointState topics {candidates}: /joint_states preferred"
                else:
                    raise ValueError(f"{p}: several JointState topics {candidates} carry the seven arm joints and "
                                     f"their efforts; choose one with --topic; topics: {found}")
            for t in missing_def:
                notes.append(f"{t} ({topics[t][0].msgtype}) not read: message definition missing from the bag")
        if chosen != topic:
            notes.extend(f"{t} not usable ({w})" for t, w in sorted(problems.items()))
        if defs_note:
            notes.append(f"{defs_note}: standard {'ROS 1 Noetic' if kind == ROS1 else 'ROS 2 Humble'} types assumed")
        if reader.filled_types:
            notes.append(f"standard {'ROS 1 Noetic' if kind == ROS1 else 'ROS 2 Humble'} definitions used for "
                         f"{reader.filled_types} (not stored in the bag)")
        conns = topics[chosen]
        reader.progress = _progress_bar(conns, chosen) if progress else None
        if layout[chosen] == "jointstate":
            arrays, meta, tnotes = _read_jointstate(reader, conns, p, found)
        else:
            arrays, meta, tnotes = _read_franka(reader, conns, layout[chosen], p, found)
    fmt = "ROS 1 bag" if kind == ROS1 else ("rosbag2 (MCAP)" if _is_mcap(p) else "rosbag2 (sqlite3)")
    others = [t for t in candidates if t != chosen]
    msgtype = conns[0].msgtype
    read_as = (f"{fmt}: topic {chosen} ({msgtype}), {why}"
               + (f"; other candidates {others}" if others and "preferred over" not in why else "")
               + "; " + "; ".join(tnotes + notes))
    meta.update({"source_format": fmt, "topic": chosen, "topic_type": msgtype, "topic_reason": why,
                 "topic_candidates": candidates, "read_as": read_as})
    return arrays, meta


def _progress_bar(conns: list[Any], topic: str) -> Any:
    from tqdm import tqdm

    total = sum(int(getattr(c, "msgcount", 0) or 0) for c in conns) or None
    return tqdm(total=total, desc=f"[franka-vs] reading {topic}", unit="msg", file=sys.stderr, mininterval=0.5,
                dynamic_ncols=True, leave=False)


def _messages(reader: Any, conns: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
    """The topic's messages, counted on the progress bar when there is one."""
    bar = getattr(reader, "progress", None)
    try:
        for k, item in enumerate(reader.messages(connections=conns)):
            if bar is not None and k % 1000 == 999:
                bar.update(1000)
            yield item
    finally:
        if bar is not None:
            bar.close()


def _is_mcap(p: Path) -> bool:
    if p.is_dir():
        return any(x.suffix == ".mcap" for x in p.iterdir())
    if p.suffix.lower() == ".mcap":
        return True
    with contextlib.suppress(OSError), open(p, "rb") as fh:
        return fh.read(5).startswith(_MCAP_MAGIC)
    return False


def _order_by(t: np.ndarray) -> tuple[np.ndarray, int]:
    order = np.argsort(t, kind="stable")
    return order, int((np.diff(t) < 0).sum())


def _read_jointstate(reader: Any, conns: list[Any], p: Path, found: str) -> tuple[dict, dict, list[str]]:
    stamps, recv, q, dq, tau = [], [], [], [], []
    skipped: dict[str, int] = {}
    for conn, rt, raw in _messages(reader, conns):
        msg = _decode(reader, conn, raw)
        what, row = _jointstate_row(msg)
        if what != "ok":
            skipped[what] = skipped.get(what, 0) + 1
            continue
        stamps.append(_stamp(msg))
        recv.append(rt * 1e-9)
        q.append(row[0])
        dq.append(row[1])
        tau.append(row[2])
    if not q:
        why = "; ".join(f"{n} messages {w}" for w, n in skipped.items())
        raise ValueError(f"{p}: no usable JointState message on {conns[0].topic}: {why}; topics: {found}")
    st = np.asarray(stamps)
    if (st > 0).all():
        t, tsrc = st, "time from the header stamps"
    else:
        t, tsrc = np.asarray(recv), f"time from the bag's receive time ({int((st <= 0).sum())} header stamps are zero)"
    order, back = _order_by(t)
    t = t[order]
    arrays = {"time": t - t[0], "q": np.asarray(q)[order], "dq": np.asarray(dq)[order],
              "tau_J": np.asarray(tau)[order]}
    notes = ["effort read as the measured link-side torque tau_J", f"{tsrc}, from the first sample ({t[0]:.9g} s)"]
    if back:
        notes.append(f"{back} messages out of time order, sorted")
    if skipped:
        notes.append(", ".join(f"{n} messages skipped ({w})" for w, n in skipped.items()))
    meta = {"time_source": tsrc, "time_origin_s": float(t[0]), "messages_read": len(q),
            "messages_skipped": int(sum(skipped.values()))}
    return arrays, meta, notes


def _vec(v: Any, n: int = 7) -> np.ndarray | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=float).ravel()
    return a if a.size == n else None


def _franka_tool(msg: Any, layout: str) -> dict[str, Any]:
    """The state's declared end effector plus load in tool_from_state's terms (libfranka names)."""
    if layout == "flat":
        m, c, inertia = _attr(msg, "m_total"), _attr(msg, "f_x_ctotal"), _attr(msg, "i_total")
        if m is None or c is None or inertia is None:
            return {}
        return {"m_total": float(m), "F_x_Ctotal": np.asarray(c, float), "I_total": np.asarray(inertia, float)}
    it = getattr(_attr(msg, "inertia_total"), "inertia", None)
    if it is None:
        return {}
    i = np.array([[it.ixx, it.ixy, it.ixz], [it.ixy, it.iyy, it.iyz], [it.ixz, it.iyz, it.izz]], float)
    return {"m_total": float(it.m), "F_x_Ctotal": np.array([it.com.x, it.com.y, it.com.z]),
            "I_total": i.ravel(order="F")}


def _part(obj: Any, member: str) -> np.ndarray | None:
    """(7,) arm-joint values of a nested JointState's member, in joint order (by name when it names them)."""
    v = getattr(obj, member, None) if obj is not None else None
    if v is None:
        return None
    a = np.asarray(v, dtype=float).ravel()
    names = list(getattr(obj, "name", []) or [])
    if len(names) == len(a):
        order = _arm_order(names)
        if order is not None:
            return a[order]
    return a if a.size == 7 else None


def _read_franka(reader: Any, conns: list[Any], layout: str, p: Path, found: str) -> tuple[dict, dict, list[str]]:
    from franka_vs_gym.validation.readers.fields import tool_from_state

    opt_names = list(_FLAT_OPTIONAL if layout == "flat" else _NESTED_OPTIONAL)
    cols: dict[str, list[np.ndarray | None]] = {k: [] for k in ("q", "dq", "tau_J", *opt_names)}
    robot_t, stamps, recv = [], [], []
    first: dict[str, Any] | None = None
    load_change = None
    bad = 0
    for conn, rt, raw in _messages(reader, conns):
        msg = _decode(reader, conn, raw)
        if layout == "flat":
            row = {"q": _vec(_attr(msg, "q")), "dq": _vec(_attr(msg, "dq")), "tau_J": _vec(_attr(msg, "tau_j"))}
            row.update({k: _vec(_attr(msg, f)) for k, f in _FLAT_OPTIONAL.items()})
        else:
            js = _attr(msg, "measured_joint_state")
            row = {"q": _part(js, "position"), "dq": _part(js, "velocity"), "tau_J": _part(js, "effort")}
            for k, (sub, member) in _NESTED_OPTIONAL.items():
                row[k] = _vec(_attr(msg, member)) if sub is None else _part(_attr(msg, sub), member)
        if row["q"] is None or row["dq"] is None or row["tau_J"] is None:
            bad += 1
            continue
        for k in cols:
            cols[k].append(row.get(k))
        rtime = _attr(msg, "time")
        robot_t.append(float(rtime) if rtime is not None else 0.0)
        stamps.append(_stamp(msg))
        recv.append(rt * 1e-9)
        tool = _franka_tool(msg, layout)
        if first is None:
            first = tool
        elif load_change is None and tool and first and abs(tool["m_total"] - first["m_total"]) > 1e-9:
            load_change = (first["m_total"], tool["m_total"], len(robot_t) - 1)
    n = len(robot_t)
    if n == 0:
        raise ValueError(f"{p}: no usable message on {conns[0].topic}: {bad} messages lack q, dq or tau_J (7 values); "
                         f"topics: {found}")
    rt_arr, st = np.asarray(robot_t), np.asarray(stamps)
    if np.ptp(rt_arr) > 0 and (rt_arr > 0).all():
        t, tsrc = rt_arr, "time from the messages' 'time' field (the robot's own clock)"
    elif (st > 0).all():
        t, tsrc = st, "time from the header stamps (the messages' 'time' field does not advance)"
    else:
        t, tsrc = np.asarray(recv), "time from the bag's receive time (no robot time, zero header stamps)"
    order, back = _order_by(t)
    t = t[order]
    arrays: dict[str, np.ndarray] = {"time": t - t[0]}
    notes = [f"{tsrc}, from the first sample ({t[0]:.9g} s)", "q, dq, tau_J measured"]
    got = []
    for k, v in cols.items():
        if all(x is not None and np.isfinite(x).all() for x in v):
            arrays[k] = np.asarray(v)[order]
            if k not in ("q", "dq", "tau_J"):
                got.append(k)
        elif k in ("q", "dq", "tau_J"):
            raise ValueError(f"{p}: {conns[0].topic}: {k} is not finite in every message (NaN or inf)")
    if got:
        notes.append(f"also read: {', '.join(got)}")
    if back:
        notes.append(f"{back} messages out of time order, sorted")
    if bad:
        notes.append(f"{bad} messages skipped (no q, dq or tau_J of 7 values)")
    meta: dict[str, Any] = {"time_source": tsrc, "time_origin_s": float(t[0]), "messages_read": n,
                            "messages_skipped": bad}
    if first:
        tool, src = tool_from_state(first)
        meta["tool"] = tool
        meta["tool_source"] = src.replace("the robot state's", f"the bag's {conns[0].topic}")
        if load_change is not None:
            notes.append(f"the declared load changed during the bag (m_total {load_change[0]:.4g} -> "
                         f"{load_change[1]:.4g} kg at message {load_change[2]}): the first is used")
    return arrays, meta, notes
