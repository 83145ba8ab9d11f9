"""Mitsuba silhouette renderer: camera convention, gradients, ROI, batching, errors."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import torch

from silfit.camera import Camera, project_points
from silfit.render.silhouette import SilhouetteRenderer, check_camera, paste_roi, roi_window, RoiWindow

CENTRE = torch.tensor([0.05, -0.03, 2.0])


@pytest.fixture(scope="module")
def sphere_renderer(sphere):
    return SilhouetteRenderer(sphere[1], spp=16)


@pytest.fixture(scope="module")
def capsule_renderer(capsule):
    return SilhouetteRenderer(capsule[1])


def _centroid(img: np.ndarray) -> np.ndarray:
    ys, xs = np.mgrid[: img.shape[0], : img.shape[1]]
    return np.array([(img * xs).sum(), (img * ys).sum()]) / img.sum()


# --------------------------------------------------------------------------- setup
def test_variant_and_libllvm(sphere_renderer):
    import os

    from silfit.render._llvm import llvm_major_version

    assert sphere_renderer.variant in ("llvm_ad_mono", "cuda_ad_mono")
    if not sphere_renderer.dr.has_backend(sphere_renderer.dr.JitBackend.CUDA):
        assert sphere_renderer.variant == "llvm_ad_mono"
        assert llvm_major_version(os.environ["DRJIT_LIBLLVM_PATH"]) >= 17


def test_bad_user_libllvm_is_replaced(tmp_path):
    """A user DRJIT_LIBLLVM_PATH naming libLLVM 15 (crashes) or nothing is not kept."""
    code = (
        "import os, warnings; warnings.simplefilter('ignore');"
        "from silfit.render._llvm import configure_libllvm, llvm_major_version;"
        "p = configure_libllvm(); print(llvm_major_version(p))"
    )
    for bad in ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", str(tmp_path / "missing.so")):
        env = dict(__import__("os").environ, DRJIT_LIBLLVM_PATH=bad)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert int(out.stdout.strip()) >= 17


def test_missing_libllvm_message(monkeypatch):
    from silfit.render import _llvm

    monkeypatch.setattr(_llvm, "_SEARCH_GLOBS", ())
    with pytest.raises(_llvm.LibLLVMNotFoundError, match="apt-get install libllvm19"):
        _llvm.find_libllvm()


# --------------------------------------------------------------------------- convention
@pytest.mark.parametrize(
    "camera",
    [
        Camera(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=64),
        Camera(fx=90.0, fy=120.0, cx=36.2, cy=28.7, width=72, height=60),
    ],
)
def test_sphere_centroid_matches_projection(sphere, sphere_renderer, camera):
    """The silhouette of a sphere is an ellipse centred at f*x0*z0/(z0^2 - r^2) + c: the
    rendered centroid must land there to a few hundredths of a pixel (a half-pixel
    convention slip would be 0.5 px off)."""
    v, _ = sphere
    s = sphere_renderer(v + CENTRE, camera, spp=64, seed=1).numpy()
    x0, y0, z0 = CENTRE.tolist()
    k = z0 / (z0**2 - 0.3**2)
    expected = np.array([camera.fx * x0 * k + camera.cx, camera.fy * y0 * k + camera.cy])
    assert np.abs(_centroid(s) - expected).max() < 0.03
    # the area matches the ellipse's (semi-axes f*r/sqrt(z0^2-r^2) for a centred sphere)
    area = math.pi * camera.fx * camera.fy * 0.3**2 / (z0**2 - 0.3**2)
    assert s.sum() == pytest.approx(area, rel=0.02)


def test_projected_vertices_inside_silhouette(capsule, capsule_renderer, cam64):
    v, _ = capsule
    verts = v + CENTRE
    s = capsule_renderer(verts, cam64, spp=64, seed=3)
    uv = project_points(verts, cam64).round().long()
    own = s[uv[:, 1], uv[:, 0]]
    padded = torch.nn.functional.pad(s, (1, 1, 1, 1))
    near = torch.stack([padded[uv[:, 1] + 1 + dy, uv[:, 0] + 1 + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)]).amax(0)
    assert (own > 0).float().mean() > 0.99 and (near > 0.25).all()
    assert (own > 0.5).float().mean() > 0.9
    # and silhouette pixels far from every projected vertex are empty
    assert s[0, 0] == 0 and s[-1, -1] == 0


# --------------------------------------------------------------------------- options
def test_seed_and_batch(capsule, capsule_renderer, cam64):
    v, _ = capsule
    verts = v + CENTRE
    a = capsule_renderer(verts, cam64, seed=7)
    b = capsule_renderer(verts, cam64, seed=7)
    c = capsule_renderer(verts, cam64)
    d = capsule_renderer(verts, cam64)
    assert torch.equal(a, b)
    assert not torch.equal(c, d)  # fresh seed each call
    batch = torch.stack([verts, verts + torch.tensor([0.1, 0.0, 0.0])]).requires_grad_()
    out = capsule_renderer(batch, cam64, seed=7)
    assert out.shape == (2, 64, 64)
    assert torch.equal(out[0], a)
    assert out[1].sum() > 0 and not torch.allclose(out[0], out[1])
    (out[1] * torch.arange(64.0)).sum().backward()
    assert batch.grad[0].abs().sum() == 0 and batch.grad[1, :, 0].sum() > 0
    assert a.dtype == torch.float32 and 0 <= float(a.min()) and float(a.max()) <= 1


def test_gradient_matches_finite_differences(capsule, capsule_renderer, cam64, edge_gradient_check):
    """d loss / d (tx, ty, tz, scale) by AD vs central differences (steps ~0.05 px, the same
    seed on both sides, many stratified samples so the strip swept by the outline is
    sampled evenly); loss = sum (S - T)^2 against a fixed target."""
    v0, _ = capsule
    centre = v0.mean(0)

    def verts(p):
        return centre + p[3] * (v0 - centre) + CENTRE + p[:3]

    with torch.no_grad():
        target = (
            capsule_renderer(verts(torch.tensor([0.02, 0.015, -0.25, 0.97])), cam64, spp=64, seed=0) > 0.5
        ).float()

    def loss(s):
        return ((s - target) ** 2).sum()

    p0 = torch.tensor([0.0, 0.0, 0.0, 1.0])
    z, f, r = float(CENTRE[2]), cam64.fx, 0.3
    steps = [0.05 * z / f, 0.05 * z / f, 0.05 * z * z / (f * r), 0.05 * z / (f * r)]  # ~0.05 px of edge motion
    ad, fd, rel = edge_gradient_check(lambda v, **kw: capsule_renderer(v, cam64, **kw), verts, loss, p0, steps)
    assert all(abs(x) > 10 for x in fd.tolist())  # a real, non-vanishing gradient
    assert max(rel) < 0.03, f"AD {ad.tolist()} vs FD {fd.tolist()} (relative {rel})"


def test_interleaved_renders_keep_their_own_gradients(capsule, capsule_renderer, cam64):
    """Two renders through one cached scene, then one backward pass: each render's
    gradient is the one it has alone (the scene holds only the last vertices, so the
    earlier render's edge term must be recomputed with its own), and a [B, V, 3] batch
    gives every element its gradient."""
    v, _ = capsule
    w = torch.arange(64.0)
    alone = []
    for shift, seed in ((0.0, 1), (0.1, 2)):
        x = (v + CENTRE).clone().requires_grad_()
        (capsule_renderer(x + torch.tensor([shift, 0.0, 0.0]), cam64, seed=seed) * w).sum().backward()
        alone.append(x.grad.clone())
    a, b = (v + CENTRE).clone().requires_grad_(), (v + CENTRE).clone().requires_grad_()
    sa = capsule_renderer(a, cam64, seed=1)
    sb = capsule_renderer(b + torch.tensor([0.1, 0.0, 0.0]), cam64, seed=2)
    ((sa + sb) * w).sum().backward()
    assert torch.allclose(a.grad, alone[0]) and torch.allclose(b.grad, alone[1])
    batch = torch.stack([v + CENTRE, v + CENTRE + torch.tensor([0.1, 0.0, 0.0])]).requires_grad_()
    (capsule_renderer(batch, cam64, seed=1) * w).sum().backward()
    assert torch.allclose(batch.grad[0], alone[0]) and batch.grad[1, :, 0].sum() > 0


# --------------------------------------------------------------------------- ROI
def test_roi_equals_window_of_full_render(capsule, capsule_renderer):
    v, _ = capsule
    full_cam = Camera(fx=100.0, fy=100.0, cx=47.5, cy=40.0, width=96, height=88)
    verts = v + CENTRE
    full = capsule_renderer(verts, full_cam, spp=256, seed=1)
    x0, y0, w, h = 20, 14, 56, 60
    window = RoiWindow(x0=x0, y0=y0, scale=1.0, camera=full_cam.crop(x0, y0, w, h))
    roi, win = capsule_renderer.render_roi(verts, full_cam, window=window, spp=256, seed=2)
    assert win is window and roi.shape == (h, w)
    cut = full[y0 : y0 + h, x0 : x0 + w]
    diff = (roi - cut).abs()
    assert float(diff.mean()) < 0.004 and float(diff.max()) < 0.25
    assert float(full.sum() - cut.sum()) < 1e-3  # the window held the whole silhouette
    pasted = paste_roi(roi, window, full_cam)
    assert pasted.shape == full.shape and float((pasted - full).abs().mean()) < 0.002


def test_roi_auto_window_follows_person(capsule, capsule_renderer):
    """An automatic ROI at a fixed resolution renders the whole silhouette magnified; its
    area divided by scale^2 equals the full render's area, its centroid maps back."""
    v, _ = capsule
    big = Camera(fx=400.0, fy=400.0, cx=200.0, cy=150.0, width=400, height=300)
    verts = v + torch.tensor([0.4, 0.1, 2.5])
    roi, win = capsule_renderer.render_roi(verts, big, size=64, spp=64, seed=4)
    assert roi.shape == (64, 64) and 0.3 < win.scale < 1.5
    assert float(roi[0].sum() + roi[-1].sum() + roi[:, 0].sum() + roi[:, -1].sum()) == 0  # margin
    # area in the original image's pixels: the projected capsule's area at 400 px focal
    small = Camera(fx=100.0, fy=100.0, cx=49.625, cy=37.125, width=100, height=75)  # same view, 1/4 scale
    full_small = capsule_renderer(verts, small, spp=64, seed=4)
    assert float(roi.sum()) / win.scale**2 == pytest.approx(float(full_small.sum()) * 16, rel=0.03)
    c = _centroid(roi.numpy())
    back = (c + 0.5) / win.scale + np.array([win.x0, win.y0]) - 0.5  # ROI pixel -> full image pixel
    c_small = (_centroid(full_small.numpy()) + 0.5) * 4 - 0.5
    assert np.abs(back - c_small).max() < 0.1


# --------------------------------------------------------------------------- errors
def test_bad_inputs(capsule, capsule_renderer, cam64):
    v, f = capsule
    verts = v + CENTRE
    bad = verts.clone()
    bad[3, 1] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        capsule_renderer(bad, cam64)
    with pytest.raises(ValueError, match="empty mesh"):
        capsule_renderer(verts[:0], cam64)
    with pytest.raises(ValueError, match=r"\[V,3\]"):
        capsule_renderer(verts[:, :2], cam64)
    with pytest.raises(ValueError, match="out of range"):
        capsule_renderer(verts[:10], cam64)
    with pytest.raises(ValueError, match="empty"):
        SilhouetteRenderer(np.zeros((0, 3), dtype=np.int64))
    with pytest.raises(ValueError, match=r"\[F,3\]"):
        SilhouetteRenderer(f[:, :2])
    with pytest.raises(ValueError, match="focal"):
        capsule_renderer(verts, dict(fx=0.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=64))
    with pytest.raises(ValueError, match="focal"):
        check_camera(dict(fx=100.0, fy=-5.0, cx=31.5, cy=31.5, width=64, height=64))
    with pytest.raises(ValueError, match="width/height"):
        capsule_renderer(verts, dict(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=0, height=64))
    with pytest.raises(ValueError, match="spp"):
        capsule_renderer(verts, cam64, spp=0)
    with pytest.raises(ValueError, match="in front of the camera"):
        roi_window(verts * torch.tensor([1.0, 1.0, -1.0]), cam64)


# --------------------------------------------------------------------------- ray-cast method (issue 24)
def _scaled_about_axis(verts, cam, s):
    """Vertices whose projection is the original one scaled by ``s`` about the principal
    point (x, y scaled at fixed depth): the silhouette's area scales exactly by ``s**2``."""
    return torch.stack([s * verts[:, 0], s * verts[:, 1], verts[:, 2]], -1)


def test_raycast_area_derivative_is_exact(capsule, cam64):
    """d(sum of coverage)/d(image scale) = 2 * area exactly (divergence theorem): the edge
    integral of the ray-cast method has no bias beyond 0.5 % (an outside-ray offset of
    1e-2 px gave +5 % here, through contour folds counted twice)."""
    v, f = capsule
    verts = v + CENTRE
    r = SilhouetteRenderer(f, edge_sampling="systematic")  # evenly spaced: little noise, the bias shows
    assert r.method == "raycast"
    with torch.no_grad():
        area = float(r(verts, cam64, spp=1024, seed=1).sum())
    grads = []
    for seed in (1, 2):
        s = torch.tensor(1.0, requires_grad=True)
        r(_scaled_about_axis(verts, cam64, s), cam64, spp=4, edge_spp=16, seed=seed).sum().backward()
        grads.append(float(s.grad))
    assert abs(np.mean(grads) / (2 * area) - 1) < 0.005, (grads, 2 * area)


def test_raycast_matches_projective(capsule, cam64):
    """The two methods render the same silhouette (many samples) and, on average, the same
    gradient of a loss."""
    v, f = capsule
    verts = v + CENTRE
    ray, proj = SilhouetteRenderer(f), SilhouetteRenderer(f, method="projective")
    a = ray(verts, cam64, spp=256, seed=3)
    b = proj(verts, cam64, spp=256, seed=3, sampler="multijitter")
    assert float((a - b).abs().mean()) < 2e-3 and abs(float(a.sum() - b.sum())) < 0.5
    w = torch.arange(64.0)[None, :] * torch.ones(64, 1)
    grads = []
    for r in (ray, proj):
        x = verts.clone().requires_grad_()
        for seed in range(2):
            (r(x, cam64, spp=16, edge_spp=32, seed=seed) * w).sum().backward()
        grads.append(x.grad.sum(0))
    assert torch.allclose(grads[0], grads[1], rtol=0.03, atol=0.03 * float(grads[1].abs().max())), grads


def test_raycast_is_bit_identical_for_any_thread_count(capsule, cam64):
    """Silhouette and gradient of one seed do not depend on Dr.Jit's thread count (rays only
    in Dr.Jit, every sum in torch)."""
    v, f = capsule
    out = []
    for threads in (1, 2, 1):
        r = SilhouetteRenderer(f, threads=threads)
        x = (v + CENTRE).clone().requires_grad_()
        s = r(x, cam64, seed=9)
        (s * torch.arange(64.0)).sum().backward()
        out.append((s.detach(), x.grad))
    for s, g in out[1:]:
        assert torch.equal(s, out[0][0]) and torch.equal(g, out[0][1])


def test_auto_threads_leave_the_pool_to_the_process_or_a_ray_actor(capsule, monkeypatch):
    """``threads="auto"``: the ray-cast method takes ``AUTO_THREADS`` (``None``: Dr.Jit's pool as it is;
    a Ray actor sets the CPUs it reserved), the projective method one thread."""
    import silfit.render.silhouette as rs
    from silfit.runner import ray_backend, worker

    f = capsule[1]
    assert SilhouetteRenderer(f).threads is None and SilhouetteRenderer(f, method="projective").threads == 1
    monkeypatch.setattr(worker, "DatasetFitter", lambda options: None)
    monkeypatch.setattr(worker, "FitOptions", lambda **options: options)
    monkeypatch.setattr(rs, "AUTO_THREADS", None)
    ray_backend.FitActor({}, "out", render_threads=3)
    assert rs.AUTO_THREADS == 3 and SilhouetteRenderer(f).threads == 3
    assert SilhouetteRenderer(f, method="projective").threads == 1 and SilhouetteRenderer(f, threads=2).threads == 2


def test_render_views_shares_one_body(capsule, cam64):
    """``render_views``: one vertex set, several extrinsics; each view equals a render of the
    mapped vertices, and the gradients of all views reach the one vertex set."""
    v, f = capsule
    r = SilhouetteRenderer(f)
    angle = 0.4
    Ry = torch.tensor(
        [[math.cos(angle), 0.0, math.sin(angle)], [0.0, 1.0, 0.0], [-math.sin(angle), 0.0, math.cos(angle)]]
    )
    views = [(torch.eye(3), CENTRE), (Ry, CENTRE + torch.tensor([0.05, 0.0, 0.0]))]
    x = v.clone().requires_grad_()
    imgs = r.render_views(x, [cam64, cam64], [R for R, _ in views], [t for _, t in views], seeds=[4, 5])
    for img, (R, t), seed in zip(imgs, views, (4, 5)):
        assert torch.equal(img.detach(), r(v @ R.T + t, cam64, seed=seed))
    (imgs[0].sum() + (imgs[1] * torch.arange(64.0)).sum()).backward()
    assert x.grad.abs().sum() > 0
