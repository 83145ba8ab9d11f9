"""Limb-branch hypotheses: the depth ambiguity of a limb segment, as alternative poses.

Seen by one camera, a limb segment from joint ``p`` to joint ``d`` and its mirror image
through the plane that contains ``p`` and is perpendicular to the viewing ray project to
(nearly: exactly under weak perspective) the same 2D segment, one pointing toward the
camera and one away. Keypoints cannot tell them apart; a fit started on the wrong side
stays there. :func:`flip_segment` builds the mirrored branch as a pose: the proximal
joint's rotation is composed with the smallest rotation taking ``d - p`` to its mirror
image, so the segment and everything below it turn rigidly; at a hinge (elbow, knee) the
upper segment twists about its own axis and the hinge flexes instead, as the joint can
(:data:`HINGE_BEND`). :func:`limb_hypotheses`
proposes, per sample, the flips of the segments that point far enough out of the image
plane to matter (``min_depth_ratio``), singly and per whole limb.

Pure functions of joint positions and rotations (no gradients): the keypoint stage runs
a short L-BFGS from each hypothesis and keeps the lowest energy per sample.
"""

from __future__ import annotations

from typing import Dict, List, Sequence, Tuple

import numpy as np
import torch
from scipy.spatial.transform import Rotation

__all__ = [
    "HINGE_BEND",
    "HINGE_MIN_BEND_DEG",
    "JOINT_HYPOTHESES",
    "LIMB_SEGMENTS",
    "LIMBS",
    "TORSO_SEGMENT",
    "align_segments",
    "flip_hip",
    "joint_hypotheses",
    "flip_segment",
    "limb_hypotheses",
    "mirror_rotation",
    "rotation_between",
    "turn_hypotheses",
    "turn_root",
]

#: (segment, rotated joint, distal joint), SMPL joint names
LIMB_SEGMENTS: Tuple[Tuple[str, str, str], ...] = (
    ("left_thigh", "left_hip", "left_knee"),
    ("left_shin", "left_knee", "left_ankle"),
    ("right_thigh", "right_hip", "right_knee"),
    ("right_shin", "right_knee", "right_ankle"),
    ("left_upper_arm", "left_shoulder", "left_elbow"),
    ("left_forearm", "left_elbow", "left_wrist"),
    ("right_upper_arm", "right_shoulder", "right_elbow"),
    ("right_forearm", "right_elbow", "right_wrist"),
)
#: hinge segments: the direction the segment swings to when its hinge flexes, in the upper segment's
#: rest frame (SMPL: the body faces +Z; elbows bend the forearm forward, knees the shin backward,
#: :mod:`silfit.priors.limits`)
HINGE_BEND = {
    "left_forearm": (0.0, 0.0, 1.0),
    "right_forearm": (0.0, 0.0, 1.0),
    "left_shin": (0.0, 0.0, -1.0),
    "right_shin": (0.0, 0.0, -1.0),
}
#: a mirrored hinge segment within this many degrees of straight on from its upper segment takes the smallest turn
HINGE_MIN_BEND_DEG = 20.0
#: the torso's lean: turned at the lowest spine joint, pelvis and legs unchanged
TORSO_SEGMENT = ("torso", "spine1", "neck")
#: joint hypotheses the single-segment search cannot reach (its screen keeps only the best few,
#: and a pair of flips rarely wins one flip at a time): ``(label, parts)``, each part a tuple of
#: segments flipped in order; it runs when every part has a segment pointing out of the image
#: plane (``min_depth_ratio``). ``hip`` mirrors the pelvis-to-neck line at the root with the legs
#: kept in place (the hip's tilt); ``torso`` bends at the spine
JOINT_HYPOTHESES: Tuple[Tuple[str, Tuple[Tuple[str, ...], ...]], ...] = (
    ("both_thighs", (("left_thigh",), ("right_thigh",))),
    ("both_shins", (("left_shin",), ("right_shin",))),
    ("both_legs", (("left_thigh", "left_shin"), ("right_thigh", "right_shin"))),
    ("both_upper_arms", (("left_upper_arm",), ("right_upper_arm",))),
    ("both_forearms", (("left_forearm",), ("right_forearm",))),
    ("both_arms", (("left_upper_arm", "left_forearm"), ("right_upper_arm", "right_forearm"))),
    ("torso", (("torso",),)),
    ("hip", (("hip",),)),
    ("torso+both_shins", (("torso",), ("left_shin",), ("right_shin",))),
    ("torso+both_thighs", (("torso",), ("left_thigh",), ("right_thigh",))),
    ("torso+both_legs", (("torso",), ("left_thigh", "left_shin"), ("right_thigh", "right_shin"))),
    ("hip+torso", (("hip",), ("torso",))),
)
#: whole limbs: (upper segment, lower segment)
LIMBS = (
    ("left_thigh", "left_shin"),
    ("right_thigh", "right_shin"),
    ("left_upper_arm", "left_forearm"),
    ("right_upper_arm", "right_forearm"),
)


def mirror_rotation(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Smallest rotations ``[R, 3, 3]`` taking segments ``v [R, 3]`` to their mirror images
    through the planes of unit normals ``n [R, 3]``."""
    return rotation_between(v, v - 2.0 * (v * n).sum(-1, keepdims=True) * n)


def rotation_between(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Smallest rotations ``[R, 3, 3]`` turning directions ``v [R, 3]`` onto ``w [R, 3]``
    (lengths ignored; opposite directions: a half turn about an axis perpendicular to ``v``)."""
    w = w * (np.linalg.norm(v, axis=-1, keepdims=True) / np.maximum(np.linalg.norm(w, axis=-1, keepdims=True), 1e-12))
    axis = np.cross(v, w)
    s = np.linalg.norm(axis, axis=-1)
    c = (v * w).sum(-1)
    angle = np.arctan2(s, c)
    unit = axis / np.maximum(s, 1e-12)[:, None]
    # v and its mirror image (anti)parallel: along the normal a half turn about any axis
    # perpendicular to v; in the plane nothing to turn
    perp = np.cross(
        v, np.where(np.abs(v[:, :1]) < 0.9 * np.linalg.norm(v, axis=-1, keepdims=True), [[1.0, 0, 0]], [[0, 1.0, 0]])
    )
    perp = perp / np.maximum(np.linalg.norm(perp, axis=-1, keepdims=True), 1e-12)
    rv = np.where((s > 1e-9)[:, None], unit * angle[:, None], np.where((c < 0)[:, None], np.pi * perp, 0.0))
    return Rotation.from_rotvec(rv).as_matrix()


def _pose_state(body, rows: Dict[str, torch.Tensor]):
    with torch.no_grad():
        st = body(**rows)
    return st.joints.double().numpy(), st.transforms[..., :3, :3].double().numpy()


def flip_segment(
    body, rows: Dict[str, torch.Tensor], segment: str, joint_names: Sequence[str], parents, hinge: bool = True
) -> torch.Tensor:
    """``body_pose [R, 3 * (J - 1)]`` with ``segment`` mirrored in depth (camera frame,
    perspective: the mirror plane is perpendicular to the ray through the segment's middle).
    The segment's proximal joint takes the smallest turn that does it, except at a hinge
    (:data:`HINGE_BEND`, with ``hinge``): there the upper segment twists about its own axis and
    the hinge flexes, as an elbow or a knee can.

    ``body`` is a :class:`~silfit.fitting.body.KeypointBody`-like evaluator (joints and
    transforms of parameter rows); ``rows`` holds parameter rows in the camera frame."""
    if segment == "hip":
        return flip_hip(body, rows, joint_names)["body_pose"]
    _, proximal, distal = next(s for s in LIMB_SEGMENTS + (TORSO_SEGMENT,) if s[0] == segment)
    j, c = joint_names.index(proximal), joint_names.index(distal)
    joints, G = _pose_state(body, rows)
    p, d = joints[:, j], joints[:, c]
    ray = 0.5 * (p + d)
    n = ray / np.linalg.norm(ray, axis=-1, keepdims=True)
    turned = _turned(rows, G, j, parents, mirror_rotation(d - p, n))
    if not hinge or segment not in HINGE_BEND:
        return turned
    # a hinge (elbow, knee): the upper segment twists about its own axis until the hinge bends
    # toward the mirrored segment, then the hinge bends onto it (the smallest turn at the hinge
    # would bend it sideways, which the priors undo before the branch is scored)
    v = d - p
    target = v - 2.0 * (v * n).sum(-1, keepdims=True) * n
    u = p - joints[:, parents[j]]
    u = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    bend = np.einsum("rij,j->ri", G[:, parents[j]], np.asarray(HINGE_BEND[segment], dtype=np.float64))
    along = lambda w: w - (w * u).sum(-1, keepdims=True) * u  # noqa: E731  (the part across the upper segment)
    b, t = along(bend), along(target)
    angle = np.arctan2((np.cross(b, t) * u).sum(-1), (b * t).sum(-1))
    twisted = dict(
        rows, body_pose=_turned(rows, G, parents[j], parents, Rotation.from_rotvec(u * angle[:, None]).as_matrix())
    )
    joints, G = _pose_state(body, twisted)
    hinged = _turned(twisted, G, j, parents, rotation_between(joints[:, c] - joints[:, j], target))
    # nearly straight on from the upper segment, the mirrored segment needs little flexion and the twist
    # would follow a tiny residual (any angle): there the smallest turn, a small sideways bend (folded
    # back onto the upper segment, the twist is as ill-defined, but the fold is the hinge's to make)
    near = (np.linalg.norm(t, axis=-1) < np.sin(np.deg2rad(HINGE_MIN_BEND_DEG)) * np.linalg.norm(target, axis=-1)) & (
        (target * u).sum(-1) > 0
    )
    return torch.where(torch.as_tensor(near, device=turned.device)[:, None], turned, hinged)


def flip_hip(body, rows: Dict[str, torch.Tensor], joint_names: Sequence[str]) -> Dict[str, torch.Tensor]:
    """``{global_orient, body_pose}`` with the pelvis-to-neck line mirrored in depth at the root
    (through the pelvis) and the hips turned back, so the legs keep their place and direction."""
    joints, G = _pose_state(body, rows)
    p, d = joints[:, 0], joints[:, joint_names.index("neck")]
    n = p / np.linalg.norm(p, axis=-1, keepdims=True)
    fix = mirror_rotation(d - p, n)
    G0 = G[:, 0]
    orient = rows["global_orient"].detach().clone()
    orient[:] = torch.as_tensor(Rotation.from_matrix(fix @ G0).as_rotvec(), dtype=orient.dtype)
    back = np.einsum("rji,rkj,rkl->ril", G0, fix, G0)  # G0^T fix^T G0: the hips' world turn undone
    pose = rows["body_pose"].detach().clone()
    for hip in ("left_hip", "right_hip"):
        j = joint_names.index(hip)
        L = Rotation.from_rotvec(pose[:, 3 * (j - 1) : 3 * j].double().numpy()).as_matrix()
        pose[:, 3 * (j - 1) : 3 * j] = torch.as_tensor(Rotation.from_matrix(back @ L).as_rotvec(), dtype=pose.dtype)
    return {"global_orient": orient, "body_pose": pose}


def joint_hypotheses(
    body,
    rows: Dict[str, torch.Tensor],
    joint_names,
    parents,
    ratios: Dict[str, np.ndarray],
    min_depth_ratio: float = 0.3,
    hinge: bool = True,
) -> List[Tuple[int, str, Dict[str, torch.Tensor]]]:
    """Hypotheses ``(row, label, {parameter: value})`` of :data:`JOINT_HYPOTHESES` for the rows
    where every part has a segment with a depth ratio of at least ``min_depth_ratio``
    (``ratios``: :func:`depth_ratios`, with ``torso`` and ``hip``)."""
    out = []
    for label, parts in JOINT_HYPOTHESES:
        ok = np.ones(rows["body_pose"].shape[0], bool)
        for part in parts:
            ok &= np.max([ratios[s] for s in part], axis=0) >= min_depth_ratio
        sel = np.nonzero(ok)[0]
        if not len(sel):
            continue
        sub = {k: v[sel] for k, v in rows.items()}
        for part in parts:
            for seg in part:
                if seg == "hip":
                    sub.update(flip_hip(body, sub, joint_names))
                else:
                    sub["body_pose"] = flip_segment(body, sub, seg, joint_names, parents, hinge)
        for k, r in enumerate(sel.tolist()):
            out.append((r, label, {"body_pose": sub["body_pose"][k], "global_orient": sub["global_orient"][k]}))
    return out


def _turned(rows, G, j, parents, fix, sel=None) -> torch.Tensor:
    """``body_pose`` with joint ``j``'s global rotation ``G[:, j]`` turned by ``fix [R, 3, 3]``
    (in the rows ``sel``, default all)."""
    Gp, Gj = G[:, parents[j]], G[:, j]
    local = np.einsum("rji,rjk,rkl->ril", Gp, fix, Gj)  # Gp^T @ fix @ Gj
    pose = rows["body_pose"].detach().clone()
    sel = np.ones(len(local), bool) if sel is None else np.asarray(sel, bool)
    new = torch.as_tensor(Rotation.from_matrix(local).as_rotvec(), dtype=pose.dtype)
    pose[sel, 3 * (j - 1) : 3 * j] = new[sel]
    return pose


def align_segments(
    body, rows: Dict[str, torch.Tensor], points: np.ndarray, weights: np.ndarray, joint_names, parents, keypoint_names
) -> torch.Tensor:
    """``body_pose [R, 3 * (J - 1)]`` with every limb segment turned (upper segments first, the
    smallest rotation at its proximal joint) to point along the segment between its end
    keypoints in ``points [R, K, 3]`` (the keypoints of ``keypoint_names``, in the rows' frame);
    a segment whose end keypoints have a zero weight in ``weights [R, K]`` keeps its turn. A start
    for fitting a body to 3D points (triangulated keypoints): the limbs' swing is then right
    whatever the rest pose, and only their twist is left to the optimiser."""
    rows = dict(rows)
    names = list(keypoint_names)
    for _, proximal, distal in LIMB_SEGMENTS:
        if proximal not in names or distal not in names:
            continue
        a, b = names.index(proximal), names.index(distal)
        sel = (weights[:, a] > 0) & (weights[:, b] > 0)
        if not sel.any():
            continue
        with torch.no_grad():
            st = body(**rows)
        kp = st.keypoints.double().numpy()
        G = st.transforms[..., :3, :3].double().numpy()
        fix = rotation_between(kp[:, b] - kp[:, a], points[:, b] - points[:, a])
        rows["body_pose"] = _turned(rows, G, joint_names.index(proximal), parents, fix, sel)
    return rows["body_pose"]


def depth_ratios(body, rows, joint_names) -> Dict[str, np.ndarray]:
    """Per segment, ``|cos|`` of the angle between the segment and the image plane's normal
    (the ray): 0 for a segment in the image plane (nothing to flip), 1 along the ray."""
    joints, _ = _pose_state(body, rows)
    out = {}
    for name, proximal, distal in LIMB_SEGMENTS + (TORSO_SEGMENT, ("hip", "pelvis", "neck")):
        p, d = joints[:, joint_names.index(proximal)], joints[:, joint_names.index(distal)]
        ray = 0.5 * (p + d)
        v = d - p
        out[name] = np.abs((v * ray).sum(-1)) / np.maximum(
            np.linalg.norm(v, axis=-1) * np.linalg.norm(ray, axis=-1), 1e-12
        )
    return out


def limb_hypotheses(
    body,
    rows: Dict[str, torch.Tensor],
    joint_names,
    parents,
    min_depth_ratio: float = 0.3,
    whole_limbs: bool = True,
    joint: bool = False,
    hinge: bool = True,
    hinge_turns: bool = False,
) -> List[Tuple[int, str, torch.Tensor]]:
    """Hypotheses ``(row, label, body_pose [3 * (J - 1)])``: each segment whose depth
    ratio is at least ``min_depth_ratio`` flipped alone and, with ``whole_limbs``, each limb
    with both segments flipped (the upper first, then the lower from its new place); with
    ``joint``, also :func:`joint_hypotheses`, whose third item is a dict (``body_pose`` and
    ``global_orient``: the ``hip`` hypotheses turn the root). ``hinge``: :func:`flip_segment`'s; with
    ``hinge_turns`` each hinge segment's smallest-turn flip is a hypothesis too (``<segment>/turn``)."""
    ratios = depth_ratios(body, rows, joint_names)
    flipped = {name: flip_segment(body, rows, name, joint_names, parents, hinge) for name, _, _ in LIMB_SEGMENTS}
    out = []
    R = rows["body_pose"].shape[0]
    for name, _, _ in LIMB_SEGMENTS:
        for r in np.nonzero(ratios[name] >= min_depth_ratio)[0].tolist():
            out.append((r, name, flipped[name][r]))
    if hinge and hinge_turns:  # the smallest turn at each hinge too, labelled ``<segment>/turn``
        for name in HINGE_BEND:  # (where the hinge flip is that turn already, nearly straight on: no copy)
            turned = flip_segment(body, rows, name, joint_names, parents, hinge=False)
            for r in np.nonzero(ratios[name] >= min_depth_ratio)[0].tolist():
                if not torch.equal(turned[r], flipped[name][r]):
                    out.append((r, f"{name}/turn", turned[r]))
    if whole_limbs:
        for upper, lower in LIMBS:
            sel = np.nonzero((ratios[upper] >= min_depth_ratio) | (ratios[lower] >= min_depth_ratio))[0]
            if not len(sel):
                continue
            sub = {k: v[sel] for k, v in rows.items()}
            sub["body_pose"] = flipped[upper][sel]
            both = flip_segment(body, sub, lower, joint_names, parents, hinge)
            for k, r in enumerate(sel.tolist()):
                out.append((r, f"{upper}+{lower}", both[k]))
    if joint:
        out += joint_hypotheses(body, rows, joint_names, parents, ratios, min_depth_ratio, hinge)
    assert all(0 <= r < R for r, _, _ in out)
    return out


def turn_root(body, rows: Dict[str, torch.Tensor], joint_names, kind) -> Dict[str, torch.Tensor]:
    """``{global_orient, body_pose}`` with the root turned about the torso's axis in the image
    plane (through the pelvis: the body turns as a whole, the legs with it). ``kind``: ``"mirror"``
    mirrors the torso's left-right line (hips and shoulders) in depth, a turn to the other side of
    the image plane that projects (nearly) the same; a number turns by that many degrees."""
    joints, G = _pose_state(body, rows)
    J = lambda n: joints[:, joint_names.index(n)]  # noqa: E731
    p = joints[:, 0]
    n = p / np.linalg.norm(p, axis=-1, keepdims=True)
    if kind == "mirror":
        v = (J("right_hip") - J("left_hip")) + (J("right_shoulder") - J("left_shoulder"))
        fix = mirror_rotation(v, n)
    else:
        up = J("neck") - p
        up = up - (up * n).sum(-1, keepdims=True) * n
        up = up / np.maximum(np.linalg.norm(up, axis=-1, keepdims=True), 1e-12)
        fix = Rotation.from_rotvec(np.deg2rad(float(kind)) * up).as_matrix()
    orient = rows["global_orient"].detach().clone()
    orient[:] = torch.as_tensor(Rotation.from_matrix(fix @ G[:, 0]).as_rotvec(), dtype=orient.dtype)
    return {"global_orient": orient, "body_pose": rows["body_pose"].detach().clone()}


def turn_hypotheses(
    body,
    rows: Dict[str, torch.Tensor],
    joint_names,
    parents,
    turns: Sequence,
    min_depth_ratio: float = 0.3,
    whole_limbs: bool = True,
    hinge: bool = True,
) -> List[Tuple[int, str, Dict[str, torch.Tensor]]]:
    """Hypotheses ``(row, label, {global_orient, body_pose})``: the root turned (:func:`turn_root`,
    one per item of ``turns``), alone and with each limb flip of :func:`limb_hypotheses` proposed
    from the turned pose (a wrong orientation and a wrong limb, which one flip at a time cannot fix)."""
    out = []
    for kind in turns:
        t = turn_root(body, rows, joint_names, kind)
        sub = {**rows, **t}
        tag = "yaw" if kind == "mirror" else f"turn{float(kind):+g}"
        for r in range(rows["body_pose"].shape[0]):
            out.append((r, tag, {"body_pose": t["body_pose"][r], "global_orient": t["global_orient"][r]}))
        for r, label, pose in limb_hypotheses(
            body, sub, joint_names, parents, min_depth_ratio, whole_limbs, hinge=hinge
        ):
            out.append((r, f"{tag}+{label}", {"body_pose": pose, "global_orient": t["global_orient"][r]}))
    return out
