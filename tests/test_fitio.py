"""The one reader of fit outputs: round trip with KeypointFitResult.save, and its checks."""
import json

import numpy as np
import pytest

from silfit.camera import Camera
from silfit.dataset import SubjectError
from silfit.fitio import read_fit
from silfit.fitting.result import KeypointFitResult

CAM = Camera(fx=300.0, fy=310.0, cx=63.5, cy=60.0, width=128, height=120)


def _result():
    rng = np.random.default_rng(0)
    return KeypointFitResult(
        betas=rng.normal(size=(1, 10)).astype(np.float32), body_pose=rng.normal(size=(1, 69)).astype(np.float32),
        global_orient=rng.normal(size=(1, 3)).astype(np.float32), transl=np.array([[0.1, 0.2, 3.0]], np.float32),
        cameras=[CAM], vertices=rng.normal(size=(1, 50, 3)).astype(np.float32),
        joints=rng.normal(size=(1, 24, 3)).astype(np.float32), keypoints_2d=rng.normal(size=(1, 17, 2)).astype(np.float32),
        layout="coco17", energies={"final": np.array([1.5])}, timings={"final": 0.25},
        flipped=np.array([True]), reprojection_error=np.array([2.5]),
    )  # fmt: skip


def test_round_trip_both_files(tmp_path):
    res = _result()
    res.save(tmp_path)
    for name in ("params.npz", "params.json"):
        back = KeypointFitResult.load(tmp_path / name)
        for p in ("betas", "body_pose", "global_orient", "transl"):
            np.testing.assert_allclose(getattr(back, p), getattr(res, p), atol=1e-6)
        assert back.camera == CAM and back.layout == "coco17"
    npz = read_fit(tmp_path)  # a folder: params.npz preferred
    assert npz.path.name == "params.npz" and npz.arrays["vertices"].shape == (50, 3)
    js = KeypointFitResult.load(tmp_path / "params.json")
    assert js.flipped[0] and js.reprojection_error[0] == 2.5 and js.timings == {"final": 0.25}


def _npz(tmp_path, **fields):
    base = dict(betas=np.zeros(10), body_pose=np.zeros(69), global_orient=np.zeros(3), transl=np.zeros(3),
                camera_intrinsics=np.array([300.0, 300, 63.5, 60]), image_size=np.array([128, 120]))  # fmt: skip
    base.update(fields)
    base = {k: v for k, v in base.items() if v is not None}
    np.savez(tmp_path / "params.npz", **base)
    return tmp_path / "params.npz"


@pytest.mark.parametrize(
    "fields, field, words",
    [
        ({"body_pose": None}, "body_pose", "missing"),
        ({"body_pose": np.zeros(72)}, "body_pose", "expected [69]"),
        ({"transl": np.array([0.0, np.nan, 1.0])}, "transl", "NaN"),
        ({"betas": np.array(["a", "b"])}, "betas", "numeric"),
        ({"image_size": None}, "image_size", "missing"),
        ({"camera_intrinsics": np.array([-1.0, 300, 63.5, 60])}, "camera_intrinsics", "positive"),
        ({"layout": np.array("body99")}, "layout", "unknown keypoint layout"),
        ({"joints": np.zeros((24, 4))}, "joints", "expected [N, 3]"),
    ],
)
def test_npz_checks_name_file_and_field(tmp_path, fields, field, words):
    f = _npz(tmp_path, **fields)
    with pytest.raises(SubjectError) as info:
        KeypointFitResult.load(f)
    assert info.value.field == field and words in str(info.value) and str(f) in str(info.value)
    assert "\n" not in str(info.value)


def test_json_checks_and_partial_reads(tmp_path):
    f = tmp_path / "params.json"
    f.write_text(json.dumps({"transl": [0.0, 0.2, 3.0], "betas": [0.5]}))
    fit = read_fit(f, require=())  # render: any subset of the parameters
    assert set(fit.params) == {"transl", "betas"} and fit.camera is None
    with pytest.raises(SubjectError, match="body_pose.*missing"):
        read_fit(f)
    f.write_text(json.dumps({"transl": [0.0, 0.2, 3.0], "camera": {"fx": 1.0}}))
    with pytest.raises(SubjectError) as info:
        read_fit(f, require=())
    assert info.value.field == "camera"
    f.write_text("{not json")
    with pytest.raises(SubjectError, match="not valid JSON"):
        read_fit(f, require=())
    f.write_text(json.dumps({"camera": CAM.to_dict()}))
    with pytest.raises(SubjectError, match="none of the parameter fields"):
        read_fit(f, require=())
    with pytest.raises(FileNotFoundError, match="fit result not found"):
        read_fit(tmp_path / "nowhere")
