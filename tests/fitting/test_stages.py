"""Stages as data: validation of schedules and configs."""
from dataclasses import replace

import pytest

from silfit.fitting import KeypointFitConfig, KeypointFitter
from silfit.fitting.silhouette_stage import SilhouetteFitConfig
from silfit.fitting.stages import Stage


def test_keypoint_schedule_is_data_with_the_decision_in_the_first_pose_stage():
    stages = KeypointFitConfig().stages()
    assert [s.name for s in stages] == ["camera", "pose_1", "pose_2", "branches_1", "pose_3", "shape", "final"]
    assert stages[1].options == {"decide_after": 20} and not stages[2].options
    assert stages[0].weights == {"torso": 1.0, "depth": 1e3}
    assert "branches" in stages[3].options and stages[3].weights["interpenetration"] == 1e5
    assert [s.name for s in KeypointFitConfig(branch_search=False).stages()][3] == "pose_3"
    assert stages[-1].weights["interpenetration"] == 1e5 and "betas" in stages[-1].free


def test_mismatched_lengths_are_refused():
    with pytest.raises(ValueError, match="pose_iters .3., pose_prior_weights .2."):
        KeypointFitConfig(pose_prior_weights=(1.0, 2.0))
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
    assert [st["optimiser"] for st in s["stages"]] == ["lbfgs", "adam", "adam"] and s["contour_iterations"] == 20
