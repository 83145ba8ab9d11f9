"""Hand poses for whole-body subjects: a named library written as finger angles, anatomical finger
limits, perturbation within them, and conversion to SMPL-X's ``left/right_hand_pose [45]``.

A hand pose is ``flex [5, 3]`` (radians, fingers in :data:`~silfit.io.wholebody.FINGERS` order, joints
base to tip; positive curls towards the palm) and ``spread [5]`` (radians at each finger's base joint,
about the palm normal; positive moves the finger towards the thumb side, for the thumb away from the
palm's plane edge, i.e. opening the hand). The rotation axes come from the model's rest joints
(:func:`hand_axes`), so the same angles pose the open model and official SMPL-X alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Optional

import numpy as np
from scipy.spatial.transform import Rotation

from ..io.wholebody import FINGERS

__all__ = [
    "HandPose",
    "HAND_LIBRARY",
    "FLEX_LIMITS",
    "SPREAD_LIMITS",
    "hand_axes",
    "hand_pose_to_axis_angle",
    "sample_hand_pose",
    "within_limits",
]

#: Flexion limits [5, 3, 2] (radians): fingers MCP -20..90, PIP 0..110, DIP -5..80 degrees; thumb CMC
#: -15..50, MCP -10..60, IP -15..80 degrees.
FLEX_LIMITS = np.radians(
    np.array(
        [
            [[-15, 50], [-10, 60], [-15, 80]],
            [[-20, 90], [0, 110], [-5, 80]],
            [[-20, 90], [0, 110], [-5, 80]],
            [[-20, 90], [0, 110], [-5, 80]],
            [[-20, 90], [0, 110], [-5, 80]],
        ],
        dtype=np.float64,
    )
)
#: Spread limits [5, 2] (radians at the base joint): thumb -10..45, index -15..20, middle -15..15,
#: ring -20..15, pinky -30..15 degrees.
SPREAD_LIMITS = np.radians(np.array([[-10, 45], [-15, 20], [-15, 15], [-20, 15], [-30, 15]], dtype=np.float64))

# SMPL-X's hand joint order: index, middle, pinky, ring, thumb (3 each)
_SMPLX_ORDER = ("index", "middle", "pinky", "ring", "thumb")


@dataclass(frozen=True)
class HandPose:
    name: str
    description: str
    flex_deg: tuple  # 5 x 3
    spread_deg: tuple  # 5

    @property
    def flex(self) -> np.ndarray:
        return np.radians(np.asarray(self.flex_deg, dtype=np.float64))

    @property
    def spread(self) -> np.ndarray:
        return np.radians(np.asarray(self.spread_deg, dtype=np.float64))


_FIST = (80, 100, 60)
_RELAX = (20, 30, 15)
HAND_LIBRARY: Dict[str, HandPose] = {
    p.name: p
    for p in (
        HandPose("flat", "all fingers straight and together (the model's rest hand)", ((0, 0, 0),) * 5, (0,) * 5),
        HandPose(
            "relaxed",
            "a resting hand: fingers lightly curled, more towards the little finger",
            ((10, 15, 15), (15, 20, 10), _RELAX, (25, 35, 20), (30, 40, 25)),
            (15, 0, 0, 0, 0),
        ),
        HandPose(
            "open",
            "fingers straight and spread wide",
            ((0, 0, 0), (-5, 0, 0), (-5, 0, 0), (-5, 0, 0), (-5, 0, 0)),
            (40, 15, 0, -12, -25),
        ),
        HandPose(
            "fist",
            "a closed fist, the thumb across the fingers",
            ((40, 45, 50), _FIST, _FIST, _FIST, _FIST),
            (0, 0, 0, 0, 0),
        ),
        HandPose(
            "pointing",
            "index finger straight, the others in a fist",
            ((40, 45, 50), (0, 0, 0), _FIST, _FIST, _FIST),
            (0,) * 5,
        ),
        HandPose(
            "pinch",
            "thumb and index tips together (about 1 cm apart on the open model), the others relaxed",
            ((10, 30, 80), (60, 40, 20), (30, 35, 20), (30, 40, 25), (30, 45, 30)),
            (20, 0, 0, 0, 0),
        ),
        HandPose(
            "grasp",
            "holding a cylinder: all fingers half closed, the thumb opposed",
            ((30, 20, 20), (50, 60, 40), (50, 65, 40), (50, 65, 40), (50, 65, 40)),
            (35, 0, 0, 0, 0),
        ),
        HandPose(
            "peace",
            "index and middle straight and apart, the others in a fist",
            ((40, 45, 50), (0, 0, 0), (0, 0, 0), _FIST, _FIST),
            (0, 12, -10, 0, 0),
        ),
        HandPose(
            "thumbs_up", "a fist with the thumb straight", ((0, 0, 0), _FIST, _FIST, _FIST, _FIST), (30, 0, 0, 0, 0)
        ),
    )
}


def within_limits(flex: np.ndarray, spread: np.ndarray, atol: float = 1e-9) -> bool:
    return bool(
        np.all(flex >= FLEX_LIMITS[..., 0] - atol)
        and np.all(flex <= FLEX_LIMITS[..., 1] + atol)
        and np.all(spread >= SPREAD_LIMITS[:, 0] - atol)
        and np.all(spread <= SPREAD_LIMITS[:, 1] + atol)
    )


def hand_axes(rest_joints: np.ndarray, joint_names, side: str) -> Dict[str, np.ndarray]:
    """Per finger: ``flex [3, 3]`` (one unit axis per joint) and ``spread [3]`` (unit axis) from rest
    joints ``[J, 3]``. The palm normal points out of the palm (the knuckle plane through wrist, index
    base and pinky base, oriented downwards: rest hands lie palm down, as in SMPL-X); flexion about ``segment x palm normal`` turns the segment towards the palm;
    spread is about the palm normal, signed so that positive turns towards the thumb side (for the
    thumb: away from the index, opening the hand)."""
    j = {n: rest_joints[i] for i, n in enumerate(joint_names)}
    wrist, index1, pinky1 = j[f"{side}_wrist"], j[f"{side}_index1"], j[f"{side}_pinky1"]
    normal = np.cross(index1 - wrist, pinky1 - wrist)
    normal /= np.linalg.norm(normal)
    # Orient the normal out of the palm: SMPL-X's rest hands (and the open model's) lie palm down (-Y)
    if normal[1] > 0:
        normal = -normal
    thumb_side = (index1 - pinky1) / np.linalg.norm(index1 - pinky1)
    axes = {}
    for f in FINGERS:
        pts = [j[f"{side}_{f}{k}"] for k in (1, 2, 3)]
        segs = [pts[1] - pts[0], pts[2] - pts[1], pts[2] - pts[1]]
        # fingers curl towards the palm; the thumb's base (CMC) towards the palm, its MCP and IP joints across
        # it, towards the little finger (the thumb's nail faces sideways)
        if f == "thumb":
            towards = [normal - 0.5 * thumb_side, 0.5 * normal - thumb_side, 0.5 * normal - thumb_side]
        else:
            towards = [normal] * 3
        flex = np.stack([np.cross(s, t) / np.linalg.norm(np.cross(s, t)) for s, t in zip(segs, towards)])
        d = segs[0] / np.linalg.norm(segs[0])
        spread = normal.copy()
        if np.dot(np.cross(spread, d), thumb_side) < 0:
            spread = -spread
        axes[f] = {"flex": flex, "spread": spread}
    return axes


def hand_pose_to_axis_angle(flex: np.ndarray, spread: np.ndarray, axes: Dict[str, dict]) -> np.ndarray:
    """SMPL-X hand pose ``[45]`` (axis-angle, SMPL-X's joint order) of finger angles."""
    out = np.zeros((5, 3, 3))
    for f_i, f in enumerate(FINGERS):
        slot = _SMPLX_ORDER.index(f)
        for k in range(3):
            rot = Rotation.from_rotvec(axes[f]["flex"][k] * flex[f_i, k])
            if k == 0:
                rot = rot * Rotation.from_rotvec(axes[f]["spread"] * spread[f_i])
            out[slot, k] = rot.as_rotvec()
    return out.reshape(45)


def sample_hand_pose(rng: np.random.Generator, name: Optional[str] = None, perturb_deg: float = 6.0):
    """``(name, flex [5, 3], spread [5])``: a library pose (uniform if ``name`` is None) with Gaussian
    noise of ``perturb_deg`` on every angle, clipped into the finger limits."""
    names = list(HAND_LIBRARY)
    pose = HAND_LIBRARY[name if name is not None else names[int(rng.integers(len(names)))]]
    sigma = np.radians(perturb_deg)
    flex = np.clip(pose.flex + rng.normal(0, sigma, (5, 3)), FLEX_LIMITS[..., 0], FLEX_LIMITS[..., 1])
    spread = np.clip(pose.spread + rng.normal(0, sigma * 0.5, 5), SPREAD_LIMITS[:, 0], SPREAD_LIMITS[:, 1])
    return pose.name, flex, spread
