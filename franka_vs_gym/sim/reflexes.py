"""The robot's reflexes: limits the simulated FER enforces as the real one does, and the error they raise.

A violated limit stops the robot (brakes engaged: joints held) and raises :class:`ControlException`, the
counterpart of libfranka's ``franka::ControlException``; its ``reasons`` are libfranka's error names (the names
libfranka prints, ``getErrorName`` of the research interface, e.g. ``"joint_position_limits_violation"``; they are
the ``franka::Errors`` field names except ``tau_J_range_violation``, field ``tau_j_range_violation``), so the FCI
server can report them to a client bit for bit and user code can branch on them.
``FrankaSim.automatic_error_recovery()`` clears the error, as on the real robot, after which moving back out of a
violated position limit is allowed (moving further out is not).

Limits (a :class:`~franka_vs_gym.model.description.JointLimits`, from the robot description; sources in
docs/reliability.md), what is checked, and the reason raised:

================  ==========================================  ===================================================
limit             checked against                             reason
================  ==========================================  ===================================================
``q_min, q_max``  measured q, every physics step (see below)  ``joint_position_limits_violation``
``dq_max``        measured dq, every physics step             ``joint_velocity_violation``
``tau_max``       measured tau_J (sensor torque incl. offset) ``tau_J_range_violation``
                  every physics step
``dtau_max``      commanded torque, change per 1 ms cycle     ``controller_torque_discontinuity``
``ddq_max``       commanded joint velocity, change per 1 ms   ``joint_motion_generator_velocity_discontinuity``
``dddq_max``      commanded acceleration, change per 1 ms     ``joint_motion_generator_acceleration_discontinuity``
================  ==========================================  ===================================================

The measured state is checked after every physics step, whatever the number of steps a call runs. With the
compiled plant (:mod:`franka_vs_gym.sim.plant`) the check runs inside MuJoCo's step, so an environment's control
period (10-50 steps) stays one ``mj_step(m, d, n)`` call (one ``mujoco.batch`` call for the batched vector env): at
the first physics step whose resulting state violates a limit the plant records the violation (time, joint, value,
reason) in the robot's record in ``mjData.userdata`` and engages the brakes from that step on (joints held at that
position, zero velocity, the robot's actuator controls zeroed); the ``SimWorld.step(n)`` call then raises the
ControlException, whose detail names that time, joint and value. The state a call ends with is checked right
after the call by the same compiled check (``plant.check``), which marks it checked for the next call. Without the
compiled plant the same checks run in Python before every physics step (and after the call), which raises at the
violating step itself: the same reasons, times, joints and values, slower. After a recovery from beyond a position
limit (relaxed limits, tightened step by step as the joint comes back) the checks run in Python at every step. A
reset or recovered state is not checked; the checks start with the state after the next physics step.

The last three are limits on what a controller sends (libfranka's motion-generator and torque-command checks);
``command_rates`` chooses how FrankaSim treats them:

- ``"pass"`` (default): commands reach the joints as given and their rates are not checked. FrankaSim's commands
  are ViSP-level (vpRobotFranka smooths velocity commands with its own generator) and the environments hold an
  action for a whole control period (10-50 ms), which on the real robot would need an interpolating controller in
  between; the measured-state reflexes above still apply.
- ``"limit"``: commands pass through the robot interface's rate limiter at every physics step (one 1 ms cycle per
  step), as libfranka's ``franka::limitRate`` does by default (:mod:`franka_vs_gym.sim.rate_limit`: torque rate;
  joint velocity, acceleration and jerk, and the FR3's position-based velocity limits); nothing trips. With the
  compiled plant the limiter runs inside MuJoCo's step (``_plant.c``), so a control period stays one call.
- ``"check"``: libfranka's own semantics with ``limit_rate = false``: a command that jumps by more than the limit
  allows within one 1 ms cycle raises the named ControlException.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from typing import Any

import numpy as np

JOINT_POSITION = "joint_position_limits_violation"
JOINT_VELOCITY = "joint_velocity_violation"
TAU_J_RANGE = "tau_J_range_violation"
TORQUE_DISCONTINUITY = "controller_torque_discontinuity"
VELOCITY_DISCONTINUITY = "joint_motion_generator_velocity_discontinuity"
ACCELERATION_DISCONTINUITY = "joint_motion_generator_acceleration_discontinuity"
#: Status of a robot record whose reflexes the compiled plant checks (0: not checked; 1, 2, 3: the violation).
ARMED = -1.0
#: libfranka cycle: command rates are measured per 1 ms, whatever the physics step.
CYCLE = 1e-3
COMMAND_RATE_MODES = ("pass", "limit", "check")
#: A state this far beyond the limits is not a reflex but a diverged simulation (the hard stops hold within
#: 0.03 rad at 60 rad/s impacts; a reflex fires within one step of the velocity limit).
DIVERGED_POSITION = 0.5  # rad beyond a hard stop
DIVERGED_VELOCITY = 50.0  # times dq_max


class ControlException(RuntimeError):
    """A reflex aborted the motion (libfranka's ``franka::ControlException``).

    Attributes
    ----------
    reasons : tuple of str
        libfranka error names, e.g. ``("joint_position_limits_violation",)``.
    detail : str
        What was measured (joint, value, limit), for people.
    """

    def __init__(self, reasons: Iterable[str], detail: str = "") -> None:
        self.reasons = tuple(reasons)
        self.detail = detail
        msg = f"motion aborted by reflex! {json.dumps(list(self.reasons))}"
        super().__init__(f"{msg}: {detail}" if detail else msg)


def _limit(limits: Any, name: str) -> np.ndarray:
    v = limits[name] if isinstance(limits, dict) else getattr(limits, name)
    a = np.array(v, dtype=np.float64)
    if a.shape != (7,) or not np.isfinite(a).all():
        raise ValueError(f"reflex limit {name} must be 7 finite values, got {v}")
    return a


class Reflexes:
    """The reflexes of one simulated FER (see the module docstring). ``FrankaSim`` owns one and calls it.

    Parameters
    ----------
    sim : the FrankaSim whose joints are watched (its MuJoCo views ``_qpos``, ``_qvel``, ``_qfrc_actuator``,
        ``_ctrl_tau``, ``_ctrl_vel`` are read and, for rate limiting and the brakes, written).
    limits : JointLimits (or the dict of ``FrankaModel.limits()``): q_min, q_max, dq_max, ddq_max, dddq_max,
        tau_max, dtau_max (7,) each, SI units.
    enabled : check the limits (the brakes and ``current_errors`` work either way).
    command_rates : "pass", "limit" or "check" (see the module docstring).
    """

    def __init__(self, sim: Any, limits: Any, *, enabled: bool = True, command_rates: str = "pass",
                 rate_limits: Any = None) -> None:
        from franka_vs_gym.sim.rate_limit import FER_LIMITS, JointRateLimiter

        self.sim = sim
        self.q_min, self.q_max = _limit(limits, "q_min"), _limit(limits, "q_max")
        self.dq_max, self.ddq_max = _limit(limits, "dq_max"), _limit(limits, "ddq_max")
        self.dddq_max = _limit(limits, "dddq_max")
        self.tau_max, self.dtau_max = _limit(limits, "tau_max"), _limit(limits, "dtau_max")
        self._enabled = bool(enabled)
        self.command_rates = command_rates
        self.dt = float(sim.dt)
        self.errors: tuple[str, ...] = ()
        self.detail = ""
        self._lo, self._hi = self.q_min.copy(), self.q_max.copy()  # relaxed after a recovery outside the range
        self._relaxed = False
        self._hold: np.ndarray | None = None
        # command state: what the plant currently gets, and the target of the rate limiter
        self._tau_applied = np.zeros(7)
        self._v_target = np.zeros(7)
        self._v_ref = np.zeros(7)
        self._a_ref = np.zeros(7)
        self._ramp_tau = False
        self._ramp_vel = False
        self._check_tau = False
        self._t_command = -1.0
        # the plant's record of this robot (franka_vs_gym.sim.plant); a record the plant never writes until install
        self._native = False
        self._ud = np.zeros(66)
        # the rate limiter of command_rates="limit" (its state lives in the plant's record when _lim_native)
        self.rate_limits = FER_LIMITS if rate_limits is None else rate_limits
        self._limiter = JointRateLimiter(self.rate_limits, self.dt)
        self._lim_native = False
        self._t_from = -math.inf  # states at or before this time are not checked before a step (reset, recovery)

    @property
    def command_rates(self) -> str:
        return self._mode

    @command_rates.setter
    def command_rates(self, mode: str) -> None:
        if mode not in COMMAND_RATE_MODES:
            raise ValueError(f"command_rates must be one of {COMMAND_RATE_MODES}, got {mode!r}")
        changed = getattr(self, "_mode", mode) != mode
        self._mode = mode
        if changed and hasattr(self, "_limiter"):  # the limiter starts afresh from the current state
            self._reset_limiter(self._tau_applied.copy() if self._limiter_mode() == 1 else None)
            self._update_mode()

    @property
    def limit_rate(self) -> bool:
        return self._mode == "limit"

    # ------------------------------------------------------------------ public surface (via FrankaSim)
    def raise_if_error(self) -> None:
        """Raise the current ControlException if the robot is in error (commands are refused until recovery)."""
        if self.errors:
            raise ControlException(self.errors, f"{self.detail} (robot in reflex: call automatic_error_recovery())")

    def recover(self) -> None:
        """Clear the errors and release the brakes (``automatic_error_recovery``)."""
        q = self.sim._qpos
        self.errors, self.detail, self._hold = (), "", None
        self._clear_record()
        # a joint left beyond its limit may move back in, not further out
        self._lo = np.minimum(self.q_min, q)
        self._hi = np.maximum(self.q_max, q)
        self._relaxed = bool((self._lo < self.q_min).any() or (self._hi > self.q_max).any())
        self.reset_commands()

    def reset(self) -> None:
        """Simulation reset: no error, no brakes, limits as specified."""
        self.errors, self.detail, self._hold = (), "", None
        self._clear_record()
        self._lo, self._hi, self._relaxed = self.q_min.copy(), self.q_max.copy(), False
        self.reset_commands()

    def reset_commands(self, torque_from: np.ndarray | None = None) -> None:
        """A new control state: the rate limiters start from rest, or, entering torque control, from the torque
        the joints were producing (``torque_from``), so that the hand-over is bumpless."""
        self._tau_applied[:] = 0.0 if torque_from is None else torque_from
        self._v_target[:] = 0.0
        self._v_ref[:] = 0.0
        self._a_ref[:] = 0.0
        self._ramp_tau = self._ramp_vel = False
        self._check_tau = bool(np.any(self.sim._offset)) or bool(self.sim._torque_noise)
        if self._native:
            self._ud[2] = float(self._check_tau)
        self._reset_limiter(torque_from)
        self._update_mode()

    def _limiter_mode(self) -> int:
        """The rate limiter's mode for the current control state: 1 torque, 2 joint velocity, 0 off."""
        if self._mode != "limit":
            return 0
        from franka_vs_gym.sim.robot import RobotState

        state = getattr(self.sim, "_state", None)
        return {RobotState.STATE_FORCE_TORQUE_CONTROL: 1, RobotState.STATE_VELOCITY_CONTROL: 2}.get(state, 0)

    def _reset_limiter(self, torque_from: np.ndarray | None = None) -> None:
        """Start the rate limiter from rest at the current position (torque control: from ``torque_from``); in
        the plant's record when it runs there (compiled plant, no command delay), else in Python at every step."""
        mode = self._limiter_mode()
        q = self.sim._qpos
        self._limiter.reset(q, torque_from if mode == 1 else None)
        from franka_vs_gym.sim import plant

        self._lim_native = bool(mode and self._native and not self.sim._delay_steps)
        if self._native:
            L = self._ud[plant.L0:]
            L[0] = float(mode) if self._lim_native else 0.0
            L[3] = -1.0
            L[4:] = 0.0
            # (a reset of the data zeroes userdata: the actuators are written with every start)
            L[1], L[2] = self.sim._motor.start, self.sim._vel.start
            if self._lim_native:
                for i in (0, 1, 4):  # target, then the last command before and after a cycle
                    L[4 + 7 * i:11 + 7 * i] = self._limiter.last
                L[25:32] = q
                L[46:53] = q
        self._ramp_tau = mode == 1 and not self._lim_native
        self._ramp_vel = mode == 2 and not self._lim_native

    def limiter_target(self) -> np.ndarray | None:
        """The rate limiter's target command (7,) in the plant's record (a view), or None when the limiter does not
        run in the plant."""
        if not self._lim_native:
            return None
        from franka_vs_gym.sim import plant

        return self._ud[plant.L0 + 4:plant.L0 + 11]

    # ------------------------------------------------------------------ commands
    def command_torque(self, tau: np.ndarray) -> None:
        """A new gravity-free torque command (7,), already saturated at tau_max. Without rate limiting, a change
        beyond dtau_max per 1 ms cycle is a torque discontinuity."""
        self.raise_if_error()
        if self._mode == "limit":
            if self._lim_native:
                self.limiter_target()[:] = tau
            return
        if self.enabled and self._mode == "check":
            rate = np.abs(tau - self._tau_applied) / CYCLE
            bad = rate > self.dtau_max
            if bad.any():
                j = int(np.argmax(rate / self.dtau_max))
                self._trip((TORQUE_DISCONTINUITY,), f"joint {j}: commanded torque changes at {rate[j]:.4g} Nm/s, "
                                                    f"limit {self.dtau_max[j]:.4g} Nm/s")
        self._tau_applied[:] = tau

    def command_velocity(self, dq: np.ndarray) -> None:
        """A new joint velocity command (7,) (already within dq_max): without rate limiting, a jump beyond
        ddq_max (acceleration) or dddq_max (jerk) per 1 ms cycle is a motion-generator discontinuity. Writes the
        plant's velocity reference."""
        self.raise_if_error()
        self._v_target[:] = dq
        if self._mode == "limit":
            if self._lim_native:
                self.limiter_target()[:] = dq
            return
        if self.enabled and self._mode == "check":
            if self.sim.time - self._t_command > 1.5 * CYCLE:  # held since: no acceleration any more
                self._a_ref[:] = 0.0
            acc = (dq - self._v_ref) / CYCLE
            jerk = (acc - self._a_ref) / CYCLE
            reasons, details = [], []
            ra, rj = np.abs(acc) / self.ddq_max, np.abs(jerk) / self.dddq_max
            if ra.max() > 1.0:
                j = int(np.argmax(ra))
                reasons.append(VELOCITY_DISCONTINUITY)
                details.append(f"joint {j}: commanded acceleration {acc[j]:.4g} rad/s^2, limit {self.ddq_max[j]}")
            if rj.max() > 1.0:
                j = int(np.argmax(rj))
                reasons.append(ACCELERATION_DISCONTINUITY)
                details.append(f"joint {j}: commanded jerk {jerk[j]:.4g} rad/s^3, limit {self.dddq_max[j]}")
            if reasons:
                self._trip(tuple(reasons), "; ".join(details))
            self._a_ref[:] = acc
            self._t_command = self.sim.time
        self._v_ref[:] = dq
        self.sim._ctrl_vel[:] = dq

    # ------------------------------------------------------------------ every physics step
    def install(self, world: Any) -> None:
        """Register with the world: a check after every ``world.step(n)`` call, and a per-physics-step hook that
        does nothing (so the compiled plant keeps stepping a whole period in one call, checking the limits inside
        MuJoCo's step) except while the brakes hold the joints, a command is being rate-limited, a recovered joint
        is coming back inside its limits, or without the compiled plant (the checks then run in Python)."""
        from franka_vs_gym.sim import plant
        from franka_vs_gym.sim.world import no_op

        self._world = world
        sim, m = self.sim, world.model
        prefixes = [r.prefix for r in world.scene.robots]
        jids = np.asarray(getattr(sim, "_jids", []), dtype=np.int64)
        if getattr(sim, "_native", False) and sim.prefix in prefixes and jids.shape == (7,) and \
                (np.diff(jids) == 1).all() and m.nuser_jnt >= plant.NUSER:
            off = prefixes.index(sim.prefix) * plant.RSLOT
            if off + plant.RSLOT <= m.nuserdata:
                u = m.jnt_user
                c = plant.RCOL  # the reflex columns (franka_vs_gym.sim.plant)
                u[jids, c] = plant.RTAG
                u[jids, c + 1] = off
                u[jids, c + 2] = np.arange(7)
                u[jids, c + 3], u[jids, c + 4], u[jids, c + 5] = self.q_min, self.q_max, self.dq_max
                u[jids, c + 6], u[jids, c + 7] = self.tau_max, sim._offset
                u[jids, plant.LCOL:plant.LCOL + 9] = self.rate_limits.plant_columns()
                self._ud = world.data.userdata[off:off + plant.RSLOT]
                self._ud[plant.L0 + 1] = sim._motor.start
                self._ud[plant.L0 + 2] = sim._vel.start
                self._native = True
                self._clear_record()
        self._hook = no_op
        world.add_pre_step(self._hook)
        self._check_now = self._make_check()
        world.add_check(self._check_now)
        self._update_mode()

    def _make_check(self):
        """The check run after every ``world.step(n)``, on the state the call ends with: with the compiled plant
        armed, its C check (about 0.1 us; it also reports a violation recorded during the call); otherwise a closure
        over preallocated buffers testing |q - centre| <= half range and |dq| <= dq_max in one comparison (about
        2 us); only a violation (or a relaxed range, a torque offset) goes on to :meth:`check_state`, which names
        it."""
        from franka_vs_gym.sim import plant

        sim = self.sim
        q, dq = sim._qpos, sim._qvel
        center = (self.q_min + self.q_max) / 2
        lim = np.concatenate([(self.q_max - self.q_min) / 2, self.dq_max])
        buf = np.empty(14)
        bq, bd = buf[:7], buf[7:]
        sub, absolute = np.subtract, np.abs
        ud = self._ud
        native_check = plant.check if self._native else None
        addr = (self._world.model._address, self._world.data._address, int(sim._jids[0])) if self._native else ()

        data = self._world.data

        def prefiltered_check() -> None:
            """|q - centre| <= half range and |dq| <= dq_max in one comparison; only a violation (or a relaxed range,
            a torque offset) goes on to check_state, which names it."""
            if self._relaxed or self._check_tau:
                self.check_state()
                return
            sub(q, center, out=bq)
            bd[:] = dq
            absolute(buf, out=buf)
            if (buf > lim).any():
                self.check_state()

        def python_step() -> None:
            """Before each physics step without the compiled plant: the same prefilter, on the state the previous
            step produced."""
            if data.time > self._t_from:
                prefiltered_check()

        self._python_step = python_step

        def after_steps() -> None:
            if native_check is not None:
                r = native_check(*addr)
                if r == 2:  # armed and within the limits
                    return
                if r == 1:  # a violation recorded during the call (the plant holds the joints since) or now
                    self._trip_recorded()
            elif ud[0] > 0.0:
                self._trip_recorded()
            if not self._enabled or self._hold is not None:
                return
            prefiltered_check()

        return after_steps

    def check_now(self) -> None:
        """Check the current state as the world does after every ``step(n)`` call: the compiled plant's C check
        when it is armed (about 0.1 us), else the prefilter in front of :meth:`check_state` (the brakes already hold
        a robot in error)."""
        self._check_now()

    def _update_mode(self) -> None:
        self._arm()
        slow = self._hold is not None or self._ramp_tau or self._ramp_vel or self._relaxed
        world = getattr(self, "_world", None)
        if world is None:
            return
        from franka_vs_gym.sim.world import no_op

        if slow:
            hook = self.pre_step
        elif self._enabled and not self._native:  # without the compiled plant, Python checks every step
            hook = self._python_step
        else:
            hook = no_op
        if hook is not self._hook:
            world.replace_pre_step(self._hook, hook)
            self._hook = hook

    @property
    def enabled(self) -> bool:
        return self._enabled

    @enabled.setter
    def enabled(self, on: bool) -> None:
        self._enabled = bool(on)
        self._update_mode()

    # ------------------------------------------------------------------ the plant's record (compiled plant)
    def _arm(self) -> None:
        """Arm the plant's checks when Python would check every step's state against the specified limits (enabled,
        no brakes, no relaxed limits), disarm them otherwise; a recorded violation not yet raised is kept."""
        ud = self._ud
        if self._native and not ud[0] > 0.0:
            ud[0] = ARMED if self._enabled and self._hold is None and not self._relaxed else 0.0

    def _clear_record(self) -> None:
        """Forget any recorded violation; states after the current time are checked (a reset or recovered state is
        not: the checks start with the state after the next physics step)."""
        world = getattr(self, "_world", None)
        if world is not None:
            self._t_from = world.data.time
        if self._native:
            ud = self._ud
            ud[:13] = 0.0
            ud[1] = self._t_from
            ud[2] = float(self._check_tau)
            self._arm()

    def _detail(self, code: int, t: float, j: int, v: float) -> str:
        """What was measured, for people: time (s), joint, value and limit of a violation (1 position, 2 velocity,
        3 tau_J)."""
        if code == 1:
            return f"t={t:.4f} s: joint {j} at {v:.4f} rad, limits [{self.q_min[j]}, {self.q_max[j]}] rad"
        if code == 2:
            return f"t={t:.4f} s: joint {j} at {v:.4g} rad/s, limit {self.dq_max[j]} rad/s"
        return f"t={t:.4f} s: joint {j}: measured torque {v:.4g} Nm, limit {self.tau_max[j]} Nm"

    def _trip_recorded(self) -> None:
        """Raise the violation the plant recorded inside the last call (the brakes hold the joints at the position
        of that step), as :meth:`check_state` raises it at that step."""
        ud = self._ud
        code, t, j, v = int(ud[0]), float(ud[3]), int(ud[4]), float(ud[5])
        hold = ud[6:13].copy()
        ud[0] = 0.0
        if code == 1:
            if not (self._lo[j] - DIVERGED_POSITION < v < self._hi[j] + DIVERGED_POSITION):
                self._diverged(f"joint {j} at {v:.4g} rad at t={t:.4f} s, far beyond its hard stop")
            reasons = (JOINT_POSITION,)
        elif code == 2:
            if not abs(v) / self.dq_max[j] < DIVERGED_VELOCITY:
                self._diverged(f"joint {j} at {v:.4g} rad/s at t={t:.4f} s")
            reasons = (JOINT_VELOCITY,)
        else:
            reasons = (TAU_J_RANGE,)
        self._trip(reasons, self._detail(code, t, j, v), hold)

    def pre_step(self) -> None:
        """Before each physics step: hold the brakes, advance the rate limiters, check the measured state."""
        if self._hold is not None:
            self.sim._qpos[:] = self._hold
            self.sim._qvel[:] = 0.0
            return
        if self._ramp_tau:
            self._ramp_torque()
        elif self._ramp_vel:
            self._ramp_velocity()
        if self._enabled and self._world.data.time > self._t_from:
            self.check_state()

    def check_state(self) -> None:
        """Check the measured joint state against the position, velocity and torque limits; trip on a violation."""
        if self._ud[0] > 0.0:
            self._trip_recorded()
        sim = self.sim
        q, dq = sim._qpos, sim._qvel
        if (q < self._lo).any() or (q > self._hi).any():
            self._position_violation(q)
        elif self._relaxed:
            self._tighten(q)
        if (np.abs(dq) > self.dq_max).any():
            r = np.abs(dq) / self.dq_max
            j = int(np.argmax(r))
            if not r[j] < DIVERGED_VELOCITY:
                self._diverged(f"joint {j} at {dq[j]:.4g} rad/s")
            self._trip((JOINT_VELOCITY,), self._detail(2, sim.world.time, j, dq[j]))
        if self._check_tau and self._hold is None:
            tau = sim._qfrc_actuator + sim._offset
            r = np.abs(tau) / self.tau_max
            if r.max() > 1.0:
                j = int(np.argmax(r))
                self._trip((TAU_J_RANGE,), self._detail(3, sim.world.time, j, tau[j]))

    def _diverged(self, what: str) -> None:
        from franka_vs_gym.sim.world import SimulationDiverged

        world = self.sim.world
        world.diverged = what
        raise SimulationDiverged(f"simulation diverged at t={world.time:.4f}s: {what}")

    def _position_violation(self, q: np.ndarray) -> None:
        bad = (q < self._lo) | (q > self._hi)
        j = int(np.flatnonzero(bad)[0])
        if not (self._lo[j] - DIVERGED_POSITION < q[j] < self._hi[j] + DIVERGED_POSITION):
            self._diverged(f"joint {j} at {q[j]:.4g} rad, far beyond its hard stop")
        self._trip((JOINT_POSITION,), self._detail(1, self.sim.world.time, j, q[j]))

    def _tighten(self, q: np.ndarray) -> None:
        np.minimum(self.q_min, np.maximum(self._lo, q), out=self._lo)
        np.maximum(self.q_max, np.minimum(self._hi, q), out=self._hi)
        self._relaxed = bool((self._lo < self.q_min).any() or (self._hi > self.q_max).any())
        if not self._relaxed:
            self._update_mode()

    def _ramp_torque(self) -> None:
        """One rate-limiter cycle of the torque command in Python (without the compiled plant, or with a command
        delay: the delayed command is the target)."""
        sim = self.sim
        target = sim._ctrl_tau if sim._delay_steps else sim._tau_cmd
        sim._ctrl_tau[:] = self._limiter.torque(target)
        self._tau_applied[:] = sim._ctrl_tau

    def _ramp_velocity(self) -> None:
        """One rate-limiter cycle of the joint velocity command in Python (without the compiled plant)."""
        v = self._limiter.velocity(self._v_target)
        self._a_ref[:] = self._limiter.last_acc
        self._v_ref[:] = v
        self.sim._ctrl_vel[:] = v

    # ------------------------------------------------------------------ tripping
    def _trip(self, reasons: tuple[str, ...], detail: str, hold: np.ndarray | None = None) -> None:
        """Engage the brakes (hold the current position, or ``hold`` (7,) rad, where the plant's brakes held the
        joints), record the error, raise ControlException."""
        sim = self.sim
        self.errors, self.detail = reasons, detail
        if hold is not None:
            sim._qpos[:] = hold
        self._hold = sim._qpos.copy()
        sim._qvel[:] = 0.0
        sim._ctrl_tau[:] = 0.0
        sim._ctrl_vel[:] = 0.0
        sim._tau_cmd[:] = 0.0
        self._tau_applied[:] = 0.0
        self._v_ref[:] = 0.0
        self._a_ref[:] = 0.0
        self._ramp_tau = self._ramp_vel = False
        self._limiter.reset(self._hold)
        if self._lim_native:
            from franka_vs_gym.sim import plant

            self._ud[plant.L0 + 4:] = 0.0
            self._ud[plant.L0 + 3] = -1.0
        self._update_mode()
        raise ControlException(reasons, detail)


def position_profile_time(delta: np.ndarray, v_max: np.ndarray, a_max: np.ndarray, j_max: np.ndarray) -> float:
    """Duration (s) of a quintic (minimum-jerk) joint motion over ``delta`` (7,) rad whose peak velocity,
    acceleration and jerk stay within ``v_max``, ``a_max``, ``j_max`` (peaks of the quintic: 15/8 d/T,
    10/sqrt(3) d/T^2, 60 d/T^3)."""
    d = np.abs(delta)
    return float(max(np.max(15 / 8 * d / v_max), np.max(np.sqrt(10 / math.sqrt(3) * d / a_max)),
                     np.max(np.cbrt(60 * d / j_max))))


__all__ = ["ACCELERATION_DISCONTINUITY", "CYCLE", "ControlException", "JOINT_POSITION", "JOINT_VELOCITY",
           "Reflexes", "TAU_J_RANGE", "TORQUE_DISCONTINUITY", "VELOCITY_DISCONTINUITY", "position_profile_time"]
