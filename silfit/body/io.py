"""Reading body-model files: official SMPL ``.pkl``/``.npz`` and the shipped open model.

The official SMPL pickles were written with chumpy (a Python 2 autodiff library)
inside. They are read with :mod:`silfit.safe_pickle`'s restricted unpickler, which
allows only numpy arrays, scipy sparse matrices and chumpy classes (replaced by
stand-ins that keep the pickled state, so the arrays can be read without chumpy
installed) and refuses any other class before it runs. Sparse joint regressors are
densified. ``.npz`` files with object arrays go through the same unpickler.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from ..errors import InputError
from ..safe_pickle import load_npz, load_pickle, to_numpy

__all__ = [
    "ModelArrays",
    "OPEN_BODY_PATH",
    "REQUIRED_KEYS",
    "load_model_arrays",
    "resolve_model_path",
    "SMPL_JOINT_NAMES",
    "SMPL_PARENTS",
]

#: The shipped open body model (package data).
OPEN_BODY_PATH = Path(__file__).resolve().parent / "data" / "open_body.npz"

REQUIRED_KEYS = ("v_template", "f", "shapedirs", "J_regressor", "weights", "kintree_table")

SMPL_JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand",
)  # fmt: skip
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)

#: Extra keypoints on the official SMPL mesh (6890 vertices), as vertex ids.
SMPL_LANDMARK_VERTICES = {
    "nose": 332, "right_eye": 6260, "left_eye": 2800, "right_ear": 4071, "left_ear": 583,
    "left_big_toe": 3216, "left_small_toe": 3226, "left_heel": 3387,
    "right_big_toe": 6617, "right_small_toe": 6624, "right_heel": 6787,
}  # fmt: skip

_FILE_NAMES = {
    "neutral": ("SMPL_NEUTRAL.pkl", "SMPL_NEUTRAL.npz", "basicmodel_neutral_lbs_10_207_0_v1.1.0.pkl",
                "basicModel_neutral_lbs_10_207_0_v1.0.0.pkl"),
    "male": ("SMPL_MALE.pkl", "SMPL_MALE.npz", "basicmodel_m_lbs_10_207_0_v1.1.0.pkl",
             "basicModel_m_lbs_10_207_0_v1.0.0.pkl"),
    "female": ("SMPL_FEMALE.pkl", "SMPL_FEMALE.npz", "basicmodel_f_lbs_10_207_0_v1.1.0.pkl",
               "basicModel_f_lbs_10_207_0_v1.0.0.pkl"),
}  # fmt: skip


@dataclass
class ModelArrays:
    """The arrays of a body model in SMPL's layout, as numpy, validated."""

    v_template: np.ndarray  # [V, 3]
    faces: np.ndarray  # [F, 3] int64
    shapedirs: np.ndarray  # [V, 3, L]
    posedirs: Optional[np.ndarray]  # [V, 3, (J-1)*9] or None (no pose correctives)
    J_regressor: np.ndarray  # [J, V]
    weights: np.ndarray  # [V, J]
    parents: tuple  # [J], -1 for the root
    joint_names: tuple
    landmark_names: tuple = ()
    landmark_regressor: Optional[np.ndarray] = None  # [K, V]
    source: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def num_vertices(self) -> int:
        return self.v_template.shape[0]

    @property
    def num_joints(self) -> int:
        return self.J_regressor.shape[0]


def resolve_model_path(path: Union[str, os.PathLike, None], gender: str = "neutral") -> Path:
    """The model file to load: ``None`` gives the shipped open model, a directory is
    searched for the official SMPL file names of ``gender``."""
    if path is None:
        if not OPEN_BODY_PATH.is_file():
            raise FileNotFoundError(
                f"{OPEN_BODY_PATH}: the shipped open body model is missing from the installation "
                "(reinstall silfit, or regenerate it with tools/export_open_body.py)"
            )
        return OPEN_BODY_PATH
    path = Path(path).expanduser()
    gender = gender.lower()
    if gender not in _FILE_NAMES:
        raise ValueError(f"gender must be one of {', '.join(_FILE_NAMES)}, got {gender!r}")
    if path.is_dir():
        for name in _FILE_NAMES[gender]:
            for candidate in (path / name, path / "smpl" / name):
                if candidate.is_file():
                    return candidate
        raise FileNotFoundError(
            f"{path}: no {gender} SMPL model file in this folder (looked for {', '.join(_FILE_NAMES[gender])}, "
            "also under smpl/). Download SMPL from its website and pass the .pkl/.npz file or its folder."
        )
    if not path.exists():
        raise FileNotFoundError(f"{path}: body model file not found")
    if path.suffix.lower() not in (".pkl", ".npz"):
        raise InputError(path, f"unsupported body model file type {path.suffix!r} (expected .pkl or .npz)")
    return path


def _read_raw(path: Path) -> dict:
    if path.suffix.lower() == ".npz":
        return load_npz(path, what="an SMPL model", allow_objects=True)
    raw = load_pickle(path, what="an SMPL model")
    if not isinstance(raw, dict):
        raise InputError(path, f"expected a pickled dict of model arrays, got {type(raw).__name__}")
    return raw


def _array(raw: dict, key: str, path: Path, dtype) -> np.ndarray:
    try:
        return np.asarray(to_numpy(raw[key]), dtype=dtype)
    except (TypeError, ValueError, OverflowError, RecursionError) as err:
        raise InputError(path, f"field '{key}' is not a numeric array ({err})", field=key) from None


def _check_shape(path: Path, key: str, arr: np.ndarray, expected: tuple) -> None:
    ok = arr.ndim == len(expected) and all(e is None or e == s for e, s in zip(expected, arr.shape))
    if not ok:
        shown = "x".join("?" if e is None else str(e) for e in expected)
        raise InputError(path, f"field '{key}' has shape {tuple(arr.shape)}, expected {shown}")


def load_model_arrays(path: Union[str, os.PathLike, None] = None, gender: str = "neutral") -> ModelArrays:
    """Read and validate a body-model file (see :func:`resolve_model_path`)."""
    path = resolve_model_path(path, gender)
    raw = _read_raw(path)
    missing = [k for k in REQUIRED_KEYS if k not in raw]
    if missing:
        raise InputError(
            path, f"not an SMPL-layout model file: field(s) missing: {', '.join(missing)} "
            f"(found: {', '.join(sorted(map(str, raw))) or 'nothing'})"
        )
    v_template = _array(raw, "v_template", path, np.float64)
    _check_shape(path, "v_template", v_template, (None, 3))
    V = v_template.shape[0]
    if V == 0:
        raise InputError(path, "field 'v_template' holds no vertices")
    faces = _array(raw, "f", path, np.int64)
    _check_shape(path, "f", faces, (None, 3))
    if faces.size and (faces.min() < 0 or faces.max() >= V):
        raise InputError(path, f"field 'f' indexes vertices outside 0..{V - 1}")
    J_regressor = _array(raw, "J_regressor", path, np.float64)
    _check_shape(path, "J_regressor", J_regressor, (None, V))
    J = J_regressor.shape[0]
    if J == 0:
        raise InputError(path, "field 'J_regressor' has no joints", field="J_regressor")
    kintree = _array(raw, "kintree_table", path, np.int64)
    _check_shape(path, "kintree_table", kintree, (2, J))
    parents = kintree[0].copy()
    parents[(parents < 0) | (parents >= J)] = -1  # official files store 2**32-1 for the root
    parents = tuple(int(p) for p in parents)
    if parents[0] != -1 or any(p >= j for j, p in enumerate(parents) if j > 0) or -1 in parents[1:]:
        raise InputError(path, "field 'kintree_table' is not a tree rooted at joint 0 with parents before children")
    weights = _array(raw, "weights", path, np.float64)
    _check_shape(path, "weights", weights, (V, J))
    shapedirs = _array(raw, "shapedirs", path, np.float64)
    _check_shape(path, "shapedirs", shapedirs, (V, 3, None))

    posedirs = None
    if "posedirs" in raw:
        posedirs = _array(raw, "posedirs", path, np.float64)
        _check_shape(path, "posedirs", posedirs, (V, 3, (J - 1) * 9))
        if not np.any(posedirs):
            posedirs = None  # all zero: skip the pose-corrective product entirely

    for key, arr in (("v_template", v_template), ("J_regressor", J_regressor), ("weights", weights),
                     ("shapedirs", shapedirs), ("posedirs", posedirs)):  # fmt: skip
        if arr is not None and not np.isfinite(arr).all():
            raise InputError(path, f"field '{key}' holds NaN or infinite values", field=key)

    meta = {}
    if "meta_json" in raw:
        try:
            meta = json.loads(str(raw["meta_json"]))
        except (json.JSONDecodeError, RecursionError):
            meta = {}
        meta = meta if isinstance(meta, dict) else {}

    if "joint_names" in raw:
        joint_names = tuple(str(n) for n in np.atleast_1d(to_numpy(raw["joint_names"])).tolist())
    elif J == len(SMPL_JOINT_NAMES):
        joint_names = SMPL_JOINT_NAMES
    else:
        joint_names = tuple(f"joint_{j}" for j in range(J))
    if len(joint_names) != J:
        raise InputError(path, f"field 'joint_names' has {len(joint_names)} names for {J} joints")

    landmark_names: tuple = ()
    landmark_regressor = None
    if "landmark_regressor" in raw:
        landmark_regressor = _array(raw, "landmark_regressor", path, np.float64)
        landmark_names = tuple(str(n) for n in np.atleast_1d(to_numpy(raw.get("landmark_names", []))).tolist())
        _check_shape(path, "landmark_regressor", landmark_regressor, (len(landmark_names), V))
    elif V == 6890:  # official SMPL topology: the vertex ids of the field's extra keypoints
        landmark_names = tuple(SMPL_LANDMARK_VERTICES)
        landmark_regressor = np.zeros((len(landmark_names), V))
        landmark_regressor[np.arange(len(landmark_names)), list(SMPL_LANDMARK_VERTICES.values())] = 1.0

    return ModelArrays(
        v_template=v_template,
        faces=faces,
        shapedirs=shapedirs,
        posedirs=posedirs,
        J_regressor=J_regressor,
        weights=weights,
        parents=parents,
        joint_names=joint_names,
        landmark_names=landmark_names,
        landmark_regressor=landmark_regressor,
        source=str(path),
        meta=meta,
    )
