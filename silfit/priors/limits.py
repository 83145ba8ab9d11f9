"""Anatomical joint limits for SMPL's 23 body joints, in axis-angle components.

Frame (the body model's rest frame): Y up, body facing +Z, +X the body's left. Each
body joint's rotation is relative to its parent, and at the T-pose rest every local
frame is aligned with the model frame, so the signs below hold for every joint:

* knees: flexion (foot moves backward) is a **positive** rotation about +X;
* hips: flexion (thigh forward, +Z) is **negative** about X; abduction of the left leg
  (foot towards +X) is positive about Z, of the right leg negative;
* ankles: plantar flexion (toes down) positive about X, dorsiflexion negative;
* spine1/2/3, neck, head: forward flexion positive about X;
* elbows: flexion bends the forearm forward (+Z): **negative** Y for the left elbow,
  **positive** Y for the right (SMPLify's angle prior on pose indices 55/58);
* shoulders: the left arm lowered to the side is negative Z (about -1.5 rad with the
  collar), raised overhead positive Z; swinging it forward is negative Y.
  Right-side joints mirror the left: ``(x, y, z) -> (x, -y, -z)``.

Bounds are per component of the axis-angle vector (box limits). For a rotation about
mostly one axis they are the angle limits; for combined rotations they are an
approximation (axis-angle components are not Euler angles), so the boxes are kept
generous: wide enough for sitting, kneeling, lunging, kicking, throwing and reaching
overhead, tight enough to forbid hyperextended knees/elbows, knees bending sideways
and heads turned backwards. Values in radians.
"""

from __future__ import annotations

import math
from typing import Dict, Tuple

import torch

from ..body.io import SMPL_JOINT_NAMES

__all__ = [
    "BODY_JOINT_NAMES",
    "JOINT_LIMITS",
    "limit_bounds",
    "limit_violation",
    "within_limits",
    "clamp_to_limits",
    "limit_centre_and_range",
]

#: The 23 joints of ``body_pose`` (SMPL joints 1..23, pelvis excluded), in order.
BODY_JOINT_NAMES = SMPL_JOINT_NAMES[1:]

Bounds = Tuple[Tuple[float, float], Tuple[float, float], Tuple[float, float]]

# Left side and midline joints: ((x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi)).
_LEFT_AND_MID: Dict[str, Bounds] = {
    # Flexion to -2.6 (deep squat / high kick), extension 0.8; twist +-0.9;
    # abduction 1.4 (splits, kicks sideways), adduction 0.6 (crossed legs).
    "left_hip": ((-2.6, 0.8), (-0.9, 0.9), (-0.6, 1.4)),
    # Flexion 0 .. 2.7 (kneeling), slight hyperextension allowed; little twist/varus.
    "left_knee": ((-0.1, 2.7), (-0.4, 0.4), (-0.25, 0.25)),
    # Plantar flexion 1.0 (pointed toes), dorsiflexion -0.7; inversion/eversion.
    "left_ankle": ((-0.7, 1.0), (-0.6, 0.6), (-0.5, 0.5)),
    "left_foot": ((-0.8, 0.8), (-0.3, 0.3), (-0.3, 0.3)),
    # Each spine segment: flexion 1.0, extension 0.6, twist 0.6, side bend 0.5.
    "spine1": ((-0.6, 1.0), (-0.6, 0.6), (-0.5, 0.5)),
    "spine2": ((-0.5, 0.8), (-0.5, 0.5), (-0.4, 0.4)),
    "spine3": ((-0.5, 0.8), (-0.5, 0.5), (-0.4, 0.4)),
    "neck": ((-0.7, 0.9), (-0.9, 0.9), (-0.6, 0.6)),
    "head": ((-0.6, 0.7), (-0.9, 0.9), (-0.5, 0.5)),
    # Clavicle: elevation (+z) 0.7, depression 0.4, protraction/retraction (y) 0.5.
    "left_collar": ((-0.4, 0.4), (-0.6, 0.5), (-0.4, 0.7)),
    # Upper arm: down by the side ~-1.5 (z), overhead +1.8; forward (-y) 2.4 (across the
    # chest / overhead throw), backward 1.2; twist about the arm +-1.7.
    "left_shoulder": ((-1.7, 1.7), (-2.4, 1.2), (-2.0, 1.9)),
    # Flexion (-y) to 2.7, hyperextension 0.15; pronation/supination (x) and a little
    # carrying-angle freedom (z).
    "left_elbow": ((-1.5, 1.5), (-2.7, 0.15), (-0.6, 0.6)),
    # Forearm twist (x), radial/ulnar deviation (y), flexion/extension (z).
    "left_wrist": ((-1.6, 1.6), (-0.7, 0.7), (-1.3, 1.3)),
    "left_hand": ((-0.8, 0.8), (-0.6, 0.6), (-0.8, 0.8)),
}


def _mirror(b: Bounds) -> Bounds:
    """Limits of the right-side joint: the axis-angle of the mirrored rotation is (x, -y, -z)."""
    (xl, xh), (yl, yh), (zl, zh) = b
    return ((xl, xh), (-yh, -yl), (-zh, -zl))


def _build() -> Dict[str, Bounds]:
    out: Dict[str, Bounds] = {}
    for name in BODY_JOINT_NAMES:
        if name in _LEFT_AND_MID:
            out[name] = _LEFT_AND_MID[name]
        else:
            out[name] = _mirror(_LEFT_AND_MID[name.replace("right_", "left_")])
    return out


#: ``{joint name: ((x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi))}`` in radians, for the 23
#: body joints (``body_pose`` order given by :data:`BODY_JOINT_NAMES`).
JOINT_LIMITS: Dict[str, Bounds] = _build()

_LOWER = [lo for name in BODY_JOINT_NAMES for lo, _ in JOINT_LIMITS[name]]
_UPPER = [hi for name in BODY_JOINT_NAMES for _, hi in JOINT_LIMITS[name]]
assert len(_LOWER) == 69 and all(lo < hi for lo, hi in zip(_LOWER, _UPPER))
assert all(-math.pi < v < math.pi for v in _LOWER + _UPPER)


def limit_bounds(dtype=torch.float32, device=None) -> Tuple[torch.Tensor, torch.Tensor]:
    """``(lower [69], upper [69])`` bounds in ``body_pose`` order."""
    return (torch.tensor(_LOWER, dtype=dtype, device=device), torch.tensor(_UPPER, dtype=dtype, device=device))


def limit_centre_and_range(dtype=torch.float32, device=None) -> Tuple[torch.Tensor, torch.Tensor]:
    """``(centre [69], half_range [69])`` of the limit boxes."""
    lo, hi = limit_bounds(dtype, device)
    return (lo + hi) / 2, (hi - lo) / 2


def _check(body_pose: torch.Tensor) -> torch.Tensor:
    body_pose = torch.as_tensor(body_pose)
    if not body_pose.is_floating_point():
        body_pose = body_pose.float()
    if body_pose.ndim == 1:
        body_pose = body_pose[None]
    if body_pose.ndim != 2 or body_pose.shape[1] != 69:
        raise ValueError(f"body_pose has shape {tuple(body_pose.shape)}, expected [B, 69]")
    return body_pose


def limit_violation(body_pose: torch.Tensor) -> torch.Tensor:
    """Soft joint-limit penalty ``[B]``: sum of squared excess (radians^2) beyond the
    bounds; zero inside, differentiable everywhere. SMPL-X's 21-joint ``body_pose [B, 63]``
    is accepted too (its joints are SMPL's first 21)."""
    if torch.is_tensor(body_pose) and body_pose.ndim == 2 and body_pose.shape[1] == 63:
        body_pose = torch.cat([body_pose, body_pose.new_zeros(body_pose.shape[0], 6)], 1)
    body_pose = _check(body_pose)
    lo, hi = limit_bounds(body_pose.dtype, body_pose.device)
    below = torch.relu(lo - body_pose)
    above = torch.relu(body_pose - hi)
    return (below * below + above * above).sum(-1)


def within_limits(body_pose: torch.Tensor, tol: float = 0.0) -> torch.Tensor:
    """``BoolTensor [B]``: every component inside its bounds widened by ``tol`` radians."""
    body_pose = _check(body_pose)
    lo, hi = limit_bounds(body_pose.dtype, body_pose.device)
    return ((body_pose >= lo - tol) & (body_pose <= hi + tol)).all(-1)


def clamp_to_limits(body_pose: torch.Tensor) -> torch.Tensor:
    """``body_pose`` with every component clamped into its bounds (same shape)."""
    squeeze = torch.as_tensor(body_pose).ndim == 1
    body_pose = _check(body_pose)
    lo, hi = limit_bounds(body_pose.dtype, body_pose.device)
    out = torch.maximum(torch.minimum(body_pose, hi), lo)
    return out[0] if squeeze else out
