"""pyrender/OSMesa offscreen renderer: convention, colour/depth/mask, overlay, views, errors."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from silfit.camera import Camera, project_points
from silfit.render import offscreen


def _centroid(img):
    ys, xs = np.mgrid[: img.shape[0], : img.shape[1]]
    return np.array([(img * xs).sum(), (img * ys).sum()]) / img.sum()


def test_platform_is_osmesa_or_egl():
    offscreen.render_mask(
        np.array([[0, 0, 1.0], [1, 0, 1], [0, 1, 1]]), np.array([[0, 1, 2]]), Camera(10, 10, 4.5, 4.5, 10, 10)
    )
    import OpenGL.platform

    # the platform PyOpenGL actually loaded (the environment variable is the code's own request)
    assert type(OpenGL.platform.PLATFORM).__name__ in ("OSMesaPlatform", "EGLPlatform")
    assert os.environ["PYOPENGL_PLATFORM"] == type(OpenGL.platform.PLATFORM).__name__[:-8].lower()


def test_sphere_mask_depth_colour(sphere):
    v, f = sphere
    centre = torch.tensor([0.1, -0.05, 2.0])
    cam = Camera(fx=200.0, fy=220.0, cx=60.3, cy=50.8, width=128, height=112)
    r = offscreen.render_mesh(v + centre, f, cam)
    assert r.color.shape == (112, 128, 3) and r.color.dtype == np.uint8
    assert r.depth.shape == (112, 128) and r.mask.dtype == bool
    # ellipse centre of a projected sphere: f * x0 * z0 / (z0^2 - r^2) + c (within mask quantisation)
    k = 2.0 / (4.0 - 0.09)
    expected = np.array([cam.fx * 0.1 * k + cam.cx, cam.fy * -0.05 * k + cam.cy])
    assert np.abs(_centroid(r.mask.astype(float)) - expected).max() < 0.1
    # depth: nearest point of the sphere is at z0 - r along the centre's ray
    assert r.depth[r.mask].min() == pytest.approx(2.0 - 0.3, abs=0.01)
    assert (r.depth[~r.mask] == 0).all()
    # shaded: body pixels are not flat and the background is white
    assert r.color[r.mask].std() > 5
    assert (r.color[~r.mask] == 255).all()
    assert np.array_equal(offscreen.render_mask(v + centre, f, cam), r.mask)


def test_overlay_blends_only_the_body(sphere):
    v, f = sphere
    cam = Camera(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=64)
    image = np.full((64, 64, 3), 40, dtype=np.uint8)
    out = offscreen.overlay(image, v + torch.tensor([0.0, 0.0, 2.0]), f, cam, alpha=0.5)
    mask = offscreen.render_mask(v + torch.tensor([0.0, 0.0, 2.0]), f, cam)
    assert out.shape == image.shape and out.dtype == np.uint8
    assert (out[~mask] == 40).all()
    assert (out[mask].astype(int).max(axis=1) > 45).all()
    with pytest.raises(ValueError, match="camera is"):
        offscreen.overlay(image[:32], v + torch.tensor([0.0, 0.0, 2.0]), f, cam)


def test_views_are_framed_and_centred(capsule):
    v, f = capsule
    views = offscreen.render_views(v + torch.tensor([0.3, 0.2, 3.0]), f, views="front,side,back", size=(96, 80))
    assert [name for name, _ in views] == ["front", "side", "back"]
    for _, img in views:
        assert img.shape == (80, 96, 3)
        body = (img < 250).any(axis=2)
        assert body.sum() > 200
        assert not (body[0].any() or body[-1].any() or body[:, 0].any() or body[:, -1].any())
        c = _centroid(body.astype(float))
        assert np.abs(c - np.array([47.5, 39.5])).max() < 6
    # back = front turned by 180 degrees: about the same area, roughly mirrored
    front = (views[0][1] < 250).any(axis=2)
    back = (views[2][1] < 250).any(axis=2)
    assert back.sum() == pytest.approx(front.sum(), rel=0.2)
    mirrored = (front & back[:, ::-1]).sum() / (front | back[:, ::-1]).sum()
    assert mirrored > (front & back).sum() / (front | back).sum()
    turn = offscreen.render_views(v, f, turntable=4, size=32)
    assert [name for name, _ in turn] == ["turn000", "turn001", "turn002", "turn003"]


def test_framing_camera_fits_the_mesh(capsule):
    v, _ = capsule
    cam, moved = offscreen.framing_camera(v.numpy() * 3, 120, 90, margin=0.1)
    uv = project_points(torch.as_tensor(moved), cam)
    assert float(uv[:, 0].min()) >= 120 * 0.1 - 0.5 - 1e-3 and float(uv[:, 0].max()) <= 120 * 0.9 - 0.5 + 1e-3
    assert float(uv[:, 1].min()) >= 90 * 0.1 - 0.5 - 1e-3 and float(uv[:, 1].max()) <= 90 * 0.9 - 0.5 + 1e-3
    mid = (uv.min(0).values + uv.max(0).values) / 2
    assert torch.allclose(mid, torch.tensor([59.5, 44.5]), atol=0.6)


def test_offscreen_bad_inputs(sphere):
    v, f = sphere
    cam = Camera(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=64)
    bad = v.clone() + torch.tensor([0.0, 0.0, 2.0])
    bad[0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        offscreen.render_mesh(bad, f, cam)
    with pytest.raises(ValueError, match="empty mesh"):
        offscreen.render_mesh(v[:0], f[:0], cam)
    with pytest.raises(ValueError, match="out of range"):
        offscreen.render_mesh(v[:5], f, cam)
    with pytest.raises(ValueError, match="focal"):
        offscreen.render_mesh(v, f, dict(fx=-1.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=64))
    with pytest.raises(ValueError, match="width/height"):
        offscreen.render_mask(v, f, dict(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=0))
    with pytest.raises(ValueError, match="unknown view"):
        offscreen.view_angles("front,top")
    with pytest.raises(ValueError, match="turntable"):
        offscreen.view_angles(turntable=0)


def test_missing_osmesa_is_one_line_saying_what_to_install(tmp_path):
    """Without libOSMesa, `silfit render` says what to install on one line (exit 2, no traceback),
    as for a missing libLLVM. The library's absence is imitated in a child process (pyrender not
    yet imported there), where the loader's answer is replaced."""
    import subprocess
    import sys

    mesh = tmp_path / "tri.obj"
    mesh.write_text("v 0 0 2\nv 0.1 0 2\nv 0 0.1 2\nf 1 2 3\n")
    code = (
        "import sys, silfit.render.offscreen as o; o._osmesa_present = lambda: False;"
        "from silfit.cli import main;"
        f"sys.exit(main(['render', {str(mesh)!r}, '--out', {str(tmp_path / 'views')!r}]))"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    assert lines[0].startswith("silfit render: error: libOSMesa not found") and "apt-get install libosmesa6" in lines[0]
    assert "conda install -c conda-forge mesalib" in lines[0]


def test_osmesa_is_found_here():
    assert offscreen._osmesa_present()  # this machine has it: the check above would be wrong otherwise
