"""Virtual Intel RealSense D435 cameras: pinhole intrinsics, OpenCV pose, metric depth with the D435's noise.

PyBullet renders with OpenGL matrices; here `K` and `T_world_cam` (OpenCV: x right, y down, z forward) are the
source of truth and both PyBullet matrices are derived from them. The depth buffer is turned into metric z-depth
(distance along the optical axis, as a RealSense reports it).

Depth noise follows Intel's depth-RMS model for stereo cameras, RMS = z^2 * subpixel / (f_px * baseline), with the
D435's 50 mm baseline, 0.08 subpixel accuracy and its depth focal length (~447 px at 848x480, 87 deg HFOV): about
3.6 mm at 1 m. Readings outside the depth range (min-z 0.105 m, 10 m) are 0, like the camera's holes; so are random
dropouts and, with higher probability, pixels on depth discontinuities (stereo occlusion shadows).

Each frame also carries the twin's truth of which body each pixel shows (`Frame.instance_ids`, from PyBullet's
segmentation mask of the noise-free render), which a real camera cannot give.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet

from seggrasp.cell import Frame

#: D435 colour stream at 640x480: fx = fy ~ 615 px.
D435_WIDTH, D435_HEIGHT, D435_FOCAL = 640, 480, 615.0
D435_BASELINE = 0.050
D435_SUBPIXEL = 0.08
D435_DEPTH_FOCAL = 447.0
D435_MIN_DEPTH, D435_MAX_DEPTH = 0.105, 10.0
RENDER_NEAR, RENDER_FAR = 0.1, 12.0
#: OpenCV camera axes -> OpenGL camera axes (y and z flipped).
T_CV_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class DepthNoise:
    """Parameters of the depth error model (set `enabled=False` for ideal depth)."""

    enabled: bool = True
    dropout: float = 0.003
    edge_dropout: float = 0.5
    edge_jump: float = 0.03  # m between neighbouring pixels that counts as a discontinuity
    rgb_sigma: float = 2.0  # colour sensor noise (8-bit units)


def intrinsics(width: int = D435_WIDTH, height: int = D435_HEIGHT) -> np.ndarray:
    """D435-like colour intrinsics for an image size (the 640x480 field of view, scaled)."""
    scale = width / D435_WIDTH
    if abs(height / D435_HEIGHT - scale) > 1e-6:
        raise ValueError(f"image size {width}x{height} is not 4:3 like the D435 colour stream at 640x480")
    return np.array([[D435_FOCAL * scale, 0, (width - 1) / 2], [0, D435_FOCAL * scale, (height - 1) / 2], [0, 0, 1.0]])


def projection_matrix(K: np.ndarray, width: int, height: int, near: float = RENDER_NEAR, far: float = RENDER_FAR) -> np.ndarray:
    """OpenGL projection matrix under which PyBullet's TinyRenderer images follow pinhole `K` exactly.

    TinyRenderer samples pixel (u, v) on the ray through OpenGL window coordinates (u, H - 1 - v), so the principal
    point shifts by one pixel in y only (measured: back-projected depth of the table plane then lies within 1e-6 m
    of z = 0 for upright and rolled cameras; see tests/test_sim_cameras.py).
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2] + 1.0
    return np.array([
        [2 * fx / width, 0, 1 - 2 * cx / width, 0],
        [0, 2 * fy / height, 2 * cy / height - 1, 0],
        [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0, 0, -1, 0],
    ])


def view_matrix(T_world_cam: np.ndarray) -> np.ndarray:
    """OpenGL view matrix (world -> OpenGL camera) of an OpenCV camera pose."""
    return np.linalg.inv(np.asarray(T_world_cam, float) @ T_CV_GL)


def depth_from_buffer(buffer: np.ndarray, near: float = RENDER_NEAR, far: float = RENDER_FAR) -> np.ndarray:
    """OpenGL depth buffer values in [0, 1] -> metric z-depth."""
    return (far * near / (far - (far - near) * np.asarray(buffer, dtype=np.float64))).astype(np.float32)


def depth_rms(z: np.ndarray) -> np.ndarray:
    """The D435's depth RMS error (m) at depth `z` (m)."""
    return D435_SUBPIXEL * np.square(z) / (D435_DEPTH_FOCAL * D435_BASELINE)


class VirtualD435:
    """One simulated RGB-D camera with a fixed pose."""

    def __init__(
        self, name: str, T_world_cam: np.ndarray, width: int = D435_WIDTH, height: int = D435_HEIGHT,
        noise: DepthNoise | None = None,
    ) -> None:
        self.name = name
        self.T_world_cam = np.asarray(T_world_cam, dtype=float)
        self.width, self.height = int(width), int(height)
        self.K = intrinsics(self.width, self.height)
        self.noise = noise or DepthNoise()
        self._view = view_matrix(self.T_world_cam).T.flatten().tolist()  # PyBullet wants column-major
        self._projection = projection_matrix(self.K, self.width, self.height).T.flatten().tolist()

    def render(self, client) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Noise-free (rgb uint8 (H,W,3), z-depth float32 (H,W), segmentation int (H,W)) from a PyBullet client."""
        _, _, rgba, depth_buffer, segmentation = client.getCameraImage(
            self.width, self.height, viewMatrix=self._view, projectionMatrix=self._projection,
            renderer=pybullet.ER_TINY_RENDERER, shadow=0, lightDirection=[0.4, -0.3, 1.0],
        )
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(self.height, self.width, 4)[..., :3].copy()
        depth = depth_from_buffer(np.asarray(depth_buffer).reshape(self.height, self.width))
        return rgb, depth, np.asarray(segmentation).reshape(self.height, self.width)

    def capture(self, client, rng: np.random.Generator) -> Frame:
        """An RGB-D frame with the D435's noise, range limits and dropouts (0 = no reading)."""
        rgb, depth, segmentation = self.render(client)
        depth = depth.astype(np.float64)
        depth[segmentation < 0] = 0.0  # nothing rendered there: no surface to measure
        if self.noise.enabled:
            depth = depth + rng.standard_normal(depth.shape) * depth_rms(depth)
            jump = np.zeros(depth.shape, dtype=bool)
            jump[:, 1:] |= np.abs(np.diff(depth, axis=1)) > self.noise.edge_jump
            jump[1:, :] |= np.abs(np.diff(depth, axis=0)) > self.noise.edge_jump
            drop = rng.random(depth.shape) < np.where(jump, self.noise.edge_dropout, self.noise.dropout)
            depth[drop] = 0.0
            rgb = np.clip(rgb + rng.normal(0.0, self.noise.rgb_sigma, rgb.shape), 0, 255).astype(np.uint8)
        depth[(depth < D435_MIN_DEPTH) | (depth > D435_MAX_DEPTH)] = 0.0
        return Frame(name=self.name, rgb=rgb, depth=depth.astype(np.float32), K=self.K.copy(),
                     T_world_cam=self.T_world_cam.copy(), instance_ids=np.maximum(segmentation, -1).astype(np.int32))


def backproject(frame: Frame) -> np.ndarray:
    """World points (N, 3) of every valid depth pixel of a frame (OpenCV pinhole model)."""
    v, u = np.nonzero(frame.depth > 0)
    z = frame.depth[v, u].astype(np.float64)
    K = frame.K
    points_cam = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z, np.ones_like(z)], axis=1)
    return (points_cam @ frame.T_world_cam.T)[:, :3]
