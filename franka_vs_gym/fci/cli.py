"""``franka-vs serve``: the simulated FER behind libfranka's network interface (robot 1337, gripper 1338)."""

from __future__ import annotations

import argparse
import math

SCENES = ("table", "tag", "empty")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default 127.0.0.1; parallel servers: 127.0.0.2, 127.0.0.3, ...)")
    p.add_argument("--lockstep", action="store_true",
                   help="one 1 ms physics step per control command (deterministic, as fast as the client) "
                        "instead of real time")
    p.add_argument("--model", metavar="FILE", help="calibrated-model JSON file (tool, payload, gravity, friction...)")
    p.add_argument("--robot", default="fer", help="robot description: fer (default) or fr3 when available")
    p.add_argument("--rotor-inertia", type=float, default=1.0, metavar="SCALE",
                   help="multiply the robot's effective armature (motor and gear inertia felt through the torque "
                        "loop, RobotDescription.rotor_inertia) by SCALE: 1 the published values (default), 0 an "
                        "ideal link-side torque source (a stricter test of a torque controller), > 1 heavier")
    p.add_argument("--q0", type=float, nargs=7, metavar="Q", help="start joint position, 7 values in rad")
    p.add_argument("--scene", choices=SCENES, default="table",
                   help="table (default), tag (8 cm AprilTag id 0 on the table) or empty (no table)")
    p.add_argument("--table", type=float, metavar="HEIGHT", dest="table_height",
                   help="a raised rigid table in front of the robot with its top at HEIGHT m above the base, instead "
                        "of the scene's table (e.g. 0.59: the bare flange touches it at the neutral pose; libfranka's "
                        "force_control example)")
    p.add_argument("--tool", choices=("franka_hand", "none"),
                   help="the tool on the flange, replacing the model's: franka_hand or none (the bare flange)")
    p.add_argument("--record", metavar="LOG", help="write the session as a workbench log (.csv or .npz + .json)")
    p.add_argument("--no-camera", action="store_true", help="no wrist camera in the plant")
    p.add_argument("--truth", metavar="FILE",
                   help="a hidden truth the plant carries and the robot's model (--model) does not know: a calibrated "
                        "model file, or a JSON list of effects with values (payload, gravity_tilt, friction laws, "
                        "armature, torque_offset, link_mass, delay; see docs/fci.md)")


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.errors import UserError
    from franka_vs_gym.fci.server import FCIServer
    from franka_vs_gym.model.description import robot_description

    try:
        robot = robot_description(args.robot).with_rotor_inertia(args.rotor_inertia)
    except ValueError as e:
        raise UserError(f"--robot/--rotor-inertia: {e}") from None
    if args.q0 is not None and not all(math.isfinite(v) for v in args.q0):
        raise UserError("--q0 must be 7 finite joint angles in rad")
    if args.table_height is not None and not (math.isfinite(args.table_height) and 0.0 < args.table_height < 1.2):
        raise UserError(f"--table {args.table_height}: the table top's height above the robot base, 0 < HEIGHT < 1.2 m")
    tags = None
    if args.scene == "tag":
        from franka_vs_gym.assets.mjcf import TagSpec

        tags = [TagSpec()]
    server = FCIServer(args.host, lockstep=args.lockstep, model=args.model, robot=robot, q0=args.q0, tags=tags,
                       camera=not args.no_camera, record=args.record, table=args.scene != "empty", truth=args.truth,
                       table_height=args.table_height, tool=args.tool)
    try:
        server.serve_forever()
    except OSError as e:  # address in use / not available: one line, not a traceback
        raise UserError(str(e.strerror or e)) from None
    return 0
