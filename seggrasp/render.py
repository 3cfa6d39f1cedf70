"""Camera rig and offscreen rendering: an exact face-id buffer and a shaded RGB image for the detector per view.

Rig. The mesh is first mapped into the unit sphere (`seggrasp.mesh.unit_normalisation`). Cameras sit on a sphere of
radius `CAMERA_DISTANCE` = 3 looking at the origin, with a vertical field of view that just fits the unit sphere
(plus a margin), so the whole object is always in frame. SATR puts cameras at radius 2 and draws its views around
the front of the object; objects to be grasped have no canonical front but do have an up (+z, the table normal),
so this rig instead spreads the views evenly over a band of the sphere with a spherical Fibonacci lattice: equal
steps in sin(elevation) from -17 deg to +72 deg (about three quarters of the views look from above the equator,
none from straight below the table and none straight down, where "up" in the image is undefined) and golden-angle
steps in azimuth, so any number of views covers all sides. The seed only turns the whole rig about z. Radius 3
instead of 2 gives less perspective distortion at the same framing.

Face ids. Faces are drawn with three private vertices each, unlit (`RenderFlags.FLAT`), coloured with their index
+ 1 in 24-bit RGB; background is 0 -> id -1. With OSMesa (the default platform here) pyrender draws straight into
the single-sampled OSMesa buffer. On platforms with framebuffer objects (EGL, pyglet) pyrender renders through a 4x
multisampled framebuffer and resolves it by averaging, which would blend the colours of neighbouring faces at shared
edges; there the renderer re-allocates pyrender's multisample renderbuffers with a single sample (pyrender 0.1.45
internals `_main_cb_ms`/`_main_db_ms`). Either way every pixel is the one face that covers its centre - what a ray
through the pixel centre hits (tests/test_render.py checks this against trimesh ray casting).

Shading. The RGB image comes from the same single GL pass: every visible face gets a grey value from two-sided
Lambert shading of its normal under ambient light and a key light near the camera (`shade_faces`), looked up through
the face-id buffer. That is exactly a flat-shaded render, at half the cost of a second, lit pass (OSMesa renders in
software, and the whole render + vote budget is one second for 10 views). Meshes carry no textures here
(`seggrasp.mesh.load_mesh` drops materials), so nothing is lost.
"""

from __future__ import annotations

import atexit
import logging
import math
import threading
import time

import numpy as np
import trimesh

from seggrasp.gl import import_pyrender

pyrender = import_pyrender()  # picks headless OSMesa without a display; a missing GL library is one clear error
from OpenGL import GL  # noqa: E402
from pyrender.shader_program import ShaderProgramCache  # noqa: E402

from seggrasp.mesh import unit_normalisation  # noqa: E402
from seggrasp.views import View, look_at  # noqa: E402

logger = logging.getLogger(__name__)

#: Distance of every camera from the centre of the unit-normalised mesh.
CAMERA_DISTANCE = 3.0
#: Extra field of view (radians) beyond the angle the unit sphere subtends, so silhouettes never touch the border.
FOV_MARGIN = math.radians(4.0)
#: The band of the view sphere the rig covers, as sin(elevation): about -17 deg to +72 deg.
MIN_SIN_ELEVATION = -0.3
MAX_SIN_ELEVATION = 0.95
DEFAULT_IMAGE_SIZE = 512
#: Shaded image: a grey, flat-shaded (Lambert) surface lit by ambient light plus a key light near the camera, on white.
SURFACE_GREY = 0.8
AMBIENT_LIGHT = 0.3
KEY_LIGHT = 0.75
#: The key light shines from the camera, tilted this far towards the image top so that shapes read in 3-D.
KEY_LIGHT_TILT = math.radians(35.0)
BACKGROUND_VALUE = 255
MAX_FACES = 2**24 - 2  # face ids + 1 must fit 24 bits of RGB
#: Bounds of a rig (the default is 10 views of 512 px): every pixel holds 11 bytes (face id and RGB), so
#: MAX_RIG_PIXELS, e.g. 32 views of 1024 px, keeps the views under 400 MB; more gives no better votes.
MAX_VIEWS = 64
MIN_IMAGE_SIZE = 8
MAX_IMAGE_SIZE = 2048
MAX_RIG_PIXELS = 32 * 1024 * 1024

#: OpenCV camera (x right, y down, z forward) -> OpenGL camera (x right, y up, z backward).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
#: Direction towards the key light in OpenCV camera coordinates: backwards (towards the viewer) and up.
_KEY_LIGHT_IN_CAMERA = np.array([0.0, -math.sin(KEY_LIGHT_TILT), -math.cos(KEY_LIGHT_TILT)])


def check_rig(n_views: int, image_size: int) -> None:
    """ValueError naming the limit unless 1 <= n_views <= MAX_VIEWS, MIN_IMAGE_SIZE <= image_size <= MAX_IMAGE_SIZE
    and the rig's pixels are within MAX_RIG_PIXELS."""
    if not 1 <= n_views <= MAX_VIEWS:
        raise ValueError(f"n_views (the number of views) must be between 1 and {MAX_VIEWS}, got {n_views}")
    if not MIN_IMAGE_SIZE <= image_size <= MAX_IMAGE_SIZE:
        raise ValueError(f"image_size must be between {MIN_IMAGE_SIZE} and {MAX_IMAGE_SIZE} pixels, got {image_size}")
    if n_views * image_size**2 > MAX_RIG_PIXELS:
        raise ValueError(f"{n_views} views of {image_size} px are {n_views * image_size**2 / 2**20:.0f} Mpx; the limit "
                         f"is {MAX_RIG_PIXELS // 2**20} Mpx (views x image size^2)")


def field_of_view(distance: float = CAMERA_DISTANCE) -> float:
    """Vertical (= horizontal) field of view in radians that frames the unit sphere from `distance`."""
    return 2.0 * math.asin(1.0 / distance) + FOV_MARGIN


def intrinsics(image_size: int, distance: float = CAMERA_DISTANCE) -> np.ndarray:
    """3x3 pinhole matrix of the rig's square images; the principal point is the image centre."""
    focal = 0.5 * image_size / math.tan(0.5 * field_of_view(distance))
    centre = 0.5 * image_size
    return np.array([[focal, 0.0, centre], [0.0, focal, centre], [0.0, 0.0, 1.0]])


def camera_rig(n_views: int = 10, seed: int = 0, distance: float = CAMERA_DISTANCE) -> list[np.ndarray]:
    """Camera poses T_world_cam around the unit-normalised mesh (see the module docstring for the layout)."""
    check_rig(n_views, MIN_IMAGE_SIZE)
    if distance <= 1.0:
        raise ValueError(f"cameras must be outside the unit sphere, got distance {distance}")
    rng = np.random.default_rng(seed)
    azimuth_offset = rng.uniform(0.0, 2.0 * math.pi)
    golden_angle = math.pi * (3.0 - math.sqrt(5.0))
    poses = []
    for k in range(n_views):
        sin_elevation = MIN_SIN_ELEVATION + (k + 0.5) / n_views * (MAX_SIN_ELEVATION - MIN_SIN_ELEVATION)
        cos_elevation = math.sqrt(1.0 - sin_elevation**2)
        azimuth = azimuth_offset + k * golden_angle
        direction = np.array([cos_elevation * math.cos(azimuth), cos_elevation * math.sin(azimuth), sin_elevation])
        poses.append(look_at(distance * direction))
    return poses


def encode_face_colours(n_faces: int) -> np.ndarray:
    """(n_faces, 4) uint8 RGBA colours carrying face index + 1 in R (low byte), G, B (high byte)."""
    if n_faces > MAX_FACES:
        raise ValueError(f"mesh has {n_faces} faces; the face-id buffer holds at most {MAX_FACES}")
    code = np.arange(1, n_faces + 1, dtype=np.int64)
    colours = np.empty((n_faces, 4), dtype=np.uint8)
    colours[:, 0] = code & 0xFF
    colours[:, 1] = (code >> 8) & 0xFF
    colours[:, 2] = (code >> 16) & 0xFF
    colours[:, 3] = 255
    return colours


def decode_face_ids(rgb: np.ndarray) -> np.ndarray:
    """Inverse of `encode_face_colours` on a rendered (H, W, 3 or 4) uint8 image: face index per pixel, -1 for
    background."""
    rgb = np.asarray(rgb)
    if rgb.dtype == np.uint8 and rgb.ndim == 3 and rgb.shape[2] == 4 and rgb.flags.c_contiguous:
        packed = rgb.view("<u4")[..., 0]  # R | G << 8 | B << 16 | A << 24, read as one little-endian word
        return (packed & 0xFFFFFF).astype(np.int64) - 1
    rgb = rgb[..., :3].astype(np.int64)
    return rgb[..., 0] + (rgb[..., 1] << 8) + (rgb[..., 2] << 16) - 1


def shade_faces(face_normals: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """(F,) uint8 grey value of every face seen from a camera: ambient + key light, two-sided Lambert."""
    light = T_world_cam[:3, :3] @ _KEY_LIGHT_IN_CAMERA
    lambert = np.abs(face_normals @ light)
    return np.clip(255.0 * SURFACE_GREY * (AMBIENT_LIGHT + KEY_LIGHT * lambert), 0, 255).astype(np.uint8)


class _ProgramCachePerRenderer(ShaderProgramCache):
    """pyrender's shader-program cache, keyed without the GL context.

    pyrender keys compiled programs on `OpenGL.contextdata.getContext()`; under OSMesa that returns a new pointer
    object on every call (equal hashes, never equal), so every render pass compiled and kept a new program: memory
    grew by ~9 MB per 10 views. A renderer owns exactly one context, so the key can leave it out.
    """

    def __init__(self) -> None:
        super().__init__()
        self._by_source: dict[tuple, object] = {}

    def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
        key = (vertex_shader, fragment_shader, geometry_shader, tuple(sorted((defines or {}).items())))
        if key not in self._by_source:
            self._by_source[key] = super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)
        return self._by_source[key]

    def clear(self) -> None:
        super().clear()
        self._by_source.clear()


class ViewRenderer:
    """An offscreen pyrender renderer of one image size, reused across meshes and views (OSMesa context)."""

    def __init__(self, image_size: int = DEFAULT_IMAGE_SIZE, distance: float = CAMERA_DISTANCE) -> None:
        check_rig(1, image_size)
        self.image_size = int(image_size)
        self.distance = float(distance)
        self.K = intrinsics(self.image_size, self.distance)
        self._renderer = pyrender.OffscreenRenderer(self.image_size, self.image_size)
        self._renderer._renderer._program_cache = _ProgramCachePerRenderer()
        self._single_sampled = False

    def close(self) -> None:
        """Release the GL context."""
        self._renderer.delete()

    def _make_single_sampled(self) -> None:
        """Give pyrender's multisample renderbuffers one sample so face colours are never blended."""
        self._single_sampled = True
        platform = self._renderer._platform
        if not platform.supports_framebuffers():  # OSMesa: no multisample framebuffer in the first place
            return
        inner = self._renderer._renderer
        platform.make_current()
        inner._configure_main_framebuffer()
        size = self.image_size
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, inner._main_cb_ms)
        GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, 0, GL.GL_RGBA, size, size)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, inner._main_db_ms)
        GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, 0, GL.GL_DEPTH_COMPONENT24, size, size)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, 0)
        platform.make_uncurrent()

    def render(self, mesh: trimesh.Trimesh, poses: list[np.ndarray]) -> list[View]:
        """Render `mesh` (mapped into the unit sphere) from every pose; one `View` per pose."""
        if len(mesh.faces) == 0:
            raise ValueError("cannot render a mesh without faces")
        check_rig(max(len(poses), 1), self.image_size)
        started = time.perf_counter()
        if not self._single_sampled:
            self._make_single_sampled()
        poses = [np.asarray(pose, dtype=float) for pose in poses]
        for pose in poses:
            if pose.shape != (4, 4):
                raise ValueError(f"camera poses must be 4x4 matrices, got shape {pose.shape}")
        distances = [float(np.linalg.norm(pose[:3, 3])) for pose in poses]
        if poses and min(distances) <= 1.0:
            raise ValueError(f"every camera must be outside the unit sphere; one is at distance {min(distances):.3g}")
        normalised = mesh.copy()
        normalised.apply_transform(unit_normalisation(mesh))
        face_normals = np.asarray(normalised.face_normals)
        znear = max(min(distances, default=self.distance) - 1.05, 0.01)
        zfar = max(distances, default=self.distance) + 1.05
        scene, camera_node = self._build_scene(normalised, znear, zfar)

        views = []
        flags = pyrender.RenderFlags.FLAT | pyrender.RenderFlags.RGBA
        for pose in poses:
            scene.set_pose(camera_node, pose @ _CV_TO_GL)
            coded, _ = self._renderer.render(scene, flags=flags)
            face_ids = decode_face_ids(np.ascontiguousarray(coded))
            grey = np.append(shade_faces(face_normals, pose), np.uint8(BACKGROUND_VALUE))
            rgb = np.repeat(grey[face_ids][..., None], 3, axis=2)  # id -1 picks the trailing background value
            views.append(View(rgb=rgb, face_ids=face_ids, K=self.K.copy(), T_world_cam=pose.copy()))
        logger.info("rendered %d views of %d faces at %d px in %.1f s", len(views), len(mesh.faces), self.image_size,
                    time.perf_counter() - started)
        return views

    def _build_scene(self, mesh: trimesh.Trimesh, znear: float, zfar: float):
        """Scene of the face-id mesh (three private vertices per face, colour = id + 1) and a camera node."""
        triangles = np.asarray(mesh.triangles, dtype=np.float32).reshape(-1, 3)
        colours = np.repeat(encode_face_colours(len(mesh.faces)), 3, axis=0)
        primitive = pyrender.Primitive(
            positions=triangles, indices=np.arange(len(triangles), dtype=np.uint32).reshape(-1, 3),
            color_0=colours.astype(np.float32) / 255.0, mode=pyrender.constants.GLTF.TRIANGLES,
            material=pyrender.MetallicRoughnessMaterial(baseColorFactor=(1.0, 1.0, 1.0, 1.0), doubleSided=True),
        )
        scene = pyrender.Scene(bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=np.zeros(3))
        scene.add(pyrender.Mesh([primitive]))
        camera = scene.add(pyrender.PerspectiveCamera(yfov=field_of_view(self.distance), znear=znear, zfar=zfar))
        return scene, camera


_shared_renderers: dict[tuple[int, int, float], ViewRenderer] = {}
_shared_lock = threading.Lock()


@atexit.register
def close_shared_renderers() -> None:
    """Release the GL contexts of `render_views` (also run at exit, before PyOpenGL is torn down)."""
    with _shared_lock:
        for renderer in _shared_renderers.values():
            renderer.close()
        _shared_renderers.clear()


def render_views(mesh: trimesh.Trimesh, poses: list[np.ndarray], image_size: int = DEFAULT_IMAGE_SIZE) -> list[View]:
    """Render RGB images and exact face-id buffers of `mesh` after `unit_normalisation`, one `View` per pose.

    Poses are T_world_cam (OpenCV) in the unit-normalised frame, e.g. from `camera_rig`. The offscreen renderer of
    each image size is created once per thread and reused.
    """
    key = (threading.get_ident(), int(image_size), CAMERA_DISTANCE)
    with _shared_lock:
        renderer = _shared_renderers.get(key)
        if renderer is None:
            renderer = _shared_renderers[key] = ViewRenderer(image_size)
    return renderer.render(mesh, poses)
