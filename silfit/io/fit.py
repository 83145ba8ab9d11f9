"""Fit files: the one reader (:func:`read_fit`) and the one writer (:func:`write_fit`) of
``params.npz`` / ``params.json``, for every mode (one image, a rig, a video, whole body).

Schema (``schema = "silfit-fit/2"``): one body over ``F`` frames seen by ``C`` views::

    params.npz    the model's parameters by their SMPL / SMPL-X names, each [F, w] (betas
                  [F, L], the shared shape repeated; a model with an expression space adds
                  expression, jaw_pose, leye_pose, reye_pose, left_hand_pose, right_hand_pose),
                  so ``smplx.SMPL(...)(**{k: torch.tensor(v)})`` takes them as they are;
                  model (kind: smpl | smplx), model_source, model_sha256 (of the model file),
                  layout (keypoint layout), coordinates ("camera": the first view's camera frame,
                  OpenCV axes; "world": the rig's frame), frames [F] (frame numbers),
                  camera_intrinsics [C, 4] (fx, fy, cx, cy), image_size [C, 2] (W, H),
                  camera_R [C, 3, 3], camera_t [C, 3] (world to camera, x_cam = R x + t),
                  vertices [F, V, 3], joints [F, J, 3], keypoints_2d [F, C, K, 2] (the fitted
                  keypoints projected into each view), reprojection_error [F, C] (median px);
                  with a hand PCA in the model file, left_hand_pca / right_hand_pca [F, k]: the
                  hand poses as the coefficients smplx takes with use_pca=True and
                  num_pca_comps=k (the 45-D poses are for use_pca=False)
    params.json   the same parameters as nested lists, ``cameras`` (one object per view:
                  fx, fy, cx, cy, width, height, R, t, name) and ``camera`` (the first view),
                  model, layout, coordinates, frames, and the run's record (energies,
                  timings, start_flipped (the flipped start won), faces_camera (the
                  final body faces the camera), branches, branch_search (the depth
                  hypotheses tried and their energies), reprojection_error_px, ...)

Older files (silfit-fit/1: one image's parameters without the frame axis, ``camera_intrinsics
[4]``; videos with ``betas [L]``) read the same way. One set of checks: a field the caller
needs (``require``) must be there; every field that is there must be numeric, of its shape
and finite; the camera must be complete and valid. Errors are
:class:`silfit.io.subjects.SubjectError` (an :class:`~silfit.errors.InputError`: one line naming
the file and the field) or ``FileNotFoundError``.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from ..body.io import load_model_arrays
from ..camera import Camera, camera_from_dict
from ..errors import InputError, quoted
from .keypoints import LAYOUTS
from .limits import read_json
from .safe_pickle import load_npz
from .subjects import SubjectError

__all__ = ["FIT_FILES", "PARAM_SIZES", "SCHEMA", "FitFile", "find_fit_file", "model_record", "read_fit", "write_fit"]

#: The schema :func:`write_fit` writes.
SCHEMA = "silfit-fit/2"
#: File names looked for in a fit folder, in order of preference.
FIT_FILES = ("params.npz", "params.json")
#: SMPL parameter name -> width (``None``: any number of shape coefficients).
PARAM_SIZES: Dict[str, Optional[int]] = {"betas": None, "body_pose": 69, "global_orient": 3, "transl": 3}
#: The parameters an SMPL-X-layout model adds, and their widths (expression: any count).
WHOLEBODY_SIZES: Dict[str, Optional[int]] = {
    "expression": None,
    "jaw_pose": 3,
    "leye_pose": 3,
    "reye_pose": 3,
    "left_hand_pose": 45,
    "right_hand_pose": 45,
}
#: Optional per-frame arrays: name -> (rank after the frame axis, trailing width).
ARRAY_FIELDS = {"vertices": (2, 3), "joints": (2, 3), "keypoints_2d": (3, 2), "reprojection_error": (1, None)}
COORDINATES = ("camera", "world")

PathLike = Union[str, os.PathLike]


@dataclass
class FitFile:
    """What a fit file holds.

    ``params``: name -> float64 ``[n, w]`` with ``n`` 1 (one value for every frame) or
    :attr:`num_frames` (only the fields present); ``cameras`` (one per view; empty when not
    stored) with ``extrinsics`` (``(R [3, 3], t [3])`` per view); ``views`` (their names);
    ``layout``, ``model`` (``{"kind", "source", "sha256"}``, ``None`` in older files),
    ``coordinates`` ("camera" or "world"), ``frame_numbers [F]``; ``arrays``: ``vertices [F,
    V, 3]``, ``joints [F, J, 3]``, ``keypoints_2d [F, C, K, 2]``, ``reprojection_error [F, C]``
    where present; from ``params.json`` also ``energies``, ``timings``, ``flipped``,
    ``reprojection_error`` (the median over frames and views, px)."""

    path: Path
    params: Dict[str, np.ndarray]
    cameras: List[Camera] = field(default_factory=list)
    extrinsics: List[Tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    views: List[str] = field(default_factory=list)
    layout: Optional[str] = None
    model: Optional[dict] = None
    coordinates: str = "camera"
    frame_numbers: Optional[np.ndarray] = None
    arrays: Dict[str, np.ndarray] = field(default_factory=dict)
    energies: Dict[str, float] = field(default_factory=dict)
    timings: Dict[str, float] = field(default_factory=dict)
    flipped: Optional[bool] = None
    reprojection_error: Optional[float] = None

    @property
    def camera(self) -> Optional[Camera]:
        """The (first) view's camera, ``None`` when the file stores none."""
        return self.cameras[0] if self.cameras else None

    @property
    def num_frames(self) -> int:
        return max(v.shape[0] for v in self.params.values())

    def frame(self, index: int = 0) -> Dict[str, np.ndarray]:
        """Frame ``index``'s parameters, name -> ``[w]`` (shared ones as stored once)."""
        F = self.num_frames
        if not -F <= index < F:
            raise SubjectError(self.path, "frames", f"frame {index} asked for; the fit has {F} frame(s) (0..{F - 1})")
        return {n: v[index if v.shape[0] > 1 else 0] for n, v in self.params.items()}


def find_fit_file(path: PathLike) -> Path:
    """``path`` itself if it is a file, else the first of :data:`FIT_FILES` in that folder."""
    p = Path(path)
    if p.is_dir():
        for name in FIT_FILES:
            if (p / name).is_file():
                return p / name
        raise FileNotFoundError(f"{p}: fit result not found (no {' or '.join(FIT_FILES)} in the folder)")
    if not p.is_file():
        raise FileNotFoundError(f"{p}: fit result not found")
    return p


def model_sizes(kind: Optional[str]) -> Dict[str, Optional[int]]:
    """Parameter name -> width to check for a model kind (``None``: SMPL's, or SMPL-X's where
    the file says so)."""
    if kind == "smplx":
        return {**PARAM_SIZES, "body_pose": 63, **WHOLEBODY_SIZES}
    return dict(PARAM_SIZES)


def read_fit(
    path: PathLike,
    require: Iterable[str] = tuple(PARAM_SIZES),
    require_camera: bool = False,
    sizes: Optional[Mapping[str, Optional[int]]] = None,
) -> FitFile:
    """Read and check a fit file (or the fit folder holding one, see :func:`find_fit_file`).

    ``require``: parameter names that must be present (``()``: any subset, but at least one
    of ``sizes``); ``require_camera``: the camera must be stored; ``sizes``: parameter name
    -> width to check (default: the widths of the model kind the file records; in files that
    record none, SMPL-X's where SMPL-X's parameters are present, else SMPL's).
    """
    f = find_fit_file(path)
    if f.suffix == ".npz":
        raw = _read_npz(f)
    elif f.suffix == ".json":
        raw = _read_json(f)
    else:
        raise SubjectError(f, "<file>", f"unsupported fit file; expected {' or '.join(FIT_FILES)}")
    model = _model(f, raw)
    if sizes is None:  # the recorded model's widths; files that record none: SMPL-X's where its parameters are there
        sizes = model_sizes(model["kind"] if model else "smplx" if any(n in raw for n in WHOLEBODY_SIZES) else None)
    sizes = dict(sizes)

    params = {}
    for name, width in sizes.items():
        if name in raw:
            params[name] = _rows(f, name, raw[name], width)
    missing = [n for n in require if n not in params]
    if missing:
        raise SubjectError(f, missing[0], f"missing (the fit needs {', '.join(require)})")
    if not params:
        raise SubjectError(f, "<file>", f"none of the parameter fields {', '.join(sizes)} found")
    counts = sorted({v.shape[0] for v in params.values()} - {1})
    if len(counts) > 1:
        name = next(n for n, v in params.items() if v.shape[0] == counts[0])
        raise SubjectError(f, name, f"has {counts[0]} frames where other parameters have {counts[-1]}")
    F = counts[0] if counts else 1
    cameras, extrinsics, views = (_npz_cameras if f.suffix == ".npz" else _json_cameras)(f, raw)
    if require_camera and not cameras:
        need = "camera_intrinsics and image_size" if f.suffix == ".npz" else "camera"
        raise SubjectError(f, need.split(" ")[0], f"missing (the camera the fit used: {need})")

    out = FitFile(path=f, params=params, cameras=cameras, extrinsics=extrinsics, views=views, model=model)
    if "layout" in raw:
        layout = _text(raw["layout"])
        if layout not in LAYOUTS:
            raise SubjectError(f, "layout", f"unknown keypoint layout {quoted(layout)} (expected {', '.join(LAYOUTS)})")
        out.layout = layout
    for key in ("coordinates", "frame"):  # "frame": silfit-fit/1's name (rig fits)
        if key in raw:
            value = _text(raw[key])
            if value not in COORDINATES:
                raise SubjectError(f, key, f"expected one of {', '.join(COORDINATES)}, got {quoted(value)}")
            out.coordinates = value
            break
    if "frames" in raw:
        numbers = _numeric(f, "frames", raw["frames"]).reshape(-1)
        if numbers.shape[0] != F or (numbers != np.round(numbers)).any():
            raise SubjectError(f, "frames", f"expected {F} integer frame numbers, got {numbers.shape[0]} values")
        out.frame_numbers = numbers.astype(np.int64)
    C = max(1, len(cameras))
    for name, (rank, last) in ARRAY_FIELDS.items():
        if name in raw:
            out.arrays[name] = _frame_array(f, name, raw[name], rank, last, F, C)
    if f.suffix == ".json":
        out.energies = _scalars(f, "energies", raw.get("energies", {}))
        out.timings = _scalars(f, "timings", raw.get("timings", {}))
        key = "start_flipped" if "start_flipped" in raw else "flipped"  # silfit-fit/1 called it "flipped"
        if key in raw:
            if not isinstance(raw[key], bool):
                raise SubjectError(f, key, f"must be true or false, got {quoted(raw[key])}")
            out.flipped = raw[key]
        if "reprojection_error_px" in raw:
            out.reprojection_error = _scalars(f, "reprojection_error_px", {"v": raw["reprojection_error_px"]})["v"]
    return out


def model_record(model) -> dict:
    """``{"kind", "source", "sha256"}`` of a body model (the hash of its file's bytes, so a fit
    names the exact model it belongs to; ``""`` when the model was not read from a file)."""
    source = os.fspath(getattr(model, "source", "") or "")
    return {"kind": getattr(model, "kind", "smpl"), "source": source, "sha256": _file_sha256(source)}


def _file_sha256(source: str) -> str:
    if not source or not os.path.isfile(source):
        return ""
    stat = os.stat(source)
    key = (source, stat.st_size, stat.st_mtime_ns)
    if key not in _HASHES:
        digest = hashlib.sha256()
        with open(source, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
        _HASHES[key] = digest.hexdigest()
    return _HASHES[key]


_HASHES: Dict[tuple, str] = {}


@functools.lru_cache(maxsize=4)
def _hand_pca(source: str, sha256: str) -> Optional[Dict[str, np.ndarray]]:
    """The model file's hand PCA, side -> components ``[k, 45]`` (``None`` without one or without
    the file); ``sha256`` keys the cache to the file's content."""
    if not sha256:
        return None
    extras = load_model_arrays(source).extras
    if "hands_componentsl" not in extras:
        return None
    return {
        side: np.asarray(extras[f"hands_components{c}"], dtype=np.float64)
        for side, c in (("left", "l"), ("right", "r"))
    }


def _frame_rows(params: Mapping[str, np.ndarray]) -> Tuple[Dict[str, np.ndarray], int]:
    """``params`` as float32 ``[F, w]`` rows (one frame's repeated over the frames) and ``F``."""
    rows = {n: np.atleast_2d(np.asarray(v, dtype=np.float32)) for n, v in params.items()}
    F = max(v.shape[0] for v in rows.values())
    if any(v.shape[0] not in (1, F) for v in rows.values()):
        raise ValueError(f"parameters have frame counts {sorted({v.shape[0] for v in rows.values()})}")
    rows = {n: np.repeat(v, F, axis=0) if v.shape[0] == 1 else v for n, v in rows.items()}
    return rows, F


def _camera_poses(extrinsics, C: int) -> Tuple[np.ndarray, np.ndarray]:
    """``(R [C, 3, 3], t [C, 3])`` of the views' extrinsics (identity where omitted)."""
    ext = [(np.eye(3), np.zeros(3)) if e is None else e for e in (extrinsics or [None] * C)]
    R = np.stack([np.asarray(e[0], np.float64).reshape(3, 3) for e in ext])
    t = np.stack([np.asarray(e[1], np.float64).reshape(3) for e in ext])
    return R, t


def _npz_meta(rec: dict, rows: dict, layout: str, coordinates: str, numbers, names, cameras, R, t) -> dict:
    """``params.npz``'s fields beside the parameters: model, layout, frames, cameras (and the hand PCA)."""
    meta = {
        "schema": np.array(SCHEMA),
        "model": np.array(rec["kind"]),
        "model_source": np.array(rec["source"]),
        "model_sha256": np.array(rec["sha256"]),
        "layout": np.array(layout),
        "coordinates": np.array(coordinates),
        "frames": numbers,
        "views": np.array(names),
        "camera_intrinsics": np.array([[c.fx, c.fy, c.cx, c.cy] for c in cameras], np.float64),
        "image_size": np.array([[c.width, c.height] for c in cameras], np.int64),
        "camera_R": R,
        "camera_t": t,
    }
    pca = _hand_pca(rec["source"], rec["sha256"]) if "left_hand_pose" in rows else None
    if pca:  # the hand poses also as the coefficients smplx's use_pca=True takes
        for side, comps in pca.items():
            coeffs = np.linalg.lstsq(comps.T, rows[f"{side}_hand_pose"].astype(np.float64).T, rcond=None)[0].T
            meta[f"{side}_hand_pca"] = coeffs.astype(np.float32)  # [F, k]: coeffs @ components = the pose
    return meta


def _per_frame_arrays(vertices, joints, keypoints_2d, reprojection_error) -> Dict[str, np.ndarray]:
    """The optional per-frame arrays given, float32 with their frame (and view) axes."""
    per_frame = {}
    for name, value, rank in (
        ("vertices", vertices, 2),
        ("joints", joints, 2),
        ("keypoints_2d", keypoints_2d, 3),
        ("reprojection_error", reprojection_error, 1),
    ):
        if value is None:
            continue
        a = np.asarray(value, dtype=np.float32)
        if name == "keypoints_2d" and a.ndim == 2:  # one view's [K, 2]
            a = a[None]
        if name == "reprojection_error" and a.ndim == 0:
            a = a.reshape(1)
        per_frame[name] = a[None] if a.ndim == rank else a
    return per_frame


def _json_payload(
    rows: dict, rec: dict, layout: str, coordinates: str, numbers, cameras, R, t, names, per_frame: dict, record
) -> dict:
    """``params.json``'s content."""
    cams = [{**c.to_dict(), "R": R[i].tolist(), "t": t[i].tolist(), "name": names[i]} for i, c in enumerate(cameras)]
    payload = {
        "schema": SCHEMA,
        **{n: v.astype(float).tolist() for n, v in rows.items()},
        "model": rec,
        "layout": layout,
        "coordinates": coordinates,
        "frames": numbers.tolist(),
        "cameras": cams,
    }
    if cameras:
        payload["camera"] = cameras[0].to_dict()
    if "reprojection_error" in per_frame and "reprojection_error_px" not in (record or {}):
        finite = per_frame["reprojection_error"][np.isfinite(per_frame["reprojection_error"])]
        if finite.size:
            payload["reprojection_error_px"] = float(np.median(finite))
    payload.update(record or {})
    return payload


def write_fit(
    folder: PathLike,
    params: Mapping[str, np.ndarray],
    cameras: Sequence[Camera],
    *,
    layout: str,
    model=None,
    coordinates: str = "camera",
    extrinsics: Optional[Sequence[Tuple[np.ndarray, np.ndarray]]] = None,
    views: Optional[Sequence[str]] = None,
    frame_numbers: Optional[Sequence[int]] = None,
    vertices: Optional[np.ndarray] = None,
    joints: Optional[np.ndarray] = None,
    keypoints_2d: Optional[np.ndarray] = None,
    reprojection_error: Optional[np.ndarray] = None,
    record: Optional[dict] = None,
) -> Path:
    """Write ``params.npz`` and ``params.json`` (the module docstring's schema) into ``folder``.

    ``params``: name -> ``[F, w]`` or ``[w]`` (one frame; shared parameters given once are
    repeated over the frames); ``cameras`` one per view, with ``extrinsics`` (identity when
    omitted); ``model``: a body model or its :func:`model_record`; the optional per-frame arrays
    as in the schema (a single frame's may omit the frame axis, a single view's the view axis);
    ``record``: more JSON fields for ``params.json`` (energies, timings, config, ...)."""
    if coordinates not in COORDINATES:
        raise ValueError(f"coordinates must be one of {COORDINATES}, got {coordinates!r}")
    rows, F = _frame_rows(params)
    C = len(cameras)
    R, t = _camera_poses(extrinsics, C)
    names = list(views) if views is not None else [f"view_{c}" if C > 1 else "camera" for c in range(C)]
    rec = model if isinstance(model, dict) or model is None else model_record(model)
    rec = rec or {"kind": "smplx" if "left_hand_pose" in rows else "smpl", "source": "", "sha256": ""}
    numbers = np.arange(F) if frame_numbers is None else np.asarray(frame_numbers, dtype=np.int64)
    meta = _npz_meta(rec, rows, layout, coordinates, numbers, names, cameras, R, t)
    per_frame = _per_frame_arrays(vertices, joints, keypoints_2d, reprojection_error)
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    np.savez(out / "params.npz", **rows, **meta, **per_frame)
    payload = _json_payload(rows, rec, layout, coordinates, numbers, cameras, R, t, names, per_frame, record)
    (out / "params.json").write_text(json.dumps(payload, indent=2, default=float))
    return out


# ----------------------------------------------------------------------------- helpers
def _as_subject_error(f: Path, err) -> SubjectError:
    """A shared reader's :class:`~silfit.errors.InputError` as this reader's error type."""
    msg = str(err).partition(": ")[2]
    if err.field and msg.startswith(f"field '{err.field}'"):
        msg = msg[len(f"field '{err.field}'") :].lstrip(": ").strip()
    return SubjectError(f, err.field or "<file>", msg)


def _read_npz(f: Path) -> dict:
    """Through :func:`silfit.io.safe_pickle.load_npz`: size limits, no pickled objects."""
    try:
        return load_npz(f, what="fit parameters")
    except SubjectError:
        raise
    except InputError as err:
        raise _as_subject_error(f, err) from None
    except (zipfile.BadZipFile, EOFError, KeyError) as err:
        raise SubjectError(f, "<file>", f"not a readable .npz archive ({err})") from None


def _read_json(f: Path) -> dict:
    """Through :func:`silfit.io.limits.read_json`: size and nesting limits."""
    try:
        raw = read_json(f, "fit parameters")
    except InputError as err:
        if isinstance(err, SubjectError):
            raise
        raise _as_subject_error(f, err) from None
    if not isinstance(raw, dict):
        raise SubjectError(f, "<file>", f"expected a JSON object with {', '.join(PARAM_SIZES)}")
    return raw


def _numeric(f: Path, name: str, value) -> np.ndarray:
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        raise SubjectError(f, name, "is not a numeric array") from None
    if arr.dtype.kind not in "fiu" or arr.dtype == bool:
        raise SubjectError(f, name, f"must be numeric, got {arr.dtype if arr.dtype != object else 'mixed values'}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise SubjectError(f, name, "holds NaN or infinite values")
    return arr


def _text(value) -> str:
    return str(value.item() if isinstance(value, np.ndarray) else value)


def _rows(f: Path, name: str, value, width: Optional[int]) -> np.ndarray:
    """A parameter as ``[n, w]``: ``[w]`` is one frame."""
    arr = _numeric(f, name, value)
    if arr.ndim == 1:
        arr = arr[None]
    if arr.ndim != 2 or (width is not None and arr.shape[1] != width) or arr.size == 0:
        want = f"[{width or 'L'}] or [frames, {width or 'L'}]"
        shape = list(arr.shape[1:]) if arr.ndim == 2 and arr.shape[0] == 1 else list(arr.shape)
        raise SubjectError(f, name, f"has shape {shape}, expected {want}")
    return arr


def _frame_array(f: Path, name: str, value, rank: int, last: Optional[int], F: int, C: int) -> np.ndarray:
    """A per-frame array with its frame axis (and, for keypoints_2d, view axis) restored."""
    arr = _numeric(f, name, value) if name != "reprojection_error" else _numeric_nan(f, name, value)
    if name == "keypoints_2d" and arr.ndim == 2:  # silfit-fit/1: one image's [K, 2]
        arr = arr[None, None]
    elif name == "keypoints_2d" and arr.ndim == 3 and C == 1 and F > 1:  # silfit-fit/1 videos: [F, K, 2]
        arr = arr[:, None]
    elif name == "keypoints_2d" and arr.ndim == 3:  # silfit-fit/1 rigs (view axis first) or a [1, K, 2] image
        arr = arr[None]
    elif arr.ndim == rank:
        arr = arr[None] if F == 1 or name != "reprojection_error" else arr[:, None]
    if arr.ndim != rank + 1 or arr.shape[0] != F or (last is not None and arr.shape[-1] != last):
        raise SubjectError(
            f,
            name,
            f"has shape {list(arr.shape)}, expected [{F}{', ...' if rank > 1 else ''}"
            f"{', ' + str(last) if last else ', views'}] ({F} frame(s))",
        )
    return arr


def _numeric_nan(f: Path, name: str, value) -> np.ndarray:
    """Numeric, NaN allowed (a frame or view without keypoints has no error), no infinities."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiu" or arr.dtype == bool:
        raise SubjectError(f, name, "must be numeric")
    arr = arr.astype(np.float64)
    if np.isinf(arr).any():
        raise SubjectError(f, name, "holds infinite values")
    return arr


def _model(f: Path, raw: dict) -> Optional[dict]:
    if "model" not in raw:
        return None
    m = raw["model"]
    if isinstance(m, dict):  # params.json
        rec = {k: str(m.get(k, "")) for k in ("kind", "source", "sha256")}
    else:
        rec = {
            "kind": _text(m),
            "source": _text(raw.get("model_source", "")),
            "sha256": _text(raw.get("model_sha256", "")),
        }
    if rec["kind"] not in ("smpl", "smplx"):
        raise SubjectError(f, "model", f"unknown model kind {quoted(rec['kind'])} (expected smpl or smplx)")
    return rec


def _npz_cameras(f: Path, raw: dict):
    have = [k for k in ("camera_intrinsics", "image_size") if k in raw]
    if not have:
        return [], [], []
    if len(have) == 1:
        other = "image_size" if have[0] == "camera_intrinsics" else "camera_intrinsics"
        raise SubjectError(
            f, other, f"missing (the camera needs both camera_intrinsics and image_size; found {have[0]})"
        )
    intr = _numeric(f, "camera_intrinsics", raw["camera_intrinsics"])
    size = _numeric(f, "image_size", raw["image_size"])
    intr, size = (
        intr.reshape(-1, intr.shape[-1]) if intr.ndim else intr,
        size.reshape(-1, size.shape[-1]) if size.ndim else size,
    )
    if intr.ndim != 2 or intr.shape[1] != 4:
        raise SubjectError(f, "camera_intrinsics", f"has {intr.size} values, expected [fx, fy, cx, cy] per view")
    if size.ndim != 2 or size.shape[1] != 2:
        raise SubjectError(f, "image_size", f"has {size.size} values, expected [width, height] per view")
    C = intr.shape[0]
    if size.shape[0] != C:
        raise SubjectError(f, "image_size", f"has {size.shape[0]} views, camera_intrinsics {C}")
    cameras = []
    for i in range(C):
        try:
            cameras.append(Camera.from_intrinsics(intr[i], size[i]))
        except ValueError as err:
            raise SubjectError(f, "camera_intrinsics", str(err)) from None
    R = (
        _numeric(f, "camera_R", raw["camera_R"]).reshape(-1, 3, 3)
        if "camera_R" in raw
        else np.tile(np.eye(3), (C, 1, 1))
    )
    t = _numeric(f, "camera_t", raw["camera_t"]).reshape(-1, 3) if "camera_t" in raw else np.zeros((C, 3))
    if len(R) != C or len(t) != C:
        raise SubjectError(f, "camera_R" if len(R) != C else "camera_t", f"expected one per view ({C})")
    views = [str(v) for v in np.asarray(raw["views"]).reshape(-1)] if "views" in raw else []
    return cameras, list(zip(R, t)), views[:C] if len(views) >= C else []


def _json_cameras(f: Path, raw: dict):
    docs = raw.get("cameras") if isinstance(raw.get("cameras"), list) and raw.get("cameras") else None
    if docs is None:
        if "camera" not in raw:
            return [], [], []
        docs = [raw["camera"]]
    cameras, extrinsics, views = [], [], []
    for i, doc in enumerate(docs[:64]):
        name = "camera" if docs is not raw.get("cameras") else f"cameras[{i}]"
        try:
            cameras.append(
                camera_from_dict(
                    {k: v for k, v in doc.items() if k in ("fx", "fy", "cx", "cy", "width", "height")}
                    if isinstance(doc, dict)
                    else doc,
                    name,
                )
            )
        except InputError as err:
            raise SubjectError(f, name, str(err).partition(": ")[2]) from None
        R = _numeric(f, f"{name}.R", doc.get("R", np.eye(3).tolist())).reshape(-1)
        t = _numeric(f, f"{name}.t", doc.get("t", [0.0, 0.0, 0.0])).reshape(-1)
        if R.size != 9 or t.size != 3:
            raise SubjectError(f, f"{name}.R" if R.size != 9 else f"{name}.t", "expected a 3x3 R and a 3-vector t")
        extrinsics.append((R.reshape(3, 3), t))
        views.append(str(doc.get("name", "")))
    return cameras, extrinsics, views if all(views) else []


def _scalars(f: Path, name: str, value) -> Dict[str, float]:
    if not isinstance(value, dict):
        raise SubjectError(f, name, "expected an object of numbers")
    out = {}
    for k, v in value.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):  # NaN is allowed: a stage may not have run
            raise SubjectError(
                f, f"{name}.{k}" if name != "reprojection_error_px" else name, f"must be a number, got {quoted(v)}"
            )
        out[str(k)] = float(v)
    return out
