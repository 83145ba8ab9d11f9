"""Pure loss functions of the keypoint stage."""

from __future__ import annotations

import torch

__all__ = ["gmof", "reprojection_energy"]


def gmof(residual: torch.Tensor, sigma: float) -> torch.Tensor:
    """Geman-McClure robust penalty of residual vectors ``[..., 2]`` (SMPLify's GMoF):
    ``sigma^2 * r^2 / (sigma^2 + r^2)`` per point (``~ r^2`` for ``r << sigma``, bounded by
    ``sigma^2`` for outliers). Returns ``[...]``."""
    sq = (residual * residual).sum(-1)
    s2 = float(sigma) ** 2
    return s2 * sq / (s2 + sq)


def reprojection_energy(
    projected: torch.Tensor,
    target: torch.Tensor,
    weights: torch.Tensor,
    scale: torch.Tensor,
    sigma: float | None = 100.0,
) -> torch.Tensor:
    """Per-sample data term ``[B]``: ``sum_k w_k * rho(scale * (projected_k - target_k))``.

    ``projected, target [B, K, 2]`` pixels, ``weights [B, K]`` (confidence x per-keypoint
    weight), ``scale [B]`` converts pixels to normalised pixels. ``sigma=None`` gives the
    plain L2 term (for comparisons)."""
    res = (projected - target) * scale[:, None, None]
    rho = (res * res).sum(-1) if sigma is None else gmof(res, sigma)
    return (weights * rho).sum(-1)
