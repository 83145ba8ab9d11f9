"""``silfit detect`` and ``silfit fit --image`` on a real photograph and on a shipped render."""

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from silfit.cli import main
from silfit.io.keypoints import read_keypoints
from silfit.silhouette.masks import read_mask

SUBJECT = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "subject_000"
# a 128-px window: at 64 px (12 steps) the recovery test's fit measured 31 mm on one CPU and 51 mm
# on another (AVX-512/AMX), a window too coarse for its 4,075-px mask to constrain the shape
FAST_SILHOUETTE = ["--silhouette-resolutions", "128", "--silhouette-iterations", "12", "--quiet"]


@pytest.fixture(scope="module")
def astronaut():
    """scikit-image's public-domain portrait of Eileen Collins (NASA): head and upper body only."""
    skimage = pytest.importorskip("skimage")
    path = Path(skimage.__file__).parent / "data" / "astronaut.png"
    assert path.is_file()
    return path


def test_detect_writes_keypoints_mask_and_report(astronaut, tmp_path):
    out = tmp_path / "det"
    assert main(["detect", str(astronaut), "--out", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["detection.json", "detection.png", "keypoints.json", "mask.png"]
    kp = read_keypoints(out / "keypoints.json")
    assert kp.layout == "body25"
    names = kp.names
    for leg in ("right_knee", "left_knee", "right_ankle", "left_ankle", "left_heel", "right_big_toe"):
        assert kp.conf[names.index(leg)] == 0, leg
    for upper in ("nose", "neck", "left_shoulder", "right_shoulder", "left_eye", "right_ear"):
        assert kp.conf[names.index(upper)] > 0.5, upper
    mask = read_mask(out / "mask.png", size=(512, 512))
    # The face lies inside the mask, the flag (top-left corner) outside it.
    assert mask[130, 220] and not mask[60, 20]
    report = json.loads((out / "detection.json").read_text())
    (person,) = report["people"]
    assert person["lower_body_visible"] is False
    assert any("lower body not visible" in w for w in person["warnings"])
    assert len(person["landmarks"]) == 33 and report["focal_px"] is None


def test_detect_coco17_layout(astronaut, tmp_path):
    assert main(["detect", str(astronaut), "--out", str(tmp_path / "c"), "--layout", "coco17", "--quiet"]) == 0
    assert read_keypoints(tmp_path / "c" / "keypoints.json").layout == "coco17"


def test_fit_from_the_photo_alone_reports_the_truncation(astronaut, tmp_path):
    # Keypoint stage only here; tests/detect/test_demo.py runs both stages on the same photo.
    out = tmp_path / "fit"
    assert main(["fit", "--image", str(astronaut), "--no-silhouette", "--out", str(out), "--quiet"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["stages"] == ["keypoints"]
    assert metrics["keypoints"] is None and metrics["detection"]["lower_body_visible"] is False
    assert any("lower body not visible" in w for w in metrics["warnings"])
    assert metrics["camera_source"] == "default max(W, H)" and metrics["camera"]["fx"] == 512


def test_fit_image_on_a_render_recovers_the_body(tmp_path):
    import torch

    from silfit import load_body_model
    from silfit.io.subjects import read_gt
    from silfit.eval.metrics import procrustes_align

    out = tmp_path / "fit"
    args = ["fit", "--image", str(SUBJECT / "image.png"), "--camera", str(SUBJECT / "camera.json"), "--out", str(out)]
    assert main(args + FAST_SILHOUETTE) == 0
    params = np.load(out / "params.npz")
    model = load_body_model()
    with torch.no_grad():
        verts = (
            model(
                **{
                    k: torch.as_tensor(params[k][None] if params[k].ndim == 1 else params[k]).float()
                    for k in ("betas", "body_pose", "global_orient", "transl")
                }
            )
            .vertices[0]
            .numpy()
        )
    gt = read_gt(SUBJECT / "gt.npz").vertices
    pa_pve = 1000 * np.linalg.norm(procrustes_align(verts, gt) - gt, axis=-1).mean()
    # Measured 30 mm (keypoint stage alone from the detected keypoints: 27 mm; the default
    # silhouette levels: 24 mm); benchmarks/bench_detect.py measures it on 30+ subjects.
    assert pa_pve < 50.0, pa_pve
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["camera_source"] == "camera file" and metrics["iou"] > 0.85


def test_explicit_keypoints_win_and_exif_focal_is_used(tmp_path):
    photo = tmp_path / "photo.jpg"
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 36  # 35 mm equivalent focal length: 36 mm
    Image.open(SUBJECT / "image.png").save(photo, quality=95, exif=exif.tobytes())
    out = tmp_path / "fit"
    kp = SUBJECT / "keypoints.json"
    assert (
        main(["fit", "--keypoints", str(kp), "--image", str(photo), "--no-silhouette", "--out", str(out), "--quiet"])
        == 0
    )
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["keypoints"] == str(kp) and "detection" not in metrics
    assert metrics["camera_source"].startswith("EXIF FocalLengthIn35mmFilm")
    assert metrics["camera"]["fx"] == pytest.approx(36 * np.hypot(256, 256) / np.hypot(36, 24))


@pytest.mark.parametrize("case", ["missing", "empty", "no_person"])
def test_bad_photos_exit_2_with_one_line(case, tmp_path, capsys):
    image = tmp_path / f"{case}.png"
    if case == "empty":
        image.write_bytes(b"")
    elif case == "no_person":
        Image.fromarray(np.full((120, 160, 3), 200, np.uint8)).save(image)
    for command in (["detect", str(image)], ["fit", "--image", str(image), "--quiet"]):
        out = tmp_path / f"out_{command[0]}"
        assert main(command + ["--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(image) in err, err
        expected = {"missing": "image not found", "empty": "cannot read the image", "no_person": "no person found"}[
            case
        ]
        assert expected in err
        assert not out.exists()


def test_fit_needs_keypoints_or_an_image(tmp_path, capsys):
    assert main(["fit", "--image-size", "64x64", "--out", str(tmp_path / "o")]) == 2
    assert "give --keypoints" in capsys.readouterr().err


def test_detect_several_people(tmp_path):
    a = np.asarray(Image.open(SUBJECT / "image.png"))
    b = np.asarray(Image.open(SUBJECT.parent / "subject_004" / "image.png"))
    image = tmp_path / "two.png"
    Image.fromarray(np.concatenate([a, b], axis=1)).save(image)
    out = tmp_path / "det"
    assert main(["detect", str(image), "--people", "3", "--out", str(out), "--quiet"]) == 0
    assert {p.name for p in out.iterdir()} >= {"mask.png", "mask_1.png", "keypoints.json"}
    people = json.loads((out / "keypoints.json").read_text())["people"]
    assert len(people) == 2
    # Largest first, as read_keypoints(person="largest") picks.
    assert (
        read_keypoints(out / "keypoints.json", person=0).visible_area()
        >= read_keypoints(out / "keypoints.json", person=1).visible_area()
    )
    masks = [read_mask(out / m, size=(512, 256)) for m in ("mask.png", "mask_1.png")]
    assert not (masks[0] & masks[1]).any()
    with pytest.raises(SystemExit) as exit_:  # argparse rejects it: usage line, status 2
        main(["detect", str(image), "--people", "0", "--out", str(tmp_path / "x")])
    assert exit_.value.code == 2 and not (tmp_path / "x").exists()
    assert main(["detect", str(image), "--people", "all", "--out", str(tmp_path / "all"), "--quiet"]) == 0
    assert len(json.loads((tmp_path / "all" / "keypoints.json").read_text())["people"]) == 2


def test_fit_every_person_of_a_photo(tmp_path, capsys, monkeypatch):
    """``silfit fit --image --people all``: each detected person into OUT/person_<i>/, the people fitted as one
    batch (one model and settings for all: silfit.run.run_batch groups the jobs that share them)."""
    import silfit.run

    a = np.asarray(Image.open(SUBJECT / "image.png"))
    b = np.asarray(Image.open(SUBJECT.parent / "subject_004" / "image.png"))
    image = tmp_path / "two.png"
    Image.fromarray(np.concatenate([a, b], axis=1)).save(image)
    out = tmp_path / "fits"
    batches, real = [], silfit.run._fit_group
    monkeypatch.setattr(
        silfit.run, "_fit_group", lambda jobs, isolate: batches.append(len(jobs)) or real(jobs, isolate)
    )
    assert main(["fit", "--image", str(image), "--people", "all", "--no-silhouette", "--out", str(out), "--quiet"]) == 0
    assert batches == [2], batches  # before: two batches of one (each person's job had its own model object)
    assert json.loads((out / "person_0" / "params.json").read_text()) != json.loads(
        (out / "person_1" / "params.json").read_text()
    )
    listed = json.loads((out / "people.json").read_text())["people"]
    assert [p["folder"] for p in listed] == ["person_0", "person_1"]
    xs = [json.loads((out / p["folder"] / "params.json").read_text()) for p in listed]
    assert all((out / p["folder"] / "mesh.obj").is_file() for p in listed) and len(xs) == 2
    assert (
        main(
            [
                "fit",
                "--image",
                str(image),
                "--people",
                "all",
                "--keypoints",
                str(SUBJECT / "keypoints.json"),
                "--out",
                str(tmp_path / "bad"),
            ]
        )
        == 2
    )
    assert not (tmp_path / "bad").exists()
    capsys.readouterr()
    # a bad flag found once the people are detected (person 0's job) or before: one line, exit 2, no output folder
    for flags in (["--hypotheses", "0"], ["--sequence", str(SUBJECT.parent)]):
        bad = tmp_path / f"bad{flags[0]}"
        assert main(["fit", "--image", str(image), "--people", "all", "--quiet", "--out", str(bad)] + flags) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len([line for line in err if "error" in line]) == 1 and "Traceback" not in "\n".join(err)
        assert not bad.exists(), flags


def test_detect_does_not_write_an_exif_focal_outside_the_bounds(tmp_path, capsys):
    photo = tmp_path / "photo.jpg"
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 65535  # fx = 1.1e6 px on this 256 px image: the body 1.7 km away
    Image.open(SUBJECT / "image.png").save(photo, quality=95, exif=exif.tobytes())
    assert main(["detect", str(photo), "--out", str(tmp_path / "det")]) == 0
    printed = capsys.readouterr().err  # warnings: standard error
    report = json.loads((tmp_path / "det" / "detection.json").read_text())
    assert report["focal_px"] is None and "ignored" in report["focal_source"]
    assert len(report["warnings"]) == 1 and "FocalLengthIn35mmFilm (65535 mm)" in report["warnings"][0]
    assert f"warning: {report['warnings'][0]}" in printed
    # silfit fit says so too (and, in silfit/cli/fit.py, falls back to the default focal: photo.focal() is None)
    kp = SUBJECT / "keypoints.json"
    assert (
        main(["fit", "--keypoints", str(kp), "--image", str(photo), "--out", str(tmp_path / "fit"), "--check-only"])
        == 0
    )
    assert f"warning: {report['warnings'][0]}" in capsys.readouterr().err


def test_a_16_bit_greyscale_photo_is_read_and_a_cmyk_one_refused(tmp_path, capsys):
    grey = np.asarray(Image.open(SUBJECT / "image.png").convert("L")).astype(np.uint16) * 257
    Image.fromarray(grey).save(tmp_path / "grey16.png")  # decoded 90 % white before: "no person found"
    assert main(["detect", str(tmp_path / "grey16.png"), "--out", str(tmp_path / "det"), "--quiet"]) == 0
    assert read_keypoints(tmp_path / "det" / "keypoints.json").conf.max() > 0.5
    Image.open(SUBJECT / "image.png").convert("CMYK").save(tmp_path / "cmyk.jpg")
    assert main(["detect", str(tmp_path / "cmyk.jpg"), "--out", str(tmp_path / "det2"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cmyk.jpg: image is in CMYK" in err and not (tmp_path / "det2").exists()


def test_a_person_that_fails_is_set_aside_and_the_others_written(tmp_path, capsys, monkeypatch):
    """``--people all`` fits the people as one batch (silfit.run.run_batch): a person whose keypoints are refused
    is set aside with a warning and a failed row in people.json; the others are written."""
    import silfit.run as run_module
    from silfit.errors import InputError

    a = np.asarray(Image.open(SUBJECT / "image.png"))
    b = np.asarray(Image.open(SUBJECT.parent / "subject_004" / "image.png"))
    image = tmp_path / "two.png"
    Image.fromarray(np.concatenate([a, b], axis=1)).save(image)
    real, calls = run_module.check, []

    def refusing(job):  # the second person's keypoints refused, as check() refuses a degenerate set
        calls.append(job)
        if len(calls) == 2:
            raise InputError(str(image), "too few confident keypoints (test)", field="keypoints")
        return real(job)

    monkeypatch.setattr(run_module, "check", refusing)
    out = tmp_path / "fits"
    assert main(["fit", "--image", str(image), "--people", "all", "--no-silhouette", "--out", str(out), "--quiet"]) == 0
    rows = json.loads((out / "people.json").read_text())["people"]
    assert [r["status"] for r in rows] == ["ok", "failed"] and "too few confident keypoints" in rows[1]["error"]
    assert (out / "person_0" / "params.npz").is_file() and not (out / "person_1").exists()
    assert "person 1 set aside" in capsys.readouterr().err


def test_people_with_other_settings_keep_their_own():
    """fit --people all shares one model and settings among the people's jobs only where they are the same."""
    from dataclasses import replace

    from silfit import load_body_model
    from silfit.camera import Camera
    from silfit.cli.fit import _shared_settings
    from silfit.fitting.keypoint_stage import KeypointFitConfig
    from silfit.fitting.problem import Problem
    from silfit.io.keypoints import KeypointSet
    from silfit.run import Job

    kp = KeypointSet(np.full((25, 2), 32.0), np.ones(25), "body25")
    base = Job(
        Problem.single(kp, Camera.from_image_size(64, 64), None), load_body_model(), keypoint_config=KeypointFitConfig()
    )
    same = replace(base, model=load_body_model(), keypoint_config=KeypointFitConfig())  # equal, not the same objects
    other = replace(base, model=load_body_model(), keypoint_config=KeypointFitConfig(final_iters=5))
    a, b, c = _shared_settings([base, same, other])
    assert b.model is a.model and b.keypoint_config is a.keypoint_config
    assert c.model is not a.model and c.keypoint_config.final_iters == 5
