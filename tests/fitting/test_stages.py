"""Stages as data: validation of schedules and configs."""

from dataclasses import replace

import pytest

from silfit.fitting import BranchSearch, KeypointFitConfig, KeypointFitter
from silfit.fitting.silhouette_stage import SilhouetteFitConfig
from silfit.fitting.stages import Stage


def test_keypoint_schedule_is_data_with_the_decision_in_the_first_pose_stage():
    stages = KeypointFitConfig().stages()
    assert [s.name for s in stages] == [
        "camera",
        "pose_1",
        "pose_2",
        "branches_1",
        "pose_3",
        "shape",
        "branches_late",
        "settle",
        "branches_post",
        "final",
    ]
    # the late search and the search from the fit: final weights; the late one's best 4 settle, the best goes on
    assert all("branches" in stages[i].options and stages[i].weights == stages[-1].weights for i in (6, 8))
    assert stages[6].options["branches"]["carry"] == 4 and "carry" not in stages[8].options["branches"]
    assert stages[7].options == {"tol_change": 1e-4, "searched_only": True} and stages[7].weights == stages[-1].weights
    assert stages[8].options["branches"]["screen_after"] == 20 and stages[8].iterations == 40
    assert "branches_late" not in [s.name for s in KeypointFitConfig(branches=BranchSearch(late_iters=0)).stages()]
    assert [s.name for s in KeypointFitConfig(branches=BranchSearch(post_iters=0)).stages()][6:] == [
        "branches_late",
        "final",
    ]
    assert "carry" not in KeypointFitConfig(branches=BranchSearch(post_iters=0)).stages()[6].options["branches"]
    assert stages[1].options == {"decide_after": 20} and not stages[2].options
    assert stages[0].weights == {"torso": 1.0, "depth": 1e3}
    assert "branches" in stages[3].options and stages[3].weights["interpenetration"] == 1e5
    assert [s.name for s in KeypointFitConfig(branches=BranchSearch(search=False)).stages()][3] == "pose_3"
    assert stages[-1].weights["interpenetration"] == 1e5 and "betas" in stages[-1].free


def test_mismatched_lengths_are_refused():
    with pytest.raises(ValueError, match="pose_iters .3., pose_weight .3: one per pose stage"):
        KeypointFitConfig(pose_weight=(1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="flip_decision_stage"):
        KeypointFitConfig(flip_decision_stage=3)
    with pytest.raises(ValueError, match="resolutions .1. and iterations .2."):
        SilhouetteFitConfig(resolutions=(64,))
    with pytest.raises(ValueError, match="no learning rate"):
        SilhouetteFitConfig(optimise=("betas", "expression"))


def test_a_misspelled_weight_or_parameter_in_a_schedule_is_refused(body_model):
    bad = KeypointFitConfig(schedule=[Stage("camera", ("global_orient", "transl"), {"torso": 1.0, "dpeth": 1.0}, 5)])
    with pytest.raises(ValueError, match="stage 'camera': unknown energy term.*dpeth"):
        KeypointFitter(body_model, config=bad)
    bad = KeypointFitConfig(schedule=[Stage("pose", ("body_pose", "hand_pose"), {"keypoints": 1.0}, 5)])
    with pytest.raises(ValueError, match="stage 'pose'.*hand_pose"):
        KeypointFitter(body_model, config=bad)
    bad = KeypointFitConfig(schedule=[Stage("a", ("transl",), {"keypoints": 1.0}, 5, optimiser="sgd")])
    with pytest.raises(ValueError, match="unknown optimiser"):
        KeypointFitter(body_model, config=bad)


def test_config_is_recorded_with_its_schedule():
    d = replace(KeypointFitConfig(), camera_iters=7).to_dict()
    assert d["camera_iters"] == 7 and d["stages"][0]["iterations"] == 7 and d["stages"][0]["name"] == "camera"
    s = SilhouetteFitConfig().to_dict()
    assert [st["name"] for st in s["stages"]] == ["contour", "silhouette_128", "silhouette_256"]
    assert [st["options"]["resolution"] for st in s["stages"]] == [256, 128, 256]
    assert [st["optimiser"] for st in s["stages"]] == ["lbfgs", "adam", "adam"] and s["contour_iterations"] == 40


# ----------------------------------------------------------------------------- the schedule runner
import math  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import torch  # noqa: E402

from silfit.fitting.optim import BatchedAdam  # noqa: E402
from silfit.fitting.problem import ParameterLayout  # noqa: E402
from silfit.fitting.stages import run_schedule, run_stage  # noqa: E402
from silfit.fitting.terms import Energy, Term  # noqa: E402


class Quadratic(Term):
    """``sum_i curvature_i (x_i - target_i)^2`` per problem (the shared parameter ``x``)."""

    name = "quad"

    def __call__(self, ev):
        return (ev.data["curvature"] * (ev.params["x"] - ev.data["target"]).square()).sum(-1)


def point_body(**rows):  # a "body" of one keypoint in front of the camera: evaluate() projects it
    return SimpleNamespace(keypoints=rows["transl"][:, None, :] + torch.tensor([0.0, 0.0, 3.0], dtype=torch.float64))


def quadratic_problem(P=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    layout = ParameterLayout({"x": 4, "transl": 3}, ("x",), frames=1)
    state = layout.zeros(P)
    views = {
        "intr": torch.tensor([100.0, 100.0, 50.0, 50.0], dtype=torch.float64).expand(P, 1, 1, 4),
        "R": torch.eye(3, dtype=torch.float64).expand(P, 1, 1, 3, 3),
        "t": torch.zeros(P, 1, 1, 3, dtype=torch.float64),
    }
    data = {
        "target": torch.randn(P, 4, generator=g, dtype=torch.float64),
        "curvature": 0.5 + torch.rand(P, 4, generator=g, dtype=torch.float64),
    }
    return layout, state, Energy([Quadratic()]), views, data


ADAM = {"lr": {"x": 0.05}, "warmup": 5}


def adam_state(state):
    return {k: v.clone().requires_grad_(k == "x") for k, v in state.items()}


def test_an_adam_stage_on_a_quadratic_recovers_each_rows_minimum():
    layout, state, energy, views, data = quadratic_problem()
    params = adam_state(state)
    run = run_stage(
        Stage("q", ("x",), {"quad": 1.0}, 400, "adam", ADAM), params, layout, energy, point_body, views, data
    )
    assert isinstance(run.adam, BatchedAdam) and run.iterations.tolist() == [400, 400, 400]
    assert torch.allclose(params["x"].detach(), data["target"], atol=1e-3), params["x"] - data["target"]
    assert float(run.energy.max()) < 1e-5 and torch.equal(params["transl"], state["transl"])  # held: not free


def test_the_runner_dispatches_on_the_optimiser():
    layout, state, energy, views, data = quadratic_problem()
    lbfgs = {k: v.clone() for k, v in state.items()}
    run = run_stage(Stage("q", ("x",), {"quad": 1.0}, 50), lbfgs, layout, energy, point_body, views, data)
    # L-BFGS: a quadratic in a few iterations, each row stopping on its own; no Adam state
    assert run.adam is None and int(run.iterations.max()) < 15 and torch.allclose(lbfgs["x"], data["target"], atol=1e-6)
    adam = adam_state(state)
    run = run_stage(Stage("q", ("x",), {"quad": 1.0}, 50, "adam", ADAM), adam, layout, energy, point_body, views, data)
    assert run.adam is not None and run.iterations.tolist() == [50] * 3  # Adam: every step (no plateau stop set)
    with pytest.raises(ValueError, match="no learning rate"):
        run_stage(Stage("q", ("x",), {"quad": 1.0}, 5, "adam"), adam, layout, energy, point_body, views, data)


@pytest.mark.parametrize("optimiser", ["lbfgs", "adam"])
def test_rows_run_alone_and_the_others_are_left_as_they_are(optimiser):
    layout, state, energy, views, data = quadratic_problem()
    stage = Stage("q", ("x",), {"quad": 1.0}, 30, optimiser, ADAM if optimiser == "adam" else {})
    batch = adam_state(state) if optimiser == "adam" else {k: v.clone() for k, v in state.items()}
    run_stage(stage, batch, layout, energy, point_body, views, data)
    some = adam_state(state) if optimiser == "adam" else {k: v.clone() for k, v in state.items()}
    run = run_stage(stage, some, layout, energy, point_body, views, data, rows=torch.tensor([2]))
    assert torch.equal(some["x"][:2], state["x"][:2]) and run.iterations[:2].tolist() == [0, 0]
    # a batch gives what its rows give alone, to the bit
    assert torch.equal(some["x"][2], batch["x"][2])


def test_adam_rows_stop_on_their_own():
    layout, state, energy, views, data = quadratic_problem()
    stopped_at = {}

    def on_step(i, rows, total, parts, ev):  # row 1 "diverges" at step 3: it stops where it was
        go = [not (int(p) == 1 and i == 3) for p in rows]
        for p, g in zip(rows.tolist(), go):
            if not g:
                stopped_at[p] = ev.params["x"][rows.tolist().index(p)].detach().clone()
        return go

    params = adam_state(state)
    stage = Stage("q", ("x",), {"quad": 1.0}, 20, "adam", ADAM)
    run = run_stage(stage, params, layout, energy, point_body, views, data, on_step=on_step)
    assert run.iterations.tolist() == [20, 3, 20] and torch.equal(params["x"][1].detach(), stopped_at[1])
    alone = adam_state(state)
    run_stage(stage, alone, layout, energy, point_body, views, data, rows=torch.tensor([0]))
    assert torch.equal(alone["x"][0], params["x"][0])  # the others went on as if alone
    # a plateau stops a row whose energy no longer falls (row 2 starts next to its minimum: Adam's
    # steps, about the learning rate long, oscillate around it at once)
    data["target"][2] = 1e-3
    params = adam_state(state)
    plateau = Stage("q", ("x",), {"quad": 1.0}, 200, "adam", {**ADAM, "plateau_window": 5, "plateau_rtol": 0.01})
    run = run_stage(plateau, params, layout, energy, point_body, views, data)
    assert 10 <= int(run.iterations[2]) < int(run.iterations[:2].min())


def test_a_schedule_continues_one_adam_across_its_adam_stages():
    layout, state, energy, views, data = quadratic_problem()
    params = adam_state(state)
    stages = [Stage("a", ("x",), {"quad": 1.0}, 7, "adam", ADAM), Stage("b", ("x",), {"quad": 2.0}, 5, "adam", ADAM)]
    seen = []
    runs = run_schedule(
        stages, params, layout, energy, point_body, views, data, before_stage=lambda i, s: seen.append(s.name)
    )
    assert seen == ["a", "b"] and runs[0].adam is runs[1].adam and runs[1].adam.t.tolist() == [12, 12, 12]
    # the energy of stage b is weighted by 2
    assert torch.allclose(runs[1].terms["quad"] * 2.0, runs[1].energy.to(runs[1].terms["quad"].dtype))
    assert math.isfinite(float(runs[1].energy.sum()))
