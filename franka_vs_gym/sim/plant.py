"""The plant's joint friction and measured-state reflexes inside MuJoCo's step.

The simulated FER's friction (the law of :class:`franka_vs_gym.model.config.Friction`) is a C passive-force
callback (``franka_vs_gym/sim/_plant.c``, compiled at install) that MuJoCo runs inside every ``mj_step``, so an
environment step's substeps are one call into MuJoCo and ``mujoco.batch`` can step many robots on its threads.

MuJoCo's callbacks are global to a process, so the parameters live in each model: every joint of a robot carries
its friction parameters in its user numbers (``jnt_user``, :data:`NUSER` per joint, the scene declares
``<size nuser_jnt="26"/>``; columns 0-8 (:data:`FRICTION_COLS` of them) the friction law, 9-16 (from
:data:`RCOL`) the reflexes', 17-25 (from :data:`LCOL`) the rate limiter's limits; a scene with joint effects
declares :data:`ENUSER` (38) and columns 26-37 (from :data:`ECOL`) hold them, see :func:`effect_rows`):

====  =====================  =========
 col   meaning                 unit
====  =====================  =========
 0     :data:`TAG` when the plant applies friction at this joint, else 0
 1     phi1                    Nm
 2     phi2                    s/rad
 3     phi3                    rad/s
 4     viscous                 Nm s/rad
 5     coulomb                 Nm
 6     coulomb_vel             rad/s
 7     stribeck                Nm
 8     stribeck_vel            rad/s
====  =====================  =========

(the law of :mod:`franka_vs_gym.model.friction`; the Stribeck term, columns 7-8, is skipped at no cost when
``stribeck`` is 0). The same callback runs the measured-state reflexes (:mod:`franka_vs_gym.sim.reflexes`: joint
position, velocity and tau_J range) at every physics step; a watched robot's joints carry its limits:

====  =====================  =========
 col   meaning                 unit
====  =====================  =========
 9     :data:`RTAG` when the plant checks this robot's reflexes, else 0
 10    offset of the robot's record in ``mjData.userdata``
 11    joint index in the robot (0..6)
 12    q_min                   rad
 13    q_max                   rad
 14    dq_max                  rad/s
 15    tau_max                 Nm
 16    tau_J offset            Nm
====  =====================  =========

and each robot has a record of :data:`RSLOT` numbers in ``mjData.userdata`` (the scene declares
``<size nuserdata="66 x robots"/>``; it is part of MuJoCo's integration state, so ``mj_getState``/``mujoco.batch``
carry it): status (-1 armed, 0 off, 1/2/3 the first violation: position, velocity, tau_J), the time after which
states are checked (s), whether tau_J is checked, then the violation's time (s), joint, value, and the held joint
positions (7, rad). From the violating step on the callback holds the robot (joints put back at the held position
with zero velocity, its joint actuators' controls zeroed, at every step); Python reads the record after the call.

From number :data:`L0` of the record on, the robot interface's rate limiter (``command_rates="limit"``,
:mod:`franka_vs_gym.sim.rate_limit`) keeps its state: mode (0 off, 1 torque, 2 joint velocity), the first motor and
velocity-servo actuator, the time of its last cycle, the target command, and the last command, acceleration and
commanded position before and after that cycle; the callback runs one limiter cycle per physics step and writes the
limited command into the controls, so a rate-limited control period stays one ``mj_step(m, d, n)`` call.

Two robots in one scene, the dual-arm scene, or a batch of robots with randomised friction (one model each, see
``mujoco.batch.Batch.set_models``) each get their own law. Joints of other models never carry the tag, so the
callback leaves them alone.

Without the compiled extension (no C compiler at install, a MuJoCo whose headers differ from the build's, or
``FRANKA_VS_GYM_PURE_PYTHON=1``) :data:`NATIVE` is False and FrankaSim applies the same law from Python before
every physics step (into ``qfrc_applied``): the same physics, slower, and no batched vector environments.
"""

from __future__ import annotations

import ctypes
import os
import warnings
from typing import Any

import mujoco
import numpy as np

NUSER = 26  # user numbers per joint
FRICTION_COLS = 9  # columns 0-8: the friction law
RCOL = FRICTION_COLS  # columns RCOL..RCOL+7 (9-16): the reflexes
LCOL = 17  # columns LCOL..LCOL+8 (17-25): the rate limiter's limits (RateLimits.plant_columns)
TAG = 1179013959.0  # jnt_user[:, 0] of a joint whose friction the plant applies
RTAG = 1179013960.0  # jnt_user[:, RCOL] of a joint whose robot's reflexes the plant checks
RSLOT = 66  # userdata numbers per robot (its reflex record, then its rate limiter's state from L0)
L0 = 13  # the rate limiter's part of a robot's record (see _plant.c)
ECOL = 26  # columns ECOL..ENUSER-1 (26-39): the joint effects (cogging, static friction, elastic transmission)
ETAG = 1179013961.0  # jnt_user[:, ECOL] of a joint with joint effects
ENUSER = 40  # user numbers per joint of a scene with joint effects (the scene declares nuser_jnt="40" then)
MREC = 12  # userdata numbers of an elastic or sticking joint's record (after the robots' records)
TASK_REC = 36  # numbers in a truth record of the visual tasks' kernels (franka_vs_gym/sim/_task.c)
TASK_P_FIXED = 307  # numbers of a visual env's step plan before its observation work vectors (_task.c)
TASK_I_SIZE = 29  # integers of a visual env's step plan (_task.c)

_native: Any = None
_reason: str | None = None
if os.environ.get("FRANKA_VS_GYM_PURE_PYTHON", "") not in ("", "0"):
    _reason = "FRANKA_VS_GYM_PURE_PYTHON is set"
else:
    import importlib.util

    if importlib.util.find_spec("franka_vs_gym.sim._plant") is None:
        _reason = ("the compiled plant (franka_vs_gym.sim._plant) was not built (no C compiler at install?); "
                   "reinstall with one (pip install -e .) for the fast plant and batched environments")
    else:
        try:
            from franka_vs_gym.sim import _plant as _native
        except ImportError as e:
            _reason = f"the compiled plant (franka_vs_gym.sim._plant) does not load: {e}; reinstall (pip install -e .)"
    if _native is not None:
        if _native.MJ_VERSION_HEADER != mujoco.mj_version():
            _reason = (f"the compiled plant was built against MuJoCo {_native.MJ_VERSION_HEADER} but MuJoCo "
                       f"{mujoco.mj_version()} is installed; reinstall franka_vs_gym (pip install -e .)")
            _native = None
        elif _native.TAG != TAG or _native.NUSER != NUSER or getattr(_native, "RTAG", None) != RTAG \
                or getattr(_native, "RSLOT", None) != RSLOT or getattr(_native, "RCOL", None) != RCOL \
                or getattr(_native, "LCOL", None) != LCOL or getattr(_native, "L0", None) != L0 \
                or getattr(_native, "ECOL", None) != ECOL or getattr(_native, "ETAG", None) != ETAG \
                or getattr(_native, "ENUSER", None) != ENUSER or getattr(_native, "MREC", None) != MREC \
                or getattr(_native, "TASK_REC", None) != TASK_REC \
                or getattr(_native, "TASK_P_FIXED", None) != TASK_P_FIXED or not hasattr(_native, "tracking_post"):
            _reason = ("the compiled plant is older than its sources (franka_vs_gym/sim/_plant.c); rebuild it "
                       "(pip install -e . or python setup.py build_ext --inplace)")
            _native = None

NATIVE: bool = _native is not None
_CB_TYPE = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)
_callback = _CB_TYPE(_native.callback_address()) if NATIVE else None
#: ``check(model._address, data._address, first_joint)``: the plant's reflex check on the current state (0: the
#: robot is not armed, 1: a violation is recorded, 2: within its limits; the state is then marked checked).
check = _native.check if NATIVE else None
#: The visual tasks' compiled kernels (``franka_vs_gym/sim/_task.c``; None without the compiled extension):
#: ``tag_truth(geo, q, fMo, out)``, ``torque_cost(tau, tau_max, cost, out)`` and the two halves of a visual
#: environment's step around its physics, ``visual_pre`` and ``visual_post`` (see franka_vs_gym.envs.visual).
tag_truth = _native.tag_truth if NATIVE else None
torque_cost = _native.torque_cost if NATIVE else None
visual_pre = _native.visual_pre if NATIVE else None
visual_post = _native.visual_post if NATIVE else None
#: FrankaTorqueTracking-v0's kernels: ``tracking(q0, A, w, t, q, desired, err)`` (desired trajectory and tracking
#: error of n robots) and ``tracking_batch(...)`` (a step's end for the batched vector env).
tracking = _native.tracking if NATIVE else None
tracking_batch = _native.tracking_batch if NATIVE else None
#: ``tracking_post(P, I, model_address, data_address, out)``: a torque-action FrankaTorqueTracking-v0 env's step after
#: its physics (see franka_vs_gym.envs.compiled).
tracking_post = _native.tracking_post if NATIVE else None


def unavailable_reason() -> str | None:
    """Why the compiled plant is not used (None when it is)."""
    return _reason


def _installed() -> bool:
    cur = mujoco.get_mjcb_passive()
    return cur is not None and NATIVE and ctypes.cast(cur, ctypes.c_void_p).value == _native.callback_address()


def install() -> bool:
    """Make sure MuJoCo runs the plant's C callback (``mjcb_passive``); returns whether it does.

    Idempotent. Returns False (the caller then applies friction from Python) when the extension is unavailable or
    another passive callback is already installed in this process (it is kept: callbacks are global)."""
    global _reason
    if not NATIVE:
        return False
    cur = mujoco.get_mjcb_passive()
    if cur is None:
        mujoco.set_mjcb_passive(_callback)
        return True
    if _installed():
        return True
    if _reason is None:
        _reason = "another mjcb_passive callback is installed in this process"
        warnings.warn(f"franka_vs_gym: pure-Python plant friction (slower): {_reason}", RuntimeWarning,
                      stacklevel=2)
    return False


def friction_rows(friction: Any, scale: float = 1.0, enabled: bool = True) -> np.ndarray:
    """The (7, FRICTION_COLS) ``jnt_user`` columns 0-8 of a robot's seven joints for a friction law (``Friction``:
    phi1, phi2, phi3, viscous, coulomb (7,) each, coulomb_vel, stribeck, stribeck_vel (7,) each) multiplied by
    ``scale`` (phi1, viscous, Coulomb and Stribeck heights scaled, which scales the whole torque). ``enabled=False``
    (or a zero law) clears the tag."""
    rows = np.zeros((7, FRICTION_COLS))
    on = enabled and not friction.is_zero()
    rows[:, 0] = TAG if on else 0.0
    rows[:, 1] = friction.phi1 * scale
    rows[:, 2] = friction.phi2
    rows[:, 3] = friction.phi3
    rows[:, 4] = friction.viscous * scale
    rows[:, 5] = friction.coulomb * scale
    rows[:, 6] = friction.coulomb_vel
    rows[:, 7] = friction.stribeck * scale
    rows[:, 8] = friction.stribeck_vel
    return rows


def effect_rows(fx: Any, motor_inertia: Any, record_offsets: Any, motor_actuators: Any, link_inertia: Any,
                dt: float) -> np.ndarray:
    """The (7, ENUSER - ECOL) ``jnt_user`` columns 26-39 of a robot's seven joints for its joint effects ``fx``
    (:class:`franka_vs_gym.model.joint_effects.JointEffects`): tag, cogging A (Nm), n (cycles per link turn),
    phase (rad), breakaway (Nm), stick velocity (rad/s), K (Nm/rad), D (Nm s/rad), motor inertia B (kg m^2),
    backlash half-gap (rad), the joint record's offset in userdata (-1 without one), the joint's torque motor
    (actuator id), and the static friction's stick stiffness k_s and damping c: a mode of ``0.2 / dt``,
    critically damped, on ``link_inertia`` (7,) kg m^2 (the smallest inertia the joint shows, ``1 / (M^-1)_jj``,
    so that the explicit spring stays stable). A joint without any effect gets a zero row (no tag)."""
    rows = np.zeros((7, ENUSER - ECOL))
    el = fx.elastic
    on = (fx.cogging_Nm > 0) | (fx.breakaway_Nm > 0) | el
    rows[:, 0] = np.where(on, ETAG, 0.0)
    rows[:, 1] = fx.cogging_Nm
    rows[:, 2] = fx.cogging_cycles_per_turn
    rows[:, 3] = fx.cogging_phase_rad
    rows[:, 4] = fx.breakaway_Nm
    rows[:, 5] = fx.stick_vel
    rows[:, 6] = np.where(el, fx.stiffness_Nm_per_rad, 0.0)
    rows[:, 7] = fx.damping_Nms_per_rad
    rows[:, 8] = np.where(el, motor_inertia, 0.0)
    rows[:, 9] = fx.backlash_rad / 2
    rows[:, 10] = np.where(fx.stateful, record_offsets, -1.0)
    rows[:, 11] = motor_actuators
    w = 0.2 / dt
    rows[:, 12] = np.where(fx.breakaway_Nm > 0, w * w * np.asarray(link_inertia), 0.0)
    rows[:, 13] = np.where(fx.breakaway_Nm > 0, 2 * w * np.asarray(link_inertia), 0.0)  # critically damped
    rows[~on] = 0.0
    return rows


def plant_friction_torque(model: mujoco.MjModel, data: mujoco.MjData, dofs: Any) -> np.ndarray:
    """The friction torque tau_f (Nm, (len(dofs),)) MuJoCo's callback applies at the data's velocities: the
    passive force with the callback minus without, both from ``mj_forward`` on a copy of the data."""
    d = mujoco.MjData(model)
    mujoco.mj_copyData(d, model, data)
    mujoco.mj_forward(model, d)
    with_cb = d.qfrc_passive.copy()
    prev = mujoco.get_mjcb_passive()
    mujoco.set_mjcb_passive(None)
    try:
        mujoco.mj_forward(model, d)
    finally:
        mujoco.set_mjcb_passive(prev)
    return -(with_cb - d.qfrc_passive)[np.asarray(dofs)]


__all__ = ["check", "ECOL", "effect_rows", "ENUSER", "ETAG", "FRICTION_COLS", "friction_rows", "install", "L0", "LCOL",
           "MREC", "NATIVE", "NUSER", "plant_friction_torque", "RCOL", "RSLOT", "RTAG", "TAG", "tag_truth",
           "TASK_I_SIZE", "TASK_P_FIXED", "TASK_REC", "torque_cost", "tracking", "tracking_batch", "tracking_post",
           "unavailable_reason", "visual_post", "visual_pre"]
