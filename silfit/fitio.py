"""The one reader of fit outputs (``params.npz`` / ``params.json``), used by everything
that reads a fit: :meth:`silfit.fitting.KeypointFitResult.load`, ``silfit eval``
(:func:`silfit.eval.evaluate.read_fit`), ``silfit render`` and ``silfit fit-dataset``.

Files (as :meth:`KeypointFitResult.save` and ``silfit fit`` write them)::

    params.npz    betas [L], body_pose [69], global_orient [3], transl [3] (SMPL names; a
                  leading batch dimension of 1 is accepted), camera_intrinsics [fx, fy, cx, cy],
                  image_size [W, H], layout (string), vertices [V, 3], joints [J, 3],
                  keypoints_2d [K, 2]
    params.json   the same parameters as lists, camera {fx, fy, cx, cy, width, height},
                  layout, energies {stage: value}, timings {stage: seconds}, flipped,
                  reprojection_error_px

One set of checks: a field the caller needs (``require``) must be there; every field that is
there must be numeric, of its shape and finite; the camera must be complete and valid.
Errors are :class:`silfit.dataset.SubjectError` (a ``ValueError``: one line naming the file
and the field) or ``FileNotFoundError``.
"""
from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterable, Mapping, Optional, Union

import numpy as np

from .camera import Camera
from .errors import quoted
from .dataset import SubjectError

__all__ = ["FIT_FILES", "PARAM_SIZES", "FitFile", "read_fit", "find_fit_file"]

#: File names looked for in a fit folder, in order of preference.
FIT_FILES = ("params.npz", "params.json")
#: SMPL parameter name -> width (``None``: any number of shape coefficients).
PARAM_SIZES: Dict[str, Optional[int]] = {"betas": None, "body_pose": 69, "global_orient": 3, "transl": 3}
#: Optional per-sample arrays and their trailing shape.
ARRAY_FIELDS = {"vertices": 3, "joints": 3, "keypoints_2d": 2}

PathLike = Union[str, os.PathLike]


@dataclass
class FitFile:
    """What a fit file holds: ``params`` (name -> float64 ``[n]``, only the fields present),
    the ``camera`` (``None`` when not stored), ``layout`` (``None`` when not stored),
    ``arrays`` (``vertices``/``joints``/``keypoints_2d`` present in the file), and from
    ``params.json`` also ``energies``, ``timings``, ``flipped``, ``reprojection_error``."""

    path: Path
    params: Dict[str, np.ndarray]
    camera: Optional[Camera] = None
    layout: Optional[str] = None
    arrays: Dict[str, np.ndarray] = field(default_factory=dict)
    energies: Dict[str, float] = field(default_factory=dict)
    timings: Dict[str, float] = field(default_factory=dict)
    flipped: Optional[bool] = None
    reprojection_error: Optional[float] = None


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


def read_fit(
    path: PathLike,
    require: Iterable[str] = tuple(PARAM_SIZES),
    require_camera: bool = False,
    sizes: Optional[Mapping[str, Optional[int]]] = None,
) -> FitFile:
    """Read and check a fit file (or the fit folder holding one, see :func:`find_fit_file`).

    ``require``: parameter names that must be present (``()``: any subset, but at least one
    of ``sizes``); ``require_camera``: the camera must be stored; ``sizes``: parameter name
    -> width to check (default :data:`PARAM_SIZES`, e.g. ``model.parameter_sizes`` for
    another model kind).
    """
    f = find_fit_file(path)
    sizes = dict(PARAM_SIZES if sizes is None else sizes)
    if f.suffix == ".npz":
        raw = _read_npz(f)
        camera = _npz_camera(f, raw)
    elif f.suffix == ".json":
        raw = _read_json(f)
        camera = _json_camera(f, raw)
    else:
        raise SubjectError(f, "<file>", f"unsupported fit file; expected {' or '.join(FIT_FILES)}")

    params = {}
    for name, width in sizes.items():
        if name in raw:
            params[name] = _vector(f, name, raw[name], width)
    missing = [n for n in require if n not in params]
    if missing:
        raise SubjectError(f, missing[0], f"missing (the fit needs {', '.join(require)})")
    if not params:
        raise SubjectError(f, "<file>", f"none of the parameter fields {', '.join(sizes)} found")
    if require_camera and camera is None:
        need = "camera_intrinsics and image_size" if f.suffix == ".npz" else "camera"
        raise SubjectError(f, need.split(" ")[0], f"missing (the camera the fit used: {need})")

    out = FitFile(path=f, params=params, camera=camera)
    if "layout" in raw:
        layout = raw["layout"]
        layout = str(layout.item() if isinstance(layout, np.ndarray) else layout)
        from .keypoints import LAYOUTS

        if layout not in LAYOUTS:
            raise SubjectError(f, "layout", f"unknown keypoint layout {quoted(layout)} (expected {', '.join(LAYOUTS)})")
        out.layout = layout
    for name, last in ARRAY_FIELDS.items():
        if name in raw:
            arr = _numeric(f, name, raw[name])
            if arr.ndim == 3 and arr.shape[0] == 1:
                arr = arr[0]
            if arr.ndim != 2 or arr.shape[1] != last:
                raise SubjectError(f, name, f"has shape {list(arr.shape)}, expected [N, {last}]")
            out.arrays[name] = arr
    if f.suffix == ".json":
        out.energies = _scalars(f, "energies", raw.get("energies", {}))
        out.timings = _scalars(f, "timings", raw.get("timings", {}))
        if "flipped" in raw:
            if not isinstance(raw["flipped"], bool):
                raise SubjectError(f, "flipped", f"must be true or false, got {quoted(raw['flipped'])}")
            out.flipped = raw["flipped"]
        if "reprojection_error_px" in raw:
            out.reprojection_error = _scalars(f, "reprojection_error_px", {"v": raw["reprojection_error_px"]})["v"]
    return out


# ----------------------------------------------------------------------------- helpers
def _as_subject_error(f: Path, err) -> SubjectError:
    """A shared reader's :class:`~silfit.errors.InputError` as this reader's error type."""
    msg = str(err).partition(": ")[2]
    if err.field and msg.startswith(f"field '{err.field}'"):
        msg = msg[len(f"field '{err.field}'"):].lstrip(": ").strip()
    return SubjectError(f, err.field or "<file>", msg)



def _read_npz(f: Path) -> dict:
    """Through :func:`silfit.safe_pickle.load_npz`: size limits, no pickled objects."""
    from .errors import InputError
    from .safe_pickle import load_npz

    try:
        return load_npz(f, what="fit parameters")
    except SubjectError:
        raise
    except InputError as err:
        raise _as_subject_error(f, err) from None
    except (zipfile.BadZipFile, EOFError, KeyError) as err:
        raise SubjectError(f, "<file>", f"not a readable .npz archive ({err})") from None


def _read_json(f: Path) -> dict:
    """Through :func:`silfit.input_limits.read_json`: size and nesting limits."""
    from .errors import InputError
    from .input_limits import read_json

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


def _vector(f: Path, name: str, value, width: Optional[int]) -> np.ndarray:
    arr = _numeric(f, name, value)
    if arr.ndim == 2 and arr.shape[0] == 1:
        arr = arr[0]
    if arr.ndim != 1 or (width is not None and arr.shape[0] != width) or arr.shape[0] == 0:
        raise SubjectError(f, name, f"has shape {list(arr.shape)}, expected [{width or 'L'}]")
    return arr


def _npz_camera(f: Path, raw: dict) -> Optional[Camera]:
    have = [k for k in ("camera_intrinsics", "image_size") if k in raw]
    if not have:
        return None
    if len(have) == 1:
        other = "image_size" if have[0] == "camera_intrinsics" else "camera_intrinsics"
        raise SubjectError(f, other, f"missing (the camera needs both camera_intrinsics and image_size; found {have[0]})")
    intr = _numeric(f, "camera_intrinsics", raw["camera_intrinsics"]).reshape(-1)
    size = _numeric(f, "image_size", raw["image_size"]).reshape(-1)
    if intr.shape != (4,):
        raise SubjectError(f, "camera_intrinsics", f"has {intr.size} values, expected [fx, fy, cx, cy]")
    if size.shape != (2,):
        raise SubjectError(f, "image_size", f"has {size.size} values, expected [width, height]")
    try:
        return Camera.from_intrinsics(intr, size)
    except ValueError as err:
        raise SubjectError(f, "camera_intrinsics", str(err)) from None


def _json_camera(f: Path, raw: dict) -> Optional[Camera]:
    if "camera" not in raw:
        return None
    from .camera import camera_from_dict
    from .errors import InputError

    try:
        return camera_from_dict(raw["camera"], "camera")
    except InputError as err:
        raise SubjectError(f, "camera", str(err).partition(": ")[2]) from None


def _scalars(f: Path, name: str, value) -> Dict[str, float]:
    if not isinstance(value, dict):
        raise SubjectError(f, name, "expected an object of numbers")
    out = {}
    for k, v in value.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):  # NaN is allowed: a stage may not have run
            raise SubjectError(f, f"{name}.{k}" if name != "reprojection_error_px" else name, f"must be a number, got {quoted(v)}")
        out[str(k)] = float(v)
    return out
