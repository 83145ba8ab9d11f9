"""Pictures drawn without GL or matplotlib: the painted mesh and the IoU curve."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from silfit.camera import Camera
from PIL import Image
from silfit.outputs.figures import fit_overlay, iou_curve, paint_mesh


def _sphere(centre=(0.05, -0.03, 2.0), r=0.3):
    m = trimesh.creation.icosphere(subdivisions=4, radius=r)
    return np.asarray(m.vertices) + np.asarray(centre), np.asarray(m.faces)


def test_paint_mesh_covers_the_projected_sphere():
    cam = Camera(fx=100.0, fy=110.0, cx=40.0, cy=30.0, width=80, height=64)
    v, f = _sphere()
    rgba = paint_mesh(v, f, cam)
    alpha = rgba[..., 3] > 0
    x0, y0, z0 = 0.05, -0.03, 2.0
    k = z0 / (z0**2 - 0.3**2)
    area = math.pi * cam.fx * cam.fy * 0.3**2 / (z0**2 - 0.3**2)
    perimeter = math.pi * (cam.fx + cam.fy) * 0.3 / math.sqrt(z0**2 - 0.3**2)
    assert area < alpha.sum() < area + 0.6 * perimeter  # pixels the outline touches are included
    ys, xs = np.nonzero(alpha)
    assert abs(xs.mean() - (cam.fx * x0 * k + cam.cx)) < 0.3 and abs(ys.mean() - (cam.fy * y0 * k + cam.cy)) < 0.3
    # the front faces are found whatever the winding: the same picture with faces reversed
    assert np.array_equal(paint_mesh(v, f[:, ::-1], cam), rgba)
    # the centre, seen head on, is brighter than the rim
    assert rgba[int(round(cam.fy * y0 * k + cam.cy)), int(round(cam.fx * x0 * k + cam.cx)), 0] > rgba[ys, xs, 0].min()
    # nothing behind the camera
    assert paint_mesh(v * np.array([1, 1, -1]), f, cam)[..., 3].max() == 0


def test_overlay_and_iou_curve(tmp_path):
    cam = Camera(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=64)
    v, f = _sphere((0.0, 0.0, 2.0))
    out = fit_overlay(np.zeros((64, 64, 3), np.uint8), v, f, cam, keypoints_xy=np.array([[5.0, 5.0]]))
    assert out.shape == (64, 64, 3) and out[32, 32].min() > 60 and out[1, 60].max() == 0
    assert out[5, 5, 1] > 150  # the keypoint dot, green
    history = {
        "iou": list(np.linspace(0.7, 0.95, 30)),
        "energy": list(np.linspace(5, 1, 30)),
        "level": [0] * 15 + [1] * 15,
    }
    iou_curve(history, tmp_path / "c.png")
    img = np.asarray(Image.open(tmp_path / "c.png").convert("RGB"))
    assert img.shape == (340, 600, 3)
    blue = (img[..., 2] > 150) & (img[..., 0] < 80)
    assert blue.sum() > 200  # the IoU line was drawn
    iou_curve({"iou": [], "energy": [], "level": []}, tmp_path / "empty.png")  # no steps: still a picture


def test_contact_sheet_needs_one_title_per_picture(tmp_path):
    import pytest

    from silfit.outputs.figures import contact_sheet

    img = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(ValueError, match="3 images but 4 titles"):
        contact_sheet([img, img, img], ["a", "b", "c", ""], tmp_path / "s.png", columns=4)
    contact_sheet([img, None, img], ["a", "", "c"], tmp_path / "s.png", columns=2)  # None: an empty cell
    assert (tmp_path / "s.png").is_file()


def test_side_view_shows_depth_and_the_keypoint_fit_behind():
    """The side view (issue 23): a body moved away from the camera appears shifted sideways, the
    reference (keypoint-stage body) is drawn in orange behind the final body."""
    from pathlib import Path

    from silfit import load_body_model
    from silfit.outputs import figures
    from silfit.io.subjects import load_subject

    s = load_subject(Path(__file__).resolve().parents[2] / "data" / "synthetic" / "subject_000")
    faces = load_body_model().faces.numpy()
    v = s.gt.vertices
    alone = figures.side_view(v, faces, size=(160, 200))
    both = figures.side_view(v, faces, v + np.array([0.0, 0.0, 0.4]), size=(160, 200))
    assert alone.shape == (200, 160, 3) and alone.dtype == np.uint8
    warm = lambda img: img[..., 0].astype(int) - img[..., 2] > 60  # noqa: E731  (orange: red well above blue)
    orange = warm(both)
    assert orange.sum() > 500 and warm(alone).sum() < 50
    cols = np.flatnonzero(orange.any(0))
    grey = np.flatnonzero(((np.abs(both[..., 0].astype(int) - both[..., 2]) < 40) & (both[..., 0] < 230)).any(0))
    assert cols.mean() > grey.mean()  # farther from the camera (which looks from the left): to the right
