"""The one reader and writer of fit files: round trips for one image, a video and a rig, and the checks."""

import json

import numpy as np
import pytest

from silfit.camera import Camera
from silfit.io.subjects import SubjectError
from silfit.io.fit import SCHEMA, model_record, read_fit, write_fit
from silfit.fitting.result import KeypointFitResult

CAM = Camera(fx=300.0, fy=310.0, cx=63.5, cy=60.0, width=128, height=120)


def _result():
    rng = np.random.default_rng(0)
    return KeypointFitResult(
        betas=rng.normal(size=(1, 10)).astype(np.float32),
        body_pose=rng.normal(size=(1, 69)).astype(np.float32),
        global_orient=rng.normal(size=(1, 3)).astype(np.float32),
        transl=np.array([[0.1, 0.2, 3.0]], np.float32),
        cameras=[CAM],
        vertices=rng.normal(size=(1, 50, 3)).astype(np.float32),
        joints=rng.normal(size=(1, 24, 3)).astype(np.float32),
        keypoints_2d=rng.normal(size=(1, 17, 2)).astype(np.float32),
        layout="coco17",
        energies={"final": np.array([1.5])},
        timings={"final": 0.25},
        flipped=np.array([True]),
        reprojection_error=np.array([2.5]),
    )


def test_round_trip_both_files(tmp_path):
    res = _result()
    res.save(tmp_path)
    for name in ("params.npz", "params.json"):
        back = KeypointFitResult.load(tmp_path / name)
        for p in ("betas", "body_pose", "global_orient", "transl"):
            np.testing.assert_allclose(getattr(back, p), getattr(res, p), atol=1e-6)
        assert back.camera == CAM and back.layout == "coco17"
    npz = read_fit(tmp_path)  # a folder: params.npz preferred
    assert npz.path.name == "params.npz" and npz.arrays["vertices"].shape == (1, 50, 3)
    js = KeypointFitResult.load(tmp_path / "params.json")
    assert js.flipped[0] and js.reprojection_error[0] == 2.5 and js.timings == {"final": 0.25}
    payload = json.loads((tmp_path / "params.json").read_text())
    assert payload["start_flipped"] is True and payload["faces_camera"] is True  # global_orient turns +Z toward -Z here


def test_faces_camera_follows_the_body_not_the_start():
    from silfit.fitting.result import faces_camera

    from silfit.camera import UPRIGHT_BACK_TO_CAMERA, UPRIGHT_FACING_CAMERA

    assert faces_camera(UPRIGHT_FACING_CAMERA, [0.0, 0.2, 3.0]) and not faces_camera(
        UPRIGHT_BACK_TO_CAMERA, [0.0, 0.2, 3.0]
    )
    assert not faces_camera(UPRIGHT_FACING_CAMERA, [0.0, 0.2, -3.0])  # behind the camera, its front away from it


def _npz(tmp_path, **fields):
    base = dict(
        betas=np.zeros(10),
        body_pose=np.zeros(69),
        global_orient=np.zeros(3),
        transl=np.zeros(3),
        camera_intrinsics=np.array([300.0, 300, 63.5, 60]),
        image_size=np.array([128, 120]),
    )
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
        ({"joints": np.zeros((24, 4))}, "joints", "expected [1, ..., 3]"),
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


def test_video_and_rig_fits_keep_their_frame_and_view_axes(tmp_path):
    rng = np.random.default_rng(1)
    F, C, K = 4, 2, 25
    params = {
        "betas": rng.normal(size=10),
        "body_pose": rng.normal(size=(F, 69)),
        "global_orient": rng.normal(size=(F, 3)),
        "transl": rng.normal(size=(F, 3)),
    }
    R = [np.eye(3), np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])]
    t = [np.zeros(3), np.array([0.5, 0.0, 3.0])]
    write_fit(
        tmp_path,
        params,
        [CAM, CAM],
        layout="body25",
        coordinates="world",
        extrinsics=list(zip(R, t)),
        views=["left", "right"],
        frame_numbers=[10, 11, 12, 14],
        keypoints_2d=rng.normal(size=(F, C, K, 2)),
        reprojection_error=np.full((F, C), np.nan),
        record={"timings": {"total": 1.0}},
    )
    for name in ("params.npz", "params.json"):
        fit = read_fit(tmp_path / name)
        assert fit.num_frames == F and fit.params["betas"].shape == (F, 10) and fit.coordinates == "world"
        assert fit.views == ["left", "right"] and len(fit.cameras) == C
        np.testing.assert_allclose(fit.extrinsics[1][0], R[1]) and np.testing.assert_allclose(
            fit.extrinsics[1][1], t[1]
        )
        np.testing.assert_allclose(fit.frame(2)["body_pose"], params["body_pose"][2], atol=1e-6)
        np.testing.assert_allclose(fit.frame(3)["betas"], params["betas"], atol=1e-6)  # shared: repeated
        assert fit.model["kind"] == "smpl"
    fit = read_fit(tmp_path)
    assert fit.arrays["keypoints_2d"].shape == (F, C, K, 2) and list(fit.frame_numbers) == [10, 11, 12, 14]
    assert str(np.load(tmp_path / "params.npz")["schema"]) == SCHEMA
    with pytest.raises(SubjectError, match="frame 4 asked for; the fit has 4 frame"):
        fit.frame(4)
    with pytest.raises(SubjectError) as info:  # a one-image reader refuses a video, naming the file
        KeypointFitResult.load(tmp_path)
    assert info.value.field == "frames" and "4 frame(s)" in str(info.value)


def test_frame_counts_must_agree_and_the_model_decides_the_widths(tmp_path, open_model):
    f = _npz(tmp_path, body_pose=np.zeros((3, 69)), transl=np.zeros((2, 3)))
    with pytest.raises(SubjectError) as info:
        read_fit(f)
    assert info.value.field in ("transl", "body_pose") and "frames" in str(info.value)
    from silfit import load_body_model

    smplx = load_body_model(kind="smplx")
    rec = model_record(smplx)
    assert rec["kind"] == "smplx" and len(rec["sha256"]) == 64 and rec["source"].endswith("open_smplx.npz")
    params = {n: np.zeros(w) for n, w in smplx.parameter_sizes.items()}
    write_fit(tmp_path / "wb", params, [CAM], layout="wholebody", model=smplx)
    fit = read_fit(tmp_path / "wb")  # 63-wide body_pose and the hands read as SMPL-X's, from the record
    assert fit.params["body_pose"].shape == (1, 63) and fit.params["left_hand_pose"].shape == (1, 45)
    assert KeypointFitResult.load(tmp_path / "wb").model == rec
