"""MJCF generation for a Franka arm (FER, FR3) + Franka Hand and its scenes.

Every kinematic, inertial and limit number comes from the configuration's robot description
(:class:`~franka_vs_gym.model.config.ModelConfig` ``.robot``, typed in :mod:`franka_vs_gym.model.params`), so the
MuJoCo plant and the pinocchio model describe the same robot. The meshes are the FER's collision meshes for every
robot (the FR3 has the same kinematics; its covers differ slightly in shape). Several robots can share a scene;
each gets a name prefix (``"r0_"`` ...) on all its elements.

Modelling choices (documented because they matter when comparing with the pinocchio model):

- Links 1..7 carry the description's inertials (Gaz et al. for the FER); the tool (default the Franka Hand, fingers
  locked) and any *declared* payload are lumped into one ``hand`` body welded to link 7 at the flange, with the
  combined inertia of ``ModelConfig.flange_body``. An *undeclared* payload (one the robot does not know about) is a
  separate welded body.
- The robot's internal gravity compensation is MuJoCo's ``gravcomp`` on the arm and hand bodies, routed through the
  joint actuators (``actuatorgravcomp``), so the actuator force equals the commanded gravity-free torque plus g(q),
  like the FER's ``tau_J_d + g``. Undeclared bodies are not compensated.
- Each joint has a torque motor (``<prefix>motor<i>``) and a velocity servo (``<prefix>vel<i>``, gain set at run
  time by the robot's control mode). Actuator forces are clamped per joint at the robot's torque limits.
- Arm geoms collide with the environment (table, objects) but not with each other.
"""

from __future__ import annotations

import importlib.metadata
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import mujoco
import numpy as np

from franka_vs_gym.model.config import ModelConfig, RigidBody
from franka_vs_gym.model.description import FRANKA_HAND, TAG_SIZE
from franka_vs_gym.model.joint_effects import JointEffects

# contype/conaffinity: arm geoms collide with the environment but not with each other.
ARM_COLLISION = 'contype="2" conaffinity="1"'
ENV_COLLISION = 'contype="1" conaffinity="2"'
VISUAL_ONLY = 'contype="0" conaffinity="0"'
# Joint hard stops: stiff, critically damped limit constraints (time constant 2 ms, the smallest MuJoCo keeps stable
# at a 1 ms step; impedance 0.99-0.999) so that no torque drives a joint through its stop: 87 Nm on joint index 2
# from the neutral pose overshoots its 2.8973 rad stop by 0.027 rad at impact (59 rad/s, reflexes off) and settles
# within 1e-4 rad of it (soft default limits: 3.39 rad, 0.09 rad off after 2 s).
JOINT_STOP = 'solreflimit="0.002 1" solimplimit="0.99 0.999 0.0001"'


@lru_cache(maxsize=1)
def mesh_dir() -> Path:
    """Folder of the franka_description collision meshes shipped by the installed example-robot-data package."""
    try:
        files = importlib.metadata.files("example-robot-data") or []
    except importlib.metadata.PackageNotFoundError:
        files = []
    for f in files:
        if str(f).endswith("panda_description/meshes/collision/link0.stl"):
            return Path(str(f.locate())).parent
    raise RuntimeError("FER meshes not found: install the 'example-robot-data' package "
                       "(pip install example-robot-data)")


def _fmt(v) -> str:
    return " ".join(f"{float(x):.12g}" for x in np.ravel(v))


def mat2quat(R: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=np.float64).ravel())
    return q


def _inertial(body: RigidBody) -> str:
    I = body.inertia
    full = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
    return f'<inertial pos="{_fmt(body.com)}" mass="{body.mass:.12g}" fullinertia="{_fmt(full)}"/>'


@dataclass
class TagSpec:
    """An AprilTag 36h11 target: id, black-square side ``size`` (m), pose in the world (or in ``parent`` body)."""

    tag_id: int = 0
    size: float = TAG_SIZE
    pos: tuple[float, float, float] = (0.55, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    parent: str | None = None  # a body name (e.g. "r0_hand" to be held by a robot); None: the world
    name: str = "tag"


@dataclass
class CameraSpec:
    """A camera fixed in the world (e.g. an eye-to-hand camera): MuJoCo camera frame (looking along -z, y up) at
    ``pos`` (m) with orientation ``quat`` (w, x, y, z) in the world, vertical field of view ``fovy`` (degrees).
    :meth:`from_visp` builds one from a ViSP-convention pose wMc (z forward, y down)."""

    name: str = "fixed_camera"
    pos: tuple[float, float, float] = (1.0, 0.0, 0.5)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    fovy: float = 60.0

    @classmethod
    def from_visp(cls, name: str, wMc: np.ndarray, fovy: float = 60.0) -> CameraSpec:
        """The camera whose ViSP frame c (z forward, x right, y down) has pose ``wMc`` (4, 4) in the world."""
        from franka_vs_gym.model.geometry import CAMERA_VISP_TO_MUJOCO

        M = np.asarray(wMc, dtype=np.float64)
        return cls(name, tuple(M[:3, 3]), tuple(mat2quat(M[:3, :3] @ CAMERA_VISP_TO_MUJOCO)), float(fovy))


@dataclass
class RobotSpec:
    """One robot arm in a scene (which arm: ``config.robot``).

    prefix: name prefix of all its elements; base_pos (3,) m and base_quat (w, x, y, z) of the base in the world;
    config: the robot's model configuration; camera: add the wrist camera; ft_sensor: add a wrist force/torque
    sensor at the flange; undeclared_payload: a body held by the tool that the robot's gravity compensation ignores;
    rotor_inertia: put the robot's effective armature (``RobotDescription.rotor_inertia``, the motors as a torque
    controller feels them) on its joints (the FCI server's robot does; off by default); joint_effects: the plant's
    cogging, static friction and elastic transmission (:mod:`franka_vs_gym.model.joint_effects`; None: none): an
    elastic joint's motor inertia sits on the motor side (not in the joint's armature).
    """

    prefix: str = "r0_"
    base_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    config: ModelConfig = field(default_factory=ModelConfig)
    camera: bool = True
    ft_sensor: bool = False
    undeclared_payload: RigidBody | None = None
    rotor_inertia: bool = False
    joint_effects: JointEffects | None = None


@dataclass
class SceneSpec:
    """A scene: robots, an optional table, optional AprilTags, extra raw MJCF (assets/worldbody)."""

    robots: list[RobotSpec] = field(default_factory=lambda: [RobotSpec()])
    table: bool = True
    tags: list[TagSpec] = field(default_factory=list)
    cameras: list[CameraSpec] = field(default_factory=list)  # cameras fixed in the world
    timestep: float = 0.001
    gravity: tuple[float, float, float] | None = None  # world gravity; default: robot 0's config gravity
    extra_assets: str = ""
    extra_worldbody: str = ""
    offwidth: int = 640
    offheight: int = 480


def _robot_bodies(r: RobotSpec) -> tuple[str, str, str, str]:
    """(worldbody xml, actuator xml, sensor xml, contact-exclude xml) of one robot."""
    p, cfg = r.prefix, r.config
    robot, lim = cfg.robot, cfg.robot.limits
    xml = [f'<body name="{p}link0" pos="{_fmt(r.base_pos)}" quat="{_fmt(r.base_quat)}">',
           '<geom class="fer_visual" mesh="link0"/><geom class="fer_collision" mesh="link0"/>']
    closing = ["</body>"]
    for i, (mass, com, inertia) in enumerate(cfg.link_inertials()):
        M = robot.dh_placement(i)
        body = RigidBody(mass, com, inertia)
        lo, hi = lim.q_min[i], lim.q_max[i]
        tau = lim.tau_max[i]
        xml.append(f'<body name="{p}link{i + 1}" pos="{_fmt(M[:3, 3])}" quat="{_fmt(mat2quat(M[:3, :3]))}" '
                   f'gravcomp="1">')
        xml.append(_inertial(body))
        armature = cfg.armature[i] + (robot.rotor_inertia[i] if r.rotor_inertia else 0.0)  # (+ the motors')
        fx = r.joint_effects
        if fx is not None and fx.elastic[i]:
            armature = cfg.armature[i]  # the motor is on the other side of the transmission
        xml.append(f'<joint name="{p}joint{i + 1}" range="{lo} {hi}" armature="{armature:.12g}" '
                   f'actuatorfrcrange="{-tau} {tau}" actuatorgravcomp="true" {JOINT_STOP}/>')
        xml.append(f'<geom class="fer_visual" mesh="link{i + 1}"/><geom class="fer_collision" mesh="link{i + 1}"/>')
        closing.append("</body>")
    Mfl = robot.flange_placement()
    hand = cfg.flange_body()
    xml.append(f'<body name="{p}hand" pos="{_fmt(Mfl[:3, 3])}" gravcomp="1">')
    if hand.mass > 0:
        xml.append(_inertial(hand))
    xml.append(f'<site name="{p}flange" size="0.005" rgba="1 0 0 0"/>')
    flMe = cfg.tool.flMe
    xml.append(f'<site name="{p}ee" pos="{_fmt(flMe[:3, 3])}" quat="{_fmt(mat2quat(flMe[:3, :3]))}" size="0.005" '
               f'rgba="0 1 0 0"/>')
    if cfg.tool.name == "franka_hand":
        Rh = FRANKA_HAND.placement()[:3, :3]
        yaw = f'quat="{_fmt(mat2quat(Rh))}"'
        o = FRANKA_HAND.finger_opening / 2
        xml.append(f'<body name="{p}hand_geoms" {yaw}>')
        xml.append('<geom class="fer_visual" mesh="hand"/><geom class="fer_collision" mesh="hand"/>')
        for side, y, q in (("left", o, "1 0 0 0"), ("right", -o, "0 0 0 1")):
            xml.append(f'<body name="{p}{side}finger" pos="0 {y} {FRANKA_HAND.finger_z}" quat="{q}">'
                       '<geom class="fer_visual" mesh="finger"/><geom class="fer_collision" mesh="finger"/></body>')
        xml.append("</body>")
    if r.camera:
        # Pose set at run time from eMc (FrankaSim.set_eMc); MuJoCo cameras look along -z with y up.
        xml.append(f'<camera name="{p}wrist_camera" pos="{_fmt(flMe[:3, 3])}" fovy="60"/>')
    if r.undeclared_payload is not None and r.undeclared_payload.mass > 0:
        xml.append(f'<body name="{p}undeclared_payload" gravcomp="0">{_inertial(r.undeclared_payload)}</body>')
    xml.append("</body>")  # hand
    xml.extend(closing)
    act = []
    for i in range(7):
        tau = lim.tau_max[i]
        act.append(f'<motor name="{p}motor{i + 1}" joint="{p}joint{i + 1}" ctrlrange="{-tau} {tau}"/>')
    for i in range(7):
        act.append(f'<velocity name="{p}vel{i + 1}" joint="{p}joint{i + 1}" kv="0" '
                   f'ctrlrange="{-lim.dq_max[i]} {lim.dq_max[i]}"/>')
    sens = []
    if r.ft_sensor:
        sens.append(f'<force name="{p}ft_force" site="{p}flange"/><torque name="{p}ft_torque" site="{p}flange"/>')
    return "\n".join(xml), "\n".join(act), "\n".join(sens), ""


def _tag_xml(t: TagSpec) -> tuple[str, str]:
    """Asset and body xml of a tag: a thin box whose top face carries the tag texture (with its white border)."""
    from franka_vs_gym.assets.textures import tag_texture_png  # local: OpenCV only needed for scenes with tags

    png = tag_texture_png(t.tag_id)
    # the texture holds the 8x8-cell black square inside a 1-cell white border: 10 cells wide
    half = t.size / 2 * 10 / 8
    asset = (f'<texture name="{t.name}_tex" type="2d" file="{png}"/>'
             f'<material name="{t.name}_mat" texture="{t.name}_tex" specular="0" shininess="0" reflectance="0"/>')
    body = (f'<body name="{t.name}" pos="{_fmt(t.pos)}" quat="{_fmt(t.quat)}">'
            f'<geom name="{t.name}_geom" type="box" size="{half:.9g} {half:.9g} 0.0005" pos="0 0 -0.0005" '
            f'material="{t.name}_mat" {VISUAL_ONLY}/>'
            f'<site name="{t.name}_center" size="0.002" rgba="1 0 0 0"/></body>')
    return asset, body


def raised_table_xml(height: float, name: str = "table") -> str:
    """A rigid table in front of the robot with its top at ``height`` (m, robot base frame), as raw MJCF for a
    scene's ``extra_worldbody``: a box 0.8 m deep (x from 0.15 m) and 1.0 m wide standing on z = -0.02 m, clear of
    the robot's base and shoulder, so the hand or the bare flange can press on it (libfranka's force-control
    example needs the last joint resting on a horizontal rigid surface)."""
    h = float(height)
    if not (np.isfinite(h) and 0.0 < h < 1.2):
        raise ValueError(f"table height {height!r} m: give the table top's height above the robot base, 0 < h < 1.2")
    half = (h + 0.02) / 2
    return (f'<geom name="{name}" type="box" size="0.4 0.5 {half:.9g}" pos="0.55 0 {h - half:.9g}" '
            f'material="table_mat" {ENV_COLLISION}/>')


def scene_xml(scene: SceneSpec) -> str:
    """The complete MJCF of a scene."""
    if not scene.robots:
        raise ValueError("a scene needs at least one robot")
    prefixes = [r.prefix for r in scene.robots]
    if len(set(prefixes)) != len(prefixes):
        raise ValueError(f"robot prefixes must be unique, got {prefixes}")
    g = scene.gravity if scene.gravity is not None else scene.robots[0].config.gravity
    meshes = "\n".join(f'<mesh name="{n}" file="{n}.stl"/>' for n in
                       ["link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand", "finger"])
    bodies, acts, sens = [], [], []
    for r in scene.robots:
        b, a, s, _ = _robot_bodies(r)
        bodies.append(b)
        acts.append(a)
        sens.append(s)
    tag_assets: list[str] = []
    tag_bodies: list[str] = []
    held: dict[str, list[str]] = {}
    for t in scene.tags:
        a, b = _tag_xml(t)
        tag_assets.append(a)
        if t.parent is None:
            tag_bodies.append(b)
        else:
            held.setdefault(t.parent, []).append(b)
    world = "\n".join(bodies)
    for parent, items in held.items():
        key = f'<body name="{parent}"'
        if key not in world:
            raise ValueError(f"tag parent body {parent!r} is not in the scene")
        # insert right after the parent's opening tag line
        start = world.index(key)
        end = world.index(">", start) + 1
        world = world[:end] + "".join(items) + world[end:]
    cams = "".join(f'<camera name="{c.name}" pos="{_fmt(c.pos)}" quat="{_fmt(c.quat)}" fovy="{c.fovy:.12g}"/>'
                   for c in scene.cameras)
    table = ""
    if scene.table:
        # table top 1 mm below z = 0, so that objects lying "on" it at z = 0 (tags) are rendered above it
        table = (f'<geom name="table" type="box" size="0.8 0.8 0.02" pos="0.3 0 -0.021" material="table_mat" '
                 f'{ENV_COLLISION}/>')
    # user numbers: franka_vs_gym.sim.plant's NUSER per joint (friction law and reflex limits) and RSLOT per robot
    # (its reflex record), read by the compiled plant
    from franka_vs_gym.sim import plant  # (imported here: franka_vs_gym.sim imports this module)

    # the joint effects' columns when any robot has them, and the elastic joints' motor records after the robots'
    any_fx = any(r.joint_effects is not None and r.joint_effects.any() for r in scene.robots)
    n_motor = plant.MREC * sum(int(r.joint_effects.stateful.sum()) for r in scene.robots if r.joint_effects is not None)
    nuser = plant.ENUSER if any_fx else plant.NUSER
    nuserdata = plant.RSLOT * len(scene.robots) + n_motor

    return f"""<mujoco model="franka_vs_gym">
<compiler angle="radian" meshdir="{mesh_dir()}" inertiafromgeom="false" autolimits="true"/>
<option timestep="{scene.timestep:.9g}" integrator="implicitfast" gravity="{_fmt(g)}"/>
<size nuser_jnt="{nuser}" nuserdata="{nuserdata}"/>
<visual><global offwidth="{scene.offwidth}" offheight="{scene.offheight}"/>
<quality shadowsize="0"/><map znear="0.01" zfar="20"/></visual>
<default>
  <default class="fer_visual"><geom type="mesh" {VISUAL_ONLY} group="2" rgba="0.92 0.92 0.95 1" mass="0"/></default>
  <default class="fer_collision"><geom type="mesh" {ARM_COLLISION} group="3" rgba="0.5 0.5 0.5 0" mass="0"/></default>
</default>
<asset>
{meshes}
<texture name="sky" type="skybox" builtin="gradient" rgb1="0.75 0.82 0.9" rgb2="0.3 0.35 0.42" width="64" height="64"/>
<texture name="grid" type="2d" builtin="checker" rgb1="0.55 0.45 0.35" rgb2="0.5 0.4 0.3" width="256" height="256"/>
<material name="table_mat" texture="grid" texrepeat="8 8" specular="0" shininess="0" reflectance="0"/>
{"".join(tag_assets)}
{scene.extra_assets}
</asset>
<worldbody>
<light name="top" pos="0.3 0 2.5" dir="0 0 -1" directional="true" castshadow="false" diffuse="0.8 0.8 0.8"/>
<light name="side" pos="1.5 -1.5 1.5" dir="-1 1 -1" directional="true" castshadow="false" diffuse="0.3 0.3 0.3"/>
<camera name="overview" pos="1.6 -1.3 1.2" xyaxes="0.63 0.78 0 -0.35 0.28 0.89" fovy="45"/>
{table}
{world}
{"".join(tag_bodies)}
{cams}
{scene.extra_worldbody}
</worldbody>
<actuator>
{"".join(acts)}
</actuator>
<sensor>
{"".join(sens)}
</sensor>
</mujoco>
"""
