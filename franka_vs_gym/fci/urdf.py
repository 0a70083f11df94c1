"""URDF of the arm generated from a :class:`~franka_vs_gym.model.description.RobotDescription`.

This is the robot model the FCI server hands to a client's ``load_model()`` (libfranka builds its pinocchio model
from it). Conventions the client relies on: links ``link0`` .. ``link8`` (``link8`` is the flange, found by name),
revolute joints whose names contain ``joint1`` .. ``joint7`` with ``<limit>`` (effort, velocity, lower, upper) and
``<position_based_velocity_limits>`` (libfranka derives its position-dependent velocity bounds from them), and
no tool: the Franka Hand and any load travel in the robot state (``m_ee``/``F_x_Cee``/``I_ee``,
``m_load``...), which libfranka adds to ``link8``, so the hand is counted once.
"""

from __future__ import annotations

import math

import numpy as np

from franka_vs_gym.model.description import RobotDescription, robot_description


def _rpy(R: np.ndarray) -> tuple[float, float, float]:
    """Roll-pitch-yaw (URDF: R = Rz(yaw) Ry(pitch) Rx(roll)) of a rotation matrix."""
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(math.cos(pitch)) > 1e-9:
        roll = math.atan2(R[2, 1], R[2, 2])
        yaw = math.atan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: put everything in yaw
        roll = 0.0
        yaw = math.atan2(-R[0, 1], R[1, 1])
    return roll, pitch, yaw


def _origin(M: np.ndarray) -> str:
    x, y, z = (f"{v:.17g}" for v in M[:3, 3])
    r, p, yw = (f"{v:.17g}" for v in _rpy(M[:3, :3]))
    return f'<origin xyz="{x} {y} {z}" rpy="{r} {p} {yw}"/>'


# Position-based joint velocity limits published for the Franka Research 3 (Franka Control Interface documentation,
# "limits for Franka Research 3"; the same curves libfranka's rate limiter used before reading them from the URDF):
# dq_max(q) = min(dq_max, max(0, -velocity_offset + sqrt(2 deceleration_limit (q_max - q)))), and symmetrically
# towards q_min.
POSITION_BASED_VELOCITY_LIMITS: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "fr3": ((0.30, 0.20, 0.20, 0.30, 0.35, 0.35, 0.35),  # velocity_offset, rad/s
            (6.0, 2.585, 3.5, 4.0, 17.0, 5.5, 17.0)),  # deceleration_limit, rad/s^2
}


def velocity_envelope(robot: RobotDescription | str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(velocity_offset (7,) rad/s, deceleration_limit (7,) rad/s^2) of the robot's position-based velocity limits:
    the published FR3 values, else ``0`` and the joint acceleration limit (the speed from which a joint can still
    brake before its position limit, ``sqrt(2 ddq_max (q_max - q))``, capped by ``dq_max``)."""
    desc = robot_description(robot)
    if desc.name in POSITION_BASED_VELOCITY_LIMITS:
        off, dec = POSITION_BASED_VELOCITY_LIMITS[desc.name]
        return np.array(off), np.array(dec)
    return np.zeros(7), np.array(desc.limits.ddq_max)


def velocity_bounds(q: np.ndarray, robot: RobotDescription, envelope: tuple[np.ndarray, np.ndarray]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(lower (7,), upper (7,)) joint velocity bounds at joint position q (rad/s), as libfranka computes them
    from the URDF's ``<limit>`` and ``<position_based_velocity_limits>``."""
    lim = robot.limits
    off, dec = envelope
    vmax = np.array(lim.dq_max)
    up = np.minimum(vmax, np.maximum(0.0, -off + np.sqrt(np.maximum(0.0, 2 * dec * (np.array(lim.q_max) - q)))))
    lo = np.maximum(-vmax, np.minimum(0.0, off - np.sqrt(np.maximum(0.0, 2 * dec * (q - np.array(lim.q_min))))))
    return lo, up


def robot_urdf(robot: RobotDescription | str | None = None) -> str:
    """The URDF text (str) of the arm without tool, from the description's DH rows, link inertials and limits, with
    the position-based velocity limits of :func:`velocity_envelope`."""
    desc = robot_description(robot)
    lim = desc.limits
    offset, deceleration = velocity_envelope(desc)
    out = [f'<?xml version="1.0"?>\n<robot name="{desc.name}">', '  <link name="link0"/>']
    for i in range(7):
        link = desc.links[i]
        ixx, ixy, ixz, iyy, iyz, izz = link.inertia
        cx, cy, cz = link.com
        out.append(
            f'  <link name="link{i + 1}">\n    <inertial>\n      <origin xyz="{cx:.17g} {cy:.17g} {cz:.17g}" '
            f'rpy="0 0 0"/>\n      <mass value="{link.mass:.17g}"/>\n'
            f'      <inertia ixx="{ixx:.17g}" ixy="{ixy:.17g}" ixz="{ixz:.17g}" iyy="{iyy:.17g}" '
            f'iyz="{iyz:.17g}" izz="{izz:.17g}"/>\n    </inertial>\n  </link>')
        out.append(
            f'  <joint name="{desc.joint_names[i]}" type="revolute">\n    {_origin(desc.dh_placement(i))}\n'
            f'    <parent link="link{i}"/>\n    <child link="link{i + 1}"/>\n    <axis xyz="0 0 1"/>\n'
            f'    <limit effort="{lim.tau_max[i]:.17g}" velocity="{lim.dq_max[i]:.17g}" '
            f'lower="{lim.q_min[i]:.17g}" upper="{lim.q_max[i]:.17g}"/>\n'
            f'    <position_based_velocity_limits velocity_offset="{offset[i]:.17g}" '
            f'deceleration_limit="{deceleration[i]:.17g}"/>\n  </joint>')
    out.append('  <link name="link8"/>')
    out.append(f'  <joint name="{desc.name}_flange" type="fixed">\n    {_origin(desc.flange_placement())}\n'
               '    <parent link="link7"/>\n    <child link="link8"/>\n  </joint>')
    out.append("</robot>\n")
    return "\n".join(out)


__all__ = ["POSITION_BASED_VELOCITY_LIMITS", "robot_urdf", "velocity_bounds", "velocity_envelope"]
