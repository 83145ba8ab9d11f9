import pytest
import torch

from silfit.fitting import batched_lbfgs, gmof, reprojection_energy


def test_gmof_is_quadratic_near_zero_and_bounded():
    r = torch.tensor([[0.1, 0.0], [1e4, 0.0]])
    v = gmof(r, 100.0)
    assert v[0] == pytest.approx(0.01, rel=1e-3) and v[1] < 100.0**2


def test_reprojection_energy_weights_and_l2():
    proj = torch.zeros(1, 3, 2)
    tgt = torch.tensor([[[3.0, 4.0], [300.0, 400.0], [1.0, 0.0]]])
    w = torch.tensor([[1.0, 1.0, 0.0]])
    e_l2 = reprojection_energy(proj, tgt, w, torch.ones(1), sigma=None)
    assert float(e_l2) == pytest.approx(25.0 + 250000.0)
    e_gm = reprojection_energy(proj, tgt, w, torch.ones(1), sigma=100.0)
    assert float(e_gm) < 25.0 + 100.0**2
    # The scale converts pixels to normalised pixels.
    assert float(reprojection_energy(proj[:, :1], tgt[:, :1], w[:, :1], torch.tensor([2.0]), None)) == pytest.approx(
        100.0
    )


def rosenbrock(A):
    def fun(x, idx):
        a = A[idx]
        return (a - x[:, 0]) ** 2 + 100 * (x[:, 1] - x[:, 0] ** 2) ** 2 / a

    return fun


def test_batched_lbfgs_converges_independently_per_sample():
    A = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    x0 = torch.zeros(3, 2, dtype=torch.float64)
    x, f, iters = batched_lbfgs(rosenbrock(A), x0, max_iter=300, tol_grad=1e-9, tol_change=1e-14)
    assert torch.allclose(x[:, 0], A, atol=1e-4) and torch.allclose(x[:, 1], A**2, atol=1e-3)
    # Same as one-by-one fits: no cross-talk.
    for i in range(3):
        xi, fi, ii = batched_lbfgs(
            rosenbrock(A[i : i + 1]), x0[i : i + 1], max_iter=300, tol_grad=1e-9, tol_change=1e-14
        )
        assert torch.allclose(xi[0], x[i], atol=1e-8) and int(ii[0]) == int(iters[i])
