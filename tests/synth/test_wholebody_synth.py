"""Whole-body synthetic subjects: parameters, keypoints and the ground truth that reproduces them."""

from pathlib import Path

import numpy as np
import pytest
import torch

from silfit import load_body_model
from silfit.camera import load_camera, project_points
from silfit.io.subjects import load_subject
from silfit.synth.generate import WHOLEBODY_PARTS, SynthConfig, generate_dataset
from silfit.synth.hands import hand_axes, hand_pose_to_axis_angle, within_limits
from silfit.io.wholebody import read_wholebody, wholebody_keypoints

PARAMS = (
    "betas",
    "expression",
    "global_orient",
    "body_pose",
    "jaw_pose",
    "leye_pose",
    "reye_pose",
    "left_hand_pose",
    "right_hand_pose",
    "transl",
)
SHIPPED = Path(__file__).resolve().parents[2] / "data" / "synthetic_wholebody"


@pytest.fixture(scope="module")
def wb():
    return load_body_model(kind="smplx")


@pytest.fixture(scope="module")
def wb_dataset(tmp_path_factory, wb):
    out = tmp_path_factory.mktemp("wb") / "data"
    cfg = SynthConfig(seed=3, size=96, noise_px=2.0, clean=1, whole_body=True)
    return out, generate_dataset(out, 2, cfg, model=wb)


def check_subject(wb, folder: Path):
    gt = np.load(folder / "gt.npz")
    cam = load_camera(folder / "camera.json")
    assert set(PARAMS) <= set(gt.files)
    params = load_subject(folder, require=("gt",)).gt.params()  # the dataset reader gives SMPL-X's parameters
    assert set(params) == set(PARAMS)
    with torch.no_grad():
        out = wb(**{k: torch.as_tensor(v) for k, v in params.items()})
        kp = wholebody_keypoints(wb, out)
    # float32 forward passes: measured 2e-5 m apart between two CPUs (AVX2 / AVX-512 kernels)
    assert np.abs(out.vertices[0].numpy() - gt["vertices"]).max() < 1e-4
    stored = read_wholebody(folder / "keypoints.json", require=("body",))
    for part in WHOLEBODY_PARTS:
        clean = gt[f"{part}_2d_clean"]
        assert np.abs(project_points(kp[part][0].double(), cam).numpy() - clean).max() < 1e-3, part
        arr = getattr(stored, part)
        vis, dropped = gt[f"{part}_visibility"], gt[f"{part}_dropped"]
        kept = (vis > 0) & ~dropped
        assert np.all(arr[~kept] == 0)
        assert np.all(arr[kept & (vis == 2), 2] >= 0.6) and np.all(arr[kept & (vis == 1), 2] <= 0.3)
        err = np.linalg.norm(arr[kept, :2] - clean[kept], axis=1)
        if float(gt["noise_px"]) == 0:
            assert err.max() < 1e-3
        else:  # hands and face get a smaller share of the body's pixel noise
            assert np.median(err) < 2.5 * float(gt["noise_px"])
    J = wb(**wb.zero_params(1)).joints[0].numpy()
    for side in ("left", "right"):
        flex, spread = gt[f"{side}_hand_flex"].astype(np.float64), gt[f"{side}_hand_spread"].astype(np.float64)
        assert within_limits(flex, spread, atol=1e-6)
        aa = hand_pose_to_axis_angle(flex, spread, hand_axes(J, wb.joint_names, side))
        # flat_hand_mean: the open model's mean is zero; the axes come from the float32 joints
        # (measured 2.2e-5 rad apart between two CPUs)
        assert np.abs(aa - gt[f"{side}_hand_pose"]).max() < 1e-4
    return gt


def test_generated_subjects_reproduce_from_their_ground_truth(wb, wb_dataset):
    out, index = wb_dataset
    assert index["generator"]["whole_body"] and index["generator"]["body_model"]["kind"] == "smplx"
    for s in index["subjects"]:
        assert s["hand_left"] and s["hand_right"]
        check_subject(wb, out / s["name"])


@pytest.mark.skipif(not SHIPPED.is_dir(), reason="no shipped whole-body set")
def test_the_shipped_whole_body_set(wb):
    subjects = sorted(p for p in SHIPPED.iterdir() if p.is_dir())
    assert len(subjects) >= 3
    for folder in subjects:
        check_subject(wb, folder)


def test_whole_body_needs_a_whole_body_model(open_model, tmp_path):
    with pytest.raises(ValueError, match="--whole-body needs an SMPL-X-layout model"):
        generate_dataset(tmp_path / "x", 1, SynthConfig(size=64, whole_body=True), model=open_model)
