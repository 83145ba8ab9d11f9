"""Batched silhouettes (several subjects in tiles of one film) equal single renders within
the Monte Carlo noise, and gradients reach each subject's vertices without cross-talk."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from silfit.render.batch import BatchSilhouetteRenderer, render_batch, tile_layout
from silfit.camera import Camera


@pytest.fixture(scope="module", params=["tiled", "separate"])
def batch_renderer(capsule, request):
    return BatchSilhouetteRenderer(capsule[1], mode=request.param)


@pytest.fixture(scope="module")
def subjects(capsule):
    """Three capsules at different places seen by windows of different sizes."""
    v, _ = capsule
    verts = [v + torch.tensor(t) for t in ([0.05, -0.03, 2.0], [-0.1, 0.05, 2.4], [0.0, 0.0, 1.8])]
    cams = [
        Camera(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=64),
        Camera(fx=90.0, fy=110.0, cx=40.2, cy=22.7, width=56, height=48),
        Camera(fx=80.0, fy=80.0, cx=35.0, cy=30.0, width=72, height=60),
    ]
    return verts, cams


def _centroid(img: torch.Tensor) -> np.ndarray:
    ys, xs = np.mgrid[: img.shape[0], : img.shape[1]]
    a = img.numpy()
    return np.array([(a * xs).sum(), (a * ys).sum()]) / a.sum()


def test_layout():
    cams = [
        Camera(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=w, height=h) for w, h in ((64, 64), (56, 48), (72, 60), (64, 64))
    ]
    lay = tile_layout(cams, gap=4)
    assert (lay.columns, lay.rows, lay.cell_w, lay.cell_h) == (2, 2, 72, 64)
    assert (lay.width, lay.height) == (2 * 76 + 4, 2 * 68 + 4)
    assert lay.offsets == [(4, 4), (80, 4), (4, 72), (80, 72)]
    assert tile_layout(cams[:3], gap=0).columns == 3  # no empty cells
    t = lay.tile_camera(3, cams[1])
    assert (t.cx, t.cy, t.width, t.height) == (80.0, 72.0, lay.width, lay.height)


def test_batch_equals_single_renders(batch_renderer, subjects):
    verts, cams = subjects
    batch = batch_renderer(verts, cams, spp=256, seed=3)
    assert batch_renderer.last_fallbacks == 0
    for v, c, b in zip(verts, cams, batch):
        single = batch_renderer.single(v, c, spp=256, seed=11)
        assert b.shape == (c.height, c.width) and b.dtype == torch.float32
        assert float((b - single).abs().mean()) < 0.003
        assert float(b.sum()) == pytest.approx(float(single.sum()), rel=0.01)
        assert np.abs(_centroid(b) - _centroid(single)).max() < 0.03
    # the functional form and a [B, V, 3] tensor give the same
    again = render_batch(torch.stack(verts), cams, batch_renderer.faces, spp=256, seed=3, mode=batch_renderer.mode)
    assert all(torch.equal(a, b) for a, b in zip(again, batch))


def test_gradients_reach_each_subject_without_cross_talk(batch_renderer, subjects):
    verts, cams = subjects
    weight = torch.arange(cams[1].width, dtype=torch.float32)  # d/dx of the outline of subject 1
    g_batch, g_single = [], []
    for seed in range(4):
        xs = [v.clone().requires_grad_() for v in verts]
        out = batch_renderer(xs, cams, spp=4, edge_spp=32, seed=seed)
        (out[1] * weight).sum().backward()
        assert all(x.grad is None or x.grad.abs().sum() == 0 for x in (xs[0], xs[2]))
        g_batch.append(float(xs[1].grad[:, 0].sum()))
        # the same gradient from single renders: moving right adds area at larger x
        x = verts[1].clone().requires_grad_()
        (batch_renderer.single(x, cams[1], spp=4, edge_spp=32, seed=seed) * weight).sum().backward()
        g_single.append(float(x.grad[:, 0].sum()))
    print("batch", g_batch, "single", g_single)
    assert min(g_batch) > 0
    # means of 4 seeds; one seed's spread is about 7 %, so 8 % is about 2.5 standard errors
    assert np.mean(g_batch) == pytest.approx(np.mean(g_single), rel=0.08)
    # each subject's own loss gives each its own gradient
    xs = [v.clone().requires_grad_() for v in verts]
    sum(o.sum() for o in batch_renderer(xs, cams, seed=6)).backward()
    assert all(x.grad.abs().sum() > 0 for x in xs)


def test_subject_leaving_its_window_is_rendered_alone(batch_renderer, subjects):
    verts, cams = subjects
    if batch_renderer.mode != "tiled":
        pytest.skip("only tiles can spill")
    moved = [verts[0], verts[1] + torch.tensor([0.6, 0.0, 0.0]), verts[2]]  # far right of its window
    out = batch_renderer(moved, cams, spp=256, seed=2)
    assert batch_renderer.last_fallbacks == 1
    single = batch_renderer.single(moved[1], cams[1], spp=256, seed=7)
    assert float((out[1] - single).abs().mean()) < 0.003
    assert float(out[2].sum()) == pytest.approx(
        float(batch_renderer.single(verts[2], cams[2], spp=256, seed=1).sum()), rel=0.01
    )


def test_bad_batches(batch_renderer, subjects, sphere):
    verts, cams = subjects
    with pytest.raises(ValueError, match="cameras"):
        batch_renderer(verts, cams[:2])
    with pytest.raises(ValueError, match="out of range|same number"):
        batch_renderer([verts[0], verts[1][:50]], cams[:2])
    assert batch_renderer([], []) == []
    with pytest.raises(ValueError, match="gap"):
        BatchSilhouetteRenderer(sphere[1], gap=-1)
    with pytest.raises(ValueError, match="mode"):
        BatchSilhouetteRenderer(sphere[1], mode="fast")
