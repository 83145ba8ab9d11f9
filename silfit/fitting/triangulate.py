"""Triangulation of 2D keypoints seen by calibrated views, and the body's placement from it.

Pure numpy functions:

* :func:`projection_matrices`: ``[C, 3, 4]`` matrices ``K [R | t]`` of views.
* :func:`dlt`: the confidence-weighted linear (DLT) triangulation of points seen by
  several views (each view's two equations scaled by its weight and by the inverse focal
  length, so pixel residuals of all views count alike).
* :func:`reprojection_errors`: pixel distance of 3D points' projections to the 2D points.
* :func:`robust_triangulate`: per keypoint, every pair of views that sees it proposes a
  point (exhaustive RANSAC over view pairs, at most 28 pairs for 8 views); the proposal
  with the most views reprojecting within a gate (a share of the person's extent in that
  view, at least ``min_gate_px``) wins, ties going to the smaller mean error, and its
  inliers are triangulated again together (confidence-weighted). One wrong view (a mislabelled keypoint, another person, a
  bad detection) is left out as long as two other views agree. With two views there is
  no majority: both are kept unless the point lands behind a camera.
* :func:`triangulate_views`: every keypoint of one frame seen by calibrated views
  (:class:`~silfit.fitting.problem.View`), by :func:`robust_triangulate`, with a weight per point.
* :func:`torso_placement`: the rotation and translation (no scale) taking the model's
  rest torso keypoints (shoulders, hips, neck, mid-hip) onto the triangulated ones
  (weighted Kabsch), as ``global_orient`` / ``transl`` for a body rotating about its
  pelvis joint.
"""

from __future__ import annotations

from itertools import combinations
from typing import Optional, Sequence, Tuple

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "dlt",
    "placement_to_world",
    "projection_matrices",
    "reprojection_errors",
    "robust_triangulate",
    "torso_placement",
    "kabsch",
    "triangulate_views",
]


def projection_matrices(intr: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``[C, 3, 4]`` from intrinsics ``[C, 4]`` (fx, fy, cx, cy), ``R [C, 3, 3]``, ``t [C, 3]``."""
    intr = np.asarray(intr, dtype=np.float64).reshape(-1, 4)
    K = np.zeros((len(intr), 3, 3))
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = intr[:, 0], intr[:, 1], intr[:, 2], intr[:, 3], 1.0
    Rt = np.concatenate([np.asarray(R, np.float64).reshape(-1, 3, 3), np.asarray(t, np.float64).reshape(-1, 3, 1)], 2)
    return K @ Rt


def dlt(P: np.ndarray, xy: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted DLT: ``P [C, 3, 4]``, ``xy [C, K, 2]`` pixels, ``weights [C, K]`` (0: not seen)
    -> points ``[K, 3]`` (NaN where fewer than two views have a positive weight)."""
    P = np.asarray(P, np.float64)
    xy = np.asarray(xy, np.float64)
    w = np.asarray(weights, np.float64)
    C, K = w.shape
    # Rows x * P3 - P1 and y * P3 - P2, divided by the focal length so they are in
    # (approximately) normalised image units: every view's pixel residual weighs the same.
    # The focal lengths come from M M^T = l^2 K K^T (M = P[:, :3] = l K R, zero skew), not from
    # P[0, 0] = l (fx R00 + cx R20), which depends on the camera's rotation (and can be 0).
    M = P[:, :, :3]
    S = M @ M.transpose(0, 2, 1)
    s22 = np.maximum(S[:, 2, 2], 1e-24)
    fx2 = S[:, 0, 0] / s22 - (S[:, 0, 2] / s22) ** 2
    fy2 = S[:, 1, 1] / s22 - (S[:, 1, 2] / s22) ** 2
    f = np.sqrt(s22) * np.sqrt(np.sqrt(np.clip(fx2, 0.0, None) * np.clip(fy2, 0.0, None)))
    r1 = xy[..., 0, None] * P[:, None, 2] - P[:, None, 0]  # [C, K, 4]
    r2 = xy[..., 1, None] * P[:, None, 2] - P[:, None, 1]
    scale = (w / np.maximum(f, 1e-12)[:, None])[..., None]
    A = np.concatenate([r1 * scale, r2 * scale], 0).transpose(1, 0, 2)  # [K, 2C, 4]
    A = np.nan_to_num(A)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1]
    out = X[:, :3] / np.where(np.abs(X[:, 3:]) < 1e-12, np.nan, X[:, 3:])
    out[(w > 0).sum(0) < 2] = np.nan
    return out


def reprojection_errors(P: np.ndarray, X: np.ndarray, xy: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """``(errors [C, K] px, depth [C, K])`` of points ``X [K, 3]`` projected by ``P [C, 3, 4]``
    against ``xy [C, K, 2]`` (infinite error for points behind a camera or NaN)."""
    Xh = np.concatenate([X, np.ones((len(X), 1))], 1)
    proj = np.einsum("cij,kj->cki", P, Xh)
    z = proj[..., 2]
    uv = proj[..., :2] / np.where(np.abs(z) < 1e-12, 1e-12, z)[..., None]
    err = np.linalg.norm(uv - xy, axis=-1)
    err = np.where((z > 0) & np.isfinite(err), err, np.inf)
    return err, z


def robust_triangulate(
    P: np.ndarray,
    xy: np.ndarray,
    conf: np.ndarray,
    gate: float = 0.05,
    min_gate_px: float = 8.0,
    extent: Optional[Sequence[float]] = None,
):
    """Triangulate each keypoint from the views that agree (see the module docstring).

    ``P [C, 3, 4]``, ``xy [C, K, 2]``, ``conf [C, K]`` (0: not seen); ``extent [C]`` is the
    person's size in each view in pixels (default: from the confident keypoints), the gate
    ``max(gate * extent, min_gate_px)``. Returns ``(X [K, 3] (NaN: not triangulated),
    inliers bool [C, K], errors [C, K] px)``."""
    xy = np.asarray(xy, np.float64)
    conf = np.where(np.isfinite(np.asarray(conf, np.float64)), np.asarray(conf, np.float64), 0.0).clip(min=0)
    C, K = conf.shape
    if extent is None:
        extent = []
        for c in range(C):
            pts = xy[c][conf[c] > 0]
            extent.append(float((pts.max(0) - pts.min(0)).max()) if len(pts) > 1 else 0.0)
    thr = np.maximum(gate * np.asarray(extent, np.float64), min_gate_px)[:, None]  # [C, 1]
    seen = conf > 0
    best_score = np.full(K, -1.0)
    inliers = np.zeros((C, K), bool)
    for a, b in combinations(range(C), 2):
        w = np.zeros_like(conf)
        w[[a, b]] = conf[[a, b]]
        X = dlt(P, xy, w)
        err, _ = reprojection_errors(P, X, xy)
        ok = seen & (err < thr)
        ok &= ok[a] & ok[b]  # the pair itself must agree (both in front, both within the gate)
        # most agreeing views first; among as many, the smallest mean error (in gates)
        mean_err = (np.where(ok, err, 0.0) / thr).sum(0) / np.maximum(ok.sum(0), 1)
        score = ok.sum(0) - 0.5 * np.clip(mean_err, 0.0, 1.0)
        better = score > best_score + 1e-12
        best_score = np.where(better, score, best_score)
        inliers[:, better] = ok[:, better]
    if C == 2:  # no majority: keep both views where the point is in front of both cameras
        X = dlt(P, xy, conf)
        _, z = reprojection_errors(P, X, xy)
        inliers = seen & (z > 0).all(0)[None]
    X = dlt(P, xy, conf * inliers)
    err, _ = reprojection_errors(P, X, xy)
    return X, inliers & np.isfinite(X).all(1)[None], err


def triangulate_views(views, xy: np.ndarray, conf: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """``(X [K, 3], w [K])``: keypoints ``xy [C, K, 2]`` (confidences ``conf [C, K]``) seen by
    ``views`` (``C`` :class:`~silfit.fitting.problem.View`, world frame) triangulated from the views
    that agree (:func:`robust_triangulate`), each weighted by its inlier views' confidences summed
    over the ``C`` views and divided by ``C`` (0, and ``X`` 0, where not triangulated)."""
    ext = [v.extrinsics() for v in views]
    P = projection_matrices(
        [[v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy] for v in views], [e[0] for e in ext], [e[1] for e in ext]
    )
    conf = np.asarray(conf, np.float64)
    X, inliers, _ = robust_triangulate(P, xy, conf)
    w = (np.where(np.isfinite(conf), conf, 0.0) * inliers).sum(0) / len(views)
    ok = np.isfinite(X).all(1) & (w > 0)
    return np.where(ok[:, None], X, 0.0), np.where(ok, w, 0.0)


def kabsch(src: np.ndarray, dst: np.ndarray, weights: Optional[np.ndarray] = None) -> Tuple[np.ndarray, np.ndarray]:
    """The rotation ``R`` and translation ``c`` minimising ``sum w |R src + c - dst|^2`` (no scale)."""
    w = np.ones(len(src)) if weights is None else np.asarray(weights, np.float64)
    w = w / w.sum()
    ms, md = w @ src, w @ dst
    H = ((src - ms) * w[:, None]).T @ (dst - md)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, md - R @ ms


def torso_placement(rest_points: np.ndarray, points: np.ndarray, weights: np.ndarray, pelvis: np.ndarray):
    """``(global_orient [3] axis-angle, transl [3])`` placing a body whose rest-pose keypoints
    are ``rest_points [N, 3]`` (pelvis joint ``pelvis [3]``) onto triangulated ``points [N, 3]``
    (``weights [N]``, 0 for points not triangulated). Needs three non-collinear points."""
    ok = (np.asarray(weights) > 0) & np.isfinite(points).all(1)
    if ok.sum() < 3:
        raise ValueError(f"only {int(ok.sum())} torso keypoint(s) triangulated (seen by two agreeing views); need 3")
    R, c = kabsch(rest_points[ok], points[ok], np.asarray(weights)[ok])
    # The model maps a rest point p to R (p - pelvis) + pelvis + transl; here R p + c.
    transl = c + R @ pelvis - pelvis
    return Rotation.from_matrix(R).as_rotvec(), transl


def placement_to_world(orient: np.ndarray, transl: np.ndarray, R: np.ndarray, t: np.ndarray, pelvis: np.ndarray):
    """A body placed in a camera's frame (``global_orient``, ``transl``) placed in the world
    frame of that camera's extrinsics ``R, t``: the model maps a rest point ``p`` to
    ``G (p - j) + j + transl`` (``j``: the shaped rest pelvis), so in the world ``R^T G``
    and ``R^T (j + transl - t) - j``."""
    G = Rotation.from_rotvec(np.asarray(orient, np.float64)).as_matrix()
    j = np.asarray(pelvis, np.float64)
    return Rotation.from_matrix(R.T @ G).as_rotvec(), R.T @ (j + np.asarray(transl, np.float64) - t) - j
