"""The image depth cue (issue 54): its gates, and a subject whose keypoints cannot tell a limb's depth but
whose image can."""

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from silfit.fitting import ImageDepthOptions, KeypointFitConfig, KeypointFitter
from silfit.fitting.image_depth import SEGMENTS, DepthCue, ImageDepthConfig, ImageDepthTerm, cue_data, depth_cue
from silfit.io.keypoints import BLAZEPOSE33_NAMES, KeypointSet
from silfit.fitting.keypoint_stage import BranchSearch

NAMES = list(BLAZEPOSE33_NAMES)


def landmarks(forearm_dz: float):
    """A standing person's 33 landmarks (2D pixels and 3D metres, z away from the camera) with the left
    forearm reaching ``forearm_dz`` metres in depth (its length 0.25 m), every landmark fully visible."""
    xy = np.zeros((33, 2))
    world = np.zeros((33, 3))
    pts = {
        "left_shoulder": (120, 100),
        "right_shoulder": (80, 100),
        "left_elbow": (130, 150),
        "right_elbow": (70, 150),
        "left_wrist": (135, 190),
        "right_wrist": (65, 190),
        "left_hip": (112, 200),
        "right_hip": (88, 200),
        "left_knee": (114, 280),
        "right_knee": (86, 280),
        "left_ankle": (115, 360),
        "right_ankle": (85, 360),
    }
    for n, p in pts.items():
        xy[NAMES.index(n)] = p
        world[NAMES.index(n), :2] = (np.asarray(p) - (100, 200)) / 400.0
    world[NAMES.index("left_wrist"), 2] = forearm_dz
    world[NAMES.index("left_wrist"), 1] = world[NAMES.index("left_elbow"), 1] + np.sqrt(0.25**2 - forearm_dz**2)
    return xy, world, np.ones(33)


def keypoints_of(xy) -> KeypointSet:
    from silfit.detect.layout import blazepose_to_layout

    kp = blazepose_to_layout(xy, np.ones(33), "body25")
    return KeypointSet(kp[:, :2], kp[:, 2], "body25")


def forearm(cue: DepthCue):
    s = [n for n, _, _ in SEGMENTS].index("left_forearm")
    return cue.sign[s], cue.confidence[s]


def test_a_confident_call_decides_and_a_near_flat_one_is_off():
    xy, world, vis = landmarks(-0.2)  # depth cosine -0.8: the hand well in front of the elbow
    sign, conf = forearm(depth_cue(world, vis, NAMES, xy, keypoints_of(xy)))
    assert sign == -1 and conf == pytest.approx(1.0)
    xy, world, vis = landmarks(0.04)  # depth cosine 0.16: near-flat, below ImageDepthConfig.off_below
    assert forearm(depth_cue(world, vis, NAMES, xy, keypoints_of(xy))) == (0, 0)
    xy, world, vis = landmarks(-0.2)
    vis[NAMES.index("left_wrist")] = 0.2  # a hidden hand: no call
    assert forearm(depth_cue(world, vis, NAMES, xy, keypoints_of(xy))) == (0, 0)


def test_a_left_right_swapped_landmark_set_is_refused():
    xy, world, vis = landmarks(-0.2)
    kp = keypoints_of(xy)
    swapped = xy.copy()
    for n in NAMES:
        if n.startswith("left_"):
            a, b = NAMES.index(n), NAMES.index("right_" + n[5:])
            swapped[[a, b]] = xy[[b, a]]
    cue = depth_cue(world, vis, NAMES, swapped, kp)
    assert cue.refused and "swapped" in cue.refused
    assert not cue.decided() and (cue.weights() == 0).all()


def test_a_landmark_far_from_its_keypoint_switches_its_segments_off():
    xy, world, vis = landmarks(-0.2)
    kp = keypoints_of(xy)
    moved = xy.copy()
    moved[NAMES.index("left_wrist")] += (40.0, 0.0)  # 40 px off in a 260 px person: another reading of the hand
    cue = depth_cue(world, vis, NAMES, moved, kp)
    assert forearm(cue) == (0, 0) and not cue.refused
    assert forearm(depth_cue(world, vis, NAMES, moved, kp, ImageDepthConfig(max_disagreement=0.2)))[0] == -1


def test_the_term_charges_only_the_other_side_and_is_zero_without_a_cue(body_model):
    from silfit.fitting.terms import Evaluation

    term = ImageDepthTerm(body_model.joint_names, margin=0.1)
    J = torch.zeros(1, 24, 3, dtype=torch.float64)
    w = body_model.joint_names.index("left_wrist")
    J[0, w] = torch.tensor([0.0, 0.15, -0.2], dtype=torch.float64)  # the hand in front of the elbow (cosine -0.8)
    views = {
        "R": torch.eye(3, dtype=torch.float64).expand(1, 1, 1, 3, 3),
        "t": torch.zeros(1, 1, 1, 3, dtype=torch.float64),
    }

    def ev(data):
        return Evaluation(
            1, 1, 1, {}, {}, type("B", (), {"joints": J})(), torch.zeros(1, 1, 1, 25, 2), None, data, views=views
        )

    assert float(term(ev({}))) == 0.0
    s = [n for n, _, _ in SEGMENTS].index("left_forearm")
    cue = np.zeros((1, 1, len(SEGMENTS)))
    cue[0, 0, s] = -0.5  # nearer, confidence 0.5: the fit agrees
    assert float(term(ev({"image_depth": torch.as_tensor(cue)}))) == 0.0
    cue[0, 0, s] = 0.5  # farther: (0.1 + 0.8)^2 * 0.5
    assert float(term(ev({"image_depth": torch.as_tensor(cue)}))) == pytest.approx(0.5 * 0.9**2)
    assert cue_data([None, None]) is None


FAST = KeypointFitConfig(
    camera_iters=20,
    pose_iters=(20, 20, 30),
    shape_iters=10,
    final_iters=40,
    branches=BranchSearch(late_iters=20, post_iters=20),
)


@pytest.fixture(scope="module")
def reaching_subject(body_model):
    """A generated hard subject (``silfit synth --poses hard``, seed 20003, subject 7, 256 px) whose right arm
    reaches toward the camera: its keypoints fit as well with the arm reaching away."""
    from silfit.io.subjects import load_subject
    from silfit.synth.generate import SynthConfig, generate_subject

    with tempfile.TemporaryDirectory() as tmp:
        generate_subject(
            body_model, 7, SynthConfig(seed=20003, size=256, poses="hard", frontal_first=False), Path(tmp) / "s"
        )
        return load_subject(Path(tmp) / "s")


def test_the_image_decides_a_limb_the_keypoints_cannot(body_model, reaching_subject):
    from silfit.eval.metrics import pa_pve
    from silfit.fitting.image_depth import cue_from_image

    s = reaching_subject
    names = body_model.joint_names
    cue, record = cue_from_image(s.image, s.keypoints)  # the shipped landmark model on the rendered image
    assert cue is not None and record["decided"]["right_forearm"]["distal"] == "nearer"
    fitter = KeypointFitter(body_model, config=replace_weight(FAST, 100.0))  # the weight measured; off by default

    def fit(cues):
        with torch.no_grad():
            r = fitter.fit([s.keypoints], [s.camera], progress=False, depth_cues=cues)
        dz = r.joints[0, names.index("right_wrist"), 2] - r.joints[0, names.index("right_elbow"), 2]
        return 1000 * pa_pve(r.vertices[0].astype(np.float64), s.gt.vertices), dz

    truth_dz = s.gt.joints[names.index("right_wrist"), 2] - s.gt.joints[names.index("right_elbow"), 2]
    assert truth_dz < -0.15  # the hand 15+ cm nearer the camera than the elbow
    without, dz_without = fit(None)  # measured: 260 mm, the arm reaching away
    assert without > 150 and dz_without > 0
    with_cue, dz_with = fit([cue])  # measured: 50 mm
    assert with_cue < 100 and dz_with < 0


def test_without_an_image_the_fit_is_the_same_bit_for_bit(body_model, reaching_subject):
    s = reaching_subject
    fitter = KeypointFitter(
        body_model,
        config=KeypointFitConfig(
            camera_iters=5,
            pose_iters=(5, 5, 5),
            shape_iters=3,
            final_iters=5,
            image_depth=ImageDepthOptions(weight=100.0),
            branches=BranchSearch(late_iters=4, post_iters=4),
        ),
    )
    a = fitter.fit([s.keypoints], [s.camera], progress=False)
    b = fitter.fit([s.keypoints], [s.camera], progress=False, depth_cues=[None])
    off = KeypointFitter(body_model, config=replace_weight(fitter.config, 0.0)).fit(
        [s.keypoints], [s.camera], progress=False
    )
    assert np.array_equal(a.joints, b.joints) and np.array_equal(a.joints, off.joints)
    assert a.energies["final"][0] == off.energies["final"][0]


def replace_weight(cfg, w):
    return replace(cfg, image_depth=replace(cfg.image_depth, weight=w))


def test_the_depth_warning_names_only_limbs_the_image_leaves_undecided():
    from silfit.fitting.plausibility import depth_warnings

    close = [
        {
            "stage": "branches_1",
            "kept": "keep",
            "tried": [
                {"flip": "keep", "energy": 100.0},
                {"flip": "left_upper_arm", "energy": 101.0},
                {"flip": "right_shin", "energy": 101.5},
            ],
        }
    ]
    (w,) = depth_warnings(close)
    assert w.startswith("depth ambiguous for left_upper_arm, right_shin:")
    (w,) = depth_warnings(close, decided=["left_upper_arm"])
    assert w.startswith("depth ambiguous for right_shin:") and "left_upper_arm" not in w
    assert depth_warnings(close, decided=["left_upper_arm", "right_shin"]) == []


def test_metrics_say_image_depth_none_without_an_image(body_model, reaching_subject):
    from silfit.run import fit

    s = reaching_subject
    cfg = KeypointFitConfig(
        camera_iters=3,
        pose_iters=(3, 3, 3),
        shape_iters=2,
        final_iters=3,
        decision_iters=2,
        branches=BranchSearch(late_iters=2, post_iters=2),
    )
    r = fit(s.keypoints, camera=s.camera, model=body_model, keypoint_config=cfg, progress=False)
    assert r.metrics["image_depth"] == "none"
    r = fit(s.keypoints, camera=s.camera, model=body_model, keypoint_config=cfg, progress=False, image=s.image)
    assert r.metrics["image_depth"] == "off"  # the default: the cue is asked for
    cfg = replace_weight(cfg, 100.0)
    r = fit(s.keypoints, camera=s.camera, model=body_model, keypoint_config=cfg, progress=False, image=s.image)
    assert r.metrics["image_depth"]["decided"]["right_forearm"]["distal"] == "nearer"
    cfg = replace(cfg, image_depth=ImageDepthOptions(decide=0.6))  # the hard choice alone: the cue runs too
    r = fit(s.keypoints, camera=s.camera, model=body_model, keypoint_config=cfg, progress=False, image=s.image)
    assert r.metrics["image_depth"]["branch_choice"]["segments"]["right_forearm"] == "nearer"


@pytest.mark.parametrize("screens,early", [(True, True), (False, True), (False, False)])
def test_the_image_decides_the_branch_as_a_hard_choice(body_model, reaching_subject, screens, early):
    """``image_depth.decide``: the cue's confident calls choose among the branch search's hypotheses (the term off;
    ``image_depth.decide_screens`` and ``image_depth.decide_early`` either way); ignored, this subject's right arm is fitted reaching away (260 mm
    PA-PVE, measured)."""
    from silfit.eval.metrics import pa_pve
    from silfit.fitting.image_depth import cue_from_image

    s = reaching_subject
    names = body_model.joint_names
    cue, _ = cue_from_image(s.image, s.keypoints)
    assert cue.hard_signs(0.6)[[n for n, _, _ in SEGMENTS].index("right_forearm")] == -1  # nearer, confident
    fitter = KeypointFitter(
        body_model,
        config=replace(FAST, image_depth=ImageDepthOptions(decide=0.6, decide_screens=screens, decide_early=early)),
    )
    assert fitter.config.image_depth.weight == 0.0
    with torch.no_grad():
        r = fitter.fit([s.keypoints], [s.camera], progress=False, depth_cues=[cue])
    dz = r.joints[0, names.index("right_wrist"), 2] - r.joints[0, names.index("right_elbow"), 2]
    assert dz < 0 and 1000 * pa_pve(r.vertices[0].astype(np.float64), s.gt.vertices) < 100  # measured: 47 mm
    record = r.branch_search[0][-1]["image_depth"]  # the final choice names the sides it took as decided
    assert record["decided"]["right_forearm"] == "nearer" and record["fit_agrees"]


def test_without_an_image_the_hard_choice_changes_nothing(body_model, reaching_subject):
    s = reaching_subject
    tiny = KeypointFitConfig(
        camera_iters=5,
        pose_iters=(5, 5, 5),
        shape_iters=3,
        final_iters=5,
        branches=BranchSearch(late_iters=4, post_iters=4),
    )
    a = KeypointFitter(
        body_model, config=replace(tiny, image_depth=ImageDepthOptions(decide=0.6, decide_screens=False))
    ).fit([s.keypoints], [s.camera], progress=False, depth_cues=[None])
    b = KeypointFitter(body_model, config=tiny).fit([s.keypoints], [s.camera], progress=False)
    assert np.array_equal(a.joints, b.joints) and a.energies["final"][0] == b.energies["final"][0]
    assert a.branch_search == b.branch_search


def test_rows_against_the_decided_sides_rank_after_those_that_agree():
    from silfit.fitting.image_depth import demote_disagreeing
    from silfit.fitting.keypoint_stage import best_per_group

    f = torch.tensor([10.0, 12.0, 11.0, 5.0, 6.0], dtype=torch.float64)
    group = torch.tensor([0, 0, 0, 1, 1])
    against = torch.tensor([True, False, True, True, True])
    score = demote_disagreeing(f, group, 2, against)
    assert best_per_group(score, group, 2).tolist() == [1, 3]  # sample 1: none agrees, the energy chooses
    assert best_per_group(score, group, 2, count=3).tolist() == [1, 0, 2, 3, 4]
    assert torch.equal(score[3:], f[3:])


def test_a_mirrored_reading_read_back_is_the_reading():
    """unmirror_person maps the flipped image's landmarks back: x -> W - 1 - x, left and right swapped, the 3D's x
    negated; twice is the identity, and the depth (z) of each named landmark is kept."""
    from silfit.detect.geometry import ROI
    from silfit.detect.person import Person
    from silfit.fitting.image_depth import unmirror_person

    xy, world, vis = landmarks(-0.2)
    vis = np.linspace(0.3, 1.0, 33)
    roi = ROI(100.0, 200.0, 300.0, 0.0)
    p = Person(
        0.9,
        0.9,
        roi,
        ROI(60.0, 200.0, 300.0, 0.25),
        xy,
        world[:, 2].copy(),
        vis,
        vis,
        world,
        np.zeros((400, 200), np.float32),
        (200, 400),
    )
    m = unmirror_person(p)
    np.testing.assert_allclose(  # the region too: its corners the flipped image's, mirrored
        sorted(map(tuple, m.roi.corners())), sorted((199 - x, y) for x, y in p.roi.corners())
    )
    li, ri = NAMES.index("left_wrist"), NAMES.index("right_wrist")
    assert m.xy[li, 0] == 199 - xy[ri, 0] and m.world[li, 2] == world[ri, 2] and m.visibility[li] == vis[ri]
    assert m.world[li, 0] == -world[ri, 0]
    back = unmirror_person(m)
    assert back.roi == p.roi and back.detector_roi == p.detector_roi
    for a, b in ((back.xy, xy), (back.world, world), (back.visibility, vis), (back.z, world[:, 2])):
        np.testing.assert_array_equal(a, b)


def test_two_readings_keep_only_the_calls_they_agree_on():
    from silfit.fitting.image_depth import agreed_cue

    S = len(SEGMENTS)
    a = DepthCue(np.array([1.0, -1.0, 1.0, 0.0] + [1.0] * (S - 4)), np.full(S, 0.9), np.full(S, 0.7))
    b = DepthCue(np.array([1.0, 1.0, 1.0, 1.0] + [1.0] * (S - 4)), np.full(S, 0.6), np.full(S, -0.5))
    b.confidence[2] = 0.0  # the second reading leaves segment 2 off
    c = agreed_cue(a, b)
    assert list(c.sign[:4]) == [1.0, 0.0, 0.0, 0.0]  # differing signs, one reading off, one sign 0: off
    assert c.confidence[0] == 0.6 and c.ratio[0] == -0.5  # the smaller confidence, the flatter cosine
    assert not agreed_cue(a, None).confidence.any()  # no second reading: nothing decided


def test_the_mirror_image_reads_the_same_confident_call(reaching_subject):
    """The landmark model on the rendered subject and on its mirror image: both readings call the reaching forearm
    nearer, so the agreed cue keeps it."""
    from silfit.fitting.image_depth import cue_from_image, mirrored_person, person_cue

    s = reaching_subject
    other = mirrored_person(s.image, s.keypoints)
    assert other is not None
    names = [n for n, _, _ in SEGMENTS]
    assert person_cue(other, s.keypoints).sign[names.index("right_forearm")] == -1.0
    cue, record = cue_from_image(s.image, s.keypoints, config=ImageDepthConfig(mirror=True))
    assert record["decided"]["right_forearm"]["distal"] == "nearer"
