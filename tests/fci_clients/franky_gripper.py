"""franky client: gripper homing, move, then grasp (argv[2]: expected object width in m, or 0 for none)."""
import json
import sys

from franky import Gripper

gripper = Gripper(sys.argv[1])
out = {"homing": gripper.homing(), "max_width": gripper.max_width}
out["move"] = gripper.move(0.05, 0.05)
out["width_after_move"] = gripper.width
width = float(sys.argv[2])
out["grasp"] = gripper.grasp(width, 0.05, 20.0, epsilon_inner=0.005, epsilon_outer=0.005)
out["width_after_grasp"] = gripper.width
out["is_grasped"] = gripper.is_grasped
out["open"] = gripper.open(0.05)
out["width_after_open"] = gripper.width
print(json.dumps(out))
