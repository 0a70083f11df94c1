"""Vectorised evaluation of a model configuration on a processed log.

``predict_torque(config, data)`` gives the predicted measured torque ``tau_J = B ddq + C dq + g + tau_f(dq) +
offset`` at every sample, shifted by the configuration's delay when it is a measurement lag (the measured torque
lags the motion by ``delay`` seconds: ``tau_pred(t) = tau(t - delay)``; see :func:`delay_channel`).
:class:`ModelEvaluation` also keeps the pieces the effect library needs: the friction parts, the gravity torque per
unit gravity vector ``G`` (so ``g(q) = G @ g0``), and the joint-torque regressor of the last body (for a payload).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from franka_vs_gym.model.config import Friction, ModelConfig
from franka_vs_gym.model.description import FER
from franka_vs_gym.model.franka_model import build_pinocchio_model
from franka_vs_gym.model.friction import gaz_sigmoid, joint_friction
from franka_vs_gym.validation.signals import ProcessedLog

FLANGE_OFFSET = np.array([0.0, 0.0, FER.flange_d])  # flange origin in the joint-7 frame (same axes), m


def sigmoid_friction(fr: Friction, dq: np.ndarray) -> np.ndarray:
    """Gaz sigmoid part of the friction, (N, 7) Nm, for dq (N, 7) rad/s."""
    return gaz_sigmoid(dq, fr.phi1, fr.phi2, fr.phi3)


def friction_torque(fr: Friction, dq: np.ndarray) -> np.ndarray:
    """Full friction law of ``Friction`` (sigmoid + viscous + Coulomb + Stribeck), vectorised: (N, 7) Nm."""
    return joint_friction(dq, fr.phi1, fr.phi2, fr.phi3, fr.viscous, fr.coulomb, fr.coulomb_vel, fr.stribeck,
                          fr.stribeck_vel)


def delay_channel(config: ModelConfig) -> str:
    """How a configuration's ``delay`` acts (``ModelConfig.delay_channel``): ``"measurement"`` (the measured torque
    lags the motion) or ``"command"`` (torque commands reach the joints late; the measured torque then matches the
    motion). FrankaSim's plant implements both."""
    return config.delay_channel


def shift(x: np.ndarray, time: np.ndarray, delay: float) -> np.ndarray:
    """x(t - delay) on the same time grid (linear interpolation; held at the first value before the start)."""
    if delay == 0:
        return x
    out = np.empty_like(x)
    for j in range(x.shape[1]):
        out[:, j] = np.interp(time - delay, time, x[:, j])
    return out


@dataclass
class ModelEvaluation:
    """A configuration evaluated on every sample of a processed log (all arrays (N, 7) Nm unless said).

    rigid: B ddq + C dq + g (armature included); friction: tau_f(dq); offset: (7,); predicted: the delayed sum;
    gravity: g(q); G: (N, 7, 3) gravity torque per unit gravity component (base frame); Y_last: (N, 7, 10) joint
    torque regressor of the last body (pinocchio dynamic parameters in the joint-7 frame: m, m c, inertia about the
    joint-7 origin as Ixx, Ixy, Iyy, Ixz, Iyz, Izz); Y: (N, 7, 70) the full joint-torque regressor (10 parameters per
link, links 1..7 in order), or None when not requested.
    """

    config: ModelConfig
    rigid: np.ndarray
    friction: np.ndarray
    offset: np.ndarray
    predicted: np.ndarray
    gravity: np.ndarray
    G: np.ndarray | None
    Y: np.ndarray | None

    @property
    def Y_last(self) -> np.ndarray | None:
        """(N, 7, 10) joint-torque regressor of the last body (a payload's parameters)."""
        return None if self.Y is None else self.Y[:, :, 60:70]


def evaluate(config: ModelConfig, data: ProcessedLog, regressors: bool = False) -> ModelEvaluation:
    """Evaluate ``config`` on ``data``. ``regressors`` also computes G and the last-body regressor (slower)."""
    model, _, _ = build_pinocchio_model(config)
    d = model.createData()
    q, dq, ddq = data.q, data.dq, data.ddq
    n = len(q)
    rigid = np.empty((n, 7))
    grav = np.empty((n, 7))
    rnea, ggrav = pin.rnea, pin.computeGeneralizedGravity
    G = Y = None
    if regressors:
        Y = np.empty((n, 7, 70))
        reg = pin.computeJointTorqueRegressor
        for k in range(n):
            Y[k] = reg(model, d, q[k], dq[k], ddq[k])
        # the gravity torque per unit gravity along x, y, z: one axis at a time (not three gravity changes per sample)
        gm, _, _ = build_pinocchio_model(config)
        gd = gm.createData()
        G3 = np.empty((3, n, 7))
        for c in range(3):
            gm.gravity.linear = np.eye(3)[c]
            out = G3[c]
            for k in range(n):
                out[k] = ggrav(gm, gd, q[k])
        G = np.ascontiguousarray(G3.transpose(1, 2, 0))
        # what rnea gives: the regressor times the links' dynamic parameters, plus the armature's B ddq (to 1e-14)
        pi = np.concatenate([model.inertias[i].toDynamicParameters() for i in range(1, model.njoints)])
        rigid = Y @ pi + ddq * np.asarray(model.armature)[None, :]
        grav = np.einsum("nic,c->ni", G, config.gravity)
    else:
        for k in range(n):
            rigid[k] = rnea(model, d, q[k], dq[k], ddq[k])
            grav[k] = ggrav(model, d, q[k])
    # pinocchio's rnea includes the joint armature (model.armature) in B ddq
    fr = friction_torque(config.friction, dq)
    total = rigid + fr + config.torque_offset
    pred = shift(total, data.time, config.delay) if delay_channel(config) == "measurement" else total
    return ModelEvaluation(config, rigid, fr, config.torque_offset.copy(), pred, grav, G, Y)


def predict_torque(config: ModelConfig, data: ProcessedLog) -> np.ndarray:
    """Predicted measured joint torque (N, 7) Nm of ``config`` on the samples of ``data``."""
    return evaluate(config, data).predicted


__all__ = ["delay_channel", "ModelEvaluation", "evaluate", "friction_torque", "predict_torque", "shift",
           "sigmoid_friction", "FLANGE_OFFSET"]
