"""Timing effects: a delay of the measured torque, or of the command, against the motion."""

from __future__ import annotations

import numpy as np

from franka_vs_gym.validation.effects.base import (
    MAX_DELAY,
    MIN_DELAY,
    Effect,
    Fit,
)
from franka_vs_gym.validation.evaluate import shift


class Delay(Effect):
    """The measured torque lags the measured motion by a constant time d (s).

    Signature: residual ~ -d x time derivative of the predicted torque, largest where torque changes fast.
    Plausible: MIN_DELAY (1.5 ms, one and a half ticks of the FER's 1 kHz control cycle) <= d <= 0.1 s. The bound
    does not scale with the log's sample period: the fields of one row (a libfranka state packet, a ROS JointState
    message) are sampled together and the cleaning treats them alike (same interpolation, zero-phase filters), so
    a lag shorter than a low-rate log's period still shows as ``-d dtau/dt`` and the selection's held-out evidence,
    not the sample period, decides whether it is seen.
    """

    name = "delay"
    per_joint = False
    n_params = 1
    description = "the measured torque lags the measured motion by a constant time (s)"
    signature = "residual ~ -delay x time derivative of the predicted torque: largest where torque changes fast"
    plausible = "1.5 ms <= d <= 0.1 s"
    channel = "measurement"

    def lof_drivers(self, ctx):
        return {"d(predicted torque)/dt": ctx.dpred}

    def design(self, ctx, shape):
        return -ctx.dpred[:, :, None]

    def refine(self, ctx, y, fit):
        d0 = float(self.coef(fit)[0])
        if d0 <= 0:
            return fit
        target = y + ctx.ev.predicted
        t = ctx.data.time
        best, best_sse = d0, np.inf
        for d in np.linspace(0.5 * d0, 1.5 * d0, 21):
            sse = float(np.sum((target - shift(ctx.ev.predicted, t, d)) ** 2))
            if sse < best_sse:
                best, best_sse = d, sse
        return Fit(self.name, {"coef": np.array([best])}, fit.joints)

    def problems(self, ctx, fit):
        d = float(self.coef(fit)[0])
        if d < 0:
            return {-1: f"negative delay {d * 1000:.2f} ms (the torque would lead the motion)"}
        if d < MIN_DELAY:
            return {-1: f"delay {d * 1000:.2f} ms is below {MIN_DELAY * 1000:.1f} ms (1.5 ticks of the robot's 1 kHz "
                        "cycle): within the alignment uncertainty of the robot's own signals"}
        if d > MAX_DELAY:
            return {-1: f"delay {d * 1000:.1f} ms exceeds {MAX_DELAY * 1000:.0f} ms"}
        return {}

    def apply(self, config, fit):
        return config.copy(delay=max(0.0, config.delay + float(self.coef(fit)[0])), delay_channel=self.channel)

    def inject(self, plant, rng, magnitude):
        plant.measurement_delay = 0.010 * magnitude * rng.uniform(0.7, 1.3)
        return {"delay_s": plant.measurement_delay}

    def public(self, fit):
        return {"delay_s": round(float(self.coef(fit)[0]), 6), "channel": self.channel}


class CommandDelay(Delay):
    """The ``delay`` effect seen on the command channel: torque commands reach the joints late (as FrankaSim's plant
    applies ``ModelConfig.delay``), so the measured torque lags the *commanded* torque, not the motion. Fitted on
    ``tau_J - g(q) - tau_J_d`` (needs the logged ``tau_J_d``)."""

    description = "torque commands reach the joints late: the measured torque lags the commanded torque"
    signature = "tau_J - g(q) - tau_J_d ~ -delay x d(tau_J_d)/dt"
    channel = "command"

    def design(self, ctx, shape):
        return -ctx.dcmd[:, :, None]

    def refine(self, ctx, y, fit):
        return fit


# ---------------------------------------------------------------------------------------------- registry
