"""The default schedules as literal tables, and one name per weight (old names kept as aliases)."""

import warnings
from dataclasses import fields, replace

import pytest

from silfit.fitting import KeypointFitConfig
from silfit.fitting.schedules import (
    KEYPOINT_SCHEDULE,
    SEQUENCE_SCHEDULE,
    SILHOUETTE_SCHEDULE,
    WHOLEBODY_KEYPOINT_SCHEDULE,
)
from silfit.fitting.sequence import SequenceFitConfig
from silfit.fitting.silhouette_stage import SilhouetteFitConfig


def test_the_default_configs_give_the_literal_tables():
    assert KeypointFitConfig().stages() == KEYPOINT_SCHEDULE
    assert KeypointFitConfig().stages(whole_body=True) == WHOLEBODY_KEYPOINT_SCHEDULE
    assert SilhouetteFitConfig().stages() == SILHOUETTE_SCHEDULE
    assert SequenceFitConfig().stages() == SEQUENCE_SCHEDULE
    # and a table is a schedule to start from
    assert KeypointFitConfig(schedule=KEYPOINT_SCHEDULE[:2]).stages() == KEYPOINT_SCHEDULE[:2]


def test_the_pose_weight_has_one_name_in_every_config():
    for cfg in (KeypointFitConfig(), SilhouetteFitConfig(), SequenceFitConfig()):
        names = {f.name for f in fields(cfg)}
        assert "pose_weight" in names and not names & {
            "w_pose",
            "pose_prior_weight",
            "pose_prior_weights",
            "final_pose_prior_weight",
        }
        assert "pose_weight" in cfg.to_dict()
    cfg = KeypointFitConfig(pose_weight=(1.0, 2.0, 3.0, 4.0))
    assert [s.weights.get("pose") for s in cfg.stages()] == [
        None,
        1.0,
        2.0,
        2.0,
        3.0,
        None,
        4.0,
        4.0,
        4.0,
        4.0,
    ]  # ..., shape,
    # branches_late, settle, branches_post, final
    assert SilhouetteFitConfig(pose_weight=0.5).weights()["pose"] == 0.5
    assert SequenceFitConfig(pose_weight=7.0).stages()[0].weights["pose"] == 7.0
    with pytest.raises(ValueError, match="pose_weight .3: one per pose stage"):
        KeypointFitConfig(pose_weight=(1.0, 2.0, 3.0))


def test_old_names_map_to_the_canonical_one():
    with pytest.warns(DeprecationWarning, match="'w_pose' is deprecated, use 'pose_weight'"):
        sil = SilhouetteFitConfig(w_pose=0.01)
    assert sil.pose_weight == sil.w_pose == 0.01 and sil.weights()["pose"] == 0.01
    assert replace(sil, pose_weight=0.3).w_pose == 0.3 and replace(sil, iterations=(5, 5)).pose_weight == 0.01
    with pytest.warns(DeprecationWarning):
        seq = SequenceFitConfig(pose_prior_weight=12.0)
    assert seq.pose_weight == seq.pose_prior_weight == 12.0 and seq.stages()[0].weights["pose"] == 12.0
    with pytest.warns(DeprecationWarning):
        kp = KeypointFitConfig(pose_prior_weights=(5.0, 6.0, 7.0), final_pose_prior_weight=8.0)
    assert kp.pose_weight == (5.0, 6.0, 7.0, 8.0)
    assert kp.pose_prior_weights == (5.0, 6.0, 7.0) and kp.final_pose_prior_weight == 8.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        assert KeypointFitConfig(final_pose_prior_weight=9.0).pose_weight == (2000.0, 400.0, 80.0, 9.0)
        kp.final_pose_prior_weight = 1.5  # attributes write through too
        sil.w_pose = 0.25
    assert kp.pose_weight[-1] == 1.5 and kp.stages()[-1].weights["pose"] == 1.5 and sil.pose_weight == 0.25


def test_the_dataset_runners_options_take_the_old_name_too():
    from silfit.runner.worker import keypoint_config

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        assert keypoint_config({"pose_prior_weights": "1,2,3"}).pose_weight == (1.0, 2.0, 3.0, 40.0)
    assert keypoint_config({"pose_weight": "1,2,3,4"}).pose_weight == (1.0, 2.0, 3.0, 4.0)


def test_the_late_search_options_reach_its_stages():
    """``late_branch_rounds``, ``late_branch_turns`` and ``late_branch_survivors`` (off by default, README
    "Depth ambiguity: search failures") shape the late search's stages and their options."""
    names = [s.name for s in KeypointFitConfig().stages()]
    assert names.count("branches_late") == 1 and not any(n.startswith("branches_late_") for n in names)
    late = [
        s
        for s in KeypointFitConfig(
            late_branch_rounds=2, late_branch_turns=("mirror", 30.0), late_branch_survivors=6
        ).stages()
        if s.name.startswith("branches_late")
    ]
    assert [s.name for s in late] == ["branches_late", "branches_late_2"]
    for s in late:
        assert s.options["branches"]["turns"] == ["mirror", 30.0] and s.options["branches"]["survivors"] == 6
    default = next(s for s in KeypointFitConfig().stages() if s.name == "branches_late")
    assert "turns" not in default.options["branches"]
    assert default.options["branches"]["survivors"] == KeypointFitConfig().branch_survivors
