"""The sampler of plausible poses that do not come from the pose library."""

import numpy as np
import pytest
import torch

from silfit.poses.contact import part_contact, posed_vertices
from silfit.poses.library import BODY_JOINTS, POSE_LIBRARY
from silfit.poses.sampler import ARCHETYPES, PoseSampler, sample_poses
from silfit.priors import within_limits

NON_CONTACT = ["squat", "kneel_one", "kneel_both", "sit", "run", "lunge", "reach_overhead", "reach_forward"]
TORSO = ["pelvis", "spine1", "spine2", "spine3"]


@pytest.fixture(scope="module")
def sampler(body_model):
    return PoseSampler(body_model, archetypes=NON_CONTACT)


@pytest.fixture(scope="module")
def samples(sampler):
    return [sampler.sample(np.random.default_rng([7, i])) for i in range(6)]


def test_the_library_moved_and_synth_re_exports_it():
    import silfit.synth.poses as old

    assert old.POSE_LIBRARY is POSE_LIBRARY and old.mirror_pose is not None


def test_samples_are_within_the_limits_and_deterministic(sampler, samples, body_model):
    poses = torch.as_tensor(np.stack([s.body_pose for s in samples]))
    assert bool(within_limits(poses).all())
    again = [sampler.sample(np.random.default_rng([7, i])) for i in range(2)]
    for a, b in zip(samples, again):
        assert (
            a.archetype == b.archetype and np.array_equal(a.body_pose, b.body_pose) and np.array_equal(a.root, b.root)
        )
    other = sampler.sample(np.random.default_rng([8, 0]))
    assert not np.allclose(other.body_pose, samples[0].body_pose)
    # sample_poses: pose i depends on (seed, i) only.
    assert np.array_equal(
        sample_poses(2, seed=7, model=body_model, archetypes=NON_CONTACT)[1].body_pose, samples[1].body_pose
    )


def test_samples_do_not_come_from_the_library(samples):
    lib = np.stack([p.body_pose for p in POSE_LIBRARY.values()])
    for s in samples:
        assert np.abs(lib - s.body_pose).max(1).min() > np.radians(10)


def test_no_self_intersection(sampler, samples, body_model):
    """Below the sampler's sphere threshold, and on the mesh: no forearm or hand more than
    2 cm inside the torso or a thigh (the sampler rejects above 1.5 cm)."""
    for s in samples:
        assert s.interpenetration <= sampler.max_interpenetration
        v = posed_vertices(body_model, s.body_pose)
        for side in ("left", "right"):
            arm = [f"{side}_elbow", f"{side}_wrist", f"{side}_hand"]
            for target in (TORSO, ["left_hip"], ["right_hip"]):
                assert part_contact(body_model, v, arm, target).depth < 0.02, (s.describe(), side, target)


def test_limbs_are_coupled_as_people_move(sampler):
    """Squats: the knee flexes with the hip (deeper squat, both deeper)."""
    rng = np.random.default_rng(3)
    hip, kn = [], []
    for _ in range(10):
        s = sampler._draw(rng, "squat")
        p = s.body_pose.reshape(23, 3)
        hip.append(np.linalg.norm(p[BODY_JOINTS.index("left_hip")]))
        kn.append(np.linalg.norm(p[BODY_JOINTS.index("left_knee")]))
    assert np.corrcoef(hip, kn)[0, 1] > 0.8


def test_contact_archetype_touches_without_intersecting(body_model):
    s = PoseSampler(body_model, archetypes=["hand_face"]).sample(np.random.default_rng(0))
    hand = ["right_wrist", "right_hand"] if not s.mirrored else ["left_wrist", "left_hand"]
    c = part_contact(body_model, posed_vertices(body_model, s.body_pose), hand, ["head", "neck"])
    assert c.gap < 0.012 and c.depth <= 0.006, c
    assert bool(within_limits(torch.as_tensor(s.body_pose)[None]).all())


def test_unknown_archetype_is_an_error(body_model):
    with pytest.raises(ValueError, match="unknown"):
        PoseSampler(body_model, archetypes=["moonwalk"])
    assert set(NON_CONTACT) < set(ARCHETYPES)
