#!/usr/bin/env python
"""Stability margins of libfranka's example controllers on the simulated robot: the largest gain multiple that stays
stable, per robot, with and without the motors' effective armature (RobotDescription.rotor_inertia).

Each controller runs the example's feedback law (without the joint-impedance example's limitRate, which would
hide an unstable loop as a bounded rate-limited oscillation) in the robot's own 1 kHz cycle with the state of the
previous cycle (as a libfranka control loop does; FCIRobot, the server's robot without networking), for 1 s,
holding the start pose while a push of 10 N (sine window, 0.1 s) along x and y acts on the hand. A run is stable
when no reflex fires and the motion dies out (max |dq| over the last 0.2 s below half its peak during the first
0.3 s). The multiple m scales the example's stiffness and damping gains together; bisection over m in [1/16, 64].

    python scripts/stability_margins.py            # prints a Markdown table
"""

from __future__ import annotations

import argparse
import math

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from franka_vs_gym.fci.codec import MoveControllerMode as C
from franka_vs_gym.fci.codec import MoveMotionGeneratorMode as G
from franka_vs_gym.fci.codec import RobotCommand
from franka_vs_gym.fci.robot import FCIRobot
from franka_vs_gym.model import ModelConfig
from franka_vs_gym.model.description import robot_description
from franka_vs_gym.sim import FrankaSim

K_JOINT = np.array([600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0])  # joint_impedance_control
D_JOINT = np.array([50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0])
K_CART = (150.0, 10.0)  # cartesian_impedance_control, the stiffnesses its documentation runs it with
Z = np.zeros(7)
PUSH = 10.0  # N, peak of the push on the hand


def _run(robot: str, rotor: float, law: str, m: float, n: int = 1000) -> bool:
    sim = FrankaSim(ModelConfig(robot=robot_description(robot).with_rotor_inertia(rotor)), camera=False, table=False,
                    rotor_inertia=True)
    r = FCIRobot(sim)
    model = sim.model
    q0 = sim.q
    if law == "internal_joint_impedance":
        r.set_joint_impedance(np.array(r.K_theta) * m)
        r.start_motion(C.JOINT_IMPEDANCE, G.JOINT_POSITION)
    else:
        r.start_motion(C.EXTERNAL_CONTROLLER, G.NONE)
    T0 = model.fMe(q0)
    kt, kr = K_CART
    Kc = np.diag([kt] * 3 + [kr] * 3) * m
    Dc = np.diag([2 * math.sqrt(kt * m)] * 3 + [2 * math.sqrt(kr * m)] * 3)
    target = q0
    p_d = T0[:3, 3]
    R_d = Rotation.from_matrix(T0[:3, :3])
    hand = mujoco.mj_name2id(sim.world.model, mujoco.mjtObj.mjOBJ_BODY, f"{sim.prefix}hand")
    st = r.fill_state().f
    early = late = 0.0
    for k in range(1, n + 1):
        q, dq = np.array(st["q"], float), np.array(st["dq"], float)
        tau, q_c = Z, Z
        if law == "joint_impedance":
            tau = m * (K_JOINT * (target - q) - D_JOINT * dq) + model.coriolis(q, dq)
        elif law == "cartesian_impedance":
            T = model.fMe(q)
            J = model.fJe(q)
            e = np.concatenate([T[:3, 3] - p_d, (Rotation.from_matrix(T[:3, :3]) * R_d.inv()).as_rotvec()])
            tau = J.T @ (-Kc @ e - Dc @ (J @ dq)) + model.coriolis(q, dq) - np.array(st["tau_ext_hat_filtered"])
        else:
            q_c = q0
        push = PUSH * math.sin(math.pi * k / 100) ** 2 if k <= 100 else 0.0
        sim.world.data.xfrc_applied[hand, :2] = push
        cmd = RobotCommand(k, q_c, Z, np.eye(4).ravel(), np.zeros(6), np.zeros(2), False, False, tau, False)
        if r.step(cmd):
            return False
        st = r.fill_state().f
        if not np.isfinite(st["q"]).all():
            return False
        v = float(np.abs(st["dq"]).max())
        early = max(early, v) if k <= 300 else early
        late = max(late, v) if k > n - 200 else late
    return late < 0.5 * early


def margin(robot: str, rotor: float, law: str, lo: float = 1 / 16, hi: float = 64.0, steps: int = 8) -> str:
    if not _run(robot, rotor, law, 1.0):
        m_hi = 1.0
        m_lo = lo
        if not _run(robot, rotor, law, lo):
            return f"< {lo:g}"
    else:
        m_lo, m_hi = 1.0, hi
        if _run(robot, rotor, law, hi):
            return f">= {hi:g}"
    for _ in range(steps):
        mid = math.sqrt(m_lo * m_hi)
        if _run(robot, rotor, law, mid):
            m_lo = mid
        else:
            m_hi = mid
    return f"{m_lo:.3g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default="fer,fr3")
    args = ap.parse_args()
    laws = ("joint_impedance", "cartesian_impedance", "internal_joint_impedance")
    print("| controller | robot | largest stable gain multiple, with effective armature | without (ideal torque "
          "source) |")
    print("|---|---|---|---|")
    for law in laws:
        for robot in args.robots.split(","):
            print(f"| {law} | {robot} | {margin(robot, 1.0, law)} | {margin(robot, 0.0, law)} |", flush=True)


if __name__ == "__main__":
    main()
