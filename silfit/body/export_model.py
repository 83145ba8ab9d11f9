"""Writing the shipped open models in the files the ``smplx`` package reads (``silfit export-model``).

``smplx.create(DIR, model_type="smpl")`` reads ``DIR/smpl/SMPL_NEUTRAL.pkl`` (a pickled dict of numpy
arrays: ``v_template, f, shapedirs, posedirs, J_regressor, weights, kintree_table``);
``smplx.create(DIR, model_type="smplx")`` reads ``DIR/smplx/SMPLX_NEUTRAL.npz`` (its default
``ext``), which adds the hand PCA (``hands_componentsl/r``, ``hands_meanl/r``) and the face landmark
embedding (``lmk_faces_idx``, ``lmk_bary_coords``; ``dynamic_lmk_faces_idx``,
``dynamic_lmk_bary_coords`` for ``use_face_contour=True``). Only plain numpy arrays are written (no
chumpy, no other classes). Nothing in the open models is changed; the layout is adapted:

- **shape and expression spaces**: ``smplx`` finds the expression directions at columns 300..399 of
  ``shapedirs`` when it has 400 or more (else it assumes 10 + 10). The SMPL-X file's ``shapedirs``
  is therefore the model's 10 shape directions, zero columns up to 300, its 16 expression directions
  and zero columns up to 400: ``num_betas=10`` and ``num_expression_coeffs`` up to 16 use the whole
  model (``smplx``'s default of 10 uses the first 10 expression directions).
- **face contour**: the open model's 17 jaw-line points are fixed vertices; every one of the 79 rows
  of the dynamic tables holds them (the contour does not depend on the head's yaw).
- **extra joints** (``vertex_ids``): ``smplx`` appends vertices at SMPL/SMPL-X vertex numbers for the
  nose, eyes, ears, toes, heels and fingertips; on the open topology those numbers land elsewhere.
  ``vertex_ids.json`` beside each model file holds the open mesh's vertices nearest silfit's own
  landmarks (at rest, mean shape), in ``smplx``'s key names; see :func:`open_vertex_ids` and the
  README for passing them.

The landmarks are single vertices and single triangles, so ``smplx``'s forward pass gives the
open model's vertices and joints (see tests/body/test_export_model.py: within 0.01 mm).
"""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path
from typing import Dict, List, Union

import numpy as np

from .io import OPEN_BODY_PATH, OPEN_SMPLX_PATH, ModelArrays, load_model_arrays

__all__ = [
    "EXPORT_KINDS",
    "SMPLX_SHAPE_COLUMNS",
    "SMPLX_EXPRESSION_COLUMNS",
    "export_model",
    "open_vertex_ids",
    "read_vertex_ids",
]

EXPORT_KINDS = ("smpl", "smplx")
#: ``smplx`` reads expression directions from column 300 on when ``shapedirs`` has 300 + 100 columns.
SMPLX_SHAPE_COLUMNS, SMPLX_EXPRESSION_COLUMNS = 300, 100

#: ``smplx``'s extra-joint key -> silfit landmark name (order as ``smplx``'s ``VertexJointSelector``).
_VERTEX_ID_LANDMARKS = {
    "nose": "nose",
    "reye": "right_eye",
    "leye": "left_eye",
    "rear": "right_ear",
    "lear": "left_ear",
    "LBigToe": "left_big_toe",
    "LSmallToe": "left_small_toe",
    "LHeel": "left_heel",
    "RBigToe": "right_big_toe",
    "RSmallToe": "right_small_toe",
    "RHeel": "right_heel",
    "lthumb": "left_thumb_tip",
    "lindex": "left_index_tip",
    "lmiddle": "left_middle_tip",
    "lring": "left_ring_tip",
    "lpinky": "left_pinky_tip",
    "rthumb": "right_thumb_tip",
    "rindex": "right_index_tip",
    "rmiddle": "right_middle_tip",
    "rring": "right_ring_tip",
    "rpinky": "right_pinky_tip",
}


def _model_arrays(kind: str) -> ModelArrays:
    if kind not in EXPORT_KINDS:
        raise ValueError(f"model kind must be one of {', '.join(EXPORT_KINDS)}, got {kind!r}")
    return load_model_arrays(OPEN_SMPLX_PATH if kind == "smplx" else OPEN_BODY_PATH)


def _landmark_points(arrays: ModelArrays) -> Dict[str, np.ndarray]:
    """silfit's landmarks at rest (mean shape, zero pose): name -> ``[3]``."""
    points = arrays.landmark_regressor @ arrays.v_template
    return dict(zip(arrays.landmark_names, points))


def open_vertex_ids(kind: str = "smplx") -> Dict[str, int]:
    """``smplx``'s ``vertex_ids`` for the open topology: per extra joint, the vertex nearest silfit's
    landmark of the same name at rest (mean shape, zero pose). The two open models share one mesh;
    the fingertips (single vertices) come from the whole-body model, which names them."""
    return _vertex_ids(kind)[0]


def _vertex_ids(kind: str) -> tuple:
    """``(ids, distances)``: :func:`open_vertex_ids` and, per key, the metres from the vertex to the landmark."""
    body, whole = _model_arrays("smpl"), _model_arrays("smplx")
    points = {**_landmark_points(whole), **_landmark_points(body)}  # the body model's own where it has one
    template = (body if kind == "smpl" else whole).v_template
    ids, distances = {}, {}
    for key, name in _VERTEX_ID_LANDMARKS.items():
        d = np.linalg.norm(template - points[name], axis=1)
        ids[key] = int(np.argmin(d))
        distances[key] = float(d[ids[key]])
    return ids, distances


def _common(arrays: ModelArrays) -> dict:
    kintree = np.stack([np.asarray(arrays.parents, dtype=np.int64), np.arange(arrays.num_joints, dtype=np.int64)])
    posedirs = arrays.posedirs
    if posedirs is None:
        posedirs = np.zeros((arrays.num_vertices, 3, (arrays.num_joints - 1) * 9))
    return {
        "v_template": arrays.v_template.astype(np.float32),
        "f": arrays.faces.astype(np.int64),
        "J_regressor": arrays.J_regressor.astype(np.float32),
        "weights": arrays.weights.astype(np.float32),
        "kintree_table": kintree,
        "posedirs": posedirs.astype(np.float32),
    }


def _vertex_face(faces: np.ndarray, vertex: int) -> tuple:
    """A triangle holding ``vertex`` and the barycentric coordinates that select it."""
    rows, cols = np.nonzero(faces == vertex)
    if not len(rows):
        raise ValueError(f"vertex {vertex} is in no triangle")
    bary = np.zeros(3)
    bary[cols[0]] = 1.0
    return int(rows[0]), bary


def _face_landmark_arrays(arrays: ModelArrays) -> dict:
    """The 68-point face layout as ``smplx``'s landmark embedding: the 51 static points (17..67) and
    the 17-point contour (0..16), the same in each of the 79 yaw rows of the dynamic tables."""
    index = {n: i for i, n in enumerate(arrays.landmark_names)}

    def embed(names):
        idx, bary = [], []
        for name in names:
            row = arrays.landmark_regressor[index[name]]
            nz = np.flatnonzero(row)
            if len(nz) != 1 or not np.isclose(row[nz[0]], 1.0):
                raise ValueError(f"{arrays.source}: landmark {name} is not a single vertex")
            f, b = _vertex_face(arrays.faces, int(nz[0]))
            idx.append(f)
            bary.append(b)
        return np.asarray(idx, dtype=np.int64), np.asarray(bary, dtype=np.float32)

    lmk_idx, lmk_bary = embed([f"face_{k:02d}" for k in range(17, 68)])
    dyn_idx, dyn_bary = embed([f"face_{k:02d}" for k in range(17)])
    return {
        "lmk_faces_idx": lmk_idx,
        "lmk_bary_coords": lmk_bary,
        "dynamic_lmk_faces_idx": np.repeat(dyn_idx[None], 79, axis=0),
        "dynamic_lmk_bary_coords": np.repeat(dyn_bary[None], 79, axis=0),
    }


def smpl_file_arrays() -> dict:
    """The open body model as ``SMPL_NEUTRAL.pkl``'s dict."""
    arrays = _model_arrays("smpl")
    return {**_common(arrays), "shapedirs": arrays.shapedirs.astype(np.float32)}


def smplx_file_arrays() -> dict:
    """The open whole-body model as ``SMPLX_NEUTRAL.npz``'s arrays (see the module docstring)."""
    arrays = _model_arrays("smplx")
    V = arrays.num_vertices
    shape, expr = arrays.shapedirs, arrays.extras["exprdirs"]
    if shape.shape[-1] > SMPLX_SHAPE_COLUMNS or expr.shape[-1] > SMPLX_EXPRESSION_COLUMNS:
        raise ValueError(f"{arrays.source}: more shape/expression directions than smplx's 300 + 100")
    shapedirs = np.zeros((V, 3, SMPLX_SHAPE_COLUMNS + SMPLX_EXPRESSION_COLUMNS), dtype=np.float32)
    shapedirs[..., : shape.shape[-1]] = shape
    shapedirs[..., SMPLX_SHAPE_COLUMNS : SMPLX_SHAPE_COLUMNS + expr.shape[-1]] = expr
    out = {**_common(arrays), "shapedirs": shapedirs, **_face_landmark_arrays(arrays)}
    for side in ("l", "r"):
        comps = arrays.extras.get(f"hands_components{side}")
        mean = arrays.extras.get(f"hands_mean{side}")
        if comps is None:
            raise ValueError(f"{arrays.source}: no hand PCA (smplx needs hands_components{side})")
        out[f"hands_components{side}"] = comps.astype(np.float32)
        out[f"hands_mean{side}"] = (np.zeros(45) if mean is None else mean).astype(np.float32)
    return out


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def export_model(kind: str, folder: Union[str, os.PathLike]) -> List[Path]:
    """Write the shipped open ``kind`` model (``"smpl"`` or ``"smplx"``) into ``folder/<kind>/`` as the
    ``smplx`` package reads it, with ``vertex_ids.json`` and the model's licence; returns the files."""
    arrays = _model_arrays(kind)
    target = Path(folder).expanduser() / kind
    target.mkdir(parents=True, exist_ok=True)
    if kind == "smpl":
        model_file = target / "SMPL_NEUTRAL.pkl"
        data = smpl_file_arrays()
        _atomic_write(model_file, lambda fh: pickle.dump(data, fh, protocol=4))
    else:
        model_file = target / "SMPLX_NEUTRAL.npz"
        data = smplx_file_arrays()
        _atomic_write(model_file, lambda fh: np.savez_compressed(fh, **data))
    ids, distances = _vertex_ids(kind)
    ids_file = target / "vertex_ids.json"
    info = {
        "vertex_ids": ids,
        "distance_to_silfit_landmark_mm": {k: round(v * 1000, 2) for k, v in distances.items()},
        "how": "smplx.create(DIR, model_type='smpl', vertex_ids=VERTEX_IDS); for SMPL-X replace the selector after "
        "creating: model.vertex_joint_selector = smplx.vertex_joint_selector.VertexJointSelector(vertex_ids=VERTEX_IDS)",
        "model": Path(arrays.source).name,
    }
    _atomic_write(ids_file, lambda fh: fh.write((json.dumps(info, indent=2) + "\n").encode()))
    licence = Path(arrays.source).with_name("LICENSE-open-smplx.txt" if kind == "smplx" else "LICENSE-open-body.txt")
    files = [model_file, ids_file]
    if licence.is_file():
        (target / "LICENSE.txt").write_bytes(licence.read_bytes())
        files.append(target / "LICENSE.txt")
    return files


def read_vertex_ids(folder: Union[str, os.PathLike], kind: str) -> Dict[str, int]:
    """The ``vertex_ids`` dict :func:`export_model` wrote into ``folder/<kind>/vertex_ids.json``."""
    info = json.loads((Path(folder) / kind / "vertex_ids.json").read_text())
    return {k: int(v) for k, v in info["vertex_ids"].items()}
