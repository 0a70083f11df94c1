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


def robot_urdf(robot: RobotDescription | str | None = None) -> str:
    """The URDF text (str) of the arm without tool, from the description's DH rows, link inertials and limits.

    ``<position_based_velocity_limits>`` uses ``velocity_offset = 0`` and the joint acceleration limit as
    ``deceleration_limit``: the velocity bound towards a position limit is then the speed from which the joint can
    still brake before it, ``sqrt(2 ddq_max (q_max - q))``, capped by ``dq_max``.
    """
    desc = robot_description(robot)
    lim = desc.limits
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
            f'    <position_based_velocity_limits velocity_offset="0" '
            f'deceleration_limit="{lim.ddq_max[i]:.17g}"/>\n  </joint>')
    out.append('  <link name="link8"/>')
    out.append(f'  <joint name="{desc.name}_flange" type="fixed">\n    {_origin(desc.flange_placement())}\n'
               '    <parent link="link7"/>\n    <child link="link8"/>\n  </joint>')
    out.append("</robot>\n")
    return "\n".join(out)


__all__ = ["robot_urdf"]
