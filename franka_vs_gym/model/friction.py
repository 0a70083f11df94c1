"""The joint friction law, written once: the model, the plant, the workbench effects and the generators call it.

The law, per joint (Gaz et al., IEEE RA-L 2019, eq. (6), plus a viscous, a smoothed Coulomb and a Stribeck term)::

    tau_f(dq) = phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))     (sigmoid, 0 at rest)
              + viscous * dq
              + coulomb * tanh(dq / coulomb_vel)
              + stribeck * exp(-(dq / stribeck_vel)^2) * tanh(dq / coulomb_vel)

The last term is the Stribeck effect: the friction in excess of sliding friction at low speed (static friction
F_s above the Coulomb level F_c, ``stribeck = F_s - F_c``), decaying with speed as the exponential Stribeck curve
``(F_s - F_c) exp(-(dq / v_s)^2) sign(dq)`` of Armstrong-Helouvry, Dupont & Canudas de Wit, "A survey of models,
analysis tools and compensation methods for the control of machines with friction", Automatica 30(7), 1994
(their eq. for the static + Coulomb + viscous + Stribeck model, exponent 2); its sign is smoothed through zero by
the same ``tanh(dq / coulomb_vel)`` as the Coulomb term, so that Coulomb + Stribeck together are
``tanh(dq / coulomb_vel) (F_c + (F_s - F_c) exp(-(dq / v_s)^2))``.

Units: dq in rad/s; phi1, coulomb, stribeck in Nm; phi2 in s/rad; phi3 in rad/s; viscous in Nm s/rad; coulomb_vel,
stribeck_vel in rad/s.
Every function broadcasts: ``dq`` may be one joint vector (7,), a batch of samples (N, 7), or scalars, with the
parameters as per-joint arrays (7,) or scalars. ``tau_f`` is the torque the joint needs on top of the rigid-body
torque; the plant applies ``-tau_f``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.special import expit  # 1 / (1 + exp(-x)) without overflow for large |x|

ArrayLike = np.ndarray | float


def gaz_sigmoid(dq: ArrayLike, phi1: ArrayLike, phi2: ArrayLike, phi3: ArrayLike) -> np.ndarray:
    """Gaz sigmoid friction, Nm: ``phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))``."""
    return phi1 * expit(np.multiply(phi2, np.add(dq, phi3))) - phi1 * expit(np.multiply(phi2, phi3))


def sigmoid_levels(phi1: ArrayLike, phi2: ArrayLike, phi3: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """The Gaz sigmoid's sliding levels, Nm: ``(L_plus, L_minus)`` with ``gaz_sigmoid -> L_plus`` for dq -> +inf and
    ``-> -L_minus`` for dq -> -inf (``L_plus = phi1 (1 - s0)``, ``L_minus = phi1 s0``, ``s0 = 1 / (1 + exp(-phi2
    phi3))``)."""
    s0 = expit(np.multiply(phi2, phi3))
    return np.multiply(phi1, 1.0 - s0), np.multiply(phi1, s0)


def viscous_friction(dq: ArrayLike, viscous: ArrayLike) -> np.ndarray:
    """Viscous friction, Nm: ``viscous * dq``."""
    return np.multiply(viscous, dq)


def coulomb_friction(dq: ArrayLike, coulomb: ArrayLike, coulomb_vel: ArrayLike) -> np.ndarray:
    """Smoothed Coulomb friction, Nm: ``coulomb * tanh(dq / coulomb_vel)``."""
    return coulomb * np.tanh(np.divide(dq, coulomb_vel))


def stribeck_friction(dq: ArrayLike, stribeck: ArrayLike, stribeck_vel: ArrayLike,
                      coulomb_vel: ArrayLike) -> np.ndarray:
    """Stribeck friction, Nm: ``stribeck * exp(-(dq / stribeck_vel)^2) * tanh(dq / coulomb_vel)`` (the excess of
    static over sliding friction, decaying with speed; Armstrong-Helouvry et al. 1994)."""
    return np.multiply(stribeck, np.exp(-np.square(np.divide(dq, stribeck_vel)))) * np.tanh(np.divide(dq, coulomb_vel))


def joint_friction(dq: ArrayLike, phi1: ArrayLike, phi2: ArrayLike, phi3: ArrayLike, viscous: ArrayLike = 0.0,
                   coulomb: ArrayLike = 0.0, coulomb_vel: ArrayLike = 0.01, stribeck: ArrayLike = 0.0,
                   stribeck_vel: ArrayLike = 0.1) -> np.ndarray:
    """The whole law (sigmoid + viscous + Coulomb + Stribeck), Nm, the reference every faster form must match."""
    out = (gaz_sigmoid(dq, phi1, phi2, phi3) + viscous_friction(dq, viscous)
           + coulomb_friction(dq, coulomb, coulomb_vel))
    if np.any(stribeck):
        out = out + stribeck_friction(dq, stribeck, stribeck_vel, coulomb_vel)
    return out


def sigmoid_tanh_coefficients(phi1: np.ndarray, phi2: np.ndarray,
                              phi3: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(a, b, c, e) with ``gaz_sigmoid(dq) = a tanh(b dq + c) + e`` (the same law, as one tanh: cheaper in place).

    Uses ``1 / (1 + exp(-x)) = (1 + tanh(x / 2)) / 2``.
    """
    phi1, phi2, phi3 = (np.asarray(x, dtype=np.float64) for x in (phi1, phi2, phi3))
    a = phi1 / 2
    return a, phi2 / 2, phi2 * phi3 / 2, a - phi1 / (1.0 + np.exp(-phi2 * phi3))


def compile_friction(phi1: np.ndarray, phi2: np.ndarray, phi3: np.ndarray, viscous: np.ndarray | None = None,
                     coulomb: np.ndarray | None = None, coulomb_vel: float = 0.01, stribeck: np.ndarray | None = None,
                     stribeck_vel: np.ndarray | float = 0.1) -> Callable[[np.ndarray], np.ndarray]:
    """A fast closure ``dq -> tau_f`` equal to :func:`joint_friction`, specialised to the terms that are non-zero
    (the parameters are copied: later changes to the arrays do not affect it)."""
    p1, p2, p3 = (np.array(x, dtype=np.float64) for x in (phi1, phi2, phi3))
    visc = None if viscous is None or not np.any(viscous) else np.array(viscous, dtype=np.float64)
    coul = None if coulomb is None or not np.any(coulomb) else np.array(coulomb, dtype=np.float64)
    strb = None if stribeck is None or not np.any(stribeck) else np.array(stribeck, dtype=np.float64)
    inv_vs = 1.0 / np.asarray(stribeck_vel, dtype=np.float64)
    cv = float(coulomb_vel)
    p2p3 = p2 * p3  # the sigmoid as phi1 expit(phi2 dq + phi2 phi3): one product fewer per call, no overflow
    off = p1 * expit(p2p3)
    has_sig = bool(p1.any())
    exp = np.exp

    if has_sig and visc is None and coul is None and strb is None:
        def sigmoid_only(dq: np.ndarray) -> np.ndarray:
            return p1 * expit(p2 * dq + p2p3) - off
        # (phi1, phi2, phi2 phi3, offset) (7,) each: the law p1 expit(p2 dq + p2p3) - off, for compiled callers
        sigmoid_only.sigmoid_coefficients = (p1, p2, p2p3, off)
        return sigmoid_only

    def general(dq: np.ndarray) -> np.ndarray:
        out = p1 * expit(p2 * dq + p2p3) - off if has_sig else np.zeros(np.shape(dq))
        if visc is not None:
            out = out + visc * dq
        if coul is not None:
            out = out + coul * np.tanh(dq / cv)
        if strb is not None:
            out = out + strb * exp(-np.square(dq * inv_vs)) * np.tanh(dq / cv)
        return out
    return general


def make_plant_friction(qvel: np.ndarray, qfrc: np.ndarray, phi1: np.ndarray, phi2: np.ndarray, phi3: np.ndarray,
                        viscous: np.ndarray, coulomb: np.ndarray, coulomb_vel: float,
                        scale: float = 1.0, stribeck: np.ndarray | None = None,
                        stribeck_vel: np.ndarray | float = 0.1) -> Callable[[], None]:
    """An allocation-free hook writing ``qfrc[:] = -scale * tau_f(qvel)`` (the plant's per-step friction).

    ``qvel`` and ``qfrc`` are views into the simulator's state (7,); the hook reads the first and writes the second
    in place every physics step. ``scale`` multiplies the whole law (domain randomisation). The Stribeck term costs
    nothing when ``stribeck`` is None or zero.
    """
    a, b, c, e = sigmoid_tanh_coefficients(phi1, phi2, phi3)
    neg_a, neg_e = -scale * a, -scale * e
    visc = scale * np.asarray(viscous, dtype=np.float64)
    coul = scale * np.asarray(coulomb, dtype=np.float64)
    strb = None if stribeck is None or not np.any(stribeck) else scale * np.asarray(stribeck, dtype=np.float64)
    inv_vs = np.broadcast_to(1.0 / np.asarray(stribeck_vel, dtype=np.float64), (7,)).copy()
    cv = float(coulomb_vel)
    buf, buf2, buf3 = np.zeros(7), np.zeros(7), np.zeros(7)
    mul, add, tanh = np.multiply, np.add, np.tanh

    def sigmoid_friction_step() -> None:
        mul(b, qvel, out=buf)
        add(buf, c, out=buf)
        tanh(buf, out=buf)
        mul(buf, neg_a, out=qfrc)
        add(qfrc, neg_e, out=qfrc)

    if not (visc.any() or coul.any()) and strb is None:
        return sigmoid_friction_step

    def full_friction_step() -> None:
        sigmoid_friction_step()
        np.divide(qvel, cv, out=buf2)
        tanh(buf2, out=buf2)
        mul(coul, buf2, out=buf2)
        mul(visc, qvel, out=buf)
        add(buf, buf2, out=buf)  # viscous + Coulomb, then subtracted at once
        np.subtract(qfrc, buf, out=qfrc)

    if strb is None:
        return full_friction_step

    def stribeck_friction_step() -> None:
        full_friction_step()
        mul(qvel, inv_vs, out=buf3)
        np.square(buf3, out=buf3)
        np.negative(buf3, out=buf3)
        np.exp(buf3, out=buf3)
        mul(buf3, strb, out=buf3)
        np.divide(qvel, cv, out=buf2)
        tanh(buf2, out=buf2)
        mul(buf3, buf2, out=buf3)
        np.subtract(qfrc, buf3, out=qfrc)

    return stribeck_friction_step


__all__ = ["compile_friction", "coulomb_friction", "gaz_sigmoid", "joint_friction", "make_plant_friction",
           "sigmoid_levels", "sigmoid_tanh_coefficients", "stribeck_friction", "viscous_friction"]
