"""Rotated square regions of interest and the affine maps between an image and a crop.

Coordinates here are silfit's pixel coordinates (pixel centres on integers, the
top-left pixel's centre is ``(0, 0)``). A crop of ``S x S`` pixels samples the square of
side ``size`` centred on ``(cx, cy)`` and rotated by ``angle`` (radians; positive turns
the crop's "up" towards the image's right, i.e. clockwise on screen, as MediaPipe's
``NormalizedRect.rotation``). Crop-normalised coordinates ``(a, b)`` in ``[0, 1]`` run
over the crop's pixel *edges*, as the models' outputs do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["ROI", "roi_from_alignment_points", "normalize_angle", "warp_to_crop", "warp_from_crop"]


def normalize_angle(angle: float) -> float:
    """``angle`` wrapped into ``[-pi, pi)``."""
    return angle - 2.0 * math.pi * math.floor((angle + math.pi) / (2.0 * math.pi))


@dataclass(frozen=True)
class ROI:
    """A rotated square region: centre ``(cx, cy)`` and side ``size`` in pixels, ``angle`` in radians."""

    cx: float
    cy: float
    size: float
    angle: float = 0.0

    def rotation(self) -> np.ndarray:
        c, s = math.cos(self.angle), math.sin(self.angle)
        return np.array([[c, -s], [s, c]])

    def crop_to_image(self, normalized: np.ndarray) -> np.ndarray:
        """Crop-normalised points ``[N, 2]`` (edges at 0 and 1) -> image pixel coordinates."""
        d = (np.asarray(normalized, dtype=np.float64) - 0.5) * self.size
        return d @ self.rotation().T + np.array([self.cx, self.cy])

    def image_to_crop(self, points: np.ndarray) -> np.ndarray:
        """Image pixel coordinates ``[N, 2]`` -> crop-normalised points (inverse of :meth:`crop_to_image`)."""
        d = np.asarray(points, dtype=np.float64) - np.array([self.cx, self.cy])
        return d @ self.rotation() / self.size + 0.5

    def crop_matrix(self, out_size: int) -> np.ndarray:
        """``2 x 3`` affine map from crop pixel indices (centres ``0..S-1``) to image pixels."""
        S = float(out_size)
        A = self.rotation() * (self.size / S)
        # Crop pixel q has normalised centre (q + 0.5) / S.
        t = np.array([self.cx, self.cy]) + self.rotation() @ np.full(2, (0.5 / S - 0.5) * self.size)
        return np.concatenate([A, t[:, None]], axis=1)

    def corners(self) -> np.ndarray:
        """The four corners ``[4, 2]`` in image pixels (top-left, top-right, bottom-right, bottom-left of the crop)."""
        return self.crop_to_image(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))

    def scaled(self, factor: float) -> "ROI":
        return ROI(self.cx, self.cy, self.size * float(factor), self.angle)

    def to_dict(self) -> dict:
        return {
            "cx": round(self.cx, 3),
            "cy": round(self.cy, 3),
            "size": round(self.size, 3),
            "angle_deg": round(math.degrees(self.angle), 3),
        }


def roi_from_alignment_points(center: np.ndarray, scale_point: np.ndarray, scale: float = 1.25) -> ROI:
    """MediaPipe's alignment-points rectangle: centred on ``center``, side twice the distance
    to ``scale_point`` times ``scale``, rotated so the centre -> scale-point vector points up
    in the crop (the body's hip centre -> head direction, for the pose models)."""
    (x0, y0), (x1, y1) = np.asarray(center, dtype=np.float64), np.asarray(scale_point, dtype=np.float64)
    size = 2.0 * math.hypot(x1 - x0, y1 - y0) * float(scale)
    angle = normalize_angle(math.pi / 2 - math.atan2(-(y1 - y0), x1 - x0))
    return ROI(float(x0), float(y0), float(size), float(angle))


def warp_to_crop(image: np.ndarray, roi: ROI, out_size: int) -> np.ndarray:
    """Sample the ``out_size`` square crop of ``roi`` from ``image [H, W, C]`` (bilinear,
    zero outside the image). Large reductions are area-filtered first, to avoid aliasing."""
    img = np.asarray(image)
    H, W = img.shape[:2]
    reduction = roi.size / float(out_size)
    sx = sy = 1.0
    if reduction > 2.0:
        w, h = max(1, int(round(W / reduction))), max(1, int(round(H / reduction)))
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        sx, sy = w / W, h / H
    M = roi.crop_matrix(out_size)
    # Map image pixel centres of the full image to those of the reduced one.
    S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5]])
    M = S[:, :2] @ M
    M[:, 2] += S[:, 2]
    return cv2.warpAffine(
        img,
        M,
        (int(out_size), int(out_size)),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )


def warp_from_crop(crop: np.ndarray, roi: ROI, width: int, height: int) -> np.ndarray:
    """Put a square crop (e.g. a ``[S, S]`` probability map) back into an image of
    ``width x height`` pixels; zero where the crop does not reach."""
    S = crop.shape[0]
    M = roi.crop_matrix(S)
    return cv2.warpAffine(
        np.ascontiguousarray(crop, dtype=np.float32),
        M,
        (int(width), int(height)),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
