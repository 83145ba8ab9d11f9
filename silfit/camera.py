"""Pinhole cameras and the one camera convention of the whole project.

Convention (OpenCV, shared by projection, the Mitsuba silhouette renderer, the
offscreen rasteriser, the synthetic generator and every file silfit writes):

* Camera coordinates: x to the right, y down, z forward (into the scene), metres.
* Pixel coordinates: ``u`` to the right, ``v`` down. Pixel centres lie on integer
  coordinates, so the top-left pixel's centre is ``(0, 0)`` and the image spans
  ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.
* Intrinsics ``fx, fy, cx, cy`` in pixels:  ``u = fx * x / z + cx``,
  ``v = fy * y / z + cy``.
* The body's ``global_orient`` and ``transl`` act as the extrinsics: the body model's
  output (vertices, joints) *is* in camera coordinates, so a fit's ``params.npz``
  fed to any SMPL implementation reproduces ``mesh.obj`` vertex for vertex.  The
  model's rest frame has Y up and the body facing +Z; a person standing upright and
  facing the camera therefore has ``global_orient`` = axis-angle ``(pi, 0, 0)``
  (:data:`UPRIGHT_FACING_CAMERA`), and one seen from behind ``(0, 0, pi)``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from typing import Optional, Tuple, Union

import numpy as np
import torch

from .errors import InputError, quoted
from .io.limits import image_size_problem, read_json

__all__ = [
    "Camera",
    "DEFAULT_FOCAL_FACTOR",
    "default_focal",
    "project_points",
    "weak_perspective_project",
    "UPRIGHT_FACING_CAMERA",
    "UPRIGHT_BACK_TO_CAMERA",
    "camera_from_dict",
    "extrinsics_from_dict",
    "load_camera",
    "read_camera_file",
    "save_camera",
]

#: Default focal length (pixels) = factor * max(width, height) when no intrinsics are
#: given: about a 53 degree field of view across the longer side, typical of phone and
#: consumer cameras (SMPLify's fixed 5000 px instead assumes a far, nearly orthographic
#: camera, which is wrong for most photographs).
DEFAULT_FOCAL_FACTOR = 1.0

#: ``global_orient`` (axis-angle) of a person standing upright and facing the camera.
UPRIGHT_FACING_CAMERA = (math.pi, 0.0, 0.0)
#: ``global_orient`` (axis-angle) of a person standing upright with their back to the camera.
UPRIGHT_BACK_TO_CAMERA = (0.0, 0.0, math.pi)

_FIELDS = ("fx", "fy", "cx", "cy", "width", "height")
#: A camera file's focal lengths must lie within these multiples of the image's longer side
#: (a 0.06-degree telephoto to a 177-degree wide angle), its principal point within
#: :data:`MAX_PRINCIPAL_OFFSET` image sizes of the image centre.
FOCAL_RANGE = (0.01, 1000.0)
MAX_PRINCIPAL_OFFSET = 10.0


def _finite(value) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an int beyond float range
        return False


def default_focal(width: int, height: int, factor: float = DEFAULT_FOCAL_FACTOR) -> float:
    """The documented default focal length for an image of the given size."""
    return float(factor) * float(max(width, height))


@dataclass(frozen=True)
class Camera:
    """A pinhole camera in the project's OpenCV convention (see the module docstring)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self):
        for name in _FIELDS:
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not _finite(value):
                raise ValueError(f"camera field '{name}' must be a finite number, got {quoted(value)}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"camera focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if int(self.width) != self.width or int(self.height) != self.height or self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera width/height must be positive integers, got {self.width}x{self.height}")
        problem = image_size_problem(int(self.width), int(self.height))
        if problem:
            raise ValueError(f"camera width/height: {problem}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @classmethod
    def from_image_size(cls, width: int, height: int, focal: float | None = None) -> "Camera":
        """Centred principal point and the default (or given) focal length."""
        f = default_focal(width, height) if focal is None else float(focal)
        return cls(fx=f, fy=f, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height)

    @classmethod
    def from_intrinsics(cls, intrinsics, image_size) -> "Camera":
        """From ``(fx, fy, cx, cy)`` and ``(width, height)``, as fits store them in ``params.npz``
        (``camera_intrinsics``, ``image_size``)."""
        try:
            fx, fy, cx, cy = (float(v) for v in np.asarray(intrinsics, dtype=np.float64).reshape(-1))
        except (TypeError, ValueError):
            raise ValueError(
                f"camera_intrinsics must be 4 numbers (fx, fy, cx, cy), got {quoted(intrinsics)}"
            ) from None
        try:
            width, height = (float(v) for v in np.asarray(image_size, dtype=np.float64).reshape(-1))
        except (TypeError, ValueError):
            raise ValueError(f"image_size must be 2 numbers (width, height), got {quoted(image_size)}") from None
        if not (_finite(width) and _finite(height)) or int(width) != width or int(height) != height:
            raise ValueError(f"camera width/height must be positive integers, got {width}x{height}")
        return cls(fx=fx, fy=fy, cx=cx, cy=cy, width=int(width), height=int(height))

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    def K(self, dtype=torch.float32, device=None) -> torch.Tensor:
        """The 3x3 intrinsic matrix."""
        return torch.tensor(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=dtype, device=device
        )

    def crop(self, x0: float, y0: float, width: int, height: int, scale: float = 1.0) -> "Camera":
        """The camera of the window ``[x0, x0+width/scale) x [y0, y0+height/scale)`` of this
        image (pixel-edge coordinates of the original), resampled by ``scale``."""
        s = float(scale)
        return Camera(
            fx=self.fx * s,
            fy=self.fy * s,
            cx=(self.cx + 0.5 - x0) * s - 0.5,
            cy=(self.cy + 0.5 - y0) * s - 0.5,
            width=int(width),
            height=int(height),
        )

    def to_dict(self) -> dict:
        return asdict(self)


def project_points(points: torch.Tensor, camera: Union[Camera, torch.Tensor], eps: float = 1e-6) -> torch.Tensor:
    """Perspective projection of camera-frame points ``[..., N, 3]`` to pixels ``[..., N, 2]``.

    ``camera`` is a :class:`Camera` or a tensor ``[..., 4]`` of ``(fx, fy, cx, cy)``
    (one row per batch element) so focal lengths can be optimised or batched.
    Depths are clamped to ``eps`` so points behind the camera do not produce infinities.
    """
    if isinstance(camera, Camera):
        fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    else:
        intr = camera.to(points.dtype)
        fx, fy, cx, cy = (intr[..., i, None] for i in range(4))
    z = points[..., 2].clamp(min=eps)
    u = fx * points[..., 0] / z + cx
    v = fy * points[..., 1] / z + cy
    return torch.stack([u, v], dim=-1)


def weak_perspective_project(points: torch.Tensor, scale: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """Weak-perspective (scaled orthographic) projection ``u = s * x + t``.

    ``points [..., N, 3]`` in camera axes, ``scale [...]`` in pixels per metre,
    ``offset [..., 2]`` in pixels.
    """
    return scale[..., None, None] * points[..., :2] + offset[..., None, :]


def camera_from_dict(data, source: str) -> Camera:
    """A :class:`Camera` from a JSON object with ``fx, fy, cx, cy, width, height``, with
    plausible intrinsics (:data:`FOCAL_RANGE`, :data:`MAX_PRINCIPAL_OFFSET`); errors are
    :class:`~silfit.errors.InputError` naming ``source`` and the field."""
    if not isinstance(data, dict):
        raise InputError(source, f"expected a JSON object with fields {', '.join(_FIELDS)}")
    missing = [name for name in _FIELDS if name not in data]
    if missing:
        raise InputError(source, f"camera field(s) missing: {', '.join(missing)} (expected {', '.join(_FIELDS)})")
    try:
        camera = Camera(**{name: data[name] for name in _FIELDS})
    except ValueError as err:
        raise InputError(source, str(err)) from None
    side = max(camera.width, camera.height)
    for name in ("fx", "fy"):
        ratio = getattr(camera, name) / side
        if not FOCAL_RANGE[0] <= ratio <= FOCAL_RANGE[1]:
            raise InputError(
                source,
                f"camera field '{name}' = {getattr(camera, name):g} px is {ratio:g} times the image's longer "
                f"side; expected {FOCAL_RANGE[0]:g} to {FOCAL_RANGE[1]:g} times (is it in pixels?)",
                field=name,
            )
    for name, centre, size in (("cx", camera.width / 2, camera.width), ("cy", camera.height / 2, camera.height)):
        if abs(getattr(camera, name) - centre) > MAX_PRINCIPAL_OFFSET * size:
            raise InputError(
                source,
                f"camera field '{name}' = {getattr(camera, name):g} lies far outside the "
                f"{camera.width}x{camera.height} image",
                field=name,
            )
    return camera


#: a rotation's ``R R^T`` may differ from the identity by this much (and ``det R`` from 1)
ROTATION_TOL = 1e-3
#: camera centres must lie within this many metres of the world origin
MAX_TRANSLATION_M = 1e4


def _leaves(value):
    if isinstance(value, (list, tuple)):
        for v in value:
            yield from _leaves(v)
    else:
        yield value


def _matrix(value, shape, source, name) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(source, f"camera field '{name}' must be numbers of shape {shape}", field=name) from None
    if arr.size != int(np.prod(shape)):
        raise InputError(source, f"camera field '{name}' must have shape {shape}, got {arr.shape}", field=name)
    if not isinstance(value, (list, tuple)) or any(isinstance(v, (bool, str)) for v in _leaves(value)):
        raise InputError(
            source,
            f"camera field '{name}' must be a list of numbers of shape {shape} (no booleans or strings)",
            field=name,
        )
    arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise InputError(source, f"camera field '{name}' holds NaN or infinity", field=name)
    return arr


def check_rotation(R: np.ndarray, source: str, name: str = "R") -> np.ndarray:
    """``R`` as a proper rotation matrix, or an :class:`InputError` naming the field."""
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    if err > ROTATION_TOL or abs(float(np.linalg.det(R)) - 1.0) > ROTATION_TOL:
        raise InputError(
            source,
            f"camera field '{name}' is not a rotation matrix (|R R^T - I| = {err:.3g}, "
            f"det {np.linalg.det(R):.3g}); expected world-to-camera R, OpenCV convention",
            field=name,
        )
    return R


def check_translation(t: np.ndarray, source: str, name: str = "t") -> np.ndarray:
    if float(np.abs(t).max()) > MAX_TRANSLATION_M:
        raise InputError(
            source,
            f"camera field '{name}' = {t.tolist()} is beyond {MAX_TRANSLATION_M:g} m (is it in metres?)",
            field=name,
        )
    return t


def extrinsics_from_dict(data: dict, source: str) -> Tuple[Optional[np.ndarray], Optional[np.ndarray]]:
    """Optional ``R`` (3x3 world to camera) and ``t`` (metres) of a camera object; both or neither."""
    has_R, has_t = "R" in data, "t" in data
    if has_R != has_t:
        missing = "t" if has_R else "R"
        raise InputError(
            source, f"camera field '{missing}' missing: give both R (3x3) and t (3), or neither", field=missing
        )
    if not has_R:
        return None, None
    R = check_rotation(_matrix(data["R"], (3, 3), source, "R"), source)
    t = check_translation(_matrix(data["t"], (3,), source, "t"), source)
    return R, t


def read_camera_file(path: Union[str, os.PathLike]) -> Tuple[Camera, Optional[np.ndarray], Optional[np.ndarray]]:
    """The one reader of ``camera.json``: ``(camera, R, t)`` from ``fx, fy, cx, cy, width,
    height`` and the optional world-to-camera extrinsics ``R`` (3x3), ``t`` (metres; both or
    neither, ``None`` without them), every field checked, errors naming the file and field."""
    data = read_json(path, "camera")
    source = os.fspath(path)
    camera = camera_from_dict(data, source)
    R, t = extrinsics_from_dict(data, source)
    return camera, R, t


def load_camera(path: Union[str, os.PathLike]) -> Camera:
    """The intrinsics of a ``camera.json`` (:func:`read_camera_file`; its ``R``, ``t`` are checked too)."""
    return read_camera_file(path)[0]


def save_camera(camera: Camera, path: Union[str, os.PathLike]) -> None:
    """Write ``camera.json`` atomically (a temporary file renamed into place)."""
    tmp = f"{os.fspath(path)}.tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(camera.to_dict(), fh, indent=2)
    os.replace(tmp, path)
