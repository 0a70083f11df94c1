"""The robot behind the FCI: motion generators, internal controllers, reflexes and the robot state, on FrankaSim.

:class:`FCIRobot` is the part of the server that does not touch sockets. It drives a
:class:`~franka_vs_gym.sim.FrankaSim` in torque mode (gravity-free torques; the plant adds g(q), as the FER does)
one 1 ms physics step per control cycle, and fills the libfranka robot state from the plant.

What runs inside, as on the FER:

- motion generators: joint position ``q_c``, joint velocity ``dq_c``, Cartesian pose ``O_T_EE_c`` and Cartesian
  velocity ``O_dP_EE_c`` (with the optional elbow ``elbow_c`` = joint-3 angle), or none (external torque control).
  Cartesian commands are turned into a joint trajectory by the robot's inverse kinematics (the end-effector pose
  plus the elbow angle make a square 7x7 system, solved by Newton steps from the previous desired joints).
- internal controllers: joint impedance (stiffness ``K_theta`` from ``set_joint_impedance``, critical damping on
  the diagonal of B(q), inertial, Coriolis and friction feed-forward: :class:`~franka_vs_gym.control.JointImpedance`)
  and Cartesian impedance (``K_x`` from ``set_cartesian_impedance``:
  :class:`~franka_vs_gym.control.CartesianImpedance`), or the client's torques.
- reflexes (libfranka's names, see :mod:`franka_vs_gym.fci.errors`): the motion-generator limits (position,
  velocity, acceleration = "velocity discontinuity", jerk = "acceleration discontinuity", joint and Cartesian),
  controller torque discontinuity (torque rate), joint position and velocity limits of the plant, joint and
  Cartesian collision thresholds (``set_collision_behavior``), communication constraints (real-time mode), and any
  :class:`~franka_vs_gym.sim.reflexes.ControlException` the simulator raises. After a reflex the robot holds its
  position until ``automatic_error_recovery``.

Units SI; poses 4x4 homogeneous (column-major on the wire); O is the robot base (ViSP's f), F the flange, NE the
nominal end effector (the tool's ``flMe``), EE the end effector (``NE_T_EE`` from ``set_NE_to_EE``), K the stiffness
frame (``EE_T_K``).
"""

from __future__ import annotations

import math

import numpy as np

from franka_vs_gym.control.impedance import CartesianImpedance, JointImpedance, pose_error
from franka_vs_gym.fci.codec import (
    ControllerMode,
    MotionGeneratorMode,
    MoveControllerMode,
    MoveMotionGeneratorMode,
    RobotCommand,
    RobotMode,
    RobotStateBuffer,
)
from franka_vs_gym.fci.errors import error_flags
from franka_vs_gym.fci.urdf import POSITION_BASED_VELOCITY_LIMITS, velocity_bounds, velocity_envelope
from franka_vs_gym.model.description import RobotDescription, robot_description
from franka_vs_gym.sim import FORCE_TORQUE, JOINT_STATE, FrankaSim, SimulationDiverged
from franka_vs_gym.sim.reflexes import ControlException

# Defaults of the internal controllers' stiffness (libfranka's examples, setDefaultBehavior) and of the collision
# thresholds (values libfranka's examples have used; the robot's own defaults are set in Desk).
DEFAULT_K_THETA = (3000.0, 3000.0, 3000.0, 2500.0, 2500.0, 2000.0, 2000.0)  # Nm/rad
DEFAULT_K_X = (3000.0, 3000.0, 3000.0, 300.0, 300.0, 300.0)  # N/m, Nm/rad
DEFAULT_TORQUE_THRESHOLDS = (20.0, 20.0, 18.0, 18.0, 16.0, 14.0, 12.0)  # Nm
DEFAULT_FORCE_THRESHOLDS = (20.0, 20.0, 20.0, 25.0, 25.0, 25.0)  # N, Nm
# Tolerances of the motion-generator checks (relative to the limits) and of communication in real-time mode.
LIMIT_TOLERANCE = 0.05  # on finite-difference accelerations and jerks of the commands
CARTESIAN_JOINT_TOLERANCE = 2.0  # on the joint accelerations and jerks of Cartesian commands (see below)
PLANT_VELOCITY_MARGIN = 0.01  # the internal controllers may overshoot a command that sits at the velocity limit
MAX_MISSED_COMMANDS = 20  # consecutive 1 ms cycles without a command before communication_constraints_violation

_MG_FROM_MOVE = {
    MoveMotionGeneratorMode.JOINT_POSITION: MotionGeneratorMode.JOINT_POSITION,
    MoveMotionGeneratorMode.JOINT_VELOCITY: MotionGeneratorMode.JOINT_VELOCITY,
    MoveMotionGeneratorMode.CARTESIAN_POSITION: MotionGeneratorMode.CARTESIAN_POSITION,
    MoveMotionGeneratorMode.CARTESIAN_VELOCITY: MotionGeneratorMode.CARTESIAN_VELOCITY,
    MoveMotionGeneratorMode.NONE: MotionGeneratorMode.NONE,
}
_CTRL_FROM_MOVE = {
    MoveControllerMode.JOINT_IMPEDANCE: ControllerMode.JOINT_IMPEDANCE,
    MoveControllerMode.CARTESIAN_IMPEDANCE: ControllerMode.CARTESIAN_IMPEDANCE,
    MoveControllerMode.EXTERNAL_CONTROLLER: ControllerMode.EXTERNAL_CONTROLLER,
}


_I3 = np.eye(3)
_ROW3 = np.array([0.0, 0.0, 0.0, 1.0])
# the reductions called directly (ndarray.any/.all go through a Python wrapper: ~1 us each at every 1 kHz cycle)
_any, _all, _amax = np.logical_or.reduce, np.logical_and.reduce, np.maximum.reduce


def _norm3(v: np.ndarray) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def _pose_err(T: np.ndarray, Td: np.ndarray) -> np.ndarray:
    """:func:`~franka_vs_gym.control.impedance.pose_error` (``[p_d - p; theta u]`` in the base frame), with a fast
    path for the small rotations between consecutive 1 ms commands (theta / sin(theta) = 1 + sin^2 / 6 to 1e-13
    below 1 mrad)."""
    Re = Td[:3, :3] @ T[:3, :3].T
    w = np.array([Re[2, 1] - Re[1, 2], Re[0, 2] - Re[2, 0], Re[1, 0] - Re[0, 1]])
    sin = 0.5 * _norm3(w)
    if sin > 1e-3 or Re[0, 0] + Re[1, 1] + Re[2, 2] < 1.0:
        return pose_error(T, Td)
    out = np.empty(6)
    out[:3] = Td[:3, 3] - T[:3, 3]
    out[3:] = (0.5 + sin * sin / 12.0) * w
    return out


def _cm(M: np.ndarray) -> np.ndarray:
    """Column-major flattening (libfranka's storage of 4x4 and 3x3 matrices)."""
    return M.ravel(order="F")


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _expm_so3(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector w (Rodrigues)."""
    th = float(np.linalg.norm(w))
    if th < 1e-12:
        return np.eye(3) + _skew(w)
    K = _skew(w / th)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


class Reflex(Exception):
    """A reflex fired in this cycle: ``reasons`` are libfranka error names."""

    def __init__(self, reasons: list[str] | tuple[str, ...], detail: str = "") -> None:
        self.reasons = tuple(reasons)
        self.detail = detail
        super().__init__(f"{list(self.reasons)}: {detail}")


class FCIRobot:
    """The simulated FER as the FCI sees it (no networking): modes, generators, controllers, reflexes, state.

    Parameters
    ----------
    sim : FrankaSim
        The plant (its ``model`` is the robot's internal model: arm + tool, gravity vector of the mounting).
    robot : RobotDescription or name
        Limits and Cartesian limits the reflexes enforce (default: the sim's robot, the FER).
    """

    def __init__(self, sim: FrankaSim, robot: RobotDescription | str | None = None) -> None:
        self.sim = sim
        self.desc = robot_description(robot if robot is not None else sim.model.config.robot)
        self.model = sim.model
        lim = self.desc.limits
        self.q_min, self.q_max = np.array(lim.q_min), np.array(lim.q_max)
        self.dq_max, self.ddq_max = np.array(lim.dq_max), np.array(lim.ddq_max)
        self.dddq_max, self.tau_max = np.array(lim.dddq_max), np.array(lim.tau_max)
        self.dtau_max = np.array(lim.dtau_max)
        self.cart = self.desc.cartesian_limits
        self._envelope = (velocity_envelope(self.desc) if self.desc.name in POSITION_BASED_VELOCITY_LIMITS
                          else None)
        self.dt = sim.dt
        self._cmd_dt = self.dt  # the time a motion command spans in the client's clock (see _to_command_time)
        tool = self.model.config.tool
        self.F_T_NE = tool.flMe.copy()
        self.m_ee, self.F_x_Cee, self.I_ee = tool.body.mass, tool.body.com.copy(), tool.body.inertia.copy()
        self.NE_T_EE = np.eye(4)
        self.EE_T_K = np.eye(4)
        self.m_load, self.F_x_Cload, self.I_load = 0.0, np.zeros(3), np.zeros((3, 3))
        self._load_model = None  # FrankaModel with the declared load, when one is set
        # a plant that differs from the robot's model (serve --truth): the model of the bodies MuJoCo's gravcomp
        # compensates; the robot's own gravity compensation is then commanded as the difference
        self.plant_gravity = None  # FrankaModel or None
        self.K_theta = np.array(DEFAULT_K_THETA)
        self.K_x = np.array(DEFAULT_K_X)
        self.torque_thresholds = np.array(DEFAULT_TORQUE_THRESHOLDS)
        self.force_thresholds = np.array(DEFAULT_FORCE_THRESHOLDS)
        self.lower_torque_thresholds = self.torque_thresholds.copy()
        self.lower_force_thresholds = self.force_thresholds.copy()
        self.joint_ctrl = JointImpedance(self.model, k=self.K_theta, coriolis=True, friction=True)
        self._update_cartesian_controller()
        self.gravity = np.array(self.model.config.gravity, dtype=float)
        sim.set_robot_state(FORCE_TORQUE)
        # the plant's joint velocity servos (views): the internal controllers' damping, integrated implicitly
        self._servo_gain, self._servo_bias, self._servo_ctrl = sim.velocity_servo_views()
        self._q_view, self._dq_view = sim.joint_views()
        self._servo_on = True  # (unknown: switched off at the first step)
        self._contact_fields_zero = False
        self.state = RobotStateBuffer()
        self._settings_changed = True
        self.robot_mode = RobotMode.IDLE
        self.mg_mode = MotionGeneratorMode.IDLE
        self.ctrl_mode = ControllerMode.JOINT_IMPEDANCE
        self.errors = np.zeros(41, dtype=bool)
        self.last_motion_errors = np.zeros(41, dtype=bool)
        self.reflex_detail = ""
        self.success_window = np.ones(100, dtype=bool)
        self._win_i = 0
        self._success_sum = len(self.success_window)
        self.missed_in_row = 0
        self.worst_missed = 0
        self.max_missed_commands = MAX_MISSED_COMMANDS
        self.tau_J_prev = sim.get_force_torque(JOINT_STATE)
        self._reset_desired()

    # ------------------------------------------------------------------ helpers
    @property
    def q(self) -> np.ndarray:
        return self._q_view

    @property
    def dq(self) -> np.ndarray:
        return self._dq_view

    def O_T_EE_of(self, q: np.ndarray) -> np.ndarray:
        """Pose of EE in O (4x4) at joint position q."""
        return self.model.fMe(q) @ self.NE_T_EE

    def _J_EE(self, q: np.ndarray, NE_p: np.ndarray | None = None) -> np.ndarray:
        """Jacobian (6, 7), base-frame axes, [v; w], of the EE frame's origin, or of the point ``NE_p`` (3,)
        given in the nominal end-effector frame NE."""
        J = self.model.fJe(q)
        r = self.model.fMe(q)[:3, :3] @ (self.NE_T_EE[:3, 3] if NE_p is None else NE_p)
        if r.any():
            J = J.copy()
            J[:3] -= _skew(r) @ J[3:]
        return J

    def _update_cartesian_controller(self) -> None:
        """The Cartesian impedance acts on the stiffness frame K: its controller's model has K as end effector, and
        it knows the motors (the plant's effective armature on the diagonal of its mass matrix: task inertia,
        damping and null space as the joints really are)."""
        from franka_vs_gym.model import FrankaModel
        from franka_vs_gym.model.config import Tool

        cfg = self.model.config
        flMK = self.F_T_NE @ self.NE_T_EE @ self.EE_T_K
        model = FrankaModel(cfg.copy(tool=Tool(cfg.tool.name, flMK, cfg.tool.body),
                                     armature=cfg.armature + self.sim.rotor_inertia))
        self.cart_ctrl = CartesianImpedance(model, k_translation=self.K_x[:3], k_rotation=self.K_x[3:])

    def _reset_desired(self) -> None:
        """Desired signals follow the measured state (start of a motion, idle, after a reflex)."""
        q = self.q.copy()
        self.q_d, self.dq_d, self.ddq_d = q, np.zeros(7), np.zeros(7)
        self.q_hold = q.copy()
        self.O_T_EE_c = self.O_T_EE_of(q)
        self.O_dP_EE_c = np.zeros(6)
        self.O_ddP_EE_c = np.zeros(6)
        self.elbow_c = np.array([q[2], np.sign(q[3]) or -1.0])
        self.delbow_c = np.zeros(2)
        self.ddelbow_c = np.zeros(2)
        self.tau_J_d = np.zeros(7)
        self._first_command = True
        self._answered: int | None = None  # the state the last motion command answered (its message id)
        self._after_command: tuple | None = None  # the desired motion right after that command

    # ------------------------------------------------------------------ settings (TCP setters)
    def set_joint_impedance(self, K_theta: np.ndarray) -> None:
        self.K_theta = np.asarray(K_theta, dtype=float).copy()
        self.joint_ctrl.k = self.K_theta

    def set_cartesian_impedance(self, K_x: np.ndarray) -> None:
        self.K_x = np.asarray(K_x, dtype=float).copy()
        self.cart_ctrl.k = self.K_x.copy()
        self.cart_ctrl.d = None  # critical damping recomputed from the new stiffness

    def set_collision_behavior(self, lower_torque: np.ndarray, upper_torque: np.ndarray, lower_force: np.ndarray,
                               upper_force: np.ndarray) -> None:
        self.lower_torque_thresholds = np.asarray(lower_torque, dtype=float)
        self.torque_thresholds = np.asarray(upper_torque, dtype=float)
        self.lower_force_thresholds = np.asarray(lower_force, dtype=float)
        self.force_thresholds = np.asarray(upper_force, dtype=float)

    def set_load(self, mass: float, F_x_Cload: np.ndarray, I_load: np.ndarray) -> None:
        """Declare a load (kg, com in the flange frame m, inertia about the com kg m^2): the robot's gravity
        compensation then includes it, whether or not the plant carries it (as on the real robot)."""
        from franka_vs_gym.model import FrankaModel

        self.m_load, self.F_x_Cload, self.I_load = float(mass), np.array(F_x_Cload, float), np.array(I_load, float)
        self._settings_changed = True
        if self.m_load > 0:
            self._load_model = FrankaModel(self.model.config)
            self._load_model.set_payload(self.m_load, self.F_x_Cload, self.I_load)
        else:
            self._load_model = None

    # ------------------------------------------------------------------ motions
    def start_motion(self, controller: MoveControllerMode, generator: MoveMotionGeneratorMode) -> None:
        self.robot_mode = RobotMode.MOVE
        self.mg_mode = _MG_FROM_MOVE[generator]
        self.ctrl_mode = _CTRL_FROM_MOVE[controller]
        self.last_motion_errors[:] = False
        self.missed_in_row = 0
        self.worst_missed = 0  # the motion's longest run of cycles without a command (real time)
        self._reset_desired()

    def finish_motion(self) -> None:
        """Back to idle, holding the current position."""
        self.robot_mode = RobotMode.IDLE
        self.mg_mode = MotionGeneratorMode.IDLE
        self.ctrl_mode = ControllerMode.JOINT_IMPEDANCE
        self._reset_desired()

    def enter_reflex(self, reasons: tuple[str, ...] | list[str], detail: str = "") -> None:
        flags = error_flags(reasons)
        self.errors |= flags
        self.last_motion_errors[:] = flags
        self.reflex_detail = detail
        self.robot_mode = RobotMode.REFLEX
        self.mg_mode = MotionGeneratorMode.IDLE
        self.ctrl_mode = ControllerMode.OTHER
        self._reset_desired()
        self.sim.stop_joints()  # brakes engaged

    def automatic_error_recovery(self) -> None:
        self.errors[:] = False
        recover = getattr(self.sim, "automatic_error_recovery", None)
        if recover is not None:
            recover()
            self.sim.set_robot_state(FORCE_TORQUE)
        self.robot_mode = RobotMode.IDLE
        self.mg_mode = MotionGeneratorMode.IDLE
        self.ctrl_mode = ControllerMode.JOINT_IMPEDANCE
        self._reset_desired()

    @property
    def moving(self) -> bool:
        return self.robot_mode == RobotMode.MOVE

    @property
    def finished_by(self) -> str:
        return "torque" if self.mg_mode == MotionGeneratorMode.NONE else "motion"

    # ------------------------------------------------------------------ motion generators
    def _check_joint_trajectory(self, q_d: np.ndarray, dq_d: np.ndarray, ddq_d: np.ndarray, dddq_d: np.ndarray,
                                prefix: str) -> None:
        # Joint trajectories of Cartesian commands come from this robot's inverse kinematics, not the FER's: their
        # accelerations and jerks are checked against twice the limits (a discontinuity, not a planning detail).
        tol = 1.0 + LIMIT_TOLERANCE if prefix.startswith("joint") else CARTESIAN_JOINT_TOLERANCE
        if (q_d > self.q_max).any() or (q_d < self.q_min).any():
            j = int(np.argmax(np.maximum(q_d - self.q_max, self.q_min - q_d)))
            raise Reflex([f"{prefix}position_limits_violation"],
                         f"commanded joint {j} at {q_d[j]:.4f} rad, limits [{self.q_min[j]}, {self.q_max[j]}]")
        if self._envelope is not None:  # position-based velocity limits (FR3)
            lo, up = velocity_bounds(q_d, self.desc, self._envelope)
        else:
            lo, up = -self.dq_max, self.dq_max
        over = np.maximum(dq_d - up, lo - dq_d)
        if over.max() > 1e-9:
            j = int(np.argmax(over))
            raise Reflex([f"{prefix}velocity_limits_violation"],
                         f"commanded joint {j} velocity {dq_d[j]:.3f} rad/s at {q_d[j]:.3f} rad, "
                         f"limits [{lo[j]:.3f}, {up[j]:.3f}]")
        r = np.abs(ddq_d) / self.ddq_max
        if r.max() > tol:
            j = int(np.argmax(r))
            raise Reflex([f"{prefix}velocity_discontinuity"],
                         f"commanded joint {j} acceleration {ddq_d[j]:.1f} rad/s^2, limit {self.ddq_max[j]}")
        r = np.abs(dddq_d) / self.dddq_max
        if r.max() > tol:
            j = int(np.argmax(r))
            raise Reflex([f"{prefix}acceleration_discontinuity"],
                         f"commanded joint {j} jerk {dddq_d[j]:.0f} rad/s^3, limit {self.dddq_max[j]}")

    def _advance_joint(self, q_new: np.ndarray, prefix: str) -> None:
        dt = self._cmd_dt
        dq_new = (q_new - self.q_d) / dt
        ddq_new = (dq_new - self.dq_d) / dt
        dddq_new = (ddq_new - self.ddq_d) / dt
        self._check_joint_trajectory(q_new, dq_new, ddq_new, dddq_new, prefix)
        self.q_d, self.dq_d, self.ddq_d = q_new, dq_new, ddq_new

    def _ik(self, T: np.ndarray, elbow: float | None) -> np.ndarray:
        """Joint position reaching EE pose T (4x4 in O) from the current q_d: with joint 3 at ``elbow`` when given
        (a square 7x7 system), else the minimum-norm joint step (the elbow follows)."""
        q = self.q_d.copy()
        A = np.zeros((7, 7))
        A[6, 2] = 1.0
        b = np.zeros(7)
        for _ in range(4):
            b[:6] = _pose_err(self.O_T_EE_of(q), T)
            if elbow is not None:
                b[6] = elbow - q[2]
            if np.abs(b).max() < 1e-10:  # 0.1 nm, 0.1 nrad
                break
            J = self._J_EE(q)
            if elbow is None:  # minimum-norm step J^T (J J^T)^-1 b
                try:
                    step = J.T @ np.linalg.solve(J @ J.T, b[:6])
                except np.linalg.LinAlgError:
                    step = np.linalg.lstsq(J, b[:6], rcond=1e-6)[0]
            else:
                A[:6] = J
                try:
                    step = np.linalg.solve(A, b)
                except np.linalg.LinAlgError:
                    step = np.linalg.lstsq(A, b, rcond=1e-6)[0]
            q = q + step
        return q

    def _extrapolate(self) -> None:
        """A motion generator's cycle without a command: the desired motion goes on with constant acceleration, as
        the FCI does when a packet is lost (libfranka's rate_limiting.h, ``kTolNumberPacketsLost``: "FCI assumes a
        constant acceleration model"), so a command that arrives a cycle late, computed for the later time, continues
        the trajectory instead of jumping from a held one. Joint space; a Cartesian generator's pose follows the
        extrapolated joints (forward kinematics) and its twist the constant acceleration."""
        dt = self.dt
        self.dq_d = self.dq_d + self.ddq_d * dt
        self.q_d = self.q_d + self.dq_d * dt
        if self.mg_mode in (MotionGeneratorMode.CARTESIAN_POSITION, MotionGeneratorMode.CARTESIAN_VELOCITY):
            self.O_dP_EE_c = self.O_dP_EE_c + self.O_ddP_EE_c * dt
            self.O_T_EE_c = self.O_T_EE_of(self.q_d)
            self.delbow_c = self.delbow_c + self.ddelbow_c * dt
            self.elbow_c = np.array([self.q_d[2], self.elbow_c[1]])

    def _desired(self) -> tuple:
        return (self.q_d, self.dq_d, self.ddq_d, self.O_T_EE_c, self.O_dP_EE_c, self.O_ddP_EE_c, self.elbow_c,
                self.delbow_c)

    def _to_command_time(self, answered: int) -> None:
        """Put the desired motion where a command answering state ``answered`` continues it, in the client's time.
        A command answering state n is the motion generator's value one cycle after state n. The desired motion
        restarts from the last command (answering state k), whatever the server extrapolated meanwhile for cycles
        without a command, and the new command spans the n - k cycles since then (its velocity, acceleration and
        jerk are differences over that span, as the client's own clock has them: a client that skipped a state,
        its ``period`` 2 ms, is checked on its 2 ms grid, and a command one cycle late takes the place of the
        extrapolated cycle). In lock-step, and in real time while the client keeps up, n = k + 1: one cycle, as
        before."""
        if self._answered is None or self._after_command is None:
            return
        span = answered - self._answered
        if span < 1 or span > self.max_missed_commands + 1:
            return
        (self.q_d, self.dq_d, self.ddq_d, self.O_T_EE_c, self.O_dP_EE_c, self.O_ddP_EE_c, self.elbow_c,
         self.delbow_c) = self._after_command
        self._cmd_dt = span * self.dt

    def _cartesian_checks(self, T_new: np.ndarray) -> None:
        dt, c, tol = self._cmd_dt, self.cart, 1.0 + LIMIT_TOLERANCE
        v = _pose_err(self.O_T_EE_c, T_new) / dt  # [translation; rotation vector in O] per step
        a = (v - self.O_dP_EE_c) / dt
        j = (a - self.O_ddP_EE_c) / dt
        checks = ((v, c.v_max, c.w_max, "velocity_limits_violation", "m/s", 1.0 + 1e-9),
                  (a, c.a_max, c.alpha_max, "velocity_discontinuity", "m/s^2", tol),
                  (j, c.j_max, c.rot_j_max, "acceleration_discontinuity", "m/s^3", tol))
        if not self._first_command:
            for vec, lin, rot, name, unit, k in checks:
                nl, nr = _norm3(vec[:3]), _norm3(vec[3:])
                if nl > lin * k or nr > rot * k:
                    raise Reflex([f"cartesian_motion_generator_{name}"],
                                 f"commanded end-effector {nl:.3g} {unit} (limit {lin}), "
                                 f"rotation {nr:.3g} (limit {rot})")
        self.O_dP_EE_c, self.O_ddP_EE_c = v, a

    def _apply_motion(self, cmd: RobotCommand) -> None:
        mg = self.mg_mode
        if mg == MotionGeneratorMode.JOINT_POSITION:
            self._advance_joint(np.array(cmd.q_c), "joint_motion_generator_")
        elif mg == MotionGeneratorMode.JOINT_VELOCITY:
            self._advance_joint(self.q_d + self._cmd_dt * np.asarray(cmd.dq_c), "joint_motion_generator_")
        elif mg in (MotionGeneratorMode.CARTESIAN_POSITION, MotionGeneratorMode.CARTESIAN_VELOCITY):
            if mg == MotionGeneratorMode.CARTESIAN_POSITION:
                T = np.asarray(cmd.O_T_EE_c).reshape(4, 4, order="F").copy()
                R = T[:3, :3]
                if not (np.abs(R @ R.T - _I3).max() < 1e-4 and np.abs(T[3] - _ROW3).max() < 1e-9):
                    raise Reflex(["cartesian_position_motion_generator_invalid_frame_flag"],
                                 "O_T_EE_c is not a homogeneous transformation")
            else:
                tw = np.asarray(cmd.O_dP_EE_c)
                T = self.O_T_EE_c.copy()
                T[:3, 3] += tw[:3] * self._cmd_dt
                T[:3, :3] = _expm_so3(tw[3:] * self._cmd_dt) @ T[:3, :3]
            self._cartesian_checks(T)
            if cmd.valid_elbow:
                elbow = float(cmd.elbow_c[0])
                if np.sign(cmd.elbow_c[1]) != np.sign(self.elbow_c[1]):
                    raise Reflex(["cartesian_motion_generator_elbow_sign_inconsistent"],
                                 f"elbow flip {cmd.elbow_c[1]} differs from the current {self.elbow_c[1]}")
                q_new = self._ik(T, elbow)
            else:
                q_new = self._ik(T, None)
            new_elbow = np.array([q_new[2], self.elbow_c[1]])
            d1 = (new_elbow - self.elbow_c) / self._cmd_dt
            self.ddelbow_c = (d1 - self.delbow_c) / self._cmd_dt
            self.delbow_c, self.elbow_c = d1, new_elbow
            self.O_T_EE_c = T
            self._advance_joint(q_new, "cartesian_motion_generator_joint_")
        self._first_command = False

    # ------------------------------------------------------------------ one control cycle
    def control_torque(self, cmd: RobotCommand | None) -> np.ndarray:
        """Gravity-free joint torque for this cycle (may raise :class:`Reflex`)."""
        q, dq = self.q, self.dq
        if self.robot_mode != RobotMode.MOVE:
            return self._joint_impedance(q, dq, self.q_hold, np.zeros(7), None)
        if cmd is not None:
            if self.mg_mode != MotionGeneratorMode.NONE:
                self._to_command_time(cmd.message_id)
                try:
                    self._apply_motion(cmd)
                finally:
                    self._cmd_dt = self.dt
                self._answered = cmd.message_id
                self._after_command = self._desired()
            if self.ctrl_mode == ControllerMode.EXTERNAL_CONTROLLER:
                tau = np.array(cmd.tau_J_d, dtype=float)
                if not _all(np.isfinite(tau)):
                    raise Reflex(["controller_torque_discontinuity"], "non-finite torque command")
                rate = np.abs(tau - self.tau_J_d) / self.dt
                if _any(rate > self.dtau_max * (1.0 + LIMIT_TOLERANCE)):
                    j = int(np.argmax(rate / self.dtau_max))
                    raise Reflex(["controller_torque_discontinuity"],
                                 f"joint {j} torque rate {rate[j]:.0f} Nm/s, limit {self.dtau_max[j]}")
                self.tau_J_d = tau
                return tau
        else:  # a cycle without a command (real time: the client missed it)
            if self.mg_mode != MotionGeneratorMode.NONE:
                self._extrapolate()
            if self.ctrl_mode == ControllerMode.EXTERNAL_CONTROLLER:
                return self.tau_J_d  # the last torque is held
        if self.ctrl_mode == ControllerMode.CARTESIAN_IMPEDANCE:
            T = self.O_T_EE_c @ self.EE_T_K  # goal of the stiffness frame
            v = self.O_dP_EE_c.copy()
            v[:3] += np.cross(v[3:], self.O_T_EE_c[:3, :3] @ self.EE_T_K[:3, 3])
            tau = self.cart_ctrl(q, dq, T, v)
        else:
            tau = self._joint_impedance(q, dq, self.q_d, self.dq_d, self.ddq_d)
        self.tau_J_d = tau
        return tau

    def _joint_impedance(self, q: np.ndarray, dq: np.ndarray, q_d: np.ndarray, dq_d: np.ndarray,
                         ddq_d: np.ndarray | None) -> np.ndarray:
        """The internal joint impedance controller, the law of :class:`~franka_vs_gym.control.JointImpedance`
        (stiffness ``K_theta``, critical damping on the diagonal of B(q) plus the motors' effective armature,
        inertial (motors included), Coriolis and friction feed-forward) with one evaluation of B per cycle. Its
        damping ``D (dq_d - dq)`` runs in the plant's joint velocity servos, which MuJoCo integrates implicitly;
        the rest is the returned motor torque. The FER's joint controllers run faster than the 1 kHz interface; an
        explicit 1 ms damping term would be unstable on the
        light coupled modes of the arm (e.g. joints 1 and 3 turning against each other when aligned). The state's
        tau_J (``FrankaSim.get_force_torque``) includes the servos' force as applied, at the end-of-step velocity."""
        m, ctrl, rotor = self.model, self.joint_ctrl, self.sim.rotor_inertia
        B = m.mass_matrix(q)
        D = 2.0 * ctrl.zeta * np.sqrt(ctrl.k * (B.diagonal() + rotor))  # the robot's controllers know its motors
        self._set_servo(D, dq_d)
        tau = ctrl.k * (q_d - q) + m.coriolis(q, dq) + m.friction(dq_d)
        if ddq_d is not None:  # implicit damping acts on the end-of-step velocity: feed its share of ddq_d forward
            tau += B @ ddq_d + (rotor + self.dt * D) * ddq_d
        return tau

    def _set_servo(self, D: np.ndarray, dq_d: np.ndarray) -> None:
        """Gains (Nm s/rad) and set point (rad/s) of the plant's joint velocity servos."""
        self._servo_gain[:] = D
        np.negative(D, out=self._servo_bias)
        self._servo_ctrl[:] = dq_d
        self._servo_on = True

    def _servo_off(self) -> None:
        if self._servo_on:
            self._servo_gain[:] = 0.0
            self._servo_bias[:] = 0.0
            self._servo_ctrl[:] = 0.0
            self._servo_on = False

    def step(self, cmd: RobotCommand | None) -> tuple[str, ...]:
        """Apply ``cmd`` (or hold), step the plant 1 ms, check the reflexes. Returns the reflex reasons (empty if
        none fired); on a reflex the robot is already in REFLEX mode."""
        sim = self.sim
        try:
            self._servo_off()
            if self.robot_mode == RobotMode.REFLEX and getattr(sim, "current_errors", ()):
                sim.step()  # the simulator's brakes hold the arm until automatic_error_recovery
                return ()
            tau = self.control_torque(cmd)
            if self.plant_gravity is not None:
                believed = self._load_model if self._load_model is not None else self.model
                tau = tau + believed.gravity(self.q) - self.plant_gravity.gravity(self.q)
            elif self._load_model is not None:
                tau = tau + self._load_model.gravity(self.q) - self.model.gravity(self.q)
            sim.set_force_torque(JOINT_STATE, tau)
            sim.step()
            if self.robot_mode == RobotMode.MOVE and not getattr(sim, "reflexes", False):
                self._check_plant()  # (a simulator with its own reflexes is the authority on its limits)
        except Reflex as r:
            self.enter_reflex(r.reasons, r.detail)
            return r.reasons
        except ControlException as e:  # the simulator's own reflexes
            reasons = tuple(getattr(e, "reasons", ("joint_reflex",)))
            self.enter_reflex(reasons, getattr(e, "detail", str(e)))
            return reasons
        except SimulationDiverged as e:
            self.enter_reflex(("instability_detected",), str(e))
            return ("instability_detected",)
        return ()

    def _check_plant(self) -> None:
        q, dq = self.q, self.dq
        over = ((q > self.q_max) & (dq > 0)) | ((q < self.q_min) & (dq < 0))
        if _any(over):
            j = int(np.argmax(over))
            raise Reflex(["joint_position_limits_violation"],
                         f"joint {j} at {q[j]:.4f} rad, limits [{self.q_min[j]}, {self.q_max[j]}]")
        r = np.abs(dq) / self.dq_max
        if _amax(r) > 1.0 + PLANT_VELOCITY_MARGIN:
            j = int(np.argmax(r))
            raise Reflex(["joint_velocity_violation"], f"joint {j} at {dq[j]:.3f} rad/s, limit {self.dq_max[j]}")

    def count_command(self, received: bool, silent: int | None = None) -> None:
        """Real-time bookkeeping: whether this cycle's command arrived in time; ``silent``: the cycles of wall time
        since the client last owed a command (the server may have run fewer cycles when the machine ran it late;
        the client's silence counts in wall time, as the robot counts it)."""
        self._success_sum += int(received) - int(self.success_window[self._win_i])
        self.success_window[self._win_i] = received
        self._win_i = (self._win_i + 1) % len(self.success_window)
        self.missed_in_row = 0 if received else max(self.missed_in_row + 1, silent or 0)
        if self.missed_in_row > self.worst_missed:
            self.worst_missed = self.missed_in_row
        if self.missed_in_row > self.max_missed_commands and self.robot_mode == RobotMode.MOVE:
            self.enter_reflex(("communication_constraints_violation",),
                              f"{self.missed_in_row} cycles in a row without a command")

    # ------------------------------------------------------------------ state
    def external_torque(self) -> np.ndarray:
        """The external joint torque the robot feels (7,), Nm, in libfranka's sign convention (``tau_J`` minus
        what the motion needs): minus the generalized force of the plant's contacts on the arm."""
        d = self.sim.world.data
        if d.ncon == 0:
            return np.zeros(7)
        return -np.array(d.qfrc_constraint[self.sim.dof_slice])

    def _fill_settings(self) -> None:
        """State fields that change only with the settings (frames, end effector and load, gravity)."""
        f = self.state.f
        f["F_T_EE"][:] = _cm(self.F_T_NE @ self.NE_T_EE)
        f["EE_T_K"][:] = _cm(self.EE_T_K)
        f["F_T_NE"][:] = _cm(self.F_T_NE)
        f["NE_T_EE"][:] = _cm(self.NE_T_EE)
        f["m_ee"][0] = self.m_ee
        f["I_ee"][:] = _cm(self.I_ee)
        f["F_x_Cee"][:] = self.F_x_Cee
        f["m_load"][0] = self.m_load
        f["I_load"][:] = _cm(self.I_load)
        f["F_x_Cload"][:] = self.F_x_Cload
        f["O_ddP_O"][:] = self.gravity
        self._settings_changed = False

    def set_EE_to_K(self, EE_T_K: np.ndarray) -> None:
        """Stiffness frame K in the end-effector frame (4x4)."""
        self.EE_T_K = np.array(EE_T_K, dtype=float)
        self._settings_changed = True
        self._update_cartesian_controller()

    def set_NE_to_EE(self, NE_T_EE: np.ndarray) -> None:
        """End-effector frame in the nominal end-effector frame (4x4)."""
        self.NE_T_EE = np.array(NE_T_EE, dtype=float)
        self._settings_changed = True
        self._update_cartesian_controller()

    def fill_state(self) -> RobotStateBuffer:
        st, f = self.state, self.state.f
        q, dq = self.q, self.dq
        tau_J = self.sim.get_force_torque(JOINT_STATE)
        O_T_EE = self.O_T_EE_of(q)
        f["O_T_EE"][:] = _cm(O_T_EE)
        moving = self.robot_mode == RobotMode.MOVE
        if moving and self.mg_mode != MotionGeneratorMode.NONE:
            q_d, dq_d, ddq_d = self.q_d, self.dq_d, self.ddq_d
            f["O_T_EE_d"][:] = _cm(self.O_T_EE_of(q_d))
            f["O_dP_EE_d"][:] = self._J_EE(q_d) @ dq_d if dq_d.any() else 0.0
        else:
            q_d, dq_d, ddq_d = q, dq, np.zeros(7)
            f["O_T_EE_d"][:] = f["O_T_EE"]
            f["O_dP_EE_d"][:] = 0.0
        if moving and self.mg_mode in (MotionGeneratorMode.CARTESIAN_POSITION, MotionGeneratorMode.CARTESIAN_VELOCITY):
            f["O_T_EE_c"][:] = _cm(self.O_T_EE_c)
            f["O_dP_EE_c"][:] = self.O_dP_EE_c
            f["O_ddP_EE_c"][:] = self.O_ddP_EE_c
            f["elbow_c"][:] = self.elbow_c
            f["delbow_c"][:] = self.delbow_c
            f["ddelbow_c"][:] = self.ddelbow_c
        else:
            f["O_T_EE_c"][:] = f["O_T_EE_d"]
            f["O_dP_EE_c"][:] = f["O_dP_EE_d"]
            f["O_ddP_EE_c"][:] = 0.0
            f["elbow_c"][:] = (q_d[2], -1.0 if q_d[3] < 0 else 1.0)
            f["delbow_c"][:] = (dq_d[2], 0.0)
            f["ddelbow_c"][:] = 0.0
        if self._settings_changed:
            self._fill_settings()
        f["elbow"][:] = (q[2], -1.0 if q[3] < 0 else 1.0)
        f["elbow_d"][:] = (q_d[2], -1.0 if q_d[3] < 0 else 1.0)
        f["tau_J"][:] = tau_J
        f["tau_J_d"][:] = self.tau_J_d
        f["dtau_J"][:] = (tau_J - self.tau_J_prev) / self.dt
        self.tau_J_prev = tau_J
        f["q"][:] = q
        f["q_d"][:] = q_d
        f["dq"][:] = dq
        f["dq_d"][:] = dq_d
        f["ddq_d"][:] = ddq_d
        if self.sim.joint_effects is not None and self.sim.joint_effects.elastic.any():  # the motor side
            f["theta"][:], f["dtheta"][:] = self.sim.motor_state()
        else:
            f["theta"][:] = q
            f["dtheta"][:] = dq
        tau_ext = self.external_torque()
        f["tau_ext_hat_filtered"][:] = tau_ext
        if _any(tau_ext):
            J = self._J_EE(q, (self.NE_T_EE @ self.EE_T_K)[:3, 3])  # the wrench acts at K's origin
            F = np.linalg.lstsq(J.T, tau_ext, rcond=1e-6)[0]
            R = (O_T_EE @ self.EE_T_K)[:3, :3]
            f["O_F_ext_hat_K"][:] = F
            f["K_F_ext_hat_K"][:] = np.concatenate([R.T @ F[:3], R.T @ F[3:]])
            f["joint_contact"][:] = np.abs(tau_ext) > self.lower_torque_thresholds
            f["joint_collision"][:] = np.abs(tau_ext) > self.torque_thresholds
            f["cartesian_contact"][:] = np.abs(F) > self.lower_force_thresholds
            f["cartesian_collision"][:] = np.abs(F) > self.force_thresholds
            self._contact_fields_zero = False
        elif not self._contact_fields_zero:
            for k in ("O_F_ext_hat_K", "K_F_ext_hat_K", "joint_contact", "joint_collision", "cartesian_contact",
                      "cartesian_collision"):
                f[k][:] = 0.0
            self._contact_fields_zero = True
        st.motion_generator_mode = self.mg_mode
        st.controller_mode = self.ctrl_mode
        st.robot_mode = self.robot_mode
        st.errors = self.errors
        st.reflex_reason = self.last_motion_errors
        st.control_command_success_rate = self._success_sum / len(self.success_window)
        return st

    def collision_reflex(self) -> tuple[str, ...]:
        """Joint/Cartesian collision reflexes from the last state's contact estimate (while moving)."""
        if self.robot_mode != RobotMode.MOVE or self._contact_fields_zero:  # (no contact: no collision flag set)
            return ()
        f = self.state.f
        reasons = []
        if _any(f["joint_collision"]):
            reasons.append("joint_reflex")
        if _any(f["cartesian_collision"]):
            reasons.append("cartesian_reflex")
        if reasons:
            self.enter_reflex(reasons, "external force above the collision thresholds")
        return tuple(reasons)


__all__ = ["DEFAULT_K_THETA", "DEFAULT_K_X", "MAX_MISSED_COMMANDS", "FCIRobot", "Reflex"]
