"""Silhouette losses: distance transforms of the target mask (computed once, no gradient)
and a two-sided energy whose gradient flows through the rendered silhouette only.

``E(S) = [ sum(S * DT_out) + sum((1 - S) * DT_in) ] / area(mask)``

* ``DT_out``: for pixels outside the mask, Euclidean distance (pixels) to the mask;
  penalises rendered body where the person is not.
* ``DT_in``: for pixels inside the mask, distance to the background; penalises mask
  pixels the body does not cover, most strongly deep inside the person.

Both are exact Euclidean transforms from OpenCV (``DIST_MASK_PRECISE``); ``E = 0`` when
the rendered silhouette equals the mask.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["MaskTarget", "distance_transforms", "silhouette_energy", "soft_iou"]


def distance_transforms(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(DT_out, DT_in)`` float32 ``[H, W]`` of a boolean mask (see the module docstring)."""
    import cv2

    mask = np.asarray(mask, dtype=bool)
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return outside.astype(np.float32), inside.astype(np.float32)


@dataclass
class MaskTarget:
    """A target mask with its distance transforms, as tensors, croppable to a window."""

    mask: torch.Tensor  # [H, W] float (0/1)
    dt_out: torch.Tensor  # [H, W]
    dt_in: torch.Tensor  # [H, W]
    area: float

    @classmethod
    def from_mask(cls, mask: np.ndarray, device=None, dtype=torch.float32) -> "MaskTarget":
        dt_out, dt_in = distance_transforms(mask)
        as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
        return cls(as_t(np.asarray(mask, dtype=np.float32)), as_t(dt_out), as_t(dt_in), float(np.count_nonzero(mask)))

    def window(self, x0: int, y0: int, width: int, height: int) -> "MaskTarget":
        """The target restricted to pixels ``[x0, x0+width) x [y0, y0+height)``; pixels outside
        the image count as background (their outside distance measured to the mask)."""
        H, W = self.mask.shape
        if x0 >= 0 and y0 >= 0 and x0 + width <= W and y0 + height <= H:
            sl = (slice(y0, y0 + height), slice(x0, x0 + width))
            return MaskTarget(self.mask[sl], self.dt_out[sl], self.dt_in[sl], self.area)
        ys = torch.arange(y0, y0 + height, device=self.mask.device)
        xs = torch.arange(x0, x0 + width, device=self.mask.device)
        gy, gx = torch.meshgrid(ys, xs, indexing="ij")
        inside = (gy >= 0) & (gy < H) & (gx >= 0) & (gx < W)
        cy, cx = gy.clamp(0, H - 1), gx.clamp(0, W - 1)
        # Outside the image: distance to the mask >= distance to the nearest border pixel's value.
        extra = torch.sqrt(((gy - cy) ** 2 + (gx - cx) ** 2).to(self.dt_out.dtype))
        mask = torch.where(inside, self.mask[cy, cx], torch.zeros_like(self.mask[cy, cx]))
        dt_out = torch.where(inside, self.dt_out[cy, cx], self.dt_out[cy, cx] + extra)
        dt_in = torch.where(inside, self.dt_in[cy, cx], torch.zeros_like(extra))
        return MaskTarget(mask, dt_out, dt_in, self.area)


def silhouette_energy(silhouette: torch.Tensor, target: MaskTarget) -> torch.Tensor:
    """Two-sided distance-transform energy of ``silhouette [..., H, W]`` in [0, 1] against
    ``target``, normalised by the mask's area; one value per leading batch element."""
    over = (silhouette * target.dt_out).sum(dim=(-2, -1))
    under = ((1.0 - silhouette) * target.dt_in).sum(dim=(-2, -1))
    return (over + under) / max(target.area, 1.0)


def soft_iou(silhouette: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """IoU of a soft silhouette with a 0/1 mask: ``sum(min) / sum(max)``."""
    inter = torch.minimum(silhouette, mask).sum(dim=(-2, -1))
    union = torch.maximum(silhouette, mask).sum(dim=(-2, -1))
    return inter / union.clamp(min=1e-9)

