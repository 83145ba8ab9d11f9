"""A picture of a detection: each person's mask tinted, region outlined, skeleton drawn."""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from .layout import BLAZEPOSE33_NAMES

__all__ = ["detection_overlay"]

_BONES = (
    ("left_shoulder", "right_shoulder"),
    ("left_hip", "right_hip"),
    ("left_shoulder", "left_hip"),
    ("right_shoulder", "right_hip"),
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("left_hip", "left_knee"),
    ("left_knee", "left_ankle"),
    ("left_ankle", "left_heel"),
    ("left_heel", "left_foot_index"),
    ("left_ankle", "left_foot_index"),
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
    ("right_ankle", "right_heel"),
    ("right_heel", "right_foot_index"),
    ("right_ankle", "right_foot_index"),
    ("left_wrist", "left_index"),
    ("left_wrist", "left_pinky"),
    ("left_wrist", "left_thumb"),
    ("right_wrist", "right_index"),
    ("right_wrist", "right_pinky"),
    ("right_wrist", "right_thumb"),
    ("nose", "left_eye"),
    ("nose", "right_eye"),
    ("left_eye", "left_ear"),
    ("right_eye", "right_ear"),
)
_TINTS = ((40, 200, 40), (40, 120, 230), (230, 160, 30), (200, 40, 200))
_LEFT, _RIGHT = (60, 120, 255), (255, 90, 60)


def detection_overlay(image: np.ndarray, people: Sequence, alpha: float = 0.4) -> np.ndarray:
    """RGB ``uint8`` picture: masks tinted per person, their regions outlined and the
    visible landmarks joined (left side blue, right side red)."""
    out = np.asarray(image, dtype=np.uint8)[..., :3].astype(np.float64)
    for i, p in enumerate(people):
        m = p.mask_prob[..., None].astype(np.float64) * alpha
        out = out * (1 - m) + np.array(_TINTS[i % len(_TINTS)], dtype=np.float64) * m
    out = np.ascontiguousarray(out.round().clip(0, 255).astype(np.uint8))
    thick = max(1, round(max(out.shape[:2]) / 300))
    index = {n: k for k, n in enumerate(BLAZEPOSE33_NAMES)}
    for i, p in enumerate(people):
        corners = np.round(p.roi.corners()).astype(np.int32)
        cv2.polylines(out, [corners], True, _TINTS[i % len(_TINTS)], thick, lineType=cv2.LINE_AA)
        conf = p.confidence()
        for a, b in _BONES:
            ia, ib = index[a], index[b]
            if conf[ia] > 0 and conf[ib] > 0:
                colour = (
                    _LEFT
                    if a.startswith("left") and b.startswith("left")
                    else (_RIGHT if a.startswith("right") and b.startswith("right") else (230, 230, 230))
                )
                pa, pb = (tuple(int(round(v)) for v in p.xy[k]) for k in (ia, ib))
                cv2.line(out, pa, pb, colour, thick + 1, lineType=cv2.LINE_AA)
        for k in np.flatnonzero(conf > 0):
            cv2.circle(out, tuple(int(round(v)) for v in p.xy[k]), thick + 2, (255, 255, 255), -1, lineType=cv2.LINE_AA)
    return out
