"""Priors for whole-body (SMPL-X-layout) fitting: the body priors on SMPL-X's 21-joint ``body_pose``,
a hand-pose prior, and the L2 priors on the jaw and the expression.

* SMPL-X's ``body_pose [63]`` is SMPL's ``body_pose [69]`` without SMPL's two hand joints (22, 23): a
  Gaussian-mixture pose prior over 69 values is *marginalised* to the first 63 (each component's mean
  and covariance block, the component weights recovered from its constants), other priors see the
  pose padded with zeros at those two joints (:func:`body_prior_for`, :func:`padded`).
* :class:`HandPosePrior`: a Gaussian over hand poses sampled around the hand-pose library
  (:mod:`silfit.synth.hands`: named poses perturbed within the finger limits), in the model's own hand
  parameter space: the PCA coefficients when the model takes hands as PCA coefficients (``use_pca``),
  else the 45 axis-angle values; energy ``0.5 (x - mu)^T S^-1 (x - mu)`` (0 at the library mean),
  ``S`` the samples' covariance plus ``floor_deg^2`` on the diagonal so no direction is infinitely stiff.
  Like the body's library prior it is circular with the synthetic data (the generator poses hands from
  the same library).
* :func:`l2`: ``|x|^2`` per row (jaw pose in radians, expression coefficients in their unit-variance space).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import torch
from torch import nn

from ..synth.hands import HAND_LIBRARY, hand_axes, hand_pose_to_axis_angle, sample_hand_pose
from . import spd
from .pose import MaxMixturePrior, quadratic_forms

__all__ = ["HandPosePrior", "body_prior_for", "l2", "padded"]

SMPL_BODY_POSE = 69


def l2(x: torch.Tensor) -> torch.Tensor:
    """``[B]``: ``|x|^2`` over the last axis."""
    return (x * x).sum(-1)


def padded(fn: Callable, width: int = SMPL_BODY_POSE) -> Callable:
    """``fn`` of SMPL's ``[B, 69]`` applied to a shorter ``body_pose`` padded with zeros (SMPL-X's 63)."""

    def wrapped(body_pose: torch.Tensor) -> torch.Tensor:
        if body_pose.shape[-1] >= width:
            return fn(body_pose)
        pad = body_pose.new_zeros(*body_pose.shape[:-1], width - body_pose.shape[-1])
        return fn(torch.cat([body_pose, pad], dim=-1))

    wrapped.__name__ = getattr(fn, "__name__", "prior")
    return wrapped


def marginal_mixture(prior: MaxMixturePrior, dim: int) -> MaxMixturePrior:
    """The mixture over the first ``dim`` values: component means and covariance blocks, weights
    recovered from the constants (``const_k = -log w_k + 0.5 log det S_k`` up to one offset)."""
    prec = prior.precisions.double().cpu().numpy()
    # BLAS-free, the same bits on every CPU (silfit.priors.spd; a prior's precisions are exactly symmetric);
    # log det S_k = -log det P_k
    cov, logdet_prec = spd.inverse_and_logdet(prec)
    logw = [-0.5 * float(ld) - float(c) for ld, c in zip(logdet_prec, prior.constants.double().cpu().numpy())]
    w = np.array([math.exp(x - max(logw)) for x in logw])
    out = MaxMixturePrior(
        prior.means.double()[:, :dim].cpu().numpy(),
        cov[:, :dim, :dim],
        w,
        source=f"{prior.source} (marginal over the first {dim} values)",
        dtype=prior.means.dtype,
    )
    return out


def body_prior_for(model, prior):
    """The pose prior for ``model``'s ``body_pose``: ``prior`` itself when the widths agree, its
    marginal for a mixture over SMPL's 69 values and SMPL-X's 63, else ``prior`` on the padded pose."""
    width = model.num_body_pose
    dim = getattr(prior, "dim", width)
    if dim == width:
        return prior
    if dim < width:
        raise ValueError(f"the pose prior is over {dim} values, the model's body_pose has {width}")
    if isinstance(prior, MaxMixturePrior):
        return marginal_mixture(prior, width)
    return padded(prior, dim)


def library_hand_poses(model, side: str, count: int = 800, seed: int = 0) -> np.ndarray:
    """``[count, 45]`` axis-angle hand poses (the model's parameter convention: its mean hand
    subtracted) sampled around the hand-pose library on ``model``'s rest hand."""
    with torch.no_grad():
        joints = model(**model.zero_params(1)).joints[0].double().cpu().numpy()
    axes = hand_axes(joints, model.joint_names, side)
    start = 75 if side == "left" else 120
    mean = model.pose_mean.double().cpu().numpy()[start : start + 45]
    rng = np.random.default_rng([seed, 0 if side == "left" else 1])
    out = np.empty((int(count), 45))
    for i in range(int(count)):
        _, flex, spread = sample_hand_pose(rng)
        out[i] = hand_pose_to_axis_angle(flex, spread, axes) - mean
    return out


class HandPosePrior(nn.Module):
    """``prior(hand_pose [B, w]) -> [B]`` for one hand (see the module docstring)."""

    def __init__(self, model, side: str, count: int = 800, floor_deg: float = 5.0, dtype=None):
        super().__init__()
        if side not in ("left", "right"):
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        poses = library_hand_poses(model, side, count)
        if getattr(model, "use_pca", False):
            comps = getattr(model, f"hand_components_{side[0]}").double().cpu().numpy()  # [k, 45], orthonormal rows
            poses = poses @ np.linalg.pinv(comps)
            self.space = f"{comps.shape[0]} hand PCA coefficients"
        else:
            self.space = "45 axis-angle values"
        mu = poses.mean(0)
        d = poses - mu  # the covariance as a sum of outer products in order, not np.cov's BLAS product
        cov = np.zeros((poses.shape[1], poses.shape[1]))
        for row in d:
            cov += row[:, None] * row[None, :]
        cov = cov / (poses.shape[0] - 1) + math.radians(floor_deg) ** 2 * np.eye(poses.shape[1])
        dtype = dtype or model.dtype
        self.side, self.dim = side, poses.shape[1]
        self.register_buffer("mean", torch.as_tensor(mu, dtype=dtype))
        self.register_buffer("precision", torch.as_tensor(spd.inverse(cov), dtype=dtype))

    def forward(self, hand_pose: torch.Tensor) -> torch.Tensor:
        if hand_pose.shape[-1] != self.dim:
            raise ValueError(f"{self.side} hand pose has {hand_pose.shape[-1]} values, the prior is over {self.dim}")
        d = hand_pose - self.mean.to(hand_pose.dtype)
        return 0.5 * quadratic_forms(d, self.precision.to(hand_pose.dtype))


def library_hand_set(model, side: str) -> torch.Tensor:
    """``[N, w]`` the hand-pose library's named poses (unperturbed) in ``model``'s hand parameter
    space (axis-angle minus the mean hand, or PCA coefficients with ``use_pca``)."""
    with torch.no_grad():
        joints = model(**model.zero_params(1)).joints[0].double().cpu().numpy()
    axes = hand_axes(joints, model.joint_names, side)
    start = 75 if side == "left" else 120
    mean = model.pose_mean.double().cpu().numpy()[start : start + 45]
    poses = np.stack([hand_pose_to_axis_angle(p.flex, p.spread, axes) - mean for p in HAND_LIBRARY.values()])
    if getattr(model, "use_pca", False):
        poses = poses @ np.linalg.pinv(getattr(model, f"hand_components_{side[0]}").double().cpu().numpy())
    return torch.as_tensor(poses, dtype=model.dtype)
