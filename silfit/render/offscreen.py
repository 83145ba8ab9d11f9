"""Offscreen rasterisation with pyrender on OSMesa: shaded images, depth, masks, overlays, views.

Camera convention
-----------------
The project's one convention (:mod:`silfit.camera`): meshes are in OpenCV camera
coordinates (x right, y down, z forward, metres); pixel centres lie on integer
coordinates, ``u = fx * x / z + cx``.  The GL scene keeps those coordinates as its world
frame and puts the GL camera (looking down -z, y up) at the origin with pose
``diag(1, -1, -1, 1)``.  OpenGL's window coordinates put pixel centres at ``i + 0.5``
(like Mitsuba), so the pyrender intrinsics get ``cx + 0.5, cy + 0.5``.  Images come back
with row 0 at the top; depth is the z coordinate in metres, 0 where nothing was drawn;
a pixel is in the mask when its centre is covered (no multisampling on OSMesa).

Platform
--------
``PYOPENGL_PLATFORM`` must be chosen before PyOpenGL is imported: this module sets it to
``osmesa`` unless the user already chose ``osmesa`` or ``egl`` (EGL masks are shifted by
0.1-0.4 px by multisampling: keep OSMesa for sub-pixel ground truth).  pyrender is
imported lazily, so importing :mod:`silfit.render` costs nothing until the first render.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import os
import sys
import threading
from dataclasses import dataclass
from typing import Optional, Sequence, Union

import numpy as np

from silfit.camera import Camera
from silfit.errors import SystemLibraryError

__all__ = [
    "OSMesaNotFoundError",
    "BODY_COLOR",
    "Rendering",
    "OffscreenRenderer",
    "get_renderer",
    "render_mesh",
    "render_mask",
    "render_depth",
    "overlay",
    "framing_camera",
    "view_angles",
    "rotate_about_vertical",
    "render_views",
    "mesh_arrays",
]

#: Neutral light grey-blue clay, linear RGB in [0, 1].
BODY_COLOR = (0.58, 0.64, 0.74)
_BACKGROUND = (1.0, 1.0, 1.0)

_ALLOWED_PLATFORMS = ("osmesa", "egl")


def _ensure_platform() -> str:
    platform = os.environ.get("PYOPENGL_PLATFORM", "").lower()
    if platform not in _ALLOWED_PLATFORMS:
        if "OpenGL" in sys.modules and platform:
            raise RuntimeError(
                f"PyOpenGL was already imported with PYOPENGL_PLATFORM={platform!r}; "
                "silfit.render.offscreen needs 'osmesa' (or 'egl') chosen before OpenGL is imported"
            )
        os.environ["PYOPENGL_PLATFORM"] = "osmesa"
        platform = "osmesa"
    return platform


class OSMesaNotFoundError(SystemLibraryError):
    """libOSMesa (offscreen OpenGL, for pyrender) is not installed."""


#: The one line shown when libOSMesa is missing (as the libLLVM one, :mod:`silfit.render._llvm`).
OSMESA_MESSAGE = (
    "libOSMesa not found: silfit draws its pictures with pyrender on OSMesa (offscreen OpenGL); "
    "install it with `apt-get install libosmesa6` (Debian/Ubuntu) or `conda install -c conda-forge mesalib`, "
    "or set PYOPENGL_PLATFORM=egl where an EGL driver is installed"
)


def _osmesa_present() -> bool:
    """Whether the dynamic loader finds libOSMesa (as PyOpenGL's osmesa platform looks it up)."""
    if ctypes.util.find_library("OSMesa"):
        return True
    for name in ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so"):  # a library on LD_LIBRARY_PATH only
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def _pyrender():
    platform = _ensure_platform()
    if platform == "osmesa" and "pyrender" not in sys.modules and not _osmesa_present():
        raise OSMesaNotFoundError(OSMESA_MESSAGE)
    try:
        import pyrender
    except (ImportError, AttributeError, OSError) as err:  # PyOpenGL failing to load its platform's library
        if platform == "osmesa" and not _osmesa_present():
            raise OSMesaNotFoundError(OSMESA_MESSAGE) from err
        raise
    return pyrender


# --------------------------------------------------------------------------- inputs
def mesh_arrays(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Validated float32 ``[V,3]`` vertices and int ``[F,3]`` faces (torch or numpy in)."""
    v = vertices.detach().cpu().numpy() if hasattr(vertices, "detach") else np.asarray(vertices)
    f = faces.detach().cpu().numpy() if hasattr(faces, "detach") else np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape [V,3], got {list(v.shape)}")
    if v.shape[0] == 0:
        raise ValueError("empty mesh: no vertices")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices contain NaN or infinite values")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape [F,3], got {list(f.shape)}")
    if f.shape[0] == 0:
        raise ValueError("empty mesh: no faces")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise ValueError(f"faces index vertices out of range [0, {v.shape[0]})")
    return np.ascontiguousarray(v, dtype=np.float32), np.ascontiguousarray(f, dtype=np.int64)


def _check_camera(camera) -> Camera:
    from .silhouette import check_camera  # light: no Mitsuba import at module level there

    return check_camera(camera)


# --------------------------------------------------------------------------- renderer
@dataclass
class Rendering:
    """``color [H,W,3] uint8`` (``None`` for depth-only renders), ``depth [H,W] float32``
    (z in metres, 0 = background) and ``mask [H,W] bool``."""

    color: Optional[np.ndarray]
    depth: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        return self.depth > 0


def _look_pose(direction: Sequence[float]) -> np.ndarray:
    """4x4 pose whose -z axis points along ``direction`` (light travel direction)."""
    d = np.asarray(direction, dtype=np.float64)
    z = -d / np.linalg.norm(d)
    up = np.array([0.0, -1.0, 0.0]) if abs(z[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = x, y, z
    return pose


#: (direction of travel in camera coordinates, intensity): key from upper left, fill from
#: the right, rim from behind-above: shows the body's shape without harsh shadows.
_LIGHTS = (((0.5, 0.55, 1.0), 2.4), ((-0.8, 0.1, 0.6), 0.7), ((0.0, 0.6, -1.0), 1.2))
_GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])


class OffscreenRenderer:
    """A pyrender ``OffscreenRenderer`` of one size plus a reusable scene (camera, lights).

    Not thread-safe (OpenGL contexts are per thread); use :func:`get_renderer` to share one
    per size."""

    def __init__(self, width: int, height: int):
        if int(width) <= 0 or int(height) <= 0:
            raise ValueError(f"render size must be positive, got {width}x{height}")
        pr = _pyrender()
        self.width, self.height = int(width), int(height)
        self._pr = pr
        self._renderer = pr.OffscreenRenderer(self.width, self.height)
        self._scene = pr.Scene(bg_color=(*_BACKGROUND, 0.0), ambient_light=(0.1, 0.1, 0.11))
        self._camera_node = self._scene.add(
            pr.IntrinsicsCamera(1.0, 1.0, 0.0, 0.0, znear=0.01, zfar=1000.0), pose=_GL_FROM_CV
        )
        for direction, intensity in _LIGHTS:
            self._scene.add(pr.DirectionalLight(color=np.ones(3), intensity=intensity), pose=_look_pose(direction))
        self._mesh_node = None

    def _set_camera(self, camera: Camera) -> None:
        cam = self._camera_node.camera
        cam.fx, cam.fy = camera.fx, camera.fy
        cam.cx, cam.cy = camera.cx + 0.5, camera.cy + 0.5
        self._camera_node.camera.zfar = 1000.0

    def _set_mesh(self, vertices: np.ndarray, faces: np.ndarray, color, shaded: bool) -> None:
        pr = self._pr
        if self._mesh_node is not None:
            self._scene.remove_node(self._mesh_node)
            self._mesh_node = None
        normals = _vertex_normals(vertices, faces) if shaded else None
        material = pr.MetallicRoughnessMaterial(
            baseColorFactor=(*[float(c) for c in color], 1.0),
            metallicFactor=0.0,
            roughnessFactor=0.65,
            doubleSided=True,
        )
        prim = pr.Primitive(
            positions=vertices, normals=normals, indices=faces, material=material, mode=pr.constants.GLTF.TRIANGLES
        )
        self._mesh_node = self._scene.add(pr.Mesh([prim]))

    def render(self, vertices, faces, camera: Camera, color=BODY_COLOR, depth_only: bool = False) -> Rendering:
        """Shaded colour (unless ``depth_only``) and depth of a mesh in camera coordinates."""
        camera = _check_camera(camera)
        if (camera.width, camera.height) != (self.width, self.height):
            raise ValueError(
                f"camera is {camera.width}x{camera.height} but this renderer is {self.width}x{self.height}"
            )
        v, f = mesh_arrays(vertices, faces)
        self._set_camera(camera)
        self._set_mesh(v, f, color, shaded=not depth_only)
        flags = self._pr.RenderFlags.SKIP_CULL_FACES
        if depth_only:
            depth = self._renderer.render(self._scene, flags=flags | self._pr.RenderFlags.DEPTH_ONLY)
            return Rendering(color=None, depth=np.asarray(depth, dtype=np.float32))
        color_im, depth = self._renderer.render(self._scene, flags=flags)
        return Rendering(color=np.asarray(color_im[..., :3], dtype=np.uint8), depth=np.asarray(depth, dtype=np.float32))

    def delete(self) -> None:
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer = None


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    idx = faces.reshape(-1)
    vn = np.stack([np.bincount(idx, weights=np.repeat(fn[:, c], 3), minlength=len(vertices)) for c in range(3)], axis=1)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    return (vn / np.maximum(norm, 1e-12)).astype(np.float32)


_RENDERERS: dict[tuple[int, int, int], OffscreenRenderer] = {}


def get_renderer(width: int, height: int) -> OffscreenRenderer:
    """The shared :class:`OffscreenRenderer` of this size (one per thread)."""
    key = (threading.get_ident(), int(width), int(height))
    renderer = _RENDERERS.get(key)
    if renderer is None:
        renderer = _RENDERERS[key] = OffscreenRenderer(width, height)
    return renderer


# --------------------------------------------------------------------------- functions
def render_mesh(vertices, faces, camera: Camera, color=BODY_COLOR) -> Rendering:
    """Shaded colour, depth and mask of a camera-frame mesh under ``camera``."""
    camera = _check_camera(camera)
    return get_renderer(camera.width, camera.height).render(vertices, faces, camera, color=color)


def render_depth(vertices, faces, camera: Camera) -> np.ndarray:
    """Depth ``[H,W]`` float32 (z in metres, 0 = background)."""
    camera = _check_camera(camera)
    return get_renderer(camera.width, camera.height).render(vertices, faces, camera, depth_only=True).depth


def render_mask(vertices, faces, camera: Camera) -> np.ndarray:
    """Binary mask ``[H,W]`` bool: pixels whose centre the mesh covers."""
    return render_depth(vertices, faces, camera) > 0


def overlay(
    image: np.ndarray, vertices, faces, camera: Optional[Camera] = None, alpha: float = 0.6, color=BODY_COLOR
) -> np.ndarray:
    """The shaded body blended over ``image`` (``[H,W,3]`` or ``[H,W]`` uint8) with opacity
    ``alpha`` where the body is.  ``camera`` defaults to the image's default camera."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"overlay image must be [H,W], [H,W,3] or [H,W,4], got {list(img.shape)}")
    img = img[..., :3]
    if img.dtype != np.uint8:
        img = np.clip(img * (255.0 if img.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    h, w = img.shape[:2]
    if camera is None:
        camera = Camera.from_image_size(w, h)
    camera = _check_camera(camera)
    if (camera.width, camera.height) != (w, h):
        raise ValueError(f"camera is {camera.width}x{camera.height} but the image is {w}x{h}")
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    r = render_mesh(vertices, faces, camera, color=color)
    a = (r.mask.astype(np.float32) * float(alpha))[..., None]
    out = img.astype(np.float32) * (1.0 - a) + r.color.astype(np.float32) * a
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------- views
_NAMED_VIEWS = {"front": 0.0, "right": 90.0, "side": 90.0, "back": 180.0, "left": 270.0}


def view_angles(
    views: Union[str, Sequence[str], None] = None, turntable: Optional[int] = None
) -> list[tuple[str, float]]:
    """``(name, degrees)`` for named views (``front, side/right, back, left``) or a
    turntable of ``turntable`` evenly spaced views (``turn000`` ...)."""
    if turntable is not None:
        if int(turntable) != turntable or turntable <= 0:
            raise ValueError(f"turntable needs a positive number of views, got {turntable!r}")
        n = int(turntable)
        return [(f"turn{k:03d}", 360.0 * k / n) for k in range(n)]
    if views is None:
        views = ["front"]
    if isinstance(views, str):
        views = [s.strip() for s in views.split(",") if s.strip()]
    out = []
    for name in views:
        if name not in _NAMED_VIEWS:
            raise ValueError(f"unknown view {name!r}; choose from {', '.join(_NAMED_VIEWS)}")
        out.append((name, _NAMED_VIEWS[name]))
    if not out:
        raise ValueError("no views requested")
    return out


def rotate_about_vertical(vertices: np.ndarray, degrees: float, centre: Optional[np.ndarray] = None) -> np.ndarray:
    """Rotate camera-frame vertices about the camera's vertical (y) axis through ``centre``
    (default: the bounding-box centre), as if walking around the person: 90 degrees
    shows the person's right/left side depending on their facing."""
    v = np.asarray(vertices, dtype=np.float64)
    c = (v.min(0) + v.max(0)) / 2 if centre is None else np.asarray(centre, dtype=np.float64)
    t = math.radians(degrees)
    rot = np.array([[math.cos(t), 0.0, math.sin(t)], [0.0, 1.0, 0.0], [-math.sin(t), 0.0, math.cos(t)]])
    return ((v - c) @ rot.T + c).astype(np.float32)


def framing_camera(
    vertices, width: int, height: int, fov_degrees: float = 30.0, margin: float = 0.08
) -> tuple[Camera, np.ndarray]:
    """A camera (centred principal point, vertical field of view ``fov_degrees``) and the
    vertices moved along the optical axis so the mesh's bounding box is centred and fills
    the image up to ``margin`` (fraction of the size) on each side.  Returns ``(camera,
    moved vertices)``; the mesh's orientation relative to the camera is unchanged."""
    if int(width) <= 0 or int(height) <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if not 0 <= margin < 0.5:
        raise ValueError(f"margin must be in [0, 0.5), got {margin}")
    v = np.asarray(vertices, dtype=np.float64)
    f = (height / 2.0) / math.tan(math.radians(fov_degrees) / 2.0)
    camera = Camera(fx=f, fy=f, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=int(width), height=int(height))
    lo, hi = v.min(0), v.max(0)
    centre = (lo + hi) / 2
    half = np.maximum((hi - lo) / 2, 1e-6)
    usable_w, usable_h = width * (0.5 - margin), height * (0.5 - margin)
    # The nearest face of the box (depth d - half_z) must still fit: conservative distance.
    d = half[2] + max(f * half[0] / usable_w, f * half[1] / usable_h)
    moved = v - centre + np.array([0.0, 0.0, d])
    # Recentre on the projected box (perspective shifts it slightly) by a lateral move.
    uv = np.stack([f * moved[:, 0] / moved[:, 2], f * moved[:, 1] / moved[:, 2]], axis=1)
    mid = (uv.min(0) + uv.max(0)) / 2
    moved[:, :2] -= mid * d / f
    return camera, moved.astype(np.float32)


def render_views(
    vertices,
    faces,
    views: Union[str, Sequence[str], None] = ("front", "side", "back"),
    turntable: Optional[int] = None,
    size: Union[int, tuple[int, int]] = 512,
    color=BODY_COLOR,
    fov_degrees: float = 30.0,
) -> list[tuple[str, np.ndarray]]:
    """Shaded images ``(name, [H,W,3] uint8)`` of a camera-frame mesh from several views,
    each framed automatically (white background).  The same framing distance is used for
    every view so the body's size is comparable between images."""
    v, f = mesh_arrays(vertices, faces)
    w, h = (size, size) if isinstance(size, int) else (int(size[0]), int(size[1]))
    angles = view_angles(views, turntable)
    centre = (v.min(0) + v.max(0)) / 2
    # Frame with the largest horizontal extent any view can have (the bounding circle).
    radius_xz = float(np.max(np.linalg.norm((v - centre)[:, [0, 2]], axis=1)))
    ys = (v[:, 1].min() - centre[1], v[:, 1].max() - centre[1])
    box = np.array([[x, y, z] for x in (-radius_xz, radius_xz) for y in ys for z in (-radius_xz, radius_xz)])
    camera, moved_box = framing_camera(box, w, h, fov_degrees=fov_degrees)
    offset = moved_box.mean(0).astype(np.float64)  # where the box centre went
    out = []
    for name, deg in angles:
        rv = rotate_about_vertical(v, deg, centre) - centre + offset
        out.append((name, render_mesh(rv, f, camera, color=color).color))
    return out
