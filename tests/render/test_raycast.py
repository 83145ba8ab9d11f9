"""silfit.render.raycast: the visibility-edge points' density (issue 24's speed part), the vertex gradient."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from silfit.render.raycast import _dilate
from silfit.render.silhouette import SilhouetteRenderer

CENTRE = torch.tensor([0.05, -0.03, 2.0])


def _render(r, x, cam, seed, edge_density, spp=4):
    eye, zero = torch.eye(3), torch.zeros(3)
    return r.render_views(x, [cam], [eye], [zero], spp=spp, edge_spp=1, seeds=[seed], edge_density=edge_density)[0]


def test_render_views_edge_density(capsule, cam64):
    """``edge_density`` (edge points per pixel of contour-candidate length instead of
    ``edge_spp`` per image pixel) leaves the image as it is and the gradient's expectation
    too: d(coverage)/d(image scale) = 2 * area (divergence theorem) within 3 % over 8 seeds
    (one seed's spread at density 4: about 1.2 %), and d(ramp-weighted coverage)/d(translation)
    within 5 % of the ``edge_density=None`` gradient's largest component."""
    v, f = capsule
    r = SilhouetteRenderer(f)
    verts = v + CENTRE
    with torch.no_grad():
        area = float(r(verts, cam64, spp=1024, seed=1).sum())
    ramp = torch.arange(64.0)[None, :] + 0.5 * torch.arange(64.0)[:, None]
    scale_grads, shift_grads = {}, {}
    for dens in (None, 4.0):
        scale_grads[dens], shift_grads[dens] = [], []
        for seed in range(8):
            s = torch.tensor(1.0, requires_grad=True)
            img = _render(r, torch.stack([s * verts[:, 0], s * verts[:, 1], verts[:, 2]], -1), cam64, seed, dens)
            img.sum().backward()
            scale_grads[dens].append(float(s.grad))
            x = verts.clone().requires_grad_()
            img = _render(r, x, cam64, seed, dens)
            (img * ramp).sum().backward()
            shift_grads[dens].append(x.grad.sum(0))
            if dens is not None:  # the image does not depend on the edge points
                with torch.no_grad():
                    assert torch.equal(img.detach(), _render(r, verts, cam64, seed, None))
    for dens in (None, 4.0):
        assert abs(np.mean(scale_grads[dens]) / (2 * area) - 1) < 0.03, (dens, scale_grads[dens], 2 * area)
    old, new = torch.stack(shift_grads[None]).mean(0), torch.stack(shift_grads[4.0]).mean(0)
    assert torch.allclose(new, old, rtol=0.0, atol=0.05 * float(old.abs().max())), (old, new)
    with pytest.raises(ValueError, match="edge_density"):
        _render(r, verts.clone().requires_grad_(), cam64, 0, 0.0)


def test_dilate_is_a_3x3_max_pool():
    """The ray plan's boolean dilation gives the bits of a 3x3 max-pool with zero padding."""
    g = torch.Generator().manual_seed(3)
    m = torch.rand(37, 53, generator=g) > 0.93
    m[0, 0] = m[-1, -1] = m[0, -1] = True
    pool = torch.nn.functional.max_pool2d(m[None, None].float(), 3, stride=1, padding=1)[0, 0] > 0
    assert torch.equal(_dilate(m), pool)


def test_vertex_gradient_jacobian_matches_autograd(capsule, cam64):
    """The edge integral's vertex gradient from the projection's Jacobian at the used endpoints (issue 24's
    runtime part) is the gradient torch's autograd gives through the projection of every vertex (rotated and
    translated view, within 1e-6 of the largest component: float64 both ways, float32 out)."""
    from silfit.render.raycast import RaycastScene

    v, f = capsule
    r = SilhouetteRenderer(f)
    ang = torch.tensor([0.1, -0.2, 0.05])
    R = torch.linalg.matrix_exp(torch.tensor([[0.0, -ang[2], ang[1]], [ang[2], 0.0, -ang[0]], [-ang[1], ang[0], 0.0]]))
    t = CENTRE.clone()
    ramp = torch.arange(64.0)[None, :] + 0.5 * torch.arange(64.0)[:, None]
    grads = {}
    try:
        for analytic in (False, True):
            RaycastScene.analytic_grad = analytic
            x = v.clone().requires_grad_()
            img = r.render_views(x, [cam64], [R], [t], spp=4, edge_spp=1, seeds=[5], edge_density=4.0)[0]
            (img * ramp).sum().backward()
            grads[analytic] = x.grad.clone()
    finally:
        RaycastScene.analytic_grad = True
    assert grads[True].abs().max() > 0
    assert torch.allclose(grads[True], grads[False], rtol=0.0, atol=1e-6 * float(grads[False].abs().max()))
