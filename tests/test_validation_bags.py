"""Real FER recordings as other labs make them: ROS 1 bags of franka_ros (FrankaState + JointState + a merged
/joint_states with the fingers at another rate) and ROS 2 bags of franka_ros2 (FrankaRobotState, MCAP and sqlite3),
written with rosbags' own writers from a simulated FER run, read back and diagnosed.

The message definitions below are typed from the field lists published in franka_ros (``franka_msgs/msg/
FrankaState.msg``, ``Errors.msg``) and franka_ros2 (``franka_msgs/msg/FrankaRobotState.msg``,
``CollisionIndicators.msg``, ``Elbow.msg``, ``Errors.msg``); the bags embed them as real recordings do.
"""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from franka_vs_gym.model.config import Tool  # noqa: E402
from franka_vs_gym.validation.diagnose import diagnose  # noqa: E402
from franka_vs_gym.validation.hidden import make_hidden_effect_log  # noqa: E402
from franka_vs_gym.validation.loading import load_log  # noqa: E402

_ERRORS_ROS1 = [
    "joint_position_limits_violation", "cartesian_position_limits_violation", "self_collision_avoidance_violation",
    "joint_velocity_violation", "cartesian_velocity_violation", "force_control_safety_violation", "joint_reflex",
    "cartesian_reflex", "max_goal_pose_deviation_violation", "max_path_pose_deviation_violation",
    "cartesian_velocity_profile_safety_violation", "joint_position_motion_generator_start_pose_invalid",
    "joint_motion_generator_position_limits_violation", "joint_motion_generator_velocity_limits_violation",
    "joint_motion_generator_velocity_discontinuity", "joint_motion_generator_acceleration_discontinuity",
    "cartesian_position_motion_generator_start_pose_invalid", "cartesian_motion_generator_elbow_limit_violation",
    "cartesian_motion_generator_velocity_limits_violation", "cartesian_motion_generator_velocity_discontinuity",
    "cartesian_motion_generator_acceleration_discontinuity", "cartesian_motion_generator_elbow_sign_inconsistent",
    "cartesian_motion_generator_start_elbow_invalid", "cartesian_motion_generator_joint_position_limits_violation",
    "cartesian_motion_generator_joint_velocity_limits_violation",
    "cartesian_motion_generator_joint_velocity_discontinuity",
    "cartesian_motion_generator_joint_acceleration_discontinuity",
    "cartesian_position_motion_generator_invalid_frame", "force_controller_desired_force_tolerance_violation",
    "controller_torque_discontinuity", "start_elbow_sign_inconsistent", "communication_constraints_violation",
    "power_limit_violation"]
_ERRORS_ROS2 = _ERRORS_ROS1 + ["joint_p2p_insufficient_torque_for_planning", "tau_j_range_violation",
                               "instability_detected"]
_MODES = "\n".join(f"uint8 ROBOT_MODE_{m}={i}" for i, m in enumerate(
    ("OTHER", "IDLE", "MOVE", "GUIDING", "REFLEX", "USER_STOPPED", "AUTOMATIC_ERROR_RECOVERY")))


def _ros1_franka_state() -> str:
    """franka_ros franka_msgs/FrankaState (Noetic), field list as published."""
    arrays = [("6", "cartesian_collision"), ("6", "cartesian_contact"), ("7", "q"), ("7", "q_d"), ("7", "dq"),
              ("7", "dq_d"), ("7", "theta"), ("7", "dtheta"), ("7", "tau_J"), ("7", "dtau_J"), ("7", "tau_J_d"),
              ("6", "K_F_ext_hat_K"), ("2", "elbow"), ("2", "elbow_d"), ("7", "joint_collision"),
              ("7", "joint_contact"), ("6", "O_F_ext_hat_K"), ("7", "tau_ext_hat_filtered")]
    body = ["std_msgs/Header header"] + [f"float64[{n}] {f}" for n, f in arrays]
    body += ["float64 m_ee", "float64[3] F_x_Cee", "float64[9] I_ee", "float64 m_load", "float64[3] F_x_Cload",
             "float64[9] I_load", "float64 m_total", "float64[3] F_x_Ctotal", "float64[9] I_total",
             "float64[16] O_T_EE", "float64[16] O_T_EE_d", "float64[16] F_T_EE", "float64[16] EE_T_K",
             "float64 time", "float64 control_command_success_rate", _MODES, "uint8 robot_mode",
             "franka_msgs/Errors current_errors", "franka_msgs/Errors last_motion_errors"]
    return "\n".join(body) + "\n"


def _ros2_franka_robot_state() -> dict[str, str]:
    """franka_ros2 franka_msgs/msg/FrankaRobotState and the franka_msgs types it uses, field lists as published."""
    return {
        "franka_msgs/msg/CollisionIndicators": "\n".join(
            [f"geometry_msgs/Vector3 is_cartesian_{a}_{b}" for b in ("collision", "contact")
             for a in ("linear", "angular")] + ["float64[7] is_joint_collision", "float64[7] is_joint_contact"]),
        "franka_msgs/msg/Elbow": "\n".join(f"float64[2] {f}" for f in (
            "position", "desired_position", "commanded_position", "commanded_velocity", "commanded_acceleration")),
        "franka_msgs/msg/Errors": "\n".join(f"bool {e}" for e in _ERRORS_ROS2),
        "franka_msgs/msg/FrankaRobotState": "\n".join([
            "std_msgs/Header header", "CollisionIndicators collision_indicators",
            "sensor_msgs/JointState measured_joint_state", "sensor_msgs/JointState desired_joint_state",
            "sensor_msgs/JointState measured_joint_motor_state", "float64[7] ddq_d", "float64[7] dtau_j",
            "sensor_msgs/JointState tau_ext_hat_filtered", "Elbow elbow",
            "geometry_msgs/WrenchStamped k_f_ext_hat_k", "geometry_msgs/WrenchStamped o_f_ext_hat_k",
            "geometry_msgs/InertiaStamped inertia_ee", "geometry_msgs/InertiaStamped inertia_load",
            "geometry_msgs/InertiaStamped inertia_total", "geometry_msgs/PoseStamped o_t_ee",
            "geometry_msgs/PoseStamped o_t_ee_d", "geometry_msgs/PoseStamped o_t_ee_c",
            "geometry_msgs/PoseStamped f_t_ee", "geometry_msgs/PoseStamped ee_t_k",
            "geometry_msgs/TwistStamped o_dp_ee_d", "geometry_msgs/TwistStamped o_dp_ee_c",
            "geometry_msgs/AccelStamped o_ddp_ee_c", "float64 time", "float64 control_command_success_rate",
            _MODES, "uint8 robot_mode", "Errors current_errors", "Errors last_motion_errors"]),
    }


ARM = [f"fer_joint{i}" for i in range(1, 8)]
FINGERS = ["fer_finger_joint1", "fer_finger_joint2"]
HAND = Tool.franka_hand().body
T0 = 1700000000.0  # wall-clock epoch of the header stamps
ROBOT_T0 = 523.417  # the robot's own clock (s since it booted)


@pytest.fixture(scope="module")
def source():
    """A 6 s simulated FER run with an undeclared payload, and its diagnosis."""
    log, answer = make_hidden_effect_log("payload", 7, duration=6.0)
    return log, answer, diagnose(log)


def _schedule(log, step: int, seed: int):
    """Sample indices at 1000/step Hz with a 40 ms gap, header stamps with 0.3 ms jitter, receive times after them."""
    rng = np.random.default_rng(seed)
    idx = np.arange(0, log.n, step)
    g = len(idx) // 2
    idx = idx[(idx < idx[g]) | (idx >= idx[g] + 40)]
    stamp = T0 + log.time[idx] + rng.normal(0, 3e-4, len(idx))
    recv = stamp + 1e-3 + rng.exponential(5e-4, len(idx))
    return idx, stamp, recv


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _time(ts, t: float):
    sec = int(t)
    return ts.types["builtin_interfaces/msg/Time"](sec, int(round((t - sec) * 1e9)))


def _write_ros1(path: Path, log, step: int = 4) -> np.ndarray:
    """franka_ros on Noetic: franka_states and joint_states of the state controller at 1000/step Hz, the gripper's
    finger joints at 30 Hz, and joint_state_publisher's merged /joint_states at 100 Hz. Returns the sample indices."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    typs = get_types_from_msg("\n".join(f"bool {e}" for e in _ERRORS_ROS1), "franka_msgs/msg/Errors")
    typs.update(get_types_from_msg(_ros1_franka_state(), "franka_msgs/msg/FrankaState"))
    ts.register(typs)
    FS, JS, H = (ts.types[k] for k in ("franka_msgs/msg/FrankaState", JOINTSTATE1, "std_msgs/msg/Header"))
    Err = ts.types["franka_msgs/msg/Errors"]
    no_err = Err(*([False] * len(_ERRORS_ROS1)))
    idx, stamp, recv = _schedule(log, step, 11)
    z = np.zeros
    out = []  # (receive time, connection key, message)
    for k, i in enumerate(idx):
        h = H(k, _time(ts, stamp[k]), "")
        fs = FS(h, z(6), z(6), log.q[i], log.q_d[i], log.dq[i], log.dq_d[i], log.q[i], log.dq[i], log.tau_J[i],
                z(7), log.tau_J_d[i], z(6), z(2), z(2), z(7), z(7), z(6), log.tau_J[i] - log.tau_J_d[i],
                HAND.mass, HAND.com, HAND.inertia.ravel(order="F"), 0.0, z(3), z(9),
                HAND.mass, HAND.com, HAND.inertia.ravel(order="F"), np.eye(4).ravel(), np.eye(4).ravel(),
                np.eye(4).ravel(), np.eye(4).ravel(), ROBOT_T0 + log.time[i], 1.0, 2, no_err, no_err)
        out.append((recv[k], "fs", fs))
        out.append((recv[k] + 2e-5, "js", JS(h, ARM, log.q[i], log.dq[i], log.tau_J[i])))
    for k in range(0, len(idx), max(1, 10 // step)):  # merged at 100 Hz: arm + fingers, the publisher's own stamp
        i = idx[k]
        t = stamp[k] + 2e-3
        out.append((t + 1e-4, "merged", JS(H(k, _time(ts, t), ""), ARM + FINGERS, np.r_[log.q[i], 0.04, 0.04],
                                          np.r_[log.dq[i], 0, 0], np.r_[log.tau_J[i], 0, 0])))
    for t in np.arange(stamp[0], stamp[-1], 1 / 30):  # the gripper alone: fingers only
        out.append((t + 1e-4, "gripper", JS(H(0, _time(ts, t), ""), FINGERS, np.full(2, 0.04), z(2), z(2))))
    out.sort(key=lambda x: x[0])
    with Writer(path) as w:
        c = {"fs": w.add_connection("/franka_state_controller/franka_states", FS.__msgtype__, typestore=ts),
             "js": w.add_connection("/franka_state_controller/joint_states", JOINTSTATE1, typestore=ts),
             "merged": w.add_connection("/joint_states", JOINTSTATE1, typestore=ts),
             "gripper": w.add_connection("/franka_gripper/joint_states", JOINTSTATE1, typestore=ts)}
        for t, key, msg in out:
            w.write(c[key], _ns(t), ts.serialize_ros1(msg, c[key].msgtype))
    return idx


JOINTSTATE1 = "sensor_msgs/msg/JointState"


def _write_ros2(path: Path, log, storage: str, step: int = 2) -> np.ndarray:
    """franka_ros2: FrankaRobotState from the state broadcaster and /franka/joint_states at 1000/step Hz, the
    merged /joint_states (arm + fingers) at 50 Hz. Returns the sample indices."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    typs = {}
    for name, text in _ros2_franka_robot_state().items():
        typs.update(get_types_from_msg(text, name))
    ts.register(typs)
    T = ts.types
    RS, JS, H = T["franka_msgs/msg/FrankaRobotState"], T[JOINTSTATE1], T["std_msgs/msg/Header"]
    V3, W, WS = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Wrench"], T["geometry_msgs/msg/WrenchStamped"]
    In, InS = T["geometry_msgs/msg/Inertia"], T["geometry_msgs/msg/InertiaStamped"]
    P, Pt, Qn, PS = (T[f"geometry_msgs/msg/{k}"] for k in ("Pose", "Point", "Quaternion", "PoseStamped"))
    Tw, TwS, Ac, AcS = (T[f"geometry_msgs/msg/{k}"] for k in ("Twist", "TwistStamped", "Accel", "AccelStamped"))
    CI, El, Err = (T[f"franka_msgs/msg/{k}"] for k in ("CollisionIndicators", "Elbow", "Errors"))
    v0 = V3(0.0, 0.0, 0.0)
    no_err = Err(*([False] * len(_ERRORS_ROS2)))
    z = np.zeros
    inertia = HAND.inertia

    def inert(h, m, c, i):
        return InS(h, In(m, V3(*c), i[0, 0], i[0, 1], i[0, 2], i[1, 1], i[1, 2], i[2, 2]))

    idx, stamp, recv = _schedule(log, step, 12)
    order = [2, 0, 1, 6, 4, 3, 5]  # the joint states name their joints in another order: the reader maps by name
    names = [ARM[j] for j in order]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        c_rs = w.add_connection("/franka_robot_state_broadcaster/robot_state", RS.__msgtype__, typestore=ts)
        c_js = w.add_connection("/franka/joint_states", JOINTSTATE1, typestore=ts)
        c_m = w.add_connection("/joint_states", JOINTSTATE1, typestore=ts)
        for k, i in enumerate(idx):
            h = H(_time(ts, stamp[k]), "base")
            pose = PS(h, P(Pt(0.0, 0.0, 0.0), Qn(0.0, 0.0, 0.0, 1.0)))
            msg = RS(h, CI(v0, v0, v0, v0, z(7), z(7)),
                     JS(h, names, log.q[i][order], log.dq[i][order], log.tau_J[i][order]),
                     JS(h, names, log.q_d[i][order], log.dq_d[i][order], log.tau_J_d[i][order]),
                     JS(h, names, log.q[i][order], log.dq[i][order], z(0)), log.ddq_d[i], z(7),
                     JS(h, names, z(0), z(0), (log.tau_J[i] - log.tau_J_d[i])[order]), El(z(2), z(2), z(2), z(2), z(2)),
                     WS(h, W(v0, v0)), WS(h, W(v0, v0)), inert(h, HAND.mass, HAND.com, inertia),
                     inert(h, 0.0, z(3), z((3, 3))), inert(h, HAND.mass, HAND.com, inertia), pose, pose, pose, pose,
                     pose, TwS(h, Tw(v0, v0)), TwS(h, Tw(v0, v0)), AcS(h, Ac(v0, v0)), ROBOT_T0 + log.time[i], 1.0,
                     2, no_err, no_err)
            w.write(c_rs, _ns(recv[k]), ts.serialize_cdr(msg, RS.__msgtype__))
            js = JS(h, names, log.q[i][order], log.dq[i][order], log.tau_J[i][order])
            w.write(c_js, _ns(recv[k] + 2e-5), ts.serialize_cdr(js, JOINTSTATE1))
            if k % max(1, 20 // step) == 0:
                m = JS(H(_time(ts, stamp[k] + 1e-3), ""), names + FINGERS, np.r_[log.q[i][order], 0.04, 0.04],
                       np.r_[log.dq[i][order], 0, 0], np.r_[log.tau_J[i][order], 0, 0])
                w.write(c_m, _ns(recv[k] + 1e-3), ts.serialize_cdr(m, JOINTSTATE1))
    return idx


def _check_read_back(bag_log, src, idx, fields):
    np.testing.assert_allclose(bag_log.time, src.time[idx] - src.time[idx[0]], rtol=0, atol=1e-12)
    for f in fields:
        np.testing.assert_array_equal(getattr(bag_log, f), getattr(src, f)[idx], err_msg=f)


def test_ros1_franka_ros_bag(source, tmp_path):
    src, answer, d_src = source
    bag = tmp_path / "franka_ros_run.bag"
    idx = _write_ros1(bag, src)
    log = load_log(bag)
    # the state topic is preferred; every field it carries is read; the time is the robot's clock
    assert log.extra["topic"] == "/franka_state_controller/franka_states"
    _check_read_back(log, src, idx, ("q", "dq", "tau_J", "tau_J_d", "q_d", "dq_d"))
    np.testing.assert_allclose(log.tau_ext_hat_filtered, src.tau_J[idx] - src.tau_J_d[idx], atol=1e-12)
    assert log.ddq_d is None  # franka_ros's FrankaState has no ddq_d
    assert log.tool_declared and log.tool == "franka_hand" and "m_total" in log.extra["tool_source"]
    read_as = log.extra["read_as"]
    assert read_as.startswith("ROS 1 bag: topic /franka_state_controller/franka_states")
    assert "the robot's own clock" in read_as and "/joint_states" in read_as
    assert log.extra["topic_candidates"] == ["/franka_state_controller/franka_states",
                                             "/franka_state_controller/joint_states", "/joint_states"]
    # the JointState topics: the controller's own, and the merged one (fingers skipped), stamped by the header
    js = load_log(bag, topic="/franka_state_controller/joint_states")
    assert not js.tool_declared and "header stamps" in js.extra["read_as"]
    np.testing.assert_array_equal(js.tau_J, src.tau_J[idx])
    np.testing.assert_allclose(js.time, src.time[idx] - src.time[idx[0]], atol=2e-3)  # 0.3 ms stamp jitter
    merged = load_log(bag, topic="/joint_states")
    assert merged.n == len(range(0, len(idx), 2)) and merged.extra["messages_skipped"] == 0
    np.testing.assert_array_equal(merged.q, src.q[idx[::2]])
    with pytest.raises(ValueError, match=r"no usable JointState message on /franka_gripper/joint_states: \d+ "
                                         r"messages without the seven arm joints; topics: \[/franka_gripper"):
        load_log(bag, topic="/franka_gripper/joint_states")
    # the verdict of franka-vs diagnose on the bag equals the one on the source log
    out = subprocess.run([sys.executable, "-m", "franka_vs_gym.cli", "diagnose", str(bag), "--json", "--quiet"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    js_out = json.loads(out.stdout)
    assert d_src.verdict == answer["effect"] == "payload"
    assert js_out["verdict"] == d_src.verdict
    a = js_out["assumptions"]
    assert "franka_states" in a["log_read_as"] and "declared by the log" in a["tool_source"]
    assert a["log_rate_hz"] == pytest.approx(250.0, rel=0.01) and a["cleaning"]["max_gap_s"] >= 0.04


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_ros2_franka_ros2_bag(source, tmp_path, storage):
    src, _, d_src = source
    bag = tmp_path / f"robot_state_{storage}"
    idx = _write_ros2(bag, src, storage)
    log = load_log(bag)
    assert log.extra["topic"] == "/franka_robot_state_broadcaster/robot_state"
    assert log.extra["topic_type"] == "franka_msgs/msg/FrankaRobotState"
    _check_read_back(log, src, idx, ("q", "dq", "tau_J", "tau_J_d", "q_d", "dq_d", "ddq_d"))
    np.testing.assert_allclose(log.tau_ext_hat_filtered, src.tau_J[idx] - src.tau_J_d[idx], atol=1e-12)
    assert log.tool == "franka_hand" and log.tool_declared
    assert log.extra["source_format"] == ("rosbag2 (MCAP)" if storage == "mcap" else "rosbag2 (sqlite3)")
    # of the two JointState topics, the driver's own (arm joints only) is preferred over the merged one
    assert log.extra["topic_candidates"] == ["/franka_robot_state_broadcaster/robot_state", "/franka/joint_states",
                                             "/joint_states"]
    assert "37 messages out of time order, sorted" in log.extra["read_as"]  # receive order != the robot's clock
    js = load_log(bag, topic="/franka/joint_states")  # joints named in another order: mapped by name
    assert "header stamps" in js.extra["read_as"] and js.n == len(idx)
    np.testing.assert_array_equal(np.sort(js.dq, axis=0), np.sort(src.dq[idx], axis=0))
    if storage == "mcap":
        d = diagnose(log)
        assert d.verdict == d_src.verdict == "payload"
        assert d.selection[0].params["mass_kg"] == pytest.approx(d_src.selection[0].params["mass_kg"], rel=0.05)
        assert "robot_state" in d.assumptions["log_read_as"]


def test_ros2_bag_without_franka_definitions(source, tmp_path):
    """A rosbag2 whose franka_msgs definitions were not stored: the state topic cannot be read (a one-line error
    when asked for), the JointState topic is read instead, and the choice is stated."""
    src, _, _ = source
    bag = tmp_path / "no_defs"
    idx = _write_ros2(bag, src.slice(0, 1500), "sqlite3", step=5)
    db = next(bag.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions WHERE topic_type LIKE 'franka_msgs/%'")
    log = load_log(bag)
    assert log.extra["topic"] == "/franka/joint_states"
    assert "driver's own" in log.extra["topic_reason"]
    assert "robot_state (franka_msgs/msg/FrankaRobotState) not read: message definition missing" in \
        log.extra["read_as"]
    np.testing.assert_array_equal(log.tau_J, src.tau_J[idx])
    with pytest.raises(ValueError, match=r"topic /franka_robot_state_broadcaster/robot_state \(franka_msgs/msg/"
                                         r"FrankaRobotState\): message definition missing from the bag"):
        load_log(bag, topic="/franka_robot_state_broadcaster/robot_state")
    # no definitions at all (rosbag2 before format 8): standard types for the JointState topics, stated
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions")
    log = load_log(bag)
    assert log.extra["topic"] == "/franka/joint_states" and "no message definitions" in log.extra["read_as"]


def test_bag_errors_name_the_problem_and_the_topics(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    JS, H = ts.types[JOINTSTATE1], ts.types["std_msgs/msg/Header"]
    Str = ts.types["std_msgs/msg/String"]
    bag = tmp_path / "gui.bag"
    with Writer(bag) as w:  # a joint_state_publisher GUI: positions only, no torques
        c = w.add_connection("/joint_states", JOINTSTATE1, typestore=ts)
        s = w.add_connection("/rosout_text", "std_msgs/msg/String", typestore=ts)
        for k in range(30):
            msg = JS(H(k, _time(ts, 100 + k * 0.01), ""), ARM, np.zeros(7), np.zeros(7), np.zeros(0))
            w.write(c, _ns(100 + k * 0.01), ts.serialize_ros1(msg, JOINTSTATE1))
        w.write(s, _ns(100.0), ts.serialize_ros1(Str("hello"), "std_msgs/msg/String"))
    with pytest.raises(ValueError) as e:
        load_log(bag)
    msg = str(e.value)
    assert "no usable topic" in msg and "/joint_states: its first 20 messages without efforts (torques)" in msg
    assert "/rosout_text (std_msgs/msg/String)" in msg and "\n" not in msg
    with pytest.raises(ValueError, match="topic /joint_states carries no efforts"):
        load_log(bag, topic="/joint_states")
    with pytest.raises(ValueError, match="topic /rosout_text is std_msgs/msg/String, neither"):
        load_log(bag, topic="/rosout_text")
    # a ROS 1 bag under another name is recognised by its header; a truncated one is a one-line error
    other = tmp_path / "recording.dat"
    other.write_bytes(bag.read_bytes())
    with pytest.raises(ValueError, match="no usable topic"):
        load_log(other)
    broken = tmp_path / "broken.bag"
    broken.write_bytes(bag.read_bytes()[:200])
    with pytest.raises(ValueError, match="not a readable ROS 1 bag"):
        load_log(broken)
    cut = tmp_path / "cut.bag"  # a message whose bytes were cut short
    with Writer(cut) as w:
        c = w.add_connection("/joint_states", JOINTSTATE1, typestore=ts)
        for k in range(10):
            raw = ts.serialize_ros1(JS(H(k, _time(ts, 100 + k * 0.01), ""), ARM, np.zeros(7), np.zeros(7),
                                       np.zeros(7)), JOINTSTATE1)
            w.write(c, _ns(100 + k * 0.01), raw[:-20] if k == 5 else raw)
    with pytest.raises(ValueError, match=r"cut.bag: a message on /joint_states cannot be decoded as "
                                         r"sensor_msgs/msg/JointState with the definition in the bag: \w"):
        load_log(cut)
    out = subprocess.run([sys.executable, "-m", "franka_vs_gym.cli", "compare", str(bag), "--quiet"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 2 and "no usable topic" in out.stderr and "Traceback" not in out.stderr


def _ros2_franka_state() -> str:
    """franka_ros2's older franka_msgs/msg/FrankaState: franka_ros's fields in lower case, plus ddq_d and the
    commanded elbow, twists and pose (field list as published)."""
    arrays = [("6", "cartesian_collision"), ("6", "cartesian_contact"), ("7", "q"), ("7", "q_d"), ("7", "dq"),
              ("7", "dq_d"), ("7", "ddq_d"), ("7", "theta"), ("7", "dtheta"), ("7", "tau_j"), ("7", "dtau_j"),
              ("7", "tau_j_d"), ("6", "k_f_ext_hat_k"), ("2", "elbow"), ("2", "elbow_d"), ("2", "elbow_c"),
              ("2", "delbow_c"), ("2", "ddelbow_c"), ("7", "joint_collision"), ("7", "joint_contact"),
              ("6", "o_f_ext_hat_k"), ("6", "o_dp_ee_d"), ("6", "o_dp_ee_c"), ("6", "o_ddp_ee_c"),
              ("7", "tau_ext_hat_filtered")]
    body = ["std_msgs/Header header"] + [f"float64[{n}] {f}" for n, f in arrays]
    body += ["float64 m_ee", "float64[3] f_x_cee", "float64[9] i_ee", "float64 m_load", "float64[3] f_x_cload",
             "float64[9] i_load", "float64 m_total", "float64[3] f_x_ctotal", "float64[9] i_total"]
    body += [f"float64[16] {f}" for f in ("o_t_ee", "o_t_ee_d", "o_t_ee_c", "f_t_ee", "ee_t_k")]
    body += ["float64 time", "float64 control_command_success_rate", _MODES, "uint8 robot_mode",
             "Errors current_errors", "Errors last_motion_errors"]
    return "\n".join(body) + "\n"


def test_franka_ros2_frankastate_declared_load_two_robots_and_sidecar(source, tmp_path):
    """franka_ros2's older FrankaState (lower-case fields) with a load declared on top of the Hand, changed half
    way; two arms in one bag need --topic; a sidecar's tool overrides the bag's, and says so."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    src, _, _ = source
    ts = get_typestore(Stores.ROS2_HUMBLE)
    typs = get_types_from_msg("\n".join(f"bool {e}" for e in _ERRORS_ROS2), "franka_msgs/msg/Errors")
    typs.update(get_types_from_msg(_ros2_franka_state(), "franka_msgs/msg/FrankaState"))
    ts.register(typs)
    FS, H, Err = (ts.types[k] for k in ("franka_msgs/msg/FrankaState", "std_msgs/msg/Header",
                                         "franka_msgs/msg/Errors"))
    no_err = Err(*([False] * len(_ERRORS_ROS2)))
    z = np.zeros
    # the Hand plus a 0.4 kg load 0.1 m along the flange z axis (libfranka: end effector + load in m_total)
    load_com = np.array([0.0, 0.0, 0.1])
    m_tot = HAND.mass + 0.4
    c_tot = (HAND.mass * HAND.com + 0.4 * load_com) / m_tot
    i_tot = np.diag([0.003, 0.004, 0.002]) + np.array([[0, 1e-4, 0], [1e-4, 0, 0], [0, 0, 0]])
    idx = np.arange(0, 600, 2)
    bag = tmp_path / "two_arms"
    with Writer(bag, version=9) as w:
        conns = [w.add_connection(f"/{arm}/franka_robot_state_broadcaster/robot_state", FS.__msgtype__,
                                  typestore=ts) for arm in ("left", "right")]
        for k, i in enumerate(idx):
            m = m_tot if k < len(idx) // 2 else HAND.mass  # the load is put down half way
            msg = FS(H(_time(ts, T0 + src.time[i]), ""), z(6), z(6), src.q[i], src.q_d[i], src.dq[i], src.dq_d[i],
                     src.ddq_d[i], src.q[i], src.dq[i], src.tau_J[i], z(7), src.tau_J_d[i], z(6), z(2), z(2), z(2),
                     z(2), z(2), z(7), z(7), z(6), z(6), z(6), z(6), z(7), HAND.mass, HAND.com,
                     HAND.inertia.ravel(order="F"), m - HAND.mass, load_com, z(9), m, c_tot,
                     i_tot.ravel(order="F"), *(np.eye(4).ravel() for _ in range(5)), ROBOT_T0 + src.time[i], 1.0, 2,
                     no_err, no_err)
            for c in conns:
                w.write(c, _ns(T0 + src.time[i] + 1e-3), ts.serialize_cdr(msg, FS.__msgtype__))
    with pytest.raises(ValueError, match=r"several Franka state topics \['/left/.*'/right/.*--topic"):
        load_log(bag)
    log = load_log(bag, topic="/right/franka_robot_state_broadcaster/robot_state")
    assert log.extra["topic_reason"] == "chosen with --topic"
    _check_read_back(log, src, idx, ("q", "dq", "tau_J", "tau_J_d", "q_d", "dq_d", "ddq_d"))
    assert log.tool["mass"] == pytest.approx(m_tot, abs=1e-12)
    np.testing.assert_allclose(log.tool["com"], c_tot, atol=1e-12)
    np.testing.assert_allclose(log.tool["inertia"], i_tot, atol=1e-12)
    assert "declared load changed during the bag (m_total 1.13 -> 0.73 kg at message 150)" in log.extra["read_as"]
    side = bag.with_name(bag.name + ".json")
    side.write_text(json.dumps({"tool": None}))
    log = load_log(bag, topic="/left/franka_robot_state_broadcaster/robot_state")
    assert log.tool is None and log.tool_declared and "tool_source" not in log.extra


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_ros2_bag_folder_without_metadata_yaml_reads_as_its_storage_file(tmp_path, storage):
    """A rosbag2 folder whose metadata.yaml is missing (an interrupted recording, a copy of the storage file alone)
    is read as a bag, identical to the folder with it; several storage files without metadata are a named error."""
    log, _ = make_hidden_effect_log("none", 3, duration=3.0)
    bag = tmp_path / "with_meta"
    _write_ros2(bag, log, storage, step=5)
    bare = tmp_path / "no_meta"
    bare.mkdir()
    for f in bag.iterdir():
        if f.name != "metadata.yaml":
            (bare / f.name).write_bytes(f.read_bytes())
    a, b = load_log(bag), load_log(bare)
    for name in ("time", "q", "dq", "tau_J"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.extra["topic"] == b.extra["topic"]
    suffix = ".mcap" if storage == "mcap" else ".db3"
    (bare / f"second{suffix}").write_bytes(next(bare.glob(f"*{suffix}")).read_bytes())
    with pytest.raises(ValueError, match="without metadata.yaml holding 2 storage files"):
        load_log(bare)
