"""Shared parts of the libfranka example programs written for pylibfranka (see README in docs/fci.md).

Ported from libfranka's ``examples/examples_common.cpp`` (Apache-2.0) in law and constants: the synchronised joint
motion generator used to reach the start pose (:class:`MotionGenerator`), the rate limiter the examples apply to
their own torque commands (:func:`limit_rate`), the default collision and impedance settings
(:func:`set_default_behavior`), and a run loop (:func:`run`) that drives one pylibfranka control object the way
``franka::Robot::control`` drives a callback: read a state, compute, write, until the callback says the motion is
finished. Every example prints a JSON summary with ``--json`` (final state, worst tracking error, errors) so tests
and users can compare runs on the simulator and on the robot.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time as wallclock
from collections.abc import Callable
from typing import Any

import numpy as np
import pylibfranka

Q_READY = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)
K_MAX_TORQUE_RATE = np.full(7, 1000.0)  # Nm/s, examples_common.h kMaxTorqueRate
# examples_common.h: MotionGenerator's limits and its end-of-motion threshold
DQ_MAX = np.array([2.0, 2.0, 2.0, 2.0, 2.5, 2.5, 2.5])  # rad/s
DDQ_MAX_START = np.full(7, 5.0)  # rad/s^2
DDQ_MAX_GOAL = np.full(7, 5.0)  # rad/s^2
DELTA_Q_MOTION_FINISHED = 1e-6  # rad
COLLISION_20 = ([20.0, 20.0, 18.0, 18.0, 16.0, 14.0, 12.0], [20.0, 20.0, 20.0, 25.0, 25.0, 25.0])


def arguments(doc: str, **extra: Any) -> argparse.Namespace:
    """The examples' command line: the robot's address, ``--json``, and each example's own options
    (``name=(type, default, help)``)."""
    ap = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    ap.add_argument("host", help="robot (or simulator) address, e.g. 172.16.0.2 or 127.0.0.1")
    ap.add_argument("--json", action="store_true", help="print a JSON summary (final state, tracking error, errors)")
    for name, (typ, default, text) in extra.items():
        ap.add_argument(f"--{name.replace('_', '-')}", type=typ, default=default, help=text)
    return ap.parse_args()


def connect(host: str) -> pylibfranka.Robot:
    return pylibfranka.Robot(host, pylibfranka.RealtimeConfig.kIgnore)


def set_collision_20(robot: pylibfranka.Robot) -> None:
    """The collision thresholds most examples set (20/18/16/14/12 Nm, 20/25 N, Nm; libfranka's C++ examples give
    them per phase, acceleration and nominal, with the same values; pylibfranka takes one set)."""
    j, c = COLLISION_20
    robot.set_collision_behavior(j, j, c, c)


def set_default_behavior(robot: pylibfranka.Robot) -> None:
    """examples_common.cpp setDefaultBehavior: collision thresholds, joint and Cartesian impedance."""
    # the C++ sets 20 Nm / 20 N for the acceleration phase and 10 for the nominal one; pylibfranka takes one set:
    # the nominal phase's lower (contact) and the acceleration phase's upper (collision) thresholds
    robot.set_collision_behavior([10.0] * 7, [20.0] * 7, [10.0] * 6, [20.0] * 6)
    robot.set_joint_impedance([3000, 3000, 3000, 2500, 2500, 2000, 2000])
    robot.set_cartesian_impedance([3000, 3000, 3000, 300, 300, 300])


DEFAULT_CUTOFF_FREQUENCY = 100.0  # Hz, lowpass_filter.h kDefaultCutoffFrequency


def lowpass(command: np.ndarray, last: np.ndarray, cutoff_frequency: float = DEFAULT_CUTOFF_FREQUENCY,
            sample_time: float = 1e-3) -> np.ndarray:
    """libfranka's first-order low-pass (lowpass_filter.cpp lowpassFilter), which ``franka::Robot::control`` applies
    to every torque command by default (cutoff 100 Hz, against the last command the robot reports, ``tau_J_d``);
    pylibfranka's ``start_torque_control`` loop does not, so the ports whose C++ example relies on it apply it here:
    ``gain = T / (T + 1 / (2 pi f_c))`` (0.386 at 1 kHz and 100 Hz), ``y = gain x + (1 - gain) y_last``."""
    gain = sample_time / (sample_time + 1.0 / (2.0 * math.pi * cutoff_frequency))
    return gain * np.asarray(command) + (1.0 - gain) * np.asarray(last)


def limit_rate(max_derivatives: np.ndarray, desired: np.ndarray, last: np.ndarray) -> np.ndarray:
    """examples_common.cpp limitRate: each value moves at most ``max_derivatives * 1 ms`` from ``last``."""
    step = np.clip((desired - last) / 1e-3, -max_derivatives, max_derivatives) * 1e-3
    return last + step


class MotionGenerator:
    """examples_common.cpp MotionGenerator: a joint position motion from ``q_d`` at start to ``q_goal``, every
    joint with the same synchronised profile (cubic acceleration ramps, constant velocity), scaled by
    ``speed_factor``. Call it as a joint-position callback: ``(state, period) -> (q_command, finished)``."""

    def __init__(self, speed_factor: float, q_goal: Any) -> None:
        self.q_goal = np.asarray(q_goal, dtype=float)
        self.dq_max = DQ_MAX * speed_factor
        self.ddq_start = DDQ_MAX_START * speed_factor
        self.ddq_goal = DDQ_MAX_GOAL * speed_factor
        self.time = 0.0
        self.q_start = self.delta = None

    def _synchronise(self) -> None:
        d, ds, dg = self.delta, self.ddq_start, self.ddq_goal
        moving = np.abs(d) > DELTA_Q_MOTION_FINISHED
        reach = self.dq_max.copy()
        short = np.abs(d) < 0.75 * (self.dq_max**2 / ds) + 0.75 * (self.dq_max**2 / dg)
        reach = np.where(short, np.sqrt(4.0 / 3.0 * np.abs(d) * ds * dg / (ds + dg)), reach)
        t1, dt2 = 1.5 * reach / ds, 1.5 * reach / dg
        tf = np.where(moving, t1 / 2 + dt2 / 2 + np.abs(d) / np.where(moving, reach, 1.0), 0.0)
        tmax = tf.max()
        a = 1.5 / 2.0 * (dg + ds)
        b = -tmax * dg * ds
        c = np.abs(d) * dg * ds
        disc = np.maximum(b * b - 4 * a * c, 0.0)
        self.v = np.where(moving, (-b - np.sqrt(disc)) / (2 * a), 0.0)
        self.t1 = 1.5 * self.v / ds
        dt2s = 1.5 * self.v / dg
        self.tf = np.where(moving, self.t1 / 2 + dt2s / 2 + np.abs(d) / np.where(moving, self.v, 1.0), 0.0)
        self.t2 = self.tf - dt2s
        self.q1 = self.v * np.sign(d) * 0.5 * self.t1
        self.moving = moving

    def _delta(self, t: float) -> tuple[np.ndarray, bool]:
        out = np.zeros(7)
        done = np.ones(7, dtype=bool)
        s = np.sign(self.delta)
        for i in np.flatnonzero(self.moving):
            t1, t2, tf, v = self.t1[i], self.t2[i], self.tf[i], self.v[i]
            td, dt2 = t2 - t1, tf - t2
            if t < t1:
                out[i] = -1.0 / t1**3 * v * s[i] * (0.5 * t - t1) * t**3
                done[i] = False
            elif t < t2:
                out[i] = self.q1[i] + (t - t1) * v * s[i]
                done[i] = False
            elif t < tf:
                out[i] = self.delta[i] + 0.5 * (1.0 / dt2**3 * (t - t1 - 2.0 * dt2 - td) * (t - t1 - td)**3
                                                + (2.0 * t - 2.0 * t1 - dt2 - 2.0 * td)) * v * s[i]
                done[i] = False
            else:
                out[i] = self.delta[i]
        return out, bool(done.all())

    def __call__(self, state: Any, period: float) -> tuple[np.ndarray, bool]:
        self.time += period
        if self.q_start is None:
            self.q_start = np.array(state.q_d)
            self.delta = self.q_goal - self.q_start
            self._synchronise()
        dq, finished = self._delta(self.time)
        return self.q_start + dq, finished


def run(control: Any, callback: Callable[[Any, float], tuple[Any, bool]]) -> tuple[Any, int]:
    """Drive a pylibfranka control object as ``franka::Robot::control`` drives a callback: ``callback(state,
    period_s) -> (command, finished)``; the finished command is the last one sent. Returns the last state read and
    the number of cycles."""
    n = 0
    while True:
        state, period = control.readOnce()
        cmd, finished = callback(state, period.to_sec())
        cmd.motion_finished = bool(finished)
        control.writeOnce(cmd)
        n += 1
        if finished:
            return state, n


def move_to(robot: pylibfranka.Robot, q_goal: Any = Q_READY, speed_factor: float = 0.5) -> None:
    """Move to ``q_goal`` with the examples' MotionGenerator (joint impedance controller)."""
    gen = MotionGenerator(speed_factor, q_goal)
    control = robot.start_joint_position_control(pylibfranka.ControllerMode.JointImpedance)

    def cb(state, period):
        q, finished = gen(state, period)
        return pylibfranka.JointPositions(q.tolist()), finished

    run(control, cb)


def report(args: argparse.Namespace, robot: pylibfranka.Robot, name: str, started: float, **numbers: Any) -> None:
    """Print the example's end: human-readable, or one JSON line with ``--json``."""
    state = robot.read_once()
    out = {"example": name, "q": list(state.q), "errors": str(state.current_errors),
           "robot_mode": str(state.robot_mode), "wall_s": wallclock.monotonic() - started,
           **{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in numbers.items()}}
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k}: {v}")
    sys.stdout.flush()
