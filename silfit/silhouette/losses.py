"""Silhouette losses: distance transforms of the target mask (computed once, no gradient)
and a two-sided energy whose gradient flows through the rendered silhouette only.

``E(S) = [ sum(S * DT_out) + sum((1 - S) * DT_in) ] / area(mask)``

* ``DT_out``: for pixels outside the mask, Euclidean distance (pixels) to the mask;
  penalises rendered body where the person is not.
* ``DT_in``: for pixels inside the mask, distance to the background; penalises mask
  pixels the body does not cover, most strongly deep inside the person.

Both are exact Euclidean transforms from OpenCV (``DIST_MASK_PRECISE``, without IPP: the same
mask gives the same distances whatever its buffer's address); ``E = 0`` when the rendered
silhouette equals the mask.

**Truncation.** Where a target has a ``valid`` map (the pixels inside the image; a silhouette
window may reach beyond the image's border), what lies outside the image is unknown, not
background: ``DT_out`` is 0 there (a body that continues beyond the border costs nothing for
the part outside), ``DT_in`` measures the distance to the *visible* background only (the
border where the mask is cut is not the body's edge), the outline points of the cover term
leave out the cut (:func:`contour_points` with ``valid``), and the IoU counts the image's
pixels only.

The contour surrogate (no rendering; the silhouette stage's coarse level) compares points
instead of pixels, in the same pixel units:

* :func:`outside_distance_energy`: projected body vertices against ``DT_out`` (bilinear):
  every vertex of a body that matches the mask projects inside it;
* :func:`cover_energy`: the mask's contour points (:func:`contour_points`) against the
  nearest projected vertex: every part of the mask's outline has body next to it.

Both are means of squared pixel distances (smooth at zero, so a quasi-Newton method can
use them); neither needs the body's own outline, so no visibility is computed.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch

__all__ = [
    "MaskTarget", "contour_points", "cover_energy", "distance_transforms", "outside_distance_energy",
    "silhouette_energy", "soft_iou",
]  # fmt: skip


def distance_transforms(mask: np.ndarray, valid=None) -> tuple[np.ndarray, np.ndarray]:
    """``(DT_out, DT_in)`` float32 ``[H, W]`` of a boolean mask (see the module docstring);
    ``valid`` (bool ``[H, W]``, default everywhere): the pixels that were seen (the image)."""
    import cv2

    mask = np.asarray(mask, dtype=bool)
    unseen = np.zeros_like(mask) if valid is None else ~np.asarray(valid, dtype=bool)
    # OpenCV's IPP path of the precise transform rounds by the input buffer's address (1-2 ulp:
    # the same mask gave other distances, and fits other results, from one process to the next);
    # its own implementation does not. The switch is per thread (OpenCV keeps it thread-local).
    use_ipp = cv2.ipp.useIPP()
    cv2.ipp.setUseIPP(False)
    try:
        outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        inside = cv2.distanceTransform((mask | unseen).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    finally:
        cv2.ipp.setUseIPP(use_ipp)
    outside[unseen] = 0.0  # unknown: a body there costs nothing
    inside[~mask] = 0.0
    return outside.astype(np.float32), inside.astype(np.float32)


@dataclass
class MaskTarget:
    """A target mask with its distance transforms, as tensors."""

    mask: torch.Tensor  # [H, W] float (0/1)
    dt_out: torch.Tensor  # [H, W]
    dt_in: torch.Tensor  # [H, W]
    area: float
    #: [H, W] float (0/1): the pixels inside the image (``None``: all of them)
    valid: Optional[torch.Tensor] = None

    @classmethod
    def from_mask(cls, mask: np.ndarray, device=None, dtype=torch.float32, valid=None) -> "MaskTarget":
        """``valid``: bool ``[H, W]``, the pixels inside the image (module docstring: truncation)."""
        dt_out, dt_in = distance_transforms(mask, valid)
        as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
        seen = None if valid is None else as_t(np.asarray(valid, dtype=np.float32))
        return cls(as_t(np.asarray(mask, dtype=np.float32)), as_t(dt_out), as_t(dt_in), float(np.count_nonzero(mask)), seen)


def silhouette_energy(silhouette: torch.Tensor, target: MaskTarget) -> torch.Tensor:
    """Two-sided distance-transform energy of ``silhouette [..., H, W]`` in [0, 1] against
    ``target``, normalised by the mask's area; one value per leading batch element."""
    over = (silhouette * target.dt_out).sum(dim=(-2, -1))
    under = ((1.0 - silhouette) * target.dt_in).sum(dim=(-2, -1))
    return (over + under) / max(target.area, 1.0)


def soft_iou(silhouette: torch.Tensor, mask: torch.Tensor, valid: Optional[torch.Tensor] = None) -> torch.Tensor:
    """IoU of a soft silhouette with a 0/1 mask: ``sum(min) / sum(max)``, over the ``valid``
    pixels only when given (the image's: what lies beyond it is unknown)."""
    if valid is not None:
        silhouette = silhouette * valid
    inter = torch.minimum(silhouette, mask).sum(dim=(-2, -1))
    union = torch.maximum(silhouette, mask).sum(dim=(-2, -1))
    return inter / union.clamp(min=1e-9)



def contour_points(mask: np.ndarray, count: int, valid=None) -> np.ndarray:
    """Up to ``count`` points ``[B, 2]`` (x, y pixel centres, float64) spread evenly along the
    outlines of a boolean mask (outer outlines and holes, OpenCV's contour order; the
    same mask gives the same points). With ``valid`` (bool ``[H, W]``: the image's pixels)
    the outline where the mask is cut by the image's border is left out: it is not the body's."""
    import cv2

    if int(count) <= 0:
        raise ValueError(f"contour point count must be positive, got {count}")
    m = np.asarray(mask, dtype=bool)
    seen = None if valid is None else np.asarray(valid, dtype=bool)
    if seen is not None:
        m = m | ~seen  # the unseen region joins the mask: no outline along the cut
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.int64)
    if seen is not None:  # keep outline points in the image whose 3x3 neighbourhood is all seen
        near = cv2.erode(seen.astype(np.uint8), np.ones((3, 3), np.uint8), borderValue=0).astype(bool)
        pts = pts[near[pts[:, 1], pts[:, 0]]]
    pts = pts.astype(np.float64)
    if len(pts) > count:
        pts = pts[np.linspace(0, len(pts) - 1, int(count)).round().astype(np.int64)]
    return pts


def _bilinear(image: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """``image [H, W]`` at points ``uv [N, 2]`` (x, y on pixel centres), bilinear; points
    outside the image take the border's value plus their distance to the image."""
    H, W = image.shape
    x = uv[:, 0].clamp(0, W - 1)
    y = uv[:, 1].clamp(0, H - 1)
    beyond = (uv[:, 0] - x).abs() + (uv[:, 1] - y).abs()
    x0 = x.detach().floor().clamp(max=W - 2).long() if W > 1 else torch.zeros_like(x, dtype=torch.long)
    y0 = y.detach().floor().clamp(max=H - 2).long() if H > 1 else torch.zeros_like(y, dtype=torch.long)
    fx, fy = x - x0.to(x.dtype), y - y0.to(y.dtype)
    x1, y1 = (x0 + 1).clamp(max=W - 1), (y0 + 1).clamp(max=H - 1)
    img = image.to(uv.dtype)
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy + beyond


def outside_distance_energy(uv: torch.Tensor, dt_out: torch.Tensor) -> torch.Tensor:
    """Mean squared distance (pixels) from the projected points ``uv [N, 2]`` to the mask
    whose outside distance transform is ``dt_out [H, W]`` (0 inside the mask)."""
    return _bilinear(dt_out, uv).square().mean()


def cover_energy(uv: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Mean over the mask's contour ``points [B, 2]`` of the squared distance (pixels) to the
    nearest projected point ``uv [N, 2]`` (the gradient reaches each point's nearest one)."""
    if points.shape[0] == 0:
        return uv.new_zeros(())
    pts = points.to(uv.dtype)
    with torch.no_grad():  # the nearest point of each contour point: |p|^2 - 2 p.u + |u|^2 (one product)
        u = uv.detach()
        nearest = torch.addmm((u * u).sum(-1)[None, :], pts, u.T, alpha=-2.0).argmin(dim=1)  # [B]
    return (pts - uv[nearest]).square().sum(-1).mean()
