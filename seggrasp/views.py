"""A rendered view of a mesh: what the detector sees and which face each pixel shows."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class View:
    """One rendered view.

    `face_ids[v, u]` is the index of the (working) mesh face seen at pixel (u, v), or -1 for background. Camera
    pose `T_world_cam` (OpenCV convention) is expressed in the frame the mesh was rendered in.
    """

    rgb: np.ndarray  # (H, W, 3) uint8
    face_ids: np.ndarray  # (H, W) int64, -1 = background
    K: np.ndarray  # (3, 3)
    T_world_cam: np.ndarray  # (4, 4)

    @property
    def size(self) -> tuple[int, int]:
        """(height, width) in pixels."""
        return int(self.face_ids.shape[0]), int(self.face_ids.shape[1])
