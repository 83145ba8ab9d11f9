"""The schedules as literal tables (the single source: the configs edit them), and one name per weight (old names
kept as aliases)."""

import warnings
from dataclasses import fields, replace

import pytest

from silfit.fitting import BranchSearch, KeypointFitConfig
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


def test_the_table_is_the_source(monkeypatch):
    """The stage fields' defaults are the table's cells, and a field that differs edits only the cells it names."""
    from silfit.fitting import schedule_edits
    from silfit.fitting.schedules import named, row

    poses, cfg = named(KEYPOINT_SCHEDULE, r"pose_\d+"), KeypointFitConfig()
    assert (
        cfg.pose_iters == tuple(s.iterations for s in poses)
        and cfg.final_iters == row(KEYPOINT_SCHEDULE, "final").iterations
    )
    assert cfg.pose_weight == tuple(s.weights["pose"] for s in poses) + (
        row(KEYPOINT_SCHEDULE, "final").weights["pose"],
    )
    assert SilhouetteFitConfig().iterations == tuple(s.iterations for s in SILHOUETTE_SCHEDULE[1:])
    assert SequenceFitConfig().iterations == SEQUENCE_SCHEDULE[0].iterations
    table = tuple(
        replace(s, weights={**s.weights, "limits": 5.0}) if s.name == "pose_2" else s for s in KEYPOINT_SCHEDULE
    )
    monkeypatch.setattr(schedule_edits, "KEYPOINT_SCHEDULE", table)
    assert KeypointFitConfig().stages() == table
    edited = {s.name: s for s in KeypointFitConfig(pose_iters=(1, 2, 3)).stages()}
    assert list(edited) == [s.name for s in table] and edited["pose_2"].iterations == 2
    assert edited["pose_2"].weights["limits"] == 5.0 and edited["pose_3"].weights["limits"] == 1e4
    assert {
        s.name: s.weights["limits"] for s in KeypointFitConfig(limit_weight=7.0).stages() if "limits" in s.weights
    } == {s.name: 7.0 for s in table if "limits" in s.weights}
    late = row(KeypointFitConfig(branches=BranchSearch(post_iters=0, search=True)).stages(), "branches_late")
    assert "carry" not in late.options["branches"]  # nothing goes on to a search from the fit


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


#: every weight with one name per term (issue 57): the canonical field in each config, and the old names it had
ONE_NAME = {
    "angle_weight": {"angle_prior_weights", "final_angle_prior_weight", "angle_prior_weight", "w_angle"},
    "shape_weight": {"final_shape_weight", "w_shape"},
    "limit_weight": {"w_limits"},
}


@pytest.mark.parametrize("name", sorted(ONE_NAME))
def test_the_prior_weights_have_one_name_in_every_config(name):
    for cfg in (KeypointFitConfig(), SilhouetteFitConfig(), SequenceFitConfig()):
        names = {f.name for f in fields(cfg)}
        assert name in names and not names & ONE_NAME[name], type(cfg).__name__
        assert name in cfg.to_dict() and not set(cfg.to_dict()) & ONE_NAME[name]


def test_the_keypoint_angle_and_shape_weights_are_stages_then_final():
    cfg = KeypointFitConfig(angle_weight=(1.0, 2.0, 3.0, 4.0), shape_weight=(6.0, 7.0))
    by_name = {s.name: s.weights for s in cfg.stages()}
    assert [by_name[f"pose_{i}"]["angle"] for i in (1, 2, 3)] == [1.0, 2.0, 3.0]
    assert by_name["final"]["angle"] == 4.0 and by_name["branches_late"]["angle"] == 4.0
    assert by_name["shape"]["shape"] == 6.0 and by_name["final"]["shape"] == 7.0
    assert cfg.to_dict()["angle_weight"] == [1.0, 2.0, 3.0, 4.0] and cfg.to_dict()["shape_weight"] == [6.0, 7.0]
    assert SilhouetteFitConfig(angle_weight=0.5, shape_weight=0.25, limit_weight=2.0).weights() == {
        **SilhouetteFitConfig().weights(),
        "angle": 0.5,
        "shape": 0.25,
        "limits": 2.0,
    }
    assert SequenceFitConfig(angle_weight=3.0).stages()[0].weights["angle"] == 3.0
    with pytest.raises(ValueError, match="angle_weight .3: the same. do not match"):
        KeypointFitConfig(angle_weight=(1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="shape_weight has 3 values"):
        KeypointFitConfig(shape_weight=(1.0, 2.0, 3.0))


def test_old_prior_weight_names_map_with_a_warning():
    with pytest.warns(DeprecationWarning) as caught:
        sil = SilhouetteFitConfig(w_angle=0.01, w_shape=0.02, w_limits=3.0)
    assert sorted(str(w.message) for w in caught) == [
        f"SilhouetteFitConfig: '{old}' is deprecated, use '{new}'"
        for old, new in (("w_angle", "angle_weight"), ("w_limits", "limit_weight"), ("w_shape", "shape_weight"))
    ]
    assert (sil.angle_weight, sil.shape_weight, sil.limit_weight) == (0.01, 0.02, 3.0)
    assert (sil.w_angle, sil.w_shape, sil.w_limits) == (0.01, 0.02, 3.0)
    assert replace(sil, iterations=(5, 5)).weights() == sil.weights()
    with pytest.warns(DeprecationWarning, match="'angle_prior_weight' is deprecated, use 'angle_weight'"):
        seq = SequenceFitConfig(angle_prior_weight=2.5)
    assert seq.angle_weight == seq.angle_prior_weight == 2.5 and seq.stages()[0].weights["angle"] == 2.5
    with pytest.warns(DeprecationWarning) as caught:
        kp = KeypointFitConfig(
            angle_prior_weights=(5.0, 6.0, 7.0), final_angle_prior_weight=8.0, final_shape_weight=9.0
        )
    assert {str(w.message) for w in caught} == {
        f"KeypointFitConfig: '{old}' is deprecated, use '{new}'"
        for old, new in (
            ("angle_prior_weights", "angle_weight"),
            ("final_angle_prior_weight", "angle_weight"),
            ("final_shape_weight", "shape_weight"),
        )
    }
    assert kp.angle_weight == (5.0, 6.0, 7.0, 8.0) and kp.shape_weight == (20.0, 9.0)
    assert kp.angle_prior_weights == (5.0, 6.0, 7.0) and kp.final_angle_prior_weight == 8.0
    assert kp.final_shape_weight == 9.0
    with pytest.raises(ValueError, match="pose_iters .3., angle_prior_weights .2."):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            KeypointFitConfig(angle_prior_weights=(1.0, 2.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        kp.final_angle_prior_weight = 1.5  # attributes write through too
        kp.final_shape_weight = 2.5
        kp.angle_prior_weights = (1.0, 2.0, 3.0)
        sil.w_angle, sil.w_shape, sil.w_limits = 0.1, 0.2, 0.3
        seq.angle_prior_weight = 4.0
    assert kp.angle_weight == (1.0, 2.0, 3.0, 1.5) and kp.shape_weight == (20.0, 2.5)
    assert kp.stages()[-1].weights["angle"] == 1.5 and kp.stages()[-1].weights["shape"] == 2.5
    assert (sil.angle_weight, sil.shape_weight, sil.limit_weight, seq.angle_weight) == (0.1, 0.2, 0.3, 4.0)


def test_a_single_keypoint_shape_weight_is_the_shape_stages_as_before():
    """``KeypointFitConfig.shape_weight`` was the shape stage's number; one number still means that (warned)."""
    for old in (30.0, 30, (30.0,)):
        with pytest.warns(DeprecationWarning, match="single shape_weight is deprecated"):
            assert KeypointFitConfig(shape_weight=old).shape_weight == (30.0, 5.0)
    with pytest.warns(DeprecationWarning):
        assert KeypointFitConfig(shape_weight=30.0, final_shape_weight=6.0).shape_weight == (30.0, 6.0)


def test_the_dataset_runners_options_take_the_old_name_too():
    from silfit.runner.worker import FitOptions, keypoint_config, silhouette_config

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        assert keypoint_config({"pose_prior_weights": "1,2,3"}).pose_weight == (1.0, 2.0, 3.0, 40.0)
    assert keypoint_config({"pose_weight": "1,2,3,4"}).pose_weight == (1.0, 2.0, 3.0, 4.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        kp = keypoint_config(
            {"angle_prior_weights": "1,2,3", "final_angle_prior_weight": "4", "final_shape_weight": "6"}
        )
        assert (kp.angle_weight, kp.shape_weight) == ((1.0, 2.0, 3.0, 4.0), (20.0, 6.0))
        assert keypoint_config({"shape_weight": "30"}).shape_weight == (30.0, 5.0)  # the old meaning
        sil = silhouette_config(FitOptions(silhouette_options={"w_angle": "0.5", "w_shape": "0.25", "w_limits": "2"}))
    assert (sil.angle_weight, sil.shape_weight, sil.limit_weight) == (0.5, 0.25, 2.0)
    assert keypoint_config({"angle_weight": "1,2,3,4", "shape_weight": "7,8"}).shape_weight == (7.0, 8.0)
    sil = silhouette_config(FitOptions(silhouette_options={"angle_weight": "0.5", "limit_weight": "2"}))
    assert (sil.angle_weight, sil.limit_weight) == (0.5, 2.0)


def test_the_late_search_options_reach_its_stages():
    """``late_branch_rounds``, ``late_branch_turns`` and ``late_branch_survivors`` (off by default, README
    "Depth ambiguity: search failures") shape the late search's stages and their options."""
    names = [s.name for s in KeypointFitConfig().stages()]
    assert names.count("branches_late") == 1 and not any(n.startswith("branches_late_") for n in names)
    late = [
        s
        for s in KeypointFitConfig(
            branches=BranchSearch(late_rounds=2, late_turns=("mirror", 30.0), late_survivors=6)
        ).stages()
        if s.name.startswith("branches_late")
    ]
    assert [s.name for s in late] == ["branches_late", "branches_late_2"]
    for s in late:
        assert s.options["branches"]["turns"] == ["mirror", 30.0] and s.options["branches"]["survivors"] == 6
    default = next(s for s in KeypointFitConfig().stages() if s.name == "branches_late")
    assert "turns" not in default.options["branches"]
    assert default.options["branches"]["survivors"] == KeypointFitConfig().branches.survivors


def test_grouped_settings_keep_their_flat_names_for_one_release():
    """The image depth and occlusion cues' settings are groups (``image_depth.weight``...); the flat names still work
    (warned), attributes read and write through, and ``to_dict`` (metrics.json) records the flat names as before."""
    from silfit.fitting import ImageDepthOptions, OcclusionOptions
    from silfit.runner.worker import keypoint_config

    with pytest.warns(DeprecationWarning, match="'image_depth_weight' is deprecated, use 'image_depth.weight'"):
        old = KeypointFitConfig(image_depth_weight=100.0, image_depth_decide=0.6)
    new = KeypointFitConfig(image_depth=ImageDepthOptions(weight=100.0, decide=0.6))
    assert old == new and old.image_depth_weight == 100.0 and old.to_dict() == new.to_dict()
    d = new.to_dict()
    assert d["image_depth_weight"] == 100.0 and d["occlusion_conf"] == [0.3, 0.6] and "image_depth" not in d
    assert replace(new, final_iters=50).image_depth is new.image_depth  # frozen groups: shared safely
    new.occlusion_weight = 0.5  # writes through
    assert new.occlusion == OcclusionOptions(weight=0.5) and new.stages()[3].options["branches"]["occlusion"] == 0.5
    kp = keypoint_config({"image_depth.weight": "100", "image_depth.decide": "none", "occlusion.conf": "0.1,0.9"})
    assert kp.image_depth == ImageDepthOptions(weight=100.0) and kp.occlusion.conf == (0.1, 0.9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        assert keypoint_config({"image_depth_decide": "0.6"}).image_depth.decide == 0.6
    with pytest.raises(ValueError, match="image_depth is a group: give its fields"):
        keypoint_config({"image_depth": "100"})


def test_the_branch_search_settings_are_a_group():
    """``KeypointFitConfig.branches`` (:class:`BranchSearch`): the old ``branch_*`` names still work, edit the same
    table cells and are recorded as before."""
    from silfit.fitting import BranchSearch
    from silfit.fitting.schedule_edits import changed_fields
    from silfit.runner.worker import keypoint_config

    with pytest.warns(DeprecationWarning, match="'late_branch_iters' is deprecated, use 'branches.late_iters'"):
        old = KeypointFitConfig(late_branch_iters=0, branch_survivors=3)
    new = KeypointFitConfig(branches=BranchSearch(late_iters=0, survivors=3))
    assert old == new and old.stages() == new.stages() and old.to_dict() == new.to_dict()
    assert "branches_late" not in [s.name for s in new.stages()] and new.branch_survivors == 3
    assert new.to_dict()["late_branch_iters"] == 0 and "branches" not in new.to_dict()
    assert changed_fields(new) == {"branches", "late_branch_iters", "branch_survivors"}
    off = keypoint_config({"branches.search": "false"})
    assert off.branches.search is False and not any(s.name.startswith("branches") for s in off.stages())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        assert keypoint_config({"branch_search": "false"}) == off


def test_the_mask_settings_are_a_group():
    """``SilhouetteFitConfig.mask`` (:class:`MaskHandling`): the old flat names still work and are recorded."""
    from silfit.fitting.silhouette_stage import MaskHandling
    from silfit.runner.worker import FitOptions, silhouette_config

    with pytest.warns(DeprecationWarning, match="'trim_clothing' is deprecated, use 'mask.trim_clothing'"):
        old = SilhouetteFitConfig(trim_clothing=False, cover_cap=0.1)
    new = SilhouetteFitConfig(mask=MaskHandling(trim_clothing=False, cover_cap=0.1))
    assert old == new and new.trim_clothing is False and new.cover_profile(100).cap == 10.0
    assert new.to_dict()["cover_cap"] == 0.1 and "mask" not in new.to_dict() and old.stages() == new.stages()
    sil = silhouette_config(FitOptions(silhouette_options={"mask.leak_distance": "0", "mask.trim_quantile": "0.5"}))
    assert sil.mask == MaskHandling(leak_distance=0.0, trim_quantile=0.5)
    sil = silhouette_config(FitOptions(silhouette_options={"mask.trim_upper": "none", "mask.trim_upper_max": "0.02"}))
    assert sil.mask == MaskHandling(trim_upper=None, trim_upper_max=0.02)
    with pytest.raises(ValueError, match="mask.trim_quantile must lie in"):
        SilhouetteFitConfig(mask=MaskHandling(trim_quantile=2.0))


def test_the_keypoint_term_starts_solutions_and_temporal_settings_are_groups():
    """``KeypointFitConfig.keypoint_term``, ``.starts``, ``.solutions`` (the count was ``hypotheses``) and
    ``.temporal``: the old flat names still work (warned, read and written through) and are recorded as before."""
    from silfit.fitting import KeypointTermOptions, Solutions, Starts, TemporalOptions
    from silfit.runner.worker import keypoint_config

    with pytest.warns(DeprecationWarning, match="'hypotheses' is deprecated, use 'solutions.count'"):
        old = KeypointFitConfig(hypotheses=3, keypoint_weights={"nose": 2.0}, init_poses=1, temporal_robust="gm")
    new = KeypointFitConfig(
        solutions=Solutions(count=3),
        keypoint_term=KeypointTermOptions(weights={"nose": 2.0}),
        starts=Starts(poses=1),
        temporal=TemporalOptions(robust="gm"),
    )
    assert old == new and old.stages() == new.stages() and old.to_dict() == new.to_dict()
    d = new.to_dict()
    assert d["hypotheses"] == 3 and d["keypoint_weights"] == {"nose": 2.0} and d["init_poses"] == 1
    assert d["sigma"] == 100.0 and d["temporal_robust"] == "gm" and d["hypothesis_unrefined"] is True
    assert not {"solutions", "starts", "keypoint_term", "temporal"} & set(d)
    assert new.hypotheses == 3 and new.flip_test is True and new.sigma == 100.0
    new.flip_test = False  # writes through
    assert new.starts == Starts(flip=False, poses=1)
    kp = keypoint_config({"solutions.count": "2", "starts.flip": "false", "keypoint_term.sigma": "50"})
    assert kp.solutions.count == 2 and kp.starts.flip is False and kp.keypoint_term.sigma == 50.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        assert keypoint_config({"init_poses": "1", "hypothesis_joint_max_m": "none"}) == KeypointFitConfig(
            starts=Starts(poses=1), solutions=Solutions(joint_max_m=None)
        )
    with pytest.raises(ValueError, match="starts.poses must be at least 1"):
        KeypointFitConfig(starts=Starts(poses=0))


def test_the_trust_region_settings_are_a_group():
    """``SilhouetteFitConfig.trust`` (:class:`TrustRegion`; ``w_trust``, a weight, stays): the old ``trust_*`` names
    still work and are recorded as before."""
    from silfit.fitting.silhouette_stage import TrustRegion
    from silfit.runner.worker import FitOptions, silhouette_config

    with pytest.warns(DeprecationWarning, match="'trust_free_ratio' is deprecated, use 'trust.free_ratio'"):
        old = SilhouetteFitConfig(trust_free_ratio=1.3, trust_median=0.5)
    new = SilhouetteFitConfig(trust=TrustRegion(free_ratio=1.3, median=0.5))
    assert old == new and old.to_dict() == new.to_dict() and new.trust_median == 0.5
    assert new.to_dict()["trust_free_ratio"] == 1.3 and "trust" not in new.to_dict()
    assert new.free_pass().trust == TrustRegion(fraction=0.06, from_start=False, median=0.5, free_ratio=1.3)
    sil = silhouette_config(FitOptions(silhouette_options={"trust.ratio": "2", "trust.free_ratio": "none"}))
    assert sil.trust == TrustRegion(ratio=2.0)
    with pytest.raises(ValueError, match="trust.fraction, trust.median must be 0 or more"):
        SilhouetteFitConfig(trust=TrustRegion(fraction=-1.0, median=-1.0))
    with pytest.raises(ValueError, match="trust.free_ratio must be above 0"):
        SilhouetteFitConfig(trust=TrustRegion(free_ratio=0.0))


def test_the_rendering_settings_are_a_group():
    """``SilhouetteFitConfig.render`` (:class:`Rendering`; the proxy's faces, table cells, stay): the old names still
    work and are recorded as before, in their old places."""
    from silfit.fitting.silhouette_stage import BEFORE_FOURTH_PART, Rendering
    from silfit.runner.worker import FitOptions, silhouette_config

    with pytest.warns(DeprecationWarning, match="'batch_render' is deprecated, use 'render.batch_render'"):
        old = SilhouetteFitConfig(batch_render=True, seed=None, spp=4)
    new = SilhouetteFitConfig(render=Rendering(batch_render=True, seed=None, spp=4))
    assert old == new and old.to_dict() == new.to_dict() and new.spp == 4 and old.stages() == new.stages()
    keys = list(new.to_dict())
    assert keys.index("spp") < keys.index("margin") and keys.index("optimise") + 1 == keys.index("seed")
    assert keys[keys.index("level_proxy_faces") + 1 :][:2] == ["proxy_body", "batch_render"] and "render" not in keys
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # the library's own settings go by the group's names
        legacy = SilhouetteFitConfig.legacy()
    assert legacy.render == Rendering(spp=BEFORE_FOURTH_PART["spp"], edge_density=None)
    sil = silhouette_config(FitOptions(silhouette_options={"render.seed": "none", "render.edge_spp": "2"}))
    assert sil.render == Rendering(seed=None, edge_spp=2)


def test_the_branch_choice_over_time_is_a_group():
    """``SequenceFitConfig.branch_choice`` (:class:`BranchChoice`): the old ``branch_*`` names still work and are
    recorded as before (tuples kept)."""
    from silfit.fitting.sequence import BranchChoice

    with pytest.warns(DeprecationWarning, match="'branch_offsets' is deprecated, use 'branch_choice.offsets'"):
        old = SequenceFitConfig(branch_offsets=(1, 3), branch_dp=False)
    new = SequenceFitConfig(branch_choice=BranchChoice(offsets=(1, 3), dp=False))
    assert old == new and old.to_dict() == new.to_dict() and new.branch_dp is False
    d = new.to_dict()
    assert d["branch_offsets"] == (1, 3) and d["branch_hypotheses"] == 3 and "branch_choice" not in d
    assert list(d).index("neighbour_starts") + 1 == list(d).index("branch_dp") and old.stages() == new.stages()
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        SequenceFitConfig()  # its keypoint settings by the groups' names


def test_the_record_holds_every_field_of_a_group_a_field_without_a_flat_name_by_its_group():
    """``to_dict`` (metrics.json's record of the settings) leaves no group field out: one added after the flat names
    were grouped (the mask handling's hole and cover settings, issue 55) is recorded as ``group.field``."""
    cfg = SilhouetteFitConfig()
    d = cfg.to_dict()
    assert d["mask.hole_covered"] == 0.5 and d["mask.untrimmed_inner"] == 1.0 and d["mask.whole_iou"] == 0.9
    off = replace(cfg, mask=replace(cfg.mask, hole_covered=0.0, untrimmed_inner=None))
    assert off.to_dict() != d and off.to_dict()["mask.untrimmed_inner"] is None
    assert d["hole_fraction"] == cfg.mask.hole_fraction and "mask.hole_fraction" not in d  # the flat name stays
