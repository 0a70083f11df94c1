"""Joint effects of the plant that the robot's model does not know: cogging, static friction, an elastic
transmission with backlash (a :class:`JointEffects` for ``FrankaSim(joint_effects=...)`` and ``franka-vs serve
--truth``). The compiled plant applies them inside MuJoCo's step (``franka_vs_gym/sim/_plant.c``); all are off by
default. Per joint (7,), SI units:

- **cogging** ``tau_c = A sin(n x + phase)`` (Nm), resisted by the drive like friction: ``x = q`` on a rigid joint
  (the link-side torque sensor sees it, as it sees the plant's friction), ``x = theta`` (the motor) on an elastic
  one. ``n`` is in cycles per *link* turn: a ripple of ``c`` cycles per motor turn behind a gear of ratio ``N``
  shows ``n = c N`` per link turn. A strain-wave (harmonic) gear's dominant ripple comes at two cycles per turn of
  its wave generator (the flexspline meshes in two opposite regions), i.e. ``2 N`` per link turn (Tuttle 1992,
  "Understanding and modeling the behavior of a harmonic drive gear transmission", MIT AI Lab TR 1365); the FER's
  gear ratios are not published (strain-wave gears of this size come with ratios of 50-160, hence 100-320 cycles per
  link turn). Motor cogging (slot and pole count, tens of cycles per motor turn) lands at thousands of cycles per
  link turn: above what a 1 ms plant resolves except at a few mrad/s.
- **static friction** (stiction): a joint at rest holds up to ``breakaway`` (Nm) whatever loads it, and slips when
  the load exceeds it; once sliding the breakaway decays as ``breakaway (1 - tanh(|dq| / stick_vel))`` and the
  plant's friction law (Gaz et al. 2019 for the FER, fitted on moving joints) takes over. The stick is
  elasto-plastic: the joint is tied to an anchor by a stiff spring-damper whose force is capped at that level (the
  anchor follows a slipping joint), so at rest it holds with zero velocity and a deflection of load / k_s (k_s a
  1 ms plant's stable stiffness: about 0.2 mrad for 0.3 Nm on joint 7), as presliding displacement does.
- **elastic joint** (Spong 1987, "Modeling and control of elastic joint robots", J. Dyn. Sys. Meas. Control 109):
  the motor (position ``theta``, inertia ``motor_inertia`` on the motor side) is driven by the commanded torque plus
  the gravity compensation; the link feels ``tau_t = K dz(theta - q) + D (dtheta - dq)`` and the torque sensor reads
  ``tau_t``. ``dz`` is the **backlash** dead zone (total gap ``backlash`` rad, ``+-backlash/2`` about zero
  deflection): no torque passes inside the gap, the damping engages with the contact. A backlash without a given
  stiffness uses :data:`DEFAULT_STIFFNESS` for the gear beyond the gap.

How sure are the numbers: none of these is published for the FER or the FR3. :data:`DEFAULT_STIFFNESS` is an order
of magnitude for harmonic-drive joints with link-side torque sensors of this size (10^4 Nm/rad for the large, a few
10^3 for the wrist joints), trust within a factor 3; with the FR3's effective armature on the motor side it puts the
FER's motor-link modes at 38-111 Hz (neutral pose), above the 8-20 Hz link-side ringing the workbench's own generator
of elastic logs assumes (tests/independent_logs_b.py). The FR3's last link (0.0019 kg m^2) allows at most about
1.8 10^3 Nm/rad on joint 7 at a 1 ms step (the defaults are refused there with a message: give ``K``, ``D``).
The robot's internal joint impedance (motion generators, 2000-3000 Nm/rad) feeds back the link position through
the transmission: keep K well above its stiffness (with 1.5 10^3 on joint 7 a FER excitation tripped the velocity
reflex). Choose your own from a measurement (a step response's ringing gives ``sqrt(K (1/B + 1/M))``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from franka_vs_gym.errors import UserError

DEFAULT_STIFFNESS = (1.0e4, 1.0e4, 1.0e4, 1.0e4, 3.0e3, 3.0e3, 3.0e3)  # Nm/rad (see the module docstring)
DEFAULT_DAMPING = (10.0, 10.0, 10.0, 10.0, 2.0, 2.0, 2.0)  # Nm s/rad
DEFAULT_STICK_VEL = 2e-3  # rad/s: below this a joint is at rest for the static friction
MAX_OMEGA_DT = 1.0  # the elastic joint's mode sqrt(K (1/B + 1/M)) dt must stay below this (semi-implicit Euler: 2)


def _z() -> np.ndarray:
    return np.zeros(7)


def _vec(v: Any, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.size not in (1, 7) or not np.isfinite(a).all():
        raise UserError(f"joint effects: {name} must be 7 finite numbers (or one for all), got {v!r}")
    return np.broadcast_to(a.ravel() if a.size == 7 else a.ravel()[0], (7,)).astype(float).copy()


@dataclass
class JointEffects:
    """The plant's joint effects (see the module docstring); every field (7,) except ``stick_vel`` (rad/s).

    cogging_Nm, cogging_cycles_per_turn, cogging_phase_rad : the ripple ``A sin(n x + phase)``.
    breakaway_Nm : static friction level (0: none); stick_vel : rest tolerance of the static friction.
    stiffness_Nm_per_rad : transmission stiffness K (0: rigid joint); damping_Nms_per_rad : D;
    motor_inertia_kgm2 : B on the motor side (None: the robot's effective armature, ``RobotDescription.rotor_inertia``);
    backlash_rad : total gap of the transmission (needs a stiffness; one is given by default).
    """

    cogging_Nm: np.ndarray = field(default_factory=_z)
    cogging_cycles_per_turn: np.ndarray = field(default_factory=_z)
    cogging_phase_rad: np.ndarray = field(default_factory=_z)
    breakaway_Nm: np.ndarray = field(default_factory=_z)
    stick_vel: float = DEFAULT_STICK_VEL
    stiffness_Nm_per_rad: np.ndarray = field(default_factory=_z)
    damping_Nms_per_rad: np.ndarray = field(default_factory=_z)
    motor_inertia_kgm2: np.ndarray | None = None
    backlash_rad: np.ndarray = field(default_factory=_z)

    def __post_init__(self) -> None:
        for n in ("cogging_Nm", "cogging_cycles_per_turn", "cogging_phase_rad", "breakaway_Nm",
                  "stiffness_Nm_per_rad", "damping_Nms_per_rad", "backlash_rad"):
            setattr(self, n, _vec(getattr(self, n), n))
        if self.motor_inertia_kgm2 is not None:
            self.motor_inertia_kgm2 = _vec(self.motor_inertia_kgm2, "motor_inertia_kgm2")
        self.stick_vel = float(self.stick_vel)
        if not (math.isfinite(self.stick_vel) and 1e-6 <= self.stick_vel <= 0.1):
            raise UserError(f"joint effects: stick_vel must be in [1e-6, 0.1] rad/s, got {self.stick_vel}")
        for n in ("cogging_Nm", "breakaway_Nm", "stiffness_Nm_per_rad", "damping_Nms_per_rad", "backlash_rad"):
            if (getattr(self, n) < 0).any():
                raise UserError(f"joint effects: {n} must be >= 0, got {getattr(self, n).tolist()}")
        if (self.cogging_Nm > 20).any() or (self.breakaway_Nm > 20).any():
            raise UserError("joint effects: cogging_Nm and breakaway_Nm must be <= 20 Nm (a joint's torque limit "
                            "is 12-87 Nm)")
        if (self.cogging_cycles_per_turn[self.cogging_Nm > 0] <= 0).any():
            raise UserError("joint effects: cogging_cycles_per_turn must be > 0 where cogging_Nm is")
        if (self.backlash_rad > 0.1).any():
            raise UserError(f"joint effects: backlash_rad must be <= 0.1 rad, got {self.backlash_rad.tolist()}")
        if self.motor_inertia_kgm2 is not None and (self.motor_inertia_kgm2[self.elastic] <= 0).any():
            raise UserError("joint effects: motor_inertia_kgm2 must be > 0 at an elastic joint")
        # a backlash needs the gear's stiffness beyond the gap
        gap_only = (self.backlash_rad > 0) & (self.stiffness_Nm_per_rad == 0)
        self.stiffness_Nm_per_rad[gap_only] = np.asarray(DEFAULT_STIFFNESS)[gap_only]
        self.damping_Nms_per_rad[gap_only & (self.damping_Nms_per_rad == 0)] = \
            np.asarray(DEFAULT_DAMPING)[gap_only & (self.damping_Nms_per_rad == 0)]

    @property
    def elastic(self) -> np.ndarray:
        """(7,) bool: the joints with an elastic transmission (a motor state)."""
        return self.stiffness_Nm_per_rad > 0

    @property
    def stateful(self) -> np.ndarray:
        """(7,) bool: the joints whose effects keep a state in the plant (elastic: the motor; static friction: the
        stick's anchor)."""
        return self.elastic | (self.breakaway_Nm > 0)

    def any(self) -> bool:
        """Whether any effect is on."""
        return bool(self.cogging_Nm.any() or self.breakaway_Nm.any() or self.elastic.any())

    def motor_inertia(self, rotor_inertia: Any) -> np.ndarray:
        """B (7,) kg m^2: the given motor inertia, else the robot's effective armature ``rotor_inertia``."""
        return np.asarray(rotor_inertia if self.motor_inertia_kgm2 is None else self.motor_inertia_kgm2, dtype=float)

    def check_stable(self, link_inertia: Any, rotor_inertia: Any, dt: float) -> None:
        """Raise UserError when an elastic joint's mode ``sqrt(K (1/B + 1/M)) dt`` (``M`` the link-side inertia
        ``link_inertia`` (7,), e.g. the mass matrix's diagonal) or its damping ``D dt (1/B + 1/M)`` is beyond what
        the plant's step integrates stably (:data:`MAX_OMEGA_DT`)."""
        B = self.motor_inertia(rotor_inertia)
        M = np.asarray(link_inertia, dtype=float)
        for j in np.flatnonzero(self.elastic):
            if not B[j] > 0:
                raise UserError(f"joint effects: joint {j} is elastic but has no motor inertia (give "
                                "motor_inertia_kgm2)")
            inv = 1.0 / B[j] + 1.0 / M[j]
            w = math.sqrt(self.stiffness_Nm_per_rad[j] * inv)
            if w * dt > MAX_OMEGA_DT or self.damping_Nms_per_rad[j] * dt * inv > MAX_OMEGA_DT:
                raise UserError(f"joint effects: joint {j}'s elastic mode ({w / (2 * math.pi):.0f} Hz with K "
                                f"{self.stiffness_Nm_per_rad[j]:g} Nm/rad, B {B[j]:g}, M {M[j]:.3g} kg m^2, D "
                                f"{self.damping_Nms_per_rad[j]:g} Nm s/rad) is too fast for a {dt * 1e3:g} ms step: "
                                f"keep sqrt(K (1/B + 1/M)) dt and D dt (1/B + 1/M) <= {MAX_OMEGA_DT:g}")

    def modes_hz(self, link_inertia: Any, rotor_inertia: Any) -> np.ndarray:
        """(7,) Hz: each elastic joint's motor-link natural frequency ``sqrt(K (1/B + 1/M)) / 2 pi`` (0 if rigid)."""
        B = self.motor_inertia(rotor_inertia)
        M = np.asarray(link_inertia, dtype=float)
        with np.errstate(divide="ignore"):
            w = np.sqrt(self.stiffness_Nm_per_rad * (1.0 / np.where(B > 0, B, np.inf) + 1.0 / M))
        return np.where(self.elastic, w / (2 * math.pi), 0.0)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()}
        return out


__all__ = ["DEFAULT_DAMPING", "DEFAULT_STICK_VEL", "DEFAULT_STIFFNESS", "JointEffects", "MAX_OMEGA_DT"]
