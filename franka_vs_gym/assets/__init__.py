"""Assets: the MJCF of the FER + Franka Hand and its scenes, generated from ``franka_vs_gym.model.params``.

Meshes come from the installed ``example-robot-data`` package (franka_description STL meshes, Apache-2.0); nothing
is downloaded at run time.
"""

from franka_vs_gym.assets.mjcf import RobotSpec, SceneSpec, TagSpec, mesh_dir, scene_xml

__all__ = ["RobotSpec", "SceneSpec", "TagSpec", "mesh_dir", "scene_xml"]
