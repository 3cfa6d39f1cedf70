"""The twin's camera frames as RealSense D435 recordings that the client's real pyrealsense2 plays (`rs.pipeline`).

After each placement the emulator calls `write_recordings({serial: frame}, folder)`: one ROS 2 `.db3` bag per
camera, `folder/<serial>.db3`, replaced atomically, holding a D435 as pyrealsense2 records one (serial, a depth
sensor with its depth units, a colour sensor, intrinsics and the depth-to-colour extrinsics) and `n_frames`
identical frame sets of the still scene, uncompressed (about 31 MB per camera at 640x480). A client camera
configured with `recording: <that path>` re-opens the file when it is replaced (hardware/realsense.py). In a scene
of several objects each camera's body-per-pixel mask goes beside its recording (`write_instance_masks`).
pyrealsense2 2.59 records `.db3` only, and its software device is seen by no pipeline, so a recording is the way in
(bridge audit, F8).

Depth is not written registered to colour: a D435's depth comes from its left imager, about 15 mm from the colour
camera, with a wider field of view, and the client registers it with `rs.align(rs.stream.color)`. Feeding rs.align
the twin's colour-registered depth with identity extrinsics punches rows and columns of holes (F9). So the twin's
depth is re-imaged by a depth imager placed and shaped like the D435's (`depth_imager`, `reimage_depth`), and the
extrinsics between the two streams are registered in the recording: the client's unchanged rs.align then does a
real registration, with the real one's resampling at the coarser depth resolution. What the colour camera cannot
see, the re-imaged depth lacks too; that is the occlusion band a D435 also has beside near edges.
"""

from __future__ import annotations

import os
import sqlite3
from collections.abc import Mapping
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyrealsense2 as rs

from seggrasp.cell import Frame
from seggrasp.io import atomic_save_npy
from sim.cameras import D435_WIDTH, DepthNoise

#: The D435 depth stream's focal length at 640x480 (the 1280x800 imagers scaled by 0.6; units vary around it).
D435_DEPTH_FOCAL_VGA = 384.0
#: Where the depth (left imager) origin sits in the colour camera's optical frame: about 15 mm along +x.
D435_DEPTH_IN_COLOR = np.array([0.015, 0.0, 0.0])
#: The D435's default depth units (m per z16 step).
DEPTH_UNITS = 0.001
#: Frame sets per recording: the client's 15 warm-up frame sets, a capture, and spares (playback may drop the
#: first one or two).
FRAMES_PER_SCENE = 20
#: Samples re-imaged into one depth pixel belong to its front surface when they lie this close behind the nearest.
FRONT_SURFACE = DepthNoise().edge_jump


@dataclass(frozen=True)
class DepthImager:
    """A D435-like depth imager beside a colour camera: its intrinsics and its origin in the colour optical frame
    (no rotation between the two, so a depth pixel's z is the same in both frames)."""

    K: np.ndarray  # (3, 3)
    origin_in_color: np.ndarray  # (3,)


def depth_imager(width: int, height: int) -> DepthImager:
    """The D435 depth imager for a stream of `width` x `height` (the 640x480 intrinsics scaled, centred)."""
    focal = D435_DEPTH_FOCAL_VGA * width / D435_WIDTH
    K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return DepthImager(K=K, origin_in_color=D435_DEPTH_IN_COLOR.copy())


def reimage_depth(depth: np.ndarray, K_color: np.ndarray, imager: DepthImager) -> np.ndarray:
    """A colour-registered depth image (m, 0 = none) as the depth imager sees it (same size, m, 0 = none).

    Every valid colour pixel's point is projected into the depth imager. A depth pixel takes, of the points that
    land in it on its front surface (within `FRONT_SURFACE` of the nearest), the one closest to its centre."""
    height, width = depth.shape
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64)
    points = np.stack([(u - K_color[0, 2]) * z / K_color[0, 0], (v - K_color[1, 2]) * z / K_color[1, 1], z], axis=1)
    points -= imager.origin_in_color
    K = imager.K
    with np.errstate(divide="ignore", invalid="ignore"):
        ud = K[0, 0] * points[:, 0] / points[:, 2] + K[0, 2]
        vd = K[1, 1] * points[:, 1] / points[:, 2] + K[1, 2]
    ui, vi = np.rint(ud), np.rint(vd)
    inside = (points[:, 2] > 0) & (ui >= 0) & (ui < width) & (vi >= 0) & (vi < height)
    pixel = (vi[inside] * width + ui[inside]).astype(np.int64)
    zd = points[inside, 2]
    off_centre = (ud[inside] - ui[inside]) ** 2 + (vd[inside] - vi[inside]) ** 2
    out = np.zeros(height * width)
    # first the nearest point per pixel, then the most central on its front surface: sort by pixel, then by the
    # key (each key scaled into [0, 1) and added to the pixel index: one float sort instead of a slower lexsort)
    for key in ("depth", "centre"):
        fraction = zd / (zd.max() + 1.0) if key == "depth" else off_centre  # off_centre is at most 0.5
        order = np.argsort(pixel + fraction)
        pixel, zd, off_centre = pixel[order], zd[order], off_centre[order]
        first = np.flatnonzero(np.r_[True, pixel[1:] != pixel[:-1]])
        out[pixel[first]] = zd[first]
        if key == "depth":
            front = zd <= out[pixel] + FRONT_SURFACE
            pixel, zd, off_centre = pixel[front], zd[front], off_centre[front]
    return out.reshape(height, width)


def write_recordings(frames: Mapping[str, Frame], folder: str | Path, *, fps: int = 30,
                     n_frames: int = FRAMES_PER_SCENE, imager: DepthImager | None = None) -> dict[str, Path]:
    """Write `folder/<serial>.db3` for every camera's twin frame; returns {serial: path}.

    Each file is written under a temporary name in `folder` and then renamed over the old one, so a reader sees
    the old recording or the new one, never half of one. `n_frames=1` makes a camera whose stream stops during the
    client's warm-up (the `camera_stop` fault). `imager` replaces the D435's depth imager (`depth_imager`)."""
    if n_frames < 1:
        raise ValueError(f"a recording needs at least one frame set, got n_frames={n_frames}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for serial, frame in frames.items():
        path = folder / f"{serial}.db3"
        partial = folder / f".{serial}.{os.getpid()}.partial.db3"
        try:
            _record(partial, serial, frame, fps, n_frames, imager)
            _check_frames(partial, n_frames)
            os.replace(partial, path)
        finally:
            partial.unlink(missing_ok=True)
        paths[serial] = path
    return paths


def instance_mask_path(folder: str | Path, serial: str) -> Path:
    """Where the emulator writes the body-per-pixel mask of camera `serial`'s recording: `<serial>.instances.npy`."""
    return Path(folder) / f"{serial}.instances.npy"


def write_instance_masks(frames: Mapping[str, Frame], folder: str | Path) -> dict[str, Path]:
    """Write each frame's body id per colour pixel (`Frame.instance_ids`, -1: none) beside its recording, replaced
    atomically as the recordings are. A real camera has no such mask: the emulated cell hands it to the simulated
    object detector only, as the twin backend does (sim.evaluate.emulated.EmulatedCell.capture)."""
    paths = {}
    for serial, frame in frames.items():
        if frame.instance_ids is None:
            raise ValueError(f"camera {serial}: the frame carries no body mask to write")
        paths[serial] = path = instance_mask_path(folder, serial)
        atomic_save_npy(path, np.asarray(frame.instance_ids, dtype=np.int32))
    return paths


def _intrinsics(K: np.ndarray, width: int, height: int) -> rs.intrinsics:
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = width, height
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    intrinsics.model = rs.distortion.none
    intrinsics.coeffs = [0.0] * 5
    return intrinsics


def _stream(kind: rs.stream, uid: int, fmt: rs.format, bpp: int, K: np.ndarray, width: int, height: int,
            fps: int) -> rs.video_stream:
    stream = rs.video_stream()
    stream.type, stream.index, stream.uid, stream.fmt, stream.bpp = kind, 0, uid, fmt, bpp
    stream.width, stream.height, stream.fps = width, height, fps
    stream.intrinsics = _intrinsics(K, width, height)
    return stream


def _record(path: Path, serial: str, frame: Frame, fps: int, n_frames: int, imager: DepthImager | None) -> None:
    """Record `n_frames` copies of one frame through a software device. Every pyrealsense2 object lives in this
    function: the recorder writes the file's end when the last of them is gone, i.e. when this returns."""
    rgb = np.ascontiguousarray(frame.rgb, dtype=np.uint8)
    height, width = rgb.shape[:2]
    if rgb.shape != (height, width, 3) or frame.depth.shape != (height, width):
        raise ValueError(f"camera {serial}: colour {rgb.shape} and depth {frame.depth.shape} do not match")
    imager = imager or depth_imager(width, height)
    z16 = np.rint(reimage_depth(frame.depth, frame.K, imager) / DEPTH_UNITS).astype(np.uint16)

    device = rs.software_device()
    device.register_info(rs.camera_info.name, "Intel RealSense D435 (SegGrasp twin)")
    device.register_info(rs.camera_info.serial_number, serial)
    depth_sensor, color_sensor = device.add_sensor("Stereo Module"), device.add_sensor("RGB Camera")
    depth_sensor.add_read_only_option(rs.option.depth_units, DEPTH_UNITS)
    depth_profile = depth_sensor.add_video_stream(
        _stream(rs.stream.depth, 0, rs.format.z16, 2, imager.K, width, height, fps))
    color_profile = color_sensor.add_video_stream(
        _stream(rs.stream.color, 1, rs.format.rgb8, 3, frame.K, width, height, fps))
    depth_to_color = rs.extrinsics()
    depth_to_color.rotation = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    depth_to_color.translation = imager.origin_in_color.tolist()  # p_color = p_depth + origin
    depth_profile.register_extrinsics_to(color_profile, depth_to_color)

    recorder = rs.recorder(str(path), device, False)  # uncompressed: twice as fast to write, 3x to play back
    sensors = recorder.query_sensors()
    for sensor, profile in zip(sensors, (depth_profile, color_profile)):
        sensor.open(profile)
        sensor.start(lambda _: None)
    streams = ((depth_sensor, depth_profile.as_video_stream_profile(), z16, 2),
               (color_sensor, color_profile.as_video_stream_profile(), rgb, 3))
    for index in range(n_frames):
        for sensor, profile, pixels, bpp in streams:
            out = rs.software_video_frame()
            out.pixels, out.stride, out.bpp, out.profile = pixels, width * bpp, bpp, profile
            out.timestamp, out.domain, out.frame_number = index * 1000.0 / fps, rs.timestamp_domain.hardware_clock, index
            if pixels is z16:
                out.depth_units = DEPTH_UNITS
            sensor.on_video_frame(out)
    for sensor in sensors:
        sensor.stop()
        sensor.close()


def _check_frames(path: Path, n_frames: int) -> None:
    """Raise unless the bag (SQLite) holds `n_frames` images of each of the two streams."""
    with closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as bag:
        counts = dict(bag.execute(
            "SELECT topics.name, COUNT(*) FROM messages JOIN topics ON messages.topic_id = topics.id "
            "WHERE topics.name LIKE '%/image/data%' GROUP BY topics.name").fetchall())
    if len(counts) != 2 or set(counts.values()) != {n_frames}:
        raise RuntimeError(f"recording {path} is incomplete: image messages per stream {counts}, "
                           f"expected {n_frames} for depth and colour")
