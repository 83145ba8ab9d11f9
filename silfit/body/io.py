"""Reading body-model files: official SMPL ``.pkl``/``.npz`` and the shipped open model.

The official SMPL pickles were written with chumpy (a Python 2 autodiff library)
inside. They are read with :mod:`silfit.io.safe_pickle`'s restricted unpickler, which
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
from typing import Optional, Union

import numpy as np

from ..errors import InputError
from ..io.safe_pickle import load_npz, load_pickle, to_numpy

__all__ = [
    "ModelArrays",
    "OPEN_BODY_PATH",
    "REQUIRED_KEYS",
    "load_model_arrays",
    "resolve_model_path",
    "SMPL_JOINT_NAMES",
    "SMPL_PARENTS",
    "OPEN_SMPLX_PATH",
    "SMPLX_JOINT_NAMES",
    "SMPLX_PARENTS",
    "is_smplx_layout",
    "read_smplx_extras",
    "find_smplx_file",
]

#: The shipped open body model (package data).
OPEN_BODY_PATH = Path(__file__).resolve().parent / "data" / "open_body.npz"

#: The shipped open whole-body model in SMPL-X's layout (package data).
OPEN_SMPLX_PATH = Path(__file__).resolve().parent / "data" / "open_smplx.npz"

REQUIRED_KEYS = ("v_template", "f", "shapedirs", "J_regressor", "weights", "kintree_table")

SMPL_JOINT_NAMES = (
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hand",
    "right_hand",
)
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)

#: Extra keypoints on the official SMPL mesh (6890 vertices), as vertex ids.
SMPL_LANDMARK_VERTICES = {
    "nose": 332,
    "right_eye": 6260,
    "left_eye": 2800,
    "right_ear": 4071,
    "left_ear": 583,
    "left_big_toe": 3216,
    "left_small_toe": 3226,
    "left_heel": 3387,
    "right_big_toe": 6617,
    "right_small_toe": 6624,
    "right_heel": 6787,
}

_FILE_NAMES = {
    "neutral": (
        "SMPL_NEUTRAL.pkl",
        "SMPL_NEUTRAL.npz",
        "basicmodel_neutral_lbs_10_207_0_v1.1.0.pkl",
        "basicModel_neutral_lbs_10_207_0_v1.0.0.pkl",
        "SMPLX_NEUTRAL.npz",
        "SMPLX_NEUTRAL.pkl",
    ),
    "male": (
        "SMPL_MALE.pkl",
        "SMPL_MALE.npz",
        "basicmodel_m_lbs_10_207_0_v1.1.0.pkl",
        "basicModel_m_lbs_10_207_0_v1.0.0.pkl",
        "SMPLX_MALE.npz",
        "SMPLX_MALE.pkl",
    ),
    "female": (
        "SMPL_FEMALE.pkl",
        "SMPL_FEMALE.npz",
        "basicmodel_f_lbs_10_207_0_v1.1.0.pkl",
        "basicModel_f_lbs_10_207_0_v1.0.0.pkl",
        "SMPLX_FEMALE.npz",
        "SMPLX_FEMALE.pkl",
    ),
}


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
    kind: str = "smpl"  # "smplx" for SMPL-X's layout (55 joints); then ``extras`` holds its extra arrays
    extras: dict = field(default_factory=dict)

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
            for candidate in (path / name, path / "smpl" / name, path / "smplx" / name):
                if candidate.is_file():
                    return candidate
        raise FileNotFoundError(
            f"{path}: no {gender} SMPL model file in this folder (looked for {', '.join(_FILE_NAMES[gender])}, "
            "also under smpl/ and smplx/). Download SMPL from its website and pass the .pkl/.npz file or its folder."
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


def _meta(raw) -> dict:
    """The file's ``meta_json`` as a dict (empty where absent or unreadable)."""
    if "meta_json" not in raw:
        return {}
    try:
        meta = json.loads(str(raw["meta_json"]))
    except (json.JSONDecodeError, RecursionError):
        return {}
    return meta if isinstance(meta, dict) else {}


def _joint_names(raw, path, parents: tuple) -> tuple:
    """The file's ``joint_names``, else SMPL's or SMPL-X's by the joint count and tree, else ``joint_<j>``."""
    J = len(parents)
    if "joint_names" in raw:
        joint_names = tuple(str(n) for n in np.atleast_1d(to_numpy(raw["joint_names"])).tolist())
    elif J == len(SMPL_JOINT_NAMES):
        joint_names = SMPL_JOINT_NAMES
    elif parents == SMPLX_PARENTS:
        joint_names = SMPLX_JOINT_NAMES
    else:
        joint_names = tuple(f"joint_{j}" for j in range(J))
    if len(joint_names) != J:
        raise InputError(path, f"field 'joint_names' has {len(joint_names)} names for {J} joints")
    return joint_names


def _landmarks(raw, path, V: int) -> tuple:
    """``(names, regressor [N, V])`` of the extra keypoints: the file's ``landmark_regressor``, else on the official
    SMPL topology the field's vertex ids, else none."""
    if "landmark_regressor" in raw:
        landmark_regressor = _array(raw, "landmark_regressor", path, np.float64)
        landmark_names = tuple(str(n) for n in np.atleast_1d(to_numpy(raw.get("landmark_names", []))).tolist())
        _check_shape(path, "landmark_regressor", landmark_regressor, (len(landmark_names), V))
        return landmark_names, landmark_regressor
    if V == 6890:  # official SMPL topology: the vertex ids of the field's extra keypoints
        landmark_names = tuple(SMPL_LANDMARK_VERTICES)
        landmark_regressor = np.zeros((len(landmark_names), V))
        landmark_regressor[np.arange(len(landmark_names)), list(SMPL_LANDMARK_VERTICES.values())] = 1.0
        return landmark_names, landmark_regressor
    return (), None


def load_model_arrays(path: Union[str, os.PathLike, None] = None, gender: str = "neutral") -> ModelArrays:
    """Read and validate a body-model file (see :func:`resolve_model_path`)."""
    path = resolve_model_path(path, gender)
    raw = _read_raw(path)
    missing = [k for k in REQUIRED_KEYS if k not in raw]
    if missing:
        raise InputError(
            path,
            f"not an SMPL-layout model file: field(s) missing: {', '.join(missing)} "
            f"(found: {', '.join(sorted(map(str, raw))) or 'nothing'})",
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

    for key, arr in (
        ("v_template", v_template),
        ("J_regressor", J_regressor),
        ("weights", weights),
        ("shapedirs", shapedirs),
        ("posedirs", posedirs),
    ):
        if arr is not None and not np.isfinite(arr).all():
            raise InputError(path, f"field '{key}' holds NaN or infinite values", field=key)

    meta = _meta(raw)
    joint_names = _joint_names(raw, path, parents)
    landmark_names, landmark_regressor = _landmarks(raw, path, V)
    arrays = ModelArrays(
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
    if is_smplx_layout(parents, meta):
        read_smplx_extras(raw, path, arrays)
    return arrays


# ---------------------------------------------------------------------------------------------- SMPL-X
SMPLX_JOINT_NAMES = SMPL_JOINT_NAMES[:22] + (
    "jaw",
    "left_eye_smplhf",
    "right_eye_smplhf",
    *(f"left_{f}{k}" for f in ("index", "middle", "pinky", "ring", "thumb") for k in (1, 2, 3)),
    *(f"right_{f}{k}" for f in ("index", "middle", "pinky", "ring", "thumb") for k in (1, 2, 3)),
)
SMPLX_PARENTS = (
    SMPL_PARENTS[:22]
    + (15, 15, 15)
    + tuple(
        p
        for wrist in (20, 21)
        for base in range(25 + 15 * (wrist - 20), 40 + 15 * (wrist - 20), 3)
        for p in (wrist, base, base + 1)
    )
)

#: SMPL-X's shape space: ``shapedirs`` holds 300 shape then 100 expression directions (v1.1);
#: the v1.0 files hold 10 + 10.
SMPLX_SHAPE_SPACE_DIM = 300

#: Extra keypoints on the official SMPL-X mesh (10475 vertices), as vertex ids (as the ``smplx``
#: package's ``vertex_ids['smplx']``).
SMPLX_LANDMARK_VERTICES = {
    "nose": 9120,
    "right_eye": 9929,
    "left_eye": 9448,
    "right_ear": 616,
    "left_ear": 6,
    "left_big_toe": 5770,
    "left_small_toe": 5780,
    "left_heel": 8846,
    "right_big_toe": 8463,
    "right_small_toe": 8474,
    "right_heel": 8635,
    "left_thumb_tip": 5361,
    "left_index_tip": 4933,
    "left_middle_tip": 5058,
    "left_ring_tip": 5169,
    "left_pinky_tip": 5286,
    "right_thumb_tip": 8079,
    "right_index_tip": 7669,
    "right_middle_tip": 7794,
    "right_ring_tip": 7905,
    "right_pinky_tip": 8022,
}


def is_smplx_layout(parents: tuple, meta: Optional[dict] = None) -> bool:
    """Whether a model file is in SMPL-X's layout: SMPL-X's 55-joint tree, or declared so in its meta.
    (Other trees load as generic SMPL-like models.)"""
    return tuple(parents) == SMPLX_PARENTS or (meta or {}).get("kind") == "smplx"


def _shape_expression_split(raw: dict, path: Path, total: int, meta: dict) -> int:
    """How many of ``shapedirs``' columns are shape (the rest are expression)."""
    if "shape_space_dim" in meta:
        n = int(meta["shape_space_dim"])
    elif total > SMPLX_SHAPE_SPACE_DIM:
        n = SMPLX_SHAPE_SPACE_DIM
    else:  # SMPL-X v1.0 layout: 10 shape + 10 expression
        n = min(10, total)
    if not 0 < n <= total:
        raise ValueError(f"{path}: field 'shapedirs' has {total} columns, fewer than its {n} shape directions")
    return n


def read_smplx_extras(raw: dict, path: Path, arrays: ModelArrays) -> ModelArrays:
    """Fill ``arrays.extras`` (and set ``kind``) from SMPL-X's extra fields, validated:

    ``shapedirs`` split into shape and ``exprdirs [V, 3, M]`` (expression) parts; hand PCA
    ``hands_componentsl/r [C, 45]`` and ``hands_meanl/r [45]`` where present; the face landmark
    embedding ``lmk_faces_idx [K]`` / ``lmk_bary_coords [K, 3]`` (static, as vertex-weight rows appended
    to the landmark regressor as ``face_17`` ... ``face_67``) and the dynamic contour
    ``dynamic_lmk_faces_idx [79, 17]`` / ``dynamic_lmk_bary_coords [79, 17, 3]``."""
    V, J = arrays.num_vertices, arrays.num_joints
    if J != len(SMPLX_JOINT_NAMES):
        raise ValueError(f"{path}: an SMPL-X model needs {len(SMPLX_JOINT_NAMES)} joints, field 'J_regressor' has {J}")
    if tuple(arrays.parents) != SMPLX_PARENTS:
        raise ValueError(f"{path}: field 'kintree_table' is not SMPL-X's kinematic tree")
    extras: dict = {}
    total = arrays.shapedirs.shape[-1]
    n = _shape_expression_split(raw, path, total, arrays.meta)
    extras["exprdirs"] = arrays.shapedirs[:, :, n:]
    arrays.shapedirs = arrays.shapedirs[:, :, :n]
    for side in ("l", "r"):
        comp_key, mean_key = f"hands_components{side}", f"hands_mean{side}"
        if comp_key in raw:
            comps = _array(raw, comp_key, path, np.float64)
            _check_shape(path, comp_key, comps, (None, 45))
            extras[comp_key] = comps
        if mean_key in raw:
            mean = _array(raw, mean_key, path, np.float64).reshape(-1)
            _check_shape(path, mean_key, mean, (45,))
            extras[mean_key] = mean
    if ("hands_componentsl" in extras) != ("hands_componentsr" in extras):
        raise ValueError(f"{path}: fields 'hands_componentsl' and 'hands_componentsr' must come together")
    faces = arrays.faces
    if "lmk_faces_idx" in raw:
        if "lmk_bary_coords" not in raw:
            raise ValueError(f"{path}: field 'lmk_bary_coords' is missing (needed with 'lmk_faces_idx')")
        idx = _array(raw, "lmk_faces_idx", path, np.int64).reshape(-1)
        bary = _array(raw, "lmk_bary_coords", path, np.float64)
        _check_shape(path, "lmk_bary_coords", bary, (idx.size, 3))
        if idx.size and (idx.min() < 0 or idx.max() >= len(faces)):
            raise ValueError(f"{path}: field 'lmk_faces_idx' indexes triangles outside 0..{len(faces) - 1}")
        rows = np.zeros((idx.size, V))
        np.add.at(rows, (np.repeat(np.arange(idx.size), 3), faces[idx].reshape(-1)), bary.reshape(-1))
        first = 68 - idx.size  # 51 static landmarks are the 68-point layout's points 17..67
        names = tuple(f"face_{first + k:02d}" for k in range(idx.size))
        _append_landmarks(arrays, names, rows)
    if "dynamic_lmk_faces_idx" in raw:
        didx = _array(raw, "dynamic_lmk_faces_idx", path, np.int64)
        _check_shape(path, "dynamic_lmk_faces_idx", didx, (None, None))
        if "dynamic_lmk_bary_coords" not in raw:
            raise ValueError(
                f"{path}: field 'dynamic_lmk_bary_coords' is missing (needed with 'dynamic_lmk_faces_idx')"
            )
        dbary = _array(raw, "dynamic_lmk_bary_coords", path, np.float64)
        _check_shape(path, "dynamic_lmk_bary_coords", dbary, didx.shape + (3,))
        if didx.size and (didx.min() < 0 or didx.max() >= len(faces)):
            raise ValueError(f"{path}: field 'dynamic_lmk_faces_idx' indexes triangles outside 0..{len(faces) - 1}")
        extras["dynamic_lmk_faces_idx"], extras["dynamic_lmk_bary_coords"] = didx, dbary
    if V == 10475 and not set(SMPLX_LANDMARK_VERTICES) & set(arrays.landmark_names):
        rows = np.zeros((len(SMPLX_LANDMARK_VERTICES), V))
        rows[np.arange(len(rows)), list(SMPLX_LANDMARK_VERTICES.values())] = 1.0
        _append_landmarks(arrays, tuple(SMPLX_LANDMARK_VERTICES), rows)
    arrays.kind, arrays.extras = "smplx", extras
    return arrays


def find_smplx_file(folder: Path, gender: str = "neutral") -> Path:
    """The SMPL-X file of ``gender`` in a folder (``SMPLX_<GENDER>.npz`` or ``.pkl``, also under smplx/)."""
    folder = Path(folder).expanduser()
    names = [f"SMPLX_{gender.upper()}.npz", f"SMPLX_{gender.upper()}.pkl"]
    for name in names:
        for candidate in (folder / name, folder / "smplx" / name):
            if candidate.is_file():
                return candidate
    raise FileNotFoundError(
        f"{folder}: no {gender} SMPL-X model file in this folder (looked for {', '.join(names)}, also under smplx/)"
    )


def _append_landmarks(arrays: ModelArrays, names: tuple, rows: np.ndarray) -> None:
    if arrays.landmark_regressor is None:
        arrays.landmark_names, arrays.landmark_regressor = tuple(names), rows
    else:
        arrays.landmark_names = tuple(arrays.landmark_names) + tuple(names)
        arrays.landmark_regressor = np.concatenate([arrays.landmark_regressor, rows])
