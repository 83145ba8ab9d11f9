"""Rig fitting: one body seen by calibrated views, recovered in world coordinates."""
from dataclasses import replace

import numpy as np
import pytest

from silfit.eval.metrics import pve, shape_pve
from silfit.fitting.keypoint_stage import KeypointFitConfig, KeypointFitter
from silfit.fitting.problem import Problem, View
from silfit.fitting.rig_fit import fit_rig_keypoints, rig_problem
from silfit.rig import load_rig, look_at
from silfit.synth.generate import SynthConfig
from silfit.synth.camera_rigs import RigConfig, generate_rig_subject

FAST = KeypointFitConfig(camera_iters=20, pose_iters=(20, 20, 30), shape_iters=10, final_iters=20, init_poses=2)


@pytest.fixture(scope="module")
def two_views(body_model, tmp_path_factory):
    d = tmp_path_factory.mktemp("rig2")
    generate_rig_subject(body_model, 0, SynthConfig(seed=1, size=128, noise_px=0.0, clean=1), RigConfig(views=2), d)
    return d, {k: v for k, v in np.load(d / "gt.npz").items()}


def test_two_view_noise_free_subject_is_recovered_in_world_coordinates(body_model, two_views):
    d, gt = two_views
    views = load_rig(d)
    R0, _ = views[0].view.extrinsics()
    assert not np.allclose(R0, np.eye(3))  # the world is not a camera's frame
    fit = fit_rig_keypoints(KeypointFitter(body_model, config=FAST), [rig_problem(views)])[0]
    # Tolerances (noise-free keypoints, two cameras about 90 degrees apart, the fast schedule):
    # every view reprojects within 1 px; the mesh, with no alignment at all, within 25 mm of
    # the truth on average; the pelvis within 20 mm; the shape (T-posed PVE) within 20 mm.
    assert fit.reprojection_error.max() < 1.0, fit.reprojection_error
    assert 1000 * pve(fit.vertices, gt["vertices"], align=False) < 25.0
    assert 1000 * np.linalg.norm(fit.joints[0] - gt["joints"][0]) < 20.0
    assert 1000 * shape_pve(body_model, fit.params["betas"], gt["betas"]) < 20.0


def test_one_view_rig_is_placed_in_the_world(body_model, two_views):
    # One view (no triangulation): fitted as an image in its camera frame, then moved to the
    # world by the extrinsics, so it reprojects as well there as a single-image fit does.
    d, gt = two_views
    views = load_rig(d)[1:]
    fit = fit_rig_keypoints(KeypointFitter(body_model, config=FAST), [rig_problem(views)])[0]
    assert fit.reprojection_error[0] < 1.5
    assert fit.keypoints_2d.shape == (1, 25, 2)


def test_moving_the_world_frame_moves_the_fit_with_it(body_model, two_views):
    # Moving the whole rig (world frame) by a rigid motion moves the fit by the same motion
    # (the energy is invariant; the optimiser's path is not exactly, hence millimetres).
    d, _ = two_views
    problem = rig_problem(load_rig(d))
    Rw, tw = look_at([0.4, -0.2, -1.0], [0.0, 0.3, 0.5])  # world' = Rw world + tw
    moved = Problem([replace(o, view=View(o.view.camera, o.view.extrinsics()[0] @ Rw.T,
                                          o.view.extrinsics()[1] - o.view.extrinsics()[0] @ Rw.T @ tw))
                     for o in problem.observations])  # fmt: skip
    fitter = KeypointFitter(body_model, config=FAST)
    a, b = fit_rig_keypoints(fitter, [problem, moved])
    err = np.linalg.norm(a.vertices @ Rw.T + tw - b.vertices, axis=1)
    assert err.mean() < 0.006 and err.max() < 0.03


def test_the_points_start_poses_the_body_onto_its_triangulated_keypoints(body_model, two_views):
    # Two views fix every keypoint in 3D: the start the schedule runs from has the limbs where
    # the views put them (measured: keypoints 20 mm from the truth on average, noise-free, 128 px
    # views), where the placed rest pose is 114 mm off.
    import torch

    from silfit.fitting.rig_fit import camera_to_world, in_first_camera, pose_from_points, triangulated_keypoints

    d, gt = two_views
    problem = rig_problem(load_rig(d))
    fitter = KeypointFitter(body_model, config=FAST)
    X, w = triangulated_keypoints(problem, fitter.kp_weights.double().numpy())
    seen = w > 0
    assert seen.sum() >= 20 and np.abs(X[seen] - gt["keypoints_3d"][seen]).max() < 0.02  # world frame, noise-free
    run = [in_first_camera(problem)]
    _, _, state = fitter._problem_data(run, (False,))
    rows = {n: v[:, 0] if v.dim() == 3 else v for n, v in state.items()}
    start = dict(rows, **pose_from_points(fitter, run, state))

    def error(r):
        with torch.no_grad():
            kp = fitter.body(**camera_to_world(fitter.model, r, [problem.observations[0].view])).keypoints[0].numpy()
        return 1000 * np.linalg.norm(kp - gt["keypoints_3d"], axis=-1)[seen].mean()

    assert error(start) < 35.0 and error(rows) > 80.0, (error(start), error(rows))
