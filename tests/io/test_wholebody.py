"""OpenPose whole-body keypoints: sources on the whole-body model, and the JSON files (round trip, errors)."""

import json

import numpy as np
import pytest
import torch

from silfit import load_body_model
from silfit.io.wholebody import FACE70_NAMES, HAND21_NAMES, read_wholebody, wholebody_keypoints, write_wholebody_json


@pytest.fixture(scope="module")
def wb():
    return load_body_model(kind="smplx")


def test_sources_on_the_model(wb, open_model):
    out = wb()
    kp = wholebody_keypoints(wb, out)
    assert {k: tuple(v.shape) for k, v in kp.items()} == {
        "body": (1, 25, 3),
        "hand_left": (1, 21, 3),
        "hand_right": (1, 21, 3),
        "face": (1, 70, 3),
    }
    J = out.joints[0]
    names = list(wb.joint_names)
    hl = kp["hand_left"][0]
    assert torch.equal(hl[0], J[names.index("left_wrist")]) and torch.equal(hl[1], J[names.index("left_thumb1")])
    assert torch.equal(hl[5], J[names.index("left_index1")]) and torch.equal(hl[17], J[names.index("left_pinky1")])
    # flat left hand along +X: each finger's points go outwards, the tip last
    for f in range(5):
        x = hl[1 + 4 * f : 5 + 4 * f, 0]
        assert torch.all(x[1:] > x[:-1]), HAND21_NAMES[1 + 4 * f]
    hr = kp["hand_right"][0]
    assert torch.allclose(hr * torch.tensor([-1.0, 1.0, 1.0]), hl, atol=2e-3)  # mirror images
    face = kp["face"][0]
    assert torch.equal(face[68], J[names.index("right_eye_smplhf")]) and face[69, 0] > 0 > face[68, 0]
    with pytest.raises(ValueError, match="need an SMPL-X-layout model"):
        wholebody_keypoints(open_model, open_model())


def random_parts(rng):
    parts = [np.c_[rng.uniform(0, 500, (n, 2)), rng.uniform(0.1, 1, n)] for n in (25, 21, 21, 70)]
    return [np.round(p, 3) for p in parts]


def test_round_trip_and_absent_parts(tmp_path):
    rng = np.random.default_rng(0)
    body, hl, hr, face = random_parts(rng)
    write_wholebody_json(tmp_path / "k.json", body, hl, hr, face)
    k = read_wholebody(tmp_path / "k.json", require=("body", "hand_left", "hand_right", "face"))
    assert np.allclose(k.body.as_array(), body) and np.allclose(k.hand_left, hl)
    assert np.allclose(k.hand_right, hr) and np.allclose(k.face, face)
    write_wholebody_json(tmp_path / "b.json", body)  # hands and face written as [] (OpenPose does so)
    k = read_wholebody(tmp_path / "b.json")
    assert k.hand_left is None and k.face is None and len(k.body) == 25
    # the body-only reader still reads the whole-body file
    from silfit.io.keypoints import read_keypoints

    assert np.allclose(read_keypoints(tmp_path / "k.json").as_array(), body)
    assert len(FACE70_NAMES) == 70 and len(HAND21_NAMES) == 21


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda p: p.update(hand_left_keypoints_2d=[1.0] * 60),
            r"'people\[0\].hand_left_keypoints_2d' has 20 keypoints, expected 21",
        ),
        (lambda p: p.update(face_keypoints_2d=[1.0] * 209), "not a multiple of 3"),
        (lambda p: p["face_keypoints_2d"].__setitem__(4, float("nan")), "NaN or infinite values at point"),
        (
            lambda p: p.update(hand_right_keypoints_2d=[0.0] * 63),
            "hand_right_keypoints_2d': all keypoint confidences are zero",
        ),
        (lambda p: p.update(face_keypoints_2d=[]), "'face_keypoints_2d' is missing or empty"),
        (lambda p: p.pop("pose_keypoints_2d"), r"'people\[0\].pose_keypoints_2d' is missing"),
        (lambda p: p["hand_left_keypoints_2d"].__setitem__(2, -0.5), "negative confidences"),
        # a ragged nested array: numpy's "inhomogeneous shape" before, with neither file nor field
        (
            lambda p: p["hand_left_keypoints_2d"].__setitem__(1, [1.0, [2.0, 3.0]]),
            r"'people\[0\].hand_left_keypoints_2d' value 1 is list",
        ),
        (
            lambda p: p.update(hand_left_keypoints_2d=[[1.0, 2.0, 0.5]] * 20 + [[1.0, 2.0]]),
            r"hand_left_keypoints_2d\[20\]' has 2 values",
        ),
    ],
)
def test_bad_files_fail_clearly(tmp_path, edit, message):
    rng = np.random.default_rng(1)
    write_wholebody_json(tmp_path / "k.json", *random_parts(rng))
    data = json.loads((tmp_path / "k.json").read_text())
    edit(data["people"][0])
    (tmp_path / "bad.json").write_text(json.dumps(data).replace("NaN", "NaN"))
    with pytest.raises(ValueError, match=message) as err:
        read_wholebody(tmp_path / "bad.json", require=("body", "hand_left", "hand_right", "face"))
    assert "bad.json" in str(err.value)


def test_unreadable_whole_body_files_are_one_input_error(tmp_path):
    # the same reader checks as every JSON input (silfit.io.limits.read_json): not UTF-8, nested too deeply
    from silfit.errors import InputError

    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00garbage")
    (tmp_path / "deep.json").write_text("[" * 100000 + "]" * 100000)
    for name, words in (("bin.json", "not a text"), ("deep.json", "nested too deeply")):
        with pytest.raises(InputError, match=words):
            read_wholebody(tmp_path / name)
    with pytest.raises(FileNotFoundError, match="keypoint file not found"):
        read_wholebody(tmp_path / "none.json")
