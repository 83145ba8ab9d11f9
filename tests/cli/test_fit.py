import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fitting"))
from silfit_toy_body import toy_model, write_toy_npz  # noqa: E402

from silfit.camera import Camera, project_points, save_camera  # noqa: E402
from silfit.cli import main  # noqa: E402
from silfit.io.keypoints import model_keypoints, write_openpose_json  # noqa: E402


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    import torch

    d = tmp_path_factory.mktemp("fit_in")
    model_path = write_toy_npz(d / "toy.npz")
    m = toy_model()
    out = m(global_orient=torch.tensor([[np.pi, 0, 0]]), transl=torch.tensor([[0.0, 0.2, 3.0]]))
    cam = Camera.from_image_size(320, 240)
    xy = project_points(model_keypoints(m, out, "body25"), cam)[0].numpy()
    write_openpose_json(d / "kp.json", np.concatenate([xy, np.ones((25, 1))], 1))
    save_camera(cam, d / "camera.json")
    return d, model_path


FAST = ["--quiet"]


def test_fit_writes_all_outputs(inputs, tmp_path):
    d, model = inputs
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            "--keypoints",
            str(d / "kp.json"),
            "--camera",
            str(d / "camera.json"),
            "--model",
            str(model),
            "--no-silhouette",
            "--out",
            str(out),
        ]
        + FAST
    )
    assert rc == 0
    for f in ("params.npz", "params.json", "mesh.obj", "overlay.png", "metrics.json"):
        assert (out / f).exists(), f
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["reprojection_error_px"] < 2.0
    t = metrics["timings_s"]  # the stage's total, not total + its parts
    assert t["keypoints"] == pytest.approx(t["keypoints.total"])
    assert t["keypoints"] < sum(v for k, v in t.items() if k.startswith("keypoints.") and k != "keypoints.total") * 1.5
    lines = (out / "mesh.obj").read_text().splitlines()
    assert sum(ln.startswith("v ") for ln in lines) == toy_model().num_vertices
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".fit.")]


def test_fit_with_image_size_and_focal(inputs, tmp_path):
    d, model = inputs
    # 500 px, not the default max(W, H) = 320: ignoring --focal changes the camera and the fitted depth
    rc = main(
        [
            "fit",
            "--keypoints",
            str(d / "kp.json"),
            "--image-size",
            "320x240",
            "--focal",
            "500",
            "--model",
            str(model),
            "--no-silhouette",
            "--out",
            str(tmp_path / "o"),
        ]
        + FAST
    )
    assert rc == 0
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["camera"]["fx"] == metrics["camera"]["fy"] == 500.0
    assert (metrics["camera"]["width"], metrics["camera"]["height"]) == (320, 240)
    params = json.loads((tmp_path / "o" / "params.json").read_text())
    # the keypoints came from a body 3.0 m away under f = 320: under f = 500 it fits 500/320 as far
    assert params["transl"][0][2] == pytest.approx(3.0 * 500 / 320, rel=0.03), params["transl"]  # [frames, 3]


@pytest.mark.parametrize("case", ["camera_field", "no_camera", "mask", "bad_keypoints"])
def test_fit_errors_are_one_line_and_leave_nothing(inputs, tmp_path, capsys, case):
    d, model = inputs
    kp, cam = d / "kp.json", d / "camera.json"
    extra = []
    if case == "camera_field":
        bad = tmp_path / "cam.json"
        bad.write_text(json.dumps({"fx": 1.0, "fy": 1.0, "cx": 0.0, "cy": 0.0, "width": 320}))
        cam, expect = bad, "height"
    elif case == "no_camera":
        cam, expect = None, "no camera"
    elif case == "mask":
        (tmp_path / "m.png").write_bytes(b"x")
        extra, expect = ["--mask", str(tmp_path / "m.png")], "m.png"
    else:
        kp = tmp_path / "kp.json"
        kp.write_text(json.dumps({"people": [{"pose_keypoints_2d": [1.0] * 30}]}))
        expect = "10 keypoints"
    args = ["fit", "--keypoints", str(kp), "--model", str(model), "--out", str(tmp_path / "out")] + FAST + extra
    if cam is not None:
        args += ["--camera", str(cam)]
    if case != "mask":
        args.append("--no-silhouette")
    assert main(args) == 2
    err = capsys.readouterr().err
    assert expect in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]


SUBJECT = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "subject_000"
SMALL_SILHOUETTE = ["--silhouette-resolutions", "64", "--silhouette-iterations", "6"]


def test_fit_with_mask_writes_the_silhouette_outputs(tmp_path):
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            "--keypoints",
            str(SUBJECT / "keypoints.json"),
            "--camera",
            str(SUBJECT / "camera.json"),
            "--mask",
            str(SUBJECT / "mask.png"),
            "--image",
            str(SUBJECT / "image.png"),
            "--out",
            str(out),
        ]
        + FAST
        + SMALL_SILHOUETTE
    )
    assert rc == 0
    for f in (
        "params.npz",
        "params.json",
        "mesh.obj",
        "overlay.png",
        "side.png",
        "silhouette.png",
        "iou_curve.png",
        "metrics.json",
        "stages/keypoints/params.npz",
        "stages/keypoints/overlay.png",
    ):
        assert (out / f).is_file() and (out / f).stat().st_size > 0, f
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["stages"] == ["keypoints", "silhouette"]
    assert metrics["silhouette_guard"]["kept"] in ("silhouette", "keypoints")
    assert 0.5 < metrics["iou_keypoint_stage"] <= 1 and 0.5 < metrics["iou"] <= 1
    assert set(metrics["timings_s"]) >= {"keypoints", "silhouette"}


@pytest.mark.parametrize("problem", ["size", "empty", "colour"])
def test_malformed_masks_are_clear_errors(tmp_path, capsys, problem):
    import cv2

    mask = cv2.imread(str(SUBJECT / "mask.png"), cv2.IMREAD_UNCHANGED)
    bad = {
        "size": mask[:100],
        "empty": np.zeros_like(mask),
        "colour": np.dstack([mask, np.zeros_like(mask), mask // 3]),
    }[problem]
    cv2.imwrite(str(tmp_path / "bad_mask.png"), bad)
    rc = main(
        [
            "fit",
            "--keypoints",
            str(SUBJECT / "keypoints.json"),
            "--camera",
            str(SUBJECT / "camera.json"),
            "--mask",
            str(tmp_path / "bad_mask.png"),
            "--out",
            str(tmp_path / "out"),
        ]
        + FAST
    )
    assert rc == 2
    err = capsys.readouterr().err
    assert "bad_mask.png" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "case",
    [
        "binary_keypoints",
        "string_numbers",
        "huge_camera",
        "huge_image_size",
        "person",
        "hostile_model",
        "directory_as_keypoints",
        "huge_image",
    ],
)
def test_hostile_and_broken_inputs_exit_2_with_one_line(inputs, tmp_path, capsys, case):

    d, model = inputs
    kp, cam, extra, expect = d / "kp.json", ["--camera", str(d / "camera.json")], [], None
    if case == "binary_keypoints":
        kp = tmp_path / "kp.json"
        kp.write_bytes(bytes(range(256)))
        expect = "kp.json: not a text"
    elif case == "string_numbers":
        kp = tmp_path / "kp.json"
        kp.write_text(json.dumps({"people": [{"pose_keypoints_2d": ["12.5"] * 75}]}))
        expect = "field 'people[0].pose_keypoints_2d' value 0 is '12.5'"
    elif case == "huge_camera":
        (tmp_path / "cam.json").write_text(
            json.dumps(dict(fx=1e5, fy=1e5, cx=5e4, cy=5e4, width=100000, height=100000))
        )
        cam, expect = ["--camera", str(tmp_path / "cam.json")], "cam.json: camera width/height: 100000x100000"
    elif case == "huge_image_size":
        cam, expect = ["--image-size", "100000x100000"], "--image-size: image size 100000x100000 pixels is larger"
    elif case == "person":
        extra, expect = ["--person", "first"], "--person 'first'"
    elif case == "hostile_model":
        marker = tmp_path / "ran"
        evil = tmp_path / "SMPL_NEUTRAL.pkl"
        evil.write_bytes(b"cos\nsystem\n(V" + f"touch {marker}".encode() + b"\ntR.")
        model, expect = evil, "refused to unpickle 'os.system'"
    elif case == "directory_as_keypoints":
        kp, expect = tmp_path, "keypoint file not found"
    else:
        from PIL import Image

        Image.new("L", (20000, 8)).save(tmp_path / "wide.png")
        cam, expect = ["--image", str(tmp_path / "wide.png")], "wide.png: image size 20000x8 pixels is larger"
    out = tmp_path / "new" / "out"
    rc = main(
        ["fit", "--keypoints", str(kp), "--model", str(model), "--no-silhouette", "--out", str(out)]
        + cam
        + extra
        + FAST
    )
    err = capsys.readouterr().err
    assert rc == 2, err
    assert expect in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not (tmp_path / "new").exists()
    if case == "hostile_model":
        assert not (tmp_path / "ran").exists()


def test_check_only_reads_everything_and_writes_nothing(inputs, tmp_path, capsys):
    d, model = inputs
    args = [
        "fit",
        "--keypoints",
        str(d / "kp.json"),
        "--camera",
        str(d / "camera.json"),
        "--model",
        str(model),
        "--out",
        str(tmp_path / "out"),
        "--check-only",
    ]
    assert main(args) == 0
    assert "inputs OK" in capsys.readouterr().out and not (tmp_path / "out").exists()
    (tmp_path / "prior.pkl").write_bytes(b"cos\nsystem\n(Vtouch " + str(tmp_path / "ran").encode() + b"\ntR.")
    assert main(args + ["--pose-prior", str(tmp_path / "prior.pkl")]) == 2
    assert "prior.pkl: refused to unpickle 'os.system'" in capsys.readouterr().err
    assert not (tmp_path / "ran").exists()


def test_fit_camera_extrinsics_are_checked_and_reported(inputs, tmp_path, capsys):
    # one image: camera.json's R, t are validated as for rigs and said not to be applied
    d, model = inputs
    cam = json.loads((d / "camera.json").read_text())
    c, s = np.cos(0.3), np.sin(0.3)
    (tmp_path / "rt.json").write_text(json.dumps({**cam, "R": [[c, 0, s], [0, 1, 0], [-s, 0, c]], "t": [0.1, 0, 0]}))
    (tmp_path / "bad.json").write_text(json.dumps({**cam, "R": [[1, 0, 0], [0, 1, 0], [0, 0, 2]], "t": [0, 0, 0]}))
    args = ["fit", "--keypoints", str(d / "kp.json"), "--model", str(model), "--no-silhouette"]
    assert main(args + ["--camera", str(tmp_path / "bad.json"), "--out", str(tmp_path / "o_bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.json" in err and "'R'" in err and not (tmp_path / "o_bad").exists()
    assert main(args + ["--camera", str(tmp_path / "rt.json"), "--out", str(tmp_path / "o")]) == 0
    assert "warning:" in (err := capsys.readouterr().err) and "R, t not applied" in err
    assert "R, t not applied" in json.loads((tmp_path / "o" / "metrics.json").read_text())["camera_source"]


def test_fit_export_writes_upright_glb_and_ply(inputs, tmp_path, capsys):
    import trimesh

    from silfit.outputs.export import to_upright

    d, model = inputs
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            "--keypoints",
            str(d / "kp.json"),
            "--camera",
            str(d / "camera.json"),
            "--model",
            str(model),
            "--no-silhouette",
            "--export",
            "glb,ply",
            "--out",
            str(out),
        ]
        + FAST
    )
    err = capsys.readouterr().err  # the fit's warnings (a depth warning, say): not part of the bad run's one line below
    assert rc == 0, err
    params = np.load(out / "params.npz")  # the camera frame (as mesh.obj), as documented
    joints, vertices = (
        params["joints"].reshape(-1, 24, 3)[0],
        params["vertices"].reshape(-1, toy_model().num_vertices, 3)[0],
    )
    assert joints[15, 1] < joints[7, 1]  # camera frame: the head (joint 15) above the ankle (7) means smaller y
    for name in ("mesh.glb", "mesh.ply"):
        loaded = trimesh.load(out / name, process=False)
        mesh = loaded.geometry["body"] if isinstance(loaded, trimesh.Scene) else loaded
        assert np.allclose(mesh.vertices, to_upright(vertices), atol=1e-5), name
        head, foot = to_upright(joints[15]), to_upright(joints[7])
        assert head[1] > foot[1], name
        top = mesh.vertices[:, 1].argmax()
        assert np.linalg.norm(mesh.vertices[top, [0, 2]] - head[[0, 2]]) < 0.3, name  # the highest point is the head's
    assert (
        main(
            [
                "fit",
                "--keypoints",
                str(d / "kp.json"),
                "--camera",
                str(d / "camera.json"),
                "--model",
                str(model),
                "--no-silhouette",
                "--export",
                "obj",
                "--out",
                str(tmp_path / "bad"),
            ]
            + FAST
        )
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--export 'obj'" in err and not (tmp_path / "bad").exists()
    assert main(["fit", "--rig", str(d), "--export", "glb", "--out", str(tmp_path / "rig")] + FAST) == 2
    assert "--export with --rig" in capsys.readouterr().err and not (tmp_path / "rig").exists()


def test_fit_hypotheses_writes_each_solution_and_records_them(inputs, tmp_path, capsys):
    import cv2
    import torch

    from silfit.io.fit import read_fit

    body = toy_model()

    d, model = inputs
    out = tmp_path / "fit"
    rc = main(
        [
            "fit",
            "--keypoints",
            str(d / "kp.json"),
            "--camera",
            str(d / "camera.json"),
            "--model",
            str(model),
            "--no-silhouette",
            "--hypotheses",
            "2",
            "--out",
            str(out),
        ]
        + FAST
    )
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())
    hyps = metrics["hypotheses"]
    assert 1 <= len(hyps) <= 2 and hyps[0]["rank"] == 1 and hyps[0]["gap"] == 0.0
    assert all((out / "hypotheses" / str(h["rank"]) / "params.npz").is_file() for h in hyps)
    assert not (out / "hypotheses" / str(len(hyps) + 1)).exists()
    assert metrics["branch_search"][0]["tried"][0]["flip"] == metrics["branch_search"][0]["kept"]
    best = read_fit(out / "hypotheses" / "1")  # the first is the fit itself
    assert np.allclose(best.frame(0)["body_pose"], read_fit(out).frame(0)["body_pose"], atol=1e-5)
    for h in hyps:  # each one a fit of its own: its record, its mesh posed from its parameters, no silhouette stage
        d_h = out / "hypotheses" / str(h["rank"])
        record = json.loads((d_h / "params.json").read_text())
        assert (record["rank"], record["label"], record["kept"], record["params_from"]) == (
            h["rank"],
            h["label"],
            h["rank"] == 1,
            "keypoint stage",
        )
        assert not (d_h / "stages").exists()
        v = np.array(
            [
                [float(x) for x in line.split()[1:]]
                for line in (d_h / "mesh.obj").read_text().splitlines()
                if line.startswith("v ")
            ]
        )
        params = {k: torch.as_tensor(x[None], dtype=torch.float32) for k, x in read_fit(d_h).frame(0).items()}
        assert np.allclose(v, body(**params).vertices[0].numpy(), atol=1e-5)
    sheet = cv2.imread(str(out / "hypotheses.png"))  # each hypothesis from the front and the side
    assert sheet.ndim == 3 and sheet.shape[1] > sheet.shape[0] and sheet.std() > 10
    capsys.readouterr()
    assert main(["fit", "--rig", str(d), "--hypotheses", "2", "--out", str(tmp_path / "rig")] + FAST) == 2
    assert "--hypotheses with --sequence/--rig" in capsys.readouterr().err  # refused for the flag, not for the folder


def test_silhouette_option_reaches_the_stage_and_a_bad_one_is_one_line(inputs, tmp_path, capsys):
    """``--silhouette-option NAME=VALUE`` (as fit-dataset's): the job's silhouette stage takes it, with
    ``--silhouette-resolutions/--silhouette-iterations`` beside it; a bad option, or a level given as one, exits 2
    with one line and writes nothing."""
    from silfit.cli import build_parser
    from silfit.cli.jobs import build_job

    d, model = inputs
    image = ["fit", "--keypoints", str(d / "kp.json"), "--camera", str(d / "camera.json"), "--model", str(model)]
    job = build_job(
        build_parser().parse_args(
            image
            + [
                "--silhouette-option",
                "alternatives_margin=0",
                "--silhouette-option",
                "plausibility_guard=false",
                "--silhouette-resolutions",
                "64",
                "--silhouette-iterations",
                "3",
                "--out",
                str(tmp_path / "x"),
            ]
        )
    )
    cfg = job.silhouette_config
    assert cfg.alternatives_margin == 0.0 and cfg.plausibility_guard is False
    assert cfg.resolutions == (64,) and cfg.iterations == (3,) and cfg.alternatives_max == 2  # the rest: defaults
    _each_bad_option_is_one_line(
        image + FAST,
        "--silhouette-option",
        (
            ("nope=1", "unknown silhouette-stage option 'nope'"),
            ("alternatives_margin=x", "alternatives_margin"),
            ("choice_margin=-1", "choice_margin must be 0 or more"),
            ("spp", "expected NAME=VALUE"),
            ("resolutions=64", "give --silhouette-resolutions instead"),
        ),
        tmp_path,
        capsys,
    )


def _each_bad_option_is_one_line(command, flag, cases, tmp_path, capsys):
    """Each ``(value, said)`` of ``cases`` given as ``flag value`` to ``command``: exit 2, one line holding ``said``,
    no output folder."""
    for bad, said in cases:
        capsys.readouterr()
        rc = main(command + [flag, bad, "--out", str(tmp_path / "bad")])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and err.count("\n") == 0 and said in err, err
        assert not (tmp_path / "bad").exists()


def test_keypoint_option_reaches_each_mode_and_a_bad_one_is_one_line(inputs, tmp_path, capsys):
    """``--keypoint-option NAME=VALUE`` (as fit-dataset's): an image's keypoint stage takes it over the default
    (with --hypotheses too), a video's per-frame start over the video's own settings (a float field the video
    leaves at None included); a bad option, or --hypotheses given as one, exits 2 with one line."""
    import shutil

    from silfit.cli import build_parser
    from silfit.cli.jobs import build_job
    from silfit.fitting.sequence import SequenceFitConfig

    d, model = inputs
    image = ["fit", "--keypoints", str(d / "kp.json"), "--camera", str(d / "camera.json"), "--model", str(model)]
    job = build_job(
        build_parser().parse_args(
            image
            + [
                "--hypotheses",
                "2",
                "--keypoint-option",
                "final_iters=5",
                "--keypoint-option",
                "pose_iters=5,6,7",
                "--out",
                str(tmp_path / "x"),
            ]
        )
    )
    assert job.keypoint_config.final_iters == 5 and tuple(job.keypoint_config.pose_iters) == (5, 6, 7)
    assert job.keypoint_config.solutions.count == 2
    assert (
        build_job(build_parser().parse_args(image + ["--out", str(tmp_path / "x")])).keypoint_config is None
    )  # the default
    video = tmp_path / "video"
    video.mkdir()
    for f in range(2):
        shutil.copy(d / "kp.json", video / f"clip_{f:012d}_keypoints.json")
    job = build_job(
        build_parser().parse_args(
            [
                "fit",
                "--sequence",
                str(video),
                "--camera",
                str(d / "camera.json"),
                "--model",
                str(model),
                "--keypoint-option",
                "final_tol_change=1e-5",
                "--keypoint-option",
                "final_iters=7",
                "--out",
                str(tmp_path / "y"),
            ]
        )
    )
    start, default = job.sequence_config.keypoint, SequenceFitConfig().keypoint
    assert start.final_iters == 7 and start.final_tol_change == 1e-5 and isinstance(start.final_tol_change, float)
    assert (
        start.branches.refine == default.branches.refine and start.starts.poses == default.starts.poses
    )  # the video's own
    out = tmp_path / "fit"
    assert (
        main(
            image
            + [
                "--no-silhouette",
                "--keypoint-option",
                "starts.poses=1",
                "--keypoint-option",
                "final_iters=5",
                "--out",
                str(out),
            ]
            + FAST
        )
        == 0
    )
    assert (out / "params.npz").is_file()
    _each_bad_option_is_one_line(
        image + FAST,
        "--keypoint-option",
        (
            ("nope=1", "unknown keypoint-stage option 'nope'"),
            ("final_iters=x", "final_iters"),
            ("final_iters", "expected NAME=VALUE"),
            ("hypotheses=2", "give --hypotheses instead"),
            ("solutions.count=2", "give --hypotheses instead"),  # its name in the group (issue 57)
        ),
        tmp_path,
        capsys,
    )
