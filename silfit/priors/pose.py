"""Pose priors over SMPL's 69 ``body_pose`` values (global orientation excluded).

* :class:`MaxMixturePrior` reads SMPLify's Gaussian-mixture file (``gmm_08.pkl``: a
  pickled dict with ``means [K, 69]``, ``covars [K, 69, 69]``, ``weights [K]``, written
  by Python 2, so it is read with ``encoding='latin1'``) and scores a pose by the
  negative log-likelihood of its best component, as SMPLify does.
* :class:`LibraryMixturePrior` is the prior silfit ships and uses by default (no
  download): a :class:`MaxMixturePrior` read from ``priors/data/pose_mixture.npz``,
  fitted (by ``tools/build_pose_prior.py``, see :mod:`silfit.priors.library_prior`) to
  perturbed, mirrored and blended samples of silfit's **hand-authored** pose library
  (:data:`silfit.poses.library.POSE_LIBRARY`, 38 poses), not to motion capture. See its
  docstring for what that means for evaluation (the synthetic generator draws from the
  same library).
* :class:`LimitsPrior` (``load_pose_prior("limits")``, the default before the library
  mixture) needs no data at all. No motion-capture data
  can be shipped with the project, so it is **not learnt from data**: it is a
  hand-set "split normal" per axis-angle component, with its mode at the rest pose
  (zero) and a different spread on either side, chosen so that each component's
  anatomical limit (:mod:`silfit.priors.limits`) lies at ``limit_sigmas`` standard
  deviations. It therefore prefers small rotations, is much stiffer in directions
  where a joint barely moves (knee/elbow hyperextension, sideways knee bending) and
  knows nothing about correlations between joints (a mocap-trained GMM does).
  The hard part of the limits is enforced separately by
  :func:`silfit.priors.limits.limit_violation`.

Both return energies ``[B]`` that are zero at their best pose and differentiable.
"""

from __future__ import annotations

import math
import os
from typing import Union

import numpy as np
import torch
from torch import nn

from ..errors import InputError
from ..io.safe_pickle import load_npz, load_pickle
from . import spd
from .limits import limit_bounds

__all__ = [
    "MaxMixturePrior",
    "LibraryMixturePrior",
    "LimitsPrior",
    "load_pose_prior",
    "default_pose_prior",
    "DEFAULT_MIXTURE_PATH",
]

#: The shipped library mixture (built by ``tools/build_pose_prior.py``).
DEFAULT_MIXTURE_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "pose_mixture.npz")


def quadratic_forms(d: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """``d^T P d`` over the last axis: ``d [B, ..., D]``, ``P [..., D, D]`` -> ``[B, ...]``.

    A broadcast product and sums, not a GEMM: a row's value and gradient do not depend on the
    other rows of the batch, their number or its position (see :mod:`silfit.body.lbs`)."""
    return (d * (P * d[..., None, :]).sum(-1)).sum(-1)


def _check_pose(body_pose: torch.Tensor, dim: int) -> torch.Tensor:
    if body_pose.ndim == 1:
        body_pose = body_pose[None]
    if body_pose.ndim != 2 or body_pose.shape[1] != dim:
        raise ValueError(f"body_pose has shape {tuple(body_pose.shape)}, expected [B, {dim}]")
    return body_pose


class MaxMixturePrior(nn.Module):
    """SMPLify's pose prior: ``min_k [0.5 (x - mu_k)^T S_k^-1 (x - mu_k) - log w_k + 0.5 log det S_k]``
    minus the smallest constant over components (so the energy is 0 at the mean of the
    most probable component and ``>= 0`` everywhere)."""

    def __init__(self, means, covars, weights, source: str = "<arrays>", dtype=torch.float32):
        super().__init__()
        arrays = {}
        for name, value in (("means", means), ("covars", covars), ("weights", weights)):
            try:
                arrays[name] = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError, OverflowError) as err:
                raise InputError(source, f"field '{name}' is not a numeric array ({err})", field=name) from None
        means, covars, weights = arrays["means"], arrays["covars"], arrays["weights"].reshape(-1)
        if means.ndim != 2 or 0 in means.shape:
            raise InputError(source, f"field 'means' must be [K, D], got shape {means.shape}", field="means")
        K, D = means.shape
        if covars.shape != (K, D, D):
            raise InputError(source, f"field 'covars' has shape {covars.shape}, expected {(K, D, D)}", field="covars")
        if weights.shape != (K,):
            raise InputError(source, f"field 'weights' has shape {weights.shape}, expected ({K},)", field="weights")
        for name, arr in (("means", means), ("covars", covars), ("weights", weights)):
            if not np.isfinite(arr).all():
                raise InputError(source, f"field '{name}' holds NaN or infinite values", field=name)
        if (weights <= 0).any():
            raise InputError(source, "field 'weights' must be positive", field="weights")
        # BLAS-free (silfit.priors.spd): LAPACK's inverse followed numpy's OpenBLAS kernel, so the precisions,
        # and every fit they weigh, followed the CPU
        covars_t = np.transpose(covars, (0, 2, 1))
        if not np.allclose(covars, covars_t, rtol=1e-8, atol=1e-12 * max(float(np.abs(covars).max()), 1e-300)):
            raise InputError(source, "field 'covars' is not symmetric", field="covars")
        symmetric = 0.5 * (covars + covars_t)
        try:
            precisions, logdet = spd.inverse_and_logdet(symmetric)
        except np.linalg.LinAlgError:
            raise InputError(source, "field 'covars' is not positive definite", field="covars") from None
        total = math.fsum(float(w) for w in weights)
        const = np.array([-math.log(float(w) / total) for w in weights]) + 0.5 * logdet
        self.source = source
        self.num_components, self.dim = K, D
        self.register_buffer("means", torch.as_tensor(means, dtype=dtype))
        self.register_buffer("precisions", torch.as_tensor(precisions, dtype=dtype))
        self.register_buffer("constants", torch.as_tensor(const - const.min(), dtype=dtype))

    @classmethod
    def from_pickle(cls, path: Union[str, os.PathLike], dtype=torch.float32) -> "MaxMixturePrior":
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: pose prior file not found")
        data = load_pickle(path, what="a pose prior (gmm_08.pkl)")
        if not isinstance(data, dict):
            raise InputError(path, "expected a dict with fields means, covars, weights")
        missing = [k for k in ("means", "covars", "weights") if k not in data]
        if missing:
            raise InputError(path, f"field(s) missing: {', '.join(missing)}")
        return cls(data["means"], data["covars"], data["weights"], source=path, dtype=dtype)

    def component_energies(self, body_pose: torch.Tensor) -> torch.Tensor:
        """``[B, K]`` energy of each component."""
        x = _check_pose(body_pose, self.dim)
        # Evaluated in float64 whatever the input's dtype: with a sharp mixture and a large
        # prior weight, float32 rounding (which depends on the batch size) would otherwise
        # make a batched fit drift away from the same fit done one sample at a time.
        return _energies_and_products(x, self.means, self.precisions, self.constants)[0]

    def forward(self, body_pose: torch.Tensor) -> torch.Tensor:
        x = _check_pose(body_pose, self.dim)
        return _BestComponent.apply(x, self.means, self.precisions, self.constants)


def _energies_and_products(x: torch.Tensor, means, precisions, constants) -> tuple:
    """Each component's energy ``[B, K]`` (in ``x``'s dtype) and ``P_k (x - mu_k)`` ``[B, K, D]`` (float64):
    :func:`quadratic_forms`' products, kept for the gradient."""
    d = x.double()[:, None, :] - means.double()  # [B, K, D]
    Pd = (precisions.double() * d[..., None, :]).sum(-1)
    return (0.5 * (d * Pd).sum(-1) + constants.double()).to(x.dtype), Pd


class _BestComponent(torch.autograd.Function):
    """The best component's energy ``[B]`` (the values of ``component_energies(x).min(1)``, the
    same bits) with its gradient ``P_k (x - mu_k)`` taken from the forward's own product: the
    minimum's gradient is its component's alone, so the backward pass does not go through all
    ``K`` quadratic forms again (it was the keypoint stage's largest backward cost)."""

    @staticmethod
    def forward(ctx, x, means, precisions, constants):
        energies, Pd = _energies_and_products(x, means, precisions, constants)
        value, best = energies.min(dim=1)
        ctx.save_for_backward(Pd[torch.arange(len(best), device=best.device), best])
        ctx.dtype = x.dtype
        return value

    @staticmethod
    @torch.autograd.function.once_differentiable  # (a second derivative would need P_k itself: refused, not wrong)
    def backward(ctx, grad):
        # the mixture is a fixed prior (buffers): no gradient for its means, precisions or constants
        (Pd,) = ctx.saved_tensors
        return (grad.double()[:, None] * Pd).to(ctx.dtype), None, None, None


class LibraryMixturePrior(MaxMixturePrior):
    """silfit's default pose prior: SMPLify's best-component Gaussian-mixture NLL, with the
    mixture fitted to samples around silfit's own hand-authored pose library.

    **What it is and is not.** No motion-capture data could be used, so this is *not* a
    learnt model of how people move: it encodes the 38 library poses (standing, walking,
    running, sitting, squatting, kneeling, lunging, reaching, waving, pointing, throwing,
    kicking, jumping, lying, ...), their mirror images, blends between them and noise
    around them (about 10 degrees, more at shoulders/elbows/hips/knees), with a
    covariance floor of ``reg_deg`` (6 degrees) per component and shrinkage towards the
    pooled covariance so that poses outside the library cost more but are not forbidden.
    Its main job is to break the 2D depth ambiguity the way people usually stand: arms
    in front of the body rather than behind it, elbows and knees bent the natural way.

    **Circularity.** The synthetic data generator (:mod:`silfit.synth`) poses its
    subjects from the same library, so accuracy measured on synthetic data with this
    prior is optimistic: it is partly "recognising" the library. Expect a smaller gain
    on real photos, and worse fits for poses unlike any library pose (e.g. dance,
    acrobatics, sports-specific poses) than a mocap-trained prior would give.
    ``benchmarks/bench_fit.py --holdout`` measures the effect with a prior built from
    half the library on subjects posed from the other half. Users with SMPLify's
    ``gmm_08.pkl`` (CMU mocap) can pass it instead (``load_pose_prior(path)``).
    """

    @classmethod
    def from_npz(cls, path: Union[str, os.PathLike, None] = None, dtype=torch.float32) -> "LibraryMixturePrior":
        path = os.fspath(DEFAULT_MIXTURE_PATH if path is None else path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: pose prior file not found")
        data = load_npz(path, what="a pose prior")
        missing = [k for k in ("means", "covars", "weights") if k not in data]
        if missing:
            raise InputError(path, f"field(s) missing: {', '.join(missing)}")
        prior = cls(data["means"], data["covars"], data["weights"], source=path, dtype=dtype)
        try:
            prior.settings = {k[len("setting_") :]: float(v) for k, v in data.items() if k.startswith("setting_")}
            prior.pose_names = [str(n) for n in np.atleast_1d(data.get("pose_names", []))]
        except (TypeError, ValueError) as err:
            raise InputError(path, f"a 'setting_*' or 'pose_names' field is malformed ({err})") from None
        return prior


class LimitsPrior(nn.Module):
    """The data-free pose prior (the default before :class:`LibraryMixturePrior`; see the module docstring): energy
    ``0.5 * sum_i (x_i / s_i(x_i))^2`` with ``s_i = |limit_i| / limit_sigmas`` on the side
    of zero ``x_i`` lies on (limits closer than ``min_sigma * limit_sigmas`` to zero are
    treated as that far, so no direction is infinitely stiff)."""

    def __init__(self, limit_sigmas: float = 2.0, min_sigma: float = 0.05, dtype=torch.float32):
        super().__init__()
        lo, hi = limit_bounds(torch.float64)
        self.source = "silfit default (joint-limit split normal)"
        self.dim = 69
        self.register_buffer("sigma_neg", (lo.abs() / limit_sigmas).clamp(min=min_sigma).to(dtype))
        self.register_buffer("sigma_pos", (hi.abs() / limit_sigmas).clamp(min=min_sigma).to(dtype))

    def forward(self, body_pose: torch.Tensor) -> torch.Tensor:
        x = _check_pose(body_pose, self.dim)
        s = torch.where(x < 0, self.sigma_neg.to(x.dtype), self.sigma_pos.to(x.dtype))
        return 0.5 * ((x / s) ** 2).sum(-1)


def default_pose_prior(dtype=torch.float32) -> LibraryMixturePrior:
    """The shipped :class:`LibraryMixturePrior` (``priors/data/pose_mixture.npz``)."""
    return LibraryMixturePrior.from_npz(None, dtype=dtype)


def load_pose_prior(path: Union[str, os.PathLike, None] = None, dtype=torch.float32) -> nn.Module:
    """``None``, ``"default"`` or ``"library"``: the shipped :class:`LibraryMixturePrior`;
    ``"limits"``: the data-free :class:`LimitsPrior`; a path ending in ``.npz``: a mixture
    in the shipped file's layout (``means``, ``covars``, ``weights``; e.g. one rebuilt by
    ``tools/build_pose_prior.py``); any other path: a ``gmm_08.pkl``-style pickle."""
    if path is None or (isinstance(path, str) and path in ("default", "library")):
        return default_pose_prior(dtype)
    if isinstance(path, str) and path == "limits":
        return LimitsPrior(dtype=dtype)
    if os.fspath(path).endswith(".npz"):
        return LibraryMixturePrior.from_npz(path, dtype=dtype)
    return MaxMixturePrior.from_pickle(path, dtype=dtype)
