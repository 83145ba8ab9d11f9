"""Other people are not this person (issue 55): a person's mask with the other people's regions taken out.

A segmenter run around one person also marks the people next to them: a second person's arm reaching
across, a neighbour standing behind. The silhouette stage then widens or turns the body to cover them.
With several people detected, :func:`own_mask` removes from one person's mask every pixel that belongs to
another person rather than to them:

* a pixel of the mask that also lies in another person's mask and is nearer that person's skeleton than
  this person's (the overlap of two masks is shared out by the skeletons, so this person keeps their own
  arm where it crosses the other's mask);
* a pixel of the mask within ``radius`` of another person's skeleton and nearer to it than to this
  person's (the neighbourhood of the other person's keypoints: the part of them their own mask missed).

A skeleton (:func:`skeleton_distance`) is the segments between the confident keypoints of a person's
layout (:data:`BONES`, by name: BODY_25, COCO-17, BlazePose-33 and the whole-body layout's body part) and
the keypoints themselves. Pure functions of arrays; the image path applies them where a photo's people are
detected (``silfit fit --image``, ``--people all``).
"""

from __future__ import annotations

from typing import Optional, Sequence

import cv2
import numpy as np

__all__ = ["BONES", "own_mask", "skeleton_distance"]

#: the segments of a person's skeleton, by keypoint name (a pair a layout does not name is skipped)
BONES = (
    ("neck", "nose"),
    ("neck", "mid_hip"),
    ("left_shoulder", "right_shoulder"),
    ("left_hip", "right_hip"),
    ("left_shoulder", "left_hip"),
    ("right_shoulder", "right_hip"),
    ("neck", "left_shoulder"),
    ("neck", "right_shoulder"),
    ("mid_hip", "left_hip"),
    ("mid_hip", "right_hip"),
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("left_hip", "left_knee"),
    ("left_knee", "left_ankle"),
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
    ("left_ankle", "left_heel"),
    ("right_ankle", "right_heel"),
    ("left_ankle", "left_big_toe"),
    ("right_ankle", "right_big_toe"),
    ("left_ankle", "left_foot_index"),
    ("right_ankle", "right_foot_index"),
    ("nose", "left_eye"),
    ("nose", "right_eye"),
    ("left_eye", "left_ear"),
    ("right_eye", "right_ear"),
    ("left_wrist", "left_index"),
    ("right_wrist", "right_index"),
)


def skeleton_distance(
    shape: tuple, xy: np.ndarray, conf: np.ndarray, names: Sequence[str], min_conf: float = 0.2
) -> Optional[np.ndarray]:
    """Distance (pixels, float32 ``[H, W]`` for ``shape = (H, W)``) from every pixel to a person's skeleton:
    the segments of :data:`BONES` between keypoints of confidence above ``min_conf`` and those keypoints;
    ``None`` when none is confident."""
    H, W = int(shape[0]), int(shape[1])
    xy, conf = np.asarray(xy, dtype=np.float64), np.asarray(conf, dtype=np.float64)
    ok = (conf > float(min_conf)) & np.isfinite(xy).all(1)
    if not ok.any():
        return None
    index = {n: k for k, n in enumerate(names)}
    canvas = np.zeros((H, W), np.uint8)
    # drawn with 4 bits of sub-pixel precision; points beyond the image are clipped by OpenCV
    pts = np.round(np.clip(xy, -4 * max(H, W), 5 * max(H, W)) * 16).astype(np.int64)
    for a, b in BONES:
        i, j = index.get(a), index.get(b)
        if i is not None and j is not None and ok[i] and ok[j]:
            cv2.line(canvas, tuple(int(v) for v in pts[i]), tuple(int(v) for v in pts[j]), 1, 1, cv2.LINE_8, 4)
    for k in np.nonzero(ok)[0]:
        cv2.circle(canvas, tuple(int(v) for v in pts[k]), 0, 1, 1, cv2.LINE_8, 4)
    if not canvas.any():  # every confident keypoint beyond the image: the distance to the nearest one
        yy, xx = np.mgrid[0:H, 0:W]
        d = np.min([np.hypot(xx - x, yy - y) for x, y in xy[ok]], axis=0)
        return d.astype(np.float32)
    return cv2.distanceTransform((canvas == 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def own_mask(
    mask: np.ndarray, own: tuple, others: Sequence[tuple], min_conf: float = 0.2, keep: float = 0.0
) -> np.ndarray:
    """``mask`` (bool ``[H, W]``) less the pixels that belong to other people (module docstring).

    ``own``: this person's ``(xy [K, 2], conf [K], names)``; ``others``: per other person ``(mask or None,
    xy, conf, names, radius)``, ``radius`` (pixels) how far from their skeleton their neighbourhood reaches
    (about a limb's half-width). Pixels within ``keep`` pixels of this person's own skeleton stay (their body
    where it overlaps the other: an arm across them). Without a confident keypoint of this person nothing is removed;
    a removal that would leave nothing returns ``mask`` unchanged."""
    m = np.asarray(mask, dtype=bool)
    if not others or not m.any():
        return m.copy()
    d_own = skeleton_distance(m.shape, *own, min_conf=min_conf)
    if d_own is None:
        return m.copy()
    removed = np.zeros_like(m)
    for other_mask, xy, conf, names, radius in others:
        d_other = skeleton_distance(m.shape, xy, conf, names, min_conf=min_conf)
        if d_other is None:
            continue
        theirs = d_other < d_own
        near = d_other <= float(radius)
        if other_mask is not None:
            near = near | np.asarray(other_mask, dtype=bool)
        removed |= m & theirs & near & (d_own > float(keep))
    out = m & ~removed
    return out if out.any() else m.copy()
