"""Problems over frames and views: shared parameters, packing, one L-BFGS row per problem."""

import math

import numpy as np
import pytest
import torch

from silfit.camera import Camera
from silfit.fitting import KeypointFitConfig, KeypointFitter
from silfit.fitting.problem import Observation, ParameterLayout, Problem, View, world_to_camera
from silfit.fitting.stages import Stage, run_lbfgs_stage
from silfit.fitting.terms import evaluate
from silfit.io.keypoints import KeypointSet
from silfit.fitting.keypoint_stage import Starts

CAM = Camera.from_image_size(256, 256)


def test_pack_and_unpack_round_trip_with_shared_and_per_frame_parameters():
    layout = ParameterLayout({"betas": 2, "body_pose": 3, "transl": 3}, ("betas",), frames=4)
    state = layout.zeros(5)
    state["betas"] = torch.randn(5, 2, dtype=torch.float64)
    state["body_pose"] = torch.randn(5, 4, 3, dtype=torch.float64)
    x = layout.pack(state, ("betas", "body_pose"))
    assert x.shape == (5, 2 + 4 * 3)
    back = layout.unpack(x, ("betas", "body_pose"))
    assert torch.equal(back["betas"], state["betas"]) and torch.equal(back["body_pose"], state["body_pose"])
    rows = layout.rows(state)
    assert rows["betas"].shape == (20, 2) and torch.equal(rows["betas"][4:8], state["betas"][1].expand(4, 2))


def test_world_to_camera_applies_the_extrinsics():
    R = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    t = torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)
    p = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    assert world_to_camera(p, R, t).tolist() == [[0.0, 1.0, 2.0]]


def test_grid_refuses_holes_and_duplicates():
    with pytest.raises(ValueError, match="two observations"):
        Problem([Observation(View(CAM)), Observation(View(CAM))]).grid()
    with pytest.raises(ValueError, match="lacks"):
        Problem([Observation(View(CAM)), Observation(View(CAM), frame=1, view_index=1)]).grid()


def two_frame_problem(model, fitter):
    """One body (one shape) in two frames with different poses: noise-free keypoints."""
    torch.manual_seed(0)
    betas = torch.tensor([[1.0, -0.5] + [0.0] * 8])
    sets, poses = [], []
    for pose_scale in (0.0, 0.3):
        params = model.zero_params(1)
        params["betas"] = betas.to(model.dtype)
        params["global_orient"] = torch.tensor([[math.pi, 0.0, 0.0]], dtype=model.dtype)
        params["body_pose"] = torch.randn(1, 69, dtype=model.dtype) * 0.1 * pose_scale
        params["transl"] = torch.tensor([[0.0, 0.2, 3.0]], dtype=model.dtype)
        with torch.no_grad():
            kp = fitter.body(**params).keypoints[0]
        uv = torch.stack([CAM.fx * kp[:, 0] / kp[:, 2] + CAM.cx, CAM.fy * kp[:, 1] / kp[:, 2] + CAM.cy], 1)
        sets.append(KeypointSet(uv.numpy(), np.ones(25), "body25"))
        poses.append(params["body_pose"][0])
    obs = [Observation(View(CAM), ks, frame=f) for f, ks in enumerate(sets)]
    return Problem(obs), betas, torch.stack(poses)


def test_two_frames_share_one_shape_and_the_gradient_flows_through_it(open_model64):
    model64 = open_model64
    fitter = KeypointFitter(model64, config=KeypointFitConfig(starts=Starts(poses=1, flip=False)))
    problem, betas, poses = two_frame_problem(model64, fitter)
    data, views, state = fitter._problem_data([problem], (False,))
    layout = ParameterLayout(fitter.params.sizes, ("betas",), 2)
    assert state["betas"].shape == (1, 10) and state["body_pose"].shape == (1, 2, 69)
    weights = {"keypoints": 1.0, "shape": 1.0}
    state["betas"] = torch.full((1, 10), 0.1, dtype=torch.float64)

    def energy_of(b):
        st = dict(state, betas=b)
        return fitter.energy(evaluate(fitter.body, layout, st, views, data), weights)[0].sum()

    b = state["betas"].clone().requires_grad_(True)
    (g,) = torch.autograd.grad(energy_of(b), b)
    h = 1e-6
    for i in (0, 1, 5):  # central differences through the shared parameter (both frames)
        e = torch.zeros_like(b)
        e[0, i] = h
        fd = (energy_of(b.detach() + e) - energy_of(b.detach() - e)) / (2 * h)
        assert float(g[0, i]) == pytest.approx(float(fd), rel=1e-5, abs=1e-6)
    # Optimising the shape alone (the frames' poses, orientation and translation at the truth) finds
    # the one shape that fits both frames.
    state["body_pose"][0] = poses
    state["global_orient"][:] = torch.tensor([math.pi, 0.0, 0.0], dtype=torch.float64)
    state["transl"][:] = torch.tensor([0.0, 0.2, 3.0], dtype=torch.float64)
    stage = Stage("shape", ("betas",), {"keypoints": 1.0}, 40)
    run_lbfgs_stage(stage, state, layout, fitter.energy, fitter.body, views, data)
    assert state["betas"].shape == (1, 10)
    assert torch.allclose(state["betas"][0, :2], betas[0, :2].double(), atol=0.05), state["betas"]
