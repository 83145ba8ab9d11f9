"""Each CLI flag changes the output in a way checked here (a test fails when the flag is ignored).

Cheap: the toy body of ``tests/fitting`` for ``fit`` (keypoint stage only), tiny images for
``synth`` and ``render``.
"""

import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image
from test_fit import FAST, inputs  # noqa: F401  (the module fixture: toy model, keypoints, camera)

from silfit.cli import main


#: A short keypoint schedule: these tests check what a flag changes, not how well the toy body fits.
KP_SHORT = [
    f"--keypoint-option={o}"
    for o in (
        "starts.poses=1",
        "camera_iters=10",
        "pose_iters=10,10,10",
        "shape_iters=5",
        "final_iters=10",
        "branches.post_iters=0",
    )
]


def fit_args(d, model, out, *extra):
    return [
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
        *FAST,
        *KP_SHORT,
        *extra,
    ]


def params(out):
    return {k: np.asarray(v) for k, v in json.loads((out / "params.json").read_text()).items() if k != "camera"}


def test_version_prints_the_package_version(capsys):
    import silfit

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out.strip() == f"silfit {silfit.__version__}"


def test_fit_person_picks_that_person(inputs, tmp_path):  # noqa: F811
    d, model = inputs
    doc = json.loads((d / "kp.json").read_text())
    first = doc["people"][0]
    kp = np.asarray(first["pose_keypoints_2d"]).reshape(-1, 3)
    shifted = kp.copy()
    shifted[:, 0] += 40.0  # the same body 40 px to the right: 40 * 3.0 / 320 = 0.375 m at 3 m (f = 320)
    doc["people"] = [first, {**first, "pose_keypoints_2d": [round(float(v), 4) for v in shifted.reshape(-1)]}]
    two = tmp_path / "two.json"
    two.write_text(json.dumps(doc))
    xs = []
    for person in ("0", "1"):
        out = tmp_path / f"p{person}"
        args = fit_args(d, model, out, "--person", person)
        args[args.index("--keypoints") + 1] = str(two)
        assert main(args) == 0
        xs.append(float(params(out)["transl"].reshape(-1)[0]))
    assert xs[1] - xs[0] == pytest.approx(0.375, rel=0.05), xs


def test_fit_overwrite_replaces_the_folder(inputs, tmp_path, capsys):  # noqa: F811
    d, model = inputs
    out = tmp_path / "fit"
    out.mkdir()
    (out / "stale.txt").write_text("from an earlier run")
    assert main(fit_args(d, model, out)) == 2
    assert "use --overwrite" in capsys.readouterr().err and (out / "stale.txt").exists()
    assert main(fit_args(d, model, out, "--overwrite")) == 0
    assert not (out / "stale.txt").exists() and (out / "params.json").is_file()


def test_fit_gender_selects_the_file_in_a_model_folder(inputs, tmp_path, capsys):  # noqa: F811
    d, model = inputs
    folder = tmp_path / "models"
    folder.mkdir()
    shutil.copy(model, folder / "SMPL_FEMALE.npz")  # only a female model in the folder
    args = fit_args(d, folder, tmp_path / "neutral")
    assert main(args) == 2 and "no neutral SMPL model file" in capsys.readouterr().err
    assert main(fit_args(d, folder, tmp_path / "female", "--gender", "female")) == 0
    assert json.loads((tmp_path / "female" / "metrics.json").read_text())["model"].endswith("SMPL_FEMALE.npz")


def test_fit_pose_prior_changes_the_fit(inputs, tmp_path):  # noqa: F811
    d, model = inputs
    assert main(fit_args(d, model, tmp_path / "default")) == 0
    assert main(fit_args(d, model, tmp_path / "limits", "--pose-prior", "limits")) == 0
    a, b = params(tmp_path / "default")["body_pose"], params(tmp_path / "limits")["body_pose"]
    assert np.abs(a - b).max() > 1e-3  # a different prior, a different optimum


def test_render_alpha_blends_the_overlay(tmp_path):
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"global_orient": [math.pi, 0.0, 0.0], "transl": [0.0, 0.2, 3.0]}))
    cam = {"fx": 60.0, "fy": 60.0, "cx": 39.5, "cy": 29.5, "width": 80, "height": 60}
    (tmp_path / "camera.json").write_text(json.dumps(cam))
    Image.fromarray(np.full((60, 80, 3), 30, dtype=np.uint8)).save(tmp_path / "image.png")
    body = {}
    for alpha in ("0.2", "0.9"):
        out = tmp_path / f"a{alpha}"
        assert (
            main(
                [
                    "render",
                    str(path),
                    "--camera",
                    str(tmp_path / "camera.json"),
                    "--overlay",
                    str(tmp_path / "image.png"),
                    "--mask",
                    "--alpha",
                    alpha,
                    "--out",
                    str(out),
                ]
            )
            == 0
        )
        mask = np.asarray(Image.open(out / "mask.png")) > 127
        overlay = np.asarray(Image.open(out / "overlay.png")).astype(float)
        body[alpha] = overlay[mask].mean() - 30.0  # how far the body pixels are from the image
    # a blend: the body's contribution scales with alpha (0.9 / 0.2 = 4.5)
    assert body["0.9"] / body["0.2"] == pytest.approx(4.5, rel=0.1), body


def synth(tmp_path, name, *extra):
    out = tmp_path / name
    assert main(["synth", "--n", "3", "--seed", "3", "--out", str(out), "--size", "64", "--quiet", *extra]) == 0
    return out, json.loads((out / "index.json").read_text())["subjects"]


def test_synth_camera_and_framing_flags(tmp_path):
    out, subs = synth(
        tmp_path, "ds", "--fov", "30", "30", "--fill", "0.4", "0.4", "--elevation", "0.5", "--roll", "0.5"
    )
    for s in subs:
        cam = json.loads((out / s["name"] / "camera.json").read_text())
        assert cam["fx"] == pytest.approx(32.0 / math.tan(math.radians(15.0)), rel=1e-6)  # a 30-degree field of view
        mask = np.asarray(Image.open(out / s["name"] / "mask.png")) > 127
        ys, xs = np.nonzero(mask)
        fill = max(np.ptp(xs) + 1, np.ptp(ys) + 1) / 64.0
        assert fill == pytest.approx(0.4, abs=2.5 / 64)  # the body's box fills 40 % of the frame (pixel rounding)
    for s in subs[1:]:  # the first subject is the frontal one, always within +-5 degrees elevation and no roll
        assert abs(s["elevation_deg"]) <= 0.5 and abs(s["roll_deg"]) <= 0.5
    # under the defaults (+-15 and +-5 degrees) this seed draws larger angles
    _, default = synth(tmp_path, "default")
    assert (
        max(abs(s["elevation_deg"]) for s in default[1:]) > 2.0 and max(abs(s["roll_deg"]) for s in default[1:]) > 1.0
    )


def test_synth_truncation_truncates(tmp_path):
    out, subs = synth(tmp_path, "trunc", "--truncation", "1.0")
    assert [bool(s["truncated"]) for s in subs] == [False, True, True]  # the first subject is the frontal, whole one
    for s in subs[1:]:
        mask = np.asarray(Image.open(out / s["name"] / "mask.png")) > 127
        border = np.concatenate([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
        assert border.any(), s["name"]  # the body is cut by the image's edge


def test_eval_fits_and_plot_name_their_folders(tmp_path, open_model):
    from silfit.synth.generate import SynthConfig, generate_dataset

    data, elsewhere = tmp_path / "data", tmp_path / "elsewhere"
    generate_dataset(data, 2, SynthConfig(seed=8, size=96, noise_px=0.0), model=open_model)
    for name in ("subject_000", "subject_001"):  # the truth as the "fit", outside DIR/fits
        with np.load(data / name / "gt.npz") as gt:
            (elsewhere / name / "keypoints").mkdir(parents=True)
            np.savez(
                elsewhere / name / "keypoints" / "params.npz",
                **{k: gt[k] for k in ("betas", "body_pose", "global_orient", "transl")},
            )
    report_path, plot = tmp_path / "report.json", tmp_path / "plots" / "errors.png"
    plot.parent.mkdir()
    assert (
        main(
            ["eval", str(data), "--fits", str(elsewhere), "--plot", str(plot), "--report", str(report_path), "--no-iou"]
        )
        == 0
    )
    report = json.loads(report_path.read_text())
    assert report["num_scored"] == 2 and report["missing_fits"] == []
    assert plot.is_file() and not (tmp_path / "report_errors.png").exists()


def test_render_model_changes_the_body(tmp_path):
    from silfit_toy_body import write_toy_npz

    toy = write_toy_npz(tmp_path / "toy.npz")
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"global_orient": [math.pi, 0.0, 0.0], "transl": [0.0, 0.2, 3.0]}))
    masks = {}
    for name, extra in (("default", []), ("toy", ["--model", str(toy)])):
        assert (
            main(
                [
                    "render",
                    str(path),
                    "--directions",
                    "front",
                    "--write-mask",
                    "--size",
                    "64",
                    "--out",
                    str(tmp_path / name),
                    *extra,
                ]
            )
            == 0
        )
        masks[name] = np.asarray(Image.open(tmp_path / name / "mask.png")) > 127
    assert masks["default"].any() and masks["toy"].any()
    assert (masks["default"] != masks["toy"]).mean() > 0.02  # another body, another silhouette


def test_no_subcommand_prints_help_and_exits_2(capsys):
    assert main([]) == 2
    err = capsys.readouterr().err
    assert "usage: silfit" in err and "fit-dataset" in err


#: what a ``--help`` must not load: the fitting and rendering stacks (numpy is allowed: ``cli/render.py`` uses it)
HEAVY = ("torch", "scipy", "cv2", "mitsuba", "drjit", "pyrender", "matplotlib", "trimesh", "silfit.fitting")


@pytest.mark.parametrize(
    "command", ["", "demo", "fit", "detect", "synth", "eval", "render", "fit-dataset", "export-model", "report"]
)
def test_help_starts_without_the_heavy_packages(command):
    """``silfit --help`` and every subcommand's ``--help`` start fast: the CLI imports torch, scipy, OpenCV, Mitsuba
    and the fitting code inside the commands, never at the top of a module that ``--help`` loads."""
    code = (
        "import sys\nfrom silfit.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules), file=sys.stderr)"
    )
    argv = [command, "--help"] if command else ["--help"]
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True)
    assert out.returncode == 0 and "usage: silfit" in out.stdout, out.stderr
    assert out.stderr.strip().splitlines()[-1] == "[]", out.stderr


def test_quiet_hides_progress_only_and_warnings_go_to_stderr(inputs, tmp_path, capsys):  # noqa: F811
    d, model = inputs
    doc = json.loads((d / "kp.json").read_text())
    kp = np.asarray(doc["people"][0]["pose_keypoints_2d"], dtype=float).reshape(-1, 3)
    kp[4] = [1e6, 1e6, 0.9]  # a far-outside wrist: dropped with a warning
    doc["people"][0]["pose_keypoints_2d"] = kp.reshape(-1).tolist()
    bad = tmp_path / "far.json"
    bad.write_text(json.dumps(doc))
    args = fit_args(d, model, tmp_path / "q", "--quiet")
    args[args.index("--keypoints") + 1] = str(bad)
    assert main(args) == 0
    cap = capsys.readouterr()
    assert cap.out.startswith("wrote ") and "median reprojection error" in cap.out  # the result line stays
    assert "warning:" not in cap.out and "warning:" in cap.err  # warnings on standard error, also with --quiet


@pytest.mark.parametrize("command", ["fit", "fit-dataset"])
def test_the_silhouette_levels_help_states_the_stages_defaults(command):
    """``--silhouette-resolutions`` and ``--silhouette-iterations`` say the defaults the stage runs with (the help
    text is written out so that ``--help`` does not import the fitting code)."""
    import re

    from silfit.cli import build_parser
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices[command]
    text = {a.option_strings[0]: a.help for a in sub._actions if a.option_strings}
    cfg = SilhouetteFitConfig()
    for flag, value in (("--silhouette-resolutions", cfg.resolutions), ("--silhouette-iterations", cfg.iterations)):
        stated = re.search(r"default (\d+(?:,\d+)*)", text[flag]).group(1)
        assert stated == ",".join(str(v) for v in value), (flag, text[flag])
