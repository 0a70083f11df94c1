"""The hidden truth of ``franka-vs serve --truth FILE``: a plant that differs from what the robot's own model knows.

FILE is either a calibrated model file (what ``franka-vs fit -o`` writes: the plant is that configuration) or a JSON
list of effects with values, each added to the robot's model (``--model``, default the FER) to make the plant::

    [{"effect": "payload", "mass_kg": 1.2, "com_flange_m": [0.0, 0.02, 0.06]},
     {"effect": "coulomb_friction", "coulomb_Nm": [0.8, 0.8, 0.6, 0.6, 0.25, 0.25, 0.15]},
     {"effect": "delay", "delay_s": 0.008}]

or an object ``{"effects": [...], "torque_noise_Nm": 0.2, "seed": 0}`` that also sets white measurement noise of
the torque sensors. The keys are those the workbench reports for each effect (and the hidden-effect generators
answer with): ``payload`` (``mass_kg``, ``com_flange_m``, optional ``inertia_kgm2`` about the centre of mass, 3
or 3x3; held at the flange, unknown to the robot's gravity compensation and model), ``gravity_tilt`` (``tilt_deg``
with ``axis`` (3,) horizontal, default x; or ``gravity_m_per_s2`` (3,)), ``torque_offset`` (``offset_Nm``),
``armature`` (``armature_kgm2``), ``viscous_friction`` (``viscous_Nms_per_rad``), ``coulomb_friction``
(``coulomb_Nm``, ``coulomb_vel_rad_per_s`` default 0.05), ``stribeck_friction`` (``F_s_Nm``, ``v_s_rad_per_s``
default 0.1, ``coulomb_vel_rad_per_s`` default 0.05), ``sigmoid_friction`` (``phi1_Nm``, ``phi2_s_per_rad``,
``phi3_rad_per_s``: the plant's sigmoid replaced), ``link_mass`` (``link_mass_scale`` (7,) factors) and ``delay``
(``delay_s``; ``channel`` "measurement", the default: the torque sensors report late, or "command").

Joint effects (:mod:`franka_vs_gym.model.joint_effects`, in the plant's step), with the keys of the workbench's
generators of these effects (``validation/injected.py``, ``tests/independent_logs*.py``): ``cogging``
(``cycles_per_turn`` (or ``k``), ``amplitude_Nm`` (or ``A``), optional ``phase_rad`` and ``joints``: only those
joints get it), ``backlash`` (``b_rad``: the total gap, the transmission passes no torque within +-b/2),
``elastic`` (``stiffness_Nm_per_rad`` (or ``K``), ``damping_Nms_per_rad``, ``motor_inertia_kgm2``; defaults
:data:`~franka_vs_gym.model.joint_effects.DEFAULT_STIFFNESS`, ``DEFAULT_DAMPING`` and the robot's effective
armature) and ``static_friction`` (``breakaway_Nm``, ``stick_vel_rad_per_s`` default 0.002).

The robot's model (what ``load_model``, ``set_load`` and its gravity compensation use) stays the ``--model``: the
plant's extra mass, tilt, friction, armature, offsets and delay are effects it does not know, as on a real robot.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.errors import UserError
from franka_vs_gym.model.config import Friction, ModelConfig, RigidBody
from franka_vs_gym.model.joint_effects import DEFAULT_DAMPING, DEFAULT_STICK_VEL, DEFAULT_STIFFNESS, JointEffects

SUPPORTED = ("payload", "gravity_tilt", "torque_offset", "armature", "viscous_friction", "coulomb_friction",
             "stribeck_friction", "sigmoid_friction", "link_mass", "delay", "cogging", "backlash", "elastic",
             "static_friction")
JOINT_EFFECTS = ("cogging", "backlash", "elastic", "static_friction")


@dataclass
class Truth:
    """The plant's configuration, the payload the robot does not know (or None), the torque sensors' white noise
    (Nm) and its seed, and where it came from."""

    plant: ModelConfig
    payload: RigidBody | None
    torque_noise: float
    seed: int | None
    source: str
    effects: list[dict[str, Any]]
    joint_effects: JointEffects | None = None


def _vec(item: dict, key: str, n: int, where: str, default: Any = None) -> np.ndarray:
    v = item.get(key, default)
    if v is None:
        raise UserError(f"{where}: missing {key!r}")
    a = np.asarray(v, dtype=float) if not isinstance(v, str) else None
    if a is None or a.size not in (1, n) or not np.isfinite(a).all():
        raise UserError(f"{where}: {key!r} must be {n} finite numbers (or one for all), got {v!r}")
    return np.broadcast_to(a.ravel() if a.size == n else a.ravel()[0], (n,)).astype(float).copy()


def _num(item: dict, key: str, where: str, default: float | None = None) -> float:
    return float(_vec(item, key, 1, where, default)[0])


def add_effect(cfg: ModelConfig, payload: RigidBody | None, item: dict, where: str
               ) -> tuple[ModelConfig, RigidBody | None]:
    """The plant with one effect (a dict with ``effect`` and its values) added."""
    name = item.get("effect")
    if name not in SUPPORTED:
        raise UserError(f"{where}: unknown or unsupported effect {name!r}: choose from {', '.join(SUPPORTED)}")
    if name in JOINT_EFFECTS:
        raise UserError(f"{where}: {name} is a joint effect of the plant (FrankaSim(joint_effects=...)), not of the "
                        "model configuration")
    fr = Friction.from_dict(cfg.friction.to_dict())
    if name == "payload":
        m = _num(item, "mass_kg", where)
        if not 0 < m <= 20:
            raise UserError(f"{where}: payload mass_kg must be in (0, 20] kg, got {m}")
        com = _vec(item, "com_flange_m", 3, where, [0.0, 0.0, 0.05])
        inertia = item.get("inertia_kgm2")
        if inertia is None:
            I = np.eye(3) * m * 0.06 ** 2 / 6  # a 6 cm cube
        else:
            a = np.asarray(inertia, dtype=float)
            I = np.diag(a) if a.shape == (3,) else a
            if I.shape != (3, 3) or not np.isfinite(I).all():
                raise UserError(f"{where}: inertia_kgm2 must be 3 principal moments or a 3x3 matrix")
        if payload is not None:
            raise UserError(f"{where}: one payload only")
        return cfg, RigidBody(m, com, I)
    if name == "gravity_tilt":
        g0 = cfg.gravity
        if "gravity_m_per_s2" in item:
            g = _vec(item, "gravity_m_per_s2", 3, where)
        else:
            ang = math.radians(_num(item, "tilt_deg", where))
            axis = _vec(item, "axis", 3, where, [1.0, 0.0, 0.0])
            axis = axis / max(np.linalg.norm(axis), 1e-12)
            g = g0 * math.cos(ang) + np.cross(axis, g0) * math.sin(ang) + axis * (axis @ g0) * (1 - math.cos(ang))
        if abs(np.linalg.norm(g) - 9.81) > 0.5:
            raise UserError(f"{where}: gravity {g.tolist()} m/s^2 is not Earth's")
        return cfg.copy(gravity=g), payload
    if name == "torque_offset":
        return cfg.copy(torque_offset=cfg.torque_offset + _vec(item, "offset_Nm", 7, where)), payload
    if name == "armature":
        a = _vec(item, "armature_kgm2", 7, where)
        if (cfg.armature + a < 0).any():
            raise UserError(f"{where}: the plant's armature would be negative")
        return cfg.copy(armature=cfg.armature + a), payload
    if name == "viscous_friction":
        fr.viscous = fr.viscous + _vec(item, "viscous_Nms_per_rad", 7, where)
    elif name == "coulomb_friction":
        fr.coulomb = fr.coulomb + _vec(item, "coulomb_Nm", 7, where)
        fr.coulomb_vel = _num(item, "coulomb_vel_rad_per_s", where, 0.05)
    elif name == "stribeck_friction":
        fr.stribeck = fr.stribeck + _vec(item, "F_s_Nm", 7, where)
        fr.stribeck_vel = _vec(item, "v_s_rad_per_s", 7, where, 0.1)
        fr.coulomb_vel = _num(item, "coulomb_vel_rad_per_s", where, 0.05)
    elif name == "sigmoid_friction":
        fr.phi1 = _vec(item, "phi1_Nm", 7, where)
        fr.phi2 = _vec(item, "phi2_s_per_rad", 7, where, fr.phi2)
        fr.phi3 = _vec(item, "phi3_rad_per_s", 7, where, fr.phi3)
    elif name == "link_mass":
        s = _vec(item, "link_mass_scale", 7, where)
        if (s <= 0).any():
            raise UserError(f"{where}: link_mass_scale must be > 0")
        return cfg.copy(link_mass_scale=cfg.link_mass_scale * s), payload
    elif name == "delay":
        d = _num(item, "delay_s", where)
        ch = item.get("channel", "measurement")
        if not 0 <= d <= 0.1 or ch not in ("measurement", "command"):
            raise UserError(f"{where}: delay_s must be in [0, 0.1] s and channel 'measurement' or 'command'")
        return cfg.copy(delay=d, delay_channel=ch), payload
    return cfg.copy(friction=fr), payload


def _alias(item: dict, key: str, alias: str) -> dict:
    if key not in item and alias in item:
        item = dict(item)
        item[key] = item[alias]
    return item


def add_joint_effect(fx: dict[str, Any], item: dict, where: str) -> None:
    """Add one joint effect (cogging, backlash, elastic, static_friction) to ``fx`` (JointEffects keyword
    arguments, updated in place)."""
    name = item["effect"]
    if name in fx.get("_seen", ()):
        raise UserError(f"{where}: {name} given twice")
    fx.setdefault("_seen", []).append(name)
    if name == "cogging":
        item = _alias(_alias(item, "cycles_per_turn", "k"), "amplitude_Nm", "A")
        A = _vec(item, "amplitude_Nm", 7, where)
        n = _vec(item, "cycles_per_turn", 7, where)
        ph = _vec(item, "phase_rad", 7, where, 0.0)
        if "joints" in item:
            js = item["joints"]
            if not isinstance(js, list) or not all(isinstance(j, int) and 0 <= j < 7 for j in js):
                raise UserError(f"{where}: 'joints' must be a list of joint indices 0..6, got {js!r}")
            A = np.where(np.isin(np.arange(7), js), A, 0.0)
        if (A < 0).any() or (n[A > 0] <= 0).any() or (n > 10000).any():
            raise UserError(f"{where}: cogging needs amplitude_Nm >= 0 and cycles_per_turn in (0, 10000]")
        fx.update(cogging_Nm=A, cogging_cycles_per_turn=n, cogging_phase_rad=ph)
    elif name == "backlash":
        b = _vec(item, "b_rad", 7, where)
        if (b < 0).any() or (b > 0.1).any():
            raise UserError(f"{where}: b_rad (the total gap) must be in [0, 0.1] rad, got {b.tolist()}")
        fx["backlash_rad"] = b
    elif name == "elastic":
        item = _alias(_alias(item, "stiffness_Nm_per_rad", "K"), "damping_Nms_per_rad", "D")
        K = _vec(item, "stiffness_Nm_per_rad", 7, where, list(DEFAULT_STIFFNESS))
        D = _vec(item, "damping_Nms_per_rad", 7, where, list(DEFAULT_DAMPING))
        if (K <= 0).any() or (D < 0).any():
            raise UserError(f"{where}: elastic needs stiffness_Nm_per_rad > 0 and damping_Nms_per_rad >= 0")
        fx.update(stiffness_Nm_per_rad=K, damping_Nms_per_rad=D)
        if "motor_inertia_kgm2" in item:
            fx["motor_inertia_kgm2"] = _vec(item, "motor_inertia_kgm2", 7, where)
    else:  # static_friction
        F = _vec(item, "breakaway_Nm", 7, where)
        fx.update(breakaway_Nm=F, stick_vel=_num(item, "stick_vel_rad_per_s", where, DEFAULT_STICK_VEL))


def load_truth(path: str | Path, model: ModelConfig) -> Truth:
    """Read ``--truth FILE`` (see the module docstring) against the robot's model ``model``. Raises UserError
    naming the problem."""
    from franka_vs_gym import io

    p = Path(path)
    try:
        data = json.loads(io.read_text(p, what="truth file"))
    except json.JSONDecodeError as e:
        raise UserError(f"--truth {p}: not a JSON file ({e.msg} at line {e.lineno})") from None
    noise, seed = 0.0, None
    if isinstance(data, dict) and "effects" not in data:  # a calibrated model file
        try:
            plant = ModelConfig.load(p, model.robot)
        except (ValueError, KeyError, TypeError) as e:
            raise UserError(f"--truth {p}: neither a list of effects nor a model file: {e}") from None
        return Truth(plant, None, 0.0, None, str(p), [])
    if isinstance(data, dict):
        items = data["effects"]
        noise = float(data.get("torque_noise_Nm", 0.0))
        seed = data.get("seed")
        if not (noise >= 0 and math.isfinite(noise)):
            raise UserError(f"--truth {p}: torque_noise_Nm must be >= 0")
    else:
        items = data
    if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
        raise UserError(f"--truth {p}: expected a list of effects, each an object with 'effect' and its values")
    cfg, payload = model.copy(), None
    fx: dict[str, Any] = {}
    for k, item in enumerate(items):
        where = f"--truth {p} item {k}"
        if item.get("effect") in JOINT_EFFECTS:
            add_joint_effect(fx, item, where)
        else:
            cfg, payload = add_effect(cfg, payload, item, where)
    fx.pop("_seen", None)
    joint = None
    if fx:
        try:
            joint = JointEffects(**fx)
        except UserError as e:
            raise UserError(f"--truth {p}: {e}") from None
    return Truth(cfg, payload, noise, None if seed is None else int(seed), str(p), list(items), joint)


__all__ = ["JOINT_EFFECTS", "SUPPORTED", "Truth", "add_effect", "add_joint_effect", "load_truth"]
