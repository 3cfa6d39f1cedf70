"""The cell configuration: one YAML file for the robot, gripper, cameras, calibration, limits and workspace.

`load_config(path)` reads and validates the file; every problem is reported as a `ConfigError` (a `ValueError`)
in one sentence naming the file, the line and the field, e.g.
``cell.yaml:58: limits.max_tool_speed: must be a positive number, got -1``. Unknown keys are errors too, so a typo
cannot silently drop a limit, and so are duplicated keys and base-60 numbers (the strict reader in
`hardware/fields.py`). Speeds, accelerations, forces and the stroke are bounded by what the UR5/UR5e and the 2F-85
can do (the constants below), times by what a cell can sensibly wait. The workspace box must be within the arm's
reach and clear of the robot's base column. See `hardware/cell.example.yaml`.
"""

from __future__ import annotations

import ipaddress
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hardware.calibration import load_extrinsics
from hardware.fields import ConfigError, FieldReader, read_yaml, shown
from hardware.kinematics import ARM_MODELS
from seggrasp.cell import DEFAULT_GRIP_FORCE, FINGER_SPEED_RANGE, GRIP_FORCE_RANGE
from seggrasp.hands import ROBOTIQ_2F85

#: Arm models whose nominal kinematics (hardware/kinematics.py) the joint-path safety check knows.
UR_MODELS = tuple(ARM_MODELS)
#: The 2F-85's numbers (stroke, finger speed and grip force ranges, default force) are its hand description's,
#: `seggrasp.hands.ROBOTIQ_2F85`. A measured `gripper.stroke` (the opening between the pads when fully open) may fall
#: short of the datasheet stroke with thicker custom pads, down to half.
STROKE_2F85 = ROBOTIQ_2F85.stroke
STROKE_RANGE = (0.5 * STROKE_2F85, 1.03 * STROKE_2F85)
#: UR5 (CB3) and UR5e datasheets: every joint turns at up to 180 deg/s (3.14 rad/s); the tool ("TCP speed,
#: typical") at up to 1 m/s.
UR_JOINT_SPEED_MAX = 3.14
UR_TOOL_SPEED_MAX = 1.0
#: Neither datasheet gives an acceleration. These are the largest the controller interface takes: ur_rtde 1.6.5
#: raises for moveJ a > 40 rad/s^2 and moveL a > 150 m/s^2 (bridge audit, section 1), so a larger limit would be
#: planned by a dry run and fail at the robot's first motion.
UR_JOINT_ACCELERATION_MAX = 40.0
UR_TOOL_ACCELERATION_MAX = 150.0
#: Longest waits (s) a config may set. A motion that the cell's speeds plan to take longer than MAX_MOTION_TIMEOUT
#: is a configuration mistake (the UR5 crosses its whole reach in seconds), and so is a gripper reply or finger
#: settle margin beyond MAX_GRIPPER_TIMEOUT (the URCap answers within milliseconds, a full 2F-85 stroke takes
#: stroke / slowest finger speed, 4.25 s). The hold is ten times the twin's 1 s at most: longer only delays the
#: verdict.
MAX_MOTION_TIMEOUT = 300.0
MAX_GRIPPER_TIMEOUT = 60.0
MAX_HOLD_TIME = 10.0
#: A joint move the cell may make (home from a grasp): at most half a turn of the leading joint.
LONGEST_JOINT_MOVE = math.pi
_HOST_LABEL = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?")


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
    timeout: float  # s, per socket reply; a finger motion may take its travel at the commanded speed plus this
    speed: float  # m/s finger speed used for grasps (the 2F-85 does 0.02-0.15)
    force: float  # N grip force used for grasps (within the 2F-85's GRIP_FORCE_RANGE)
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
    recording: Path | None = None  # a pyrealsense2 .db3 recording played instead of the live camera

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
    emulator: dict | None = None  # the `emulator:` section: this cell is emulated by `python -m sim.lab`


_TOP_KEYS = {"robot", "gripper", "cameras", "calibration", "workspace", "table", "limits", "motion", "interactive",
             "emulator"}


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
    r = FieldReader(str(path), data)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping with sections {sorted(_TOP_KEYS)}")
    r.check_keys(data, "", _TOP_KEYS)

    robot = _parse_robot(r, data)
    gripper = _parse_gripper(r, data, robot.ip)
    limits = _parse_limits(r, data)
    _check_workspace_reach(r, limits, robot)
    motion = _parse_motion(r, data, limits, gripper)
    _check_motion_timeout(r, robot, limits, motion)
    cameras = _parse_cameras(r, data, path, require_calibration)
    emulator = data.get("emulator")
    if emulator is not None and not isinstance(emulator, dict):
        raise r.error("emulator", f"must be a mapping of `python -m sim.lab serve` options, got {shown(emulator)}")
    return CellConfig(path=path, robot=robot, gripper=gripper, cameras=cameras, limits=limits, motion=motion,
                      interactive=r.boolean(data, "interactive", "", False),
                      calibration_file=_calibration_file(r, data.get("calibration") or {}, path),
                      emulator=None if emulator is None else dict(emulator))


def _parse_robot(r: FieldReader, data: dict) -> RobotConfig:
    section = r.section(data, "robot", "", {"ip", "model", "home_joints", "tcp_offset", "motion_timeout"})
    ip = _host(r, section, "ip", "robot.")
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
                       motion_timeout=r.number(section, "motion_timeout", "robot.", 30.0, positive=True,
                                               high=MAX_MOTION_TIMEOUT))


def _host(r: FieldReader, section: dict, key: str, prefix: str, default: str | None = None) -> str:
    """An IPv4 address or a DNS host name: all-numeric dotted text must be a usable IPv4 address (``256.300.1.999``
    and ``0`` are not), a name must be one a resolver takes (labels of letters, digits and inner hyphens)."""
    name = f"{prefix}{key}"
    value = section.get(key, default)
    if value is None:
        raise r.error(name, "missing (the controller's IP address or host name)")
    if not isinstance(value, str) or not value.strip():
        raise r.error(name, f"must be an IP address or host name, got {shown(value)}")
    host = value.strip()
    labels = host.split(".")
    if all(label.isdigit() for label in labels):
        try:
            address = ipaddress.IPv4Address(host)
        except ValueError:
            raise r.error(name, f"{host!r} is not an IPv4 address (four numbers 0-255 such as 192.168.1.10)") \
                from None
        if address.is_unspecified or address.is_multicast or address == ipaddress.IPv4Address("255.255.255.255"):
            raise r.error(name, f"{host} is not the address of one machine (unspecified, multicast or broadcast)")
        return host
    if len(host) > 253 or not all(_HOST_LABEL.fullmatch(label) for label in labels):
        raise r.error(name, f"must be an IP address or host name (letters, digits, inner hyphens, dots), got "
                      f"{shown(host)}")
    return host


def _parse_gripper(r: FieldReader, data: dict, robot_ip: str) -> GripperConfig:
    section = r.section(data, "gripper", "", {"host", "port", "stroke", "open_register", "closed_register",
                                              "timeout", "speed", "force", "tip_beyond_origin", "closing_shift"})
    p = "gripper."
    config = GripperConfig(
        host=_host(r, section, "host", p, robot_ip),
        port=r.integer(section, "port", p, 63352, low=1, high=65535),
        stroke=r.number(section, "stroke", p, STROKE_2F85, positive=True),
        open_register=r.integer(section, "open_register", p, 3, low=0, high=255),
        closed_register=r.integer(section, "closed_register", p, 230, low=0, high=255),
        timeout=r.number(section, "timeout", p, 5.0, positive=True, high=MAX_GRIPPER_TIMEOUT),
        speed=r.number(section, "speed", p, 0.05, low=FINGER_SPEED_RANGE[0], high=FINGER_SPEED_RANGE[1]),
        force=r.number(section, "force", p, DEFAULT_GRIP_FORCE, low=GRIP_FORCE_RANGE[0], high=GRIP_FORCE_RANGE[1]),
        tip_beyond_origin=r.number(section, "tip_beyond_origin", p, 0.02, non_negative=True),
        closing_shift=r.number(section, "closing_shift", p, 0.0),
    )
    if abs(config.closing_shift) > 0.05:
        raise r.error("gripper.closing_shift", f"{config.closing_shift} m is implausible for a 2F-85 (|shift| <= 0.05)")
    if config.closed_register <= config.open_register:
        raise r.error("gripper.closed_register", "must be greater than gripper.open_register")
    if not STROKE_RANGE[0] <= config.stroke <= STROKE_RANGE[1]:
        raise r.error("gripper.stroke", f"{config.stroke:g} m is not a 2F-85's opening between the pads (metres: "
                      f"{STROKE_RANGE[0]:.4g}-{STROKE_RANGE[1]:.4g}, datasheet stroke {STROKE_2F85:g})")
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
    for name, value, cap, unit, source in (
            ("max_tool_speed", limits.max_tool_speed, UR_TOOL_SPEED_MAX, "m/s", "the UR5/UR5e's datasheet tool speed"),
            ("max_joint_speed", limits.max_joint_speed, UR_JOINT_SPEED_MAX, "rad/s",
             "the UR5/UR5e's datasheet joint speed"),
            ("max_tool_acceleration", limits.max_tool_acceleration, UR_TOOL_ACCELERATION_MAX, "m/s^2",
             "the largest tool acceleration the UR controller interface accepts"),
            ("max_joint_acceleration", limits.max_joint_acceleration, UR_JOINT_ACCELERATION_MAX, "rad/s^2",
             "the largest joint acceleration the UR controller interface accepts")):
        if value > cap:
            raise r.error(f"limits.{name}", f"{value:g} {unit} is above {source} ({cap:g} {unit})")
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
        hold_time=r.number(section, "hold_time", p, 1.0, low=0.0, high=MAX_HOLD_TIME),
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


def _motion_time(distance: float, speed: float, acceleration: float) -> float:
    """Seconds a trapezoidal (or, when too short to reach `speed`, triangular) profile takes over `distance`."""
    if distance * acceleration >= speed ** 2:
        return distance / speed + speed / acceleration
    return 2.0 * math.sqrt(distance / acceleration)


def _check_motion_timeout(r: FieldReader, robot: RobotConfig, limits: Limits, motion: MotionConfig) -> None:
    """Refuse speeds so slow that an ordinary motion (a straight move across the workspace box's diagonal, half a
    turn of a joint) would outlast `robot.motion_timeout` and be stopped half way as a failure."""
    diagonal = float(np.linalg.norm(limits.workspace_max - limits.workspace_min))
    for field, what, duration in (
            ("motion.tool_speed", f"a straight move across the workspace ({diagonal:.2f} m) at "
             f"{motion.tool_speed:g} m/s", _motion_time(diagonal, motion.tool_speed, motion.tool_acceleration)),
            ("motion.joint_speed", f"half a joint turn at {motion.joint_speed:g} rad/s",
             _motion_time(LONGEST_JOINT_MOVE, motion.joint_speed, motion.joint_acceleration))):
        if duration > robot.motion_timeout:
            raise r.error(field, f"{what} takes {duration:.3g} s, longer than robot.motion_timeout "
                          f"({robot.motion_timeout:g} s): speed the motion up or raise the timeout (at most "
                          f"{MAX_MOTION_TIMEOUT:g} s)")


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
        r.check_keys(entry, p, {"serial", "name", "width", "height", "fps", "mount", "recording"})
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
            recording=_recording(r, entry, p, path),
        ))
    serials = [c.serial for c in cameras]
    if len(set(serials)) != len(serials):
        raise r.error("cameras", f"serial numbers must be distinct, got {serials}")
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise r.error("cameras", f"camera names must be distinct, got {names}")
    return tuple(cameras)


def _recording(r: FieldReader, entry: dict, prefix: str, path: Path) -> Path | None:
    """cameras[i].recording resolved against the config's folder (`~` expanded); it need not exist yet (the
    emulated cell writes it after the first placement; the camera names a missing file when it starts)."""
    if "recording" not in entry:
        return None
    recording = Path(r.string(entry, "recording", prefix)).expanduser()
    if recording.suffix != ".db3":
        raise r.error(f"{prefix}recording", "must be a .db3 file (pyrealsense2 2.59 plays and records ROS 2 .db3 "
                      f"bags only), got {shown(str(recording))}")
    return recording if recording.is_absolute() else path.parent / recording


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

