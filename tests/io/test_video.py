"""Reading a video's per-frame OpenPose folder."""

import json

import numpy as np
import pytest

from silfit.errors import InputError
from silfit.io.keypoints import write_openpose_json
from silfit.io.video import frame_number, read_sequence


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


def _frames(folder, numbers, stem="v"):
    folder.mkdir(exist_ok=True)
    for n in numbers:
        write_openpose_json(folder / f"{stem}_{n:012d}_keypoints.json", kp(n))


def _masks(folder, numbers, stem="v"):
    from PIL import Image

    folder.mkdir(exist_ok=True)
    for n in numbers:
        Image.fromarray(np.pad(np.full((4, 4), 255, np.uint8), 2)).save(folder / f"{stem}_{n:012d}.png")


def test_a_frame_number_far_from_the_others_is_refused_before_any_frame_is_allocated(tmp_path):
    """The issue's folder: frames 0-5 and 99999 (100,000 frames before); a gap up to
    MAX_GAP missing frames is still bridged."""
    from silfit.io.video import MAX_GAP

    _frames(tmp_path / "a", [0, 1, 2, 3, 4, 5, 99999])
    with pytest.raises(
        InputError,
        match=rf"v_000000099999_keypoints\.json: frame 99999 comes 99993 missing frames after frame 5 \(at most {MAX_GAP}",
    ):
        read_sequence(tmp_path / "a")
    _frames(tmp_path / "b", [0, 1, MAX_GAP + 2])
    assert len(read_sequence(tmp_path / "b").numbers) == MAX_GAP + 3
    _frames(tmp_path / "c", [0, 1, MAX_GAP + 3])
    with pytest.raises(InputError, match=rf"frame {MAX_GAP + 3} comes {MAX_GAP + 1} missing"):
        read_sequence(tmp_path / "c")


def test_a_keypoint_file_without_a_frame_number_is_refused(tmp_path):
    _frames(tmp_path, [0, 1])
    write_openpose_json(tmp_path / "extra_keypoints.json", kp(0))
    with pytest.raises(InputError, match=r"extra_keypoints\.json: keypoint file name has no frame number"):
        read_sequence(tmp_path)


def test_two_videos_in_one_folder_are_refused(tmp_path):
    _frames(tmp_path / "kp", [0, 1, 2], stem="walk")
    _frames(tmp_path / "kp", [3, 4], stem="run")
    with pytest.raises(
        InputError, match=r"keypoint files of 2 videos in one folder: 'walk' \(frames 0..2\) and 'run' \(frames 3..4\)"
    ):
        read_sequence(tmp_path / "kp")
    _frames(tmp_path / "one", [0, 1, 2], stem="walk")
    _masks(tmp_path / "m", [0, 1], stem="walk")
    _masks(tmp_path / "m", [2], stem="run")
    with pytest.raises(InputError, match=r"mask files of 2 videos"):
        read_sequence(tmp_path / "one", masks=tmp_path / "m")


def test_masks_that_do_not_match_the_frames_are_reported(tmp_path):
    _frames(tmp_path / "kp", [0, 1, 2, 3])
    _masks(tmp_path / "m", [0, 2, 3, 7, 8])  # none for frame 1; 7 and 8 are not frames
    seq = read_sequence(tmp_path / "kp", masks=tmp_path / "m")
    assert sorted(seq.masks) == [0, 2, 3, 7, 8]
    text = " | ".join(seq.warnings)
    assert "2 mask(s) for frames the keypoints do not have, ignored: 7, 8" in text, text
    assert "no mask for 1 frame(s) with a person (no silhouette term there): 1" in text, text
    _masks(tmp_path / "other", [50, 51])
    with pytest.raises(
        InputError, match=r"other: no mask file matches a frame: masks for frames 50..51, keypoints for 0..3"
    ):
        read_sequence(tmp_path / "kp", masks=tmp_path / "other")
    assert read_sequence(tmp_path / "kp", masks=None).warnings == []
