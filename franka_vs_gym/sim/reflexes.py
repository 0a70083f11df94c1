"""The robot's reflexes: limits the simulated FER enforces as the real one does, and the error they raise.

A violated limit stops the robot (brakes engaged: joints held) and raises :class:`ControlException`, the
counterpart of libfranka's ``franka::ControlException``; its ``reasons`` are libfranka's error names (the fields of
``franka::Errors``, e.g. ``"joint_position_limits_violation"``), so the FCI server can report them to a client bit
for bit and user code can branch on them. ``FrankaSim.automatic_error_recovery()`` clears the error, as on the real
robot.
"""

from __future__ import annotations

import json
from collections.abc import Iterable


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


__all__ = ["ControlException"]
