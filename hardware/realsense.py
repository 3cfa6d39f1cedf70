"""RealSense cameras over pyrealsense2: one pipeline per serial, depth aligned to colour, returned as `Frame`s.

Each camera streams RGB (rgb8) and depth (z16); `rs.align(rs.stream.color)` resamples depth into the colour
camera, so one K (the colour intrinsics) describes both images. Depth is converted to float32 metres with the
device's depth scale (0 stays 0 = no reading). `T_world_cam` comes from the calibration (colour optical frame,
which is the OpenCV convention: x right, y down, z forward); a wrist-mounted camera's is the gripper pose at the
capture times its calibrated `T_gripper_cam`.

A camera whose config names a `recording` (a ROS 2 `.db3` bag, as pyrealsense2 2.59's `rs.recorder` writes them)
plays that file instead of a live device, through the same pipeline and the same rs.align: a recorded scene can be
replayed through perception offline. The recording must hold the configured serial and both streams at the
configured size and fps. It plays once, like a camera streaming for as long as the recording lasts; when it has
run out, the camera has stopped. Before every capture the camera looks at the file again: when it was replaced
since it was opened (the emulated cell writes a new recording per placed scene, sim/lab/cameras.py), the camera
re-opens it and warms up again.

Every wait has a deadline: warming up may take `timeout_ms` plus the warm-up frames' own time at the stream's
fps, a capture `timeout_ms`. A camera that stops delivering raises `ConnectionLostError` naming it."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from hardware.config import CameraConfig
from hardware.errors import ConnectionLostError
from seggrasp.cell import Frame

log = logging.getLogger(__name__)


def _rs() -> Any:
    """pyrealsense2, imported when a camera is used (tests with stand-ins need no device library)."""
    import pyrealsense2

    return pyrealsense2


def intrinsics_to_K(intrinsics: Any) -> np.ndarray:
    """pyrealsense2 `intrinsics` (fx, fy, ppx, ppy) -> 3x3 pinhole matrix."""
    return np.array([[intrinsics.fx, 0.0, intrinsics.ppx],
                     [0.0, intrinsics.fy, intrinsics.ppy],
                     [0.0, 0.0, 1.0]], dtype=np.float64)


class RealSenseCamera:
    """One RealSense camera, live or played from `config.recording`. `pipeline` and `align` default to the
    pyrealsense2 objects (tests pass fakes)."""

    def __init__(self, config: CameraConfig, *, pipeline: Any = None, align: Any = None, warmup_frames: int = 15,
                 timeout_ms: int = 5000) -> None:
        self.config = config
        self._pipeline = pipeline
        self._align = align
        # made here, a recording gets a new pipeline and align per opening
        self._own_pipeline, self._own_align = pipeline is None, align is None
        self.warmup_frames = warmup_frames
        self.timeout_ms = timeout_ms
        self.K: np.ndarray | None = None
        self.depth_scale: float | None = None
        self._running = False
        self._playback: Any = None  # the playing recording's device (pyrealsense2 `playback`)
        self._opened: tuple[int, ...] | None = None  # the recording file's identity when it was opened
        self._delivered = 0  # frame sets delivered since the stream started

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def recording(self) -> Path | None:
        """The recording this camera plays instead of a live device, if any."""
        return self.config.recording

    def start(self) -> None:
        """Start streaming from this serial (or its recording), read intrinsics and depth scale, and let
        auto-exposure settle."""
        rs = _rs()
        # one pipeline (and align) playing one file after another aborts the process now and then
        if self._own_pipeline and (self._pipeline is None or self.recording is not None):
            self._pipeline = rs.pipeline()
        if self._own_align and (self._align is None or self.recording is not None):
            self._align = rs.align(rs.stream.color)
        stream_config = rs.config()
        if self.recording is None:
            stream_config.enable_device(self.config.serial)
        else:
            opened = self._recording_identity()
            stream_config.enable_device_from_file(str(self.recording), repeat_playback=False)
        stream_config.enable_stream(rs.stream.depth, self.config.width, self.config.height, rs.format.z16,
                                    self.config.fps)
        stream_config.enable_stream(rs.stream.color, self.config.width, self.config.height, rs.format.rgb8,
                                    self.config.fps)
        try:
            if self.recording is not None:
                # a playback starts in real time, and frames it plays before anyone reads them are dropped (under
                # load, all but the last): make it deliver as fast as the camera reads before it starts playing
                resolved = stream_config.resolve(rs.pipeline_wrapper(self._pipeline))
                resolved.get_device().as_playback().set_real_time(False)
            profile = self._pipeline.start(stream_config)
        except RuntimeError as exc:
            raise ConnectionLostError(f"cannot start {self._describe()}: {self._start_failure(exc)}") from exc
        self._running, self._delivered = True, 0
        try:
            self._streaming(rs, profile)
        except BaseException:
            self.stop()
            raise
        if self.recording is not None:
            self._opened = opened
        log.info("camera %s (%s) started%s: %dx%d, depth scale %.6f m", self.name, self.config.serial,
                 f" from recording {self.recording}" if self.recording else "", self.config.width,
                 self.config.height, self.depth_scale)

    def _streaming(self, rs: Any, profile: Any) -> None:
        """Check a started stream (a recording's serial), read its depth scale and intrinsics, and warm up."""
        if self.recording is not None:
            self._playback = profile.get_device().as_playback()
            serial = profile.get_device().get_info(rs.camera_info.serial_number)
            if serial != self.config.serial:
                raise ConnectionLostError(f"camera {self.name}: recording {self.recording} holds camera {serial}, "
                                          f"not {self.config.serial}")
        self.depth_scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
        intrinsics = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.K = intrinsics_to_K(intrinsics)
        if np.any(np.abs(np.asarray(intrinsics.coeffs, dtype=float)) > 1e-6):
            log.warning("camera %s reports non-zero distortion %s; frames are used undistorted",
                        self.name, list(intrinsics.coeffs))
        if self.warmup_frames:
            self._frames(self.warmup_frames, self.timeout_ms / 1000 + self.warmup_frames / self.config.fps)

    def capture(self, T_world_gripper: np.ndarray | None = None) -> Frame:
        """One aligned RGB-D frame as a `seggrasp.cell.Frame` (depth in metres, 0 = no reading).

        A wrist-mounted camera needs the gripper's pose at the moment of capture to place the frame in the world.
        A camera playing a recording first re-opens it when the file was replaced.
        """
        if not self._running or self.K is None or self.depth_scale is None:
            raise ConnectionLostError(f"camera {self.name} is not streaming (call start() first)")
        if self.recording is not None and self._recording_identity() != self._opened:
            log.info("camera %s: recording %s was replaced; opening the new one", self.name, self.recording)
            self.stop()
            self.start()
        frames = self._align.process(self._frames(1, self.timeout_ms / 1000))
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
        """Stop streaming. Safe to call more than once.

        A recording is first played to its end: its reader thread stops the playback by itself at the end of the
        file, and a `pipeline.stop()` racing that stop aborts the process ("pure virtual method called")."""
        if self._running:
            if self._playback is not None:
                self._play_to_end()
            try:
                self._pipeline.stop()
            except RuntimeError as exc:
                log.warning("stopping camera %s failed: %s", self.name, exc)
            self._running, self._playback = False, None

    # --------------------------------------------------------------------------------------------------- helpers
    def _describe(self) -> str:
        where = f" from recording {self.recording}" if self.recording is not None else ""
        return f"RealSense camera {self.config.serial} ({self.name}){where}"

    def _play_to_end(self) -> None:
        """Drop the recording's remaining frame sets until its playback has stopped (within `timeout_ms`), then wait
        for its reader thread to finish stopping."""
        stopped = _rs().playback_status.stopped
        deadline = time.monotonic() + self.timeout_ms / 1000
        while self._playback.current_status() != stopped and time.monotonic() < deadline:
            self._pipeline.try_wait_for_frames(100)
        if self._playback.current_status() != stopped:
            log.warning("camera %s: recording %s still playing after %.1f s; stopping it anyway", self.name,
                        self.recording, self.timeout_ms / 1000)
        # the status reads "stopped" as the reader thread begins to stop; it then rewinds the file and tells the
        # pipeline, and a pipeline stopped and freed meanwhile is called after its end (a rare segfault under load).
        # `pause` runs on that thread and returns once the thread has done all it had queued
        self._playback.pause()

    def _frames(self, count: int, seconds: float) -> Any:
        """The `count`-th next frame set (the ones before it are dropped), all within `seconds`."""
        deadline = time.monotonic() + seconds
        for index in range(count):
            remaining_ms = int((deadline - time.monotonic()) * 1000)
            try:
                if remaining_ms <= 0:
                    raise RuntimeError("no time left")
                frames = self._pipeline.wait_for_frames(remaining_ms)
            except RuntimeError as exc:
                got = "no frames" if index == 0 else f"only {index} of {count} frame sets"
                ended = ""
                if self._playback is not None and self._playback.current_status() == _rs().playback_status.stopped:
                    ended = f"; its recording ended after {self._delivered} frame sets"
                raise ConnectionLostError(f"{self._describe()} delivered {got} within {seconds:.1f} s{ended} "
                                          f"({exc})") from exc
            self._delivered += 1
        return frames

    def _recording_identity(self) -> tuple[int, ...]:
        """What changes when the recording file is replaced: its device, inode, size and modification time."""
        try:
            stat = os.stat(self.recording)
        except OSError as exc:
            raise ConnectionLostError(f"camera {self.name} ({self.config.serial}): its recording {self.recording} "
                                      f"cannot be read ({exc.strerror})") from exc
        return stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns

    def _start_failure(self, exc: RuntimeError) -> str:
        """Why the pipeline did not start: for a recording whose streams do not match the config, what it holds."""
        if self.recording is None or "resolve requests" not in str(exc):
            return str(exc)
        bare = _rs().config()
        bare.enable_device_from_file(str(self.recording), repeat_playback=False)
        try:
            held = self._pipeline.start(bare).get_streams()
        except RuntimeError:
            return str(exc)
        streams = ", ".join(f"{p.stream_type().name} {p.format().name} {p.as_video_stream_profile().width()}x"
                            f"{p.as_video_stream_profile().height()} at {p.fps()} fps" for p in held)
        self._pipeline.stop()
        return (f"it holds {streams}, the config asks for depth z16 and color rgb8 at "
                f"{self.config.width}x{self.config.height}, {self.config.fps} fps")
