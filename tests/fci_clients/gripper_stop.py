"""franky client: start closing the gripper slowly, stop it halfway, report the widths and what the move returned."""
import json
import sys
import time

from franky import Gripper

gripper = Gripper(sys.argv[1])
gripper.homing()
out = {"width_start": gripper.width}
future = gripper.move_async(0.0, 0.005)  # 16 s of closing at 5 mm/s from 0.08 m
time.sleep(0.05)
out["stop"] = gripper.stop()
try:
    out["move_result"] = future.get()
except Exception as e:  # the interrupted move is answered "aborted"
    out["move_result"] = f"{type(e).__name__}: {e}"
time.sleep(0.05)
out["width_after_stop"] = gripper.width
time.sleep(0.05)
out["width_later"] = gripper.width
print(json.dumps(out))
