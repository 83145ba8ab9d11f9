"""The on-disk subject format shared by ``silfit synth``, ``silfit fit`` and ``silfit eval``.

A **subject** is one folder::

    <subject>/
      keypoints.json   OpenPose BODY_25 JSON: people[0].pose_keypoints_2d = 25 x [x, y, confidence]
                       (COCO-17 and plain lists are read too, see silfit.io.keypoints.read_keypoints);
                       undetected / out-of-image points are (0, 0, 0).
      camera.json      {"fx", "fy", "cx", "cy", "width", "height"}: OpenCV pinhole (x right, y down,
                       z forward; pixel centres on integers, the top-left pixel's centre is (0, 0)).
      mask.png         binary person mask, 8-bit grey (0 background, 255 person), width x height.
      image.png        RGB render / photo, width x height (optional for fitting).
      gt.npz           ground truth (synthetic subjects only): betas [10], body_pose [69],
                       global_orient [3], transl [3], vertices [V, 3], joints [24, 3] (metres, in
                       camera.json's camera frame), plus keypoints_3d [25, 3],
                       keypoints_2d_clean [25, 2] (noise-free projections), keypoints_visibility [25]
                       (2 visible, 1 self-occluded, 0 outside the image), keypoints_dropped [25]
                       (bool), coco17_2d_clean [17, 2], stature (m) and the subject's noise_px.
                       Whole-body subjects (``silfit synth --whole-body``): body_pose [63], joints
                       [55, 3], SMPL-X's expression, jaw/eye and hand poses, the finger angles, and
                       hand_left/hand_right/face _3d, _2d_clean, _visibility, _dropped.

A **dataset** is a folder of subject folders, optionally with ``index.json``
(``{"format": "silfit-synthetic", "version": 1, "generator": {...}, "subjects": [{"name": ..., ...}]}``);
without an index every sub-folder holding a ``keypoints.json`` or ``camera.json`` is a subject.

Every reader here raises :class:`SubjectError` (a ``ValueError``) or ``FileNotFoundError``
whose message starts with the offending file's path and names the field.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, Optional, Sequence, Union

import numpy as np
from PIL import Image

from ..errors import InputError

from ..camera import Camera, load_camera
from ..silhouette.masks import read_mask as read_person_mask
from .images import pixels_to_rgb8, read_pixels
from .keypoints import KeypointSet, read_keypoints
from .safe_pickle import load_npz

__all__ = [
    "SUBJECT_FILES",
    "GT_FIELDS",
    "SubjectError",
    "GroundTruth",
    "Subject",
    "load_subject",
    "read_mask",
    "read_image",
    "read_gt",
    "read_truth",
    "read_index",
    "list_subjects",
    "write_png",
    "save_npz",
]

PathLike = Union[str, os.PathLike]

#: Component name -> file name inside a subject folder.
SUBJECT_FILES = {
    "keypoints": "keypoints.json",
    "camera": "camera.json",
    "mask": "mask.png",
    "image": "image.png",
    "gt": "gt.npz",
}
#: Required fields of ``gt.npz`` and their shapes (``None``: any size along that axis).
GT_FIELDS = {
    "betas": (None,),
    "body_pose": (None,),  # 69 (SMPL) or 63 (SMPL-X, whole-body subjects)
    "global_orient": (3,),
    "transl": (3,),
    "vertices": (None, 3),
    "joints": (None, 3),
}
#: The SMPL-X parameters a whole-body subject's gt.npz adds (kept in ``GroundTruth.extras``).
WHOLEBODY_GT_PARAMS = ("expression", "jaw_pose", "leye_pose", "reye_pose", "left_hand_pose", "right_hand_pose")
INDEX_NAME = "index.json"


class SubjectError(InputError):
    """A malformed subject file: ``path`` and ``field`` name what is wrong."""

    def __init__(self, path: PathLike, field: str, message: str):
        self.path = os.fspath(path)
        self.message = message
        super().__init__(self.path, message if field == "<file>" else f"field '{field}': {message}", field)


@dataclass
class GroundTruth:
    betas: np.ndarray
    body_pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray
    vertices: np.ndarray
    joints: np.ndarray
    extras: Dict[str, np.ndarray] = field(default_factory=dict)

    def params(self) -> Dict[str, np.ndarray]:
        """The SMPL (or, for whole-body subjects, SMPL-X) parameters as ``[1, n]`` arrays, ready for
        ``model(**params)``."""
        params = {
            k: getattr(self, k)[None].astype(np.float32) for k in ("betas", "body_pose", "global_orient", "transl")
        }
        params.update({k: self.extras[k][None].astype(np.float32) for k in WHOLEBODY_GT_PARAMS if k in self.extras})
        return params


@dataclass
class Subject:
    name: str
    path: Path
    camera: Camera
    keypoints: Optional[KeypointSet] = None
    mask: Optional[np.ndarray] = None  # bool [H, W]
    image: Optional[np.ndarray] = None  # uint8 [H, W, 3]
    gt: Optional[GroundTruth] = None

    def file(self, component: str) -> Path:
        return self.path / SUBJECT_FILES[component]


# ----------------------------------------------------------------------------- writers
def write_png(path: PathLike, array: np.ndarray) -> None:
    """Write a uint8 grey ``[H, W]`` or RGB ``[H, W, 3]`` PNG with no metadata (byte-identical for
    identical pixels), atomically (a temporary file renamed into place)."""
    arr = np.ascontiguousarray(array)
    if arr.dtype == bool:
        arr = arr.astype(np.uint8) * 255
    if arr.dtype != np.uint8:
        raise ValueError(f"{os.fspath(path)}: PNG data must be uint8 or bool, got {arr.dtype}")
    tmp = Path(f"{os.fspath(path)}.tmp")
    try:
        Image.fromarray(arr).save(tmp, format="PNG", optimize=False, compress_level=6)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def save_npz(path: PathLike, arrays: Mapping[str, np.ndarray], compress: bool = True) -> None:
    """Like ``np.savez_compressed`` but deterministic: fixed zip timestamps, sorted-free insertion
    order as given, so the same arrays always give the same bytes."""
    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    tmp = Path(f"{os.fspath(path)}.tmp")
    with zipfile.ZipFile(tmp, "w", compression=mode) as zf:
        for key, value in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asanyarray(value), allow_pickle=False)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = mode
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())
    os.replace(tmp, path)


# ----------------------------------------------------------------------------- readers
def read_mask(path: PathLike, size: Optional[Sequence[int]] = None) -> np.ndarray:
    """Read a person mask as ``bool [H, W]`` with :func:`silfit.silhouette.read_mask`'s rules;
    ``size = (width, height)`` checks the image size. Errors are :class:`SubjectError`."""
    try:
        return read_person_mask(path, size)
    except (ValueError, FileNotFoundError) as err:
        message = str(err)
        prefix = f"{os.fspath(path)}: "
        raise SubjectError(path, "mask", message[len(prefix) :] if message.startswith(prefix) else message) from None


def read_image(path: PathLike, size: Optional[Sequence[int]] = None) -> np.ndarray:
    """Read an image as ``uint8 [H, W, 3]`` RGB."""
    arr = pixels_to_rgb8(_read_png(path, "image"))
    _check_size(path, "image", arr, size)
    return arr


def _read_png(path: PathLike, what: str) -> np.ndarray:
    """The shared image reader (:mod:`silfit.io.images`: size limits from the header, every
    decoding error one line), its errors as :class:`SubjectError`."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: {what} file not found")
    try:
        arr = read_pixels(path, what)
    except InputError as err:
        raise SubjectError(path, what, str(err).partition(": ")[2]) from None
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise SubjectError(path, what, f"unexpected image shape {arr.shape}")
    return arr


def _check_size(path, what, arr, size):
    if size is not None:
        w, h = int(size[0]), int(size[1])
        if arr.shape[0] != h or arr.shape[1] != w:
            raise SubjectError(
                path, what, f"image is {arr.shape[1]}x{arr.shape[0]} pixels but camera.json says {w}x{h}"
            )


def read_truth(path: PathLike) -> Dict[str, np.ndarray]:
    """Every array of a ``gt.npz`` (any kind: one image's, a rig's, a sequence's), numeric and
    read without pickles and within the size limits of :func:`silfit.io.safe_pickle.load_npz`; the one
    reader of ground-truth files (:func:`read_gt` checks one image's fields on top)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: ground-truth file not found")
    raw = {k: np.asarray(v) for k, v in load_npz(path, what="ground truth").items()}
    for name, arr in raw.items():
        if arr.dtype.kind not in "fiub":
            raise SubjectError(path, name, f"must be numeric, got dtype {arr.dtype}")
    return raw


def read_gt(path: PathLike, fields: Iterable[str] = tuple(GT_FIELDS)) -> GroundTruth:
    """Read and validate ``gt.npz`` (see the module docstring for its fields)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: ground-truth file not found")
    try:
        with np.load(path, allow_pickle=False) as data:
            raw = {k: np.asarray(data[k]) for k in data.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as err:
        raise SubjectError(path, "<file>", f"not a readable .npz archive ({err})") from None
    out = {}
    for name in fields:
        if name not in raw:
            raise SubjectError(path, name, f"missing (the file holds: {', '.join(sorted(raw)) or 'nothing'})")
        arr = raw[name]
        if arr.dtype.kind not in "fiu":
            raise SubjectError(path, name, f"must be numeric, got dtype {arr.dtype}")
        arr = arr.astype(np.float64)
        expected = GT_FIELDS.get(name)
        if expected is not None:
            if arr.ndim == len(expected) + 1 and arr.shape[0] == 1:
                arr = arr[0]
            if arr.ndim != len(expected) or any(e is not None and e != s for e, s in zip(expected, arr.shape)):
                shape = "[" + ", ".join("N" if e is None else str(e) for e in expected) + "]"
                raise SubjectError(path, name, f"has shape {list(arr.shape)}, expected {shape}")
        if name == "body_pose" and arr.shape[0] not in (63, 69):
            raise SubjectError(path, name, f"has {arr.shape[0]} values, expected 69 (SMPL) or 63 (SMPL-X)")
        if not np.isfinite(arr).all():
            raise SubjectError(path, name, "holds NaN or infinite values")
        out[name] = arr
    extras = {k: v for k, v in raw.items() if k not in out}
    return GroundTruth(
        betas=out["betas"],
        body_pose=out["body_pose"],
        global_orient=out["global_orient"],
        transl=out["transl"],
        vertices=out["vertices"],
        joints=out["joints"],
        extras=extras,
    )


def load_subject(
    path: PathLike,
    require: Iterable[str] = ("keypoints", "camera"),
    load: Iterable[str] = ("keypoints", "camera", "mask", "image", "gt"),
) -> Subject:
    """Read one subject folder.

    Components in ``require`` must exist; the others in ``load`` are read when their file
    exists. Every file that is read is validated (and image sizes checked against
    ``camera.json``); errors name the file and the field.
    """
    folder = Path(path)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: subject folder not found")
    require, load = set(require), set(load) | set(require)
    unknown = (require | load) - set(SUBJECT_FILES)
    if unknown:
        raise ValueError(f"unknown subject component(s) {sorted(unknown)}; expected {sorted(SUBJECT_FILES)}")
    for comp in sorted(require):
        f = folder / SUBJECT_FILES[comp]
        if not f.is_file():
            raise FileNotFoundError(f"{f}: required file missing ({comp})")

    cam_file = folder / SUBJECT_FILES["camera"]
    if cam_file.is_file():
        camera = load_camera(cam_file)
    else:
        camera = None
    subject = Subject(name=folder.name, path=folder, camera=camera)
    size = None if camera is None else (camera.width, camera.height)

    if "keypoints" in load and (folder / SUBJECT_FILES["keypoints"]).is_file():
        subject.keypoints = read_keypoints(folder / SUBJECT_FILES["keypoints"], person=0)
    if "mask" in load and (folder / SUBJECT_FILES["mask"]).is_file():
        subject.mask = read_mask(folder / SUBJECT_FILES["mask"], size)
    if "image" in load and (folder / SUBJECT_FILES["image"]).is_file():
        subject.image = read_image(folder / SUBJECT_FILES["image"], size)
    if "gt" in load and (folder / SUBJECT_FILES["gt"]).is_file():
        subject.gt = read_gt(folder / SUBJECT_FILES["gt"])
    if camera is None:
        # No camera.json (allowed when not required): the default camera of the image size.
        ref = subject.mask if subject.mask is not None else (subject.image if subject.image is not None else None)
        if ref is None:
            raise FileNotFoundError(f"{cam_file}: camera file not found and no image or mask gives the image size")
        subject.camera = Camera.from_image_size(ref.shape[1], ref.shape[0])
    return subject


def read_index(dataset: PathLike) -> Optional[dict]:
    """The dataset's ``index.json``, or ``None`` when there is none."""
    f = Path(dataset) / INDEX_NAME
    if not f.is_file():
        return None
    try:
        data = json.loads(f.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise SubjectError(f, "<file>", f"not valid JSON ({err})") from None
    if not isinstance(data, dict) or not isinstance(data.get("subjects"), list):
        raise SubjectError(f, "subjects", "expected an object with a 'subjects' list")
    for i, s in enumerate(data["subjects"]):
        if not isinstance(s, dict) or not isinstance(s.get("name"), str):
            raise SubjectError(f, f"subjects[{i}].name", "each subject needs a 'name' string")
    return data


def list_subjects(dataset: PathLike) -> List[Path]:
    """Subject folders of a dataset: those named in ``index.json`` (in its order), else every
    sub-folder (sorted) holding a ``keypoints.json`` or ``camera.json``. A folder that is
    itself a subject is returned alone."""
    root = Path(dataset)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: dataset folder not found")
    index = read_index(root)
    if index is not None:
        return [root / s["name"] for s in index["subjects"]]
    if any((root / SUBJECT_FILES[c]).is_file() for c in ("keypoints", "camera")):
        return [root]
    subjects = sorted(
        p
        for p in root.iterdir()
        if p.is_dir() and any((p / SUBJECT_FILES[c]).is_file() for c in ("keypoints", "camera", "gt"))
    )
    return subjects
