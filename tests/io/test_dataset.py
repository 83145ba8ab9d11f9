"""Reading subject folders: validation errors name the file and the field."""

import json

import numpy as np
import pytest

from silfit.camera import Camera, save_camera
from silfit.io.subjects import SubjectError, list_subjects, load_subject, read_gt, read_mask, save_npz, write_png
from silfit.io.keypoints import write_openpose_json


def make_subject(folder, size=(40, 30)):
    w, h = size
    folder.mkdir(parents=True, exist_ok=True)
    save_camera(Camera(fx=40.0, fy=40.0, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h), folder / "camera.json")
    kp = np.zeros((25, 3))
    kp[:, 0], kp[:, 1], kp[:, 2] = np.linspace(5, 30, 25), np.linspace(3, 25, 25), 0.9
    write_openpose_json(folder / "keypoints.json", kp)
    mask = np.zeros((h, w), bool)
    mask[5:25, 10:30] = True
    write_png(folder / "mask.png", mask)
    write_png(folder / "image.png", np.full((h, w, 3), 128, np.uint8))
    save_npz(
        folder / "gt.npz",
        {
            "betas": np.zeros(10),
            "body_pose": np.zeros(69),
            "global_orient": np.array([np.pi, 0, 0]),
            "transl": np.array([0, 0, 3.0]),
            "vertices": np.zeros((8, 3)),
            "joints": np.zeros((24, 3)),
        },
    )
    return folder


def test_reads_a_complete_subject(tmp_path):
    s = load_subject(make_subject(tmp_path / "a"))
    assert s.name == "a" and s.camera.width == 40 and s.camera.height == 30
    assert s.keypoints.xy.shape == (25, 2) and s.mask.shape == (30, 40) and s.mask.sum() == 400
    assert s.image.shape == (30, 40, 3) and s.gt.body_pose.shape == (69,)
    assert s.gt.params()["betas"].shape == (1, 10)


def test_missing_required_file_names_the_path(tmp_path):
    d = make_subject(tmp_path / "a")
    (d / "keypoints.json").unlink()
    with pytest.raises(FileNotFoundError, match=r"a/keypoints\.json"):
        load_subject(d)
    # Optional files may be absent.
    (d / "image.png").unlink()
    assert load_subject(d, require=("camera",)).image is None


@pytest.mark.parametrize(
    "file, content, field",
    [
        ("camera.json", '{"fx": 40, "fy": 40, "cx": 1, "cy": 1, "width": 40}', "height"),
        ("keypoints.json", '{"people": [{"pose_keypoints_2d": [1, 2]}]}', "pose_keypoints_2d"),
        ("keypoints.json", "{not json", "not valid JSON"),
    ],
)
def test_malformed_json_names_path_and_field(tmp_path, file, content, field):
    d = make_subject(tmp_path / "a")
    (d / file).write_text(content)
    with pytest.raises(ValueError, match=field) as info:
        load_subject(d)
    assert str(d / file) in str(info.value)


def test_gt_fields_are_validated(tmp_path):
    d = make_subject(tmp_path / "a")
    save_npz(d / "gt.npz", {"betas": np.zeros(10), "body_pose": np.zeros(60)})
    with pytest.raises(SubjectError) as info:
        load_subject(d)
    assert info.value.field == "body_pose" and info.value.path == str(d / "gt.npz") and "69" in str(info.value)
    save_npz(d / "gt.npz", {"betas": np.zeros(10), "body_pose": np.zeros(69)})
    with pytest.raises(SubjectError, match="'global_orient': missing"):
        read_gt(d / "gt.npz")
    (d / "gt.npz").write_bytes(b"garbage")
    with pytest.raises(SubjectError, match="gt.npz"):
        load_subject(d)


def test_mask_size_and_content_checked(tmp_path):
    d = make_subject(tmp_path / "a")
    write_png(d / "mask.png", np.ones((10, 10), bool))
    with pytest.raises(
        SubjectError, match=r"mask\.png: field 'mask': mask is 10x10 pixels but the image/camera is 40x30"
    ):
        load_subject(d)
    write_png(d / "mask.png", np.zeros((30, 40), bool))
    with pytest.raises(SubjectError, match="empty"):
        read_mask(d / "mask.png")
    (d / "mask.png").write_text("not a png")
    with pytest.raises(SubjectError, match="cannot read the mask"):
        load_subject(d)


def test_list_subjects_with_and_without_index(tmp_path):
    for name in ("s1", "s0"):
        make_subject(tmp_path / name)
    (tmp_path / "other").mkdir()
    assert [p.name for p in list_subjects(tmp_path)] == ["s0", "s1"]
    (tmp_path / "index.json").write_text(json.dumps({"subjects": [{"name": "s1"}, {"name": "s0"}]}))
    assert [p.name for p in list_subjects(tmp_path)] == ["s1", "s0"]
    assert list_subjects(tmp_path / "s0") == [tmp_path / "s0"]


def test_save_npz_is_byte_identical(tmp_path):
    arrays = {"a": np.arange(10.0), "b": np.eye(3, dtype=np.float32)}
    save_npz(tmp_path / "x.npz", arrays)
    save_npz(tmp_path / "y.npz", arrays)
    assert (tmp_path / "x.npz").read_bytes() == (tmp_path / "y.npz").read_bytes()
    with np.load(tmp_path / "x.npz") as d:
        assert np.array_equal(d["a"], arrays["a"]) and d["b"].dtype == np.float32
