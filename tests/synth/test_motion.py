"""Synthetic motions: smooth per-frame truth, OpenPose per-frame files, determinism."""

import json

import numpy as np
import pytest

from silfit.camera import load_camera, project_points
from silfit.io.keypoints import read_keypoints
from silfit.synth.motion import MOTIONS, SequenceConfig, frame_stem, generate_sequence_dataset, motion_trajectory


@pytest.mark.parametrize("name", list(MOTIONS))
def test_motions_are_smooth_cycles(name):
    m = MOTIONS[name]
    fps = 30.0
    period_frames = int(round(m.period * fps))
    traj = motion_trajectory(name, 3 * period_frames, fps)
    pose = traj["body_pose"]
    assert pose.shape == (3 * period_frames, 69)
    # periodic: one period later the pose repeats (to the rounding of the period to frames)
    assert np.abs(pose[period_frames] - pose[0]).max() < 0.15
    # smooth: the second difference per frame stays far below the poses' range
    acc = np.abs(np.diff(pose, 2, axis=0)).max()
    assert acc < 0.05 * max(np.ptp(pose, axis=0).max(), 0.1) + 0.01
    with pytest.raises(ValueError, match="unknown motion"):
        motion_trajectory("jog", 10, fps)


def test_sequence_dataset_truth_matches_its_files(tmp_path, open_model):
    cfg = SequenceConfig(seed=4, frames=6, size=64, noise_px=0.0, drop_frames=0.0, motions=("squat",), orbit_deg=20.0)
    index = generate_sequence_dataset(tmp_path / "d", 1, cfg, model=open_model)
    seq = tmp_path / "d" / "seq_000"
    assert index["format"] == "silfit-synthetic-sequence" and index["sequences"][0]["motion"] == "squat"
    gt = np.load(seq / "gt.npz")
    cam = load_camera(seq / "camera.json")
    import torch

    proj = project_points(torch.as_tensor(gt["keypoints_3d"], dtype=torch.float64), cam).numpy()
    assert np.abs(proj - gt["keypoints_2d_clean"]).max() < 1e-3
    for f in range(6):
        ks = read_keypoints(seq / "keypoints" / f"{frame_stem('seq_000', f)}_keypoints.json")
        ok = ks.conf > 0
        assert ok.sum() >= 10
        assert np.abs(ks.xy[ok] - gt["keypoints_2d_clean"][f][ok]).max() < 1e-3  # noise-free
        assert (seq / "masks" / f"{frame_stem('seq_000', f)}.png").is_file()
    # the same seed gives the same sequence
    generate_sequence_dataset(tmp_path / "e", 1, cfg, model=open_model)
    again = np.load(tmp_path / "e" / "seq_000" / "gt.npz")
    assert np.array_equal(gt["body_pose"], again["body_pose"]) and np.array_equal(gt["transl"], again["transl"])


def test_dropped_frames_have_no_person(tmp_path, open_model):
    cfg = SequenceConfig(seed=1, frames=8, size=32, drop_frames=0.5, motions=("wave",))
    generate_sequence_dataset(tmp_path / "d", 1, cfg, model=open_model)
    seq = tmp_path / "d" / "seq_000"
    dropped = np.load(seq / "gt.npz")["frame_dropped"]
    assert dropped.any() and not dropped[0] and not dropped[-1]
    for f in np.flatnonzero(dropped):
        data = json.loads((seq / "keypoints" / f"{frame_stem('seq_000', f)}_keypoints.json").read_text())
        assert data["people"] == []
