"""Wire format of the Franka Control Interface (FCI), as libfranka speaks it: one definition per message.

Layouts follow libfranka's public research-interface headers (``research_interface/robot/service_types.h``,
``rbk_types.h``, ``gripper/types.h``; robot protocol version 10, gripper protocol version 3): little-endian,
packed (no padding), TCP messages prefixed by a header, UDP datagrams carrying one state or one command.

- Robot TCP header: ``<u32 command, u32 command_id, u32 size>`` where ``size`` counts the header too.
- Gripper TCP header: ``<u16 command, u32 command_id, u32 size>``.
- Robot state (UDP, server -> client): ``u64 message_id`` then float32 fields, then mode bytes, two arrays of 41
  error flags, the robot mode and the command success rate (:data:`ROBOT_STATE_FIELDS`).
- Robot command (UDP, client -> server): ``u64 message_id``, the motion-generator command (float64) and the
  controller command (float64), see :data:`ROBOT_COMMAND`.

4x4 poses and 3x3 inertias travel column-major, as libfranka stores them.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

import numpy as np

ROBOT_VERSION = 10
GRIPPER_VERSION = 3
ROBOT_PORT = 1337
GRIPPER_PORT = 1338


# ---------------------------------------------------------------------------------------------- robot commands
class Command(enum.IntEnum):
    """Robot TCP commands (``research_interface::robot::Command``, protocol 10)."""

    CONNECT = 0
    MOVE = 1
    STOP_MOVE = 2
    SET_COLLISION_BEHAVIOR = 3
    SET_JOINT_IMPEDANCE = 4
    SET_CARTESIAN_IMPEDANCE = 5
    SET_GUIDING_MODE = 6
    SET_EE_TO_K = 7
    SET_NE_TO_EE = 8
    SET_LOAD = 9
    AUTOMATIC_ERROR_RECOVERY = 10
    GET_ROBOT_MODEL = 11


class MoveControllerMode(enum.IntEnum):
    """Controller requested in a Move command."""

    JOINT_IMPEDANCE = 0
    CARTESIAN_IMPEDANCE = 1
    EXTERNAL_CONTROLLER = 2


class MoveMotionGeneratorMode(enum.IntEnum):
    """Motion generator requested in a Move command (note: no idle entry, unlike the state's enum)."""

    JOINT_POSITION = 0
    JOINT_VELOCITY = 1
    CARTESIAN_POSITION = 2
    CARTESIAN_VELOCITY = 3
    NONE = 4


class MotionGeneratorMode(enum.IntEnum):
    """Motion generator reported in the robot state."""

    IDLE = 0
    JOINT_POSITION = 1
    JOINT_VELOCITY = 2
    CARTESIAN_POSITION = 3
    CARTESIAN_VELOCITY = 4
    NONE = 5


class ControllerMode(enum.IntEnum):
    """Controller reported in the robot state."""

    JOINT_IMPEDANCE = 0
    CARTESIAN_IMPEDANCE = 1
    EXTERNAL_CONTROLLER = 2
    OTHER = 3


class RobotMode(enum.IntEnum):
    """Robot mode reported in the robot state."""

    OTHER = 0
    IDLE = 1
    MOVE = 2
    GUIDING = 3
    REFLEX = 4
    USER_STOPPED = 5
    AUTOMATIC_ERROR_RECOVERY = 6


class ConnectStatus(enum.IntEnum):
    SUCCESS = 0
    INCOMPATIBLE_LIBRARY_VERSION = 1


class MoveStatus(enum.IntEnum):
    SUCCESS = 0
    MOTION_STARTED = 1
    PREEMPTED = 2
    PREEMPTED_DUE_TO_ACTIVATED_SAFETY_FUNCTIONS = 3
    COMMAND_REJECTED_DUE_TO_ACTIVATED_SAFETY_FUNCTIONS = 4
    COMMAND_NOT_POSSIBLE_REJECTED = 5
    START_AT_SINGULAR_POSE_REJECTED = 6
    INVALID_ARGUMENT_REJECTED = 7
    REFLEX_ABORTED = 8
    EMERGENCY_ABORTED = 9
    INPUT_ERROR_ABORTED = 10
    ABORTED = 11


class StopMoveStatus(enum.IntEnum):
    SUCCESS = 0
    COMMAND_NOT_POSSIBLE_REJECTED = 1
    COMMAND_REJECTED_DUE_TO_ACTIVATED_SAFETY_FUNCTIONS = 2
    EMERGENCY_ABORTED = 3
    REFLEX_ABORTED = 4
    ABORTED = 5


class SetterStatus(enum.IntEnum):
    """Status of the getter/setter commands (collision behaviour, impedances, frames, load, guiding mode)."""

    SUCCESS = 0
    COMMAND_NOT_POSSIBLE_REJECTED = 1
    INVALID_ARGUMENT_REJECTED = 2
    COMMAND_REJECTED_DUE_TO_ACTIVATED_SAFETY_FUNCTIONS = 3


class RecoveryStatus(enum.IntEnum):
    SUCCESS = 0
    COMMAND_NOT_POSSIBLE_REJECTED = 1
    COMMAND_REJECTED_DUE_TO_ACTIVATED_SAFETY_FUNCTIONS = 2
    MANUAL_ERROR_RECOVERY_REQUIRED_REJECTED = 3
    REFLEX_ABORTED = 4
    EMERGENCY_ABORTED = 5
    ABORTED = 6


class GetRobotModelStatus(enum.IntEnum):
    SUCCESS = 0
    COMMAND_NOT_POSSIBLE_REJECTED = 1
    COMMAND_REJECTED_DUE_TO_ACTIVATED_SAFETY_FUNCTIONS = 2


ROBOT_HEADER = struct.Struct("<III")  # command, command_id, size (header included)

# Request payloads (after the header), one struct per message.
CONNECT_REQUEST = struct.Struct("<HH")  # version, udp_port
CONNECT_RESPONSE = struct.Struct("<BH")  # status, version
# controller_mode, motion_generator_mode, max path deviation (translation, rotation, elbow), max goal pose
# deviation (same), use_async_motion_generator, maximum_velocity[7]
MOVE_REQUEST = struct.Struct("<II3d3d?7d")
SET_COLLISION_BEHAVIOR_REQUEST = struct.Struct("<7d7d7d7d6d6d6d6d")
SET_JOINT_IMPEDANCE_REQUEST = struct.Struct("<7d")  # K_theta
SET_CARTESIAN_IMPEDANCE_REQUEST = struct.Struct("<6d")  # K_x
SET_GUIDING_MODE_REQUEST = struct.Struct("<6??")  # guiding_mode, nullspace
SET_EE_TO_K_REQUEST = struct.Struct("<16d")  # EE_T_K, column-major
SET_NE_TO_EE_REQUEST = struct.Struct("<16d")  # NE_T_EE, column-major
SET_LOAD_REQUEST = struct.Struct("<d3d9d")  # m_load, F_x_Cload, I_load (column-major)
STATUS_RESPONSE = struct.Struct("<B")  # every other response: one status byte (GetRobotModel appends the URDF)

REQUEST_STRUCTS: dict[Command, struct.Struct | None] = {
    Command.CONNECT: CONNECT_REQUEST,
    Command.MOVE: MOVE_REQUEST,
    Command.STOP_MOVE: None,
    Command.SET_COLLISION_BEHAVIOR: SET_COLLISION_BEHAVIOR_REQUEST,
    Command.SET_JOINT_IMPEDANCE: SET_JOINT_IMPEDANCE_REQUEST,
    Command.SET_CARTESIAN_IMPEDANCE: SET_CARTESIAN_IMPEDANCE_REQUEST,
    Command.SET_GUIDING_MODE: SET_GUIDING_MODE_REQUEST,
    Command.SET_EE_TO_K: SET_EE_TO_K_REQUEST,
    Command.SET_NE_TO_EE: SET_NE_TO_EE_REQUEST,
    Command.SET_LOAD: SET_LOAD_REQUEST,
    Command.AUTOMATIC_ERROR_RECOVERY: None,
    Command.GET_ROBOT_MODEL: None,
}


def robot_message(command: int, command_id: int, payload: bytes = b"") -> bytes:
    """A robot TCP message: header + payload."""
    return ROBOT_HEADER.pack(int(command), command_id, ROBOT_HEADER.size + len(payload)) + payload


def status_response(command: int, command_id: int, status: int) -> bytes:
    return robot_message(command, command_id, STATUS_RESPONSE.pack(int(status)))


def connect_response(command_id: int, status: int, version: int = ROBOT_VERSION) -> bytes:
    return robot_message(Command.CONNECT, command_id, CONNECT_RESPONSE.pack(int(status), version))


def robot_model_response(command_id: int, urdf: str) -> bytes:
    return robot_message(Command.GET_ROBOT_MODEL, command_id,
                         STATUS_RESPONSE.pack(GetRobotModelStatus.SUCCESS) + urdf.encode())


@dataclass(frozen=True)
class MoveRequest:
    controller_mode: MoveControllerMode
    motion_generator_mode: MoveMotionGeneratorMode
    maximum_path_deviation: tuple[float, float, float]
    maximum_goal_pose_deviation: tuple[float, float, float]
    use_async_motion_generator: bool

    @classmethod
    def decode(cls, payload: bytes) -> MoveRequest:
        v = MOVE_REQUEST.unpack_from(payload)
        return cls(MoveControllerMode(v[0]), MoveMotionGeneratorMode(v[1]), v[2:5], v[5:8], bool(v[8]))


# ---------------------------------------------------------------------------------------------- robot state
# (name, count, kind) in wire order; kind "f" = float32 array, others are single values.
ROBOT_STATE_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("message_id", 1, "Q"),
    ("O_T_EE", 16, "f"), ("O_T_EE_d", 16, "f"), ("F_T_EE", 16, "f"), ("EE_T_K", 16, "f"), ("F_T_NE", 16, "f"),
    ("NE_T_EE", 16, "f"),
    ("m_ee", 1, "f"), ("I_ee", 9, "f"), ("F_x_Cee", 3, "f"),
    ("m_load", 1, "f"), ("I_load", 9, "f"), ("F_x_Cload", 3, "f"),
    ("elbow", 2, "f"), ("elbow_d", 2, "f"),
    ("tau_J", 7, "f"), ("tau_J_d", 7, "f"), ("dtau_J", 7, "f"),
    ("q", 7, "f"), ("q_d", 7, "f"), ("dq", 7, "f"), ("dq_d", 7, "f"), ("ddq_d", 7, "f"),
    ("joint_contact", 7, "f"), ("cartesian_contact", 6, "f"), ("joint_collision", 7, "f"),
    ("cartesian_collision", 6, "f"),
    ("tau_ext_hat_filtered", 7, "f"), ("O_F_ext_hat_K", 6, "f"), ("K_F_ext_hat_K", 6, "f"),
    ("O_dP_EE_d", 6, "f"), ("O_ddP_O", 3, "f"),
    ("elbow_c", 2, "f"), ("delbow_c", 2, "f"), ("ddelbow_c", 2, "f"),
    ("O_T_EE_c", 16, "f"), ("O_dP_EE_c", 6, "f"), ("O_ddP_EE_c", 6, "f"),
    ("theta", 7, "f"), ("dtheta", 7, "f"),
    ("accelerometer_top", 18, "f"), ("accelerometer_bottom", 18, "f"),
    ("motion_generator_mode", 1, "B"), ("controller_mode", 1, "B"),
    ("errors", 41, "?"), ("reflex_reason", 41, "?"),
    ("robot_mode", 1, "B"), ("control_command_success_rate", 1, "f"),
)
N_ERRORS = 41
ROBOT_STATE = struct.Struct("<" + "".join(f"{n}{k}" if n > 1 else k for _, n, k in ROBOT_STATE_FIELDS))


def _float_block() -> tuple[dict[str, slice], int, int]:
    """Offsets of the contiguous float32 block (O_T_EE .. accelerometer_bottom) inside the state."""
    slices, i = {}, 0
    for name, n, kind in ROBOT_STATE_FIELDS[1:]:
        if kind != "f":
            break
        slices[name] = slice(i, i + n)
        i += n
    return slices, i, struct.calcsize("<Q")


FLOAT_SLICES, N_FLOATS, FLOAT_OFFSET = _float_block()
# offsets of the tail after the float block
_TAIL = struct.Struct("<BB41?41?Bf")
TAIL_OFFSET = FLOAT_OFFSET + 4 * N_FLOATS
assert TAIL_OFFSET + _TAIL.size == ROBOT_STATE.size


class RobotStateBuffer:
    """A reusable robot-state datagram: fill the float fields through :attr:`f` (float32 views by field name)
    and the modes/errors through attributes, then :meth:`encode`. Built on :data:`ROBOT_STATE`'s layout."""

    def __init__(self) -> None:
        self.buf = bytearray(ROBOT_STATE.size)
        self.floats = np.zeros(N_FLOATS, dtype=np.float32)
        self.f = {name: self.floats[s] for name, s in FLOAT_SLICES.items()}
        self.errors = np.zeros(N_ERRORS, dtype=bool)
        self.reflex_reason = np.zeros(N_ERRORS, dtype=bool)
        self.motion_generator_mode = MotionGeneratorMode.IDLE
        self.controller_mode = ControllerMode.JOINT_IMPEDANCE
        self.robot_mode = RobotMode.IDLE
        self.control_command_success_rate = 1.0

    def encode(self, message_id: int) -> bytes:
        buf = self.buf
        struct.pack_into("<Q", buf, 0, message_id)
        buf[FLOAT_OFFSET:TAIL_OFFSET] = self.floats.tobytes()
        o = TAIL_OFFSET
        buf[o] = int(self.motion_generator_mode)
        buf[o + 1] = int(self.controller_mode)
        buf[o + 2:o + 2 + N_ERRORS] = self.errors.tobytes()
        buf[o + 2 + N_ERRORS:o + 2 + 2 * N_ERRORS] = self.reflex_reason.tobytes()
        buf[o + 2 + 2 * N_ERRORS] = int(self.robot_mode)
        struct.pack_into("<f", buf, o + 3 + 2 * N_ERRORS, self.control_command_success_rate)
        return bytes(buf)


def decode_robot_state(data: bytes) -> dict[str, np.ndarray | int | float]:
    """Decode a robot-state datagram into a dict keyed by libfranka's field names (for tests and tools)."""
    values = ROBOT_STATE.unpack(data)
    out: dict[str, np.ndarray | int | float] = {}
    i = 0
    for name, n, kind in ROBOT_STATE_FIELDS:
        if n == 1:
            out[name] = values[i]
        else:
            out[name] = np.array(values[i:i + n], dtype=bool if kind == "?" else np.float64)
        i += n
    return out


# ---------------------------------------------------------------------------------------------- robot command
# message_id; motion: q_c[7], dq_c[7], O_T_EE_c[16], O_dP_EE_c[6], elbow_c[2], valid_elbow,
# motion_generation_finished; control: tau_J_d[7], torque_command_finished
ROBOT_COMMAND = struct.Struct("<Q7d7d16d6d2d??7d?")


@dataclass
class RobotCommand:
    """One decoded UDP command (float64 arrays; poses column-major (16,) as on the wire)."""

    message_id: int
    q_c: np.ndarray
    dq_c: np.ndarray
    O_T_EE_c: np.ndarray
    O_dP_EE_c: np.ndarray
    elbow_c: np.ndarray
    valid_elbow: bool
    motion_generation_finished: bool
    tau_J_d: np.ndarray
    torque_command_finished: bool

    @classmethod
    def decode(cls, data: bytes) -> RobotCommand:
        v = np.frombuffer(data, dtype="<f8", count=38, offset=8)
        t = np.frombuffer(data, dtype="<f8", count=7, offset=8 + 38 * 8 + 2)
        (message_id,) = struct.unpack_from("<Q", data)
        o = 8 + 38 * 8
        return cls(message_id, v[0:7], v[7:14], v[14:30], v[30:36], v[36:38], bool(data[o]), bool(data[o + 1]),
                   t, bool(data[-1]))

    def encode(self) -> bytes:
        return ROBOT_COMMAND.pack(self.message_id, *self.q_c, *self.dq_c, *self.O_T_EE_c, *self.O_dP_EE_c,
                                  *self.elbow_c, self.valid_elbow, self.motion_generation_finished,
                                  *self.tau_J_d, self.torque_command_finished)


# ---------------------------------------------------------------------------------------------- gripper
class GripperCommand(enum.IntEnum):
    """Gripper TCP commands (``research_interface::gripper::Command``, protocol 3)."""

    CONNECT = 0
    HOMING = 1
    GRASP = 2
    MOVE = 3
    STOP = 4


class GripperStatus(enum.IntEnum):
    SUCCESS = 0
    FAIL = 1
    UNSUCCESSFUL = 2
    ABORTED = 3


GRIPPER_HEADER = struct.Struct("<HII")  # command (u16), command_id, size (header included)
GRIPPER_CONNECT_REQUEST = struct.Struct("<HH")  # version, udp_port
GRIPPER_CONNECT_RESPONSE = struct.Struct("<HH")  # status (u16), version
GRIPPER_MOVE_REQUEST = struct.Struct("<dd")  # width, speed
GRIPPER_GRASP_REQUEST = struct.Struct("<ddddd")  # width, epsilon inner, epsilon outer, speed, force
GRIPPER_STATUS_RESPONSE = struct.Struct("<H")
GRIPPER_STATE = struct.Struct("<Idd?H")  # message_id, width, max_width, is_grasped, temperature


def gripper_message(command: int, command_id: int, payload: bytes = b"") -> bytes:
    return GRIPPER_HEADER.pack(int(command), command_id, GRIPPER_HEADER.size + len(payload)) + payload


__all__ = [n for n in dir() if n.isupper() or n[0].isupper()] + ["decode_robot_state", "robot_message",
                                                                 "status_response", "connect_response",
                                                                 "robot_model_response", "gripper_message"]
