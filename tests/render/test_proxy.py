"""Render proxy: a fixed linear map of the body's vertices to a coarser mesh whose
silhouette matches the full mesh's (IoU >= 0.995) and whose gradients pass the
finite-difference check."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import silfit
from silfit.render.proxy import DEFAULT_PROXY_FACES, build_proxy, get_proxy, proxy_cache_dir
from silfit.render.silhouette import SilhouetteRenderer, roi_window
from silfit.camera import Camera
from silfit.synth.poses import POSE_LIBRARY


@pytest.fixture(scope="module")
def model():
    return silfit.load_body_model()


@pytest.fixture(scope="module")
def proxy(model, tmp_path_factory):
    import os

    old = os.environ.get("SILFIT_CACHE_DIR")
    os.environ["SILFIT_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    try:
        yield get_proxy(model.v_template, model.faces, DEFAULT_PROXY_FACES)
    finally:
        if old is None:
            os.environ.pop("SILFIT_CACHE_DIR")
        else:
            os.environ["SILFIT_CACHE_DIR"] = old


def _posed(model, pose_name=None, seed=None):
    if pose_name is not None:
        body_pose = torch.tensor(np.asarray(POSE_LIBRARY[pose_name].body_pose), dtype=torch.float32)[None]
        betas = torch.zeros(1, model.num_betas)
    else:
        g = torch.Generator().manual_seed(seed)
        body_pose = 0.3 * torch.randn(1, model.num_body_pose, generator=g)
        betas = torch.randn(1, model.num_betas, generator=g)
    with torch.no_grad():
        out = model(
            betas=betas,
            body_pose=body_pose,
            global_orient=torch.tensor([[math.pi, 0.2, 0.0]]),
            transl=torch.tensor([[0.0, 0.1, 3.0]]),
        )
    return out.vertices[0].float()


def test_proxy_is_a_fixed_affine_map(model, proxy):
    assert 0.95 * DEFAULT_PROXY_FACES <= proxy.n_faces <= DEFAULT_PROXY_FACES
    assert proxy.n_faces < model.faces.shape[0] / 2
    assert np.allclose(proxy.weights.sum(1), 1.0, atol=1e-5)
    assert np.abs(proxy.weights).max() < 3.0  # bounded weights, no wild extrapolation
    v = _posed(model, seed=3).double()
    p = proxy(v)
    assert p.shape == (proxy.n_vertices, 3)
    assert torch.allclose(torch.sparse.mm(proxy.matrix(torch.float64), v), p, atol=1e-9)
    # batched and equivariant under rigid motions (affine weights)
    from scipy.spatial.transform import Rotation

    R = torch.tensor(Rotation.from_rotvec([0.3, -1.1, 0.4]).as_matrix())
    t = torch.tensor([0.5, -0.2, 1.0], dtype=torch.float64)
    both = proxy(torch.stack([v, v @ R.T + t]))
    assert torch.allclose(both[1], p @ R.T + t, atol=1e-9)
    # the proxy vertices lie on (or within a few mm of) the template surface
    rest = proxy(model.v_template.double()).numpy()
    from scipy.spatial import cKDTree

    d, _ = cKDTree(model.v_template.double().numpy()).query(rest)
    assert d.max() < 0.03
    with pytest.raises(ValueError, match="proxy expects"):
        proxy(v[:100])


def test_proxy_cache(model, proxy, monkeypatch, tmp_path):
    assert get_proxy(model.v_template, model.faces, DEFAULT_PROXY_FACES) is proxy  # memory
    from silfit.render import proxy as module

    monkeypatch.setenv("SILFIT_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(module, "_MEMORY", {})  # built here, whatever earlier tests left in memory
    small = get_proxy(model.v_template, model.faces, 2000)
    files = list(proxy_cache_dir().glob("*.npz"))
    assert len(files) == 1
    module._MEMORY.clear()
    again = get_proxy(model.v_template, model.faces, 2000)  # from disk
    assert again is not small and np.array_equal(again.faces, small.faces)
    assert np.array_equal(again.indices, small.indices) and np.array_equal(again.weights, small.weights)
    files[0].write_bytes(b"not an npz")  # a corrupt cache file is rebuilt
    module._MEMORY.clear()
    rebuilt = get_proxy(model.v_template, model.faces, 2000)
    assert np.array_equal(rebuilt.faces, small.faces)
    with pytest.raises(ValueError, match="n_faces"):
        build_proxy(model.v_template.numpy(), model.faces.numpy(), 2)


def test_proxy_silhouette_iou(model, proxy):
    """Proxy vs full mesh at 256 px (the window fitted to the body, as in the silhouette
    stage), the same seed and stratified samples on both: soft IoU >= 0.995 for library
    poses and random poses and shapes."""
    full_r, proxy_r = SilhouetteRenderer(model.faces), SilhouetteRenderer(proxy.faces)
    cam = Camera(fx=1000.0, fy=1000.0, cx=511.5, cy=511.5, width=1024, height=1024)
    ious = []
    for name, seed in [
        ("t_pose", None),
        ("sit_chair", None),
        ("kneel_one", None),
        ("lie_reclined", None),
        (None, 1),
        (None, 2),
    ]:
        v = _posed(model, name, seed)
        window = roi_window(v, cam, size=256, margin=0.12)
        full = full_r(v, window.camera, spp=32, seed=1, sampler="multijitter")
        coarse = proxy_r(proxy(v), window.camera, spp=32, seed=1, sampler="multijitter")
        ious.append(float(torch.minimum(full, coarse).sum() / torch.maximum(full, coarse).sum()))
    print("IoU", ious)
    assert min(ious) >= 0.995, ious


def test_proxy_gradient_matches_finite_differences(model, proxy, edge_gradient_check):
    """The edge-gradient FD check of tests/render/test_mitsuba_silhouette.py, through
    the proxy map: d loss / d (tx, ty, tz, scale) of the body's model vertices."""
    v0 = _posed(model, "stand_relaxed")
    centre = v0.mean(0)
    cam = roi_window(v0, Camera(fx=1000.0, fy=1000.0, cx=511.5, cy=511.5, width=1024, height=1024), size=64).camera
    renderer = SilhouetteRenderer(proxy.faces)

    def verts(p):
        return proxy(centre + p[3] * (v0 - centre) + p[:3])

    with torch.no_grad():
        target = (renderer(verts(torch.tensor([0.01, 0.008, -0.1, 0.985])), cam, spp=64, seed=0) > 0.5).float()

    def loss(s):
        return ((s - target) ** 2).sum()

    p0 = torch.tensor([0.0, 0.0, 0.0, 1.0])
    z, f, r = float(centre[2]), cam.fx, 0.4  # r: a typical distance of the outline from the centre
    steps = [0.05 * z / f, 0.05 * z / f, 0.05 * z * z / (f * r), 0.05 * z / (f * r)]
    ad, fd, rel = edge_gradient_check(lambda v, **kw: renderer(v, cam, **kw), verts, loss, p0, steps)
    assert all(abs(x) > 10 for x in fd.tolist())
    assert max(rel) < 0.03, f"AD {ad.tolist()} vs FD {fd.tolist()} (relative {rel})"


def test_proxy_renderer_is_a_drop_in(model, proxy):
    from silfit.render.proxy import ProxySilhouetteRenderer

    v = _posed(model, seed=4)
    cam = roi_window(v, Camera(fx=1000.0, fy=1000.0, cx=511.5, cy=511.5, width=1024, height=1024), size=48).camera
    r = ProxySilhouetteRenderer(proxy)
    x = v.clone().requires_grad_()
    s = r(x, cam, seed=3)
    assert torch.equal(s, r.renderer(proxy(v), cam, seed=3))
    (s * torch.arange(48.0)).sum().backward()
    assert x.grad[:, 0].sum() > 0  # the gradient reaches the model's vertices
    roi, window = r.render_roi(v, cam, size=32, seed=1)
    assert roi.shape == (32, 32) and roi.sum() > 0
