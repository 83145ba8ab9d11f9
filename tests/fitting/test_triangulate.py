"""Triangulation (confidence-weighted DLT, robust to one wrong view) and the torso placement."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from silfit.fitting.triangulate import (
    dlt,
    kabsch,
    placement_to_world,
    projection_matrices,
    reprojection_errors,
    robust_triangulate,
    torso_placement,
)
from silfit.io.rig import ring_layout


def rig(n, seed=0):
    rng = np.random.default_rng(seed)
    ext = ring_layout(n, 3.0, rng.uniform(-0.3, 1.0, n), start_deg=rng.uniform(0, 360))
    intr = np.stack(
        [rng.uniform(400, 700, n), rng.uniform(400, 700, n), rng.uniform(200, 300, n), rng.uniform(200, 300, n)], 1
    )
    return projection_matrices(intr, [e[0] for e in ext], [e[1] for e in ext])


def project(P, X):
    h = np.einsum("cij,kj->cki", P, np.c_[X, np.ones(len(X))])
    return h[..., :2] / h[..., 2:]


@pytest.mark.parametrize("views", [2, 3, 8])
def test_dlt_is_exact_on_noise_free_points(views):
    P = rig(views)
    X = np.random.default_rng(1).normal(0, 0.5, (25, 3))
    conf = np.random.default_rng(2).uniform(0.2, 1.0, (views, 25))
    assert np.abs(dlt(P, project(P, X), conf) - X).max() < 1e-9
    Y, inliers, err = robust_triangulate(P, project(P, X), conf)
    assert np.abs(Y - X).max() < 1e-9 and inliers.all() and err.max() < 1e-6


def test_dlt_weighs_views_independently_of_the_world_frame():
    # Rotating the world (every camera's R by the same Q) rotates the noisy DLT solution by Q:
    # the per-view normalisation must use the focal length, not P[0, 0] (which mixes in R).
    rng = np.random.default_rng(5)
    ext = ring_layout(3, 3.0, [0.0, 0.4, 0.8], start_deg=20.0)
    intr = np.array([[1000.0, 1000.0, 500.0, 400.0]] * 3)
    R = np.stack([e[0] for e in ext])
    t = np.stack([e[1] for e in ext])
    X = rng.normal(0, 0.3, (40, 3))
    P = projection_matrices(intr, R, t)
    xy = project(P, X) + rng.normal(0, 3.0, (3, 40, 2))
    conf = rng.uniform(0.3, 1.0, (3, 40))
    for angle in (30.0, 63.43494882292201, 120.0):  # 63.43 deg: P[0, 0] = fx R00 + cx R20 = 0 for one view
        Q = Rotation.from_euler("y", angle, degrees=True).as_matrix()
        Y = dlt(projection_matrices(intr, R @ Q.T, t), xy, conf)
        assert np.abs(Y - dlt(P, xy, conf) @ Q.T).max() < 1e-6


def test_points_seen_by_one_view_are_not_triangulated():
    P = rig(3)
    X = np.zeros((2, 3))
    conf = np.array([[1.0, 1.0], [0.0, 1.0], [0.0, 0.0]])
    Y = dlt(P, project(P, X), conf)
    assert np.isnan(Y[0]).all() and np.abs(Y[1]).max() < 1e-9


@pytest.mark.parametrize("views, bad", [(3, 0), (4, 2), (8, 5)])
def test_robust_to_one_corrupted_view(views, bad):
    rng = np.random.default_rng(views)
    P = rig(views, seed=views)
    X = rng.normal(0, 0.4, (25, 3))
    xy = project(P, X)
    xy[bad] += rng.uniform(60, 150, (25, 2)) * rng.choice([-1, 1], (25, 2))  # e.g. another person's keypoints
    conf = np.ones((views, 25))
    plain = dlt(P, xy, conf)
    Y, inliers, _ = robust_triangulate(P, xy, conf)
    assert np.abs(plain - X).max() > 0.02  # the plain DLT is pulled away by the wrong view...
    assert np.abs(Y - X).max() < 1e-6  # ...the robust one leaves it out
    assert not inliers[bad].any() and inliers[np.arange(views) != bad].all()


def test_reprojection_errors_flag_points_behind_a_camera():
    P = rig(2)
    X = np.zeros((1, 3))
    err, z = reprojection_errors(P, X, project(P, X))
    assert (z > 0).all() and err.max() < 1e-9
    far = -10 * (P[0, 2, :3] / np.linalg.norm(P[0, 2, :3]))  # behind camera 0 (it looks at the origin)
    err, _ = reprojection_errors(P, far[None], project(P, X))
    assert np.isinf(err[0, 0])


def test_kabsch_recovers_a_rigid_motion():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(6, 3))
    R = Rotation.from_rotvec([0.3, -2.0, 0.5]).as_matrix()
    R_fit, c = kabsch(src, src @ R.T + [1.0, 2.0, 3.0], rng.uniform(0.5, 1, 6))
    assert np.allclose(R_fit, R) and np.allclose(c, [1.0, 2.0, 3.0])


def test_torso_placement_and_world_placement_match_the_model(body_model):
    from silfit.fitting.keypoint_stage import KeypointFitter

    fitter = KeypointFitter(body_model)
    orient = Rotation.from_rotvec([0.0, 2.2, 0.0]) * Rotation.from_rotvec([np.pi, 0, 0])
    params = body_model.zero_params(1)
    params["global_orient"] = torch.tensor(orient.as_rotvec()[None], dtype=body_model.dtype)
    params["transl"] = torch.tensor([[0.3, -0.2, 1.5]], dtype=body_model.dtype)
    with torch.no_grad():
        kp = fitter.body(**params).keypoints[0].double().numpy()
    idx = [1, 2, 5, 8, 9, 12]  # neck, shoulders, mid-hip, hips (BODY_25)
    go, tr = torso_placement(fitter.rest_keypoints[idx], kp[idx], np.ones(6), fitter.rest_pelvis)
    # compared by the geodesic angle between the rotations: this one turns by about pi, where the
    # axis-angle vector of a rotation and its numerically identical twin point opposite ways
    assert rotation_angle(go, orient) < 1e-6 and np.allclose(tr, [0.3, -0.2, 1.5], atol=1e-6)
    with pytest.raises(ValueError, match="need 3"):
        torso_placement(fitter.rest_keypoints[idx], kp[idx], np.array([1, 1, 0, 0, 0, 0.0]), fitter.rest_pelvis)
    # The same body placed in a camera's frame, moved to the world: the model's world keypoints.
    R, t = Rotation.from_rotvec([0.2, 0.9, -0.1]).as_matrix(), np.array([0.1, 0.0, 3.0])
    cam_orient = (Rotation.from_matrix(R) * orient).as_rotvec()
    with torch.no_grad():
        pelvis = body_model(**body_model.zero_params(1)).joints[0, 0].double().numpy()
    cam_tr = R @ (pelvis + np.array([0.3, -0.2, 1.5])) + t - pelvis
    w_orient, w_tr = placement_to_world(cam_orient, cam_tr, R, t, pelvis)
    assert rotation_angle(w_orient, orient) < 1e-9 and np.allclose(w_tr, [0.3, -0.2, 1.5], atol=1e-9)


def rotation_angle(rotvec, rotation: Rotation) -> float:
    """Geodesic angle (radians) between the rotation of an axis-angle vector and ``rotation``."""
    return float((Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)) * rotation.inv()).magnitude())


def confident_and_doubtful_views(jitter=None):
    """Three views (256 px) of 25 points; view 0's points are 5 px off (below the robust gate of
    8 px, so not rejected as outliers) and have confidence 0.1, the other two views are exact.
    ``jitter`` (a seed): a further 1e-9 px perturbation of every point (to measure the margins)."""
    rng = np.random.default_rng(7)
    ext = ring_layout(3, 3.0, [0.0, 0.4, 0.8], start_deg=20.0)
    P = projection_matrices(np.array([[500.0, 500.0, 128.0, 128.0]] * 3), [e[0] for e in ext], [e[1] for e in ext])
    X = rng.normal(0, 0.3, (25, 3))
    xy = project(P, X)
    off = rng.normal(0, 1, (25, 2))
    xy[0] += 5.0 * off / np.linalg.norm(off, axis=1, keepdims=True)
    if jitter is not None:
        xy = xy + np.random.default_rng(jitter).normal(0, 1e-9, xy.shape)
    conf = np.ones((3, 25))
    conf[0] = 0.1
    return P, X, xy, conf


def test_dlt_trusts_the_confident_views():
    """A view whose points are a few pixels off (too little for the robust gate) and which its
    detector doubts (confidence 0.1) must barely move the triangulated points: the DLT weighs each
    view's equations by its confidence. Weighting every view alike would put them 16 mm off."""
    P, X, xy, conf = confident_and_doubtful_views()
    mm = lambda Y: np.linalg.norm(Y - X, axis=1) * 1000  # noqa: E731
    weighted, alike = mm(dlt(P, xy, conf)), mm(dlt(P, xy, (conf > 0).astype(float)))
    Y, inliers, _ = robust_triangulate(P, xy, conf)
    assert inliers.all()  # the doubtful view is within the gate: kept, so only its weight helps
    # measured: weighted mean 0.41 mm (max 0.89), the same with 1e-9 px jitter (3 seeds) and under
    # ATEN_CPU_CAPABILITY=default and SILFIT_KERNELS=native; views weighted alike: mean 16.0 mm (max 24.1)
    assert weighted.mean() < 2.0 and weighted.max() < 4.0, weighted
    assert mm(Y).mean() < 2.0, mm(Y)  # the robust triangulation's final DLT weighs the same way
    assert alike.mean() > 8.0  # the case needs the weights (it would catch a DLT ignoring them)
    assert weighted.mean() < 0.1 * alike.mean()
