"""Sequence fitting: bridging, consistent facings, one shape, and recovery of a short motion."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from silfit.camera import Camera, project_points
from silfit.eval.metrics import acceleration_error, pa_mpjpe
from silfit.fitting import KeypointFitConfig
from silfit.fitting.sequence import (
    SequenceFitConfig,
    _fits_from,
    _merge_windows,
    _neighbour_sources,
    _refit_from_offsets,
    _windows,
    body_forward,
    branch_path,
    consistent_facings,
    fit_sequence,
    interpolate_frames,
    keypoint_outliers,
    pose_distances,
    viterbi,
)
from silfit.io.keypoints import KeypointSet, model_keypoints
from silfit.synth.motion import motion_trajectory
from silfit.fitting.keypoint_stage import BranchSearch, Starts
from silfit.fitting.sequence import BranchChoice

CAM = Camera.from_image_size(256, 256)


def test_keypoint_outliers_flag_a_jump_but_not_smooth_motion():
    F, K = 5, 4
    xy = np.stack([np.stack([np.full(K, 100.0 + 3 * f), 50.0 + 40 * np.arange(K)], 1) for f in range(F)])
    conf = np.ones((F, K))
    assert not keypoint_outliers(xy, conf).any()  # steady motion of 3 px per frame
    xy[2, 1] += 60.0  # a 60 px jump: 0.5 of the 120 px extent
    out = keypoint_outliers(xy, conf, jump=0.2)
    assert out.sum() == 1 and out[2, 1]
    conf[1, 1] = 0.0  # a neighbour missing: no judgement
    assert not keypoint_outliers(xy, conf)[2, 1]


def test_interpolate_frames_slerps_rotations_and_holds_the_ends():
    orient = np.zeros((5, 3))
    orient[1] = [0.0, 0.4, 0.0]
    orient[3] = [0.0, 1.2, 0.0]
    transl = np.arange(15, dtype=float).reshape(5, 3)
    known = np.array([False, True, False, True, False])
    out = interpolate_frames({"global_orient": orient, "transl": transl}, known)
    assert out["global_orient"][2] == pytest.approx([0.0, 0.8, 0.0])
    assert out["global_orient"][0] == pytest.approx(orient[1]) and out["global_orient"][4] == pytest.approx(orient[3])
    assert out["transl"][2] == pytest.approx(0.5 * (transl[1] + transl[3]))
    assert out["transl"][1] == pytest.approx(transl[1])


def test_consistent_facings_flag_the_fewest_flipped_frames_and_allow_a_slow_turn():
    yaw = np.radians(np.linspace(0, 150, 12))  # a slow turn: no jump
    orient = np.stack(
        [(Rotation.from_rotvec([math.pi, 0, 0]) * Rotation.from_rotvec([0, y, 0])).as_rotvec() for y in yaw]
    )
    valid = np.ones(12, dtype=bool)
    assert not consistent_facings(body_forward(orient), valid).any()
    flipped = orient.copy()
    for f in (4, 5):  # two frames fitted facing the other way
        flipped[f] = (Rotation.from_rotvec(orient[f]) * Rotation.from_rotvec([0, math.pi, 0])).as_rotvec()
    assert np.flatnonzero(consistent_facings(body_forward(flipped), valid)).tolist() == [4, 5]
    valid[5] = False  # an invalid frame is neither judged nor a neighbour
    assert np.flatnonzero(consistent_facings(body_forward(flipped), valid)).tolist() == [4]


def test_viterbi_pays_a_frames_own_cost_to_stay_continuous_and_not_beyond():
    switch = np.array([[0.0, 10.0], [10.0, 0.0]])  # changing label between steps costs 10
    unary = [np.array([0.0, 5.0]), np.array([3.0, 0.0]), np.array([3.0, 0.0]), np.array([0.0, 5.0])]
    assert viterbi(unary, [None] + [switch] * 3).tolist() == [0, 0, 0, 0]  # two frames at 3 each < two switches
    cheap = np.array([[0.0, 1.0], [1.0, 0.0]])
    assert viterbi(unary, [None] + [cheap] * 3).tolist() == [0, 1, 1, 0]  # switching is cheaper than 3
    assert viterbi([np.array([1.0, 1.0, 0.5])], [None]).tolist() == [2]
    assert viterbi([np.array([1.0, 1.0])] * 2, [None, np.zeros((2, 2))]).tolist() == [0, 0]  # ties: the lower label
    assert viterbi([], []).tolist() == []
    ragged = viterbi([np.array([0.0]), np.array([2.0, 0.0, 1.0])], [None, np.array([[0.0, 5.0, 0.0]])])
    assert ragged.tolist() == [0, 2]  # 1 + 0 beats 2 + 0 and 0 + 5


def test_branch_path_prefers_the_continuous_branch_over_a_slightly_lower_energy():
    rng = np.random.default_rng(0)
    base = rng.normal(size=(24, 3)) * 0.3
    flipped = base.copy()
    flipped[1:4, 2] += 0.4  # a limb mirrored in depth: 0.4 m at 3 of 24 joints
    assert pose_distances(base[None], np.stack([base, flipped]))[0] == pytest.approx([0.0, 0.05])
    assert pose_distances(base[None], (base + 5.0)[None])[0, 0] == pytest.approx(0.0)  # relative to the root
    joints = [np.stack([base, flipped])] * 5
    energies = [np.array([100.0, 300.0])] * 2 + [np.array([100.0, 95.0])] + [np.array([100.0, 300.0])] * 2
    gaps = [1] * 5
    assert branch_path(energies, joints, gaps).tolist() == [0] * 5  # 5 % lower energy against two jumps of 2.5: stay
    assert branch_path(energies, joints, gaps, temporal_weight=0.0).tolist() == [0, 0, 1, 0, 0]
    energies[2] = np.array([800.0, 95.0])  # the continuous branch 7 typical frames worse: take the other
    assert branch_path(energies, joints, gaps).tolist() == [0, 0, 1, 0, 0]
    energies[2] = np.array([np.nan, 95.0])  # a failed candidate is never taken
    assert branch_path(energies, joints, gaps).tolist() == [0, 0, 1, 0, 0]
    # a wider gap between frames allows more motion
    two = [
        np.array([100.0, 300.0]),
        np.array([150.0, 95.0]),
    ]  # the second frame: 0.55 typical energies lower on the other
    assert branch_path(two, joints[:2], [1, 1]).tolist() == [0, 0]  # a jump of 2.5
    assert branch_path(two, joints[:2], [1, 10]).tolist() == [0, 1]  # 10 frames apart: 0.25


def test_windows_cover_the_sequence_and_merge_from_their_middles():
    assert _windows(10, 0, 2) == [0] and _windows(10, 20, 2) == [0]
    starts = _windows(25, 10, 4)
    assert starts[0] == 0 and starts[-1] == 15 and all(b - a <= 6 for a, b in zip(starts, starts[1:]))
    v = np.stack([np.full((10, 1), p, dtype=float) for p in range(len(starts))])
    owner = _merge_windows({"x": v}, starts, 25)["x"][:, 0].astype(int)
    assert owner[0] == 0 and owner[-1] == len(starts) - 1
    for f in range(25):  # each frame comes from a window that holds it
        s = starts[owner[f]]
        assert s <= f < s + 10


def motion_keypoints(model, F=8, params=False):
    """A noise-free walk seen from the front-left, BODY_25 projections, and the truth (``params``: and
    its parameters ``{name: [F, w]}``)."""
    traj = motion_trajectory("walk", F, 30.0)
    pose = torch.as_tensor(traj["body_pose"], dtype=model.dtype)
    betas = torch.tensor([[0.8, -0.6] + [0.0] * 8], dtype=model.dtype).expand(F, 10)
    orient = torch.as_tensor(
        (Rotation.from_rotvec([math.pi, 0, 0]) * Rotation.from_rotvec([0, 0.5, 0])).as_rotvec(), dtype=model.dtype
    )
    transl = torch.stack([torch.linspace(-0.1, 0.1, F), torch.full((F,), 0.2), torch.full((F,), 3.2)], 1).to(
        model.dtype
    )
    with torch.no_grad():
        out = model(betas=betas, body_pose=pose, global_orient=orient.expand(F, 3), transl=transl)
        uv = project_points(model_keypoints(model, out, "body25").double(), CAM).numpy()
    sets = [KeypointSet(uv[f], np.ones(25), "body25") for f in range(F)]
    if params:
        truth = {"betas": betas, "body_pose": pose, "global_orient": orient.expand(F, 3), "transl": transl}
        return sets, out.joints.double().numpy(), {k: v.double().clone() for k, v in truth.items()}
    return sets, out.joints.double().numpy(), betas[0].numpy()


FAST_INIT = KeypointFitConfig(
    camera_iters=15,
    pose_iters=(15, 15, 15),
    shape_iters=8,
    final_iters=15,
    starts=Starts(poses=1),
    branches=BranchSearch(search=False),
)


def test_a_dropped_frame_is_bridged_and_the_sequence_has_one_shape(open_model):
    sets, joints, betas = motion_keypoints(open_model)
    sets[3] = None  # no detection in frame 3
    torso_only = sets[5].conf.copy()
    torso_only[:] = 0.0
    torso_only[[1, 2]] = 1.0  # neck and a shoulder only: too few torso points
    sets[5] = KeypointSet(sets[5].xy, torso_only, "body25")
    cfg = SequenceFitConfig(keypoint=FAST_INIT, iterations=60)
    r = fit_sequence(sets, CAM, open_model, config=cfg)
    assert r.betas.shape == (10,) and r.body_pose.shape == (8, 69) and r.transl.shape == (8, 3)
    assert r.bridged.tolist() == [False, False, False, True, False, True, False, False]
    assert np.isnan(r.reprojection_error[3]) and np.isfinite(r.reprojection_error[0])
    err = pa_mpjpe(r.joints, joints) * 1000  # mm per frame
    assert err[3] < 40.0 and err[5] < 40.0, err  # the bridged frames' poses follow their neighbours
    assert err.mean() < 35.0, err
    # the bridged frame lies near its neighbours' midpoint (true motion there: about 5 mm off it)
    mid = 0.5 * (r.joints[2] + r.joints[4]) - 0.5 * (r.joints[2, :1] + r.joints[4, :1])
    assert np.linalg.norm((r.joints[3] - r.joints[3, :1]) - mid, axis=-1).mean() < 0.02
    # the joint refinement is smoother than the per-frame fits, against the truth
    with torch.no_grad():
        pf = open_model(
            **{k: torch.as_tensor(v, dtype=open_model.dtype) for k, v in r.per_frame.items()}
        ).joints.numpy()
    assert acceleration_error(r.joints, joints) < acceleration_error(pf, joints)


def test_branch_choice_over_time_fits_the_walk_and_records_its_changes(open_model):
    sets, joints, _ = motion_keypoints(open_model, F=6)
    fast = replace(FAST_INIT, branches=replace(FAST_INIT.branches, search=True, iters=8, screen_iters=4))
    cfg = SequenceFitConfig(keypoint=fast, iterations=40, branch_choice=BranchChoice(dp=True, hypotheses=2))
    r = fit_sequence(sets, CAM, open_model, config=cfg)
    assert r.rebranched.shape == (6,) and r.rebranched.dtype == bool
    assert r.config["branch_dp"] is True
    err = pa_mpjpe(r.joints, joints) * 1000
    assert err.mean() < 35.0 and err.max() < 60.0, err
    assert any("depth branch" in w for w in r.warnings) == bool(r.rebranched.any())


def test_neighbour_sources_are_the_frames_at_the_offsets_inside_the_sequence():
    assert _neighbour_sources(5, 20, (1, 2, 4)) == [4, 6, 3, 7, 1, 9]
    assert _neighbour_sources(0, 20, (1, 2, 4)) == [1, 2, 4]
    assert _neighbour_sources(18, 20, (1, 2, 4)) == [17, 19, 16, 14]
    assert _neighbour_sources(1, 3, (1, 2, 4)) == [0, 2]
    assert _neighbour_sources(0, 1, (1, 2, 4)) == []
    assert _neighbour_sources(2, 5, (1, 1)) == [1, 3]  # each source once
    assert _neighbour_sources(2, 5, ()) == [] and _neighbour_sources(2, 5, None) == []


def test_offsets_round_recovers_a_wrong_pick_and_never_raises_an_energy(open_model):
    """Each frame's pick is its fit from the truth, but frame 2's from its pose negated (a wrong branch):
    refitted from the picks 1, 2 and 4 frames away, frame 2 is recovered, and no frame's energy rises (each
    keeps its pick unless a refit is lower). No offsets: no round."""
    from silfit.fitting.keypoint_stage import KeypointFitter
    from silfit.fitting.problem import Problem

    F = 4
    cheap = replace(FAST_INIT, camera_iters=10, pose_iters=(10, 10, 10), final_iters=10)
    sets, joints, truth = motion_keypoints(open_model, F=F, params=True)
    truth["body_pose"][2] = -truth["body_pose"][2]
    fitter = KeypointFitter(open_model, "body25", cheap)
    probs = [Problem.single(s, CAM) for s in sets]
    state, energy = _fits_from(open_model, "body25", cheap, fitter, probs, truth, np.arange(F), np.arange(F), False)
    picks = {k: v.double().reshape(F, -1) for k, v in state.items()}
    energy = energy.double()

    def errors(params):
        with torch.no_grad():
            out = fitter.body(**{k: v.to(fitter.dtype) for k, v in params.items()}).joints.double().numpy()
        return pa_mpjpe(out, joints) * 1000

    before = errors(picks)
    assert before[2] > 80.0, before  # the wrong branch is wrong
    kept, kept_energy = _refit_from_offsets(open_model, "body25", cheap, fitter, probs, picks, energy, (1, 2, 4), False)
    assert np.all(kept_energy.numpy() <= energy.numpy() * (1 + 1e-6)), (energy, kept_energy)
    after = errors(kept)
    assert after[2] < 40.0 and after.max() < 40.0, (before, after)
    same, same_energy = _refit_from_offsets(open_model, "body25", cheap, fitter, probs, picks, energy, (), False)
    assert torch.equal(same_energy, energy) and all(torch.equal(same[k], picks[k]) for k in picks)


def test_fit_sequence_refuses_a_sequence_without_usable_frames(open_model):
    with pytest.raises(ValueError, match="no frame"):
        fit_sequence([None, None], CAM, open_model)


def test_windowed_refinement_keeps_one_shape(open_model):
    sets, joints, _ = motion_keypoints(open_model)
    cfg = SequenceFitConfig(keypoint=FAST_INIT, iterations=40, window=5, overlap=2, window_pose_iterations=20)
    r = fit_sequence(sets, CAM, open_model, config=cfg)
    assert r.betas.shape == (10,) and r.body_pose.shape == (8, 69)
    err = pa_mpjpe(r.joints, joints) * 1000
    assert err.mean() < 35.0 and err.max() < 60.0, err


def temporal_smoothness(model, temporal=True, jitter=None):
    """The 8-frame walk of :func:`motion_keypoints` with 3 px Gaussian noise on every keypoint,
    fitted with :data:`FAST_INIT` and 60 refinement steps (the temporal terms at their default
    weights, or off); ``(acceleration error of the fit, of its per-frame start (mm), mean PA-MPJPE
    of the fit (mm))``. ``jitter`` (a seed): a further 1e-9 px perturbation, to measure margins."""
    sets, joints, _ = motion_keypoints(model)
    rng = np.random.default_rng(0)
    noisy = [KeypointSet(s.xy + rng.normal(0, 3.0, s.xy.shape), s.conf, "body25") for s in sets]
    if jitter is not None:
        rng = np.random.default_rng(1000 + jitter)
        noisy = [KeypointSet(s.xy + rng.normal(0, 1e-9, s.xy.shape), s.conf, "body25") for s in noisy]
    cfg = SequenceFitConfig(keypoint=FAST_INIT, iterations=60)
    if not temporal:
        cfg = replace(cfg, joint_smooth_weight=0.0, root_smooth_weight=0.0)
    r = fit_sequence(noisy, CAM, model, config=cfg)
    with torch.no_grad():
        start = model(**{k: torch.as_tensor(v, dtype=model.dtype) for k, v in r.per_frame.items()}).joints.numpy()
    mm = 1000.0
    return (
        acceleration_error(r.joints, joints) * mm,
        acceleration_error(start, joints) * mm,
        pa_mpjpe(r.joints, joints).mean() * mm,
    )


def test_temporal_terms_smooth_a_noisy_sequence(open_model):
    """On noisy keypoints the joint refinement's temporal terms make the motion far smoother than
    its per-frame start, and than the same refinement without them."""
    acc, acc_start, _ = temporal_smoothness(open_model)
    acc_off, _, _ = temporal_smoothness(open_model, temporal=False)
    # measured (acceleration error, mm): fit 12.3, per-frame start 131, fit without the temporal terms 113;
    # with 1e-9 px jitter (3 seeds): 13.0-16.5, 112-133, 99-116; ATEN_CPU_CAPABILITY=default: 12.7, 128, 111;
    # SILFIT_KERNELS=native: 13.1, 131, 113 (worst ratio to the start 0.15, to the fit without the terms 0.17)
    assert acc < 30.0, (acc, acc_start, acc_off)
    assert acc < 0.3 * acc_start and acc < 0.3 * acc_off, (acc, acc_start, acc_off)


def test_a_rig_video_is_fitted_over_frames_and_views_in_the_world_frame(open_model, tmp_path):
    """A rig video (``fit_sequence`` given the rig's views, ``frames[f][c]``): each frame starts from the rig's
    keypoint stage, the refinement sees every view; the fit is in the rig's world frame (no alignment), a
    view missing in a frame leaves it fitted from the other view, a frame missing in every view is bridged."""
    from silfit.fitting.sequence import refine_sequence_silhouettes
    from silfit.io.video import load_rig_sequence
    from silfit.silhouette.masks import read_mask
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.synth.motion import SequenceConfig, generate_sequence_dataset

    generate_sequence_dataset(
        tmp_path,
        1,
        SequenceConfig(seed=5, frames=4, size=96, noise_px=0.0, motions=("walk",)),
        model=open_model,
        views=2,
    )
    seq = load_rig_sequence(tmp_path / "seq_000")
    gt = np.load(tmp_path / "seq_000" / "gt.npz")
    frames = [list(row) for row in seq.frames]
    frames[1][0] = None  # view_0 saw nobody in frame 1
    frames[2] = [None, None]  # nobody saw frame 2
    views = [v.view for v in seq.views]
    r = fit_sequence(frames, views, open_model, config=SequenceFitConfig(keypoint=FAST_INIT, iterations=30))
    assert r.views is not None and r.keypoints_2d.shape == (4, 2, 25, 2) and r.reprojection_error.shape == (4, 2)
    assert r.bridged.tolist() == [False, False, True, False] and r.betas.shape == (10,)
    assert np.isnan(r.reprojection_error[1, 0]) and np.isfinite(r.reprojection_error[1, 1])
    assert np.nanmax(r.reprojection_error) < 3.0, r.reprojection_error
    err = 1000 * np.linalg.norm(r.joints - gt["joints"], axis=-1).mean(-1)  # mm per frame, world frame, no alignment
    assert err.max() < 40.0 and err[[0, 1, 3]].mean() < 25.0, err
    masks = [[read_mask(p) for p in row] for row in zip(*(seq.per_view(c, "masks") for c in range(2)))]
    s = refine_sequence_silhouettes(
        open_model, r, frames, masks, config=SilhouetteFitConfig(resolutions=(32,), iterations=(2,))
    )
    assert s.silhouette_iou.shape == (4, 2) and s.keypoints_2d.shape == (4, 2, 25, 2) and s.views is r.views
    assert np.nanmax(s.reprojection_error) < 4.0
