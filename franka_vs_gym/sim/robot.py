"""FrankaSim: a simulated FER whose API mirrors ViSP's vpRobotFranka.

Controller code written against :class:`FrankaSim` needs only its construction changed to run on the real robot
with ViSP: the control states, frames and method names are ViSP's (snake_case, with camelCase aliases such as
``setVelocity``), getters return values instead of filling output arguments, and time is the simulator's.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from franka_vs_gym.assets.mjcf import CameraSpec, RobotSpec, SceneSpec, TagSpec, mat2quat
from franka_vs_gym.errors import UserError
from franka_vs_gym.model.checks import as_pose, as_vector
from franka_vs_gym.model.config import ModelConfig, RigidBody, Tool, resolve_config
from franka_vs_gym.model.description import FER, RobotDescription
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.model.friction import make_plant_friction
from franka_vs_gym.model.geometry import (
    CAMERA_VISP_TO_MUJOCO,
    combine_inertials,
    homogeneous,
    pose_vector,
    twist_transform,
)
from franka_vs_gym.model.joint_effects import JointEffects
from franka_vs_gym.sim import plant
from franka_vs_gym.sim.rate_limit import rate_limits
from franka_vs_gym.sim.reflexes import ARMED, ControlException, Reflexes, position_profile_time
from franka_vs_gym.sim.world import SimulationDiverged, SimWorld
from franka_vs_gym.sim.world import no_op as _no_op


class RobotState(enum.IntEnum):
    """Control states, as vpRobot::vpRobotStateType."""

    STATE_STOP = 0
    STATE_VELOCITY_CONTROL = 1
    STATE_POSITION_CONTROL = 2
    STATE_ACCELERATION_CONTROL = 3
    STATE_FORCE_TORQUE_CONTROL = 4


class ControlFrame(enum.IntEnum):
    """Frames of commands and measurements, as vpRobot::vpControlFrameType."""

    REFERENCE_FRAME = 0  # f, the robot base
    ARTICULAR_FRAME = 1
    JOINT_STATE = 1
    END_EFFECTOR_FRAME = 2
    TOOL_FRAME = 2
    CAMERA_FRAME = 3
    MIXT_FRAME = 4


# Short aliases (ViSP users write vpRobot::JOINT_STATE, vpRobot::STATE_VELOCITY_CONTROL).
STOP, POSITION, VELOCITY, FORCE_TORQUE = (RobotState.STATE_STOP, RobotState.STATE_POSITION_CONTROL,
                                          RobotState.STATE_VELOCITY_CONTROL, RobotState.STATE_FORCE_TORQUE_CONTROL)
JOINT_STATE, END_EFFECTOR_FRAME, CAMERA_FRAME, REFERENCE_FRAME = (
    ControlFrame.JOINT_STATE, ControlFrame.END_EFFECTOR_FRAME, ControlFrame.CAMERA_FRAME, ControlFrame.REFERENCE_FRAME)

# Default wrist camera mount: optical axis along the end-effector z axis, 9 cm to the side of the fingers (x_e)
# and 5 cm behind the finger tips, so the fingers stay out of the image.
DEFAULT_eMc = np.array([[1.0, 0.0, 0.0, 0.09], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -0.05], [0.0, 0.0, 0.0, 1.0]])
# Gains of the FER's joint velocity servo (Nm s/rad); each robot's own are ``RobotDescription.servo_gains``.
VELOCITY_GAINS = np.array(FER.servo_gains)
# Velocity commands are scaled to 98 % of the limits at most, so that the joint servo's small overshoot does not trip
# the velocity reflex (libfranka's rate limiter likewise keeps commands a margin below the limits).
VELOCITY_COMMAND_SCALE = 0.98
_IMPLICITFAST = int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)


@dataclass(frozen=True)
class BatchLayout:
    """A robot's place in its MuJoCo data (:meth:`FrankaSim.batch_layout`): index slices of its joints in ``qpos``
    and ``qvel``, of its torque motors and velocity servos in ``ctrl``, the offset of its reflex record in
    ``userdata`` (-1 without the compiled plant; see :mod:`franka_vs_gym.sim.reflexes`), its reflex limits
    q_min, q_max (rad) and dq_max (rad/s), (7,) each, and the MuJoCo id of its first joint."""

    qpos: slice
    qvel: slice
    ctrl_torque: slice
    ctrl_velocity: slice
    reflex_record: int
    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    first_joint: int


class FrankaSim:
    """A simulated Franka arm (the FER by default, or any registered robot: ``robot="fr3"``) with the API of ViSP's
    vpRobotFranka.

    Control states (``set_robot_state``): STOP, POSITION (``set_position`` moves there), VELOCITY (``set_velocity``
    in JOINT_STATE, END_EFFECTOR_FRAME, CAMERA_FRAME or REFERENCE_FRAME) and FORCE_TORQUE (``set_force_torque``
    with gravity-free joint torques: the robot adds g(q) itself, as libfranka does).

    Units and frames: SI (rad, rad/s, Nm, m, s). f is the base, e the end effector (``flMe`` of the tool), c the
    wrist camera (``eMc``; ViSP convention: z forward, x right, y down). Twists are [v; w] (6,).

    Limits, as on the real robot: torque commands are saturated at the robot's torque limits (87/12 Nm; the total
    actuator torque, command plus gravity, is clamped too); joint velocity commands (and the joint velocities a
    Cartesian command maps to) are scaled down uniformly so that no joint exceeds its velocity limit; joint
    position limits are hard stops in the plant. NaN, inf or wrong-shape commands raise ValueError and never
    reach MuJoCo. A diverging simulation raises :class:`SimulationDiverged`.

    Parameters
    ----------
    model : ModelConfig, FrankaModel, path to a calibrated model file, or None
        The robot (tool, payload, gravity, friction...). Both the plant and ``self.model`` are built from it.
    robot : RobotDescription, a registered name ("fer", "fr3"), or None
        The arm when ``model`` is None (``FrankaSim(robot="fr3")``); with a ``model`` it must name the same robot.
    friction : bool
        Apply the configured joint friction in the plant (default True). The model's friction is unaffected.
    camera : bool
        Add the wrist camera.
    cameras : list of CameraSpec
        Cameras fixed in the world (e.g. an eye-to-hand camera).
    tags : list of TagSpec
        AprilTags in the scene (e.g. ``[TagSpec()]``: an 8 cm tag id 0 on the table).
    world, prefix :
        To put several robots in one scene, build a :class:`SimWorld` from a SceneSpec with several RobotSpecs and
        make one FrankaSim per prefix; ``world.step()`` (or any robot's ``step``) advances all of them.
    q0 : (7,) initial joint position (default the neutral pose).
    torque_noise : standard deviation (Nm) of white noise added to measured torques.
    seed : seed of the measurement-noise generator.
    reflexes : enforce the robot's limits as the real FER does (default True): a measured joint position,
        velocity or torque beyond its limit holds the joints (brakes) and raises
        :class:`~franka_vs_gym.sim.reflexes.ControlException` with libfranka's reason name; ``current_errors``
        lists them and ``automatic_error_recovery()`` clears them. See :mod:`franka_vs_gym.sim.reflexes`.
    rotor_inertia : put the robot's effective armature (``RobotDescription.rotor_inertia``: the motors and gears as
        a torque controller feels them through the robot's torque loop) between the commanded torque and the link
        (default False: an ideal link-side torque source, what the environments and the project's link-side
        controllers are tuned on; the FCI server's robot has it on). ``tau_J`` stays the link-side torque.
    command_rates : "pass" (default: commands reach the joints as given), "limit" (through the robot interface's
        rate limiter, libfranka's ``limitRate`` with the robot's published limits: franka_vs_gym.sim.rate_limit)
        or "check" (a command that jumps beyond those limits within one 1 ms cycle trips
        ``controller_torque_discontinuity`` or the joint motion generator's discontinuity reflexes, as a raw
        libfranka loop does).
    joint_effects : the plant's cogging, static friction and elastic transmission with backlash
        (:class:`~franka_vs_gym.model.joint_effects.JointEffects`; default None: none), effects the robot's model does
        not know. With an elastic joint the motor position ``theta`` differs from ``q`` (:meth:`motor_state`) and
        ``tau_J`` is the transmission's torque. Needs the compiled plant.
    """

    def __init__(self, model: Any = None, *, robot: RobotDescription | str | None = None, friction: bool = True,
                 camera: bool = True, tags: list[TagSpec] | None = None, table: bool = True, timestep: float = 0.001,
                 world: SimWorld | None = None, prefix: str = "r0_", q0: Any = None, ft_sensor: bool = False,
                 undeclared_payload: RigidBody | None = None, torque_noise: float = 0.0, seed: int | None = None,
                 extra_worldbody: str = "", extra_assets: str = "", reflexes: bool = True,
                 command_rates: str = "pass", cameras: list[CameraSpec] | None = None,
                 rotor_inertia: bool = False, joint_effects: JointEffects | None = None) -> None:
        world, spec, cfg = self._make_world(model, robot, world, prefix, camera=camera, tags=tags, table=table,
                                            cameras=cameras, timestep=timestep, ft_sensor=ft_sensor,
                                            rotor_inertia=rotor_inertia, joint_effects=joint_effects,
                                            undeclared_payload=undeclared_payload, extra_worldbody=extra_worldbody,
                                            extra_assets=extra_assets)
        self.world, self.prefix, self.spec = world, prefix, spec
        self._m, self._d = world.model, world.data
        self.model = FrankaModel(cfg)
        self._use_mounting_gravity(cfg)
        self.dt = world.dt
        jids = self._bind_mujoco()
        lim = self.model.limits()
        self.q_min, self.q_max, self.dq_max, self.tau_max = lim["q_min"], lim["q_max"], lim["dq_max"], lim["tau_max"]
        self._setup_friction(cfg, friction, jids)
        self._setup_delay(cfg)
        self._tau_cmd = np.zeros(7)
        self._offset = cfg.torque_offset.copy()
        # the plant's effective armature (kg m^2): the description's rotor_inertia when the spec asks for it
        self.rotor_inertia = np.array(cfg.robot.rotor_inertia if spec.rotor_inertia else (0.0,) * 7, dtype=np.float64)
        self.servo_gains = self._servo_gains(cfg)  # joint velocity servo, Nm s/rad
        self._setup_joint_effects(cfg)
        self._torque_noise = float(torque_noise)
        if not (math.isfinite(self._torque_noise) and self._torque_noise >= 0):
            raise ValueError(f"torque_noise must be a finite number >= 0 Nm (standard deviation), got {torque_noise}")
        self._rng = np.random.default_rng(seed)
        self._state = RobotState.STATE_STOP
        self._eMc = DEFAULT_eMc.copy()
        self._positioning_velocity = 20.0
        self._hook = self._make_pre_step()
        world.add_pre_step(self._hook)
        # the reflexes' limits come from the robot description (config.robot)
        self._reflexes = Reflexes(self, cfg.robot.limits, enabled=reflexes, command_rates=command_rates,
                                  rate_limits=rate_limits(cfg.robot))
        self._reflexes.install(world)
        if self._cam >= 0:
            self.set_eMc(self._eMc)
        self.reset(cfg.robot.neutral() if q0 is None else q0)

    # ------------------------------------------------------------------ construction steps
    @staticmethod
    def _make_world(model: Any, robot: RobotDescription | str | None, world: SimWorld | None, prefix: str,
                    **scene: Any) -> tuple[SimWorld, RobotSpec, ModelConfig]:
        """(world, this robot's spec, its configuration): a new one-robot scene, or this prefix's robot in ``world``."""
        if world is None:
            cfg = resolve_config(model, robot)
            spec = RobotSpec(prefix=prefix, config=cfg, camera=scene["camera"], ft_sensor=scene["ft_sensor"],
                             undeclared_payload=scene["undeclared_payload"], rotor_inertia=scene["rotor_inertia"],
                             joint_effects=scene["joint_effects"])
            timestep = scene["timestep"]
            if not (timestep > 0 and math.isfinite(timestep)):
                raise ValueError(f"timestep must be > 0 s, got {timestep}")
            world = SimWorld(SceneSpec(robots=[spec], table=scene["table"], tags=list(scene["tags"] or []),
                                       cameras=list(scene["cameras"] or []),
                                       timestep=timestep, extra_worldbody=scene["extra_worldbody"],
                                       extra_assets=scene["extra_assets"]))
            return world, spec, cfg
        specs = [r for r in world.scene.robots if r.prefix == prefix]
        if not specs:
            raise ValueError(f"no robot with prefix {prefix!r} in the world "
                             f"(have {[r.prefix for r in world.scene.robots]})")
        return world, specs[0], specs[0].config

    def _servo_gains(self, cfg: ModelConfig) -> np.ndarray:
        """The joint velocity servo's gains (7,) Nm s/rad: the description's ``servo_gains`` (bandwidth
        ``kv / B_ii`` at the neutral pose) plus the motors' effective armature at the same bandwidth, so the servo
        keeps its bandwidth on the heavier joint (at most 0.5 / dt, so ``kv dt / (B_ii + rotor)`` stays below 1)."""
        kv = np.array(cfg.robot.servo_gains, dtype=np.float64)
        if not self.rotor_inertia.any():
            return kv
        b = np.diag(self.model.mass_matrix(cfg.robot.neutral()))
        bandwidth = np.minimum(kv / b, 0.5 / self.dt)  # rad/s; at most half the implicit step's bound
        return kv + bandwidth * self.rotor_inertia

    def _use_mounting_gravity(self, cfg: ModelConfig) -> None:
        """Gravity as the robot sees it: the world's gravity expressed in this robot's base frame (mounting)."""
        m, d = self._m, self._d
        mujoco.mj_kinematics(m, d)
        base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{self.prefix}link0")
        g_base = d.xmat[base].reshape(3, 3).T @ m.opt.gravity
        if not np.allclose(g_base, cfg.gravity, atol=1e-9):
            self.model.set_gravity(g_base)

    def _bind_mujoco(self) -> list[int]:
        """This robot's MuJoCo ids and the views into the simulator state (joints, actuators, sites, camera, F/T
        sensor) that every command and measurement uses; returns the joint ids."""
        m, d, prefix = self._m, self._d, self.prefix
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"{prefix}joint{i + 1}") for i in range(7)]
        qadr = [int(m.jnt_qposadr[j]) for j in jids]
        vadr = [int(m.jnt_dofadr[j]) for j in jids]
        if qadr != list(range(qadr[0], qadr[0] + 7)) or vadr != list(range(vadr[0], vadr[0] + 7)):
            raise RuntimeError("joint addresses of a robot must be contiguous")
        self._qs, self._vs = slice(qadr[0], qadr[0] + 7), slice(vadr[0], vadr[0] + 7)
        self._qpos, self._qvel = d.qpos[self._qs], d.qvel[self._vs]
        self._qacc = d.qacc[self._vs]
        self._qfrc_applied = d.qfrc_applied[self._vs]
        self._qfrc_actuator = d.qfrc_actuator[self._vs]
        a0 = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{prefix}motor1")
        v0 = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"{prefix}vel1")
        self._motor = slice(a0, a0 + 7)
        self._vel = slice(v0, v0 + 7)
        self._ctrl_tau, self._ctrl_vel = d.ctrl[self._motor], d.ctrl[self._vel]
        self._bind_implicit_share()
        self._ee_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"{prefix}ee")
        self._hand_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}hand")
        self._base_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{prefix}link0")
        self._cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, f"{prefix}wrist_camera")
        self._ft = None
        if self.spec.ft_sensor:
            fs = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, f"{prefix}ft_force")
            ts = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, f"{prefix}ft_torque")
            self._ft = (int(m.sensor_adr[fs]), int(m.sensor_adr[ts]))
        return jids

    def _bind_implicit_share(self) -> None:
        """Views for the share of the joint actuators' torque that MuJoCo's implicit integrator applies on top of
        ``qfrc_actuator`` (see :meth:`_applied_torque`): the diagonal of ``qDeriv`` at this robot's dofs (a strided
        view when the entries are evenly spaced, else their indices) and the start-of-step joint velocity as the
        actuators saw it (``actuator_velocity`` of the velocity servos). The scene's integrator and the joints'
        passive damping (which ``qDeriv`` holds too, but which is not actuator torque) are read here, once."""
        m, d = self._m, self._d
        v0, v1 = self._vs.start, self._vs.stop
        diag = []
        for i in range(v0, v1):
            a, n = int(m.D_rowadr[i]), int(m.D_rownnz[i])
            cols = m.D_colind[a:a + n]
            diag.append(a + int(np.flatnonzero(cols == i)[0]))
        step = diag[1] - diag[0]
        even = step > 0 and bool((np.diff(diag) == step).all())
        self._deriv_idx = None if even else np.array(diag)
        self._deriv_diag = d.qDeriv[diag[0]:diag[-1] + 1:step] if even else None
        self._servo_velocity = d.actuator_velocity[self._vel]
        damping = m.dof_damping[self._vs].copy()
        self._joint_damping = damping if damping.any() else None
        self._implicit_actuators = int(m.opt.integrator) == _IMPLICITFAST
        rot = m.dof_armature[self._vs] - self.spec.config.armature
        self._rotor = rot if np.abs(rot).max() > 0 else None  # the plant's effective armature (motor side)
        self._rotor_per_dt = None if self._rotor is None else self._rotor / m.opt.timestep

    def _applied_torque(self) -> np.ndarray:
        """The joint actuators' torque over the last physics step (7,), Nm: gravity compensation, torque motors and
        velocity servos, as the joints really applied it (a view of ``qfrc_actuator`` when nothing is added).

        MuJoCo's ``qfrc_actuator`` holds the actuator torque at the start of the step. With the scene's integrator
        (``implicitfast``) the velocity-dependent part of the actuator forces (the joint velocity servos' damping,
        ``-Kv dq``) is integrated implicitly: the step solves ``M ddq = qfrc(dq0) + qDeriv (dq1 - dq0)``, so the
        servos apply their force at the end-of-step velocity dq1 (``Kv (dq_set - dq1)``) and the joints applied
        ``qfrc_actuator + (qDeriv + damping) (dq1 - dq0)`` (``qDeriv``'s diagonal at these dofs is ``-Kv -
        damping``; it is the step's own, whatever the gains are now). Without servo gains (torque control) nothing
        is added. A call right after a step sees that step; after ``reset`` (dq1 = dq0) nothing is added.

        With an effective armature (``RobotDescription.rotor_inertia``) the actuators drive the motors, and the
        link side (the torque sensor) receives their torque minus what accelerates the motors over the step:
        ``rotor (dq1 - dq0) / dt`` is subtracted, so tau_J stays the link-side torque."""
        tau = self._qfrc_actuator
        rot = self._rotor_per_dt
        if not self._implicit_actuators:
            return tau if rot is None else tau - rot * (self._qvel - self._servo_velocity)
        k = self._deriv_diag if self._deriv_idx is None else self._d.qDeriv[self._deriv_idx]
        if self._joint_damping is not None:
            k = k + self._joint_damping
        if rot is not None:
            k = k - rot
        elif not np.count_nonzero(k):
            return tau
        dv = self._qvel - self._servo_velocity
        dv *= k
        dv += tau
        return dv

    def _setup_friction(self, cfg: ModelConfig, friction: bool, jids: list[int]) -> None:
        """Friction in the plant: -tau_f(dq) of the configured law (franka_vs_gym.model.friction). The compiled plant
        applies it inside mj_step from the parameters in the model (jnt_user); the Python friction step, written into
        qfrc_applied in place before every physics step, is the fallback without it (franka_vs_gym.sim.plant)."""
        self._friction_enabled = bool(friction) and not cfg.friction.is_zero()
        self._friction_scale = 1.0
        self._friction_step = self._make_friction_step()
        self._native = plant.install()
        self._jids = jids
        self._write_plant_friction()

    def _setup_joint_effects(self, cfg: ModelConfig) -> None:
        """The spec's joint effects into the joint user numbers (columns plant.ECOL..) and the elastic joints' motor
        records (after the robots' records in userdata, in the order of the scene's robots and joints)."""
        fx = self.spec.joint_effects
        self.joint_effects = fx if fx is not None and fx.any() else None
        self._has_motors = False  # any elastic joint (its motor record: _motor_records())
        self._records: np.ndarray | None = None  # the stateful joints' records (k, MREC), a view of userdata
        self._elastic = np.zeros(7, dtype=bool)
        if self.joint_effects is None:
            return
        if not self._native:
            raise UserError("joint effects (cogging, static friction, elastic joints) need the compiled plant: "
                            f"{plant.unavailable_reason()}")
        m = self._m
        B = fx.motor_inertia(cfg.robot.rotor_inertia)
        if fx.elastic.any():
            fx.check_stable(np.diag(self.model.mass_matrix(cfg.robot.neutral())) + cfg.armature, B, self.dt)
        base = plant.RSLOT * len(self.world.scene.robots)
        for r in self.world.scene.robots:
            if r.prefix == self.prefix:
                break
            if r.joint_effects is not None:
                base += plant.MREC * int(r.joint_effects.stateful.sum())
        st, el = fx.stateful, fx.elastic
        offsets = base + plant.MREC * (np.cumsum(st) - 1)
        # the smallest inertia each joint shows (the others free), with the armature the plant puts on it
        M = self.model.mass_matrix(cfg.robot.neutral()) + np.diag(m.dof_armature[self._vs])
        link = 1.0 / np.diag(np.linalg.inv(M))
        rows = plant.effect_rows(fx, B, offsets, np.arange(self._motor.start, self._motor.start + 7), link, self.dt)
        m.jnt_user[self._jids, plant.ECOL:plant.ENUSER] = rows
        self._elastic = el
        if st.any():
            k = int(st.sum())
            self._records = self._d.userdata[base:base + plant.MREC * k].reshape(k, plant.MREC)
        if el.any():
            self._has_motors = True
            actuators = self._applied_torque

            def applied_torque() -> np.ndarray:  # the link side of an elastic joint feels the transmission
                tau = np.array(actuators())
                tau[el] += self._transmission_correction()
                return tau

            self._applied_torque = applied_torque  # type: ignore[method-assign]

    def motor_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The motors' position theta (7,) rad and velocity dtheta (7,) rad/s, link-side units (libfranka's
        ``theta``/``dtheta``): the elastic joints' motors, ``q``/``dq`` at the rigid ones."""
        theta, dtheta = self._qpos.copy(), self._qvel.copy()
        if self._has_motors:
            r = self._motor_records()
            now = r[:, 1] == self._d.time  # the callback already ran at this time: the state is "at t"
            theta[self._elastic] = np.where(now, r[:, 2], r[:, 4])
            dtheta[self._elastic] = np.where(now, r[:, 3], r[:, 5])
        return theta, dtheta

    def _transmission_correction(self) -> np.ndarray:
        """(k,) Nm: what the elastic joints' links felt over the last physics step besides the actuators' torque
        (the transmission's torque minus the motor's command)."""
        r = self._motor_records()
        return np.where(r[:, 1] == self._d.time, r[:, 7], r[:, 6])

    def _motor_records(self) -> np.ndarray:
        st = self.joint_effects.stateful  # type: ignore[union-attr]
        return self._records[self._elastic[st]]  # type: ignore[index]

    def _setup_delay(self, cfg: ModelConfig) -> None:
        """The configured delay: torque commands queued ("command") or torque measurements recorded after each step
        and reported late ("measurement")."""
        n_delay = int(round(cfg.delay / self.dt))
        self._delay_steps = n_delay if cfg.delay_channel == "command" else 0
        self._meas_fifo: deque[np.ndarray] | None = None
        if cfg.delay_channel == "measurement" and n_delay:
            self._meas_fifo = deque(maxlen=n_delay + 1)
            self.world.add_post_step(self._record_measurement)
        self._tau_fifo: deque[np.ndarray] = deque()

    # ------------------------------------------------------------------ stepping
    @property
    def friction_enabled(self) -> bool:
        """Whether the plant applies the configured joint friction (the model's friction is unaffected)."""
        return self._friction_enabled

    @friction_enabled.setter
    def friction_enabled(self, on: bool) -> None:
        self._friction_enabled = bool(on) and not self.spec.config.friction.is_zero()
        self._refresh_hook()

    @property
    def friction_scale(self) -> float:
        """Factor on the whole plant friction law (1 by default; domain randomisation), dimensionless."""
        return self._friction_scale

    def set_friction_scale(self, scale: float) -> None:
        """Scale the plant's friction law (every term) by ``scale`` >= 0; the model's friction is unaffected."""
        scale = float(scale)
        if not (scale >= 0 and math.isfinite(scale)):
            raise ValueError(f"friction scale must be a finite number >= 0, got {scale}")
        self._friction_scale = scale
        self._friction_step = self._make_friction_step()
        self._refresh_hook()

    def _refresh_hook(self) -> None:
        if not self._friction_enabled:
            self._qfrc_applied[:] = 0.0
        self._write_plant_friction()
        hook = self._make_pre_step()
        self.world.replace_pre_step(self._hook, hook)
        self._hook = hook

    def _write_plant_friction(self) -> None:
        """The friction parameters into the model's joint user numbers, read by the compiled plant."""
        on = self._native and self._friction_enabled
        rows = plant.friction_rows(self.spec.config.friction, self._friction_scale, on)
        self._m.jnt_user[self._jids, :plant.FRICTION_COLS] = rows

    def _make_friction_step(self):
        fr = self.spec.config.friction
        return make_plant_friction(self._qvel, self._qfrc_applied, fr.phi1, fr.phi2, fr.phi3, fr.viscous,
                                   fr.coulomb, fr.coulomb_vel, self._friction_scale, fr.stribeck, fr.stribeck_vel)

    def _make_pre_step(self):
        """The per-physics-step hook (runs at 1 kHz before every mj_step): none with the compiled plant and no
        command delay; without the compiled plant, the friction step itself (allocation-free,
        :func:`franka_vs_gym.model.friction.make_plant_friction`)."""
        if self._delay_steps:
            return self._pre_step
        return self._friction_step if self._friction_enabled and not self._native else _no_op

    def _pre_step(self) -> None:
        """General hook: friction (without the compiled plant), and the command delay FIFO."""
        if self._friction_enabled and not self._native:
            self._friction_step()
        if self._delay_steps and self._state == RobotState.STATE_FORCE_TORQUE_CONTROL:
            self._tau_fifo.append(self._tau_cmd.copy())
            self._ctrl_tau[:] = self._tau_fifo.popleft() if len(self._tau_fifo) > self._delay_steps else 0.0

    def _record_measurement(self) -> None:
        self._meas_fifo.append(np.array(self._applied_torque()))  # type: ignore[union-attr]

    def step(self) -> None:
        """Advance the simulation by one physics step (``dt``, 1 ms by default); all robots of the world move.
        Raises ControlException when a reflex fires (the robot is then held until ``automatic_error_recovery``)."""
        self.world.step()  # the world runs the reflex check after the step

    def wait(self, duration: float) -> None:
        """Advance the simulation by ``duration`` seconds (rounded to whole physics steps); ControlException as
        ``step``."""
        if not (duration >= 0 and math.isfinite(duration)):
            raise ValueError(f"duration must be a finite number >= 0 s, got {duration}")
        n = int(round(duration / self.dt))
        if self._reflexes.enabled:  # the reflexes watch every physics step, as the robot's do
            step = self.world.step
            for _ in range(n):
                step()
        else:
            self.world.step(n)
        self.check_reflexes()

    # ------------------------------------------------------------------ reflexes
    @property
    def reflexes(self) -> bool:
        """Whether the robot's limits are enforced (see :mod:`franka_vs_gym.sim.reflexes`)."""
        return self._reflexes.enabled

    @reflexes.setter
    def reflexes(self, on: bool) -> None:
        self._reflexes.enabled = bool(on)

    @property
    def command_rates(self) -> str:
        """How command rates are treated: "pass", "limit" or "check" (see the constructor)."""
        return self._reflexes.command_rates

    @command_rates.setter
    def command_rates(self, mode: str) -> None:
        self._reflexes.command_rates = mode
        self._reflexes.reset_commands()

    @property
    def current_errors(self) -> tuple[str, ...]:
        """libfranka names of the active errors (empty when the robot is fine)."""
        return self._reflexes.errors

    def check_reflexes(self) -> None:
        """Check the current state against the limits now (the simulator also does it before every physics
        step); raises ControlException on a violation."""
        if self._reflexes.enabled and not self._reflexes.errors:
            self._reflexes.check_now()

    def automatic_error_recovery(self) -> None:
        """Clear the reflex errors and release the brakes (libfranka's ``automaticErrorRecovery``). The robot is
        then stopped; a joint beyond a position limit may be moved back inside, not further out."""
        self._reflexes.recover()
        self.set_robot_state(RobotState.STATE_STOP)

    def get_time(self) -> float:
        """Simulated time, s."""
        return float(self._d.time)

    time = property(get_time)

    def reset(self, q: Any, dq: Any = None) -> None:
        """Place the robot at joint position q (7,) with velocity dq (default 0), stopped (simulation only)."""
        q = as_vector(q, 7, "q")
        if (q < self.q_min - 1e-9).any() or (q > self.q_max + 1e-9).any():
            raise ValueError(f"q is outside the joint limits: {q}")
        self._reflexes.reset()
        self._qpos[:] = q
        self._qvel[:] = 0.0 if dq is None else as_vector(dq, 7, "dq")
        if self._records is not None:
            self._records[:] = 0.0  # motors at the static deflection of the next step's command, anchors at q
        self._ctrl_tau[:] = 0.0
        self._ctrl_vel[:] = 0.0
        self._tau_cmd[:] = 0.0
        self._tau_fifo.clear()
        if self._meas_fifo is not None:
            self._meas_fifo.clear()
        self._reflexes.reset()
        self.set_robot_state(RobotState.STATE_STOP)
        self.world.diverged = None
        mujoco.mj_forward(self._m, self._d)

    # ------------------------------------------------------------------ control state
    def set_robot_state(self, state: RobotState | int) -> RobotState:
        """Switch control state. Returns the new state. STOP holds the robot with the velocity servo at 0."""
        state = RobotState(state)
        if state == RobotState.STATE_ACCELERATION_CONTROL:
            raise ValueError("acceleration control is not available on the FER")
        m = self._m
        # the joints' current servo torque: torque control takes over from it without a jump
        servo = self._d.actuator_force[self._vel].copy() if state == RobotState.STATE_FORCE_TORQUE_CONTROL else None
        kv = 0.0 if state == RobotState.STATE_FORCE_TORQUE_CONTROL else self.servo_gains
        m.actuator_gainprm[self._vel, 0] = kv
        m.actuator_biasprm[self._vel, 2] = -np.asarray(kv)
        self._ctrl_vel[:] = 0.0
        self._ctrl_tau[:] = 0.0
        self._tau_cmd[:] = 0.0
        self._tau_fifo.clear()
        self._state = state
        self._reflexes.reset_commands(servo)
        return state

    def get_robot_state(self) -> RobotState:
        return self._state

    # ------------------------------------------------------------------ commands
    def set_force_torque(self, frame: ControlFrame | int, tau: Any) -> None:
        """Joint torque command (7,), Nm, gravity-free (the robot adds g(q)); needs FORCE_TORQUE state.

        Torques beyond the FER limits are saturated. Only JOINT_STATE is supported (as on vpRobotFranka).
        """
        if frame is not ControlFrame.JOINT_STATE and ControlFrame(frame) != ControlFrame.JOINT_STATE:
            raise ValueError("set_force_torque supports JOINT_STATE only")
        if self._state != RobotState.STATE_FORCE_TORQUE_CONTROL:
            raise RuntimeError("set_force_torque needs the robot in STATE_FORCE_TORQUE_CONTROL "
                               "(call set_robot_state(FORCE_TORQUE) first)")
        t = as_vector(tau, 7, "tau")
        tau_max = self.tau_max
        np.minimum(t, tau_max, out=self._tau_cmd)
        np.maximum(self._tau_cmd, -tau_max, out=self._tau_cmd)
        self._reflexes.command_torque(self._tau_cmd)
        if not self._delay_steps:
            self._ctrl_tau[:] = self._tau_cmd

    def set_velocity(self, frame: ControlFrame | int, v: Any) -> None:
        """Velocity command; needs VELOCITY state.

        JOINT_STATE: dq (7,) rad/s. END_EFFECTOR_FRAME: twist of e expressed in e (6,). CAMERA_FRAME: twist of c
        expressed in c (6,). REFERENCE_FRAME: twist of e expressed in the base frame f (6,). Cartesian twists are
        mapped to joint velocities with the Jacobian pseudo-inverse. The joint velocity is scaled down uniformly if
        any joint would exceed its limit (direction preserved).
        """
        if self._state != RobotState.STATE_VELOCITY_CONTROL:
            raise RuntimeError("set_velocity needs the robot in STATE_VELOCITY_CONTROL "
                               "(call set_robot_state(VELOCITY) first)")
        if frame is not ControlFrame.JOINT_STATE:  # (the enum lookup is skipped on the common path)
            frame = ControlFrame(frame)
        if frame == ControlFrame.JOINT_STATE:
            dq = as_vector(v, 7, "joint velocity")
        else:
            twist = as_vector(v, 6, "twist")
            q = self._qpos
            if frame == ControlFrame.END_EFFECTOR_FRAME:
                J = self.model.eJe(q)
            elif frame == ControlFrame.CAMERA_FRAME:
                J = twist_transform(np.linalg.inv(self._eMc)) @ self.model.eJe(q)
            elif frame == ControlFrame.REFERENCE_FRAME:
                J = self.model.fJe(q)
            else:
                raise ValueError(f"unsupported velocity frame {frame!r}")
            dq = np.linalg.pinv(J, rcond=1e-4) @ twist
        self._apply_joint_velocity(dq)

    def _apply_joint_velocity(self, dq: np.ndarray) -> None:
        ratio = (np.abs(dq) / (self.dq_max * VELOCITY_COMMAND_SCALE)).max()
        if ratio > 1.0:
            dq = dq / ratio
        self._reflexes.command_velocity(dq)
        # feed-forward friction compensation, as the FER's internal joint controller does
        self._ctrl_tau[:] = self.model.friction(dq) if self.friction_enabled else 0.0

    def set_positioning_velocity(self, percent: float) -> None:
        """Speed of ``set_position`` motions, in percent of the joint velocity limits (as ViSP)."""
        if not (isinstance(percent, (int, float, np.floating, np.integer)) and 0 < percent <= 100):
            raise ValueError(f"positioning velocity must be in (0, 100] %, got {percent}")
        self._positioning_velocity = float(percent)

    def set_position(self, frame: ControlFrame | int, position: Any, timeout: float = 30.0) -> None:
        """Move to a joint position (JOINT_STATE, (7,) rad) or an end-effector pose (END_EFFECTOR_FRAME /
        REFERENCE_FRAME: 4x4 fMe, solved by inverse kinematics), with a smooth (quintic) joint trajectory at the
        positioning velocity. Blocks (in simulated time) until the motion is done; needs POSITION state."""
        if self._state != RobotState.STATE_POSITION_CONTROL:
            raise RuntimeError("set_position needs the robot in STATE_POSITION_CONTROL")
        if not (isinstance(timeout, (int, float, np.floating, np.integer)) and math.isfinite(timeout)
                and timeout > 0):
            raise ValueError(f"timeout must be a finite number of seconds > 0, got {timeout!r}")
        self._reflexes.raise_if_error()
        frame = ControlFrame(frame)
        if frame == ControlFrame.JOINT_STATE:
            qd = as_vector(position, 7, "joint position")
        elif frame in (ControlFrame.END_EFFECTOR_FRAME, ControlFrame.REFERENCE_FRAME):
            qd = self.model.inverse_kinematics(as_pose(position, "fMe"), self.get_position())
        else:
            raise ValueError(f"unsupported position frame {frame!r}")
        if (qd < self.q_min).any() or (qd > self.q_max).any():
            raise ValueError(f"target joint position outside the joint limits: {qd}")
        q0 = self.get_position()
        scale = self._positioning_velocity / 100
        r = self._reflexes
        # quintic whose peak velocity, acceleration and jerk stay within the scaled limits
        T = max(position_profile_time(qd - q0, r.dq_max * scale, r.ddq_max * scale, r.dddq_max * scale), 0.05)
        if T > timeout:
            raise ValueError(f"set_position: the motion would take {T:.3g} s at {self._positioning_velocity:g} % "
                             f"positioning velocity, more than timeout={timeout:g} s")
        n = int(math.ceil(T / self.dt))
        # joint velocity servo along the trajectory, plus a position correction
        m = self._m
        m.actuator_gainprm[self._vel, 0] = self.servo_gains
        m.actuator_biasprm[self._vel, 2] = -self.servo_gains
        for k in range(1, n + 1):
            s = k * self.dt / T
            dsdt = (30 * s**2 - 60 * s**3 + 30 * s**4) / T
            pos = q0 + (qd - q0) * (10 * s**3 - 15 * s**4 + 6 * s**5)
            v = (qd - q0) * dsdt + 20.0 * (pos - self._qpos)
            self._ctrl_vel[:] = np.clip(v, -self.dq_max, self.dq_max)
            self.world.step()
        err = qd - self._qpos
        for _ in range(max(int((timeout - T) / self.dt), 1)):
            err = qd - self._qpos
            if np.max(np.abs(err)) < 1e-4 and np.max(np.abs(self._qvel)) < 1e-3:
                break
            self._ctrl_vel[:] = np.clip(20.0 * err, -self.dq_max, self.dq_max)
            self.world.step()
        else:
            raise RuntimeError(f"set_position: target not reached within {timeout} s (error {err})")
        self._ctrl_vel[:] = 0.0
        self.check_reflexes()

    # ------------------------------------------------------------------ measurements
    @property
    def q(self) -> np.ndarray:
        """Joint position (7,), rad (a copy; the cheapest read for a control loop)."""
        return self._qpos.copy()

    @property
    def dq(self) -> np.ndarray:
        """Joint velocity (7,), rad/s (a copy)."""
        return self._qvel.copy()

    def get_position(self, frame: ControlFrame | int = ControlFrame.JOINT_STATE) -> np.ndarray:
        """JOINT_STATE: q (7,) rad. END_EFFECTOR_FRAME/REFERENCE_FRAME: pose vector of e in f (6,)
        (t, theta-u). CAMERA_FRAME: pose vector of c in f."""
        frame = ControlFrame(frame)
        if frame == ControlFrame.JOINT_STATE:
            return self._qpos.copy()
        if frame in (ControlFrame.END_EFFECTOR_FRAME, ControlFrame.REFERENCE_FRAME):
            return pose_vector(self.get_fMe())
        if frame == ControlFrame.CAMERA_FRAME:
            return pose_vector(self.get_fMc())
        raise ValueError(f"unsupported frame {frame!r}")

    def get_velocity(self, frame: ControlFrame | int = ControlFrame.JOINT_STATE) -> np.ndarray:
        """JOINT_STATE: dq (7,) rad/s. END_EFFECTOR_FRAME: twist of e in e; CAMERA_FRAME: twist of c in c;
        REFERENCE_FRAME: twist of e in f (6,)."""
        frame = ControlFrame(frame)
        dq = self._qvel.copy()
        if frame == ControlFrame.JOINT_STATE:
            return dq
        q = self._qpos
        if frame == ControlFrame.END_EFFECTOR_FRAME:
            return self.model.eJe(q) @ dq
        if frame == ControlFrame.CAMERA_FRAME:
            return twist_transform(np.linalg.inv(self._eMc)) @ self.model.eJe(q) @ dq
        if frame == ControlFrame.REFERENCE_FRAME:
            return self.model.fJe(q) @ dq
        raise ValueError(f"unsupported frame {frame!r}")

    def get_acceleration(self) -> np.ndarray:
        """Joint accelerations of the last step (7,), rad/s^2 (a simulator convenience)."""
        return self._qacc.copy()

    def get_force_torque(self, frame: ControlFrame | int = ControlFrame.JOINT_STATE) -> np.ndarray:
        """JOINT_STATE: measured link-side joint torques tau_J (7,), Nm, gravity included (libfranka's tau_J): the
        torque the joints applied over the last physics step in any control state, the velocity servos' implicitly
        integrated damping included (in free motion B ddq + C dq + g + tau_f(dq) at the step's start with the step's
        acceleration), plus the configured sensor offset, delay and noise.
        END_EFFECTOR_FRAME: wrench (6,) [f; tau] exerted by the environment on the tool, in e, from the wrist F/T
        sensor (needs ``ft_sensor=True``), with the tool's own weight removed."""
        frame = ControlFrame(frame)
        if frame == ControlFrame.JOINT_STATE:
            # the sensors report the torque of delay_channel="measurement" steps ago
            now = self._meas_fifo[0] if self._meas_fifo else self._applied_torque()
            tau = now + self._offset  # a new array (never a view of the simulator's)
            if self._torque_noise:
                tau += self._rng.normal(0.0, self._torque_noise, 7)
            return tau
        if frame == ControlFrame.END_EFFECTOR_FRAME:
            return self.get_ft_wrench()
        raise ValueError(f"unsupported frame {frame!r}")

    def get_ft_wrench(self) -> np.ndarray:
        """External wrench on the tool from the wrist F/T sensor, (6,) [f; tau] in e (N, Nm), torque about e.

        The sensor at the flange measures the force link 7 exerts on the tool body. The tool's own weight and
        inertial load (from its acceleration) are removed, leaving what the environment applies, as a calibrated
        F/T sensor with load compensation reports."""
        if self._ft is None:
            raise RuntimeError("this robot has no wrist force/torque sensor (construct with ft_sensor=True)")
        m, d, b = self._m, self._d, self._hand_body
        fa, ta = self._ft
        R = d.xmat[b].reshape(3, 3)  # sensor site frame = hand (flange) body frame
        f_link = R @ d.sensordata[fa:fa + 3]
        t_link = R @ d.sensordata[ta:ta + 3]
        # tool acceleration at its com, gravity included (accelerometer convention: a - g), and angular motion
        acc = np.zeros(6)
        mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_BODY, b, acc, 0)
        vel = np.zeros(6)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, b, vel, 0)
        mass = m.body_mass[b]
        Ri = d.ximat[b].reshape(3, 3)
        I = Ri @ np.diag(m.body_inertia[b]) @ Ri.T
        w, alpha = vel[:3], acc[:3]
        r_com = d.xipos[b] - d.xpos[b]
        f_need = mass * acc[3:]  # total force the tool needs, minus gravity
        t_need = np.cross(r_com, f_need) + I @ alpha + np.cross(w, I @ w)  # about the sensor origin
        f_ext = f_need - f_link
        t_ext = t_need - t_link
        p_e = d.site_xpos[self._ee_site]
        t_ext_e = t_ext - np.cross(p_e - d.xpos[b], f_ext)
        Re = d.site_xmat[self._ee_site].reshape(3, 3)
        return np.concatenate([Re.T @ f_ext, Re.T @ t_ext_e])

    # ------------------------------------------------------------------ model getters (vpRobotFranka names)
    def get_mass(self) -> np.ndarray:
        """B(q) (7, 7) at the current position, from the robot's model."""
        return self.model.mass_matrix(self._qpos)

    def get_coriolis(self) -> np.ndarray:
        """C(q, dq) dq (7,), Nm, at the current state (as vpRobotFranka::getCoriolis)."""
        return self.model.coriolis(self._qpos, self._qvel)

    def get_gravity(self) -> np.ndarray:
        """g(q) (7,), Nm."""
        return self.model.gravity(self._qpos)

    def get_friction(self) -> np.ndarray:
        """Model friction torques at the current velocity (7,), Nm."""
        return self.model.friction(self._qvel)

    def get_fJe(self, q: Any = None) -> np.ndarray:
        return self.model.fJe(self._qpos if q is None else as_vector(q, 7, "q"))

    def get_eJe(self, q: Any = None) -> np.ndarray:
        return self.model.eJe(self._qpos if q is None else as_vector(q, 7, "q"))

    def get_fMe(self, q: Any = None) -> np.ndarray:
        """Pose of the end effector in the base frame (4, 4)."""
        return self.model.fMe(self._qpos if q is None else as_vector(q, 7, "q"))

    def get_fMc(self, q: Any = None) -> np.ndarray:
        """Pose of the camera (ViSP convention) in the base frame (4, 4)."""
        return self.get_fMe(q) @ self._eMc

    def get_eMc(self) -> np.ndarray:
        return self._eMc.copy()

    def set_eMc(self, eMc: Any) -> None:
        """Camera mount: pose of the camera frame c (ViSP: z forward, y down) in the end-effector frame."""
        eMc = as_pose(eMc, "eMc")
        self._eMc = eMc.copy()
        if self._cam >= 0:
            flMc = self.spec.config.tool.flMe @ eMc
            self._m.cam_pos[self._cam] = flMc[:3, 3]
            self._m.cam_quat[self._cam] = mat2quat(flMc[:3, :3] @ CAMERA_VISP_TO_MUJOCO)

    def get_wMf(self) -> np.ndarray:
        """Pose of the robot base in the world (4, 4)."""
        d, b = self._d, self._base_body
        return homogeneous(d.xmat[b].reshape(3, 3), d.xpos[b])

    def set_tool(self, flMe: Any, mass: float = 0.0, flMcom: Any = (0, 0, 0), inertia: Any = None, *,
                 plant: bool = False) -> None:
        """Declare the tool to the robot's model (as the real robot's end-effector settings): updates the model
        used by the getters and Cartesian commands.

        flMe (4, 4): end-effector pose in the flange frame; mass (kg), flMcom (3,) m in the flange frame and inertia
        (3, 3) or (3,) kg m^2 about the centre of mass. With ``plant=True`` the simulated tool changes too (its
        inertia, the end-effector site and the wrist camera mount follow; the tool's meshes stay as built).
        """
        flMe = as_pose(flMe, "flMe")
        self.model.set_tool(flMe, mass, flMcom, inertia)
        if plant:
            tool = self.model.config.tool
            self._plant_nominal()["tool"] = tool
            self._apply_hand_body()
            self._m.site_pos[self._ee_site] = flMe[:3, 3]
            self._m.site_quat[self._ee_site] = mat2quat(flMe[:3, :3])
            if self._cam >= 0:
                self.set_eMc(self._eMc)
            mujoco.mj_setConst(self._m, self._d)
            mujoco.mj_forward(self._m, self._d)

    # ------------------------------------------------------------------ plant dynamics (randomisation, injection)
    def set_dynamics(self, *, link_mass_scale: Any = None, friction_scale: float | None = None,
                     payload: RigidBody | None | bool = False, undeclared_payload: RigidBody | None = None,
                     delay: float | None = None) -> None:
        """Change the simulated plant's dynamics in place (domain randomisation, effect injection); the robot's
        model (``self.model``, used by controllers) is not told, as a real robot's would not be.

        Parameters (each left out keeps its current value)
        ----------
        link_mass_scale : (7,) factors on the mass and inertia of links 1..7 relative to the built plant (1 = as
            built). The robot's internal gravity compensation follows the true masses.
        friction_scale : factor >= 0 on the plant's whole friction law (:meth:`set_friction_scale`).
        payload : a load held by the tool and declared to the robot's internal gravity compensation (as after
            libfranka's ``setLoad``): a RigidBody in the flange frame, merged into the hand body; None removes it.
        undeclared_payload : new mass, centre of mass and inertia of the undeclared payload body (only for a robot
            built with ``undeclared_payload``); a mass of 0 is stored as 1e-9 kg.
        delay : command delay, s (torque commands reach the joints this late; rounded to physics steps).
        """
        nom = self._plant_nominal()
        m = self._m
        changed = False
        if link_mass_scale is not None:
            k = as_vector(link_mass_scale, 7, "link_mass_scale")
            if (k <= 0).any():
                raise ValueError(f"link_mass_scale must be > 0, got {k}")
            m.body_mass[nom["links"]] = nom["mass"] * k
            m.body_inertia[nom["links"]] = nom["inertia"] * k[:, None]
            changed = True
        if friction_scale is not None:
            self.set_friction_scale(friction_scale)
        if payload is not False:
            nom["payload"] = payload
            self._apply_hand_body()
            changed = True
        if undeclared_payload is not None:
            b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{self.prefix}undeclared_payload")
            if b < 0:
                raise ValueError("this robot has no undeclared payload body (construct with undeclared_payload=...)")
            self._set_body_inertial(b, RigidBody(max(undeclared_payload.mass, 1e-9), undeclared_payload.com,
                                                 undeclared_payload.inertia))
            changed = True
        if delay is not None:
            delay = float(delay)
            if not (delay >= 0 and math.isfinite(delay)):
                raise ValueError(f"delay must be a finite number >= 0 s, got {delay}")
            self._delay_steps = int(round(delay / self.dt))
            self._tau_fifo.clear()
            self._refresh_hook()
        if changed:
            mujoco.mj_setConst(m, self._d)

    def _plant_nominal(self) -> dict[str, Any]:
        """The plant's dynamics as built (captured on first use)."""
        nom = getattr(self, "_nominal", None)
        if nom is None:
            m, p = self._m, self.prefix
            links = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{p}link{i + 1}") for i in range(7)]
            h = self._hand_body
            nom = self._nominal = {"links": links, "mass": m.body_mass[links].copy(),
                                   "inertia": m.body_inertia[links].copy(), "tool": self.spec.config.tool,
                                   "payload": None, "hand": (float(m.body_mass[h]), m.body_ipos[h].copy(),
                                                             m.body_inertia[h].copy(), m.body_iquat[h].copy())}
        return nom

    def _apply_hand_body(self) -> None:
        """The hand body's inertial = tool + configured payload + declared extra payload (flange frame)."""
        nom = self._plant_nominal()
        cfg = self.spec.config
        extra = [nom["payload"]] if nom["payload"] is not None and nom["payload"].mass > 0 else []
        if not extra and nom["tool"] is cfg.tool:  # as built: restore MuJoCo's own compiled values exactly
            m, h = self._m, self._hand_body
            m.body_mass[h], m.body_ipos[h], m.body_inertia[h], m.body_iquat[h] = nom["hand"]
            return
        body = cfg.copy(tool=nom["tool"]).flange_body()
        if extra:
            body = RigidBody(*combine_inertials([(body.mass, body.com, body.inertia)]
                                                + [(b.mass, b.com, b.inertia) for b in extra]))
        self._set_body_inertial(self._hand_body, body if body.mass > 0 else RigidBody(1e-9, np.zeros(3),
                                                                                      np.eye(3) * 1e-12))

    def _set_body_inertial(self, b: int, body: RigidBody) -> None:
        w, V = np.linalg.eigh(body.inertia)
        if np.linalg.det(V) < 0:
            V[:, 0] = -V[:, 0]
        m = self._m
        m.body_mass[b], m.body_ipos[b] = body.mass, body.com
        m.body_inertia[b], m.body_iquat[b] = w, mat2quat(V)

    # ------------------------------------------------------------------ views for in-process servers
    @property
    def dof_slice(self) -> slice:
        """Indices of this robot's 7 joints in the world's qvel/qacc/qfrc arrays (``world.data``)."""
        return self._vs

    def joint_views(self) -> tuple[np.ndarray, np.ndarray]:
        """Live views (q (7,) rad, dq (7,) rad/s) into the simulator state, for 1 kHz loops that must not copy.
        Read them; writing moves the robot without physics."""
        return self._qpos, self._qvel

    def velocity_servo_views(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Live views (gain Kv (7,) Nm s/rad, bias (7,) = -Kv, set-point (7,) rad/s) of the plant's joint velocity
        servos, integrated implicitly by MuJoCo: a controller may write them to add joint damping
        ``Kv (dq_set - dq)`` (e.g. an in-process FCI server's internal impedance controller)."""
        m = self._m
        return m.actuator_gainprm[self._vel, 0], m.actuator_biasprm[self._vel, 2], self._ctrl_vel

    def batch_layout(self) -> BatchLayout:
        """Where this robot lives in its MuJoCo data, for code that steps many robots' data at once (the batched
        vector env writes commands into, and reads joint states from, ``mujoco.batch`` views of the same fields)."""
        r = self._reflexes
        off = int(self._m.jnt_user[self._jids[0], plant.RCOL + 1]) if r._native else -1
        return BatchLayout(self._qs, self._vs, self._motor, self._vel, off, r.q_min.copy(), r.q_max.copy(),
                           r.dq_max.copy(), int(self._jids[0]))

    def torque_command_views(self) -> tuple[np.ndarray, np.ndarray]:
        """The arrays ``set_force_torque`` leaves a torque command in with ``command_rates="pass"`` (the commanded
        torque and the reflexes' last applied torque, (7,) each, Nm): compiled code that writes a torque command
        into the controls itself (see :meth:`runs_inside_mj_step`) writes them as well, instead of calling
        :meth:`commands_from_controls`."""
        return self._tau_cmd, self._reflexes._tau_applied

    def velocity_command_views(self) -> tuple[np.ndarray, np.ndarray]:
        """The arrays ``set_velocity`` leaves a joint velocity command in (the velocity target and, with
        ``command_rates="pass"``, the reflexes' velocity reference, (7,) each, rad/s): compiled code that writes a
        joint velocity command itself (see :meth:`runs_inside_mj_step`) writes them as well."""
        return self._reflexes._v_target, self._reflexes._v_ref

    def feedforward_friction(self) -> tuple[np.ndarray, ...] | None:
        """What ``set_velocity`` adds to the motors' controls as the joint controller's feed-forward friction, for
        compiled code that writes a joint velocity command itself: ``()`` when the friction is off (zero torque), the
        coefficients (phi1, phi2, phi2 phi3, offset) (7,) each when the model's friction law is the sigmoid alone
        (tau = phi1 / (1 + exp(-(phi2 dq + phi2 phi3))) - offset), None for another law (only the model computes
        it). The same objects while the law is the same (compare by identity)."""
        if not self._friction_enabled:
            return ()
        return getattr(self.model._friction, "sigmoid_coefficients", None)

    def kinematics_key(self) -> tuple[Any, Any]:
        """Two objects that are replaced whenever the robot's kinematic model (a new tool or payload rebuilds it)
        or its camera mount changes: geometry computed from ``get_fMe``/``get_eMc`` is current while both are the
        same objects (compare by identity)."""
        return self.model.model, self._eMc

    def runs_inside_mj_step(self, control_state: RobotState | int) -> bool:
        """Whether a control period of this robot, in ``control_state``, is plain MuJoCo steps: nothing per physics
        step in Python (compiled plant, no command delay or rate limiting, no brakes holding it, no relaxed limits),
        reflexes armed in the plant (recording any violation in the data's userdata), commands passed as given
        (``command_rates="pass"``), no torque-measurement noise or offset to check and no error pending. Code that
        steps such a robot's data elsewhere (``mujoco.batch``) writes its controls as ``set_force_torque`` /
        ``set_velocity`` would and then calls :meth:`commands_from_controls`."""
        r, w = self._reflexes, self.world
        return (self._native and r._native and r._enabled and (r._mode == "pass" or r._lim_native)
                and r._hold is None
                and not r._relaxed and not r._check_tau and not r.errors and r._ud[0] == ARMED
                and not self._delay_steps and self._meas_fifo is None and not w._active and not w._post_hooks
                and len(w._checks) == 1
                and (control_state is self._state or self._state == RobotState(control_state)))  # (enum call skipped)

    @property
    def limits_commands_in_plant(self) -> bool:
        """Whether ``command_rates="limit"`` runs in the compiled plant for this robot (the plant is built, no
        command delay): rate-limited commands are then written as the limiter's target in the robot's userdata
        record (numbers ``plant.L0 + 4`` on, see :meth:`batch_layout`) and the plant writes the controls."""
        r = self._reflexes
        return r._mode == "limit" and r._native and not self._delay_steps

    @property
    def rate_limiter_active(self) -> bool:
        """Whether the plant's rate limiter runs now (``limits_commands_in_plant`` and a torque or velocity
        control state)."""
        return self._reflexes._lim_native

    def commands_from_controls(self) -> None:
        """After the controls in the data were written from outside (see :meth:`runs_inside_mj_step`), make the
        robot's command state what ``set_force_torque`` (torque control) or ``set_velocity`` (velocity control)
        leaves behind with ``command_rates="pass"`` for those controls."""
        r = self._reflexes
        target = r.limiter_target()
        if target is not None:  # rate-limited: the command is the limiter's target (the controls its output)
            if self._state == RobotState.STATE_FORCE_TORQUE_CONTROL:
                self._tau_cmd[:] = target
            else:
                r._v_target[:] = target
            return
        if self._state == RobotState.STATE_FORCE_TORQUE_CONTROL:
            self._tau_cmd[:] = self._ctrl_tau
            r._tau_applied[:] = self._ctrl_tau
        elif self._state == RobotState.STATE_VELOCITY_CONTROL:
            r._v_target[:] = self._ctrl_vel
            r._v_ref[:] = self._ctrl_vel

    def stop_joints(self) -> None:
        """Zero the joint velocities at once (the brakes engaging after a reflex)."""
        self._qvel[:] = 0.0

    def camera_name(self) -> str:
        if self._cam < 0:
            raise RuntimeError("this robot has no wrist camera (construct with camera=True)")
        return f"{self.prefix}wrist_camera"

    # ViSP camelCase aliases, so code written for vpRobotFranka reads the same.
    setRobotState = set_robot_state
    getRobotState = get_robot_state
    setVelocity = set_velocity
    setForceTorque = set_force_torque
    setPosition = set_position
    setPositioningVelocity = set_positioning_velocity
    getPosition = get_position
    getVelocity = get_velocity
    getForceTorque = get_force_torque
    getMass = get_mass
    getCoriolis = get_coriolis
    getGravity = get_gravity
    getFriction = get_friction
    getTime = get_time


__all__ = ["BatchLayout", "CAMERA_FRAME", "ControlFrame", "DEFAULT_eMc", "END_EFFECTOR_FRAME", "FORCE_TORQUE",
           "FrankaSim", "JOINT_STATE", "POSITION", "REFERENCE_FRAME", "RobotState", "STOP", "SimulationDiverged",
           "VELOCITY", "Tool", "ModelConfig", "twist_transform", "pose_vector", "ControlException"]
