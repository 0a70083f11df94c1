"""Model configuration: everything that turns a robot description into one concrete robot.

A :class:`ModelConfig` holds the robot (a :class:`~franka_vs_gym.model.description.RobotDescription`, default the
FER), the tool on the flange, an optional payload, the gravity vector in the base frame, the
friction law, rotor inertia (armature), a torque-sensor offset and a torque/motion delay. It is what the
model-vs-measurement workbench calibrates and saves (a JSON "calibrated model file"), and what ``FrankaModel``,
``FrankaSim`` and ``gymnasium.make(..., model=...)`` load. Both the pinocchio model and the MuJoCo plant are built
from it, so they always describe the same robot.

Frames: tool and payload quantities are expressed in the flange frame ``fl`` (as libfranka's ``setLoad``), with
inertia tensors about the body's own centre of mass. Units are SI.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.model import checks
from franka_vs_gym.model.checks import as_vector
from franka_vs_gym.model.description import (
    FER,
    FRANKA_HAND,
    GRAVITY,
    ROBOTS,
    LinkInertial,
    RobotDescription,
    robot_description,
)
from franka_vs_gym.model.friction import compile_friction, joint_friction
from franka_vs_gym.model.geometry import combine_inertials, rotate_inertia

FORMAT = "franka_vs_gym.model/2"
# Older formats still read: version 1 files predate the robot field and describe the FER.
_FORMATS = {"franka_vs_gym.model/1": 1, FORMAT: 2}


class _RobotDefault:
    """Marker of a ``ModelConfig`` field left to the robot description's default (tool, friction)."""

    def __repr__(self) -> str:
        return "ROBOT_DEFAULT"


ROBOT_DEFAULT: Any = _RobotDefault()


def _mat(x: Any, shape: tuple[int, int], name: str) -> np.ndarray:
    return checks.as_matrix(x, shape, name)


@dataclass
class RigidBody:
    """A rigid body fixed to the flange: mass (kg), com (3,) in the flange frame (m), inertia (3, 3) about the com
    with flange-frame axes (kg m^2)."""

    mass: float = 0.0
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    def __post_init__(self) -> None:
        self.mass = checks.as_scalar(self.mass, "mass", 0.0, checks.MAX_BODY_MASS, "kg")
        self.com = as_vector(self.com, 3, "com")
        try:
            inertia = np.asarray(self.inertia, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"inertia must be a numeric (3, 3) or (3,) array, got {type(self.inertia).__name__}") \
                from None
        if inertia.shape == (3,):
            inertia = np.diag(inertia)
        self.inertia = _mat(inertia, (3, 3), "inertia")
        checks.check_inertia(self.inertia, self.mass, "rigid body")

    def to_dict(self) -> dict[str, Any]:
        return {"mass": self.mass, "com": self.com.tolist(), "inertia": self.inertia.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any], name: str = "payload") -> RigidBody:
        if not isinstance(d, dict):
            raise ValueError(f"{name} must be an object with mass, com, inertia")
        missing = {"mass", "com", "inertia"} - set(d)
        if missing:
            raise ValueError(f"{name} lacks {sorted(missing)}")
        try:
            return cls(d["mass"], d["com"], d["inertia"])
        except ValueError as e:
            raise ValueError(f"{name}: {e}") from None


@dataclass
class Tool:
    """The tool mounted on the flange: its end-effector frame ``flMe`` (4x4) and its rigid body."""

    name: str = "franka_hand"
    flMe: np.ndarray = field(default_factory=FRANKA_HAND.flMe)
    body: RigidBody = field(default_factory=lambda: franka_hand_body())

    def __post_init__(self) -> None:
        self.flMe = _mat(self.flMe, (4, 4), "flMe")
        R = self.flMe[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError("flMe must be a homogeneous transform with a rotation matrix")

    @classmethod
    def franka_hand(cls) -> Tool:
        return cls()

    @classmethod
    def none(cls) -> Tool:
        """No tool: the end effector is the flange."""
        return cls("none", np.eye(4), RigidBody())

    @classmethod
    def named(cls, name: str | None) -> Tool:
        """A tool by name: "franka_hand", or "none" / None for the bare flange."""
        return cls.from_dict(name)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "flMe": self.flMe.tolist(), **self.body.to_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, Any] | str | None) -> Tool:
        if d is None or d == "none":
            return cls.none()
        if d == "franka_hand":
            return cls.franka_hand()
        if isinstance(d, str):
            raise ValueError(f"unknown tool {d!r}: use 'franka_hand', null, or a mass/com/inertia object")
        if not isinstance(d, dict):
            raise ValueError(f"tool must be 'franka_hand', null, or an object with mass, com, inertia; got "
                             f"{type(d).__name__}")
        flMe = d.get("flMe", np.eye(4))
        name = d.get("name", "custom")
        if not isinstance(name, str):
            raise ValueError(f"tool name must be a string, got {type(name).__name__}")
        return cls(name, flMe, RigidBody.from_dict(d, "tool"))


def franka_hand_body() -> RigidBody:
    """The Franka Hand's inertial parameters expressed in the flange frame."""
    R = FRANKA_HAND.placement()[:3, :3]
    h = FRANKA_HAND.body
    return RigidBody(h.mass, R @ np.array(h.com), rotate_inertia(R, h.inertia_matrix()))


@dataclass
class Friction:
    """Joint friction law, per joint (7,):

    ``tau_f(dq) = phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))``  (Gaz sigmoid)
    ``          + viscous * dq + coulomb * tanh(dq / coulomb_vel)``
    ``          + stribeck * exp(-(dq / stribeck_vel)^2) * tanh(dq / coulomb_vel)``  (Stribeck, Armstrong-Helouvry).

    Units: phi1, coulomb, stribeck in Nm; phi2 in s/rad; phi3 in rad/s; viscous in Nm s/rad; coulomb_vel in rad/s (a
    smoothing velocity for the Coulomb and Stribeck terms, small compared with the motion); stribeck_vel (7,) in rad/s
    (the Stribeck velocity: the excess friction ``stribeck`` at rest has fallen to 1/e at this speed). A model file
    stores ``stribeck`` and ``stribeck_vel`` only when the Stribeck term is non-zero (older files load unchanged).
    """

    phi1: np.ndarray = field(default_factory=lambda: np.array(FER.friction.phi1))  # type: ignore[union-attr]
    phi2: np.ndarray = field(default_factory=lambda: np.array(FER.friction.phi2))  # type: ignore[union-attr]
    phi3: np.ndarray = field(default_factory=lambda: np.array(FER.friction.phi3))  # type: ignore[union-attr]
    viscous: np.ndarray = field(default_factory=lambda: np.zeros(7))
    coulomb: np.ndarray = field(default_factory=lambda: np.zeros(7))
    coulomb_vel: float = 0.01
    stribeck: np.ndarray = field(default_factory=lambda: np.zeros(7))
    stribeck_vel: np.ndarray = field(default_factory=lambda: np.full(7, 0.1))

    def __post_init__(self) -> None:
        for name in ("phi1", "phi2", "phi3", "viscous", "coulomb", "stribeck", "stribeck_vel"):
            setattr(self, name, as_vector(getattr(self, name), 7, f"friction.{name}"))
        self.coulomb_vel = checks.as_scalar(self.coulomb_vel, "friction.coulomb_vel", unit="rad/s")
        if self.coulomb_vel <= 0:
            raise ValueError(f"friction.coulomb_vel must be > 0 rad/s, got {self.coulomb_vel}")
        if not (self.stribeck_vel > 0).all():
            j = int(np.argmin(self.stribeck_vel))
            raise ValueError(f"friction.stribeck_vel[{j}] = {self.stribeck_vel[j]:g} rad/s: the Stribeck velocity "
                             "must be > 0")
        if (self.phi2 < 0).any():
            j = int(np.argmin(self.phi2))
            raise ValueError(f"friction.phi2[{j}] = {self.phi2[j]:g} s/rad: the sigmoid's slope must be >= 0 "
                             "(a negative slope would push the joint)")

    @classmethod
    def none(cls) -> Friction:
        """No friction (phi2 = 1 keeps the sigmoid well defined at zero height)."""
        z = np.zeros(7)
        return cls(z, np.ones(7), z, z, z)

    @classmethod
    def of(cls, robot: RobotDescription | str | None = None) -> Friction:
        """The identified friction of a robot description, or no friction when it has none (calibrate it)."""
        fr = robot_description(robot).friction
        if fr is None:
            return cls.none()
        return cls(np.array(fr.phi1), np.array(fr.phi2), np.array(fr.phi3))

    def is_zero(self) -> bool:
        return not (self.phi1.any() or self.viscous.any() or self.coulomb.any() or self.stribeck.any())

    def compile(self):
        """A fast closure dq -> tau_f (7,), Nm (:func:`franka_vs_gym.model.friction.compile_friction`)."""
        return compile_friction(self.phi1, self.phi2, self.phi3, self.viscous, self.coulomb, self.coulomb_vel,
                                self.stribeck, self.stribeck_vel)

    def __call__(self, dq: np.ndarray) -> np.ndarray:
        """tau_f(dq), Nm, for dq (7,) or (N, 7) rad/s (the law of :mod:`franka_vs_gym.model.friction`)."""
        return joint_friction(dq, self.phi1, self.phi2, self.phi3, self.viscous, self.coulomb, self.coulomb_vel,
                              self.stribeck, self.stribeck_vel)

    def to_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k).tolist() for k in ("phi1", "phi2", "phi3", "viscous", "coulomb")} | {
            "coulomb_vel": self.coulomb_vel}
        if self.stribeck.any():  # written only when present: files without it stay as they were
            d |= {"stribeck": self.stribeck.tolist(), "stribeck_vel": self.stribeck_vel.tolist()}
        return d

    def check_dissipative(self, dq_max: Any = None) -> None:
        """Raise ValueError unless the law opposes motion at every velocity up to ``dq_max`` (7,) rad/s (default
        the FER's limits)."""
        dq_max = np.array(FER.limits.dq_max if dq_max is None else dq_max, dtype=np.float64)
        checks.check_dissipative(self.compile(), dq_max)
        if self.stribeck.any():  # the hump lives at low speed: check there too (1e-3 dq_max and up)
            tau_f = self.compile()
            for s in np.geomspace(1e-3, 0.05, 12):
                checks.check_dissipative(tau_f, s * dq_max)

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None, robot: RobotDescription | str | None = None) -> Friction:
        """Read a friction law; sigmoid parameters missing from ``d`` are the robot's identified ones."""
        if d is None:
            return cls.none()
        if not isinstance(d, dict):
            raise ValueError(f"friction must be an object (phi1, phi2, phi3, viscous, coulomb, coulomb_vel, stribeck, "
                             f"stribeck_vel) or null, got "
                             f"{type(d).__name__}")
        unknown = set(d) - {"phi1", "phi2", "phi3", "viscous", "coulomb", "coulomb_vel", "stribeck", "stribeck_vel"}
        if unknown:
            raise ValueError(f"unknown keys in friction: {sorted(unknown)} (known: phi1, phi2, phi3, viscous, coulomb, "
                             "coulomb_vel, stribeck, stribeck_vel)")
        base = cls.of(robot)
        kw = {k: d.get(k, getattr(base, k)) for k in ("phi1", "phi2", "phi3")}
        kw.update({k: d.get(k, np.zeros(7)) for k in ("viscous", "coulomb", "stribeck")})
        return cls(**kw, coulomb_vel=d.get("coulomb_vel", 0.01), stribeck_vel=d.get("stribeck_vel", np.full(7, 0.1)))


@dataclass
class ModelConfig:
    """One concrete robot: a description (links, limits) plus tool, payload, gravity, friction, armature, offset and
    delay.

    Attributes
    ----------
    robot : RobotDescription or its registered name
        The arm (default :data:`~franka_vs_gym.model.description.FER`); ``"fr3"`` for the Franka Research 3. Stored
        as the description itself; a model file stores its name.
    tool : Tool or None
        Tool on the flange (default the robot's ``default_tool``, the Franka Hand for the FER and the FR3; None: the
        bare flange); its ``flMe`` defines the end-effector frame e.
    payload : RigidBody or None
        Extra load held by the tool (flange frame), as libfranka's ``setLoad``.
    gravity : (3,) array
        Gravity vector in the base frame f, m/s^2 (default (0, 0, -9.81): vertical mounting).
    friction : Friction or None
        Joint friction law (default: the robot's identified law, Gaz et al. 2019 for the FER; none for a robot
        without one; None: no friction).
    armature : (7,) array
        Reflected rotor inertia added to the diagonal of the mass matrix, kg m^2.
    torque_offset : (7,) array
        Bias of the joint torque sensors, Nm: measured tau_J = true tau_J + torque_offset.
    delay : float
        A time delay, s (0 by default), acting on ``delay_channel``.
    delay_channel : "command" or "measurement"
        "command": torque commands reach the joints ``delay`` late (the measured torque then matches the motion
        but lags the commanded torque). "measurement": the torque sensors report ``delay`` late (the measured torque
        lags the motion). FrankaSim implements both.
    link_mass_scale : (7,) array
        Multiplies the mass and inertia of each link (domain randomisation), 1 by default.
    """

    tool: Tool = ROBOT_DEFAULT
    payload: RigidBody | None = None
    gravity: np.ndarray = field(default_factory=lambda: np.array(GRAVITY, dtype=np.float64))
    friction: Friction = ROBOT_DEFAULT
    armature: np.ndarray = field(default_factory=lambda: np.zeros(7))
    torque_offset: np.ndarray = field(default_factory=lambda: np.zeros(7))
    delay: float = 0.0
    delay_channel: str = "command"
    link_mass_scale: np.ndarray = field(default_factory=lambda: np.ones(7))
    notes: dict[str, Any] = field(default_factory=dict)
    robot: RobotDescription = FER
    check_gravity: bool = True

    def __post_init__(self) -> None:
        self.robot = robot_description(self.robot)
        if self.tool is ROBOT_DEFAULT:
            self.tool = Tool.named(self.robot.default_tool)
        elif self.tool is None or isinstance(self.tool, str):
            self.tool = Tool.named(self.tool)
        if self.friction is ROBOT_DEFAULT:
            self.friction = Friction.of(self.robot)
        elif self.friction is None:
            self.friction = Friction.none()
        self.gravity = as_vector(self.gravity, 3, "gravity")
        if self.check_gravity:
            checks.check_gravity(self.gravity)
        self.armature = as_vector(self.armature, 7, "armature")
        if (self.armature < 0).any():
            raise ValueError(f"armature must be >= 0 kg m^2, got {self.armature}")
        self.torque_offset = as_vector(self.torque_offset, 7, "torque_offset")
        self.link_mass_scale = as_vector(self.link_mass_scale, 7, "link_mass_scale")
        if (self.link_mass_scale <= 0).any():
            raise ValueError("link_mass_scale must be > 0")
        self.delay = checks.as_scalar(self.delay, "delay", unit="s")
        if not math.isfinite(self.delay) or self.delay < 0:
            raise ValueError(f"delay must be a finite number >= 0 s, got {self.delay}")
        if self.delay_channel not in ("command", "measurement"):
            raise ValueError(f"delay_channel must be 'command' or 'measurement', got {self.delay_channel!r}")
        self._check_plausible()

    def _check_plausible(self) -> None:
        """Refuse values no FER can have (see :mod:`franka_vs_gym.model.checks`)."""
        if self.delay > 1.0:
            raise ValueError(f"delay = {self.delay:g} s is not plausible for a 1 kHz torque loop (> 1 s); units (ms)?")
        if (self.armature > 10.0).any():
            raise ValueError(f"armature {self.armature.tolist()} kg m^2: over 10 kg m^2 is not plausible")
        if (self.link_mass_scale > 100).any():
            raise ValueError(f"link_mass_scale {self.link_mass_scale.tolist()}: over 100 is not plausible")
        load = self.flange_body()
        if load.mass > checks.MAX_FLANGE_LOAD:
            raise ValueError(f"tool + payload mass {load.mass:.4g} kg is not plausible for the FER (rated payload "
                             f"3 kg; refused above {checks.MAX_FLANGE_LOAD:g} kg); grams?")
        if load.mass > 0 and np.linalg.norm(load.com) > checks.MAX_LOAD_COM:
            raise ValueError(f"tool + payload centre of mass {np.round(load.com, 4).tolist()} m is over "
                             f"{checks.MAX_LOAD_COM:g} m from the flange; mm?")

    def plausibility_warnings(self) -> list[str]:
        """Values a user may mean but that are outside the FER's specification (reported with results)."""
        out = []
        load = self.flange_body()
        if load.mass > checks.RATED_FLANGE_LOAD + 1e-9:
            out.append(f"tool + payload {load.mass:.3g} kg exceeds the FER's rated payload (3 kg plus the 0.73 kg "
                       "hand)")
        if not self.check_gravity:
            out.append(f"gravity check disabled: |g| = {np.linalg.norm(self.gravity):.4g} m/s^2")
        if np.abs(self.torque_offset).max() > 5.0:
            out.append(f"torque offset up to {np.abs(self.torque_offset).max():.3g} Nm (FER sensors: < 1 Nm)")
        if self.delay > 0.02:
            out.append(f"delay {self.delay * 1e3:.3g} ms is long for the FER (a few ms expected)")
        try:
            self.friction.check_dissipative(self.robot.limits.dq_max)
        except ValueError as e:
            out.append(str(e))
        return out

    def copy(self, **changes: Any) -> ModelConfig:
        """A deep copy with some fields replaced (validated like a new configuration)."""
        new = replace(self, **changes)
        return ModelConfig.from_dict(new.to_dict(), robot=new.robot)

    def link_inertials(self) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """(mass, com (3,), inertia (3,3) about com) of links 1..7 after scaling."""
        out = []
        for s, link in zip(self.link_mass_scale, self.robot.links, strict=True):
            out.append((link.mass * s, np.array(link.com), link.inertia_matrix() * s))
        return out

    def flange_body(self) -> RigidBody:
        """Tool and payload combined into one rigid body in the flange frame."""
        bodies = [self.tool.body] + ([self.payload] if self.payload is not None else [])
        m, c, inertia = combine_inertials((b.mass, b.com, b.inertia) for b in bodies)
        return RigidBody() if m == 0 else RigidBody(m, c, inertia)

    # --- serialisation (the calibrated-model file)
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "robot": self.robot.name,
            **_robot_overrides(self.robot),
            "tool": self.tool.to_dict(),
            "payload": None if self.payload is None else self.payload.to_dict(),
            "gravity": self.gravity.tolist(),
            "friction": self.friction.to_dict(),
            "armature": self.armature.tolist(),
            "torque_offset": self.torque_offset.tolist(),
            "delay": self.delay,
            "delay_channel": self.delay_channel,
            "link_mass_scale": self.link_mass_scale.tolist(),
            "notes": self.notes,
            **({} if self.check_gravity else {"check_gravity": False}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], robot: RobotDescription | str | None = None) -> ModelConfig:
        """Read a model file's content. ``robot``: the robot the caller expects (a name or a description); a file
        naming another robot is an error. Version-1 files (no robot field) describe the FER."""
        if not isinstance(d, dict):
            raise ValueError("a model file must hold a JSON object")
        fmt = d.get("format", FORMAT)
        if fmt not in _FORMATS:
            raise ValueError(f"unsupported model file format {fmt!r} (expected {FORMAT!r})")
        desc = _file_robot(d, robot)
        if "links" in d:
            desc = replace(desc, links=_links_from_file(d["links"]))
        known = {"format", "robot", "links", "tool", "payload", "gravity", "friction", "armature", "torque_offset",
                 "delay", "delay_channel", "link_mass_scale", "notes", "check_gravity"}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown keys in model file: {sorted(unknown)}")
        if not isinstance(d.get("notes", {}), dict):
            raise ValueError("notes in a model file must be an object")
        if not isinstance(d.get("check_gravity", True), bool):
            raise ValueError("check_gravity in a model file must be true or false")
        if not isinstance(d.get("delay_channel", "command"), str):
            raise ValueError("delay_channel must be 'command' or 'measurement'")
        cfg = cls(
            tool=Tool.from_dict(d.get("tool", "franka_hand")),
            payload=None if d.get("payload") is None else RigidBody.from_dict(d["payload"]),
            gravity=d.get("gravity", GRAVITY),
            friction=Friction.from_dict(d["friction"], desc) if "friction" in d else Friction.of(desc),
            armature=d.get("armature", np.zeros(7)),
            torque_offset=d.get("torque_offset", np.zeros(7)),
            delay=d.get("delay", 0.0),
            delay_channel=d.get("delay_channel", "command"),
            link_mass_scale=d.get("link_mass_scale", np.ones(7)),
            notes=dict(d.get("notes", {})),
            robot=desc,
            check_gravity=d.get("check_gravity", True),
        )
        if d.get("friction") is not None:  # a file's friction law must oppose motion
            cfg.friction.check_dissipative(cfg.robot.limits.dq_max)
        return cfg

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the model file atomically (a unique temporary in the target folder, then a rename); refuses to
        overwrite an existing file unless ``overwrite``, and never writes over an input of the running command."""
        from franka_vs_gym.io import atomic_write

        _check_nameable(self.robot)
        return atomic_write(path, json.dumps(self.to_dict(), indent=2), force=overwrite, what="model file")

    @classmethod
    def load(cls, path: str | os.PathLike, robot: RobotDescription | str | None = None) -> ModelConfig:
        """Read a calibrated-model file; ``robot`` (optional) is the robot the caller expects. ValueError naming
        the file and the problem if it is not one."""
        from franka_vs_gym.io import loads_json, read_text

        p = Path(path)
        text = read_text(p, what="model file")
        try:
            d = loads_json(text, f"model file {p}")
        except json.JSONDecodeError as e:
            raise ValueError(f"model file {p} is not valid JSON: {e}") from None
        try:
            return cls.from_dict(d, robot)
        except ValueError as e:
            raise ValueError(f"model file {p}: {e}") from None


def _check_nameable(robot: RobotDescription) -> None:
    """A model file names its robot and may store link inertials; anything else must be in the registry."""
    registered = ROBOTS.get(robot.name)
    if registered is None:
        raise ValueError(f"robot {robot.name!r} is not registered: register_robot() it before saving a model file")
    if replace(registered, links=robot.links) != robot:
        raise ValueError(f"the robot description {robot.name!r} differs from the registered one in more than its link "
                         "inertials: register it under its own name (register_robot) before saving a model file")


def _robot_overrides(robot: RobotDescription) -> dict[str, Any]:
    """What a model file stores besides the robot's name: the link inertials when they differ from the registered
    description's (e.g. identified by the workbench's ``link_inertials`` effect)."""
    registered = ROBOTS.get(robot.name)
    if registered is not None and registered.links == robot.links:
        return {}
    return {"links": [{"mass": link.mass, "com": list(link.com), "inertia": list(link.inertia)}
                      for link in robot.links]}


def _links_from_file(links: Any) -> tuple[LinkInertial, ...]:
    """Link inertials 1..7 stored in a model file (mass kg, com (3,) m, inertia (ixx, ixy, ixz, iyy, iyz, izz) kg
    m^2 about the com), checked."""
    if not isinstance(links, list) or len(links) != 7:
        raise ValueError("links in a model file must be a list of 7 objects (mass, com, inertia)")
    out = []
    for i, link in enumerate(links):
        try:
            body = RigidBody(link["mass"], link["com"], np.asarray(link["inertia"], dtype=np.float64)[[0, 1, 2, 1, 3, 4,
                                                                                                         2, 4, 5]]
                             .reshape(3, 3))
        except (KeyError, TypeError, IndexError, ValueError) as e:
            raise ValueError(f"links[{i}] in the model file: {e}") from None
        if body.mass <= 0:
            raise ValueError(f"links[{i}] in the model file: mass must be > 0 kg")
        I = body.inertia
        out.append(LinkInertial(body.mass, tuple(map(float, body.com)),
                                (I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2])))
    return tuple(out)


def _file_robot(d: dict[str, Any], expected: RobotDescription | str | None) -> RobotDescription:
    """The description a model file's content names (version 1: the FER), checked against ``expected``."""
    name = d.get("robot", FER.name)
    if not isinstance(name, str):
        raise ValueError(f"the model file's robot must be a name such as 'fer' or 'fr3', got {name!r}")
    if expected is not None:
        want = robot_description(expected)
        try:
            named = robot_description(name).name
        except ValueError:
            named = name
        if named != want.name:
            raise ValueError(f"the model file describes the robot {name!r}, not {want.name!r} "
                             f"(calibrate a model file for {want.name!r})")
        return want
    return robot_description(name)


def resolve_config(model: Any, robot: RobotDescription | str | None = None) -> ModelConfig:
    """Accept a ModelConfig, a FrankaModel, a path to a model file, or None (defaults for ``robot``).

    ``robot`` (optional): the robot the caller asks for; a configuration or file for another robot is an error.
    """
    if model is None:
        return ModelConfig(robot=robot_description(robot))
    if isinstance(model, (str, os.PathLike)):
        return ModelConfig.load(model, robot)
    cfg = model if isinstance(model, ModelConfig) else getattr(model, "config", None)
    if not isinstance(cfg, ModelConfig):
        raise TypeError(f"cannot make a model configuration from {type(model).__name__}")
    if robot is not None and robot_description(robot).name != cfg.robot.name:
        raise ValueError(f"the model configuration describes the robot {cfg.robot.name!r}, "
                         f"not {robot_description(robot).name!r}")
    return cfg
