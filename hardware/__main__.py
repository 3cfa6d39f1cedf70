"""Command line for the real cell: `python -m hardware check|calibrate|grasp|replay CONFIG [...] [--dry-run]`.

- `check`: validate the config and print a summary; with `--connect`, also connect, read the arm and gripper
  state and capture one frame per camera; a gripper fault, a camera that does not start or a controller that does
  not answer (within its connect deadline) fails the check, naming each.
- `calibrate`: hand-eye calibration of one camera. The gripper visits the poses listed in a YAML file
  (`poses: [{xyz: [...], rpy: [...]}, ...]` or 4x4 matrices). A table-mounted camera watches a checkerboard held
  by the gripper (eye-to-hand -> `T_world_cam`); a wrist-mounted camera watches a checkerboard fixed on the table
  (eye-in-hand -> `T_gripper_cam`). The result is merged into the calibration file: `--out`, else the config's
  `calibration.file`, else `calibration.yaml` beside the config (which the config then has to name).
- `grasp`: one top-down grasp at a point (reset, execute, print the outcome) - the first grasp on a new cell.
- `replay`: capture one frame per camera without the robot (a dry-run cell: nothing connects to the arm or the
  gripper) and print what perception makes of it; with cameras that name a `recording`, a recorded scene is
  replayed offline through the same pyrealsense2 pipeline, rs.align and perception as on the cell.

Every error is one line `error: ...` and exit code 1 (2 for a malformed command line, 130 when interrupted).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import re
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from hardware.calibration import (EXTRINSIC_KEYS, EYE_IN_HAND_METHODS, EYE_TO_HAND_METHODS, Checkerboard,
                                  calibrate_eye_in_hand, calibrate_eye_to_hand, collect_samples,
                                  eye_in_hand_residual, eye_to_hand_residual, load_extrinsics, save_extrinsics)
from hardware.cell import RealCell, make_guard
from hardware.config import CellConfig, ConfigError, load_config
from hardware.errors import HardwareError
from hardware.fields import FieldReader, read_yaml
from hardware.kinematics import ARM_MODELS, forward_kinematics
from hardware.realsense import RealSenseCamera
from hardware.robotiq import FAULTS, GripperState
from seggrasp.hands import ROBOTIQ_2F85

#: Most poses a calibration tour may list (hand-eye calibration wants 10-30).
MAX_CALIBRATION_POSES = 200
#: The calibration file written beside the config when neither --out nor calibration.file names one.
DEFAULT_CALIBRATION_FILE = "calibration.yaml"


class _Parser(argparse.ArgumentParser):
    """An `ArgumentParser` that reads ``-1e308``, ``-.5`` and ``-inf`` as numbers, not as options (Python 3.11's
    only takes ``-1`` and ``-1.5``; the later ones match like this)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-(\.?\d|inf|nan)", re.IGNORECASE)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m hardware", description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)

    check = commands.add_parser("check", help="validate a cell config (and optionally connect)")
    check.add_argument("config", type=Path)
    check.add_argument("--connect", action="store_true", help="connect and read the hardware's state")
    check.add_argument("--dry-run", action="store_true", help="with --connect: do not connect to robot/gripper")

    calibrate = commands.add_parser("calibrate", help="hand-eye calibration of one camera (table or wrist)")
    calibrate.add_argument("config", type=Path)
    calibrate.add_argument("--serial", required=True, help="the camera to calibrate")
    calibrate.add_argument("--poses", required=True, type=Path, help="YAML file with the gripper poses to visit")
    calibrate.add_argument("--board", default="7x6", help="inner corners COLUMNSxROWS (one even, one odd)")
    calibrate.add_argument("--square", type=float, required=True, help="checkerboard square size in metres")
    calibrate.add_argument("--out", type=Path, help="calibration file (default: the config's calibration.file, "
                           f"else {DEFAULT_CALIBRATION_FILE} beside the config)")
    calibrate.add_argument("--method", choices=sorted(EYE_TO_HAND_METHODS) + sorted(EYE_IN_HAND_METHODS),
                           help="solver (default: shah for table cameras, park for wrist cameras)")
    calibrate.add_argument("--dry-run", action="store_true", help="check and log the tour of poses only")

    grasp = commands.add_parser("grasp", help="one top-down grasp at a world point")
    grasp.add_argument("config", type=Path)
    grasp.add_argument("--at", nargs=3, type=float, required=True, metavar=("X", "Y", "Z"),
                       help="world point between the pads at the grasp (metres)")
    grasp.add_argument("--yaw", type=float, default=0.0,
                       help="rotation of the closing direction about z (rad, within +-2 pi)")
    grasp.add_argument("--width", type=float, required=True, help="object width between the pads (metres)")
    grasp.add_argument("--dry-run", action="store_true", help="plan and log the motions only")

    replay = commands.add_parser("replay", help="capture every camera (recordings or live) and perceive the object")
    replay.add_argument("config", type=Path)
    replay.add_argument("--mesh", type=Path, help="also write the perceived object mesh (.ply, .obj or .stl)")
    replay.add_argument("--json", action="store_true", help="print one JSON object instead of lines")
    return parser


def _check(args: argparse.Namespace) -> int:
    if args.dry_run and not args.connect:
        raise ValueError("--dry-run only applies with --connect (without it nothing connects anyway)")
    config = load_config(args.config)
    home = forward_kinematics(config.robot.model, config.robot.home_joints) @ config.robot.T_flange_gripper
    make_guard(config).check_pose(home, "the home pose (robot.home_joints, gripper fully open)")
    limits = config.limits
    cameras = [c.serial + (f" (plays {c.recording})" if c.recording else "") for c in config.cameras]
    print(f"{args.config}: valid. UR {config.robot.model} at {config.robot.ip}, gripper at "
          f"{config.gripper.host}:{config.gripper.port}, cameras {cameras}")
    print(f"workspace {limits.workspace_min.tolist()} .. {limits.workspace_max.tolist()}, table at "
          f"{limits.table_height} m, tool <= {limits.max_tool_speed} m/s, grip <= {limits.max_grip_force} N")
    if not args.connect:
        return 0
    cell = RealCell.from_config(args.config, dry_run=args.dry_run, with_cameras=False)
    try:
        print("gripper pose (world):", np.round(cell.arm.tcp_pose(), 4).tolist())
        print("joints (rad):", np.round(cell.arm.joints(), 4).tolist())
        state = cell.gripper.state()
        print("gripper:", state, f"width {cell.gripper.width() * 1000:.1f} mm")
        problems = [] if args.dry_run else _gripper_problems(state)
        problems += _check_cameras(config, cell)
    finally:
        cell.close()
    if problems:
        raise HardwareError(f"the check failed: {'; '.join(problems)}")
    return 0


def _replay(args: argparse.Namespace) -> int:
    """Capture every camera of a dry-run cell and print each frame's depth coverage and the perceived object."""
    from seggrasp.perception import perceive_object  # perception is only needed here

    cell = RealCell.from_config(args.config, dry_run=True)
    try:
        frames = cell.capture()
        workspace = cell.workspace
    finally:
        cell.close()
    cameras = []
    for camera, frame in zip(cell.config.cameras, frames):
        valid = frame.depth > 0
        cameras.append({"name": frame.name, "serial": camera.serial,
                        "recording": str(camera.recording) if camera.recording else None,
                        "size": [frame.rgb.shape[1], frame.rgb.shape[0]],
                        "depth_fraction": round(float(valid.mean()), 4),
                        "median_depth": round(float(np.median(frame.depth[valid])), 4) if valid.any() else 0.0})
    mesh = perceive_object(frames, workspace)
    found = {"bounds": np.round(mesh.bounds, 4).tolist(), "extents": np.round(mesh.extents, 4).tolist(),
             "faces": int(len(mesh.faces)), "volume": round(float(mesh.volume), 7) if mesh.is_watertight else None}
    if args.mesh:
        mesh.export(args.mesh)
    if args.json:
        print(json.dumps({"cameras": cameras, "object": found}))
        return 0
    for entry in cameras:
        plays = f", plays {entry['recording']}" if entry["recording"] else ""
        print(f"camera {entry['name']} ({entry['serial']}{plays}): {entry['size'][0]}x{entry['size'][1]}, "
              f"{entry['depth_fraction']:.0%} depth, median {entry['median_depth']:.3f} m")
    volume = f", volume {found['volume'] * 1e6:.1f} cm^3" if found["volume"] is not None else ""
    print(f"object: bounds {found['bounds']} m, extents {found['extents']} m, {found['faces']} faces{volume}"
          + (f"; mesh written to {args.mesh}" if args.mesh else ""))
    return 0


def _gripper_problems(state: GripperState) -> list[str]:
    """A fault the connected (and, by `RealCell.from_config`, activated) gripper reports, as a sentence part."""
    if state.fault:
        return [f"the gripper reports fault {state.fault} ({FAULTS.get(state.fault, 'unknown fault')}); clear it "
                "(RobotiqGripper.clear_fault() resets and activates it, the fingers move) and check again"]
    return []


def _check_cameras(config: CellConfig, cell: RealCell) -> list[str]:
    """Start each camera, print what one frame holds and stop it; the cameras that failed, as sentence parts."""
    problems = []
    for camera_config in config.cameras:
        camera = RealSenseCamera(camera_config)
        try:
            camera.start()
            frame = camera.capture(cell.arm.tcp_pose() if camera_config.mount == "wrist" else None)
        except HardwareError as exc:
            print(f"camera {camera_config.name}: FAILED: {exc}")
            problems.append(str(exc) + (" (a dry run still uses the cameras)" if cell.dry_run else ""))
            continue
        finally:
            camera.stop()
        valid = frame.depth > 0
        print(f"camera {frame.name}: {frame.rgb.shape[1]}x{frame.rgb.shape[0]}, {valid.mean():.0%} depth, "
              f"median {np.median(frame.depth[valid]) if valid.any() else 0:.3f} m")
    return problems


def _read_poses(path: Path) -> list[np.ndarray]:
    data = read_yaml(path, "poses file")
    if not isinstance(data, dict) or not isinstance(data.get("poses"), list) or not data["poses"]:
        raise ValueError(f"{path}: expected 'poses:' with a list of 4x4 matrices or {{xyz, rpy}} entries")
    if len(data["poses"]) > MAX_CALIBRATION_POSES:
        raise ValueError(f"{path}: {len(data['poses'])} poses are more than the {MAX_CALIBRATION_POSES} a "
                         "calibration tour may list (10-30 with varied rotations are enough)")
    reader = FieldReader(str(path), data)
    return [reader.transform(pose, f"poses[{index}]") for index, pose in enumerate(data["poses"])]


def _calibration_output(args: argparse.Namespace, config: CellConfig) -> tuple[Path, dict]:
    """The calibration file to update (--out, calibration.file, or one beside the config) and what it holds now;
    checked before the robot moves."""
    out = args.out or config.calibration_file or config.path.parent / DEFAULT_CALIBRATION_FILE
    if out.is_dir():
        raise ValueError(f"calibration output {out} is a folder; give a file name")
    if not out.parent.is_dir() or not os.access(out.parent, os.W_OK):
        raise ValueError(f"cannot write the calibration file {out}: its folder does not exist or is not writable")
    existing = load_extrinsics(out) if out.exists() else {key: {} for key in EXTRINSIC_KEYS}
    return out, existing


def _calibrate(args: argparse.Namespace) -> int:
    try:
        columns, rows = (int(n) for n in args.board.lower().split("x"))
    except ValueError:
        raise ValueError(f"--board must be COLUMNSxROWS inner corners such as 7x6, got {args.board!r}") from None
    board = Checkerboard(columns, rows, args.square)
    poses = _read_poses(args.poses)
    config = load_config(args.config, require_calibration=False)
    camera_config = next((c for c in config.cameras if c.serial == args.serial), None)
    if camera_config is None:
        raise ValueError(f"camera {args.serial!r} is not in {args.config} (its serials: "
                         f"{', '.join(c.serial for c in config.cameras)})")
    wrist = camera_config.mount == "wrist"
    method = args.method or ("park" if wrist else "shah")
    if method not in (EYE_IN_HAND_METHODS if wrist else EYE_TO_HAND_METHODS):
        raise ValueError(f"--method {method} does not solve the {camera_config.mount}-mounted case")
    out, extrinsics = _calibration_output(args, config)
    motion = config.motion
    if args.dry_run:  # check and log the tour only: a camera in front of a robot that does not move sees nothing new
        cell = RealCell.from_config(args.config, dry_run=True, require_calibration=False, with_cameras=False)
        try:
            for pose in poses:
                cell.arm.move_linear(pose, motion.tool_speed, motion.tool_acceleration)
        finally:
            cell.close()
        print(f"dry run: all {len(poses)} calibration poses are within the limits; nothing moved (the result would "
              f"go to {out}{_unused_hint(config, out)})")
        return 0
    cell = RealCell.from_config(args.config, require_calibration=False)
    try:
        camera = next(c for c in cell.cameras if c.config.serial == args.serial)
        grippers, boards = collect_samples(cell.arm, lambda: camera.capture(cell.arm.tcp_pose()), poses, board,
                                           speed=motion.tool_speed, acceleration=motion.tool_acceleration)
        cell.arm.move_joints(config.robot.home_joints, motion.joint_speed, motion.joint_acceleration)
    finally:
        cell.close()
    if len(boards) < 3:
        raise ValueError(f"the board was seen in only {len(boards)} of {len(poses)} poses; need at least 3")
    if wrist:
        key, T = "T_gripper_cam", calibrate_eye_in_hand(grippers, boards, method)
        residual = eye_in_hand_residual(T, grippers, boards)
    else:
        key = "T_world_cam"
        T, T_gripper_target = calibrate_eye_to_hand(grippers, boards, method)
        residual = eye_to_hand_residual(T, T_gripper_target, grippers, boards)
    for other in EXTRINSIC_KEYS:  # a camera has one calibration: drop an old one of the other kind
        extrinsics[other].pop(args.serial, None)
    extrinsics[key][args.serial] = T
    save_extrinsics(out, extrinsics, {"last_calibrated": args.serial, "method": method, "samples": len(boards),
                                      "residual_m": round(residual, 6)})
    print(f"camera {args.serial}: {key} written to {out} ({len(boards)}/{len(poses)} poses, "
          f"residual {residual * 1000:.2f} mm){_unused_hint(config, out)}")
    return 0


def _unused_hint(config: CellConfig, out: Path) -> str:
    """What to change so the config reads `out`, when it does not name it as its calibration.file."""
    if config.calibration_file is not None and config.calibration_file.resolve() == out.resolve():
        return ""
    return (f"; {config.path} does not read it yet: make its calibration section `file: "
            f"{os.path.relpath(out, config.path.parent)}` in place of any inline matrices")


def _grasp(args: argparse.Namespace) -> int:
    """One grasp; a grasp the cell refuses (limits, reach, width) is exit code 1 with the reason on stderr."""
    if not all(map(math.isfinite, [*args.at, args.yaw])):
        raise ValueError(f"--at and --yaw must be finite numbers, got --at {args.at} --yaw {args.yaw}")
    if abs(args.yaw) > 2 * math.pi:
        raise ValueError(f"--yaw must be within [-2 pi, 2 pi] rad, got {args.yaw:g}")
    if not (math.isfinite(args.width) and 0 <= args.width <= 1):
        raise ValueError(f"--width must be the object's width in metres (0-1; the 2F-85 opens "
                         f"{ROBOTIQ_2F85.stroke:g}), got {args.width:g}")
    config = load_config(args.config)
    arm = ARM_MODELS[config.robot.model]
    reach = arm.reach + float(np.linalg.norm(config.robot.T_flange_gripper[:3, 3]))
    distance = math.dist(args.at, arm.shoulder)  # scaled: no overflow at 1e308
    if distance > reach:
        raise ValueError(f"--at {[float(f'{v:.4g}') for v in args.at]} is {distance:.3g} m from the "
                         f"{config.robot.model.upper()}'s shoulder, beyond its reach ({reach:.3f} m with the tool)")
    T = np.eye(4)
    T[:3, :3] = (Rotation.from_euler("z", args.yaw) * Rotation.from_euler("x", np.pi)).as_matrix()
    T[:3, 3] = args.at
    cell = RealCell.from_config(args.config, dry_run=args.dry_run, with_cameras=False)
    try:
        cell.reset()
        outcome = cell.execute(T, args.width)
    finally:
        cell.close()
    print(json.dumps(outcome.to_json(), indent=2))
    if not outcome.reachable:
        print(f"error: grasp refused{' (dry run)' if args.dry_run else ''}: {outcome.message}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the exit code (1 with a message on bad input, a hardware failure or a refused
    grasp)."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return {"check": _check, "calibrate": _calibrate, "grasp": _grasp, "replay": _replay}[args.command](args)
    except (ConfigError, ValueError, HardwareError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # e.g. the calibration file's disk is full or was made read-only meanwhile
        print(f"error: {exc.filename + ': ' if exc.filename else ''}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
