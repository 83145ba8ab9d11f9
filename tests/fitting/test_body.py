"""The fitting bodies: the reduced keypoint body against the whole mesh, and batch invariance."""

import copy

import pytest
import torch

from silfit.fitting.body import KeypointBody
from silfit.io.keypoints import model_keypoints


@pytest.mark.parametrize("correctives", [False, True])
def test_reduced_body_matches_the_mesh_keypoints(open_model64, correctives):
    """The landmarks posed through precomputed (landmark, joint) pairs equal the landmarks of the
    skinned mesh, with and without pose correctives (official SMPL files have them)."""
    model = copy.deepcopy(open_model64)
    gen = torch.Generator().manual_seed(0)
    if correctives:
        model.posedirs = 2e-3 * torch.randn(207, model.num_vertices * 3, generator=gen, dtype=torch.float64)
    p = {n: 0.4 * torch.randn(3, w, generator=gen, dtype=torch.float64) for n, w in model.parameter_sizes.items()}
    body = KeypointBody(model, "body25")
    assert 0 < body.lm_pair_joint.numel() < 100  # a few dozen pairs (35), not thousands of vertices
    ref = model_keypoints(model, model(**p), "body25")
    assert torch.allclose(body(**p).keypoints, ref, atol=1e-10)
    if correctives:  # the correctives move the landmarks: the comparison above saw them
        plain = model_keypoints(open_model64, open_model64(**p), "body25")
        assert (plain - ref).abs().max() > 1e-4


def test_reduced_body_does_not_depend_on_the_rest_of_its_batch(open_model64):
    body = KeypointBody(open_model64, "body25")
    gen = torch.Generator().manual_seed(1)
    rows = {
        n: 0.4 * torch.randn(6, w, generator=gen, dtype=torch.float64) for n, w in open_model64.parameter_sizes.items()
    }

    def first_row(B, pos):
        p = {n: v[1 : B + 1].clone() for n, v in rows.items()}
        for n in p:
            p[n][pos] = rows[n][0]
            p[n].requires_grad_(True)
        kp = body(**p).keypoints[pos]
        grads = torch.autograd.grad(
            (kp * torch.linspace(0.5, 1.5, kp.numel(), dtype=kp.dtype).reshape(kp.shape)).sum(), list(p.values())
        )
        return kp.detach(), [g[pos] for g in grads]

    kp0, g0 = first_row(1, 0)
    for B, pos in ((2, 1), (5, 0), (5, 3)):
        kp, g = first_row(B, pos)
        assert torch.equal(kp, kp0) and all(torch.equal(a, b) for a, b in zip(g, g0)), (B, pos)
