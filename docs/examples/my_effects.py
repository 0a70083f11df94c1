"""An example effect plug-in for ``franka-vs diagnose LOG --effects docs/examples/my_effects.py``.

``tool_mass_error``: the declared tool is right in shape but its mass is off (a gripper with different fingers, a
camera bracket left out of the sidecar). One parameter: the relative mass error s; the tool's mass, first moments
and inertia all scale by (1 + s), its centre of mass stays.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from franka_vs_gym.model.config import RigidBody, Tool
from franka_vs_gym.validation.effects import Effect
from franka_vs_gym.validation.evaluate import FLANGE_OFFSET


class ToolMassError(Effect):
    """The declared tool's mass is wrong by a factor (1 + s); centre of mass kept.

    Signature: the declared tool's own gravity and inertial torques, scaled: pose-dependent on joints 1-6.
    Plausible: -0.5 <= s <= 1 (a tool cannot lose more than half or double its declared mass unnoticed).
    """

    name = "tool_mass_error"
    per_joint = False  # one parameter shared by all joints
    n_params = 1
    description = "the declared tool's mass is off by a factor"
    signature = "the declared tool's gravity and inertial torques, scaled"
    plausible = "-0.5 <= s <= 1"

    def design(self, ctx, shape):
        """(N, 7, 1): the torque the declared tool produces, i.e. the last-body regressor times its parameters."""
        body = ctx.config.tool.body
        if body.mass <= 0:
            return np.zeros((ctx.n, 7, 1))
        # the tool's dynamic parameters in the joint-7 frame (the flange is a pure translation along z)
        pi = pin.Inertia(body.mass, np.asarray(body.com) + FLANGE_OFFSET, np.asarray(body.inertia))
        return (ctx.ev.Y_last @ pi.toDynamicParameters())[:, :, None]

    def problems(self, ctx, fit):
        s = float(self.coef(fit)[0])
        if ctx.config.tool.body.mass <= 0:
            return {-1: "the model declares no tool"}
        if not -0.5 <= s <= 1.0:
            return {-1: f"tool mass factor {1 + s:.3g} outside [0.5, 2]"}
        return {}

    def apply(self, config, fit):
        s = 1.0 + float(self.coef(fit)[0])
        b = config.tool.body
        tool = Tool("custom", config.tool.flMe, RigidBody(b.mass * s, b.com, b.inertia * s))
        return config.copy(tool=tool)

    def inject(self, plant, rng, magnitude):
        # the plant carries a heavier tool than the controller's model believes: an undeclared payload at the
        # tool's centre of mass with the extra mass
        s = 0.4 * magnitude * rng.uniform(0.7, 1.3)
        b = plant.config.tool.body
        plant.payload = RigidBody(b.mass * s, b.com, b.inertia * s)
        return {"mass_factor": 1 + s}

    def public(self, fit):
        return {"mass_factor": round(1.0 + float(self.coef(fit)[0]), 6)}
