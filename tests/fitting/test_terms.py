"""Energy terms against hand-computed values, and the energy's weight checks."""

import pytest
import torch

from silfit.fitting.body import BodyState
from silfit.fitting.problem import ParameterLayout
from silfit.fitting.terms import DepthTerm, Energy, Evaluation, KeypointTerm, PriorTerm, StayTerm

SIZES = {"betas": 2, "global_orient": 3, "body_pose": 3, "transl": 3}


def evaluation(P=1, F=1, C=1, proj=None, data=None, params=None):
    layout = ParameterLayout(SIZES, ("betas",), F)
    params = params or layout.zeros(P)
    K = 2 if proj is None else proj.shape[-2]
    proj = torch.zeros(P, F, C, K, 2, dtype=torch.float64) if proj is None else proj
    root = layout.rows(params)["transl"].reshape(P, F, 1, 3).expand(P, F, C, 3)
    return Evaluation(P, F, C, params, layout.rows(params), BodyState(None, None), proj, root, data or {})


def test_keypoint_term_is_the_weighted_geman_mcclure_sum():
    proj = torch.tensor([[[[[3.0, 4.0], [0.0, 0.0]]]]], dtype=torch.float64)  # residual 5 px, then 0
    data = {
        "target": torch.zeros(1, 1, 1, 2, 2, dtype=torch.float64),
        "weights": torch.tensor([[[[2.0, 7.0]]]], dtype=torch.float64),
        "scale": torch.tensor([[[2.0]]], dtype=torch.float64),
    }
    ev = evaluation(proj=proj, data=data)
    # r = 2 * 5 = 10 normalised px; rho = s^2 r^2 / (s^2 + r^2) with s = 10: 100 * 100 / 200 = 50; weight 2.
    assert KeypointTerm(sigma=10.0)(ev).item() == pytest.approx(100.0)
    assert KeypointTerm(sigma=None)(ev).item() == pytest.approx(2.0 * 100.0)  # plain L2
    masked = KeypointTerm(sigma=10.0, mask=torch.tensor([0.0, 1.0]))
    assert masked(ev).item() == 0.0


def test_depth_term_uses_the_root_depth_in_each_camera():
    layout = ParameterLayout(SIZES, ("betas",), 2)
    params = layout.zeros(1)
    params["transl"][0, :, 2] = torch.tensor([3.0, 5.0])
    ev = evaluation(F=2, params=params, data={"z0": torch.tensor([[[4.0], [4.0]]], dtype=torch.float64)})
    assert DepthTerm()(ev).item() == pytest.approx(1.0 + 1.0)  # summed over the two frames


def test_prior_and_stay_terms_sum_over_frames_and_shared_parameters_count_once():
    layout = ParameterLayout(SIZES, ("betas",), 3)
    params = layout.zeros(2)
    params["betas"][:] = torch.tensor([1.0, 2.0])
    params["body_pose"][1] = 0.5
    ev = evaluation(P=2, F=3, params=params, data={"start_body_pose": torch.zeros(2, 3, 3, dtype=torch.float64)})
    shape = PriorTerm("shape", lambda b: (b * b).sum(-1), "betas")(ev)
    assert shape.tolist() == pytest.approx([5.0, 5.0])  # one shape per problem, not one per frame
    pose = PriorTerm("pose", lambda p: (p * p).sum(-1), "body_pose")(ev)
    assert pose.tolist() == pytest.approx([0.0, 3 * 3 * 0.25])
    assert StayTerm("body_pose")(ev).tolist() == pytest.approx([0.0, 2.25])


def test_energy_weights_terms_and_refuses_unknown_names():
    ev = evaluation(params=None)
    ev.params["betas"][:] = 1.0
    energy = Energy([PriorTerm("shape", lambda b: (b * b).sum(-1), "betas"), StayTerm("betas", name="stay")])
    ev.data["start_betas"] = torch.zeros(1, 2, dtype=torch.float64)
    total, parts = energy(ev, {"shape": 3.0, "stay": 0.0})
    assert total.item() == pytest.approx(6.0) and set(parts) == {"shape"}  # a zero weight is not evaluated
    with pytest.raises(ValueError, match="unknown energy term.*shpe"):
        energy.check({"shpe": 1.0}, "stage 'x'")
    with pytest.raises(ValueError, match="non-negative"):
        energy.check({"shape": -1.0})
    with pytest.raises(ValueError, match="distinct names"):
        Energy([StayTerm("betas", name="a"), StayTerm("body_pose", name="a")])


def test_interpenetration_term_sums_the_collision_penalty_per_problem():
    from silfit.fitting.terms import InterpenetrationTerm

    layout = ParameterLayout(SIZES, ("betas",), 2)
    params = layout.zeros(2)
    ev = evaluation(P=2, F=2, params=params)
    penalty = lambda betas, transforms: torch.tensor([1.0, 2.0, 3.0, 4.0], dtype=torch.float64)  # noqa: E731
    assert InterpenetrationTerm(penalty)(ev).tolist() == pytest.approx([3.0, 7.0])  # rows [P * F] summed per problem
