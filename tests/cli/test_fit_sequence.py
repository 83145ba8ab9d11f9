"""``silfit fit --sequence`` and ``silfit synth --videos`` end to end on a tiny sequence (toy body)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fitting"))
from silfit_toy_body import toy_model, write_toy_npz  # noqa: E402

from silfit.cli import main  # noqa: E402
from silfit.synth.motion import SequenceConfig, generate_sequence_dataset  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from runner.helpers import FAST as KP_FAST  # noqa: E402  (a short keypoint stage per frame: the video path's plumbing)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    d = tmp_path_factory.mktemp("seq_in")
    model_path = write_toy_npz(d / "toy.npz")
    cfg = SequenceConfig(seed=3, frames=5, size=64, noise_px=0.5, motions=("walk",))
    generate_sequence_dataset(d / "data", 1, cfg, model=toy_model())
    seq = d / "data" / "seq_000"
    # frame 2: OpenPose saw nobody
    (seq / "keypoints" / "seq_000_000000000002_keypoints.json").write_text(json.dumps({"version": 1.3, "people": []}))
    return seq, model_path


def test_synth_sequence_writes_per_frame_files_and_truth(sequence):
    seq, _ = sequence
    assert len(list((seq / "keypoints").glob("*_keypoints.json"))) == 5
    assert len(list((seq / "masks").glob("*.png"))) == 5 and (seq / "camera.json").is_file()
    gt = np.load(seq / "gt.npz")
    assert gt["betas"].shape == (10,) and gt["body_pose"].shape == (5, 69) and gt["joints"].shape == (5, 24, 3)
    index = json.loads((seq.parent / "index.json").read_text())
    assert index["format"] == "silfit-synthetic-sequence" and index["sequences"][0]["motion"] == "walk"


def test_fit_sequence_writes_one_shape_and_per_frame_outputs(sequence, tmp_path, capsys):
    seq, model = sequence
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            *KP_FAST,
            "--sequence",
            str(seq),
            "--model",
            str(model),
            "--out",
            str(out),
            "--meshes",
            "--sequence-iterations",
            "10",
            "--silhouette-resolutions",
            "32",
            "--silhouette-iterations",
            "3",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    p = np.load(out / "params.npz")
    assert p["betas"].shape == (5, 10) and (p["betas"] == p["betas"][0]).all()  # one shape, repeated per frame
    assert p["body_pose"].shape == (5, 69) and p["transl"].shape == (5, 3)
    assert p["frames"].tolist() == [0, 1, 2, 3, 4]
    assert json.loads((out / "params.json").read_text())["bridged"] == [False, False, True, False, False]
    assert np.isfinite(p["body_pose"]).all()
    # the written keypoints are the final (silhouette-stage) body's, not the keypoint stage's
    import torch

    from silfit import load_body_model
    from silfit.camera import Camera, project_points
    from silfit.io.keypoints import model_keypoints

    body = load_body_model(model)
    T = lambda n: torch.as_tensor(p[n], dtype=body.dtype)  # noqa: E731
    with torch.no_grad():
        kp3 = model_keypoints(
            body, body(**{n: T(n) for n in ("betas", "body_pose", "global_orient", "transl")}), "body25"
        )
    cam = Camera.from_intrinsics(p["camera_intrinsics"][0], p["image_size"][0])
    np.testing.assert_allclose(p["keypoints_2d"][:, 0], project_points(kp3.double(), cam).numpy(), atol=0.05)
    assert sorted(f.name for f in (out / "meshes").iterdir()) == [f"frame_{i:012d}.obj" for i in range(5)]
    for f in ("params.json", "metrics.json", "strip.png", "overlay.gif", "stages/per_frame/params.npz"):
        assert (out / f).is_file(), f
    m = json.loads((out / "metrics.json").read_text())
    assert m["bridged_frames"] == [2] and m["silhouette"] == "run" and len(m["silhouette_iou"]) == 5
    assert m["reprojection_error_px_keypoint_stage"] > 0 and m["reprojection_error_px"] > 0
    assert "bridged" in capsys.readouterr().err  # a warning, on standard error


def test_fit_sequence_bad_input_is_one_line(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["fit", "--sequence", str(empty), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no OpenPose per-frame files" in err and not (tmp_path / "o").exists()
    (empty / "v_000000000000_keypoints.json").write_text("{not json")
    assert main(["fit", "--sequence", str(empty), "--out", str(tmp_path / "o")]) == 2
    assert "v_000000000000_keypoints.json" in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_fit_sequence_check_only_reads_the_masks(sequence, tmp_path, capsys):
    import shutil

    seq, model = sequence
    copy = tmp_path / "seq"
    shutil.copytree(seq, copy)
    bad = sorted((copy / "masks").glob("*.png"))[1]
    bad.write_bytes(b"not a png")
    assert (
        main(["fit", "--sequence", str(copy), "--model", str(model), "--out", str(tmp_path / "o"), "--check-only"]) == 2
    )
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and bad.name in err and not (tmp_path / "o").exists()


def test_fit_sequence_finds_openpose_folders_and_cameras_beside_the_frames(sequence, tmp_path, capsys):
    import shutil

    seq, model = sequence
    flat = tmp_path / "flat"  # the keypoint files and camera.json in one folder, as OpenPose users keep them
    shutil.copytree(seq / "keypoints", flat)
    shutil.copy(seq / "camera.json", flat / "camera.json")
    fx = json.loads((seq / "camera.json").read_text())["fx"]
    base = ["fit", "--model", str(model), "--out", str(tmp_path / "o"), "--check-only"]
    assert main(base + ["--sequence", str(flat)]) == 0
    out = capsys.readouterr().out
    assert f"camera: camera file {flat / 'camera.json'} (fx {fx:g}" in out, out
    nested = tmp_path / "nested"  # DIR/openpose/ with camera.json beside it
    shutil.copytree(seq / "keypoints", nested / "openpose")
    shutil.copy(seq / "camera.json", nested / "camera.json")
    assert main(base + ["--sequence", str(nested), "--focal", "700"]) == 0
    out = capsys.readouterr().out
    assert "5 frames" in out and f"camera file {nested / 'camera.json'} with --focal 700 (fx 700" in out, out


def test_fit_sequence_mismatched_silhouette_levels_fail_before_fitting(sequence, tmp_path, capsys, monkeypatch):
    import silfit.fitting.sequence

    def no_fit(*a, **k):
        raise AssertionError("the flags must be checked before the sequence is fitted")

    monkeypatch.setattr(silfit.fitting.sequence, "fit_sequence", no_fit)
    seq, model = sequence
    rc = main(
        [
            "fit",
            "--sequence",
            str(seq),
            "--model",
            str(model),
            "--out",
            str(tmp_path / "o"),
            "--silhouette-resolutions",
            "32,64",
            "--silhouette-iterations",
            "3",
        ]
    )
    assert rc == 2
    captured = capsys.readouterr()
    assert "same number of levels" in captured.err and "wrote" not in captured.out and not (tmp_path / "o").exists()


def test_fit_sequence_failing_write_leaves_no_parent_folder(sequence, tmp_path, capsys, monkeypatch):
    import silfit.run  # run.write calls the one writer, silfit.outputs.write's, by this name

    def failing_save(fit, out, *a, **k):  # the writer made the parents, then failed
        Path(out).parent.mkdir(parents=True)
        raise OSError(f"{out}: disk full")

    monkeypatch.setattr(silfit.run, "write_folder", failing_save)
    seq, model = sequence
    out = tmp_path / "new" / "deeper" / "fit"
    rc = main(
        [
            "fit",
            *KP_FAST,
            "--sequence",
            str(seq),
            "--model",
            str(model),
            "--out",
            str(out),
            "--sequence-iterations",
            "2",
            "--no-silhouette",
            "--quiet",
        ]
    )
    assert rc == 2 and "disk full" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_fit_sequence_frame_with_an_empty_mask_has_no_silhouette_term(sequence, tmp_path, capsys):
    import shutil

    from PIL import Image

    seq, model = sequence
    copy = tmp_path / "seq"
    shutil.copytree(seq, copy)
    masks = sorted((copy / "masks").glob("*.png"))
    size = Image.open(masks[3]).size
    Image.new("L", size, 0).save(masks[3])  # frame 3: the person was not segmented
    shutil.copy(masks[0], masks[0].with_name(masks[0].name.replace("000000000000", "000000000009")))  # not a frame
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            *KP_FAST,
            "--sequence",
            str(copy),
            "--model",
            str(model),
            "--out",
            str(out),
            "--no-video",
            "--quiet",
            "--sequence-iterations",
            "5",
            "--silhouette-resolutions",
            "32",
            "--silhouette-iterations",
            "2",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    assert m["silhouette"] == "run"
    iou = [float("nan") if v is None else v for v in m["silhouette_iou"]]
    assert np.isnan(iou[3]) and all(np.isfinite(iou[f]) for f in (0, 1, 4)), iou
    assert any("empty mask" in w and "[3]" in w for w in m["warnings"]), m["warnings"]
    assert any("1 mask(s) for frames the keypoints do not have, ignored: 9" in w for w in m["warnings"]), m["warnings"]


def test_synth_sequence_flags_reach_the_generator(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    model = write_toy_npz(d / "toy.npz")
    out = tmp_path / "motions"
    rc = main(
        [
            "synth",
            "--videos",
            "--n",
            "2",
            "--frames",
            "6",
            "--fps",
            "12",
            "--motions",
            "squat,wave",
            "--orbit",
            "40",
            "--drop-frames",
            "0.99",
            "--size",
            "48",
            "--seed",
            "5",
            "--model",
            str(model),
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert rc == 0
    seqs = json.loads((out / "index.json").read_text())["sequences"]
    assert [s["motion"] for s in seqs] == ["squat", "wave"]
    assert all(s["frames"] == 6 and s["fps"] == 12 and s["orbit_deg"] == 40 for s in seqs)
    # nearly every frame dropped, never the first or the last
    assert all(s["frames_dropped"] == 4 for s in seqs), seqs
    gt = np.load(out / seqs[0]["name"] / "gt.npz")
    assert gt["body_pose"].shape == (6, 69) and float(gt["fps"]) == 12


def test_a_whole_body_video_fits_hands_and_face_with_the_whole_body_model(tmp_path, capsys):
    """Per-frame OpenPose whole-body JSON (hands and face): the shipped SMPL-X-layout model is chosen as
    for one image, every frame's hands and face are fitted, and the fit file and render carry them."""
    src = Path(__file__).resolve().parents[2] / "data" / "synthetic_wholebody" / "subject_000"
    video = tmp_path / "video"
    video.mkdir()
    doc = json.loads((src / "keypoints.json").read_text())
    for f in range(3):  # the person walks 4 px to the right per frame
        person = dict(doc["people"][0])
        for field in ("pose_keypoints_2d", "hand_left_keypoints_2d", "hand_right_keypoints_2d", "face_keypoints_2d"):
            v = np.asarray(person[field], dtype=float).reshape(-1, 3)
            v[:, 0] += 4.0 * f * (v[:, 2] > 0)
            person[field] = v.ravel().tolist()
        (video / f"clip_{f:012d}_keypoints.json").write_text(json.dumps({**doc, "people": [person]}))
    (video / "camera.json").write_text((src / "camera.json").read_text())
    masks = tmp_path / "masks"
    masks.mkdir()
    for f in range(3):
        (masks / f"clip_{f:012d}.png").write_bytes((src / "mask.png").read_bytes())
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            *KP_FAST,
            "--sequence",
            str(video),
            "--masks",
            str(masks),
            "--out",
            str(out),
            "--sequence-iterations",
            "5",
            "--silhouette-resolutions",
            "32",
            "--silhouette-iterations",
            "2",
            "--no-video",
            "--quiet",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    assert "shipped open whole-body model" in capsys.readouterr().err
    p = np.load(out / "params.npz")
    assert str(p["model"]) == "smplx" and p["body_pose"].shape == (3, 63)
    assert p["left_hand_pose"].shape == (3, 45) and np.abs(p["left_hand_pose"]).max() > 0.05  # fitted, not at rest
    assert p["keypoints_2d"].shape == (3, 1, 137, 2)
    assert json.loads((out / "metrics.json").read_text())["silhouette"] == "run"  # the silhouette stage on SMPL-X too
    assert main(["render", str(out / "params.npz"), "--frame", "2", "--size", "48", "--out", str(tmp_path / "r")]) == 0


def test_fit_sequence_export_writes_one_animated_gltf(sequence, tmp_path, capsys):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "outputs"))
    from test_export import accessor, glb_json_and_blob

    from silfit.outputs.export import to_upright

    seq, model = sequence
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            *KP_FAST,
            "--sequence",
            str(seq),
            "--model",
            str(model),
            "--out",
            str(out),
            "--meshes",
            "--no-silhouette",
            "--sequence-iterations",
            "3",
            "--export",
            "glb,ply",
            "--fps",
            "5",
            "--quiet",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    assert (out / "overlay.gif").is_file()
    gltf, blob = glb_json_and_blob(out / "animation.glb")
    prim = gltf["meshes"][0]["primitives"][0]
    assert len(prim["targets"]) == 5 and gltf["meshes"][0]["extras"]["targetNames"][-1] == "frame_4"
    assert np.allclose(accessor(gltf, blob, gltf["animations"][0]["samplers"][0]["input"]), np.arange(5) / 5)
    import trimesh

    base = accessor(gltf, blob, prim["attributes"]["POSITION"])
    for k in range(5):
        lines = (out / "meshes" / f"frame_{k:012d}.obj").read_text().splitlines()
        obj = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("v ")])  # every vertex
        shown = base + accessor(gltf, blob, prim["targets"][k]["POSITION"])
        assert np.allclose(shown, to_upright(obj), atol=1e-5), k
        ply = trimesh.load(out / "meshes" / f"frame_{k:012d}.ply", process=False)
        assert np.allclose(ply.vertices, to_upright(obj), atol=1e-5), k
        assert shown[:, 1].max() > shown[:, 1].min() + 1.0


def test_fit_sequence_says_which_frames_have_no_mask(sequence, tmp_path, capsys):
    import shutil

    seq, model = sequence
    copy = tmp_path / "seq"
    shutil.copytree(seq, copy)
    sorted((copy / "masks").glob("*.png"))[1].unlink()
    assert (
        main(["fit", "--sequence", str(copy), "--model", str(model), "--out", str(tmp_path / "o"), "--check-only"]) == 0
    )
    out = capsys.readouterr().err  # warnings: standard error
    assert "warning:" in out and "no mask for 1 frame(s) with a person (no silhouette term there): 1" in out, out


def test_a_rig_video_is_synthesised_fitted_over_every_view_and_rendered(sequence, tmp_path, capsys):
    """``silfit synth --videos --cameras 2`` writes a rig whose views are video folders; ``silfit fit --rig``
    fits it as one video seen by every view (world frame, one shape, every view's masks) into one fit file
    of frames x views that ``silfit render`` draws."""
    _, model = sequence
    data = tmp_path / "data"
    assert (
        main(
            [
                "synth",
                "--videos",
                "--cameras",
                "2",
                "--n",
                "1",
                "--frames",
                "3",
                "--size",
                "64",
                "--seed",
                "2",
                "--noise-px",
                "0",
                "--motions",
                "walk",
                "--model",
                str(model),
                "--out",
                str(data),
                "--quiet",
            ]
        )
        == 0
    )
    rig = data / "seq_000"
    assert (rig / "cameras.json").is_file() and len(list((rig / "view_1" / "keypoints").glob("*_keypoints.json"))) == 3
    gt = np.load(rig / "gt.npz")
    assert gt["keypoints_2d_clean"].shape == (3, 2, 25, 2) and gt["joints"].shape == (3, 24, 3)
    assert (
        main(
            [
                "fit",
                "--rig",
                str(rig),
                "--model",
                str(model),
                "--check-only",
                "--views",
                "view_1",
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 0
    )
    assert "a rig video of 3 frames seen by 1 views (view_1), masks read" in capsys.readouterr().out
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            *KP_FAST,
            "--rig",
            str(rig),
            "--model",
            str(model),
            "--out",
            str(out),
            "--sequence-iterations",
            "10",
            "--silhouette-resolutions",
            "32",
            "--silhouette-iterations",
            "2",
            "--meshes",
            "--quiet",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    line = capsys.readouterr().out  # the one summary line of silfit.run.Fit
    assert "3 frames, 0 bridged" in line and "2 views" in line
    p = np.load(out / "params.npz")
    assert str(p["coordinates"]) == "world" and p["views"].tolist() == ["view_0", "view_1"]
    assert p["betas"].shape == (3, 10) and (p["betas"] == p["betas"][0]).all()  # one shape
    assert p["keypoints_2d"].shape == (3, 2, 25, 2) and p["reprojection_error"].shape == (3, 2)
    assert p["camera_R"].shape == (2, 3, 3) and np.nanmax(p["reprojection_error"]) < 3.0
    assert np.linalg.norm(p["joints"] - gt["joints"], axis=-1).mean() < 0.05  # world frame, no alignment
    m = json.loads((out / "metrics.json").read_text())
    assert m["silhouette"] == "run" and np.asarray(m["silhouette_iou"]).shape == (3, 2) and m["coordinates"] == "world"
    for f in (
        "cameras.json",
        "strip.png",
        "overlay.gif",
        "stages/per_frame/params.npz",
        "meshes/frame_000000000002.obj",
    ):
        assert (out / f).is_file(), f
    assert (
        main(["render", str(out / "params.npz"), "--frame", "all", "--size", "32", "--out", str(tmp_path / "r")]) == 0
    )
    assert (tmp_path / "r" / "view_front.gif").is_file()
    assert main(["fit", "--rig", str(rig), "--sequence", str(rig), "--out", str(tmp_path / "y")]) == 2
    assert "a rig video is --rig DIR alone" in capsys.readouterr().err


def test_a_video_the_silhouette_stage_made_less_plausible_keeps_the_keypoint_fit(
    sequence, tmp_path, capsys, monkeypatch
):
    """The plausibility guard (silfit.fitting.plausibility.silhouette_guard) holds for videos as for one image: a refined fit
    judged less plausible is not kept, and the warning says so."""
    import silfit.fitting.plausibility as plausibility

    seq, model = sequence
    real, seen = plausibility.silhouette_guard, []

    def implausible(before, after, where=""):
        seen.append(where)
        decision = real(before, after, where)
        return (
            plausibility.GuardDecision(
                "keypoints", ("stature 2.40 m",), (f"{where}: made the fit less plausible: kept the keypoint fit",)
            )
            if where == "video"
            else decision
        )

    monkeypatch.setattr(plausibility, "silhouette_guard", implausible)
    args = [
        "fit",
        *KP_FAST,
        "--sequence",
        str(seq),
        "--model",
        str(model),
        "--no-video",
        "--quiet",
        "--sequence-iterations",
        "5",
        "--silhouette-resolutions",
        "32",
        "--silhouette-iterations",
        "2",
    ]
    assert main(args + ["--out", str(tmp_path / "kp"), "--no-silhouette"]) == 0
    assert main(args + ["--out", str(tmp_path / "fit")]) == 0, capsys.readouterr().err
    assert "video" in seen
    m = json.loads((tmp_path / "fit" / "metrics.json").read_text())
    assert any("kept the keypoint fit" in w for w in m["warnings"]) and "silhouette_iou" not in m
    a, b = (np.load(tmp_path / d / "params.npz") for d in ("kp", "fit"))
    np.testing.assert_array_equal(a["body_pose"], b["body_pose"])  # the keypoint stage's fit, unchanged
