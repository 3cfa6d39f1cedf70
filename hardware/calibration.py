"""Camera extrinsics: the calibration file, checkerboard pose detection and hand-eye calibration (OpenCV).

The calibration file is YAML: ``T_world_cam: {<serial>: <4x4 matrix>}`` for table-mounted cameras (colour optical
frame -> world, the world being the robot base frame) and ``T_gripper_cam: {<serial>: <4x4 matrix>}`` for
wrist-mounted ones, plus free-form ``metadata``. Two hand-eye problems are solved with OpenCV:

- table-mounted camera, checkerboard held by the gripper (eye-to-hand): `calibrate_eye_to_hand` solves
  ``T_cam_target @ T_target_gripper = T_cam_base @ T_base_gripper`` with `cv2.calibrateRobotWorldHandEye`
  (the camera plays OpenCV's camera, the target its "world", the gripper its "base" and the robot base its
  "gripper") and returns ``T_base_cam`` = `T_world_cam`;
- wrist-mounted camera, checkerboard on the table (eye-in-hand): `calibrate_eye_in_hand` returns
  ``T_gripper_cam`` with `cv2.calibrateHandEye`.

`collect_samples` drives the arm through a list of gripper poses (every motion goes through the safety guard) and
records the gripper pose with the checkerboard pose seen by one camera at each stop; it serves both problems.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np
import yaml

from hardware.fields import FieldReader, read_yaml
from seggrasp.io import atomic_write_text

log = logging.getLogger(__name__)

#: What a calibration file holds per camera serial: table-mounted cameras' pose in the world, wrist-mounted
#: cameras' pose in the gripper frame.
EXTRINSIC_KEYS = ("T_world_cam", "T_gripper_cam")
EYE_TO_HAND_METHODS = {"shah": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH, "li": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI}
EYE_IN_HAND_METHODS = {"tsai": cv2.CALIB_HAND_EYE_TSAI, "park": cv2.CALIB_HAND_EYE_PARK,
                       "horaud": cv2.CALIB_HAND_EYE_HORAUD, "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
                       "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS}


# ------------------------------------------------------------------------------------------------ calibration file
def load_extrinsics(path: str | Path) -> dict[str, dict[str, np.ndarray]]:
    """Read a calibration file: {"T_world_cam": {serial: 4x4}, "T_gripper_cam": {serial: 4x4}} (either may be
    empty, not both); raises `ValueError` naming the file and the entry on bad input."""
    path = Path(path)
    data = read_yaml(path, "calibration file")
    if not isinstance(data, dict):
        data = {}
    r = FieldReader(str(path), data)
    unknown = sorted(set(map(str, data)) - {*EXTRINSIC_KEYS, "metadata"})
    if unknown:
        raise r.error(unknown[0], f"unknown key in the calibration file (allowed: {', '.join(EXTRINSIC_KEYS)}, "
                      "metadata)")
    extrinsics: dict[str, dict[str, np.ndarray]] = {}
    for key in EXTRINSIC_KEYS:
        entries = data.get(key) or {}
        if not isinstance(entries, dict):
            raise r.error(key, "must map camera serials to 4x4 matrices")
        extrinsics[key] = {str(serial): r.transform(T, f"{key}.{serial}") for serial, T in entries.items()}
    if not any(extrinsics.values()):
        raise ValueError(f"calibration file {path} must contain 'T_world_cam: {{<serial>: <4x4 matrix>}}' "
                         "(table-mounted cameras) and/or 'T_gripper_cam: {...}' (wrist-mounted cameras)")
    return extrinsics


def save_extrinsics(path: str | Path, extrinsics: dict[str, dict[str, np.ndarray]],
                    metadata: dict | None = None) -> None:
    """Write (atomically) a calibration file that `load_extrinsics` reads back."""
    unknown = set(extrinsics) - set(EXTRINSIC_KEYS)
    if unknown:
        raise ValueError(f"unknown extrinsic kinds {sorted(unknown)}; use {EXTRINSIC_KEYS}")
    document: dict[str, Any] = {key: {str(serial): np.asarray(T, dtype=float).round(9).tolist()
                                      for serial, T in extrinsics[key].items()}
                                for key in EXTRINSIC_KEYS if extrinsics.get(key)}
    if metadata:
        document["metadata"] = metadata
    atomic_write_text(path, yaml.safe_dump(document, sort_keys=False))


# ------------------------------------------------------------------------------------------------ hand-eye solvers
def _split(transforms: Sequence[np.ndarray], name: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    rotations, translations = [], []
    for index, T in enumerate(transforms):
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"{name}[{index}] must be a finite 4x4 matrix, got shape {T.shape}")
        rotations.append(T[:3, :3].copy())
        translations.append(T[:3, 3].reshape(3, 1).copy())
    return rotations, translations


def _join(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).reshape(3)
    return T


def _check_samples(T_base_gripper: Sequence[np.ndarray], T_cam_target: Sequence[np.ndarray]) -> None:
    if len(T_base_gripper) != len(T_cam_target):
        raise ValueError(f"got {len(T_base_gripper)} gripper poses but {len(T_cam_target)} target poses")
    if len(T_base_gripper) < 3:
        raise ValueError(f"hand-eye calibration needs at least 3 poses (use 10+ with varied rotations), "
                         f"got {len(T_base_gripper)}")


def _solver_failed(method: str, samples: int, exc: cv2.error) -> ValueError:
    return ValueError(f"the {method} hand-eye solver failed on these {samples} samples (vary the rotations between "
                      f"poses): {exc.err or exc}")


def calibrate_eye_to_hand(T_base_gripper: Sequence[np.ndarray], T_cam_target: Sequence[np.ndarray],
                          method: str = "shah") -> tuple[np.ndarray, np.ndarray]:
    """Fixed camera, target on the gripper: returns (T_base_cam, T_gripper_target)."""
    _check_samples(T_base_gripper, T_cam_target)
    if method not in EYE_TO_HAND_METHODS:
        raise ValueError(f"unknown eye-to-hand method {method!r}; choose from {sorted(EYE_TO_HAND_METHODS)}")
    R_target, t_target = _split(T_cam_target, "T_cam_target")
    R_gripper, t_gripper = _split(T_base_gripper, "T_base_gripper")
    try:
        R_target_gripper, t_target_gripper, R_cam_base, t_cam_base = cv2.calibrateRobotWorldHandEye(
            R_target, t_target, R_gripper, t_gripper, method=EYE_TO_HAND_METHODS[method])
    except cv2.error as exc:
        raise _solver_failed(method, len(R_target), exc) from None
    T_base_cam = np.linalg.inv(_join(R_cam_base, t_cam_base))
    T_gripper_target = np.linalg.inv(_join(R_target_gripper, t_target_gripper))
    return T_base_cam, T_gripper_target


def calibrate_eye_in_hand(T_base_gripper: Sequence[np.ndarray], T_cam_target: Sequence[np.ndarray],
                          method: str = "park") -> np.ndarray:
    """Camera on the wrist, target fixed on the table: returns T_gripper_cam."""
    _check_samples(T_base_gripper, T_cam_target)
    if method not in EYE_IN_HAND_METHODS:
        raise ValueError(f"unknown eye-in-hand method {method!r}; choose from {sorted(EYE_IN_HAND_METHODS)}")
    R_gripper, t_gripper = _split(T_base_gripper, "T_base_gripper")
    R_target, t_target = _split(T_cam_target, "T_cam_target")
    try:
        R, t = cv2.calibrateHandEye(R_gripper, t_gripper, R_target, t_target, method=EYE_IN_HAND_METHODS[method])
    except cv2.error as exc:
        raise _solver_failed(method, len(R_target), exc) from None
    return _join(R, t)


def eye_to_hand_residual(T_base_cam: np.ndarray, T_gripper_target: np.ndarray,
                         T_base_gripper: Sequence[np.ndarray], T_cam_target: Sequence[np.ndarray]) -> float:
    """RMS distance (m) between the target origin as observed and as predicted by the calibration."""
    errors = []
    for T_bg, T_ct in zip(T_base_gripper, T_cam_target):
        predicted = (np.linalg.inv(T_base_cam) @ T_bg @ T_gripper_target)[:3, 3]
        errors.append(np.linalg.norm(predicted - np.asarray(T_ct)[:3, 3]))
    return float(np.sqrt(np.mean(np.square(errors))))


def eye_in_hand_residual(T_gripper_cam: np.ndarray, T_base_gripper: Sequence[np.ndarray],
                         T_cam_target: Sequence[np.ndarray]) -> float:
    """RMS distance (m) of the fixed target's origin, as each sample places it, from their mean."""
    origins = np.array([(np.asarray(T_bg) @ T_gripper_cam @ np.asarray(T_ct))[:3, 3]
                        for T_bg, T_ct in zip(T_base_gripper, T_cam_target)])
    return float(np.sqrt(np.mean(np.sum((origins - origins.mean(axis=0)) ** 2, axis=1))))


# ------------------------------------------------------------------------------------------------ target detection
#: Most inner corners a side of a printed calibration board (a camera resolves a few dozen at most).
MAX_BOARD_CORNERS = 50


@dataclass(frozen=True)
class Checkerboard:
    """A printed checkerboard: inner-corner counts (columns, rows) and square size in metres."""

    columns: int
    rows: int
    square: float

    def __post_init__(self) -> None:
        if not (3 <= self.columns <= MAX_BOARD_CORNERS and 3 <= self.rows <= MAX_BOARD_CORNERS
                and 0 < self.square < 1):  # metres; also refuses NaN
            raise ValueError(f"checkerboard needs 3-{MAX_BOARD_CORNERS} inner corners a side and a square size in "
                             f"metres (0-1), got {self.columns}x{self.rows} corners of {self.square:g} m")
        if (self.columns + self.rows) % 2 == 0:
            raise ValueError(f"checkerboard {self.columns}x{self.rows} inner corners looks the same turned by 180 "
                             "degrees, so its pose is ambiguous; use one even and one odd count (e.g. 7x6)")

    def object_points(self) -> np.ndarray:
        """Inner corners in the target frame (z = 0 plane, row-major as OpenCV returns them)."""
        grid = np.mgrid[0:self.columns, 0:self.rows].T.reshape(-1, 2) * self.square
        return np.hstack([grid, np.zeros((len(grid), 1))]).astype(np.float64)


def detect_checkerboard(rgb: np.ndarray, K: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """T_cam_target of a checkerboard in an RGB image (undistorted, intrinsics K), or None if not found."""
    gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCorners(gray, (board.columns, board.rows))
    if not found:
        return None
    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
    ok, rvec, tvec = cv2.solvePnP(board.object_points(), corners, np.asarray(K, dtype=np.float64), None)
    if not ok:
        return None
    return _join(cv2.Rodrigues(rvec)[0], tvec)


def collect_samples(arm: Any, capture: Callable[[], Any], poses: Sequence[np.ndarray], board: Checkerboard, *,
                    speed: float, acceleration: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Move through `poses` (T_world_gripper), `capture()` a frame at each, and return (T_base_gripper,
    T_cam_target) for the stops where the board was found."""
    gripper_poses, target_poses = [], []
    for index, pose in enumerate(poses):
        arm.move_linear(pose, speed, acceleration)
        frame = capture()
        T_cam_target = detect_checkerboard(frame.rgb, frame.K, board)
        if T_cam_target is None:
            log.warning("calibration pose %d: checkerboard not found by camera %s; skipped", index, frame.name)
            continue
        gripper_poses.append(arm.tcp_pose())
        target_poses.append(T_cam_target)
    log.info("calibration: board seen in %d of %d poses", len(target_poses), len(poses))
    return gripper_poses, target_poses
