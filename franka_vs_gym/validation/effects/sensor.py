"""Torque-sensor effects: a constant offset of the measured joint torque."""

from __future__ import annotations

import numpy as np

from franka_vs_gym.validation.effects.base import (
    Effect,
    _joint_coef,
    _tau_max,
)


class TorqueOffset(Effect):
    """Constant bias of the joint torque sensors (per joint).

    Signature: a constant shift of the residual, independent of motion and pose.
    Plausible: abs(total) < 0.2 tau_max Nm (FER torque sensors: offsets of 0.1-1 Nm drift with temperature).
    """

    name, aliases = "torque_offset", ("offset",)
    description = "constant bias of the joint torque sensors"
    signature = "a constant shift of the residual, independent of motion and pose"
    plausible = "abs(total offset) < 0.2 tau_max (Nm)"
    SIZES = np.array([0.6, 0.6, 0.5, 0.5, 0.2, 0.2, 0.1])

    def design(self, ctx, shape):
        return ctx.cached("ones", lambda: np.ones((ctx.n, 7, 1)))

    def problems(self, ctx, fit):
        tot = ctx.config.torque_offset + _joint_coef(fit)[:, 0]
        return {j: f"offset {tot[j]:.3g} Nm exceeds 20% of the torque limit" for j in fit.joints
                if abs(tot[j]) > 0.2 * _tau_max(ctx)[j]}

    def apply(self, config, fit):
        return config.copy(torque_offset=config.torque_offset + _joint_coef(fit)[:, 0])

    def inject(self, plant, rng, magnitude):
        o = self.SIZES * magnitude * rng.uniform(0.7, 1.3, 7) * rng.choice([-1.0, 1.0], 7)
        plant.config = plant.config.copy(torque_offset=plant.config.torque_offset + o)
        return {"offset_Nm": o.tolist()}

    def public(self, fit):
        return {"offset_Nm": np.round(_joint_coef(fit)[:, 0], 6).tolist()}


