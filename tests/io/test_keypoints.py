"""Keypoint files: OpenPose and COCO JSON in, OpenPose JSON out, clear errors."""

import json

import numpy as np
import pytest

from silfit.io.keypoints import BODY25_NAMES, read_keypoints, write_openpose_json


def body25(seed=0):
    rng = np.random.default_rng(seed)
    kp = np.concatenate([rng.uniform(10, 200, size=(25, 2)), rng.uniform(0.5, 1.0, size=(25, 1))], axis=1)
    return kp


def test_openpose_round_trip(tmp_path):
    kp = body25()
    write_openpose_json(tmp_path / "k.json", kp)
    loaded = read_keypoints(tmp_path / "k.json")
    assert loaded.layout == "body25" and loaded.names == BODY25_NAMES
    assert np.allclose(loaded.as_array(), kp, atol=1e-4)
    assert not (tmp_path / "k.json.tmp").exists()


def test_largest_person_is_chosen(tmp_path):
    small, big = body25(1), body25(2)
    small[:, :2] = small[:, :2] * 0.1
    people = [{"pose_keypoints_2d": small.reshape(-1).tolist()}, {"pose_keypoints_2d": big.reshape(-1).tolist()}]
    (tmp_path / "k.json").write_text(json.dumps({"people": people}))
    assert np.allclose(read_keypoints(tmp_path / "k.json").xy, big[:, :2])
    assert np.allclose(read_keypoints(tmp_path / "k.json", person=0).xy, small[:, :2])


def test_coco_annotation_and_plain_list(tmp_path):
    coco = body25()[:17]
    (tmp_path / "ann.json").write_text(json.dumps({"keypoints": coco.reshape(-1).tolist()}))
    (tmp_path / "list.json").write_text(json.dumps(coco.tolist()))
    for name in ("ann.json", "list.json"):
        loaded = read_keypoints(tmp_path / name)
        assert loaded.layout == "coco17" and np.allclose(loaded.conf, coco[:, 2])


@pytest.mark.parametrize(
    "payload, message",
    [
        ({"people": []}, "people"),
        ({"people": [{"pose_keypoints_2d": [1.0] * 60}]}, "20 keypoints"),
        ({"people": [{"pose_keypoints_2d": [1.0] * 73}]}, "multiple of 3"),
        ({"people": [{"face": []}]}, "pose_keypoints_2d"),
        ({"people": [{"pose_keypoints_2d": [5.0, 5.0, 0.0] * 25}]}, "confidences are zero"),
        ({"something": 1}, "no keypoints"),
    ],
)
def test_bad_keypoint_files_name_file_and_field(tmp_path, payload, message):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(payload))
    with pytest.raises(ValueError, match=message) as err:
        read_keypoints(path)
    assert "bad.json" in str(err.value)


def test_nan_keypoints_are_named(tmp_path):
    kp = body25()
    kp[4, 0] = np.nan
    (tmp_path / "nan.json").write_text(
        json.dumps({"people": [{"pose_keypoints_2d": [None if np.isnan(v) else v for v in kp.reshape(-1)]}]})
    )
    with pytest.raises(ValueError, match="right_wrist"):
        read_keypoints(tmp_path / "nan.json")


# --------------------------------------------------------------------------- hostile / broken files
@pytest.mark.parametrize(
    "payload,expect",
    [
        ({"people": [{"pose_keypoints_2d": ["1.0"] * 75}]}, r"people\[0\]\.pose_keypoints_2d.*value 0 is '1\.0'"),
        ({"people": [{"pose_keypoints_2d": [True] * 75}]}, r"pose_keypoints_2d.*value 0 is True"),
        ({"people": [{"pose_keypoints_2d": [[1, 2, 3]] * 24 + [[1, 2]]}]}, r"pose_keypoints_2d\[24\].*2 values"),
        ({"people": [{"pose_keypoints_2d": {"x": 1}}]}, r"pose_keypoints_2d.*must be a list"),
        ({"people": [{"pose_keypoints_2d": [10**400] * 75}]}, r"pose_keypoints_2d.*too large"),
        ([{"keypoints": [1.0] * 51}, 7], r"\[1\]\.keypoints.*missing"),
        ({"people": "nobody"}, r"'people' is empty"),
        ({"people": [{"pose_keypoints_2d": [[1.0, 2.0, [3.0]]] * 25}]}, r"value 2 is list"),
    ],
    ids=["strings", "booleans", "ragged", "dict", "huge-int", "non-dict-annotation", "people-string", "nested"],
)
def test_malformed_keypoint_files_name_file_and_field(tmp_path, payload, expect):
    from silfit.errors import InputError

    path = tmp_path / "kp.json"
    path.write_text(json.dumps(payload))
    with pytest.raises(InputError, match=expect) as info:
        read_keypoints(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_binary_deep_and_oversized_files_are_clean_errors(tmp_path, monkeypatch):
    from silfit.io import limits as input_limits
    from silfit.errors import InputError

    (tmp_path / "bin.json").write_bytes(bytes(range(256)) * 4)
    with pytest.raises(InputError, match=r"bin\.json.*binary"):
        read_keypoints(tmp_path / "bin.json")
    (tmp_path / "deep.json").write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(InputError, match=r"deep\.json.*nested too deeply"):
        read_keypoints(tmp_path / "deep.json")
    write_openpose_json(tmp_path / "big.json", body25())
    monkeypatch.setattr(input_limits, "MAX_JSON_BYTES", 100)
    with pytest.raises(InputError, match=r"big\.json.*more than"):
        read_keypoints(tmp_path / "big.json")
