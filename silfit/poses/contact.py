"""Contact and penetration between body parts on the posed mesh (a check, not a fitting term).

Parts are groups of joints; a vertex belongs to the joint with its largest skinning
weight. For the vertices of group ``a`` the nearest vertex ``u`` of group ``b`` gives

* the **gap** ``|a - u|`` (the smallest over ``a``: 0 when the surfaces touch);
* the **depth** of a vertex inside ``b``: ``|a - u|`` where it lies behind ``b``'s surface
  (``(a - u) . n_u < 0``, ``n_u`` the outward vertex normal). Only vertices within
  ``reach`` of ``b``'s surface count (a point farther than that has passed the middle of
  the part, or is on the other side of the body), and only if the surfaces meet (gap
  below ``touch``): parts that intersect have vertices on the intersection curve.

``settle_contact`` turns a pose in which two parts intersect into one in which they just
touch: it bisects the geodesic blend from a pose where they are apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Tuple

import numpy as np
import torch
from scipy.spatial import cKDTree

from ..priors.interpenetration import vertex_normals
from .library import BODY_JOINTS, POSE_LIBRARY, arm, blend_poses, elbow

__all__ = ["Contact", "part_contact", "settle_contact", "posed_vertices", "contact_examples", "intersecting_examples"]


@dataclass(frozen=True)
class Contact:
    gap: float  # metres, smallest distance from a vertex of `a` to one of `b`
    depth: float  # metres, deepest vertex of `a` inside `b` (0 if none)
    inside: int  # vertices of `a` deeper than `tol` inside `b`


def _vertex_normals(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    return vertex_normals(v, faces)


def _group(model, names: Sequence[str]) -> np.ndarray:
    unknown = [n for n in names if n not in model.joint_names]
    if unknown:
        raise ValueError(f"unknown joints {unknown}")
    part = model.lbs_weights.argmax(1).cpu().numpy()
    return np.flatnonzero(np.isin(part, [model.joint_names.index(n) for n in names]))


def posed_vertices(model, body_pose, betas=None) -> np.ndarray:
    """Vertices ``[V, 3]`` (float64) of ``model`` in ``body_pose [69]`` (no global rotation)."""
    bp = torch.as_tensor(np.asarray(body_pose)[None], dtype=model.dtype)
    b = None if betas is None else torch.as_tensor(np.asarray(betas)[None], dtype=model.dtype)
    with torch.no_grad():
        return model(betas=b, body_pose=bp).vertices[0].double().cpu().numpy()


def part_contact(
    model,
    vertices: np.ndarray,
    a: Sequence[str],
    b: Sequence[str],
    reach: float = 0.06,
    tol: float = 0.005,
    touch: float = 0.012,
) -> Contact:
    """Gap and penetration of joint group ``a`` into joint group ``b`` on posed ``vertices [V, 3]``."""
    v = np.asarray(vertices, dtype=np.float64)
    ia, ib = _group(model, a), _group(model, b)
    normals = _vertex_normals(v, model.faces.cpu().numpy())
    d, k = cKDTree(v[ib]).query(v[ia])
    u = ib[k]
    behind = ((v[ia] - v[u]) * normals[u]).sum(1) < 0
    depth = np.where(behind & (d < reach), d, 0.0) if d.min() < touch else np.zeros_like(d)
    return Contact(gap=float(d.min()), depth=float(depth.max()), inside=int((depth > tol).sum()))


def settle_contact(
    model,
    apart,
    through,
    pairs: Sequence[Tuple[Sequence[str], Sequence[str]]],
    tol: float = 0.005,
    steps: int = 8,
    betas=None,
) -> np.ndarray:
    """The pose on the geodesic blend from ``apart`` (no group of ``pairs`` ``[(a, b), ...]``
    inside its partner) toward ``through`` (intersecting) nearest ``through`` whose
    penetrations all stay within ``tol``: the parts touch there."""
    lo, hi = 0.0, 1.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        v = posed_vertices(model, blend_poses(apart, through, mid), betas)
        if max(part_contact(model, v, a, b, tol=tol).depth for a, b in pairs) > tol:
            hi = mid
        else:
            lo = mid
    return blend_poses(apart, through, lo)


# ----------------------------------------------------------------------------- reference poses
TORSO = ["pelvis", "spine1", "spine2", "spine3"]
L_ARM = ["left_elbow", "left_wrist", "left_hand"]
R_ARM = ["right_elbow", "right_wrist", "right_hand"]
R_HAND = ["right_wrist", "right_hand"]
HEAD = ["head", "neck"]


def _with_joints(name, **rotations):
    p = POSE_LIBRARY[name].body_pose.reshape(23, 3).copy()
    for joint, rv in rotations.items():
        p[BODY_JOINTS.index(joint)] = rv
    return p.reshape(69)


def contact_examples(model) -> dict:
    """``{name: (body_pose [69], [(a, b), ...])}``: library poses adjusted so that the joint
    groups ``a`` and ``b`` of each pair just touch (arms hanging against the sides, a hand
    resting on the head, seated with the hands on the thighs, arms crossed)."""
    sides_in = _with_joints(
        "stand_relaxed", left_shoulder=arm("L", (-0.25, -1, 0.05)), right_shoulder=arm("R", (-0.25, -1, 0.05))
    )
    hand_up = dict(right_shoulder=arm("R", (0.7, 0.7, 0.2), internal=-90))
    head_apart = _with_joints("stand_relaxed", **hand_up, right_elbow=elbow("R", 60))
    head_in = _with_joints("stand_relaxed", **hand_up, right_elbow=elbow("R", 150))
    raised = _with_joints(
        "sit_chair",
        left_shoulder=arm("L", (0.2, -0.6, 0.8), internal=15),
        right_shoulder=arm("R", (0.2, -0.6, 0.8), internal=15),
    )
    loose = blend_poses(POSE_LIBRARY["arms_crossed"].body_pose, POSE_LIBRARY["stand_relaxed"].body_pose, 0.6)
    cases = {
        "arms_hanging_against_the_sides": (
            POSE_LIBRARY["stand_relaxed"].body_pose,
            sides_in,
            [(L_ARM, TORSO), (R_ARM, TORSO)],
        ),
        "hand_resting_on_the_head": (head_apart, head_in, [(R_HAND, HEAD)]),
        "seated_hands_on_the_thighs": (
            raised,
            POSE_LIBRARY["sit_chair"].body_pose,
            [(L_ARM, ["left_hip"]), (R_ARM, ["right_hip"])],
        ),
        "arms_crossed_touching": (
            loose,
            POSE_LIBRARY["arms_crossed"].body_pose,
            [(L_ARM, TORSO), (R_ARM, TORSO), (L_ARM, R_ARM)],
        ),
    }
    return {name: (settle_contact(model, a, b, pairs), pairs) for name, (a, b, pairs) in cases.items()}


def intersecting_examples() -> dict:
    """``{name: (body_pose [69], [(a, b)])}``: poses in which group ``a`` is centimetres deep
    inside group ``b`` (library poses authored with the arms through the chest or the belly,
    and a seated pose with the forearm hanging through the thigh)."""
    through_thigh = _with_joints("sit_chair", left_shoulder=arm("L", (0.1, -1, 0.55)), left_elbow=elbow("L", 0))
    return {
        "arms_crossed_through_the_chest": (POSE_LIBRARY["arms_crossed"].body_pose, [(L_ARM, TORSO)]),
        "hands_clasped_inside_the_belly": (POSE_LIBRARY["squat_half"].body_pose, [(L_ARM, TORSO)]),
        "forearm_through_the_thigh": (through_thigh, [(L_ARM, ["left_hip"])]),
    }
