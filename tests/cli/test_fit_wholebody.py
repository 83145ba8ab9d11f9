"""``silfit fit`` on whole-body OpenPose files: the open whole-body model by default, SMPL-X names."""

import json

import numpy as np
import pytest

from silfit.cli import main


@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    from silfit.body import load_body_model
    from silfit.synth.generate import SynthConfig, generate_subject

    d = tmp_path_factory.mktemp("wb") / "s"
    generate_subject(load_body_model(kind="smplx"), 0, SynthConfig(size=128, whole_body=True, seed=5), d)
    return d


def test_whole_body_fit_end_to_end(subject, tmp_path, capsys):
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            "--keypoints",
            str(subject / "keypoints.json"),
            "--camera",
            str(subject / "camera.json"),
            "--image",
            str(subject / "image.png"),
            "--mask",
            str(subject / "mask.png"),
            "--out",
            str(out),
            "--silhouette-resolutions",
            "64",
            "--silhouette-iterations",
            "8",
        ]
    )
    assert rc == 0
    assert "shipped open whole-body model" in capsys.readouterr().err  # a note, on standard error
    params = np.load(out / "params.npz")
    for name, width in (
        ("body_pose", 63),
        ("left_hand_pose", 45),
        ("right_hand_pose", 45),
        ("jaw_pose", 3),
        ("expression", 16),
    ):
        assert params[name].shape == (1, width), name  # [frames, width]
    assert params["keypoints_2d"].shape == (1, 1, 137, 2) and str(params["model"]) == "smplx"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["layout"] == "wholebody"
    assert metrics["whole_body"]["held_at_rest"] == []
    assert metrics["reprojection_error_px"] < 3.0
    assert metrics["stages"] == ["keypoints", "silhouette"] and metrics["iou"] > 0.5  # the whole-body mesh refined
    assert (out / "silhouette.png").exists() and (out / "stages" / "keypoints" / "params.npz").exists()
    lines = (out / "mesh.obj").read_text().splitlines()
    assert sum(ln.startswith("v ") for ln in lines) == 13348
    payload = json.loads((out / "params.json").read_text())
    assert len(payload["left_hand_pose"]) == 1 and len(payload["left_hand_pose"][0]) == 45


def test_body_only_file_with_the_whole_body_model(subject, tmp_path):
    kp = json.loads((subject / "keypoints.json").read_text())
    for field in ("hand_left_keypoints_2d", "hand_right_keypoints_2d", "face_keypoints_2d"):
        kp["people"][0][field] = []
    (tmp_path / "kp.json").write_text(json.dumps(kp))
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            "--keypoints",
            str(tmp_path / "kp.json"),
            "--camera",
            str(subject / "camera.json"),
            "--model",
            "open-smplx",
            "--no-silhouette",
            "--out",
            str(out),
            "--quiet",  # plumbing: a short stage
            "--keypoint-option",
            "starts.poses=1",
            "--keypoint-option",
            "final_iters=10",
        ]
    )
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert sorted(metrics["whole_body"]["held_at_rest"]) == [
        "expression",
        "jaw_pose",
        "left_hand_pose",
        "right_hand_pose",
    ]
    params = np.load(out / "params.npz")
    assert not params["left_hand_pose"].any() and not params["expression"].any()


def test_bad_hand_field_is_one_line_naming_file_and_field(subject, tmp_path, capsys):
    kp = json.loads((subject / "keypoints.json").read_text())
    kp["people"][0]["hand_right_keypoints_2d"] = kp["people"][0]["hand_right_keypoints_2d"][:30]
    bad = tmp_path / "kp.json"
    bad.write_text(json.dumps(kp))
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            "--keypoints",
            str(bad),
            "--camera",
            str(subject / "camera.json"),
            "--no-silhouette",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    err = capsys.readouterr().err.strip()
    assert rc == 2 and not out.exists()
    assert str(bad) in err and "hand_right_keypoints_2d" in err and len(err.splitlines()) == 1
