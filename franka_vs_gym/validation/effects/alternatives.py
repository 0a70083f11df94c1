"""Effects the selection tries as alternatives, not library effects (neither registered nor injectable): torque-
sensor crosstalk (what the ambiguity check fits in a friction law's place), the magnitude part of a gravity change
(what a ``gravity_tilt`` is judged against) and the delay with the exact shift of the model's torque as its design;
and the laws a log may not tell apart on a joint, with the motion that separates them."""

from __future__ import annotations

import numpy as np

from franka_vs_gym.validation.effects.base import Effect
from franka_vs_gym.validation.effects.timing import Delay
from franka_vs_gym.validation.evaluate import shift

# laws a log may not tell apart on a joint, and the motion that separates them
CONFUSABLE = {
    "torque_offset": [("asymmetric_friction", "the joint at rest for a few seconds at two or three poses, and slow "
                                              "motions in both directions (an offset stays at rest, friction "
                                              "vanishes)")],
    "asymmetric_friction": [("torque_offset", "the joint at rest for a few seconds at two or three poses, and slow "
                                              "motions in both directions (an offset stays at rest, friction "
                                              "vanishes)")],
    "viscous_friction": [("coulomb_friction", "the joint at three or more constant speeds (e.g. 0.1, 0.5 and 1 "
                                              "rad/s) in both directions (viscous friction grows with speed, a "
                                              "Coulomb step does not)")],
    "coulomb_friction": [("viscous_friction", "the joint at three or more constant speeds (e.g. 0.1, 0.5 and 1 "
                                              "rad/s) in both directions (viscous friction grows with speed, a "
                                              "Coulomb step does not)")],
    "sigmoid_friction": [("viscous_friction", "the joint at three or more constant speeds (e.g. 0.1, 0.5 and 1 "
                                              "rad/s) in both directions (viscous friction grows with speed, a "
                                              "step law does not)")],
}
CROSSTALK_SEPARATE = ("the joint held still while the joints before it move through large torque changes (torque-"
                      "sensor crosstalk follows the other joint's torque, friction needs the joint's own motion)")
FRICTION_NAMES = ("viscous_friction", "coulomb_friction", "sigmoid_friction", "asymmetric_friction",
                  "stribeck_friction")


class _Crosstalk(Effect):
    """Torque-sensor crosstalk (internal: an alternative the ambiguity check tries, not a library effect): joint j's
    sensor also measures a fraction of the torque of another joint i (the model's torque of the i whose torque
    follows the target most closely, chosen per joint)."""

    name = "torque_crosstalk"
    n_params = 2
    injectable = False

    def shape(self, ctx, target):
        P = ctx.ev.predicted[ctx.coarse]
        P = P - P.mean(axis=0)
        T = target[ctx.coarse] - target[ctx.coarse].mean(axis=0)
        c = np.abs(np.einsum("ni,nj->ij", P, T)) / np.sqrt(np.outer(np.einsum("ni,ni->i", P, P),
                                                                       np.einsum("nj,nj->j", T, T)) + 1e-30)
        np.fill_diagonal(c, -1.0)
        return {"from": np.argmax(c, axis=0).astype(float)}

    def design(self, ctx, shape):
        src = np.asarray(shape["from"], dtype=int)
        return ctx.ev.predicted[:, src][:, :, None]


CROSSTALK = _Crosstalk()


class _GravityMagnitude(Effect):
    """The part of a change of the gravity vector along it (internal: what a ``gravity_tilt`` is judged against).
    A tilt of the mounting rotates gravity: to first order it changes the gravity vector perpendicular to it, and
    only that horizontal part (2 of the law's 3 parameters) is a tilt; the part along it is second order (0.14 % of
    g at 3 degrees). A change of the magnitude is not a tilt: Earth's gravity lies within 9.780-9.832 m/s^2 from
    equator to pole (normal gravity of the Geodetic Reference System 1980; Moritz 2000, J. Geodesy 74: 128-133),
    0.3 % either side of the model's 9.81, and to the joint torques a change of it scales every body's first mass
    moment: it is a mass error of the bodies the model has (a payload's, the links')."""

    name = "gravity_magnitude"
    per_joint = False
    n_params = 1
    injectable = False

    def design(self, ctx, shape):
        g0 = np.asarray(ctx.config.gravity, dtype=np.float64)
        return (ctx.ev.G @ (g0 / max(float(np.linalg.norm(g0)), 1e-12)))[:, :, None]


GRAVITY_MAGNITUDE = _GravityMagnitude()


class _ShiftedDelay(Delay):
    """``delay`` with the exact shift of the model's torque as its design, at a delay ``d0`` (the library's law is
    first order, ``-d x d(predicted torque)/dt``): the column ``(tau_model(t - d0) - tau_model(t)) / d0``, whose
    coefficient is the delay when it is near ``d0``. The first-order law leaves ``d^2/2`` times the torque's second
    derivative, systematic at tens of milliseconds: on a recording served with a 60 ms delay it was 0.035-0.056 Nm
    on joints 0-2 (noise 0.10 Nm), and the link inertials took it at 1 kHz."""

    def __init__(self, d0: float) -> None:
        self.d0 = float(d0)

    def shape_key(self, shape):
        return (("d0", round(self.d0, 12)),)

    def design(self, ctx, shape):
        pred = ctx.ev.predicted
        return ((shift(pred, ctx.data.time, self.d0) - pred) / self.d0)[:, :, None]



__all__ = ["CONFUSABLE", "CROSSTALK", "CROSSTALK_SEPARATE", "FRICTION_NAMES", "GRAVITY_MAGNITUDE"]
