"""Pinocchio-backed Lagrangian model of a Franka arm (FER, FR3): B(q), C(q, dq), g(q), friction, kinematics and
Jacobians.

The dynamic model is ``tau_J = B(q) ddq + C(q, dq) dq + g(q) + tau_f(dq) + tau_offset``, with tau_J the link-side
joint torque measured by the robot's torque sensors (gravity included), as in Gaz et al. 2019.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin

from franka_vs_gym.errors import UserError
from franka_vs_gym.model.checks import as_vector
from franka_vs_gym.model.config import ROBOT_DEFAULT, ModelConfig, RigidBody, Tool, resolve_config
from franka_vs_gym.model.description import FER, RobotDescription

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
_LOCAL = pin.ReferenceFrame.LOCAL


def build_pinocchio_model(config: ModelConfig) -> tuple[pin.Model, int, int]:
    """Build the pinocchio model from a configuration (its robot description, tool, payload, gravity, armature).

    Returns (model, flange frame id, end-effector frame id).
    """
    robot, lim = config.robot, config.robot.limits
    model = pin.Model()
    model.name = robot.name
    parent = 0
    for i, (mass, com, inertia) in enumerate(config.link_inertials()):
        M = robot.dh_placement(i)
        placement = pin.SE3(M[:3, :3], M[:3, 3])
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{i + 1}",
                             np.array([lim.tau_max[i]]), np.array([lim.dq_max[i]]),
                             np.array([lim.q_min[i]]), np.array([lim.q_max[i]]))
        model.appendBodyToJoint(jid, pin.Inertia(mass, com, inertia), pin.SE3.Identity())
        model.addFrame(pin.Frame(f"link{i + 1}", jid, pin.SE3.Identity(), pin.FrameType.BODY))
        parent = jid
    Mfl = robot.flange_placement()
    flange = pin.SE3(Mfl[:3, :3], Mfl[:3, 3])
    body = config.flange_body()
    if body.mass > 0:
        model.appendBodyToJoint(parent, pin.Inertia(body.mass, body.com, body.inertia), flange)
    fl_id = model.addFrame(pin.Frame("flange", parent, flange, pin.FrameType.OP_FRAME))
    flMe = config.tool.flMe
    e_id = model.addFrame(pin.Frame("ee", parent, flange * pin.SE3(flMe[:3, :3], flMe[:3, 3]),
                                    pin.FrameType.OP_FRAME))
    model.gravity.linear = config.gravity
    model.armature = config.armature.copy()
    return model, fl_id, e_id


class _LimitsAccessor:
    """``FrankaModel.limits()`` gives the FER's limits; ``model.limits()`` those of the instance's robot."""

    def __get__(self, obj: FrankaModel | None, owner: type) -> Any:
        robot = FER if obj is None else obj.robot

        def limits() -> dict[str, np.ndarray]:
            """Joint limits (fresh arrays (7,)): q_min, q_max (rad), dq_max (rad/s), ddq_max (rad/s^2), dddq_max
            (rad/s^3), tau_max (Nm), dtau_max (Nm/s)."""
            return robot.limits.as_arrays()
        return limits


def _joint_vector(x: Any, name: str) -> np.ndarray:
    """``x`` as 7 joint values (float64), or a UserError naming ``name`` and what it got."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise UserError(f"{name} must be 7 numbers, got {type(x).__name__}") from None
    if a.shape != (7,):
        raise UserError(f"{name} must be 7 joint values, got shape {a.shape}")
    return a


class FrankaModel:
    """Dynamic and kinematic model of a Franka arm (+ tool), backed by pinocchio.

    Default: FER + Franka Hand, vertical mounting, Gaz et al. 2019 parameters and sigmoid friction.
    ``FrankaModel(robot="fr3")`` is the Franka Research 3 (with the Franka Hand; ``tool=None`` for the bare arm).

    All joint vectors are float64 arrays of shape (7,) in SI units (rad, rad/s, rad/s^2, Nm). Frames follow ViSP:
    f is the robot base, fl the flange, e the end effector (tool frame ``flMe``).

    Parameters
    ----------
    model : ModelConfig, path to a calibrated model file, or None
        The configuration; ``None`` gives the default configuration of ``robot``.
    robot : RobotDescription, a registered name ("fer", "fr3"), or None
        The arm. With ``model`` given, it must describe the same robot (a clear error otherwise).
    tool : Tool, "franka_hand", None (the bare flange), or left out (the configuration's tool)

    Notes
    -----
    Each instance owns its pinocchio ``Data`` workspace: use one instance per thread.
    """

    limits = _LimitsAccessor()

    def __init__(self, model: ModelConfig | str | None = None, *, robot: RobotDescription | str | None = None,
                 tool: Tool | str | None = ROBOT_DEFAULT) -> None:
        cfg = resolve_config(model, robot)
        if tool is not ROBOT_DEFAULT:
            cfg = cfg.copy(tool=tool if isinstance(tool, Tool) else Tool.named(tool))
        self._config = cfg
        self._rebuild()

    # ------------------------------------------------------------------ configuration
    @property
    def config(self) -> ModelConfig:
        """The configuration this model was built from (a copy is made on every change)."""
        return self._config

    @property
    def robot(self) -> RobotDescription:
        """The robot description (kinematics, inertials, limits) of this model."""
        return self._config.robot

    def _rebuild(self) -> None:
        self.model, self._fl_id, self._e_id = build_pinocchio_model(self._config)
        self.data = self.model.createData()
        self._friction = self._config.friction.compile()
        self._offset = self._config.torque_offset.copy()
        self._has_offset = bool(self._offset.any())
        self._il = np.tril_indices(7, -1)

    def set_config(self, config: ModelConfig) -> None:
        self._config = config
        self._rebuild()

    def set_payload(self, mass: float, com: Any = (0, 0, 0), inertia: Any = None) -> None:
        """Payload held by the tool: mass (kg), com (3,) in the flange frame (m), inertia (3,3) or (3,) about
        the com (kg m^2). ``mass = 0`` removes it."""
        payload = None if mass == 0 else RigidBody(mass, com, np.zeros((3, 3)) if inertia is None else inertia)
        self.set_config(self._config.copy(payload=payload))

    def set_tool(self, flMe: Any, mass: float, flMcom: Any = (0, 0, 0), inertia: Any = None,
                 name: str = "custom") -> None:
        """Replace the tool: end-effector pose ``flMe`` (4x4) in the flange frame, mass (kg), centre of mass
        ``flMcom`` (3,) in the flange frame and inertia (3,3) about it."""
        inertia = np.zeros((3, 3)) if inertia is None else inertia
        self.set_config(self._config.copy(tool=Tool(name, flMe, RigidBody(mass, flMcom, inertia))))

    def set_gravity(self, g0: Any) -> None:
        """Gravity vector in the base frame (3,), m/s^2; e.g. for a wall or ceiling mounting."""
        g = as_vector(g0, 3, "gravity")
        self._config = self._config.copy(gravity=g)
        self.model.gravity.linear = g

    # ------------------------------------------------------------------ dynamics
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Joint-space inertia matrix B(q), (7, 7), symmetric positive definite, kg m^2."""
        try:
            M = pin.crba(self.model, self.data, q)
        except TypeError:  # a list, ints, a wrong length: converted, or a named error
            M = pin.crba(self.model, self.data, _joint_vector(q, "q"))
        M[self._il] = M.T[self._il]
        return M.copy()

    def coriolis_matrix(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Full Coriolis/centrifugal matrix C(q, dq), (7, 7), with dB/dt - 2C skew-symmetric, Nm s/rad."""
        try:
            return pin.computeCoriolisMatrix(self.model, self.data, q, dq).copy()
        except TypeError:
            return self.coriolis_matrix(_joint_vector(q, "q"), _joint_vector(dq, "dq"))

    def coriolis(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Coriolis/centrifugal torques C(q, dq) dq, (7,), Nm."""
        try:
            return pin.rnea(self.model, self.data, q, dq, np.zeros(7)) - self.gravity(q)
        except TypeError:
            return self.coriolis(_joint_vector(q, "q"), _joint_vector(dq, "dq"))

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Gravity torques g(q), (7,), Nm."""
        try:
            return pin.computeGeneralizedGravity(self.model, self.data, q).copy()
        except TypeError:
            return pin.computeGeneralizedGravity(self.model, self.data, _joint_vector(q, "q")).copy()

    def bias(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """C(q, dq) dq + g(q), (7,), Nm (the non-linear effects, without friction)."""
        try:
            return pin.nonLinearEffects(self.model, self.data, q, dq).copy()
        except TypeError:
            return self.bias(_joint_vector(q, "q"), _joint_vector(dq, "dq"))

    def friction(self, dq: np.ndarray) -> np.ndarray:
        """Joint friction torques tau_f(dq), (7,), Nm: the torque the joint needs on top of B ddq + C dq + g."""
        return self._friction(np.asarray(dq, dtype=np.float64))

    def rigid_body_inverse_dynamics(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """B ddq + C dq + g, (7,), Nm: the rigid-body part (armature included, friction and offset excluded)."""
        try:
            return pin.rnea(self.model, self.data, q, dq, ddq).copy()  # pinocchio's rnea includes the armature
        except TypeError:
            return self.rigid_body_inverse_dynamics(_joint_vector(q, "q"), _joint_vector(dq, "dq"),
                                                    _joint_vector(ddq, "ddq"))

    def inverse_dynamics(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Predicted measured joint torque tau_J = B ddq + C dq + g + tau_f(dq) + offset, (7,), Nm."""
        if type(dq) is not np.ndarray:
            dq = _joint_vector(dq, "dq")
        tau = self.rigid_body_inverse_dynamics(q, dq, ddq) + self._friction(dq)
        return tau + self._offset if self._has_offset else tau

    def forward_dynamics(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Joint accelerations ddq (7,) for the joint torque tau_J (7,) (gravity included), rad/s^2."""
        tau_net = np.asarray(tau, dtype=np.float64) - self._friction(dq) - self._offset
        B = self.mass_matrix(q)
        return np.linalg.solve(B, tau_net - self.bias(q, dq))

    # ------------------------------------------------------------------ kinematics
    def fMe(self, q: np.ndarray) -> np.ndarray:
        """Pose of the end effector in the base frame, (4, 4)."""
        pin.forwardKinematics(self.model, self.data, q)
        return pin.updateFramePlacement(self.model, self.data, self._e_id).homogeneous

    def fMfl(self, q: np.ndarray) -> np.ndarray:
        """Pose of the flange in the base frame, (4, 4)."""
        pin.forwardKinematics(self.model, self.data, q)
        return pin.updateFramePlacement(self.model, self.data, self._fl_id).homogeneous

    def fJe(self, q: np.ndarray) -> np.ndarray:
        """Geometric Jacobian of the end effector, (6, 7): [v; w] of e's origin in base-frame axes."""
        return pin.computeFrameJacobian(self.model, self.data, q, self._e_id, _LWA)

    def eJe(self, q: np.ndarray) -> np.ndarray:
        """Geometric Jacobian of the end effector, (6, 7): [v; w] expressed in the end-effector frame."""
        return pin.computeFrameJacobian(self.model, self.data, q, self._e_id, _LOCAL)

    def fJe_dot(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Time derivative of fJe, (6, 7), for Cartesian computed torque (dJ dq is the Cartesian bias)."""
        pin.computeJointJacobiansTimeVariation(self.model, self.data, q, dq)
        pin.updateFramePlacements(self.model, self.data)
        return pin.getFrameJacobianTimeVariation(self.model, self.data, self._e_id, _LWA)

    def inverse_kinematics(self, fMe_target: np.ndarray, q0: np.ndarray | None = None, *, tol: float = 1e-9,
                           max_iter: int = 200, damping: float = 1e-6, restarts: int = 10,
                           seed: int = 0) -> np.ndarray:
        """Joint position (7,) reaching ``fMe_target`` (4x4), within the joint limits.

        Damped least squares on the SE(3) logarithm of the pose error (expressed in e), started at ``q0`` and then,
        if that fails, at seeded random in-limit configurations. Raises ValueError when no solution within the
        joint limits is found (the error then says how close it came).
        """
        T = np.asarray(fMe_target, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError("fMe_target must be a finite 4x4 homogeneous matrix")
        target = pin.SE3(T[:3, :3], T[:3, 3])
        lim = self.robot.limits
        lo, hi = np.array(lim.q_min), np.array(lim.q_max)
        rng = np.random.default_rng(seed)
        starts = [self.robot.neutral() if q0 is None else as_vector(q0, 7, "q0")]
        starts += [rng.uniform(lo, hi) for _ in range(restarts)]
        best_err = np.inf
        for q in starts:
            q = np.clip(q, lo, hi)
            for _ in range(max_iter):
                pin.forwardKinematics(self.model, self.data, q)
                cur = pin.updateFramePlacement(self.model, self.data, self._e_id)
                err = pin.log6(cur.actInv(target)).vector
                n = np.linalg.norm(err)
                if n < tol:
                    break
                J = pin.computeFrameJacobian(self.model, self.data, q, self._e_id, _LOCAL)
                J = pin.Jlog6(cur.actInv(target)) @ J
                dq = J.T @ np.linalg.solve(J @ J.T + damping * np.eye(6), err)
                q = np.clip(q + dq, lo, hi)
            best_err = min(best_err, float(n))
            if n < max(tol, 1e-8):
                return q
        raise ValueError(f"inverse_kinematics: no in-limit solution found (best pose error {best_err:.3g})")

    # ------------------------------------------------------------------ energy (for tests and validation)
    def kinetic_energy(self, q: np.ndarray, dq: np.ndarray) -> float:
        return float(0.5 * dq @ self.mass_matrix(q) @ dq)

    def potential_energy(self, q: np.ndarray) -> float:
        return float(pin.computePotentialEnergy(self.model, self.data, q))
