"""Reading body-model files: official SMPL ``.pkl``/``.npz`` and the shipped open model.

The official SMPL pickles were written with chumpy (a Python 2 autodiff library)
inside; :class:`_LenientUnpickler` replaces every chumpy class by a stand-in that keeps
the pickled state, so the arrays can be read without chumpy installed. Sparse joint
regressors (scipy) are densified.
"""
from __future__ import annotations

import json
import os
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

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


class _ChumpyStandIn:
    """Replaces any chumpy class while unpickling; keeps the pickled state."""

    def __init__(self, *args, **kwargs):
        self._args = args

    def __setstate__(self, state):
        self.__dict__["_state"] = state

    def to_array(self) -> np.ndarray:
        state = self.__dict__.get("_state")
        if isinstance(state, dict):
            for key in ("x", "a", "r"):
                if key in state:
                    return np.asarray(state[key])
        raise ValueError("a chumpy object in the file holds no array ('x') this loader can read")


class _LenientUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if module.split(".")[0] == "chumpy":
            return _ChumpyStandIn
        if module.startswith("scipy.sparse"):
            import scipy.sparse

            try:
                return super().find_class(module, name)
            except (ImportError, AttributeError):
                return getattr(scipy.sparse, name)
        return super().find_class(module, name)


def _to_numpy(value: Any) -> Any:
    if isinstance(value, _ChumpyStandIn):
        return value.to_array()
    if hasattr(value, "toarray") and hasattr(value, "tocsr"):  # scipy sparse
        return np.asarray(value.toarray())
    return value


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
        raise ValueError(f"{path}: unsupported body model file type {path.suffix!r} (expected .pkl or .npz)")
    return path


def _read_raw(path: Path) -> dict:
    if path.suffix.lower() == ".npz":
        try:
            with np.load(path, allow_pickle=False) as data:
                return {k: data[k] for k in data.files}
        except ValueError:  # object arrays inside (some converted official files)
            with np.load(path, allow_pickle=True, encoding="latin1") as data:
                return {k: data[k] for k in data.files}
    with open(path, "rb") as fh:
        try:
            raw = _LenientUnpickler(fh, encoding="latin1").load()
        except Exception as err:  # noqa: BLE001 - any unpickling failure is a bad file
            raise ValueError(f"{path}: cannot read this pickle as an SMPL model ({type(err).__name__}: {err})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: expected a pickled dict of model arrays, got {type(raw).__name__}")
    return raw


def _array(raw: dict, key: str, path: Path, dtype) -> np.ndarray:
    try:
        value = _to_numpy(raw[key])
        if isinstance(value, np.ndarray) and value.dtype == object and value.shape == ():
            value = _to_numpy(value.item())
        return np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{path}: field '{key}' is not a numeric array ({err})") from None


def _check_shape(path: Path, key: str, arr: np.ndarray, expected: tuple) -> None:
    ok = arr.ndim == len(expected) and all(e is None or e == s for e, s in zip(expected, arr.shape))
    if not ok:
        shown = "x".join("?" if e is None else str(e) for e in expected)
        raise ValueError(f"{path}: field '{key}' has shape {tuple(arr.shape)}, expected {shown}")


def load_model_arrays(path: Union[str, os.PathLike, None] = None, gender: str = "neutral") -> ModelArrays:
    """Read and validate a body-model file (see :func:`resolve_model_path`)."""
    path = resolve_model_path(path, gender)
    raw = _read_raw(path)
    missing = [k for k in REQUIRED_KEYS if k not in raw]
    if missing:
        raise ValueError(
            f"{path}: not an SMPL-layout model file: field(s) missing: {', '.join(missing)} "
            f"(found: {', '.join(sorted(map(str, raw))) or 'nothing'})"
        )
    v_template = _array(raw, "v_template", path, np.float64)
    _check_shape(path, "v_template", v_template, (None, 3))
    V = v_template.shape[0]
    if V == 0:
        raise ValueError(f"{path}: field 'v_template' holds no vertices")
    faces = _array(raw, "f", path, np.int64)
    _check_shape(path, "f", faces, (None, 3))
    if faces.size and (faces.min() < 0 or faces.max() >= V):
        raise ValueError(f"{path}: field 'f' indexes vertices outside 0..{V - 1}")
    J_regressor = _array(raw, "J_regressor", path, np.float64)
    _check_shape(path, "J_regressor", J_regressor, (None, V))
    J = J_regressor.shape[0]
    kintree = _array(raw, "kintree_table", path, np.int64)
    _check_shape(path, "kintree_table", kintree, (2, J))
    parents = kintree[0].copy()
    parents[(parents < 0) | (parents >= J)] = -1  # official files store 2**32-1 for the root
    parents = tuple(int(p) for p in parents)
    if parents[0] != -1 or any(p >= j for j, p in enumerate(parents) if j > 0) or -1 in parents[1:]:
        raise ValueError(f"{path}: field 'kintree_table' is not a tree rooted at joint 0 with parents before children")
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

    meta = {}
    if "meta_json" in raw:
        try:
            meta = json.loads(str(raw["meta_json"]))
        except json.JSONDecodeError:
            meta = {}

    if "joint_names" in raw:
        joint_names = tuple(str(n) for n in np.asarray(raw["joint_names"]).tolist())
    elif J == len(SMPL_JOINT_NAMES):
        joint_names = SMPL_JOINT_NAMES
    else:
        joint_names = tuple(f"joint_{j}" for j in range(J))
    if len(joint_names) != J:
        raise ValueError(f"{path}: field 'joint_names' has {len(joint_names)} names for {J} joints")

    landmark_names: tuple = ()
    landmark_regressor = None
    if "landmark_regressor" in raw:
        landmark_regressor = _array(raw, "landmark_regressor", path, np.float64)
        landmark_names = tuple(str(n) for n in np.asarray(raw.get("landmark_names", [])).tolist())
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
