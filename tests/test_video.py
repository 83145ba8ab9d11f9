"""Reading a video's per-frame OpenPose folder."""
import json

import numpy as np
import pytest

from silfit.errors import InputError
from silfit.keypoints import write_openpose_json
from silfit.video import frame_number, read_sequence


def kp(x):
    a = np.zeros((25, 3))
    a[:, 0], a[:, 1], a[:, 2] = x + np.arange(25), 50 + 3 * np.arange(25), 0.9
    return a


def test_frame_numbers_from_openpose_names():
    assert frame_number("video_000000000012_keypoints.json") == 12
    assert frame_number("clip7_000000000003.png") == 3
    assert frame_number("mask.png") is None


def test_read_sequence_orders_frames_and_fills_gaps(tmp_path):
    for n in (10, 11, 13):
        write_openpose_json(tmp_path / f"v_{n:012d}_keypoints.json", kp(n))
    (tmp_path / "v_000000000014_keypoints.json").write_text(json.dumps({"version": 1.3, "people": []}))
    seq = read_sequence(tmp_path)
    assert seq.numbers == [10, 11, 12, 13, 14]
    assert [ks is None for ks in seq.frames] == [False, False, True, False, True]
    assert seq.frames[3].xy[0, 0] == pytest.approx(13.0)
    assert seq.detected == 3 and seq.masks == {} and seq.camera is None


def test_read_sequence_errors_name_the_file(tmp_path):
    with pytest.raises(InputError, match="no OpenPose per-frame files"):
        read_sequence(tmp_path)
    (tmp_path / "v_000000000000_keypoints.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": [1, 2]}]}))
    with pytest.raises(InputError, match="v_000000000000_keypoints.json"):
        read_sequence(tmp_path)
    (tmp_path / "v_000000000000_keypoints.json").write_text(json.dumps({"people": []}))
    with pytest.raises(InputError, match="no person detected in any"):
        read_sequence(tmp_path)


def test_a_frame_whose_person_has_no_confident_point_is_a_frame_without_detection(tmp_path):
    for n in (0, 2):
        write_openpose_json(tmp_path / f"v_{n:012d}_keypoints.json", kp(n))
    (tmp_path / "v_000000000001_keypoints.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": [0.0] * 75}]}))
    seq = read_sequence(tmp_path)
    assert [ks is None for ks in seq.frames] == [False, True, False]
