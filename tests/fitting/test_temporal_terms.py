"""Temporal energy terms: hand-computed values and gradients against finite differences."""

import math

import pytest
import torch

from silfit.fitting.body import BodyState
from silfit.fitting.terms import Evaluation, JointSmoothnessTerm, RootSmoothnessTerm, robust_penalty, second_differences


def ev_of(joints=None, transl=None, orient=None, P=1, F=3):
    params = {}
    if transl is not None:
        params["transl"], params["global_orient"] = transl, orient
    body = BodyState(keypoints=None, joints=joints) if joints is not None else None
    return Evaluation(P, F, 1, params, {}, body, torch.zeros(P, F, 1, 1, 2, dtype=torch.float64), None, {})


def test_second_differences_and_penalties_by_hand():
    x = torch.tensor([[0.0, 1.0, 4.0, 9.0]], dtype=torch.float64)  # t^2: acceleration 2
    assert second_differences(x).tolist() == [[2.0, 2.0]]
    sq = torch.tensor([0.0, 1.0, 9.0], dtype=torch.float64)
    assert robust_penalty(sq, None).tolist() == [0.0, 1.0, 9.0]
    # Charbonnier with sigma 2: 2*4*(sqrt(1 + sq/4) - 1); GM: 4 sq / (4 + sq)
    assert robust_penalty(sq, 2.0).tolist() == pytest.approx(
        [0.0, 8 * (math.sqrt(1.25) - 1), 8 * (math.sqrt(3.25) - 1)]
    )
    assert robust_penalty(sq, 2.0, "gm").tolist() == pytest.approx([0.0, 0.8, 36 / 13])
    # large residuals: Charbonnier grows linearly (|r| * 2 sigma), GM is bounded by sigma^2
    big = torch.tensor([1e6], dtype=torch.float64)
    assert robust_penalty(big, 2.0).item() == pytest.approx(2 * 2 * 1e3, rel=1e-2)
    assert robust_penalty(big, 2.0, "gm").item() < 4.0
    with pytest.raises(ValueError, match="unknown robust penalty"):
        robust_penalty(sq, 1.0, "huber")


def test_joint_smoothness_by_hand():
    # two joints over four frames; joint 0 moves with constant velocity (no acceleration),
    # joint 1 jumps 3 mm in x at frame 1 only: accelerations (mm) +3, -6 at t=1 and 3 at t=2.
    J = torch.zeros(1, 4, 2, 3, dtype=torch.float64)
    J[0, :, 0, 0] = torch.arange(4) * 0.01
    J[0, 1, 1, 0] = 0.003
    ev = ev_of(joints=J.reshape(4, 2, 3), F=4)
    plain = JointSmoothnessTerm(sigma=None)(ev)
    # second differences of joint 1's x over frames (0, 3, 0, 0) mm: (-6, 3)
    assert plain.item() == pytest.approx(36.0 + 9.0)
    robust = JointSmoothnessTerm(sigma=2.0)(ev)
    expected = 8 * (math.sqrt(1 + 36 / 4) - 1) + 8 * (math.sqrt(1 + 9 / 4) - 1)
    assert robust.item() == pytest.approx(expected)
    # fewer than three frames: nothing to smooth
    assert JointSmoothnessTerm()(ev_of(joints=J[0, :2].reshape(2, 2, 3), F=2)).item() == 0.0


def test_root_smoothness_by_hand():
    transl = torch.tensor([[[0.0, 0, 2.0], [0.0, 0, 2.001], [0.0, 0, 2.0]]], dtype=torch.float64)  # 1 mm bump in z
    orient = torch.zeros(1, 3, 3, dtype=torch.float64)
    term = RootSmoothnessTerm(sigma=None)
    assert term(ev_of(transl=transl, orient=orient)).item() == pytest.approx(4.0)  # (-2 mm)^2
    # a rotation bump of angle a about z at the middle frame: the matrices' second difference is
    # 2 (I - R(a)), whose squared entries sum to 4 (2 (1 - cos a)^2 + 2 sin^2 a), times 500^2
    a = 0.01
    orient = torch.tensor([[[0.0, 0, 0], [0, 0, a], [0, 0, 0]]], dtype=torch.float64)
    c, s = math.cos(a), math.sin(a)
    sq = 4 * (2 * (1 - c) ** 2 + 2 * s**2) * 500.0**2
    assert term(ev_of(transl=transl * 0, orient=orient)).item() == pytest.approx(sq)


@pytest.mark.parametrize("kind", ["charbonnier", "gm"])
def test_temporal_gradients_match_finite_differences(kind):
    torch.manual_seed(0)
    P, F, J = 2, 5, 3
    joints = (torch.randn(P * F, J, 3, dtype=torch.float64) * 0.02).requires_grad_(True)
    term = JointSmoothnessTerm(sigma=10.0, kind=kind)
    assert torch.autograd.gradcheck(lambda j: term(ev_of(joints=j, P=P, F=F)), (joints,))
    transl = (torch.randn(P, F, 3, dtype=torch.float64) * 0.02).requires_grad_(True)
    orient = (torch.randn(P, F, 3, dtype=torch.float64) * 0.3).requires_grad_(True)
    root = RootSmoothnessTerm(sigma=10.0, kind=kind)
    assert torch.autograd.gradcheck(lambda t, o: root(ev_of(transl=t, orient=o, P=P, F=F)), (transl, orient))


def test_problems_are_independent():
    """Each problem's value depends on its own frames only (no cross-talk in a batch)."""
    torch.manual_seed(1)
    joints = torch.randn(2 * 4, 2, 3, dtype=torch.float64) * 0.01
    both = JointSmoothnessTerm()(ev_of(joints=joints, P=2, F=4))
    alone = [JointSmoothnessTerm()(ev_of(joints=joints[4 * p : 4 * p + 4], P=1, F=4)).item() for p in range(2)]
    assert both.tolist() == pytest.approx(alone)
