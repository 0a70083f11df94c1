"""Input checks shared by the model, the simulator and the controllers: bad input gets a ValueError naming it."""

from __future__ import annotations

from typing import Any

import numpy as np


def as_vector(x: Any, n: int, name: str) -> np.ndarray:
    """``x`` as a finite float64 array of shape (n,); ValueError naming ``name`` otherwise."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array of shape ({n},), got {type(x).__name__}") from None
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains NaN or inf: {a}")
    return a


def as_pose(M: Any, name: str) -> np.ndarray:
    """``M`` as a finite 4x4 homogeneous matrix whose rotation part is a rotation; ValueError otherwise."""
    try:
        a = np.asarray(M, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite 4x4 homogeneous matrix, got {type(M).__name__}") from None
    if a.shape != (4, 4) or not np.isfinite(a).all():
        raise ValueError(f"{name} must be a finite 4x4 homogeneous matrix, got shape {a.shape}")
    R = a[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(f"{name}: the rotation part is not a rotation matrix")
    return a


# ------------------------------------------------------------------ physical plausibility (where numbers enter)
STANDARD_GRAVITY = 9.80665
#: accepted gravity norm, m/s^2 (local gravity on Earth is 9.78-9.83; the margin leaves room for a fitted tilt)
GRAVITY_NORM_RANGE = (9.3, 10.3)
#: largest mass of any rigid body the model accepts, kg (the FER's links weigh < 5 kg, its rated payload is 3 kg)
MAX_BODY_MASS = 100.0
#: largest tool + payload on the flange, kg (refused above; warned above the FER's rated payload plus the hand)
MAX_FLANGE_LOAD = 20.0
RATED_FLANGE_LOAD = 3.0 + 0.73
#: largest distance of a flange load's centre of mass from the flange, m (the arm's reach is 0.855 m)
MAX_LOAD_COM = 1.0


def as_scalar(x: Any, name: str, lo: float | None = None, hi: float | None = None, unit: str = "") -> float:
    """``x`` as a finite float within [lo, hi]; ValueError naming ``name`` otherwise (also for wrong types)."""
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number{' (' + unit + ')' if unit else ''}, got {type(x).__name__}")
    v = float(x)
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        rng = f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
        raise ValueError(f"{name} = {v:g}{' ' + unit if unit else ''} is outside the plausible range {rng}")
    return v


def as_matrix(x: Any, shape: tuple[int, int], name: str) -> np.ndarray:
    """``x`` as a finite float64 array of ``shape``; ValueError naming ``name`` otherwise."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array of shape {shape}, got {type(x).__name__}") from None
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains NaN or inf")
    return a


def check_inertia(inertia: np.ndarray, mass: float, name: str) -> None:
    """A rigid body's inertia tensor about its centre of mass (3, 3), kg m^2: symmetric, positive semi-definite,
    principal moments obeying the triangle inequality (I1 + I2 >= I3) and below 1000 kg m^2."""
    if not np.allclose(inertia, inertia.T, atol=1e-12, rtol=1e-9):
        raise ValueError(f"{name} inertia must be symmetric")
    ev = np.linalg.eigvalsh((inertia + inertia.T) / 2)
    scale = max(float(np.abs(ev).max()), 1e-12)
    if ev.min() < -1e-9 * scale - 1e-15:
        raise ValueError(f"{name} inertia must be positive semi-definite, principal moments {ev.tolist()} kg m^2")
    if ev[0] + ev[1] < ev[2] * (1 - 1e-6) - 1e-15:
        raise ValueError(f"{name} inertia violates the triangle inequality: principal moments {ev.tolist()} kg m^2 "
                         f"({ev[0]:.3g} + {ev[1]:.3g} < {ev[2]:.3g}); no rigid body has them")
    if mass == 0 and ev[2] > 0:
        raise ValueError(f"{name} has an inertia but no mass")
    if ev[2] > 1e3:
        raise ValueError(f"{name}: principal moment {ev[2]:.3g} kg m^2 is not plausible for a robot's load; units?")


def check_gravity(g: np.ndarray, name: str = "gravity") -> None:
    """The gravity vector's norm must be Earth's (within :data:`GRAVITY_NORM_RANGE`, m/s^2)."""
    n = float(np.linalg.norm(g))
    lo, hi = GRAVITY_NORM_RANGE
    if not lo <= n <= hi:
        raise ValueError(f"{name} {np.round(g, 4).tolist()} has norm {n:.4g} m/s^2; expected about 9.81 "
                         f"({lo}-{hi}); pass check_gravity=False (model file: \"check_gravity\": false) to simulate "
                         "another gravity")


class NotDissipative(ValueError):
    """A friction law that pushes a joint (``tau_f dq < 0`` somewhere); ``joint`` is the first such joint."""

    def __init__(self, message: str, joint: int) -> None:
        super().__init__(message)
        self.joint = joint


DISSIPATION_STEPS = np.linspace(-1.0, 1.0, 41)[np.linspace(-1.0, 1.0, 41) != 0]  # fractions of dq_max checked
LOW_SPEED_STEPS = np.geomspace(1e-3, 0.05, 12)  # and, for a law with a Stribeck hump, these fractions of them


def dissipation_grid(dq_max: np.ndarray, low_speed: bool = False) -> np.ndarray:
    """The velocities (G, 7) rad/s at which :func:`check_dissipative` (and ``Friction.check_dissipative``) test a law:
    ``s dq_max`` for 40 fractions s in [-1, 1], and with ``low_speed`` also those scaled by 1e-3..0.05."""
    dq_max = np.asarray(dq_max, dtype=np.float64)
    grid = DISSIPATION_STEPS[:, None] * dq_max
    if low_speed:
        grid = np.concatenate([grid] + [s * grid for s in LOW_SPEED_STEPS])
    return grid


def check_dissipative(tau_f, dq_max: np.ndarray, name: str = "friction") -> None:
    """Friction must dissipate energy: tau_f(dq) dq >= 0 on a grid of velocities up to the limits (7,).
    ``tau_f`` maps (7,) rad/s to (7,) Nm. Raises :class:`NotDissipative` (a ValueError) naming the first joint."""
    for s in DISSIPATION_STEPS:
        dq = s * dq_max
        p = tau_f(dq) * dq
        if (p < -1e-9).any():
            j = int(np.argmin(p))
            raise NotDissipative(f"{name} of joint {j} is not dissipative: tau_f = {tau_f(dq)[j]:.4g} Nm at dq = "
                                 f"{dq[j]:.3g} rad/s (friction must oppose motion; check the signs of its parameters)",
                                 j)
