"""The BlazePose GHUM landmark model on one region of interest.

``pose_landmark_full.tflite`` takes the 256 x 256 RGB crop of a rotated square region
(values in [0, 1]) and returns, as MediaPipe's ``pose_landmark_by_roi`` graph decodes them:

* 39 landmarks x (x, y, z, visibility, presence) in crop pixels (x, y) with visibility and
  presence as logits: the 33 body landmarks (:data:`silfit.detect.layout.BLAZEPOSE33_NAMES`)
  and 6 auxiliary points, of which 33 (hip centre) and 34 (full-body scale point) give
  the next region of interest;
* the pose presence score (already a probability);
* a 256 x 256 person segmentation (logits);
* 64 x 64 x 39 heatmaps (logits), used to refine each landmark's position: the
  confidence-weighted mean of the 7 x 7 heatmap cells around it, where the heatmap's
  peak confidence is at least 0.5;
* 39 x 3 world landmarks (metres, hip-centred).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import ROI, roi_from_alignment_points, warp_from_crop, warp_to_crop
from .models import load_model

__all__ = ["LANDMARK_INPUT", "RoiLandmarks", "run_landmark_model", "refine_from_heatmap", "roi_from_landmarks"]

LANDMARK_INPUT = 256
NUM_LANDMARKS = 33
_NUM_ALL = 39
_HIP_CENTRE, _SCALE_POINT = 33, 34
#: Region margin around the body, as in MediaPipe's pose graphs.
ROI_SCALE = 1.25


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.clip(x, -80.0, 80.0)))


@dataclass
class RoiLandmarks:
    """The landmark model's output on one ROI, in image pixel coordinates."""

    roi: ROI
    presence_score: float  # pose presence in the ROI, 0..1
    xy: np.ndarray  # [39, 2] image pixels (33 body landmarks + 6 auxiliary)
    z: np.ndarray  # [39] relative depth, in crop pixels scaled to the image (smaller: nearer)
    visibility: np.ndarray  # [39] 0..1
    presence: np.ndarray  # [39] 0..1 (inside the crop and not missing)
    world: np.ndarray  # [33, 3] metres, hip-centred (the model's axes, rotated by the ROI)
    mask_crop: np.ndarray  # [256, 256] person probability in the crop


def refine_from_heatmap(
    xy_norm: np.ndarray, heatmap: np.ndarray, kernel: int = 7, min_confidence: float = 0.5
) -> np.ndarray:
    """Refine crop-normalised landmarks ``[L, 2]`` with heatmap logits ``[h, w, L]``."""
    h, w, L = heatmap.shape
    out = np.array(xy_norm, dtype=np.float64, copy=True)
    half = (kernel - 1) // 2
    for k in range(L):
        col, row = int(out[k, 0] * w), int(out[k, 1] * h)
        if not (0 <= col < w and 0 <= row < h):
            continue
        r0, r1, c0, c1 = max(0, row - half), min(h, row + half + 1), max(0, col - half), min(w, col + half + 1)
        conf = _sigmoid(heatmap[r0:r1, c0:c1, k].astype(np.float64))
        total = conf.sum()
        if total > 0 and conf.max() >= min_confidence:
            rows, cols = np.mgrid[r0:r1, c0:c1]
            out[k] = ((cols * conf).sum() / total / w, (rows * conf).sum() / total / h)
    return out


def _split_outputs(outputs: list) -> dict:
    """The landmark model's outputs by role, recognised by their shapes."""
    by = {}
    for t in outputs:
        n = t.size
        if t.ndim == 4 and t.shape[-1] == 1:
            by["segmentation"] = t.reshape(t.shape[1], t.shape[2])
        elif t.ndim == 4:
            by["heatmap"] = t.reshape(t.shape[1:])
        elif n == _NUM_ALL * 5:
            by["landmarks"] = t.reshape(_NUM_ALL, 5)
        elif n == _NUM_ALL * 3:
            by["world"] = t.reshape(_NUM_ALL, 3)
        elif n == 1:
            by["presence"] = float(t.reshape(()))
    missing = {"segmentation", "heatmap", "landmarks", "world", "presence"} - set(by)
    if missing:
        raise ValueError(f"landmark model outputs {[t.shape for t in outputs]}: cannot find {sorted(missing)}")
    return by


def run_landmark_model(image: np.ndarray, roi: ROI, refine: bool = True) -> RoiLandmarks:
    """Run the landmark model on ``roi`` of ``image`` (uint8 RGB ``[H, W, 3]``)."""
    model = load_model("pose_landmark_full")
    crop = warp_to_crop(image, roi, LANDMARK_INPUT).astype(np.float32) / 255.0
    out = _split_outputs(model(crop[None]))
    raw = out["landmarks"].astype(np.float64)
    xy_norm = raw[:, :2] / LANDMARK_INPUT
    if refine:
        xy_norm = refine_from_heatmap(xy_norm, out["heatmap"])
    xy = roi.crop_to_image(xy_norm)
    world = out["world"][:NUM_LANDMARKS].astype(np.float64)
    c, s = np.cos(roi.angle), np.sin(roi.angle)
    world[:, :2] = world[:, :2] @ np.array([[c, -s], [s, c]]).T
    return RoiLandmarks(
        roi=roi,
        presence_score=float(out["presence"]),
        xy=xy,
        z=raw[:, 2] * roi.size / LANDMARK_INPUT,
        visibility=_sigmoid(raw[:, 3]),
        presence=_sigmoid(raw[:, 4]),
        world=world,
        mask_crop=_sigmoid(out["segmentation"].astype(np.float64)).astype(np.float32),
    )


def roi_from_landmarks(lm: RoiLandmarks, scale: float = ROI_SCALE) -> ROI:
    """The next region, from the auxiliary hip-centre and full-body scale points."""
    return roi_from_alignment_points(lm.xy[_HIP_CENTRE], lm.xy[_SCALE_POINT], scale)


def mask_in_image(lm: RoiLandmarks, width: int, height: int) -> np.ndarray:
    """The person probability ``[H, W]`` (float32, 0..1) of the ROI's segmentation in the image."""
    return warp_from_crop(lm.mask_crop, lm.roi, width, height)
