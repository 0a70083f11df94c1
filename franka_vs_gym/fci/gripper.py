"""The Franka Hand behind the gripper interface (TCP 1338): homing, move, grasp, stop, and its state.

The plant's fingers are position-driven: each 1 ms step moves both finger bodies of the MuJoCo model towards the
target width at the commanded speed (the fingers are kinematic, their opening is a geometric change of the model,
so they show in the camera and touch objects). A grasp closes until a finger touches something that is not the
robot (or until the target width is passed) and succeeds when the width is within ``[width - epsilon_inner,
width + epsilon_outer]``, as libfranka's ``Gripper::grasp`` defines it. The grasp force is recorded but not
simulated as a contact force (the object is not held by friction in the plant).
"""

from __future__ import annotations

import mujoco
import numpy as np

from franka_vs_gym.fci.codec import GripperCommand, GripperStatus
from franka_vs_gym.model.description import FRANKA_HAND

MAX_WIDTH = 2 * FRANKA_HAND.finger_opening  # m
MAX_SPEED = 0.1  # m/s
HOMING_SPEED = 0.1  # m/s


class SimulatedHand:
    """Width (m), target, speed of the hand's fingers in a :class:`~franka_vs_gym.sim.FrankaSim` plant.

    ``start(command, command_id, width, speed, ...)`` begins an action; :meth:`step` advances it by ``dt`` and
    returns ``(command, command_id, status)`` when it ends, else None.
    """

    def __init__(self, sim) -> None:
        self.sim = sim
        m = sim.world.model
        p = sim.prefix
        self._m = m
        self.fingers = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{p}{s}finger") for s in ("left", "right")]
        self.available = all(b >= 0 for b in self.fingers)
        robot_bodies = [i for i in range(m.nbody)
                        if (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) or "").startswith(p)]
        self._robot_bodies = set(robot_bodies)
        self.width = float(abs(m.body_pos[self.fingers[0]][1]) * 2) if self.available else 0.0
        self.max_width = MAX_WIDTH
        self.is_grasped = False
        self.action: tuple[int, int] | None = None  # (command, command_id)
        self._phase: list[tuple[float, float]] = []  # (target width, speed) legs still to run
        self._grasp: tuple[float, float, float] | None = None  # (width, eps_inner, eps_outer)
        self.force = 0.0

    def _set_width(self, w: float) -> None:
        self.width = float(np.clip(w, 0.0, self.max_width))
        for b, s in zip(self.fingers, (1.0, -1.0), strict=True):
            self._m.body_pos[b][1] = s * self.width / 2

    def start(self, command: int, command_id: int, width: float = 0.0, speed: float = 0.0,
              force: float = 0.0, eps_inner: float = 0.0, eps_outer: float = 0.0) -> GripperStatus | None:
        """Begin an action. Returns a status at once for invalid arguments, else None (the reply comes later)."""
        if not self.available:
            return GripperStatus.FAIL
        speed = float(speed)
        if command == GripperCommand.HOMING:
            self._phase = [(0.0, HOMING_SPEED), (self.max_width, HOMING_SPEED)]
            self._grasp = None
            self.is_grasped = False
        elif command in (GripperCommand.MOVE, GripperCommand.GRASP):
            if not (0.0 <= width <= self.max_width) or not (0.0 < speed) or not np.isfinite(speed):
                return GripperStatus.FAIL
            speed = min(speed, MAX_SPEED)
            if command == GripperCommand.MOVE:
                self._phase = [(width, speed)]
                self._grasp = None
                self.is_grasped = False
            else:
                # close (or open) until a finger touches something, as far as the fingers go
                end = 0.0 if width <= self.width else self.max_width
                self._phase = [(end, speed)]
                self._grasp = (width, eps_inner, eps_outer)
                self.force = float(force)
        else:
            return GripperStatus.FAIL
        self.action = (int(command), int(command_id))
        return None

    def stop(self) -> tuple[int, int] | None:
        """Stop the running action; returns its (command, command_id) to be answered as aborted."""
        ended, self.action, self._phase = self.action, None, []
        if self._grasp is not None:
            self.is_grasped = False
        self._grasp = None
        return ended

    @property
    def busy(self) -> bool:
        return self.action is not None

    def _touching(self) -> bool:
        d = self.sim.world.data
        fingers = self.fingers
        mb = self._m.geom_bodyid
        for i in range(d.ncon):
            c = d.contact[i]
            b1, b2 = int(mb[c.geom1]), int(mb[c.geom2])
            if (b1 in fingers and b2 not in self._robot_bodies) or (b2 in fingers and b1 not in self._robot_bodies):
                return True
        return False

    def step(self, dt: float) -> tuple[int, int, GripperStatus] | None:
        if self.action is None:
            return None
        target, speed = self._phase[0]
        delta = target - self.width
        closing = delta < 0
        if self._grasp is not None and closing and self._touching():
            return self._finish_grasp()
        move = np.clip(delta, -speed * dt, speed * dt)
        self._set_width(self.width + move)
        if abs(target - self.width) < 1e-9:
            self._phase.pop(0)
            if not self._phase:
                if self._grasp is not None:
                    return self._finish_grasp()
                (cmd, cid), self.action = self.action, None
                return cmd, cid, GripperStatus.SUCCESS
        return None

    def _finish_grasp(self) -> tuple[int, int, GripperStatus]:
        width, ei, eo = self._grasp  # type: ignore[misc]
        ok = width - ei <= self.width <= width + eo
        self.is_grasped = bool(ok)
        (cmd, cid), self.action, self._phase = self.action, None, []  # type: ignore[misc]
        return cmd, cid, GripperStatus.SUCCESS if ok else GripperStatus.UNSUCCESSFUL


__all__ = ["MAX_WIDTH", "SimulatedHand"]
