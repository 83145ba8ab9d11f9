"""Weighted non-maximum suppression, as MediaPipe's ``NonMaxSuppressionCalculator`` with
``algorithm: WEIGHTED`` (the pose detector's setting): the best remaining detection
absorbs every other whose box overlaps it by more than the threshold (IoU), and its box
and keypoints become the score-weighted mean of the group; its score stays its own."""

from __future__ import annotations

import numpy as np

__all__ = ["box_iou", "weighted_nms"]


def box_iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of one ``[4]`` box (x_min, y_min, x_max, y_max) with each of ``boxes [N, 4]``."""
    lo = np.maximum(box[:2], boxes[:, :2])
    hi = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    area = lambda b: np.prod(np.clip(b[..., 2:] - b[..., :2], 0.0, None), axis=-1)  # noqa: E731
    union = area(box) + area(boxes) - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def weighted_nms(
    scores: np.ndarray,
    boxes: np.ndarray,
    keypoints: np.ndarray,
    min_score: float = 0.5,
    iou_threshold: float = 0.3,
    max_detections: int = 0,
):
    """Detections with ``score >= min_score`` after weighted NMS, best first:
    ``(scores [M], boxes [M, 4], keypoints [M, K, 2])``; ``max_detections`` 0 keeps all."""
    keep = np.flatnonzero(np.asarray(scores) >= min_score)
    order = keep[np.argsort(-scores[keep], kind="stable")]
    out_s, out_b, out_k = [], [], []
    while len(order):
        best = order[0]
        overlap = box_iou(boxes[best], boxes[order]) > iou_threshold
        overlap[0] = True
        group = order[overlap]
        w = scores[group] / scores[group].sum()
        out_s.append(scores[best])
        out_b.append((boxes[group] * w[:, None]).sum(0))
        out_k.append((keypoints[group] * w[:, None, None]).sum(0))
        order = order[~overlap]
        if max_detections and len(out_s) >= max_detections:
            break
    K = keypoints.shape[1] if keypoints.ndim == 3 else 0
    if not out_s:
        return np.zeros(0), np.zeros((0, 4)), np.zeros((0, K, 2))
    return np.array(out_s), np.stack(out_b), np.stack(out_k)
