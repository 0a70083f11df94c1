"""Vision: camera model matching MuJoCo's rendering, wrist camera, AprilTag detection and pose, visual features."""

from franka_vs_gym.vision.bench import bench
from franka_vs_gym.vision.camera import CameraIntrinsics, WristCamera, set_mujoco_camera
from franka_vs_gym.vision.tags import (
                                       TagDetection,
                                       TagDetector,
                                       TagMeasurement,
                                       detected_measurement,
                                       estimate_pose,
                                       ideal_measurement,
                                       project_tag,
                                       tag_corners,
)

__all__ = ["CameraIntrinsics", "TagDetection", "TagDetector", "TagMeasurement", "WristCamera", "bench",
           "detected_measurement", "estimate_pose", "ideal_measurement", "project_tag", "set_mujoco_camera",
           "tag_corners"]
