"""The log readers, one module per format family.

- :mod:`.rosbag`: ROS 1 and ROS 2 bags (franka_ros / franka_ros2 robot states, ``sensor_msgs/JointState``).
- :mod:`.libfranka_csv`: libfranka's ``logToCSV`` files.
- :mod:`.robot_states`: dumps of pylibfranka / franky robot states (JSON, CSV, NumPy, pickles) and
  :class:`~.robot_states.StateRecorder`, which writes them in a 1 kHz loop.
- :mod:`.fields`: the columns of a robot-state table read as the log's fields (names, time, declared tool), shared
  by the bag and dump readers.

The workbench's own CSV/NPZ format and the Gaz et al. 2019 text folder are read by
:func:`franka_vs_gym.validation.loading.load_log`, which dispatches to these readers.
"""

from franka_vs_gym.validation.readers.fields import joint_index
from franka_vs_gym.validation.readers.libfranka_csv import is_libfranka_csv, libfranka_columns
from franka_vs_gym.validation.readers.rosbag import bag_kind, franka_layout, is_rosbag, read_rosbag

__all__ = ["bag_kind", "franka_layout", "is_libfranka_csv", "is_rosbag", "joint_index", "libfranka_columns",
           "read_rosbag"]
