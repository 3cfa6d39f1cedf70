"""RealSense cameras over pyrealsense2: one pipeline per serial, depth aligned to colour, returned as `Frame`s.

Each camera streams RGB (rgb8) and depth (z16); `rs.align(rs.stream.color)` resamples depth into the colour
camera, so one K (the colour intrinsics) describes both images. Depth is converted to float32 metres with the
device's depth scale (0 stays 0 = no reading). `T_world_cam` comes from the calibration (colour optical frame,
which is the OpenCV convention: x right, y down, z forward); a wrist-mounted camera's is the gripper pose at the
capture times its calibrated `T_gripper_cam`.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from hardware.config import CameraConfig
from hardware.errors import ConnectionLostError
from seggrasp.cell import Frame

log = logging.getLogger(__name__)


def intrinsics_to_K(intrinsics: Any) -> np.ndarray:
    """pyrealsense2 `intrinsics` (fx, fy, ppx, ppy) -> 3x3 pinhole matrix."""
    return np.array([[intrinsics.fx, 0.0, intrinsics.ppx],
                     [0.0, intrinsics.fy, intrinsics.ppy],
                     [0.0, 0.0, 1.0]], dtype=np.float64)


class RealSenseCamera:
    """One RealSense camera. `pipeline` and `align` default to the pyrealsense2 objects (tests pass fakes)."""

    def __init__(self, config: CameraConfig, *, pipeline: Any = None, align: Any = None, warmup_frames: int = 15,
                 timeout_ms: int = 5000) -> None:
        self.config = config
        self._pipeline = pipeline
        self._align = align
        self.warmup_frames = warmup_frames
        self.timeout_ms = timeout_ms
        self.K: np.ndarray | None = None
        self.depth_scale: float | None = None
        self._running = False

    @property
    def name(self) -> str:
        return self.config.name

    def start(self) -> None:
        """Start streaming from this serial, read intrinsics and depth scale, and let auto-exposure settle."""
        import pyrealsense2 as rs

        if self._pipeline is None:
            self._pipeline = rs.pipeline()
        if self._align is None:
            self._align = rs.align(rs.stream.color)
        stream_config = rs.config()
        stream_config.enable_device(self.config.serial)
        stream_config.enable_stream(rs.stream.depth, self.config.width, self.config.height, rs.format.z16,
                                    self.config.fps)
        stream_config.enable_stream(rs.stream.color, self.config.width, self.config.height, rs.format.rgb8,
                                    self.config.fps)
        try:
            profile = self._pipeline.start(stream_config)
        except RuntimeError as exc:
            raise ConnectionLostError(f"cannot start RealSense camera {self.config.serial} ({self.name}): {exc}") \
                from exc
        self._running = True
        self.depth_scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
        intrinsics = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.K = intrinsics_to_K(intrinsics)
        if np.any(np.abs(np.asarray(intrinsics.coeffs, dtype=float)) > 1e-6):
            log.warning("camera %s reports non-zero distortion %s; frames are used undistorted",
                        self.name, list(intrinsics.coeffs))
        for _ in range(self.warmup_frames):
            self._wait_for_frames()
        log.info("camera %s (%s) started: %dx%d, depth scale %.6f m", self.name, self.config.serial,
                 self.config.width, self.config.height, self.depth_scale)

    def _wait_for_frames(self) -> Any:
        try:
            return self._pipeline.wait_for_frames(self.timeout_ms)
        except RuntimeError as exc:
            raise ConnectionLostError(f"RealSense camera {self.config.serial} ({self.name}) delivered no frames "
                                      f"within {self.timeout_ms} ms: {exc}") from exc

    def capture(self, T_world_gripper: np.ndarray | None = None) -> Frame:
        """One aligned RGB-D frame as a `seggrasp.cell.Frame` (depth in metres, 0 = no reading).

        A wrist-mounted camera needs the gripper's pose at the moment of capture to place the frame in the world.
        """
        if not self._running or self.K is None or self.depth_scale is None:
            raise ConnectionLostError(f"camera {self.name} is not streaming (call start() first)")
        frames = self._align.process(self._wait_for_frames())
        color, depth = frames.get_color_frame(), frames.get_depth_frame()
        if not color or not depth:
            raise ConnectionLostError(f"camera {self.name} returned an incomplete frame set")
        rgb = np.array(np.asanyarray(color.get_data()), dtype=np.uint8, copy=True)
        raw_depth = np.asanyarray(depth.get_data())
        if rgb.ndim != 3 or rgb.shape[2] != 3 or raw_depth.shape != rgb.shape[:2]:
            raise ConnectionLostError(f"camera {self.name}: colour {rgb.shape} and aligned depth {raw_depth.shape} "
                                      "do not match")
        return Frame(name=self.name, rgb=rgb, depth=(raw_depth.astype(np.float32) * np.float32(self.depth_scale)),
                     K=self.K.copy(), T_world_cam=self.config.T_world_cam(T_world_gripper))

    def stop(self) -> None:
        """Stop streaming. Safe to call more than once."""
        if self._running:
            try:
                self._pipeline.stop()
            except RuntimeError as exc:
                log.warning("stopping camera %s failed: %s", self.name, exc)
            self._running = False
