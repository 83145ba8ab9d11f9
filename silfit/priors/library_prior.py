"""Building the shipped default pose prior from silfit's own pose library.

No motion-capture data can be downloaded or shipped with silfit, so the default pose
prior (:class:`silfit.priors.pose.LibraryMixturePrior`, file ``priors/data/pose_mixture.npz``)
is a Gaussian mixture in SMPLify's form (best-component negative log-likelihood over
the 69 ``body_pose`` values) fitted to many samples drawn around the **hand-authored**
poses of :data:`silfit.poses.library.POSE_LIBRARY`:

* a library pose (uniform over the chosen names), mirrored left-right with probability
  ``mirror_prob``;
* with probability ``blend_prob`` blended per joint (geodesically) towards a second
  library pose *of the same name list* by a weight uniform in ``[0, max_blend]``;
* perturbed by Gaussian noise of ``perturb_deg`` degrees, scaled per joint (wider for
  shoulders/elbows/hips/knees, narrow for hands, feet and clavicles), and clamped into
  the joint limits.

The mixture is fitted with EM (k-means++ start, full covariances) and each covariance
gets ``reg_deg**2`` added to its diagonal (plus a shrinkage towards the pooled
covariance) so that poses unlike any library pose are penalised, not crushed.

Everything is deterministic from ``seed``; ``tools/build_pose_prior.py`` rebuilds the
shipped file and records the settings in it.

Circularity: silfit's synthetic data generator samples its poses from this same
library, so this prior fits the synthetic benchmark better than it will fit real
photos. ``benchmarks/bench_fit.py --holdout`` measures a prior built from half the
library on subjects posed only from the other half.
"""

from __future__ import annotations

import math
from typing import Dict, Optional, Sequence

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..poses.library import BODY_JOINTS, PERTURB_SCALE, POSE_LIBRARY, mirror_pose
from .limits import clamp_to_limits

__all__ = ["BUILD_DEFAULTS", "sample_library_poses", "fit_gaussian_mixture", "build_library_mixture", "split_library"]

#: Settings of the shipped ``pose_mixture.npz`` (``tools/build_pose_prior.py`` uses these).
BUILD_DEFAULTS = dict(
    n_samples=20000,
    components=12,
    seed=0,
    perturb_deg=10.0,
    blend_prob=0.7,
    max_blend=1.0,
    mirror_prob=0.5,
    reg_deg=6.0,
    shrink=0.05,
    em_iters=60,
)


def split_library(seed: int = 0):
    """A deterministic split of the library's pose names into two halves ``(a, b)``
    (for the held-out check). ``t_pose`` is always in ``a``."""
    names = [n for n in POSE_LIBRARY if n != "t_pose"]
    order = np.random.default_rng(seed).permutation(len(names))
    half = len(names) // 2
    a = ["t_pose"] + sorted(names[i] for i in order[:half])
    b = sorted(names[i] for i in order[half:])
    return a, b


def _slerp(a: np.ndarray, b: np.ndarray, w: float) -> np.ndarray:
    ra, rb = Rotation.from_rotvec(a.reshape(-1, 3)), Rotation.from_rotvec(b.reshape(-1, 3))
    return (ra * Rotation.from_rotvec((ra.inv() * rb).as_rotvec() * w)).as_rotvec().reshape(a.shape)


def sample_library_poses(
    n: int,
    seed: int = 0,
    names: Optional[Sequence[str]] = None,
    perturb_deg: float = 10.0,
    blend_prob: float = 0.7,
    max_blend: float = 1.0,
    mirror_prob: float = 0.5,
) -> np.ndarray:
    """``[n, 69]`` body poses sampled around the library poses ``names`` (default all);
    see the module docstring. Blend partners are drawn from ``names`` too."""

    names = list(POSE_LIBRARY) if names is None else list(names)
    unknown = [m for m in names if m not in POSE_LIBRARY]
    if unknown or not names:
        raise ValueError(f"unknown or no pose names: {unknown}")
    rng = np.random.default_rng(seed)
    sigma = np.repeat([PERTURB_SCALE[j] for j in BODY_JOINTS], 3) * math.radians(perturb_deg)
    out = np.empty((int(n), 69))
    for i in range(int(n)):
        pose = POSE_LIBRARY[names[rng.integers(len(names))]].body_pose.copy()
        if len(names) > 1 and rng.random() < blend_prob:
            other = POSE_LIBRARY[names[rng.integers(len(names))]].body_pose
            if rng.random() < mirror_prob:
                other = mirror_pose(other)
            pose = _slerp(pose, other, float(rng.uniform(0.0, max_blend)))
        if rng.random() < mirror_prob:
            pose = mirror_pose(pose)
        out[i] = pose + rng.normal(0.0, 1.0, 69) * sigma
    return clamp_to_limits(torch.as_tensor(out)).numpy()


def _component_logpdf(X, means, covars):
    K, D = means.shape
    out = np.empty((X.shape[0], K))
    for k in range(K):
        L = np.linalg.cholesky(covars[k])
        z = np.linalg.solve(L, (X - means[k]).T)
        out[:, k] = -0.5 * (z**2).sum(0) - np.log(np.diag(L)).sum() - 0.5 * D * math.log(2 * math.pi)
    return out


def fit_gaussian_mixture(
    X: np.ndarray,
    components: int,
    seed: int = 0,
    reg: float = 1e-2,
    shrink: float = 0.05,
    iters: int = 60,
    tol: float = 1e-6,
) -> Dict[str, np.ndarray]:
    """EM for a full-covariance Gaussian mixture (k-means++ start). Each M-step covariance
    is ``(1 - shrink) * S_k + shrink * S_pooled + reg * I``. Returns ``means [K, D]``,
    ``covars [K, D, D]``, ``weights [K]`` and the final mean log-likelihood ``loglik``."""
    X = np.asarray(X, dtype=np.float64)
    N, D = X.shape
    K = int(components)
    rng = np.random.default_rng(seed)
    # k-means++ seeding, then a few Lloyd steps.
    centres = [X[rng.integers(N)]]
    d2 = ((X - centres[0]) ** 2).sum(1)
    for _ in range(1, K):
        centres.append(X[rng.choice(N, p=d2 / d2.sum())])
        d2 = np.minimum(d2, ((X - centres[-1]) ** 2).sum(1))
    C = np.stack(centres)
    for _ in range(10):
        lab = ((X[:, None, :] - C[None]) ** 2).sum(-1).argmin(1)
        C = np.stack([X[lab == k].mean(0) if (lab == k).any() else C[k] for k in range(K)])
    pooled = np.cov(X.T)
    resp = np.eye(K)[lab]
    prev = -np.inf
    for _ in range(int(iters)):
        nk = resp.sum(0) + 1e-10
        weights = nk / N
        means = (resp.T @ X) / nk[:, None]
        covars = np.empty((K, D, D))
        for k in range(K):
            d = X - means[k]
            S = (resp[:, k, None] * d).T @ d / nk[k]
            covars[k] = (1 - shrink) * S + shrink * pooled + reg * np.eye(D)
        logp = _component_logpdf(X, means, covars) + np.log(weights)
        m = logp.max(1, keepdims=True)
        lse = m[:, 0] + np.log(np.exp(logp - m).sum(1))
        resp = np.exp(logp - lse[:, None])
        ll = float(lse.mean())
        if ll - prev < tol * abs(ll):
            break
        prev = ll
    return {"means": means, "covars": covars, "weights": weights, "loglik": np.float64(ll)}


def build_library_mixture(names: Optional[Sequence[str]] = None, **settings) -> Dict[str, np.ndarray]:
    """Sample the library (``names``, default all) and fit the mixture; returns the arrays
    of ``pose_mixture.npz`` (``means``, ``covars``, ``weights``, ``loglik`` and the settings)."""
    s = {**BUILD_DEFAULTS, **settings}
    unknown = set(s) - set(BUILD_DEFAULTS)
    if unknown:
        raise TypeError(f"unknown settings: {sorted(unknown)}")
    X = sample_library_poses(
        s["n_samples"], s["seed"], names, s["perturb_deg"], s["blend_prob"], s["max_blend"], s["mirror_prob"]
    )
    gmm = fit_gaussian_mixture(
        X, s["components"], seed=s["seed"], reg=math.radians(s["reg_deg"]) ** 2, shrink=s["shrink"], iters=s["em_iters"]
    )
    used = list(POSE_LIBRARY) if names is None else list(names)
    meta = {f"setting_{k}": np.float64(v) for k, v in s.items()}
    return {**gmm, **meta, "pose_names": np.array(used, dtype="U64")}
