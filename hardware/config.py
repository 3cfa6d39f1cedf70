"""The cell configuration: one YAML file for the robot, gripper, cameras, calibration, limits and workspace.

`load_config(path)` reads and validates the file; every problem is reported as a `ConfigError` (a `ValueError`)
that names the offending field, e.g. ``cell.yaml: limits.max_tool_speed: must be a positive number, got -1``.
Unknown keys are errors too, so a typo cannot silently drop a limit, and so are duplicated keys (the strict reader
in `hardware/fields.py`). The workspace box must be within the arm's reach and clear of the robot's base column.
See `hardware/cell.example.yaml`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hardware.calibration import load_extrinsics
from hardware.fields import ConfigError, FieldReader, read_yaml
from hardware.kinematics import ARM_MODELS
from seggrasp.cell import DEFAULT_GRIP_FORCE, GRIP_FORCE_RANGE

#: Arm models whose nominal kinematics (hardware/kinematics.py) the joint-path safety check knows.
UR_MODELS = tuple(ARM_MODELS)
#: The 2F-85's finger speed range (m/s, datasheet); its grip force range (N, `GRIP_FORCE_RANGE`) and the default
#: force are the ones the twin uses (`seggrasp.cell`). Registers 0-255 span each range linearly.
FINGER_SPEED_RANGE = (0.020, 0.150)
_HOST = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?")


@dataclass(frozen=True)
class RobotConfig:
    """The UR arm: address, model, home configuration and the tool (gripper) frame on the flange."""

    ip: str
    model: str
    home_joints: np.ndarray  # (6,) rad
    T_flange_gripper: np.ndarray  # (4, 4) the project's gripper frame (fingertip centre) in the flange frame
    motion_timeout: float  # s, longest a single motion may take before it is stopped


@dataclass(frozen=True)
class GripperConfig:
    """The Robotiq 2F-85 behind the URCap socket, and its width <-> register calibration."""

    host: str
    port: int
    stroke: float  # m, finger opening at `open_register`
    open_register: int  # POS register value read when fully open (about 3 after activation)
    closed_register: int  # POS register value read when closed on nothing (about 230 after activation)
    timeout: float  # s, per socket reply and per finger motion
    speed: float  # m/s finger speed used for grasps (the 2F-85 does 0.02-0.15)
    force: float  # N grip force used for grasps (the 2F-85 does 20-235)
    tip_beyond_origin: float  # m the fingertips reach past the gripper origin (pad centres) along +z
    closing_shift: float  # m the pad centres move along +z from fully open to closed (linkage arc), measured

    def pad_shift(self, width: float) -> float:
        """How far (m, along the gripper's +z) the pad centres sit at opening `width` relative to fully open.

        The 2F-85's fingers swing on an arc, so the pads move along the approach axis as they close; this is the
        linear interpolation of the measured `closing_shift` (0 when fully open).
        """
        return float(self.closing_shift * (1.0 - np.clip(width / self.stroke, 0.0, 1.0)))


CAMERA_MOUNTS = ("table", "wrist")


@dataclass(frozen=True)
class CameraConfig:
    """One RealSense camera, identified by its serial number, fixed in the cell ("table") or on the gripper.

    `T_mount_cam` is the colour optical frame (OpenCV) in its mount's frame: `T_world_cam` for a table-mounted
    camera, `T_gripper_cam` for a wrist-mounted one.
    """

    serial: str
    name: str
    width: int
    height: int
    fps: int
    mount: str
    T_mount_cam: np.ndarray  # (4, 4)

    def T_world_cam(self, T_world_gripper: np.ndarray | None = None) -> np.ndarray:
        """The camera's pose in the world; a wrist camera needs the gripper's pose."""
        if self.mount == "table":
            return self.T_mount_cam.copy()
        if T_world_gripper is None:
            raise ValueError(f"camera {self.name} is on the wrist: its pose needs the gripper's pose")
        return np.asarray(T_world_gripper, dtype=np.float64) @ self.T_mount_cam


@dataclass(frozen=True)
class Limits:
    """Safety limits: anything outside them is refused before a command is sent."""

    workspace_min: np.ndarray  # (3,) world-frame box the gripper origin, fingertips and flange must stay in
    workspace_max: np.ndarray  # (3,)
    table_height: float  # m, z of the table top in the world frame
    min_table_clearance: float  # m, lowest any fingertip or the flange may come above the table
    max_tool_speed: float  # m/s
    max_tool_acceleration: float  # m/s^2
    max_joint_speed: float  # rad/s
    max_joint_acceleration: float  # rad/s^2
    max_grip_force: float  # N


@dataclass(frozen=True)
class MotionConfig:
    """Speeds used by the cell (each must be within the limits) and the grasp sequence geometry."""

    tool_speed: float
    tool_acceleration: float
    joint_speed: float
    joint_acceleration: float
    pregrasp_distance: float  # m back along the approach axis
    lift_height: float  # m up in the world frame
    hold_time: float  # s held at the top before judging the grasp
    opening_margin: float  # m added to the grasp width for the approach


@dataclass(frozen=True)
class CellConfig:
    """Everything `RealCell` needs to know about the cell."""

    path: Path
    robot: RobotConfig
    gripper: GripperConfig
    cameras: tuple[CameraConfig, ...]
    limits: Limits
    motion: MotionConfig
    interactive: bool  # wait for Enter on reset (only when stdin is a terminal)
    calibration_file: Path | None = None  # calibration.file resolved against the config's folder, if given


_TOP_KEYS = {"robot", "gripper", "cameras", "calibration", "workspace", "table", "limits", "motion", "interactive"}


def load_config(path: str | Path, *, require_calibration: bool = True) -> CellConfig:
    """Read and validate a cell YAML file; raises `ConfigError` naming the field on any problem.

    With `require_calibration=False` (used to calibrate the cameras in the first place) the calibration section
    may be absent or incomplete; uncalibrated cameras get `T_mount_cam` = identity.
    """
    path = Path(path)
    data = read_yaml(path, "cell configuration file", ConfigError)
    return parse_config(data, path, require_calibration=require_calibration)


def parse_config(data: Any, path: Path, *, require_calibration: bool = True) -> CellConfig:
    """Validate already-parsed YAML `data`; `path` names the source in errors and anchors relative file paths."""
    r = FieldReader(str(path))
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping with sections {sorted(_TOP_KEYS)}")
    r.check_keys(data, "", _TOP_KEYS)

    robot = _parse_robot(r, data)
    gripper = _parse_gripper(r, data, robot.ip)
    limits = _parse_limits(r, data)
    _check_workspace_reach(r, limits, robot)
    motion = _parse_motion(r, data, limits, gripper)
    cameras = _parse_cameras(r, data, path, require_calibration)
    return CellConfig(path=path, robot=robot, gripper=gripper, cameras=cameras, limits=limits, motion=motion,
                      interactive=r.boolean(data, "interactive", "", False),
                      calibration_file=_calibration_file(r, data.get("calibration") or {}, path))


def _parse_robot(r: FieldReader, data: dict) -> RobotConfig:
    section = r.section(data, "robot", "", {"ip", "model", "home_joints", "tcp_offset", "motion_timeout"})
    ip = r.string(section, "ip", "robot.")
    if not _HOST.fullmatch(ip):
        raise r.error("robot.ip", f"must be an IP address or host name, got {ip!r}")
    model = r.string(section, "model", "robot.", "ur5").lower()
    if model not in UR_MODELS:
        raise r.error("robot.model", f"must be one of {UR_MODELS}, got {model!r}")
    if "home_joints" not in section:
        raise r.error("robot.home_joints", "missing (six joint angles in radians)")
    home = r.vector(section["home_joints"], "robot.home_joints", 6)
    if np.any(np.abs(home) > 2 * np.pi):
        raise r.error("robot.home_joints", "joint angles must be in radians within [-2 pi, 2 pi]")
    if "tcp_offset" not in section:
        raise r.error("robot.tcp_offset", "missing (the gripper frame in the flange frame, e.g. {xyz: [0, 0, 0.15]})")
    T_flange_gripper = r.transform(section["tcp_offset"], "robot.tcp_offset")
    if not 0.0 < T_flange_gripper[2, 3] < 0.5:
        raise r.error("robot.tcp_offset", "the fingertip centre must lie 0-0.5 m in front of the flange (+z)")
    return RobotConfig(ip=ip, model=model, home_joints=home, T_flange_gripper=T_flange_gripper,
                       motion_timeout=r.number(section, "motion_timeout", "robot.", 30.0, positive=True))


def _parse_gripper(r: FieldReader, data: dict, robot_ip: str) -> GripperConfig:
    section = r.section(data, "gripper", "", {"host", "port", "stroke", "open_register", "closed_register",
                                              "timeout", "speed", "force", "tip_beyond_origin", "closing_shift"})
    p = "gripper."
    config = GripperConfig(
        host=r.string(section, "host", p, robot_ip),
        port=r.integer(section, "port", p, 63352, low=1, high=65535),
        stroke=r.number(section, "stroke", p, 0.085, positive=True),
        open_register=r.integer(section, "open_register", p, 3, low=0, high=255),
        closed_register=r.integer(section, "closed_register", p, 230, low=0, high=255),
        timeout=r.number(section, "timeout", p, 5.0, positive=True),
        speed=r.number(section, "speed", p, 0.05, low=FINGER_SPEED_RANGE[0], high=FINGER_SPEED_RANGE[1]),
        force=r.number(section, "force", p, DEFAULT_GRIP_FORCE, low=GRIP_FORCE_RANGE[0], high=GRIP_FORCE_RANGE[1]),
        tip_beyond_origin=r.number(section, "tip_beyond_origin", p, 0.02, non_negative=True),
        closing_shift=r.number(section, "closing_shift", p, 0.0),
    )
    if not _HOST.fullmatch(config.host):
        raise r.error("gripper.host", f"must be an IP address or host name, got {config.host!r}")
    if abs(config.closing_shift) > 0.05:
        raise r.error("gripper.closing_shift", f"{config.closing_shift} m is implausible for a 2F-85 (|shift| <= 0.05)")
    if config.closed_register <= config.open_register:
        raise r.error("gripper.closed_register", "must be greater than gripper.open_register")
    if config.stroke > 0.2:
        raise r.error("gripper.stroke", f"{config.stroke} m is not a 2F gripper stroke (metres, e.g. 0.085)")
    return config


def _check_workspace_reach(r: FieldReader, limits: Limits, robot: RobotConfig) -> None:
    """Refuse a workspace box that reaches beyond the arm or into the robot's own base column.

    The gripper origin can be at most the arm's reach (flange from the shoulder) plus the tool offset from the
    shoulder, so a box corner farther than that can never be reached; and no part of the box may come within the
    base column's radius of the base axis (x = y = 0), where the gripper would drive into the robot itself.
    """
    arm = ARM_MODELS[robot.model]
    low, high = limits.workspace_min, limits.workspace_max
    corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])])
    distances = np.linalg.norm(corners - arm.shoulder, axis=1)
    tool = float(np.linalg.norm(robot.T_flange_gripper[:3, 3]))
    if distances.max() > arm.reach + tool:
        far = corners[int(np.argmax(distances))]
        raise r.error("workspace", f"corner {np.round(far, 3).tolist()} is {distances.max():.3f} m from the "
                      f"{robot.model.upper()}'s shoulder, beyond its reach ({arm.reach} m to the flange + "
                      f"{tool:.3f} m tool offset): shrink the box to what the arm can reach")
    nearest = np.clip(0.0, low[:2], high[:2])  # the point of the box's footprint closest to the base axis
    if np.linalg.norm(nearest) < arm.base_radius:
        raise r.error("workspace", f"the box comes within {np.linalg.norm(nearest):.3f} m of the robot's base axis "
                      f"(x = y = 0), inside its base column (radius {arm.base_radius} m): keep the box clear of "
                      "the robot itself")


def _parse_limits(r: FieldReader, data: dict) -> Limits:
    workspace = r.section(data, "workspace", "", {"min", "max"})
    for key in ("min", "max"):
        if key not in workspace:
            raise r.error(f"workspace.{key}", "missing (a world-frame corner [x, y, z] in metres)")
    low = r.vector(workspace["min"], "workspace.min", 3)
    high = r.vector(workspace["max"], "workspace.max", 3)
    if np.any(high <= low):
        raise r.error("workspace.max", f"must exceed workspace.min on every axis, got min {low} max {high}")
    table = r.section(data, "table", "", {"height"})
    table_height = r.number(table, "height", "table.")
    if not low[2] <= table_height < high[2]:
        raise r.error("table.height", f"must lie inside the workspace's z range [{low[2]}, {high[2]})")
    section = r.section(data, "limits", "", {"min_table_clearance", "max_tool_speed", "max_tool_acceleration",
                                             "max_joint_speed", "max_joint_acceleration", "max_grip_force"})
    p = "limits."
    limits = Limits(
        workspace_min=low,
        workspace_max=high,
        table_height=table_height,
        min_table_clearance=r.number(section, "min_table_clearance", p, 0.005, non_negative=True),
        max_tool_speed=r.number(section, "max_tool_speed", p, 0.25, positive=True),
        max_tool_acceleration=r.number(section, "max_tool_acceleration", p, 1.2, positive=True),
        max_joint_speed=r.number(section, "max_joint_speed", p, 1.05, positive=True),
        max_joint_acceleration=r.number(section, "max_joint_acceleration", p, 1.4, positive=True),
        max_grip_force=r.number(section, "max_grip_force", p, DEFAULT_GRIP_FORCE, positive=True),
    )
    if limits.max_tool_speed > 1.0:
        raise r.error("limits.max_tool_speed", f"{limits.max_tool_speed} m/s is above the 1 m/s the bridge allows")
    if limits.max_joint_speed > 3.14:
        raise r.error("limits.max_joint_speed", f"{limits.max_joint_speed} rad/s is above the UR5's 3.14 rad/s")
    return limits


def _parse_motion(r: FieldReader, data: dict, limits: Limits, gripper: GripperConfig) -> MotionConfig:
    section = r.section(data, "motion", "", {"tool_speed", "tool_acceleration", "joint_speed", "joint_acceleration",
                                             "pregrasp_distance", "lift_height", "hold_time", "opening_margin"},
                        required=False)
    p = "motion."
    motion = MotionConfig(
        tool_speed=r.number(section, "tool_speed", p, min(0.1, limits.max_tool_speed), positive=True),
        tool_acceleration=r.number(section, "tool_acceleration", p, min(0.5, limits.max_tool_acceleration),
                                   positive=True),
        joint_speed=r.number(section, "joint_speed", p, min(0.5, limits.max_joint_speed), positive=True),
        joint_acceleration=r.number(section, "joint_acceleration", p, min(0.8, limits.max_joint_acceleration),
                                    positive=True),
        pregrasp_distance=r.number(section, "pregrasp_distance", p, 0.10, positive=True),
        lift_height=r.number(section, "lift_height", p, 0.20, positive=True),
        hold_time=r.number(section, "hold_time", p, 1.0, non_negative=True),
        opening_margin=r.number(section, "opening_margin", p, 0.02, non_negative=True),
    )
    for name, value, cap in (("tool_speed", motion.tool_speed, limits.max_tool_speed),
                             ("tool_acceleration", motion.tool_acceleration, limits.max_tool_acceleration),
                             ("joint_speed", motion.joint_speed, limits.max_joint_speed),
                             ("joint_acceleration", motion.joint_acceleration, limits.max_joint_acceleration)):
        if value > cap:
            raise r.error(f"motion.{name}", f"{value} exceeds limits.max_{name} = {cap}")
    if gripper.force > limits.max_grip_force:
        raise r.error("gripper.force", f"{gripper.force} N exceeds limits.max_grip_force = {limits.max_grip_force}")
    return motion


def _parse_cameras(r: FieldReader, data: dict, path: Path, require_calibration: bool) -> tuple[CameraConfig, ...]:
    if "cameras" not in data:
        raise r.error("cameras", "missing (a list of {serial: ...} entries)")
    entries = data["cameras"]
    if not isinstance(entries, list) or not entries:
        raise r.error("cameras", "must be a non-empty list of {serial: ...} entries")
    extrinsics = _parse_calibration(r, data, path, require_calibration)
    cameras: list[CameraConfig] = []
    for index, entry in enumerate(entries):
        p = f"cameras[{index}]."
        if not isinstance(entry, dict):
            raise r.error(f"cameras[{index}]", f"must be a mapping with a serial, got {entry!r}")
        r.check_keys(entry, p, {"serial", "name", "width", "height", "fps", "mount"})
        serial = r.string(entry, "serial", p)
        mount = r.string(entry, "mount", p, "table")
        if mount not in CAMERA_MOUNTS:
            raise r.error(f"{p}mount", f"must be one of {CAMERA_MOUNTS}, got {mount!r}")
        key = "T_world_cam" if mount == "table" else "T_gripper_cam"
        if serial not in extrinsics[key] and require_calibration:
            raise r.error(f"{p}serial", f"no {key} for {mount}-mounted camera {serial} in the calibration")
        cameras.append(CameraConfig(
            serial=serial,
            name=r.string(entry, "name", p, f"cam{serial}"),
            width=r.integer(entry, "width", p, 640, low=1, high=4096),
            height=r.integer(entry, "height", p, 480, low=1, high=4096),
            fps=r.integer(entry, "fps", p, 30, low=1, high=300),
            mount=mount,
            T_mount_cam=extrinsics[key].get(serial, np.eye(4)),
        ))
    serials = [c.serial for c in cameras]
    if len(set(serials)) != len(serials):
        raise r.error("cameras", f"serial numbers must be distinct, got {serials}")
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise r.error("cameras", f"camera names must be distinct, got {names}")
    return tuple(cameras)


def _calibration_file(r: FieldReader, section: dict, path: Path) -> Path | None:
    """calibration.file resolved against the config's folder, or None when the calibration is inline/absent."""
    if "file" not in section:
        return None
    file = Path(r.string(section, "file", "calibration."))
    return file if file.is_absolute() else path.parent / file


def _parse_calibration(r: FieldReader, data: dict, path: Path, required: bool) -> dict[str, dict[str, np.ndarray]]:
    """{"T_world_cam": {serial: T}, "T_gripper_cam": {serial: T}} from the file or the inline matrices."""
    empty: dict[str, dict[str, np.ndarray]] = {"T_world_cam": {}, "T_gripper_cam": {}}
    section = r.section(data, "calibration", "", {"file", "T_world_cam", "T_gripper_cam"}, required=required)
    if not section and not required:
        return empty
    inline_keys = [key for key in empty if key in section]
    if ("file" in section) == bool(inline_keys):
        raise r.error("calibration", "give either calibration.file or inline calibration.T_world_cam / "
                      "calibration.T_gripper_cam, not both and not neither")
    if "file" in section:
        file = _calibration_file(r, section, path)
        if file is None or (not file.exists() and not required):
            return empty
        try:
            return load_extrinsics(file)
        except ValueError as exc:
            raise r.error("calibration.file", str(exc)) from None
    for key in inline_keys:
        inline = section[key]
        if not isinstance(inline, dict) or not inline:
            raise r.error(f"calibration.{key}", "must map camera serials to 4x4 matrices")
        empty[key] = {str(serial): r.transform(T, f"calibration.{key}.{serial}") for serial, T in inline.items()}
    return empty

