"""The robot as a value: :class:`RobotDescription` holds everything that makes one robot arm.

A description is immutable. ``FrankaModel``, the MJCF generator, ``FrankaSim``, the environments, the controllers,
the workbench and the FCI server take one (default: :data:`FER`, the Franka Emika Robot with the Gaz et al. 2019
identified dynamics), so a second robot, or a user's variant of the FER, is a new value and not an edit across the
code base::

    from dataclasses import replace
    from franka_vs_gym.model.description import FER, robot_description
    heavy_link7 = replace(FER, name="fer-heavy-wrist", links=FER.links[:6] + (my_link7,))
    fr3 = robot_description("fr3")

Numbers are typed in :mod:`franka_vs_gym.model.params` (one place, with their sources); this module only assembles
them. Conventions: SI units, joint index 0..6, link ``i`` (1..7 in prose) is ``links[i - 1]``, modified (Craig)
Denavit-Hartenberg kinematics.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from franka_vs_gym.model import params
from franka_vs_gym.model.params import LinkInertial

Vec7 = tuple[float, float, float, float, float, float, float]


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits (7,): position (rad), velocity (rad/s), acceleration (rad/s^2), jerk (rad/s^3), torque (Nm)
    and torque rate (Nm/s), as the robot's reflexes enforce them."""

    q_min: Vec7
    q_max: Vec7
    dq_max: Vec7
    ddq_max: Vec7
    dddq_max: Vec7
    tau_max: Vec7
    dtau_max: Vec7

    def as_arrays(self) -> dict[str, np.ndarray]:
        """Fresh float64 arrays keyed by field name (the dict ``FrankaModel.limits()`` returns)."""
        return {k: np.array(getattr(self, k), dtype=np.float64) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class CartesianLimits:
    """Limits of the end effector's motion (translation m/s, m/s^2, m/s^3; rotation rad/s, rad/s^2, rad/s^3) and of
    the elbow (rad/s, rad/s^2, rad/s^3), as the robot's Cartesian motion generators enforce them."""

    v_max: float
    a_max: float
    j_max: float
    w_max: float
    alpha_max: float
    rot_j_max: float
    elbow_v_max: float
    elbow_a_max: float
    elbow_j_max: float


@dataclass(frozen=True)
class SigmoidFriction:
    """Per-joint parameters of the identified sigmoid friction law (Gaz et al. 2019, eq. (6)):
    ``tau_f = phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))`` (phi1 Nm, phi2 s/rad, phi3
    rad/s)."""

    phi1: Vec7
    phi2: Vec7
    phi3: Vec7


@dataclass(frozen=True)
class RobotDescription:
    """Everything that makes one 7-joint Franka arm: kinematics, inertials, limits, friction, names, sources.

    Attributes
    ----------
    name : short identifier ("fer", "fr3"); a calibrated-model file names it.
    title : human-readable name.
    dh_a, dh_d, dh_alpha : modified DH rows for joints 1..7 (m, m, rad); ``flange_d`` the flange offset along z7.
    links : inertials of links 1..7 (mass kg, com m in the link frame, inertia about the com kg m^2).
    limits, cartesian_limits : what the reflexes and motion generators enforce.
    friction : identified sigmoid friction, or None when none is published (calibrate it with the workbench).
    q_neutral : a safe start pose (rad).
    joint_names : names as libfranka's URDF and ROS use them (``fer_joint1``...); ``aliases`` other prefixes that
        recordings use for the same joints (e.g. ``panda_``).
    default_tool : the tool a fresh model carries ("franka_hand" or "none").
    servo_gains : gains of the simulator's joint velocity servo (Nm s/rad), used in velocity and position control
        and to hold the robot. A design choice of this simulator, not a published number: per joint, the same
        bandwidth kv / B_ii on every robot, with kv dt / B_ii <= 1 at the 1 ms step for the lightest inertia the
        joint drives (with the Franka Hand); above that, a step command that saturates the joint torque sets the
        implicitly integrated servo into a limit cycle. FrankaSim raises them by ``rotor_inertia`` times the same
        bandwidth (the servo drives the motors too).
    rotor_inertia : effective armature (7,) kg m^2: the reflected motor and gear inertia each joint's torque
        controller feels through the robot's torque loop. The plant puts it between the commanded torque and the
        link (MuJoCo joint armature); the measured ``tau_J`` stays the link-side torque the sensor reads, and the
        robot's model (pinocchio, libfranka's ``Model``) stays link side. Zero: an ideal torque source at the link
        (an easier plant than the robot). :meth:`with_rotor_inertia` scales it.
    sources : where each group of numbers comes from (for docs and reports).
    """

    name: str
    title: str
    dh_a: Vec7
    dh_d: Vec7
    dh_alpha: Vec7
    flange_d: float
    links: tuple[LinkInertial, ...]
    limits: JointLimits
    cartesian_limits: CartesianLimits
    friction: SigmoidFriction | None
    q_neutral: Vec7
    joint_names: tuple[str, ...]
    aliases: tuple[str, ...] = ()
    default_tool: str = "franka_hand"
    servo_gains: Vec7 = (120.0, 120.0, 80.0, 80.0, 15.0, 15.0, 6.0)
    rotor_inertia: Vec7 = (0.0,) * 7
    sources: dict[str, str] = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self) -> None:
        for attr in ("dh_a", "dh_d", "dh_alpha", "q_neutral", "joint_names", "rotor_inertia"):
            if len(getattr(self, attr)) != params.N_JOINTS:
                raise ValueError(f"robot description {self.name!r}: {attr} must have 7 entries")
        if len(self.links) != params.N_JOINTS:
            raise ValueError(f"robot description {self.name!r}: links must have 7 entries")
        lo, hi = np.array(self.limits.q_min), np.array(self.limits.q_max)
        q0 = np.array(self.q_neutral)
        if not ((lo < hi).all() and (q0 >= lo).all() and (q0 <= hi).all()):
            raise ValueError(f"robot description {self.name!r}: q_neutral must lie within q_min < q_max")
        rot = np.array(self.rotor_inertia, dtype=np.float64)
        if not (np.isfinite(rot).all() and (rot >= 0).all() and (rot <= 10.0).all()):
            raise ValueError(f"robot description {self.name!r}: rotor_inertia must lie in [0, 10] kg m^2, got "
                             f"{rot.tolist()}")

    def with_rotor_inertia(self, scale: float) -> RobotDescription:
        """This robot with its effective armature multiplied by ``scale`` >= 0 (0: an ideal link-side torque source,
        a looser plant than the robot; > 1: a stricter one). The name is kept, so model files still match."""
        scale = float(scale)
        if not (scale >= 0 and np.isfinite(scale)):
            raise ValueError(f"rotor inertia scale must be a finite number >= 0, got {scale}")
        return replace(self, rotor_inertia=tuple(float(x) * scale for x in self.rotor_inertia))

    # --- kinematics helpers (modified DH, Craig)
    def dh_placement(self, i: int) -> np.ndarray:
        """4x4 pose of frame i+1 in frame i at theta = 0, for joint index i in 0..6."""
        return params.mdh(self.dh_a[i], self.dh_d[i], self.dh_alpha[i], 0.0)

    def flange_placement(self) -> np.ndarray:
        """4x4 pose of the flange in the frame of link 7."""
        return params.mdh(0.0, self.flange_d, 0.0, 0.0)

    def limit_arrays(self) -> dict[str, np.ndarray]:
        """Fresh arrays of the joint limits (see :meth:`JointLimits.as_arrays`)."""
        return self.limits.as_arrays()

    def neutral(self) -> np.ndarray:
        """The neutral pose (7,) rad as a fresh array."""
        return np.array(self.q_neutral, dtype=np.float64)

    def has_friction(self) -> bool:
        """Whether the description carries an identified friction law."""
        return self.friction is not None

    def summary(self) -> dict[str, Any]:
        """A JSON-friendly identification (name, title, sources) for reports and model files."""
        return {"name": self.name, "title": self.title, "sources": dict(self.sources)}


@dataclass(frozen=True)
class HandDescription:
    """The Franka Hand as a tool: its rigid body (mass kg, com m and inertia kg m^2 about the com, hand frame), the
    hand frame's yaw about the flange z axis (rad), the TCP offset along the hand z (m), and the finger geometry (m)."""

    body: LinkInertial
    yaw: float
    tcp_z: float
    finger_z: float
    finger_opening: float

    def placement(self) -> np.ndarray:
        """4x4 pose of the hand frame in the flange frame."""
        return params.mdh(0.0, 0.0, 0.0, self.yaw)

    def flMe(self) -> np.ndarray:
        """4x4 pose of the TCP (the end effector) in the flange frame."""
        return self.placement() @ params.mdh(0.0, self.tcp_z, 0.0, 0.0)


FRANKA_HAND = HandDescription(params.HAND, params.HAND_YAW, params.HAND_TCP_Z, params.HAND_FINGER_Z,
                              params.HAND_FINGER_OPENING)
GRAVITY = params.GRAVITY  # standard vertical mounting, base frame, m/s^2
TAG_SIZE = params.TAG_SIZE  # default AprilTag black-square side, m

FER_LIMITS = JointLimits(params.Q_MIN, params.Q_MAX, params.DQ_MAX, params.DDQ_MAX, params.DDDQ_MAX,
                         params.TAU_MAX, params.DTAU_MAX)

FER = RobotDescription(
    name="fer",
    title="Franka Emika Robot (Panda) with identified dynamics (Gaz et al. 2019)",
    dh_a=params.DH_A, dh_d=params.DH_D, dh_alpha=params.DH_ALPHA, flange_d=params.FLANGE_D,
    links=params.LINKS,
    limits=FER_LIMITS,
    cartesian_limits=CartesianLimits(*params.CARTESIAN_LIMITS),
    friction=SigmoidFriction(params.FRICTION_PHI1, params.FRICTION_PHI2, params.FRICTION_PHI3),
    q_neutral=params.Q_NEUTRAL,
    joint_names=tuple(f"fer_joint{i + 1}" for i in range(7)),
    aliases=("panda_joint", "joint"),
    default_tool="franka_hand",
    rotor_inertia=params.FER_ROTOR_INERTIA,
    sources={
        "kinematics": "modified DH table of the FER (Franka Control Interface documentation)",
        "limits": "Franka Control Interface documentation, limits for the FER (Panda)",
        "inertials": "Gaz et al., IEEE RA-L 2019, identified feasible parameters",
        "friction": "Gaz et al., IEEE RA-L 2019, sigmoid friction model",
        "rotor_inertia": "none published for the FER: the FR3's identified values (same drive sizes), uncertain "
                         "within about a factor of 2",
    },
)

FR3 = RobotDescription(
    name="fr3",
    title="Franka Research 3 (published description; no identified friction)",
    dh_a=params.DH_A, dh_d=params.DH_D, dh_alpha=params.DH_ALPHA, flange_d=params.FLANGE_D,
    links=params.FR3_LINKS,
    limits=JointLimits(params.FR3_Q_MIN, params.FR3_Q_MAX, params.FR3_DQ_MAX, params.FR3_DDQ_MAX,
                       params.FR3_DDDQ_MAX, params.FR3_TAU_MAX, params.FR3_DTAU_MAX),
    cartesian_limits=CartesianLimits(*params.FR3_CARTESIAN_LIMITS),
    friction=None,
    q_neutral=params.Q_NEUTRAL,
    joint_names=tuple(f"fr3_joint{i + 1}" for i in range(7)),
    aliases=("joint",),
    default_tool="franka_hand",
    # the FR3's link 7 is 3.5x lighter about its axis than the FER's (B_66 0.0019 vs 0.0067 kg m^2 with the hand):
    # the FER's wrist gain of 6 Nm s/rad would be 3.2x past the 1 ms stability bound; 1.7 keeps the FER's bandwidth
    servo_gains=(120.0, 120.0, 80.0, 80.0, 15.0, 15.0, 1.7),
    rotor_inertia=params.FR3_ROTOR_INERTIA,
    sources={
        "kinematics": "Franka Control Interface documentation (same modified DH table as the FER); "
                      "franka_description robots/fr3/kinematics.yaml",
        "limits": "franka_description robots/fr3/joint_limits.yaml (Apache-2.0); Franka Control Interface "
                  "documentation, limits for Franka Research 3",
        "inertials": "franka_description robots/fr3/inertials.yaml (Apache-2.0)",
        "friction": "none published: identify it from your own logs with the workbench (franka-vs fit)",
        "rotor_inertia": "MuJoCo Menagerie franka_fr3/fr3.xml armature, identified in torque control (pull request "
                         "168, 2025)",
    },
)

ROBOTS: dict[str, RobotDescription] = {"fer": FER, "fr3": FR3}
_ALIASES = {"panda": "fer", "fer": "fer", "fr3": "fr3", "franka_research_3": "fr3"}


def register_robot(description: RobotDescription, *aliases: str) -> None:
    """Make a description available by name (``robot="..."`` everywhere a robot is taken)."""
    ROBOTS[description.name] = description
    for a in (description.name, *aliases):
        _ALIASES[a.lower()] = description.name


# how people name the registered robots in words (a sidecar, a README, a ROS parameter): whole words, any case, the
# separators " ", "_", "-", "/" alike. "Franka Emika" alone is the maker, not a robot (it built both).
_ROBOT_WORDS: dict[str, tuple[str, ...]] = {
    "fer": ("fer", "panda", "franka emika robot", "franka emika panda", "franka panda", "fer arm"),
    "fr3": ("fr3", "franka research 3", "franka research3", "research 3", "franka fr3", "fr 3"),
}


def _words(text: str) -> str:
    return " " + " ".join(re.split(r"[\s_\-/.,;:()\[\]{}\"']+", text.lower())).strip() + " "


def robot_from_words(text: str) -> str | None:
    """The registered robot a name in words stands for (``"FER (Franka Emika Robot, aka Panda)"`` -> ``"fer"``,
    ``"Franka Research 3"``/``"franka_fr3"`` -> ``"fr3"``; any case, inside a longer phrase), or None when it names
    none of them. A phrase naming two robots (``"FER or FR3"``) raises ValueError."""
    w = _words(text)
    found = {name for name, phrases in _ROBOT_WORDS.items() for ph in phrases if f" {ph} " in w}
    found |= {name for alias, name in _ALIASES.items() if f" {' '.join(_words(alias).split())} " in w}
    if len(found) > 1:
        raise ValueError(f"{text!r} names more than one robot ({', '.join(sorted(found))})")
    return found.pop() if found else None


def robot_description(robot: RobotDescription | str | None = None) -> RobotDescription:
    """Resolve ``robot`` (a description, a registered name such as "fer" or "fr3", the robot in words as
    :func:`robot_from_words` reads it, or None for the FER)."""
    if robot is None:
        return FER
    if isinstance(robot, RobotDescription):
        return robot
    if isinstance(robot, str):
        key = _ALIASES.get(robot.strip().lower())
        if key is None:
            try:
                key = robot_from_words(robot)
            except ValueError as e:
                raise ValueError(f"ambiguous robot: {e}; known robots are {sorted(ROBOTS)}") from None
        if key is None:
            raise ValueError(f"unknown robot {robot!r}: known robots are {sorted(ROBOTS)}")
        return ROBOTS[key]
    raise TypeError(f"robot must be a RobotDescription or a name, got {type(robot).__name__}")


__all__ = ["FER", "FR3", "FRANKA_HAND", "GRAVITY", "ROBOTS", "TAG_SIZE", "CartesianLimits", "HandDescription",
           "JointLimits", "LinkInertial", "RobotDescription", "SigmoidFriction", "register_robot", "robot_description",
           "robot_from_words"]
