"""A rendered view of a mesh (what the detector sees and which face each pixel shows) and camera aiming."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class View:
    """One rendered view.

    `face_ids[v, u]` is the index of the (working) mesh face seen at pixel (u, v), or -1 for background; in a
    camera image (`seggrasp.target.camera_views`) no mesh is rendered and it holds the twin's body per pixel
    (`Frame.instance_ids`), all -1 on a real cell. Camera pose `T_world_cam` (OpenCV convention) is expressed in
    the frame the mesh was rendered in.
    """

    rgb: np.ndarray  # (H, W, 3) uint8
    face_ids: np.ndarray  # (H, W) int64, -1 = background
    K: np.ndarray  # (3, 3)
    T_world_cam: np.ndarray  # (4, 4)

    @property
    def size(self) -> tuple[int, int]:
        """(height, width) in pixels."""
        return int(self.face_ids.shape[0]), int(self.face_ids.shape[1])


def look_at(position: np.ndarray, target: np.ndarray | None = None, up: np.ndarray | None = None) -> np.ndarray:
    """T_world_cam (OpenCV axes) of a camera at `position` looking at `target` with image-up towards `up`."""
    position = np.asarray(position, dtype=float)
    target = np.zeros(3) if target is None else np.asarray(target, dtype=float)
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=float)
    forward = target - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("camera looks along its up vector; choose another up")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, forward, position
    return pose
