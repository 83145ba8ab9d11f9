"""A small capsule body in SMPL's layout (24 joints, landmarks for BODY_25) for fast
fitting tests that do not depend on the shipped model."""

import numpy as np

from silfit.body import SMPL_JOINT_NAMES, SMPL_PARENTS, BodyModel
from silfit.body.io import ModelArrays

_LEFT = {
    "pelvis": (0, 0, 0),
    "left_hip": (0.08, -0.09, 0),
    "spine1": (0, 0.11, 0),
    "left_knee": (0.1, -0.47, 0),
    "spine2": (0, 0.25, 0),
    "left_ankle": (0.09, -0.87, -0.02),
    "spine3": (0, 0.36, 0),
    "left_foot": (0.1, -0.93, 0.1),
    "neck": (0, 0.55, 0),
    "left_collar": (0.06, 0.46, 0),
    "head": (0, 0.64, 0.02),
    "left_shoulder": (0.18, 0.47, 0),
    "left_elbow": (0.45, 0.47, 0),
    "left_wrist": (0.7, 0.47, 0),
    "left_hand": (0.78, 0.47, 0),
}
_RADIUS = {
    "pelvis": 0.12,
    "spine1": 0.12,
    "spine2": 0.12,
    "spine3": 0.12,
    "neck": 0.05,
    "head": 0.09,
    "hip": 0.07,
    "knee": 0.05,
    "ankle": 0.04,
    "foot": 0.035,
    "collar": 0.04,
    "shoulder": 0.045,
    "elbow": 0.035,
    "wrist": 0.03,
    "hand": 0.03,
}
_MAIN_CHILD = {"pelvis": "spine1", "spine3": "neck"}
_LEAF_DIR = {"head": (0, 0.2, 0), "left_foot": (0, -0.02, 0.1), "left_hand": (0.08, 0, 0)}


def _joint(name):
    if name in _LEFT:
        return np.array(_LEFT[name], float)
    x, y, z = _LEFT[name.replace("right_", "left_")]
    return np.array((-x, y, z), float)


def toy_arrays(seed=0):
    rng = np.random.default_rng(seed)
    names = SMPL_JOINT_NAMES
    J = len(names)
    children = {j: [c for c, p in enumerate(SMPL_PARENTS) if p == j] for j in range(J)}
    verts, weights, faces, ring0 = [], [], [], {}
    n_around, n_rings = 8, 5
    for j, name in enumerate(names):
        a = _joint(name)
        if name in _MAIN_CHILD:
            b = _joint(_MAIN_CHILD[name])
        elif children[j]:
            b = _joint(names[children[j][0]])
        else:
            d = _LEAF_DIR.get(name) or _LEAF_DIR[name.replace("right_", "left_")]
            d = np.array(d, float)
            if name.startswith("right_"):
                d[0] = -d[0]
            b = a + d
        key = name.split("_")[-1]
        r = _RADIUS.get(name, _RADIUS.get(key, 0.04))
        axis = (b - a) / np.linalg.norm(b - a)
        helper = np.array([0, 0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0, 0])
        e1 = np.cross(axis, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        start = len(verts)
        ring0[j] = list(range(start, start + n_around))
        for k in range(n_rings):
            c = a + (b - a) * k / (n_rings - 1)
            for m in range(n_around):
                t = 2 * np.pi * m / n_around
                verts.append(c + r * (np.cos(t) * e1 + np.sin(t) * e2))
                w = np.zeros(J)
                w[j] = 1.0
                weights.append(w)
        for k in range(n_rings - 1):
            for m in range(n_around):
                i0 = start + k * n_around + m
                i1 = start + k * n_around + (m + 1) % n_around
                faces += [(i0, i1, i0 + n_around), (i1, i1 + n_around, i0 + n_around)]
    # Landmarks: extra vertices rigidly attached to the head / feet.
    head, lm_names, lm_pos, lm_part = _joint("head"), [], [], []
    for side, s in (("left", 1), ("right", -1)):
        lm_names += [f"{side}_eye", f"{side}_ear"]
        lm_pos += [head + (s * 0.035, 0.03, 0.085), head + (s * 0.08, 0.02, 0.0)]
        lm_part += [names.index("head")] * 2
        ankle, foot = _joint(f"{side}_ankle"), _joint(f"{side}_foot")
        lm_names += [f"{side}_big_toe", f"{side}_small_toe", f"{side}_heel"]
        lm_pos += [foot + (s * -0.01, -0.04, 0.08), foot + (s * 0.04, -0.04, 0.06), ankle + (0, -0.07, -0.06)]
        lm_part += [names.index(f"{side}_foot"), names.index(f"{side}_foot"), names.index(f"{side}_ankle")]
    lm_names.append("nose")
    lm_pos.append(head + (0, 0.0, 0.1))
    lm_part.append(names.index("head"))
    V0 = len(verts)
    for p, part in zip(lm_pos, lm_part):
        verts.append(p)
        w = np.zeros(J)
        w[part] = 1.0
        weights.append(w)
    verts = np.asarray(verts)
    V = len(verts)
    reg = np.zeros((J, V))
    for j in range(J):
        reg[j, ring0[j]] = 1.0 / n_around
    lm_reg = np.zeros((len(lm_names), V))
    lm_reg[np.arange(len(lm_names)), V0 + np.arange(len(lm_names))] = 1.0
    shapedirs = np.zeros((V, 3, 10))
    shapedirs[:, :, 0] = 0.06 * verts  # stature
    shapedirs[:, 0, 1] = 0.08 * verts[:, 0]  # width
    shapedirs[:, :, 2:] = rng.normal(0, 0.003, (V, 3, 8))
    return ModelArrays(
        v_template=verts,
        faces=np.asarray(faces, dtype=np.int64),
        shapedirs=shapedirs,
        posedirs=None,
        J_regressor=reg,
        weights=np.asarray(weights),
        parents=tuple(SMPL_PARENTS),
        joint_names=tuple(names),
        landmark_names=tuple(lm_names),
        landmark_regressor=lm_reg,
        source="<toy capsule body>",
    )


def toy_model(dtype=None):
    import torch

    return BodyModel(toy_arrays(), dtype=dtype or torch.float32)


def write_toy_npz(path):
    a = toy_arrays()
    parents = np.array(a.parents)
    np.savez(
        path,
        v_template=a.v_template,
        f=a.faces,
        shapedirs=a.shapedirs,
        J_regressor=a.J_regressor,
        weights=a.weights,
        kintree_table=np.stack([parents, np.arange(len(parents))]),
        joint_names=np.array(a.joint_names),
        landmark_regressor=a.landmark_regressor,
        landmark_names=np.array(a.landmark_names),
    )
    return path
