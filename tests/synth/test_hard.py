"""The hard synthetic set: sampler poses, front and back views of deep flexion over-represented."""

import json

import numpy as np
import torch

from silfit.io.subjects import list_subjects, load_subject
from silfit.poses.sampler import ARCHETYPES, DEEP_FLEXION
from silfit.priors import within_limits
from silfit.synth import generate_hard_dataset
from silfit.synth.hard import FRONTAL_BACK_PROB, hard_yaw


def test_deep_flexion_is_seen_from_the_front_and_the_back():
    rng = np.random.default_rng(0)
    deep = np.array([hard_yaw(rng, "squat") for _ in range(400)])
    other = np.array([hard_yaw(rng, "reach_overhead") for _ in range(400)])
    near = lambda y: (np.abs(y) < 30) | (np.abs(y) > 150)  # noqa: E731
    assert near(deep).mean() > FRONTAL_BACK_PROB * 0.9 + 0.3 * 0.33 - 0.05  # about 0.77 + uniform's share
    assert abs(near(other).mean() - 60 / 180) < 0.08  # uniform: 60 of 180 degrees
    assert deep.min() >= -180 and deep.max() < 180


def test_hard_generator_writes_readable_subjects(tmp_path, open_model):
    out = tmp_path / "hard"
    index = generate_hard_dataset(out, 3, seed=2, size=96, noise_px=2.0, model=open_model)
    assert index["generator"]["poses"] == "hard" and index["generator"]["noise_px"] == 2.0
    on_disk = json.loads((out / "index.json").read_text())
    assert on_disk["subjects"] == index["subjects"]
    paths = list_subjects(out)
    assert len(paths) == 3
    for path, rec in zip(paths, index["subjects"]):
        s = load_subject(path)
        assert rec["pose"] in ARCHETYPES
        assert s.image.shape[:2] == (96, 96) and s.mask.any()
        bp = torch.as_tensor(np.asarray(s.gt.body_pose, dtype=np.float64))[None]
        assert bool(within_limits(bp, tol=1e-5).all())
        # Occlusion-aware confidences: visible points high, self-occluded ones low.
        vis = s.gt.extras["keypoints_visibility"]
        assert (s.keypoints.conf[vis == 2] >= 0.6).all() and (s.keypoints.conf[vis == 1] <= 0.3).all()
    # Deterministic for the seed.
    again = generate_hard_dataset(tmp_path / "again", 1, seed=2, size=96, model=open_model)
    assert again["subjects"][0]["description"] == index["subjects"][0]["description"]
    assert set(DEEP_FLEXION) <= set(ARCHETYPES)


def test_hard_whole_body_subjects_take_the_sampler_pose_on_smplx(tmp_path):
    """``silfit synth --whole-body --poses hard``: the sampler screens its poses on an SMPL-layout body and an
    SMPL-X subject takes their first 21 joints (before: a shape error from the sampler's collision check)."""
    from silfit import load_body_model

    model = load_body_model(kind="smplx")
    index = generate_hard_dataset(tmp_path / "wb", 1, seed=3, size=64, model=model, whole_body=True)
    s = load_subject(list_subjects(tmp_path / "wb")[0])
    assert index["subjects"][0]["pose"] in ARCHETYPES
    assert np.asarray(s.gt.body_pose).shape[-1] == 63 and s.mask.any()
