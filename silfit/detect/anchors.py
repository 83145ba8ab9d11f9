"""SSD anchor centres of the BlazePose person detector and the decoding of its raw output.

The detector (``pose_detection.tflite``, 224 x 224 input) predicts, for each of 2254
anchors, a score logit and 12 numbers: the face box ``(dx, dy, w, h)`` and four body
alignment points ``(dx, dy)`` (0: hip centre, 1: a point whose distance from the hip
centre gives the full body's size and whose direction gives its rotation, 2: shoulder
centre, 3: the same for the upper body), in input pixels relative to the anchor centre.

The anchor grid follows MediaPipe's ``SsdAnchorsCalculator`` with the options of its
``pose_detection_cpu`` graph: 5 layers of strides 8, 16, 32, 32, 32 on a 224 x 224 input,
anchor offset 0.5, aspect ratio 1 plus the interpolated scale (two anchors per layer and
cell), fixed anchor size (every anchor is 1 x 1 in normalised units, so only the centres
matter). Consecutive layers with the same stride share one feature map, so the stride-32
map holds 3 x 2 = 6 anchors per cell: 28*28*2 + 14*14*2 + 7*7*6 = 2254.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

__all__ = ["DETECTOR_INPUT", "ssd_anchor_centres", "decode_detections"]

DETECTOR_INPUT = 224
_STRIDES = (8, 16, 32, 32, 32)
_ANCHORS_PER_LAYER = 2  # aspect ratio 1.0 and the interpolated-scale anchor
_SCORE_CLIP = 100.0


@lru_cache(maxsize=None)
def ssd_anchor_centres(input_size: int = DETECTOR_INPUT, strides: tuple = _STRIDES) -> np.ndarray:
    """``[N, 2]`` anchor centres ``(x, y)`` in normalised input coordinates, in the model's order:
    feature maps by increasing stride, then rows, columns and the anchors of a cell."""
    centres = []
    layer = 0
    while layer < len(strides):
        stride = strides[layer]
        same = 0
        while layer + same < len(strides) and strides[layer + same] == stride:
            same += 1
        n = int(math.ceil(input_size / stride))
        ys, xs = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n, indexing="ij")
        cell = np.stack([xs, ys], axis=-1).reshape(-1, 1, 2)
        centres.append(np.repeat(cell, same * _ANCHORS_PER_LAYER, axis=1).reshape(-1, 2))
        layer += same
    out = np.concatenate(centres, axis=0)
    out.setflags(write=False)
    return out


def decode_detections(raw_boxes: np.ndarray, raw_scores: np.ndarray, input_size: int = DETECTOR_INPUT):
    """Decode the detector's outputs ``[N, 12]`` and ``[N]`` (or with a batch dimension of 1).

    Returns ``(scores [N], boxes [N, 4] as x_min, y_min, x_max, y_max, keypoints [N, 4, 2])``
    in normalised input coordinates (0..1 across the 224-pixel input's edges).
    """
    raw = np.asarray(raw_boxes, dtype=np.float64).reshape(-1, 12)
    logits = np.asarray(raw_scores, dtype=np.float64).reshape(-1)
    anchors = ssd_anchor_centres(input_size)
    if len(raw) != len(anchors) or len(logits) != len(anchors):
        raise ValueError(f"detector output holds {len(raw)} boxes and {len(logits)} scores, expected {len(anchors)}")
    scores = 1.0 / (1.0 + np.exp(-np.clip(logits, -_SCORE_CLIP, _SCORE_CLIP)))
    centre = raw[:, 0:2] / input_size + anchors
    half = raw[:, 2:4] / input_size / 2.0
    boxes = np.concatenate([centre - half, centre + half], axis=1)
    keypoints = raw[:, 4:12].reshape(-1, 4, 2) / input_size + anchors[:, None, :]
    return scores, boxes, keypoints
