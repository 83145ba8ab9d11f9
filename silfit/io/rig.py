"""Calibrated camera rigs: cameras with extrinsics, and the folder layouts ``silfit fit --rig`` reads.

Convention (OpenCV, as everywhere in silfit, see :mod:`silfit.camera`): a view's extrinsics
map world points into its camera frame, ``x_cam = R @ x_world + t``; ``R`` is a 3x3
rotation (world to camera), ``t`` is in metres. Without ``R``/``t`` a camera is the world
frame itself (identity), as for single images.

One reader per format:

* ``camera.json`` (:func:`read_view_camera`): the intrinsics of :func:`silfit.camera.camera_from_dict`
  plus optional ``R`` (3x3, row-major nested lists) and ``t`` (3 numbers).
* ``cameras.json`` (:func:`read_cameras_json`): ``{"views": [{"name": "cam0", <camera.json fields>,
  optional "keypoints", "mask", "image" paths relative to the manifest}, ...]}``.
* EasyMocap's calibration (:func:`read_easymocap`): ``intri.yml`` (``names``, ``K_<cam>``,
  ``dist_<cam>``) and ``extri.yml`` (``R_<cam>`` Rodrigues vector or ``Rot_<cam>`` matrix,
  ``T_<cam>``), OpenCV FileStorage YAML read by ``cv2.FileStorage`` (a parser: nothing in the
  file is executed). It holds no image size: it comes from each view's image or mask.
  Lens distortion is not modelled: non-zero ``dist`` coefficients are reported as a warning
  (undistort the keypoints and masks first for exact results).

A rig folder (:func:`load_rig`) is one of: a ``cameras.json`` manifest; ``intri.yml`` +
``extri.yml`` with one sub-folder per camera name; or one sub-folder per view (sorted by
name), each with ``camera.json``. A view's folder holds ``keypoints.json`` (OpenPose),
optionally ``mask.png`` and ``image.png``; in a rig video (:func:`silfit.io.video.load_rig_sequence`) it is a video
folder instead (per-frame OpenPose JSON, ``masks/``, ``images/``: :func:`silfit.io.video.read_sequence`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional, Tuple, Union

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ..camera import (  # noqa: F401  (extrinsics_from_dict: re-exported, rig manifests name it)
    check_translation,
    camera_from_dict,
    check_rotation,
    extrinsics_from_dict,
    read_camera_file,
)
from ..errors import InputError, quoted
from ..fitting.problem import View
from .images import IMAGE_EXTENSIONS, image_file_size
from .limits import check_file_size, read_json
from .keypoints import KEYPOINT_FOLDERS

__all__ = [
    "RigView",
    "select_views",
    "video_folder",
    "extrinsics_from_dict",
    "load_rig",
    "project_world",
    "to_camera",
    "read_cameras_json",
    "read_easymocap",
    "read_view_camera",
    "view_to_dict",
    "write_cameras_json",
]

PathLike = Union[str, os.PathLike]


@dataclass
class RigView:
    """One view of a rig: its name, camera and extrinsics, and its files (``None`` when absent)."""

    name: str
    view: View
    keypoints: Optional[Path] = None
    mask: Optional[Path] = None
    image: Optional[Path] = None
    warnings: List[str] = field(default_factory=list)


def view_from_dict(data, source: str) -> View:
    """A :class:`~silfit.fitting.problem.View` from a camera object with optional ``R``/``t``."""
    camera = camera_from_dict(data, source)
    R, t = extrinsics_from_dict(data, source)
    return View(camera, R, t)


def read_view_camera(path: PathLike) -> View:
    """Read a ``camera.json`` with optional extrinsics ``R``, ``t`` (identity without them),
    with the one camera-file reader :func:`silfit.camera.read_camera_file`."""
    return View(*read_camera_file(path))


def view_to_dict(view: View) -> dict:
    R, t = view.extrinsics()
    return {**view.camera.to_dict(), "R": R.tolist(), "t": t.tolist()}


def _file(base: Path, value, source: str, name: str) -> Optional[Path]:
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise InputError(source, f"field '{name}' must be a file name", field=name)
    return base / value


def read_cameras_json(path: PathLike) -> List[RigView]:
    """Read a ``cameras.json`` manifest (see the module docstring). A view's files default
    to ``<name>/keypoints.json``, ``<name>/mask.png``, ``<name>/image.png`` next to it."""
    source = os.fspath(path)
    base = Path(source).parent
    data = read_json(source, "cameras")
    views = data.get("views") if isinstance(data, dict) else None
    if not isinstance(views, list) or not views:
        raise InputError(source, "field 'views' missing or empty: expected a list of cameras", field="views")
    out, names = [], set()
    for i, v in enumerate(views):
        where = f"{source}: views[{i}]"
        if not isinstance(v, dict):
            raise InputError(where, "expected a JSON object", field=f"views[{i}]")
        name = v.get("name", f"view_{i}")
        if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
            raise InputError(where, f"field 'name' must be a plain folder name, got {quoted(name)}", field="name")
        if name in names:
            raise InputError(where, f"two views named {quoted(name)}", field="name")
        names.add(name)
        files = {}
        for key, default in (("keypoints", "keypoints.json"), ("mask", "mask.png"), ("image", "image.png")):
            given = _file(base, v.get(key), where, key)
            files[key] = given if given is not None else base / name / default
        out.append(RigView(name, view_from_dict(v, where), **files))
    return out


def write_cameras_json(path: PathLike, views: List[Tuple[str, View]]) -> None:
    """Write a ``cameras.json`` manifest for ``(name, view)`` pairs (files in ``<name>/``)."""
    Path(path).write_text(
        json.dumps({"views": [{"name": n, **view_to_dict(v)} for n, v in views]}, indent=2) + "\n", encoding="utf-8"
    )


# ----------------------------------------------------------------------------- EasyMocap
def _fs_open(path: Path):
    check_file_size(path, what="calibration")
    fs = cv2.FileStorage()
    try:
        ok = fs.open(os.fspath(path), cv2.FILE_STORAGE_READ)
    except cv2.error as err:
        raise InputError(path, f"not an OpenCV FileStorage YAML file ({' '.join(str(err).split())[:120]})") from None
    if not ok:
        raise InputError(path, "not an OpenCV FileStorage YAML file")
    return fs


def _fs_matrix(fs, path: Path, key: str, sizes) -> np.ndarray:
    node = fs.getNode(key)
    if node.empty() or node.isNone():
        raise InputError(path, f"field '{key}' missing", field=key)
    try:  # a scalar, a string or a matrix whose data does not match rows x cols makes OpenCV assert
        mat = node.mat() if node.isMap() else None
    except cv2.error:
        mat = None
    if mat is None:
        raise InputError(
            path, f"field '{key}' is not an opencv-matrix (rows, cols, dt, data of rows x cols numbers)", field=key
        )
    mat = np.asarray(mat, dtype=np.float64)
    if mat.size not in sizes:
        raise InputError(
            path, f"field '{key}' has {mat.size} values, expected {' or '.join(map(str, sizes))}", field=key
        )
    if not np.all(np.isfinite(mat)):
        raise InputError(path, f"field '{key}' holds NaN or infinity", field=key)
    return mat


def _fs_names(fs, path: Path) -> List[str]:
    node = fs.getNode("names")
    if node.empty() or not node.isSeq() or node.size() == 0:
        raise InputError(path, "field 'names' missing or empty: expected the list of camera names", field="names")
    names = []
    for i in range(node.size()):
        item = node.at(i)
        name = item.string() if item.isString() else (str(int(item.real())) if item.isInt() else "")
        if not name or "/" in name or name in (".", ".."):
            raise InputError(path, f"field 'names[{i}]' must be a plain camera name", field=f"names[{i}]")
        names.append(name)
    return names


def _rodrigues(r: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(r.reshape(3)).as_matrix()


def _image_size_of(folder: Path) -> Optional[Tuple[int, int]]:
    for name in ("image.png", "image.jpg", "mask.png"):
        f = folder / name
        if f.is_file():
            return image_file_size(f, "image")
    for sub in ("images", "masks"):  # a rig video's view: its first frame's image or mask
        if (folder / sub).is_dir():
            first = next((p for p in sorted((folder / sub).iterdir()) if p.suffix.lower() in IMAGE_EXTENSIONS), None)
            if first is not None:
                return image_file_size(first, "image")
    return None


def read_easymocap(intri: PathLike, extri: PathLike, sizes=None) -> List[RigView]:
    """Read EasyMocap's ``intri.yml`` / ``extri.yml``. ``sizes`` maps a camera name to its
    ``(width, height)``; by default the size is read from ``<name>/image.png`` (or ``.jpg``,
    or ``mask.png``) next to ``intri.yml``. View files are ``<name>/keypoints.json`` etc."""
    intri, extri = Path(intri), Path(extri)
    base = intri.parent
    fi, fe = _fs_open(intri), _fs_open(extri)
    try:
        names = _fs_names(fi, intri)
        out = []
        for name in names:
            K = _fs_matrix(fi, intri, f"K_{name}", (9,)).reshape(3, 3)
            warnings = []
            if not fi.getNode(f"dist_{name}").empty():
                dist = _fs_matrix(fi, intri, f"dist_{name}", (4, 5, 8, 12, 14))
                if np.abs(dist).max() > 1e-6:
                    warnings.append(
                        f"{intri}: camera {name}: lens distortion (dist_{name}) is ignored; undistort the "
                        "keypoints and masks for exact results"
                    )
            if not fe.getNode(f"Rot_{name}").empty():
                R = _fs_matrix(fe, extri, f"Rot_{name}", (9,)).reshape(3, 3)
                R = check_rotation(R, os.fspath(extri), f"Rot_{name}")
            else:
                R = _rodrigues(_fs_matrix(fe, extri, f"R_{name}", (3,)))
            t = check_translation(_fs_matrix(fe, extri, f"T_{name}", (3,)).reshape(3), os.fspath(extri), f"T_{name}")
            size = (sizes or {}).get(name) or _image_size_of(base / name)
            if size is None:
                raise InputError(
                    intri,
                    f"camera {name}: no image size (intri.yml has none; expected {base / name}/image.png or mask.png)",
                    field=f"K_{name}",
                )
            cam = camera_from_dict(
                {
                    "fx": K[0, 0],
                    "fy": K[1, 1],
                    "cx": K[0, 2],
                    "cy": K[1, 2],
                    "width": int(size[0]),
                    "height": int(size[1]),
                },
                f"{intri}: K_{name}",
            )
            folder = base / name
            out.append(
                RigView(
                    name,
                    View(cam, R, t),
                    folder / "keypoints.json",
                    folder / "mask.png",
                    folder / "image.png",
                    warnings,
                )
            )
        return out
    finally:
        fi.release()
        fe.release()


# ----------------------------------------------------------------------------- rig folders
def video_folder(view: RigView) -> Path:
    """A rig video's view folder: the view's ``keypoints`` entry when it names a folder, else the
    folder its ``keypoints.json`` would be in (``<name>/``); read by :func:`silfit.io.video.read_sequence`."""
    return view.keypoints if view.keypoints.is_dir() else view.keypoints.parent


def holds_video(folder: Path) -> bool:
    if not folder.is_dir():
        return False
    return any((folder / d).is_dir() for d in KEYPOINT_FOLDERS) or any(folder.glob("*_keypoints.json"))


def select_views(views: List[RigView], names=None) -> List[RigView]:
    """Only the views ``names`` (``--views``; in the rig's order; an unknown name is an
    :class:`~silfit.errors.InputError` listing the rig's), all of them without ``names``."""
    if not names:
        return list(views)
    known = [v.name for v in views]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise InputError("--views", f"unknown view(s) {', '.join(unknown)} (the rig has {', '.join(known)})")
    return [v for v in views if v.name in names]


def load_rig(folder: PathLike) -> List[RigView]:
    """The views of a rig folder (see the module docstring), files that do not exist set to ``None``
    (a view without ``keypoints.json`` is an error)."""
    folder = Path(folder)
    views = read_rig_views(folder)
    for v in views:
        if v.keypoints is None or not v.keypoints.is_file():
            hint = (
                " (its folder holds a video: per-frame keypoints)"
                if v.keypoints is not None and holds_video(video_folder(v))
                else ""
            )
            raise InputError(v.keypoints or folder, f"view {v.name}: keypoint file not found{hint}", field="keypoints")
        v.mask = v.mask if v.mask is not None and v.mask.is_file() else None
        v.image = v.image if v.image is not None and v.image.is_file() else None
    return views


def read_rig_views(folder: Path) -> List[RigView]:
    """The rig's views with their default file paths (not checked)."""
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: rig folder not found")
    if (folder / "cameras.json").is_file():
        views = read_cameras_json(folder / "cameras.json")
    elif (folder / "intri.yml").is_file() and (folder / "extri.yml").is_file():
        views = read_easymocap(folder / "intri.yml", folder / "extri.yml")
    else:
        subs = sorted(p for p in folder.iterdir() if p.is_dir() and (p / "camera.json").is_file())
        if not subs:
            raise InputError(
                folder, "not a rig: expected cameras.json, intri.yml + extri.yml, or sub-folders with camera.json"
            )
        views = [
            RigView(p.name, read_view_camera(p / "camera.json"), p / "keypoints.json", p / "mask.png", p / "image.png")
            for p in subs
        ]
    return views


def to_camera(points: np.ndarray, view: View) -> np.ndarray:
    """World points ``[N, 3]`` in a view's camera frame, ``R x + t``."""
    R, t = view.extrinsics()
    return np.asarray(points, np.float64) @ R.T + t


def project_world(points: np.ndarray, view: View) -> np.ndarray:
    """Pixels ``[N, 2]`` of world points ``[N, 3]`` in a view (OpenCV pinhole)."""
    c = to_camera(points, view)
    cam = view.camera
    z = np.maximum(c[:, 2], 1e-6)
    return np.stack([cam.fx * c[:, 0] / z + cam.cx, cam.fy * c[:, 1] / z + cam.cy], 1)


def camera_centre(view: View) -> np.ndarray:
    """The camera centre in world coordinates, ``-R^T t``."""
    R, t = view.extrinsics()
    return -R.T @ t


def look_at(centre: np.ndarray, target: np.ndarray, up=(0.0, -1.0, 0.0)) -> Tuple[np.ndarray, np.ndarray]:
    """World-to-camera ``(R, t)`` of an OpenCV camera at ``centre`` looking at ``target``
    (image ``y`` down along ``-up``)."""
    z = np.asarray(target, float) - np.asarray(centre, float)
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up, float), z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ np.asarray(centre, float)


def ring_layout(
    n: int, radius: float, heights=None, target=(0.0, 0.0, 0.0), start_deg: float = 0.0
) -> List[Tuple[np.ndarray, np.ndarray]]:
    """``n`` cameras on a ring around ``target`` (world y down: height ``h`` is at ``y = -h``),
    evenly spaced in azimuth from ``start_deg``, all looking at ``target``."""
    heights = [0.0] * n if heights is None else list(heights)
    out = []
    for i in range(n):
        a = math.radians(start_deg + 360.0 * i / n)
        centre = np.array([radius * math.sin(a), -heights[i], -radius * math.cos(a)]) + np.asarray(target, float)
        out.append(look_at(centre, target))
    return out
