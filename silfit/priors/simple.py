"""Small priors: SMPLify's knee/elbow angle prior and the L2 shape prior."""

from __future__ import annotations

import torch

__all__ = ["ANGLE_PRIOR_INDICES", "ANGLE_PRIOR_SIGNS", "angle_prior", "shape_prior"]

#: ``body_pose`` indices of left elbow y, right elbow y, left knee x, right knee x
#: (SMPLify's 55, 58, 12, 15 of the 72-vector, minus the 3 of the global orientation).
ANGLE_PRIOR_INDICES = (52, 55, 9, 12)
#: Signs making ``exp(sign * value)`` large only when the joint bends the wrong way
#: (left elbow +y, right elbow -y, knees -x are hyperextension).
ANGLE_PRIOR_SIGNS = (1.0, -1.0, -1.0, -1.0)


def angle_prior(body_pose: torch.Tensor) -> torch.Tensor:
    """``[B]``: ``sum exp(sign * theta)^2`` over elbows and knees (SMPLify / SPIN)."""
    idx = torch.as_tensor(ANGLE_PRIOR_INDICES, device=body_pose.device)
    signs = torch.as_tensor(ANGLE_PRIOR_SIGNS, dtype=body_pose.dtype, device=body_pose.device)
    return torch.exp(body_pose[:, idx] * signs).pow(2).sum(-1)


def shape_prior(betas: torch.Tensor) -> torch.Tensor:
    """``[B]``: ``|betas|^2`` (unit-variance shape space, so this is the Gaussian's NLL x2)."""
    return (betas * betas).sum(-1)
