"""The hand pose library: finger limits, perturbation within them, and its effect on the model."""

import numpy as np
import pytest
import torch

from silfit import load_body_model
from silfit.synth.hands import (
    FLEX_LIMITS,
    HAND_LIBRARY,
    SPREAD_LIMITS,
    hand_axes,
    hand_pose_to_axis_angle,
    sample_hand_pose,
    within_limits,
)
from silfit.io.wholebody import wholebody_keypoints


@pytest.fixture(scope="module")
def wb():
    return load_body_model(kind="smplx", dtype=torch.float64)


def test_library_names_and_limits():
    assert {"relaxed", "fist", "open", "pointing", "pinch", "grasp", "peace", "thumbs_up"} <= set(HAND_LIBRARY)
    for pose in HAND_LIBRARY.values():
        assert pose.flex.shape == (5, 3) and pose.spread.shape == (5,)
        assert within_limits(pose.flex, pose.spread), pose.name
    assert np.all(FLEX_LIMITS[..., 0] < FLEX_LIMITS[..., 1]) and np.all(SPREAD_LIMITS[:, 0] < SPREAD_LIMITS[:, 1])


def test_every_sampled_hand_pose_is_within_the_finger_limits():
    rng = np.random.default_rng(0)
    for _ in range(500):
        name, flex, spread = sample_hand_pose(rng, perturb_deg=20.0)  # large noise: the clipping must hold
        assert name in HAND_LIBRARY and within_limits(flex, spread)
    assert not within_limits(FLEX_LIMITS[..., 1] + 0.01, np.zeros(5))


def tips_to_wrist(wb, side, pose_name):
    J = wb().joints[0].numpy()
    pose = HAND_LIBRARY[pose_name]
    aa = hand_pose_to_axis_angle(pose.flex, pose.spread, hand_axes(J, wb.joint_names, side))
    kp = wholebody_keypoints(wb, wb(**{f"{side}_hand_pose": torch.as_tensor(aa)[None]}))[f"hand_{side}"][0].numpy()
    return np.linalg.norm(kp[[4, 8, 12, 16, 20]] - kp[0], axis=1), kp


@pytest.mark.parametrize("side", ["left", "right"])
def test_poses_curl_the_right_fingers_towards_the_palm(wb, side):
    flat, kp_flat = tips_to_wrist(wb, side, "flat")
    fist, kp_fist = tips_to_wrist(wb, side, "fist")
    point, _ = tips_to_wrist(wb, side, "pointing")
    assert np.all(fist[1:] < 0.75 * flat[1:])  # the four fingers close
    assert point[1] > 0.97 * flat[1] and np.all(point[2:] < 0.75 * flat[2:])  # only the index stays out
    # the palm faces down (-Y) in the rest pose: curled fingers go below the knuckles (the PIP joints by the
    # proximal phalanx, about 2.5 cm) and their tips come back towards the wrist
    assert np.all(kp_fist[[6, 10, 14, 18], 1] < kp_flat[[5, 9, 13, 17], 1] - 0.015)
    outwards = np.sign(kp_flat[9, 0] - kp_flat[0, 0])
    assert np.all(outwards * (kp_fist[[8, 12, 16, 20], 0] - kp_flat[[5, 9, 13, 17], 0]) < 0.01)


def test_pinch_brings_thumb_and_index_tips_together(wb):
    _, kp = tips_to_wrist(wb, "left", "pinch")
    _, flat = tips_to_wrist(wb, "left", "flat")
    assert np.linalg.norm(kp[4] - kp[8]) < 0.02 < np.linalg.norm(flat[4] - flat[8])
