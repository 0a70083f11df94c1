"""libfranka's error names and their bit positions in the robot state's two 41-flag arrays.

The bit of an error is its index in libfranka's research-interface ``Error`` enum (protocol 10); the name is what
the client prints in ``ControlException: ... motion aborted by reflex! ["<name>"]`` (libfranka's
``getErrorName``). The simulator's reflexes (:class:`franka_vs_gym.sim.reflexes.ControlException`) use the same
names, or the ``franka::Errors`` field spelling where it differs (:data:`ALIASES`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

ERROR_NAMES: tuple[str, ...] = (
    "joint_position_limits_violation",  # 0
    "cartesian_position_limits_violation",
    "self_collision_avoidance_violation",
    "joint_velocity_violation",  # 3
    "cartesian_velocity_violation",
    "force_control_safety_violation",
    "joint_reflex",  # 6
    "cartesian_reflex",  # 7
    "max_goal_pose_deviation_violation",
    "max_path_pose_deviation_violation",
    "cartesian_velocity_profile_safety_violation",  # 10
    "joint_position_motion_generator_start_pose_invalid",
    "joint_motion_generator_position_limits_violation",
    "joint_motion_generator_velocity_limits_violation",
    "joint_motion_generator_velocity_discontinuity",
    "joint_motion_generator_acceleration_discontinuity",  # 15
    "cartesian_position_motion_generator_start_pose_invalid",
    "cartesian_motion_generator_elbow_limit_violation",
    "cartesian_motion_generator_velocity_limits_violation",
    "cartesian_motion_generator_velocity_discontinuity",
    "cartesian_motion_generator_acceleration_discontinuity",  # 20
    "cartesian_motion_generator_elbow_sign_inconsistent",
    "cartesian_motion_generator_start_elbow_invalid",
    "force_controller_desired_force_tolerance_violation",
    "start_elbow_sign_inconsistent",
    "communication_constraints_violation",  # 25
    "power_limit_violation",
    "cartesian_motion_generator_joint_position_limits_violation",
    "cartesian_motion_generator_joint_velocity_limits_violation",
    "cartesian_motion_generator_joint_velocity_discontinuity",
    "cartesian_motion_generator_joint_acceleration_discontinuity",  # 30
    "cartesian_position_motion_generator_invalid_frame_flag",
    "controller_torque_discontinuity",  # 32
    "joint_p2p_insufficient_torque_for_planning",
    "tau_J_range_violation",  # 34
    "instability_detected",
    "joint_move_in_wrong_direction",
    "cartesian_spline_motion_generator_violation",
    "joint_via_motion_generator_planning_joint_limit_violation",
    "base_acceleration_initialization_timeout",
    "base_acceleration_invalid_reading",  # 40
)
assert len(ERROR_NAMES) == 41

# franka::Errors field names that differ from the printed names
ALIASES = {
    "tau_j_range_violation": "tau_J_range_violation",
    "cartesian_position_motion_generator_invalid_frame": "cartesian_position_motion_generator_invalid_frame_flag",
}
ERROR_BITS: dict[str, int] = {name: i for i, name in enumerate(ERROR_NAMES)}
ERROR_BITS.update({alias: ERROR_BITS[name] for alias, name in ALIASES.items()})


def error_bit(name: str) -> int:
    """Bit position of a libfranka error name (printed or field spelling). Unknown names raise ValueError."""
    try:
        return ERROR_BITS[name]
    except KeyError:
        raise ValueError(f"unknown libfranka error name {name!r}") from None


def error_flags(names: Iterable[str]) -> np.ndarray:
    """The 41 flags (bool array) with the bits of ``names`` set."""
    flags = np.zeros(len(ERROR_NAMES), dtype=bool)
    for n in names:
        flags[error_bit(n)] = True
    return flags


def error_names(flags: Iterable[bool]) -> list[str]:
    """Printed names of the set flags, in bit order."""
    return [ERROR_NAMES[i] for i, f in enumerate(flags) if f]


__all__ = ["ALIASES", "ERROR_BITS", "ERROR_NAMES", "error_bit", "error_flags", "error_names"]
