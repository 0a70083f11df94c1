"""Readers for logs recorded by other tools: ROS 2 bags of ``sensor_msgs/JointState`` and libfranka's ``logToCSV``.

**ROS 2 bags** (``rosbags`` package, the ``[ros]`` extra): a rosbag2 folder (``metadata.yaml`` with sqlite3 ``.db3``
or MCAP storage) or a bare ``.mcap``/``.db3`` file. The JointState topic is ``topic`` if given, else the only
JointState topic, else ``/joint_states``. Joint names are mapped to the FER's joints 0..6 by their trailing number:
``fer_joint1``, ``panda_joint1``, ``fr3_joint1``, ``joint1``, ``joint_1`` ... -> joint 0 (finger joints are
ignored); messages that do not carry all seven arm joints (e.g. a gripper's own joint states on the same topic) are
skipped. Time is the message header stamp (the bag's receive time when the stamp is zero). ``position`` -> ``q``,
``velocity`` -> ``dq``, ``effort`` -> ``tau_J`` (franka_ros2 publishes the measured link-side torque there; a
bag whose effort is empty cannot be compared). No tool is declared by a bag: the sidecar ``<bag>.json`` or
``--tool`` says which; otherwise the Franka Hand is assumed and every output says so.

**libfranka logToCSV**: the CSV ``franka::logToCSV`` writes (header ``time, success_rate, state.q[0], ...,
state.tau_J[0], ..., cmd.tau_J_d[0], ...``; ``time`` in milliseconds). ``state.X`` columns become ``X``,
``cmd.tau_J_d`` becomes ``tau_J_d`` and the time is converted to seconds.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

_JOINT = re.compile(r"^(?:.*?[_/])?joint[_]?([1-7])$")
JOINTSTATE = "sensor_msgs/msg/JointState"


def joint_index(name: str) -> int | None:
    """FER joint index 0..6 of a JointState name (``fer_joint1`` -> 0), or None (fingers, other joints)."""
    n = name.strip().lower()
    if "finger" in n:
        return None
    m = _JOINT.match(n)
    return int(m.group(1)) - 1 if m else None


def is_rosbag(path: Path) -> bool:
    """A rosbag2 folder (with metadata.yaml) or a bare .mcap / .db3 file."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix.lower() in (".mcap", ".db3")


def read_rosbag(path: str | Path, topic: str | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Arrays (``time``, ``q``, ``dq``, ``tau_J``) and metadata read from a ROS 2 bag (see the module docstring)."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ValueError("reading ROS bags needs the 'rosbags' package: pip install 'franka_vs_gym[ros]'") from None
    p = Path(path)
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    try:
        reader = AnyReader([p], default_typestore=typestore)
        reader.open()
    except Exception as exc:  # rosbags raises its own error types for malformed bags
        raise ValueError(f"{p}: not a readable ROS 2 bag: {exc}") from None
    try:
        js = [c for c in reader.connections if c.msgtype == JOINTSTATE]
        topics = sorted({c.topic for c in js})
        if topic is not None:
            js = [c for c in js if c.topic == topic]
            if not js:
                raise ValueError(f"{p}: no sensor_msgs/JointState topic {topic!r}; JointState topics: "
                                 f"{topics or 'none'}")
        elif len(topics) > 1:
            if "/joint_states" in topics:
                js = [c for c in js if c.topic == "/joint_states"]
            else:
                raise ValueError(f"{p}: several JointState topics {topics}; choose one with --topic")
        if not js:
            others = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
            raise ValueError(f"{p}: no sensor_msgs/JointState topic (topics: {others or 'none'})")
        t, q, dq, tau = [], [], [], []
        skipped = 0
        no_effort = 0
        for conn, stamp, raw in reader.messages(connections=js):
            msg = reader.deserialize(raw, conn.msgtype)
            idx = {}
            for k, name in enumerate(msg.name):
                j = joint_index(name)
                if j is not None:
                    idx[j] = k
            if sorted(idx) != list(range(7)):
                skipped += 1
                continue
            order = [idx[j] for j in range(7)]
            pos, vel, eff = (np.asarray(v, dtype=float) for v in (msg.position, msg.velocity, msg.effort))
            if len(pos) < len(msg.name) or len(vel) < len(msg.name):
                skipped += 1
                continue
            if len(eff) < len(msg.name):
                no_effort += 1
                continue
            hs = msg.header.stamp
            ts = hs.sec + hs.nanosec * 1e-9 if (hs.sec or hs.nanosec) else stamp * 1e-9
            t.append(ts)
            q.append(pos[order])
            dq.append(vel[order])
            tau.append(eff[order])
    finally:
        reader.close()
    if not t:
        why = (f"{no_effort} messages have no effort (torque)" if no_effort else
               f"{skipped} messages lack the seven arm joints (names like fer_joint1..fer_joint7)")
        raise ValueError(f"{p}: no usable JointState message on {topics}: {why}")
    t_arr = np.asarray(t)
    order = np.argsort(t_arr, kind="stable")  # stamps of a bag are in receive order; sort by header stamp
    arrays = {"time": t_arr[order] - t_arr[order][0], "q": np.asarray(q)[order], "dq": np.asarray(dq)[order],
              "tau_J": np.asarray(tau)[order]}
    meta = {"source_format": "rosbag2", "topic": js[0].topic, "messages_skipped": skipped,
            "messages_without_effort": no_effort, "time_origin_s": float(t_arr.min())}
    return arrays, meta


def is_libfranka_csv(header: list[str]) -> bool:
    """A header written by libfranka's logToCSV (``state.q[0]`` columns)."""
    return any(h.strip().startswith("state.q[") for h in header)


def libfranka_columns(header: list[str]) -> tuple[list[str], float]:
    """Column names of a logToCSV header renamed to the log format, and the factor converting its time to s."""
    names = []
    for h in header:
        h = h.strip()
        if h.startswith("state."):
            names.append(h[len("state."):])
        elif h.startswith("cmd.tau_J_d"):
            names.append(h[len("cmd."):])
        elif h.startswith("cmd."):
            names.append("cmd_" + h[len("cmd."):].replace("[", "_").replace("]", ""))
        else:
            names.append(h)
    return names, 1e-3


__all__ = ["is_libfranka_csv", "is_rosbag", "joint_index", "libfranka_columns", "read_rosbag"]
