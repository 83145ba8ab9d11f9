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
    """A target mask with its distance transforms, as tensors."""

    mask: torch.Tensor  # [H, W] float (0/1)
    dt_out: torch.Tensor  # [H, W]
    dt_in: torch.Tensor  # [H, W]
    area: float

    @classmethod
    def from_mask(cls, mask: np.ndarray, device=None, dtype=torch.float32) -> "MaskTarget":
        dt_out, dt_in = distance_transforms(mask)
        as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
        return cls(as_t(np.asarray(mask, dtype=np.float32)), as_t(dt_out), as_t(dt_in), float(np.count_nonzero(mask)))


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

