"""``silfit render``: PNG outputs, sizes, centring, errors without partial files."""

from __future__ import annotations

import json
from pathlib import Path
import math

import numpy as np
import pytest
import trimesh
from PIL import Image

from silfit.cli import main


def _png(path):
    with Image.open(path) as im:
        return np.asarray(im)


def _centroid(mask):
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()])


@pytest.fixture(scope="module")
def params_json(tmp_path_factory):
    path = tmp_path_factory.mktemp("fit") / "params.json"
    path.write_text(
        json.dumps({"global_orient": [math.pi, 0.0, 0.0], "transl": [0.0, 0.2, 3.0], "betas": [0.5] + [0.0] * 9})
    )
    return path


@pytest.fixture(scope="module")
def box_obj(tmp_path_factory):
    path = tmp_path_factory.mktemp("mesh") / "box.obj"
    m = trimesh.creation.box(extents=(0.5, 1.6, 0.3))
    m.apply_translation([0.2, -0.1, 3.0])  # a person-sized box in front of the camera, off-centre
    m.export(path)
    return path


def test_views_and_mask_from_params(params_json, tmp_path):
    out = tmp_path / "out"
    assert (
        main(
            [
                "render",
                str(params_json),
                "--directions",
                "front,side,back",
                "--write-mask",
                "--size",
                "96x128",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    names = sorted(p.name for p in out.iterdir())
    assert names == ["mask.png", "view_back.png", "view_front.png", "view_side.png"]
    for name in names:
        img = _png(out / name)
        assert img.shape[:2] == (128, 96) and (out / name).stat().st_size > 100
    front = (_png(out / "view_front.png") < 250).any(axis=2)
    assert front.sum() > 500 and np.abs(_centroid(front) - [47.5, 63.5]).max() < 8
    mask = _png(out / "mask.png") > 127
    assert np.abs(_centroid(mask) - [47.5, 63.5]).max() < 8


def test_mesh_turntable_camera_overlay(box_obj, tmp_path):
    cam = {"fx": 60.0, "fy": 60.0, "cx": 39.5, "cy": 29.5, "width": 80, "height": 60}
    (tmp_path / "camera.json").write_text(json.dumps(cam))
    Image.fromarray(np.full((60, 80, 3), 30, dtype=np.uint8)).save(tmp_path / "image.png")
    out = tmp_path / "out"
    rc = main(
        [
            "render",
            str(box_obj),
            "--turntable",
            "3",
            "--size",
            "64",
            "--camera",
            str(tmp_path / "camera.json"),
            "--overlay",
            str(tmp_path / "image.png"),
            "--mask",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "camera.png",
        "mask.png",
        "overlay.png",
        "view_turn000.png",
        "view_turn001.png",
        "view_turn002.png",
    ]
    assert _png(out / "view_turn000.png").shape == (64, 64, 3)
    front = (_png(out / "view_turn000.png") < 250).any(axis=2)
    assert np.abs(_centroid(front) - [31.5, 31.5]).max() < 3  # framed: the body in the centre
    mask = _png(out / "mask.png") > 127
    assert mask.shape == (60, 80)
    # under the given camera the box sits where its centre projects: u = 60*0.2/3 + 39.5
    assert np.abs(_centroid(mask) - [43.5, 27.5]).max() < 1.5
    overlay = _png(out / "overlay.png")
    assert overlay.shape == (60, 80, 3) and (overlay[~mask] == 30).all() and (overlay[mask] > 30).all()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--directions", "front,top"], "unknown view"),
        (["--turntable", "0"], "turntable"),
        (["--size", "0x10"], "--size"),
        (["--camera", "CAMERA_BAD_FOCAL"], "focal"),
        (["--camera", "CAMERA_ZERO_WIDTH"], "width/height"),
        (["--overlay", "missing.png"], "not found"),
    ],
)
def test_bad_options_leave_no_png(params_json, tmp_path, capsys, args, message):
    bad_focal = {"fx": 0.0, "fy": 50.0, "cx": 10.0, "cy": 10.0, "width": 20, "height": 20}
    zero_w = {"fx": 50.0, "fy": 50.0, "cx": 10.0, "cy": 10.0, "width": 0, "height": 20}
    (tmp_path / "bad_focal.json").write_text(json.dumps(bad_focal))
    (tmp_path / "zero_w.json").write_text(json.dumps(zero_w))
    args = [
        a.replace("CAMERA_BAD_FOCAL", str(tmp_path / "bad_focal.json")).replace(
            "CAMERA_ZERO_WIDTH", str(tmp_path / "zero_w.json")
        )
        for a in args
    ]
    args = [str(tmp_path / a) if a == "missing.png" else a for a in args]
    out = tmp_path / "out"
    assert main(["render", str(params_json), "--out", str(out), "--write-mask", *args]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("kind", ["nan_params", "empty_mesh", "nan_mesh", "unknown_suffix"])
def test_bad_inputs_leave_no_png(tmp_path, capsys, kind):
    if kind == "nan_params":
        path = tmp_path / "params.json"
        path.write_text(json.dumps({"transl": [0.0, float("nan"), 3.0]}))  # json writes the NaN literal
        message = "field 'transl': holds NaN or infinite values"
    elif kind == "empty_mesh":
        path = tmp_path / "empty.obj"
        path.write_text("# nothing\n")
        message = "empty mesh"
    elif kind == "nan_mesh":
        path = tmp_path / "nan.obj"
        path.write_text("v 0 0 3\nv 1 0 3\nv nan 1 3\nf 1 2 3\n")
        message = "NaN"
    else:
        path = tmp_path / "params.txt"
        path.write_text("1 2 3")
        message = "unsupported input"
    out = tmp_path / "out"
    assert main(["render", str(path), "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())


def test_write_failure_leaves_no_partial_png(params_json, tmp_path, monkeypatch):
    """An error while encoding removes the temporary file and leaves no PNG."""
    from silfit.cli import render as render_cli

    def boom(self, fp, *a, **k):  # a partial file written, then the disk is full
        if hasattr(fp, "write"):
            fp.write(b"\x89PNG partial")
        else:
            Path(fp).write_bytes(b"\x89PNG partial")
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", boom)
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(OSError, match="disk full"):
        render_cli.write_png(out / "view_front.png", np.zeros((4, 4, 3), dtype=np.uint8))
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("kind", ["object_array", "bad_intrinsics", "camera_keys", "wrong_width", "binary_json"])
def test_hostile_fit_files_are_one_line_errors(tmp_path, capsys, kind):
    if kind == "object_array":
        path = tmp_path / "params.npz"
        np.savez(path, transl=np.array([{"x": 1}], dtype=object))
        message = "params.npz: field 'transl': holds Python objects"
    elif kind == "bad_intrinsics":
        path = tmp_path / "params.npz"
        np.savez(path, transl=np.array([0.0, 0.0, 3.0]), camera_intrinsics=np.ones(3), image_size=np.array([64, 64]))
        message = "field 'camera_intrinsics': has 3 values, expected [fx, fy, cx, cy]"
    elif kind == "camera_keys":
        path = tmp_path / "params.json"
        path.write_text(json.dumps({"transl": [0, 0, 3], "camera": {"fx": 1, "evil": 2}}))
        message = "field 'camera': camera field(s) missing"
    elif kind == "wrong_width":
        path = tmp_path / "params.json"
        path.write_text(json.dumps({"transl": [0, 0, 3], "body_pose": [0.0] * 72}))
        message = "params.json: field 'body_pose': has shape [72], expected [69]"
    else:
        path = tmp_path / "params.json"
        path.write_bytes(b"\xff\xfe\x00" * 50)
        message = "params.json: not a text"
    out = tmp_path / "out"
    assert main(["render", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def _fit_file(folder, model, frames, **kw):
    """A fit file of ``frames`` frames for ``model`` through the one writer (silfit.io.fit)."""
    from silfit.camera import Camera
    from silfit.io.fit import write_fit

    params = {n: np.zeros((frames, w)) for n, w in model.parameter_sizes.items()}
    params["global_orient"][:, 0] = math.pi
    params["transl"][:] = [0.0, 0.2, 3.0]
    params["transl"][:, 0] = np.linspace(-0.4, 0.4, frames)  # the body moves to the right over the frames
    return write_fit(folder, params, [Camera.from_image_size(96, 96)], layout="body25", model=model, **kw)


def test_render_draws_whole_body_fits_with_the_recorded_model(tmp_path, capsys):
    from silfit import load_body_model

    smplx = load_body_model(kind="smplx")
    fit = _fit_file(tmp_path / "wb", smplx, 1)
    assert main(["render", str(fit / "params.npz"), "--size", "64", "--write-mask", "--out", str(tmp_path / "r")]) == 0
    assert _png(tmp_path / "r" / "view_front.png").shape == (64, 64, 3)
    # the SMPL model cannot draw it: a clear error naming the field
    assert (
        main(
            ["render", str(fit / "params.npz"), "--model", str(load_body_model().source), "--out", str(tmp_path / "x")]
        )
        == 2
    )
    assert "body_pose" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_render_draws_a_chosen_frame_or_every_frame_of_a_video_fit(tmp_path, capsys, open_model):
    fit = _fit_file(tmp_path / "video", open_model, 5, frame_numbers=[3, 4, 5, 6, 7])
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps(json.loads((fit / "params.json").read_text())["camera"]))
    xs = []
    for f in ("0", "4"):
        out = tmp_path / f"f{f}"
        assert main(["render", str(fit / "params.npz"), "--frame", f, "--camera", str(cam), "--out", str(out)]) == 0
        camera_mask = _png(out / "camera.png").min(axis=-1) < 250  # under the stored camera: the body moves
        xs.append(_centroid(camera_mask)[0])
    assert xs[1] > xs[0] + 10, xs
    out = tmp_path / "all"
    assert (
        main(
            [
                "render",
                str(fit / "params.npz"),
                "--frame",
                "all",
                "--camera",
                str(cam),
                "--size",
                "48",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    with Image.open(out / "camera.gif") as gif:
        assert gif.n_frames == 5
    assert main(["render", str(fit / "params.npz"), "--frame", "5", "--out", str(tmp_path / "bad")]) == 2
    assert "holds 5 frame(s)" in capsys.readouterr().err


def test_render_moves_a_rig_fit_into_its_first_view(tmp_path, open_model):
    R = np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])  # the first view looks along world +x
    t = np.array([0.0, 0.0, 3.0])
    fit = _fit_file(tmp_path / "rig", open_model, 1, coordinates="world", extrinsics=[(R, t)])
    params = dict(np.load(fit / "params.npz"))
    params["transl"] = np.array([[0.0, 0.2, 0.0]], np.float32)  # at the world origin: 3 m in front of the view
    np.savez(fit / "params.npz", **params)
    cam = tmp_path / "camera.json"
    cam.write_text(json.dumps(json.loads((fit / "params.json").read_text())["camera"]))
    assert (
        main(["render", str(fit / "params.npz"), "--camera", str(cam), "--size", "48", "--out", str(tmp_path / "r")])
        == 0
    )
    assert (_png(tmp_path / "r" / "camera.png").min(axis=-1) < 250).sum() > 50  # the body is in the view
