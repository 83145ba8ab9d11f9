"""BlazePose's 33 landmarks (layout ``blazepose33``, defined with the others in
:mod:`silfit.io.keypoints`, where their sources on the body model are) and their conversion
to the other layouts silfit fits and writes (OpenPose BODY_25, COCO-17).

BODY_25 from BlazePose: the 17 points both share are copied; ``mid_hip`` is the hips'
midpoint (with the lower of the two confidences); ``big_toe`` is BlazePose's
``foot_index`` (the tip of the foot) and ``heel`` its heel. ``small_toe`` has no
BlazePose counterpart and is left undetected (confidence 0).

``neck``: the body model's neck joint (the point BODY_25's neck is fitted to) lies above
the line between BlazePose's shoulders: on 44 rendered subjects (the shipped 12 and 32
more) it sat a median 0.15 torso lengths (shoulder midpoint to hip midpoint, IQR
0.09-0.17) above the shoulder midpoint, which alone would leave a 12 px median error on
512-pixel images. The neck is therefore the shoulder midpoint moved up the torso by
:data:`NECK_ABOVE_SHOULDERS` of its length.
"""

from __future__ import annotations

import numpy as np

from ..io.keypoints import BLAZEPOSE33_NAMES, BODY25_NAMES, COCO17_NAMES

__all__ = ["BLAZEPOSE33_NAMES", "blazepose_to_layout", "LOWER_BODY"]

#: Target keypoint name -> the BlazePose landmarks it is the mean of (names not listed
#: are taken by the same name; an empty tuple: not detected).
_DERIVED = {
    "mid_hip": ("left_hip", "right_hip"),
    "left_big_toe": ("left_foot_index",),
    "right_big_toe": ("right_foot_index",),
    "left_small_toe": (),
    "right_small_toe": (),
}

#: How far (in torso lengths) the neck lies above the shoulders' midpoint (measured, see above).
NECK_ABOVE_SHOULDERS = 0.15

#: BlazePose landmarks below the hips (reported when a person's lower body is not visible).
LOWER_BODY = (
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
)

_TARGETS = {"body25": BODY25_NAMES, "coco17": COCO17_NAMES, "blazepose33": BLAZEPOSE33_NAMES}


def blazepose_to_layout(xy: np.ndarray, conf: np.ndarray, layout: str = "body25") -> np.ndarray:
    """``[K, 3]`` keypoints (x, y, confidence) of ``layout`` from BlazePose's ``xy [33, 2]``
    and per-landmark confidences ``conf [33]``; undetected points are ``(0, 0, 0)``."""
    try:
        names = _TARGETS[layout.lower()]
    except KeyError:
        raise ValueError(f"unknown keypoint layout {layout!r} (expected one of {', '.join(_TARGETS)})") from None
    xy = np.asarray(xy, dtype=np.float64).reshape(len(BLAZEPOSE33_NAMES), 2)
    conf = np.asarray(conf, dtype=np.float64).reshape(len(BLAZEPOSE33_NAMES))
    index = {n: i for i, n in enumerate(BLAZEPOSE33_NAMES)}
    out = np.zeros((len(names), 3))
    for k, name in enumerate(names):
        if name == "neck":
            out[k] = _neck(xy, conf, index)
            continue
        src = [index[s] for s in _DERIVED.get(name, (name,))]
        if not src:
            continue
        c = float(conf[src].min())
        if c > 0:
            out[k, :2] = xy[src].mean(axis=0)
            out[k, 2] = c
    return out


def _neck(xy: np.ndarray, conf: np.ndarray, index: dict) -> np.ndarray:
    ls, rs, lh, rh = (index[n] for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip"))
    c = float(min(conf[ls], conf[rs]))
    if c <= 0:
        return np.zeros(3)
    shoulders, hips = (xy[ls] + xy[rs]) / 2, (xy[lh] + xy[rh]) / 2
    return np.array([*(shoulders + NECK_ABOVE_SHOULDERS * (shoulders - hips)), c])
