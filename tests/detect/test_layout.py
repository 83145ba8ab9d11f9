import numpy as np
import pytest

from silfit.detect.layout import BLAZEPOSE33_NAMES, NECK_ABOVE_SHOULDERS, blazepose_to_layout
from silfit.io.keypoints import BODY25_NAMES, COCO17_NAMES


def _landmarks():
    xy = np.arange(66, dtype=np.float64).reshape(33, 2)
    conf = np.linspace(0.2, 1.0, 33)
    return xy, conf


def test_body25_from_blazepose():
    xy, conf = _landmarks()
    kp = blazepose_to_layout(xy, conf, "body25")
    assert kp.shape == (25, 3)
    b = {n: i for i, n in enumerate(BLAZEPOSE33_NAMES)}
    o = {n: i for i, n in enumerate(BODY25_NAMES)}
    for name in ("nose", "left_wrist", "right_knee", "left_ear", "right_heel"):
        np.testing.assert_allclose(kp[o[name]], [*xy[b[name]], conf[b[name]]])
    ls, rs, lh, rh = b["left_shoulder"], b["right_shoulder"], b["left_hip"], b["right_hip"]
    shoulders, hips = (xy[ls] + xy[rs]) / 2, (xy[lh] + xy[rh]) / 2
    neck = shoulders + NECK_ABOVE_SHOULDERS * (shoulders - hips)
    np.testing.assert_allclose(kp[o["neck"]], [*neck, min(conf[ls], conf[rs])])
    np.testing.assert_allclose(kp[o["mid_hip"], :2], hips)
    np.testing.assert_allclose(kp[o["left_big_toe"]], [*xy[b["left_foot_index"]], conf[b["left_foot_index"]]])
    assert (kp[o["left_small_toe"]] == 0).all() and (kp[o["right_small_toe"]] == 0).all()


def test_coco17_and_undetected_points():
    xy, conf = _landmarks()
    conf[BLAZEPOSE33_NAMES.index("left_ankle")] = 0.0
    kp = blazepose_to_layout(xy, conf, "coco17")
    assert kp.shape == (17, 3)
    for k, name in enumerate(COCO17_NAMES):
        i = BLAZEPOSE33_NAMES.index(name)
        expected = [0, 0, 0] if name == "left_ankle" else [*xy[i], conf[i]]
        np.testing.assert_allclose(kp[k], expected)
    with pytest.raises(ValueError, match="unknown keypoint layout"):
        blazepose_to_layout(xy, conf, "body135")


def test_blazepose33_layout_has_sources_on_the_body_model(open_model, tmp_path):
    from silfit.io.keypoints import keypoint_sources, read_keypoints, write_openpose_json

    xy, conf = _landmarks()
    np.testing.assert_allclose(blazepose_to_layout(xy, conf, "blazepose33"), np.concatenate([xy, conf[:, None]], 1))
    sources = dict(zip(BLAZEPOSE33_NAMES, keypoint_sources(open_model, "blazepose33")))
    joints, landmarks = list(open_model.joint_names), list(open_model.landmark_names)
    assert sources["left_index"] == sources["left_thumb"] == ("joint", joints.index("left_hand"))
    assert sources["right_pinky"] == ("joint", joints.index("right_hand"))
    assert sources["left_shoulder"] == ("joint", joints.index("left_shoulder"))
    assert sources["mouth_left"] == ("landmark", landmarks.index("nose"))
    assert sources["right_eye_outer"] == sources["right_eye"] == ("landmark", landmarks.index("right_eye"))
    assert sources["left_foot_index"] == ("landmark", landmarks.index("left_big_toe"))
    # 33-point OpenPose files read back as this layout.
    write_openpose_json(tmp_path / "kp.json", np.concatenate([xy, conf[:, None]], 1))
    assert read_keypoints(tmp_path / "kp.json").layout == "blazepose33"
