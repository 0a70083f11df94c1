"""Shared base of the franka_vs_gym environments: the plant, action handling, stepping, randomisation, failures.

A task (one small module per task) subclasses :class:`FrankaEnv` and provides the observation space and
observation, the reward, and its success/failure checks. Everything the robot does goes through
:class:`~franka_vs_gym.sim.FrankaSim` (velocity servo, gravity-free torques, limits), so an agent sees exactly the
robot a classical controller written against FrankaSim sees.

Time: one environment step lasts ``control_period`` seconds = ``n_substeps`` physics steps of ``physics_step``
seconds; the action is held constant over the step (zero-order hold, as a real controller running at that rate).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from franka_vs_gym.envs.kernels import clip_observation
from franka_vs_gym.model.config import ModelConfig, RigidBody, resolve_config
from franka_vs_gym.sim import CAMERA_FRAME, FORCE_TORQUE, JOINT_STATE, VELOCITY, FrankaSim, SimulationDiverged
from franka_vs_gym.sim.reflexes import ControlException

ACTION_TYPES = ("torque", "joint_velocity", "cartesian_velocity")
OBSERVATION_TYPES = ("features", "image", "features+image", "state")
# Cartesian camera-twist bounds of the contract: +-0.5 m/s, +-1 rad/s.
CARTESIAN_BOUNDS = np.array([0.5, 0.5, 0.5, 1.0, 1.0, 1.0])
ACTION_SCALES = ("normalized", "physical")
PAYLOAD_COM = (0.0, 0.0, 0.05)  # where a randomised payload is held, flange frame, m


def torque_action_scale(model: Any, acceleration: float, velocity: float) -> np.ndarray:
    """The torque (7,) Nm of a normalized torque action of +1: ``sum_k |M_jk(q_n)| a + |tau_f,j(v)|`` per joint j,
    the torque that gives every joint the acceleration ``a`` (rad/s^2) at once, whatever the signs, at the robot's
    neutral posture q_n (mass matrix of the robot's model ``model``, a FrankaModel, couplings included) on top of
    the model's friction at the velocity ``v`` (rad/s), at most tau_max: the range a torque agent adds to the
    robot's gravity compensation to move the arm at that acceleration and velocity, equally for heavy and light
    joints."""
    lim = model.limits()
    M = model.mass_matrix(model.robot.neutral())
    tau = np.abs(M).sum(axis=1) * float(acceleration) + np.abs(model.friction(np.full(7, float(velocity))))
    return np.minimum(tau, lim["tau_max"])


def default_action_scale(action_type: str, model: Any, torque: tuple[float, float] = (0.5, 0.5)) -> np.ndarray:
    """The physical value of a normalized action of +1 per component, for ``action_type`` on the robot of
    ``model`` (a FrankaModel): joint velocity, half the robot's rated joint velocities (rad/s: 1.09 rad/s on
    joints 1-4 of the FER; the scripted servo laws stay within it); Cartesian velocity, the camera-twist bounds
    (0.5 m/s, 1 rad/s); torque, :func:`torque_action_scale` at ``torque`` = (acceleration rad/s^2, velocity
    rad/s), by default 0.5 rad/s^2 and 0.5 rad/s (a servoing motion: a joint at 0.5 rad/s within a second)."""
    if action_type == "joint_velocity":
        return 0.5 * model.limits()["dq_max"]
    if action_type == "cartesian_velocity":
        return CARTESIAN_BOUNDS.copy()
    if action_type == "torque":
        return torque_action_scale(model, *torque)
    raise ValueError(f"action_type must be one of {ACTION_TYPES}, got {action_type!r}")


def _positive(x: Any, name: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {x!r}") from None
    if not (v > 0 and math.isfinite(v)):
        raise ValueError(f"{name} must be a finite number > 0, got {x!r}")
    return v


def _nonneg(x: Any, name: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {x!r}") from None
    if not (v >= 0 and math.isfinite(v)):
        raise ValueError(f"{name} must be a finite number >= 0, got {x!r}")
    return v


def _range(x: Any, name: str, *, positive: bool = False) -> tuple[float, float] | None:
    """A (low, high) range, a single number (fixed value), or None (feature off)."""
    if x is None:
        return None
    a = np.atleast_1d(np.asarray(x, dtype=np.float64))
    if a.shape == (1,):
        a = np.array([a[0], a[0]])
    if a.shape != (2,) or not np.isfinite(a).all() or a[0] > a[1]:
        raise ValueError(f"{name} must be a number or a (low, high) pair with low <= high, got {x!r}")
    if positive and a[0] <= 0:
        raise ValueError(f"{name} must be > 0, got {x!r}")
    return float(a[0]), float(a[1])


def substeps(control_period: float, physics_step: float) -> int:
    """Number of physics steps per control period; the period must be a whole multiple of the physics step."""
    n = control_period / physics_step
    k = int(round(n))
    if k < 1 or abs(n - k) > 1e-6 * max(1.0, n):
        raise ValueError(f"control_period ({control_period} s) must be a whole multiple of physics_step "
                         f"({physics_step} s)")
    return k


class ObservationPacker:
    """Turns a dict of float arrays into the float32 observation of a Dict of Box spaces, clipped to the bounds,
    with one clip and one cast for all keys (the observation is rebuilt at every step, so this is on the hot path).
    The returned arrays are views of one fresh buffer per call: never shared between two observations."""

    def __init__(self, space: spaces.Dict, skip: tuple[str, ...] = ("image",)) -> None:
        self.keys = [k for k in space.spaces if k not in skip]
        lows, highs = [], []
        self.items: list[tuple[str, slice, tuple[int, ...]]] = []
        i = 0
        for k in self.keys:
            box = space[k]
            n = int(np.prod(box.shape))
            lows.append(np.broadcast_to(box.low, box.shape).ravel().astype(np.float64))
            highs.append(np.broadcast_to(box.high, box.shape).ravel().astype(np.float64))
            self.items.append((k, slice(i, i + n), box.shape))
            i += n
        self.low, self.high = np.concatenate(lows), np.concatenate(highs)
        self._work = np.zeros(i)
        # (key, slice, None for a flat key or its shape), so that the hot path reshapes only where needed
        self._views = [(k, sl, None if len(sh) == 1 else sh) for k, sl, sh in self.items]
        self.last: np.ndarray | None = None  # the flat float32 buffer of the last observation (its keys' base)

        self._slices = {k: sl for k, sl, _ in self.items}

    def __call__(self, raw: dict[str, Any]) -> dict[str, np.ndarray]:
        v = self._work
        for k, sl, _ in self._views:
            v[sl] = raw[k]
        return self.finish()

    def write(self, key: str, value: Any) -> None:
        """Write one key's raw value into the preallocated work vector, where it stays (clipped by the next
        :meth:`finish`) until written again: a task writes only what changed since its last observation."""
        self._work[self._slices[key]] = value

    def finish(self) -> dict[str, np.ndarray]:
        """The observation of the work vector as it stands (every key written at least once): clipped in place
        (clipping a clipped value is the identity, so held keys give the same bits), cast to one fresh float32
        buffer whose views are returned."""
        buf = self.last = clip_observation(self._work, self.low, self.high)
        return {k: buf[sl] if sh is None else buf[sl].reshape(sh) for k, sl, sh in self._views}


class FrankaEnv(gym.Env):
    """Base class: a Franka arm (FrankaSim; the FER unless ``robot`` says otherwise) driven through one of three
    action types.

    Parameters (shared by every task; all are ``gymnasium.make`` keyword arguments)
    ----------
    action_type : "torque" | "joint_velocity" | "cartesian_velocity"
        torque: (7,) Nm, gravity-free (the robot adds g(q), as libfranka), bounds +-tau_max.
        joint_velocity: (7,) rad/s, bounds +-dq_max, executed by the robot's joint velocity servo.
        cartesian_velocity: (6,) twist [v; w] of the camera frame c expressed in c, m/s and rad/s, bounds +-0.5 m/s
        and +-1 rad/s, mapped to joint velocities with the Jacobian pseudo-inverse (FrankaSim CAMERA_FRAME).
    control_period : float, s
        Duration of one environment step (the action is held). Whole multiple of ``physics_step``.
    physics_step : float, s
        MuJoCo time step (1 ms = the FER's 1 kHz loop by default).
    time_limit : float, s
        Episode duration after which the episode is truncated.
    model : ModelConfig, path to a calibrated model file (JSON from ``franka-vs fit``), or None
        The simulated robot (tool, friction, armature, ...). Both the plant and the robot's model use it.
    robot : RobotDescription, a registered name ("fer", "fr3"), or None
        The arm (default the FER); ``gymnasium.make("FrankaIBVS-v0", robot="fr3")``. With ``model`` given, it must
        name the same robot.
    link_mass_range : (low, high) or None
        Domain randomisation: each link's mass and inertia are multiplied by a factor drawn uniformly in this
        range at every reset. The robot's own gravity compensation follows the true masses (as the FER's internal
        model does); the nominal :class:`FrankaModel` used by controllers does not.
    friction_scale_range : (low, high) or None
        Domain randomisation: the plant's joint friction (Gaz sigmoid, viscous and Coulomb terms) is multiplied by a
        factor drawn in this range at every reset.
    payload_mass_range : (low, high) kg or None
        Domain randomisation: a payload (a small 3 cm sphere) of a mass drawn in this range is held 5 cm in front of
        the flange.
    payload_declared : bool
        True (default): the robot knows the payload's weight and compensates it, as after libfranka's ``setLoad``
        (the payload still changes the arm's inertia, unknown to the nominal FrankaModel). False: an undeclared
        payload whose weight is not compensated: it sags under torque control and, since FrankaSim's joint
        velocity servo is proportional, makes velocity commands drift (0.2 kg already defeats classical IBVS).
    joint_noise, velocity_noise : float
        Standard deviation of white noise added to the observed q (rad) and dq (rad/s).
    action_scale : "normalized" (default) | "physical" | number or array of physical units
        "normalized": the action space is ``Box(-1, 1)`` and an action is multiplied by the task's documented scale
        (:meth:`default_action_scale`: per joint, in the units of ``action_type``) before it reaches the robot.
        "physical": the space is in the robot's units, bounds the robot's limits (+-tau_max Nm, +-dq_max rad/s,
        the Cartesian bounds). A number or array: a ``Box(-1, 1)`` space with that scale (within those limits).
        ``env.unwrapped.action_scale`` is the scale in use (None for "physical"); ``to_action(physical)`` and
        ``to_physical(action)`` convert.
    limit_rate : bool
        True (default, as libfranka's ``limit_rate``): every command passes through the robot interface's rate
        limiter (:mod:`franka_vs_gym.sim.rate_limit`, the robot's published velocity, acceleration, jerk and torque
        rate limits, one 1 ms cycle per physics step) before the robot sees it. False: commands reach the robot as
        given (a held command then jumps at each control period, as with libfranka's ``limit_rate=false`` and an
        interpolating controller in between).
    clip_actions : bool
        False (default): an action outside the action space raises ValueError. True: it is clipped to the space.
        NaN or inf always raise ValueError.
    joint_limit_guard : bool
        True (default), joint velocity actions: the robot interface's joint-limit guard bounds, per joint, the
        commanded velocity *towards* a position limit by ``min(sqrt(2 a d), d / (2 T))``, d the distance from the
        measured q to the task's joint-limit bound (the limit less 1 mrad and one control period's travel at the
        action scale, :attr:`guard_margin` more inside), a = half the robot's rated joint acceleration (the rate
        limiter's), T the control period: the velocity from which the joint can still brake before the bound, and
        no more than half the remaining distance per period. Motion away from a limit and every joint far from its
        limits are untouched (the scripted servo laws never meet it). A position-dependent velocity bound of the
        kind the FR3's own interface applies (libfranka's position-based velocity limits): it keeps exploration
        (random or learning) from running the arm into its stops. False: commands as given. Torque and Cartesian
        actions are not guarded.
    render_mode : None | "rgb_array"
        "rgb_array": ``render()`` returns an (render_height, render_width, 3) uint8 image of the scene camera.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}
    #: A task's compiled step (:class:`franka_vs_gym.envs.compiled.CompiledStep`), taken by :meth:`step` when it
    #: covers the configuration and the period; None: every step in Python.
    _plan: Any = None
    supported_action_types: tuple[str, ...] = ACTION_TYPES
    supported_observation_types: tuple[str, ...] = OBSERVATION_TYPES
    terminate_on_success = True

    def __init__(self, *, action_type: str = "joint_velocity", observation_type: str = "features",
                 control_period: float = 0.05, physics_step: float = 0.001, time_limit: float = 6.0,
                 model: Any = None, robot: Any = None, link_mass_range: Any = None, friction_scale_range: Any = None,
                 payload_mass_range: Any = None, payload_declared: bool = True, joint_noise: float = 0.0,
                 velocity_noise: float = 0.0, action_scale: Any = "normalized", limit_rate: bool = True,
                 clip_actions: bool = False, render_mode: str | None = None, render_width: int = 320,
                 render_height: int = 240, camera: bool = True, tags: list | None = None,
                 failure_penalty: float = 1.0, cameras: list | None = None,
                 joint_limit_guard: bool = True) -> None:
        super().__init__()
        if action_type not in self.supported_action_types:
            raise ValueError(f"action_type must be one of {self.supported_action_types} for {type(self).__name__}, "
                             f"got {action_type!r}")
        if observation_type not in self.supported_observation_types:
            raise ValueError(f"observation_type must be one of {self.supported_observation_types} for "
                             f"{type(self).__name__}, got {observation_type!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.action_type, self.observation_type, self.render_mode = action_type, observation_type, render_mode
        self.physics_step = _positive(physics_step, "physics_step")
        self.control_period = _positive(control_period, "control_period")
        self.n_substeps = substeps(self.control_period, self.physics_step)
        self.time_limit = _positive(time_limit, "time_limit")
        self.max_steps = max(1, int(math.ceil(self.time_limit / self.control_period - 1e-9)))
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / self.control_period)))
        self.joint_noise = _nonneg(joint_noise, "joint_noise")
        self.velocity_noise = _nonneg(velocity_noise, "velocity_noise")
        self.failure_penalty = _nonneg(failure_penalty, "failure_penalty")
        self.link_mass_range = _range(link_mass_range, "link_mass_range", positive=True)
        self.friction_scale_range = _range(friction_scale_range, "friction_scale_range")
        if self.friction_scale_range is not None and self.friction_scale_range[0] < 0:
            raise ValueError(f"friction_scale_range must be >= 0, got {friction_scale_range!r}")
        self.payload_mass_range = _range(payload_mass_range, "payload_mass_range")
        if self.payload_mass_range is not None and self.payload_mass_range[0] < 0:
            raise ValueError(f"payload_mass_range must be >= 0 kg, got {payload_mass_range!r}")
        self.clip_actions = bool(clip_actions)
        self.render_width, self.render_height = int(render_width), int(render_height)
        if self.render_width < 1 or self.render_height < 1:
            raise ValueError(f"render size must be >= 1 pixel, got {render_width}x{render_height}")
        self.config: ModelConfig = resolve_config(model, robot)
        self.payload_declared = bool(payload_declared)
        if not isinstance(limit_rate, (bool, np.bool_)):
            raise ValueError(f"limit_rate must be True or False, got {limit_rate!r}")
        self.limit_rate = bool(limit_rate)
        payload = (RigidBody(1.0, PAYLOAD_COM, np.full(3, 0.4 * 0.03**2))
                   if self.payload_mass_range is not None and not self.payload_declared else None)
        self.sim = FrankaSim(self.config, camera=camera, tags=tags, timestep=self.physics_step,
                             undeclared_payload=payload, command_rates="limit" if self.limit_rate else "pass",
                             cameras=cameras)
        self.robot = self.sim  # the FrankaSim (vpRobotFranka-style API): env.unwrapped.robot.model is its FrankaModel
        self.world = self.sim.world
        self._m, self._d = self.world.model, self.world.data
        limits = self.sim.model.limits()
        self.q_min, self.q_max = limits["q_min"], limits["q_max"]
        self.dq_max, self.tau_max = limits["dq_max"], limits["tau_max"]
        if action_type == "torque":
            hi = self.tau_max
        elif action_type == "joint_velocity":
            hi = self.dq_max
        else:
            hi = CARTESIAN_BOUNDS
        #: the physical bounds of the action type (the robot's limits)
        self.physical_action_bounds = hi.astype(np.float64)
        self.action_scale: np.ndarray | None = self._resolve_action_scale(action_scale, hi)
        # a joint within 1 mrad of its limit has hit the hard stop; with joint-velocity actions in the normalized space
        # the task's joint-limit condition also keeps one control period's travel at the action scale from the limit,
        # so an episode ends on that condition before the robot's own position reflex could stop it mid-period
        margin = np.full(self.q_min.shape, 1e-3)
        if action_type == "joint_velocity" and self.action_scale is not None:
            margin = margin + self.action_scale * self.control_period
        self._q_lo_fail, self._q_hi_fail = self.q_min + margin, self.q_max - margin
        if self.action_scale is None:
            self.action_space = spaces.Box(-hi.astype(np.float32), hi.astype(np.float32), dtype=np.float32)
        else:
            self.action_space = spaces.Box(-1.0, 1.0, hi.shape, dtype=np.float32)
        self._act_lo = self.action_space.low.astype(np.float64)
        self._act_hi = self.action_space.high.astype(np.float64)
        self._act_tol = 1e-6 * np.maximum(1.0, self._act_hi)
        self._act_lo_tol, self._act_hi_tol = self._act_lo - self._act_tol, self._act_hi + self._act_tol
        self._act_shape = self.action_space.shape
        self._act_symmetric = bool(np.array_equal(-self._act_lo_tol, self._act_hi_tol))
        if not isinstance(joint_limit_guard, (bool, np.bool_)):
            raise ValueError(f"joint_limit_guard must be True or False, got {joint_limit_guard!r}")
        self.joint_limit_guard = bool(joint_limit_guard) and action_type == "joint_velocity"
        if self.joint_limit_guard:
            # the guard's bounds and constants, in action units (the physical velocity divided by the action scale)
            self._guard_lo, self._guard_hi = self._q_lo_fail + self.guard_margin, self._q_hi_fail - self.guard_margin
            unit = np.ones(7) if self.action_scale is None else self.action_scale
            self._guard_2a = (2.0 * 0.5 * limits["ddq_max"]) / unit**2  # sqrt(2 a d) / unit = sqrt(2 a / unit^2 d)
            self._guard_rate = 1.0 / (2.0 * self.control_period * unit)
            # where the guard bounds lie beyond the action space (|a| <= 1 in action units: nothing to bound)
            free = np.maximum(1.0 / self._guard_2a, 1.0 / self._guard_rate) * float(np.max(self._act_hi))
            self._guard_free_mid = 0.5 * (self._guard_lo + self._guard_hi)
            self._guard_free_half = 0.5 * (self._guard_hi - self._guard_lo) - free
        self._arm_geoms: frozenset[int] = self._arm_geom_ids()
        self._steps = 0
        self._t0 = 0.0
        self._diverged: str | None = None
        self._last_obs: dict[str, np.ndarray] | None = None
        self._episode_params: dict[str, Any] = {}

    # ------------------------------------------------------------------ dynamics randomisation
    def _randomise_dynamics(self) -> None:
        """Draw this episode's plant (FrankaSim.set_dynamics); the draws are reported in the reset info."""
        rng, sim = self.np_random, self.sim
        info: dict[str, Any] = {}
        if self.link_mass_range is not None:
            k = rng.uniform(*self.link_mass_range, size=7)
            sim.set_dynamics(link_mass_scale=k)
            info["link_mass_scale"] = k
        if self.friction_scale_range is not None:
            k = float(rng.uniform(*self.friction_scale_range))
            sim.set_dynamics(friction_scale=k)  # scales the whole law of the plant
            info["friction_scale"] = k
        if self.payload_mass_range is not None:
            mass = float(rng.uniform(*self.payload_mass_range))
            # a small solid sphere of radius 3 cm held at PAYLOAD_COM in the flange frame
            body = RigidBody(mass, PAYLOAD_COM, np.full(3, 0.4 * mass * 0.03**2))
            if self.payload_declared:
                sim.set_dynamics(payload=body if mass > 0 else None)
            else:
                sim.set_dynamics(undeclared_payload=body)
            info["payload_mass"] = mass
        self._episode_params = info

    # ------------------------------------------------------------------ action handling
    #: (acceleration rad/s^2, velocity rad/s) of the default torque scale (:func:`torque_action_scale`)
    torque_scale_motion: tuple[float, float] = (0.5, 0.5)

    def default_action_scale(self, action_type: str) -> np.ndarray:
        """The physical value of a normalized action of +1 per component: :func:`default_action_scale` for this
        env's robot model (torque: at the task's :attr:`torque_scale_motion`)."""
        return default_action_scale(action_type, self.sim.model, self.torque_scale_motion)

    def _resolve_action_scale(self, action_scale: Any, hi: np.ndarray) -> np.ndarray | None:
        if isinstance(action_scale, str):
            if action_scale not in ACTION_SCALES:
                raise ValueError(f"action_scale must be one of {ACTION_SCALES} or a number / array of "
                                 f"{hi.shape[0]} physical values, got {action_scale!r}")
            if action_scale == "physical":
                return None
            s = np.asarray(self.default_action_scale(self.action_type), dtype=np.float64)
        else:
            try:
                s = np.broadcast_to(np.asarray(action_scale, dtype=np.float64), hi.shape).copy()
            except (TypeError, ValueError):
                raise ValueError(f"action_scale must be one of {ACTION_SCALES} or a number / array of "
                                 f"{hi.shape[0]} physical values, got {action_scale!r}") from None
        if not (np.isfinite(s).all() and (s > 0).all() and (s <= hi * (1 + 1e-9)).all()):
            raise ValueError(f"action_scale must be > 0 and within the robot's limits {np.round(hi, 4).tolist()} "
                             f"for {self.action_type} actions, got {np.asarray(action_scale).tolist()!r}")
        return s

    def to_physical(self, action: Any) -> np.ndarray:
        """The physical command (float64: Nm, rad/s or the camera twist) of an action of this env's space."""
        a = np.asarray(action, dtype=np.float64)
        return a if self.action_scale is None else a * self.action_scale

    def to_action(self, physical: Any) -> np.ndarray:
        """The action (float32, of this env's space) that commands a physical value, clipped to the space."""
        p = np.asarray(physical, dtype=np.float64)
        a = p if self.action_scale is None else p / self.action_scale
        return np.clip(a, self.action_space.low, self.action_space.high).astype(np.float32)

    def _check_action(self, action: Any) -> np.ndarray:
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"action must be a numeric array of shape {self.action_space.shape}, "
                             f"got {type(action).__name__}") from None
        if a.shape == self._act_shape:  # the common case, kept cheap: finite (NaN fails the comparisons), inside
            if self._act_symmetric:  # (|a| <= hi is exactly -hi <= a <= hi: negation is exact)
                if (np.abs(a) <= self._act_hi_tol).all():
                    return a
            elif (a >= self._act_lo_tol).all() and (a <= self._act_hi_tol).all():
                return a
        if a.shape != self.action_space.shape:
            if a.size == self.action_space.shape[0]:
                a = a.reshape(self.action_space.shape)
            else:
                raise ValueError(f"action must have shape {self.action_space.shape} ({self.action_type}), "
                                 f"got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"action contains NaN or inf: {a}")
        if self.clip_actions:
            return np.clip(a, self._act_lo, self._act_hi)
        bad = (a < self._act_lo - self._act_tol) | (a > self._act_hi + self._act_tol)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{self.action_type} action component {i} = {a[i]:.6g} is outside the action space "
                             f"[{self._act_lo[i]:.6g}, {self._act_hi[i]:.6g}] (pass clip_actions=True to clip)")
        return np.clip(a, self._act_lo, self._act_hi)

    #: rad: how far inside the task's joint-limit bound the joint-limit guard brakes a joint to rest
    guard_margin: float = 0.01

    def guard_bounds(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint-limit guard's bounds (lower, upper) on an action (action units, (..., 7)) at joint position q
        (rad, (..., 7)): ``-min(sqrt(2 a d_lo), d_lo / 2T)`` and ``min(sqrt(2 a d_hi), d_hi / 2T)`` (see
        ``joint_limit_guard``), never beyond the action space."""
        d_hi = np.maximum(self._guard_hi - q, 0.0)
        d_lo = np.maximum(q - self._guard_lo, 0.0)
        hi = np.minimum(np.sqrt(self._guard_2a * d_hi), self._guard_rate * d_hi)
        lo = np.minimum(np.sqrt(self._guard_2a * d_lo), self._guard_rate * d_lo)
        return -lo, hi

    def _guard_action(self, a: np.ndarray) -> np.ndarray:
        """The checked action ``a`` bounded by the joint-limit guard at the measured joint position (a new array
        when a joint is near its limits, ``a`` itself otherwise)."""
        q = self.sim.joint_views()[0]
        if self._far_from_limits(q):
            return a
        lo, hi = self.guard_bounds(q)
        return np.minimum(np.maximum(a, lo), hi)

    def _far_from_limits(self, q: np.ndarray) -> bool:
        """Every joint farther from its limits than the guard's braking distance at the action scale: the guard's
        bounds then lie beyond the action space (the common case, kept cheap)."""
        return bool((np.abs(q - self._guard_free_mid) < self._guard_free_half).all())

    def _apply_action(self, a: np.ndarray) -> None:
        sim = self.sim
        if self.action_type == "torque":
            sim.set_force_torque(JOINT_STATE, a)
        elif self.action_type == "joint_velocity":
            sim.set_velocity(JOINT_STATE, a)
        else:
            sim.set_velocity(CAMERA_FRAME, a)

    def _start_control(self) -> None:
        self.sim.set_robot_state(FORCE_TORQUE if self.action_type == "torque" else VELOCITY)

    # ------------------------------------------------------------------ task hooks (overridden by tasks)
    def _reset_task(self, options: dict[str, Any]) -> np.ndarray:
        """Draw the episode (targets, initial joint position); returns q0 (7,)."""
        raise NotImplementedError

    def _after_reset(self) -> None:
        """Called once the robot is at q0 (e.g. to take the first camera frame)."""

    def _segments(self) -> tuple[tuple[int, bool], ...]:
        """The physics of the next control period as (substeps, camera frame after them) segments (tasks with a
        camera capture frames in between); the batched vector env runs them on mujoco.batch."""
        return ((self.n_substeps, False),)

    def _segment_done(self, n: int, capture: bool) -> None:
        """Called after each segment of :meth:`_segments` has run."""

    def _advance(self) -> None:
        """Run the physics for one control period."""
        for n, capture in self._segments():
            self.world.step(n)
            self._segment_done(n, capture)

    def _get_obs(self) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def _evaluate(self, action: np.ndarray) -> tuple[float, bool, str | None, dict[str, Any]]:
        """(reward, success, failure reason or None, extra info) after a step."""
        raise NotImplementedError

    # ------------------------------------------------------------------ common checks
    def _arm_geom_ids(self) -> frozenset[int]:
        m, p = self._m, self.sim.prefix
        ids = []
        for g in range(m.ngeom):
            b = int(m.geom_bodyid[g])
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or ""
            if name.startswith(p) and name != f"{p}link0" and m.geom_contype[g] != 0:
                ids.append(g)
        return frozenset(ids)

    def _robot_failure(self) -> str | None:
        """Joint limit reached or the arm in contact with the environment."""
        q = self.sim.q
        out = (q < self._q_lo_fail) | (q > self._q_hi_fail)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            return f"joint limit: joint {i} at {q[i]:.4f} rad (limits [{self.q_min[i]:.4f}, {self.q_max[i]:.4f}])"
        d = self._d
        if d.ncon:
            for c in d.contact[: d.ncon]:
                g1, g2 = int(c.geom1), int(c.geom2)
                if g1 in self._arm_geoms or g2 in self._arm_geoms:
                    g = g1 if g1 in self._arm_geoms else g2
                    other = g2 if g == g1 else g1
                    name = mujoco.mj_id2name(self._m, mujoco.mjtObj.mjOBJ_BODY, int(self._m.geom_bodyid[g]))
                    oname = mujoco.mj_id2name(self._m, mujoco.mjtObj.mjOBJ_GEOM, other) or f"geom {other}"
                    return f"collision: {name} touches {oname}"
        return None

    def _noisy_joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        q, dq = self.sim.q, self.sim.dq
        if self.joint_noise:
            q += self.np_random.normal(0.0, self.joint_noise, 7)
        if self.velocity_noise:
            dq += self.np_random.normal(0.0, self.velocity_noise, 7)
        return q, dq

    @property
    def episode_time(self) -> float:
        """Simulated time since the start of the episode, s."""
        return self.sim.time - self._t0

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        # the task first, then the dynamics: a seed gives the same targets and start pose whatever randomisation
        # options are on, so that nominal and randomised runs can be compared episode by episode
        q0 = self._reset_task(options)
        self._randomise_dynamics()
        # a fresh MjData state (time 0, no solver warm start) so that a seed fully determines the episode
        mujoco.mj_resetData(self._m, self._d)
        self.sim.reset(q0)
        self._start_control()
        self._t0 = self.sim.time
        self._steps = 0
        self._diverged = None
        self._after_reset()
        obs = self._get_obs()
        self._last_obs = obs
        info = {"time": 0.0, "is_success": False, "failure": None, **self._episode_info(), **self._reset_info()}
        return obs, info

    def _reset_info(self) -> dict[str, Any]:
        return {}

    def step(self, action: Any):
        if self.joint_limit_guard and self._diverged is None and self._last_obs is not None \
                and not self._far_from_limits(self.sim.joint_views()[0]):
            action = self._guard_action(self._check_action(action))  # (before the compiled step, which then sees it)
        plan = self._plan
        if plan is not None and plan.fast and self._diverged is None and self._last_obs is not None \
                and plan.eligible(self):
            out = plan.step(self, action)  # the compiled step (franka_vs_gym.envs.compiled): same bits
            if out is not None:
                return out
        self._step_begin(action)
        try:
            if self._reflex is None:
                self._advance()
        except SimulationDiverged as e:
            return self._step_diverged(e)
        except ControlException as e:  # a reflex stopped the robot during the period
            self._reflex = e
        return self._step_end()

    # the three parts of a step, run by the batched vector env around its batched physics
    def _step_begin(self, action: Any) -> None:
        if self._diverged is not None:
            raise RuntimeError(f"the simulation diverged ({self._diverged}); call reset() before step()")
        if self._last_obs is None:
            raise RuntimeError("call reset() before step()")
        a = self._check_action(action)
        if self.joint_limit_guard:
            a = self._guard_action(a)  # (idempotent: an action step() guarded passes unchanged)
        if self.action_scale is not None:
            a = a * self.action_scale  # (the physical command; the task evaluates it)
        self._reflex: ControlException | None = None
        try:
            self._apply_action(a)
        except ControlException as e:  # the robot is still in a reflex (held by its brakes)
            self._reflex = e
        self._action = a

    def _episode_info(self) -> dict[str, Any]:
        """This episode's drawn dynamics for an info dict: fresh arrays each time, so the reset info and a final
        step's info never share an object a user might keep or modify."""
        return {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in self._episode_params.items()}

    def _step_reflex(self, e: ControlException):
        """A reflex stopped the robot (held by its brakes): the episode ends with the reason in info."""
        self._steps += 1
        obs = self._get_obs()
        self._last_obs = obs
        info = {"time": self.episode_time, "is_success": False, "failure": ",".join(e.reasons), "reflex": e.detail,
                **self._episode_info()}
        return obs, -self._failure_cost(), True, False, info

    def _step_diverged(self, e: SimulationDiverged):
        self._diverged = str(e)
        info = {"time": self.episode_time, "is_success": False, "failure": f"diverged: {e}", **self._episode_info()}
        obs = {k: v.copy() for k, v in self._last_obs.items()}  # the last valid state, never NaN
        return obs, -self._failure_cost(), True, False, info

    def _step_end(self):
        if self._reflex is None:
            try:  # the state at the end of the period (the batched vector env steps the physics itself)
                self.sim.check_reflexes()
            except ControlException as e:
                self._reflex = e
        if self._reflex is not None:
            return self._step_reflex(self._reflex)
        self._steps += 1
        return self._finish_step(self._get_obs())

    def _finish_step(self, obs: dict[str, np.ndarray], check_robot: bool = True):
        """The end of a step once its observation is made: the task's evaluation, the robot's failures (joint
        limits, contacts; ``check_robot=False`` when the caller knows there are none), the episode's end, info."""
        self._last_obs = obs
        reward, success, failure, extra = self._evaluate(self._action)
        if failure is None and check_robot:
            failure = self._robot_failure()
        terminated = bool((success and self.terminate_on_success) or failure is not None)
        if failure is not None:
            success = False
            reward -= self._failure_cost()
        truncated = (not terminated) and self._steps >= self.max_steps
        info = {"time": self.episode_time, "is_success": bool(success), "failure": failure, **extra}
        return obs, float(reward), terminated, bool(truncated), info

    def _failure_cost(self) -> float:
        """Penalty of a failure: ``failure_penalty`` per remaining step of the episode, so that ending an episode
        early by failing is never better than continuing at the worst per-step reward (-1)."""
        return self.failure_penalty * (self.max_steps - self._steps + 1)

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return self.world.render("overview", self.render_width, self.render_height)

    def close(self) -> None:
        self.world.close()
