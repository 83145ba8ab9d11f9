"""Plausibility: degenerate keypoints refused, far-outside keypoints dropped, implausible
fits reported as warnings (unit tests of the pure functions, and through ``silfit fit``)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from silfit.errors import InputError
from silfit.io.keypoints import KeypointSet, read_keypoints
from silfit.fitting.plausibility import MIN_PERSON_PX, check_keypoints, fit_warnings

SUBJECT = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "subject_000"


@pytest.fixture
def kp():
    return read_keypoints(SUBJECT / "keypoints.json")


def _with(kp, xy=None, conf=None):
    return KeypointSet(kp.xy if xy is None else xy, kp.conf if conf is None else conf, kp.layout, source="kp.json")


def test_a_real_person_passes_unchanged(kp):
    out, warnings = check_keypoints(kp, (512, 512))
    assert out is kp and warnings == []


def test_far_outside_keypoints_are_treated_as_missing(kp):
    xy = kp.xy.copy()
    wrist = kp.names.index("right_wrist")
    xy[wrist] = (1e30, -1e30)
    out, warnings = check_keypoints(_with(kp, xy), (512, 512))
    assert out.conf[wrist] == 0 and np.all(out.xy[wrist] == 0)
    assert np.array_equal(np.delete(out.conf, wrist), np.delete(kp.conf, wrist))
    assert len(warnings) == 1 and "right_wrist" in warnings[0] and "treated as missing" in warnings[0]
    xy[:] = 1e9
    with pytest.raises(InputError, match="every keypoint lies far outside"):
        check_keypoints(_with(kp, xy), (512, 512))


@pytest.mark.parametrize("case", ["one_place", "few_pixels", "zero_torso"])
def test_degenerate_keypoints_are_refused(kp, case):
    xy = kp.xy.copy()
    if case == "one_place":
        xy[:] = (100.0, 120.0)
        expect = "span only 0.0 px"
    elif case == "few_pixels":
        centre = xy[kp.conf > 0].mean(0)
        xy = centre + (xy - centre) * (0.5 * MIN_PERSON_PX / np.ptp(xy[kp.conf > 0], axis=0).max())
        expect = "needs a person at least"
    else:
        hips = [kp.names.index(n) for n in ("mid_hip", "left_hip", "right_hip")]
        for n in ("neck", "left_shoulder", "right_shoulder"):
            xy[kp.names.index(n)] = xy[hips].mean(0)
        expect = "torso .* px long"
    with pytest.raises(InputError, match=expect):
        check_keypoints(_with(kp, xy), (512, 512))


def test_fit_warnings(kp):
    ok_vertices = np.random.default_rng(0).normal([0, 0, 3], 0.3, size=(100, 3))
    good = {"iou": 0.95, "iou_keypoint_stage": 0.9, "reprojection_error_px": 2.0}
    assert fit_warnings(good, kp, ok_vertices) == []
    noise = fit_warnings(dict(good, iou=0.06, iou_keypoint_stage=0.8), kp, ok_vertices)
    assert any("only 0.060" in w for w in noise) and any("far below the keypoint fit's 0.800" in w for w in noise)
    assert "500.0" in fit_warnings(good, kp, ok_vertices + [0, 0, 497])[0]
    assert "behind the camera" in fit_warnings(good, kp, ok_vertices - [0, 0, 3])[0]
    far = fit_warnings(dict(good, reprojection_error_px=100.0), kp, ok_vertices)
    assert len(far) == 1 and "reprojection error 100.0 px" in far[0]
    assert "non-finite" in fit_warnings(good, kp, ok_vertices * np.nan)[0]


def test_through_silfit_fit(tmp_path, capsys):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from silfit_toy_body import write_toy_npz

    from silfit.cli import main

    model = write_toy_npz(tmp_path / "toy.npz")
    data = json.loads((SUBJECT / "keypoints.json").read_text())
    values = data["people"][0]["pose_keypoints_2d"]
    values[4 * 3 : 4 * 3 + 2] = [1e30, 1e30]  # right wrist
    (tmp_path / "kp.json").write_text(json.dumps(data))
    args = [
        "fit",
        "--keypoints",
        str(tmp_path / "kp.json"),
        "--camera",
        str(SUBJECT / "camera.json"),
        "--model",
        str(model),
        "--no-silhouette",
    ]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    warnings = json.loads((tmp_path / "a" / "metrics.json").read_text())["warnings"]
    assert any("right_wrist" in w and "treated as missing" in w for w in warnings)
    assert "warning:" in err and "right_wrist" in err
    data["people"][0]["pose_keypoints_2d"] = [200.0, 200.0, 1.0] * 25
    (tmp_path / "kp.json").write_text(json.dumps(data))
    assert main(args + ["--out", str(tmp_path / "b"), "--quiet"]) == 2
    assert "span only 0.0 px" in capsys.readouterr().err and not (tmp_path / "b").exists()


def test_video_frames_get_the_checks_of_one_image(kp):
    from silfit.fitting.plausibility import check_frames

    wrist = kp.names.index("right_wrist")
    one_far = kp.xy.copy()
    one_far[wrist] = (1e30, 1e30)
    frames = [kp, None, _with(kp, one_far), _with(kp, np.full_like(kp.xy, 1e30)), kp]
    out, warnings = check_frames(frames, (512, 512), numbers=[10, 11, 12, 13, 14])
    assert out[0] is kp and out[1] is None and out[4] is kp
    assert out[2].conf[wrist] == 0 and out[3] is None  # refused keypoints: a frame without a detection (bridged)
    assert len(warnings) == 2 and warnings[0].startswith("frame(s) 12:") and warnings[1].startswith("frame(s) 13:")
    with pytest.raises(InputError, match="no frame has usable keypoints; frame 13"):
        check_frames([None, frames[3]], (512, 512), numbers=[12, 13])


def test_a_silhouette_stage_that_leaves_the_keypoints_or_the_shape_space_is_reported(kp):
    verts = np.array([[0.0, 0.0, 3.0], [0.1, 0.5, 3.1]])
    drift = fit_warnings({"reprojection_error_px": 11.6, "reprojection_error_px_keypoint_stage": 1.9}, kp, verts)
    assert len(drift) == 1 and "1.9 -> 11.6 px" in drift[0] and "stages/keypoints" in drift[0]
    assert (
        fit_warnings({"reprojection_error_px": 3.0, "reprojection_error_px_keypoint_stage": 1.0}, kp, verts) == []
    )  # +2 px only
    shape = fit_warnings({}, kp, verts, betas=np.array([0.5, -4.4, 0.0]))
    assert len(shape) == 1 and "|betas| up to 4.4" in shape[0]
    assert fit_warnings({}, kp, verts, betas=np.array([2.9, -2.0])) == []


def test_branch_gap_is_the_kept_hypothesis_margin():
    from silfit.fitting.plausibility import branch_gap

    search = [
        {
            "stage": "branches_1",
            "kept": "left_shin",
            "tried": [
                {"flip": "left_shin", "energy": 100.0},
                {"flip": "keep", "energy": 103.0},
                {"flip": "right_thigh", "energy": 150.0},
            ],
        },
        {
            "stage": "branches_2",
            "kept": "keep",
            "tried": [{"flip": "keep", "energy": 90.0}, {"flip": "left_arm", "energy": 99.0}],
        },
    ]
    assert branch_gap(search) == pytest.approx(0.03)  # the smaller of 3 % and 10 %
    assert branch_gap([{"stage": "b", "kept": "keep", "tried": [{"flip": "keep", "energy": 5.0}]}]) is None
    assert branch_gap(None) is None


def test_a_mask_that_runs_out_of_the_image_is_reported():
    from silfit.fitting.plausibility import mask_warnings

    m = np.zeros((100, 80), bool)
    m[20:80, 30:50] = True
    assert mask_warnings(m) == []
    m[20:, 30:50] = True  # cut at the bottom: 20 of 80 border pixels
    w = mask_warnings(m, "person.png")
    assert len(w) == 1 and w[0].startswith("person.png:") and "bottom edge" in w[0]


def test_a_depth_branch_the_keypoints_cannot_decide_is_reported():
    from silfit.fitting.plausibility import depth_warnings

    close = [
        {
            "stage": "branches_1",
            "kept": "keep",
            "tried": [{"flip": "keep", "energy": 100.0}, {"flip": "left_upper_arm", "energy": 101.0}],
        }
    ]
    (w,) = depth_warnings(close)
    assert w.startswith("depth ambiguous for left_upper_arm:") and "branch search: left_upper_arm" in w
    assert w.endswith("check a side view (silfit fit --hypotheses 3 writes the alternatives)")
    (again,) = depth_warnings(close + close)  # two searches keeping the same alternative: it is named once
    assert again == w
    far = [
        {
            "stage": "branches_1",
            "kept": "keep",
            "tried": [{"flip": "keep", "energy": 100.0}, {"flip": "left_shin", "energy": 125.0}],
        }
    ]
    assert depth_warnings(far) == [] and depth_warnings(None) == []


def test_video_frames_whose_mask_runs_out_of_the_image_are_named():
    from silfit.fitting.sequence import _cut_off_frames

    inside = np.zeros((60, 40), bool)
    inside[10:50, 10:30] = True
    cut = inside.copy()
    cut[10:, 10:30] = True
    w = _cut_off_frames([inside, None, cut, cut])
    assert len(w) == 1 and w[0].startswith("frame(s) 2, 3:") and "cut off" in w[0]
    assert _cut_off_frames([inside, None]) == []


def test_silhouette_guard_keeps_the_keypoint_fit_when_the_refined_one_is_less_plausible():
    from silfit.fitting.plausibility import fit_summary, silhouette_guard

    kp = fit_summary(2.0, np.zeros(10), 1.70)
    assert silhouette_guard(kp, fit_summary(2.5, np.full(10, 1.0), 1.75)).keep == "silhouette"
    small = fit_summary(1.0, np.zeros(10), 1.70)
    assert silhouette_guard(small, fit_summary(1.9, np.zeros(10), 1.70)).keep == "silhouette"  # 1.9x but 0.9 px more
    rise = silhouette_guard(kp, fit_summary(4.0, np.zeros(10), 1.70), "photo.jpg")
    assert rise.reverted and "2.0 -> 4.0 px" in rise.reasons[0] and rise.warnings[0].startswith("photo.jpg: ")
    assert "kept the keypoint fit" in rise.warnings[0]
    fat = silhouette_guard(kp, fit_summary(2.0, np.r_[3.4, np.zeros(9)], 1.70))
    assert fat.reverted and "3.4" in fat.reasons[0]
    assert silhouette_guard(kp, fit_summary(2.0, np.zeros(10), 2.30)).reverted  # a giant
    assert silhouette_guard(kp, fit_summary(2.0, np.zeros(10), 1.10)).reverted
    # implausible in the same way as the keypoint fit: that one is no better, keep the refined fit
    odd = fit_summary(2.0, np.r_[3.5, np.zeros(9)], 1.70)
    assert silhouette_guard(odd, fit_summary(2.0, np.r_[3.6, np.zeros(9)], 1.70)).keep == "silhouette"


def test_body_stature_follows_the_shape(open_model):
    from silfit.fitting.plausibility import STATURE_RANGE_M, body_stature

    mean = body_stature(open_model, np.zeros(10))
    assert STATURE_RANGE_M[0] < mean < STATURE_RANGE_M[1]
    tall = body_stature(open_model, np.r_[3.0, np.zeros(9)])
    short = body_stature(open_model, np.r_[-3.0, np.zeros(9)])
    assert abs(tall - short) > 0.2


def test_hypotheses_are_summarised_and_the_ambiguous_limbs_named():
    from silfit.fitting.plausibility import depth_warnings, hypothesis_summary

    hyps = [
        {"label": "keep", "energy": 100.0, "differs": []},
        {"label": "both_shins", "energy": 101.5, "differs": ["left_shin", "right_shin"]},
        {"label": "left_forearm", "energy": 140.0, "differs": ["left_forearm"]},
    ]
    rows = hypothesis_summary(hyps)
    assert [r["rank"] for r in rows] == [1, 2, 3] and rows[1]["gap"] == pytest.approx(0.015)
    (warning,) = depth_warnings(None, hyps)
    assert warning.startswith("depth ambiguous for left_shin, right_shin: an alternative fit within 10% of the energy")
    assert "hypotheses/2" in warning and "left_forearm" not in warning  # 40 % higher: not ambiguous
    assert warning.endswith("check a side view")  # the alternative is written already
    assert depth_warnings(None, hyps[:1]) == [] and depth_warnings(None, None) == []
    assert "left_forearm" in depth_warnings(None, hyps, margin=0.5)[0]


def test_depth_warning_names_the_limbs_of_close_alternatives():
    from silfit.fitting.plausibility import HYPOTHESIS_MARGIN, SEARCH_MARGIN, depth_warnings

    def search(*tried, kept="keep"):
        return [{"stage": "branches_1", "kept": kept, "tried": [{"flip": f, "energy": e} for f, e in tried]}]

    # default fits (no hypotheses refined): the branch search's survivors within SEARCH_MARGIN
    (w,) = depth_warnings(
        search(("keep", 100.0), ("both_shins", 100 * (1 + SEARCH_MARGIN) - 1), ("left_forearm", 150.0))
    )
    assert w.startswith("depth ambiguous for left_shin, right_shin:") and "branch search: both_shins" in w
    assert "left_forearm" not in w
    assert depth_warnings(search(("keep", 100.0), ("left_forearm", 100 * (1 + SEARCH_MARGIN) + 1))) == []
    # an unflipped alternative to a flipped fit: the fit's flipped segments are the ambiguous ones
    (w,) = depth_warnings(search(("left_thigh+left_shin", 100.0), ("keep", 101.0), kept="left_thigh+left_shin"))
    assert "left_shin, left_thigh" in w
    assert depth_warnings(None) == [] and depth_warnings([]) == []
    # refined hypotheses decide where there are distinct ones: their final energies, the tighter margin
    hyps = [
        {"label": "keep", "energy": 100.0, "differs": []},
        {"label": "right_upper_arm", "energy": 100 * (1 + HYPOTHESIS_MARGIN) - 0.5, "differs": []},
    ]
    close = search(("keep", 100.0), ("left_shin", 101.0))
    (w,) = depth_warnings(close, hyps)
    assert "right_upper_arm" in w and "hypotheses/2" in w and "left_shin" not in w
    far = [hyps[0], dict(hyps[1], energy=100 * (1 + HYPOTHESIS_MARGIN) + 1)]
    assert depth_warnings(close, far) == []
    assert depth_warnings(close, far[:1])  # no distinct alternative refined: the search decides


def test_an_alternative_that_moves_no_joint_far_is_no_depth_warning():
    # issue 25: a close alternative warns only when it moves some joint far from the fit (MIN_SHIFT_MM for
    # refined hypotheses, SEARCH_MIN_SHIFT_MM for branch-search survivors)
    from silfit.fitting.plausibility import MIN_SHIFT_MM, SEARCH_MIN_SHIFT_MM, depth_warnings, moves_a_joint

    assert SEARCH_MIN_SHIFT_MM < 450 and MIN_SHIFT_MM < 450

    assert moves_a_joint({"max_shift_mm": MIN_SHIFT_MM}) and not moves_a_joint({"max_shift_mm": MIN_SHIFT_MM - 1})
    assert moves_a_joint({})  # recorded before joint shifts were: the energy alone decides
    tried = [
        {"flip": "keep", "energy": 100.0, "shift_mm": 2.0, "max_shift_mm": 5.0},
        {"flip": "left_shin", "energy": 101.0, "shift_mm": 12.0, "max_shift_mm": 120.0},
        {"flip": "right_forearm", "energy": 104.0, "shift_mm": 25.0, "max_shift_mm": 450.0},
    ]
    search = [{"stage": "branches_late", "kept": "keep", "tried": tried}]
    (w,) = depth_warnings(search)
    assert w.startswith("depth ambiguous for right_forearm:") and "0.45 m" in w and "left_shin" not in w
    assert depth_warnings(search[:1], search_min_shift_mm=500) == []
    assert "left_shin" in depth_warnings(search, search_min_shift_mm=0)[0]
    # refined hypotheses likewise; unrefined ones (search energies) never count as refined alternatives
    hyps = [
        {"label": "keep", "energy": 100.0, "differs": [], "refined": True, "shift_mm": 0.0, "max_shift_mm": 0.0},
        {
            "label": "left_shin",
            "energy": 105.0,
            "differs": ["left_shin"],
            "refined": True,
            "shift_mm": 9.0,
            "max_shift_mm": 90.0,
        },
        {
            "label": "both_arms",
            "energy": 50.0,
            "differs": ["left_upper_arm"],
            "refined": False,
            "stage": "branches_1",
            "gap": 0.05,
            "shift_mm": 60.0,
            "max_shift_mm": 500.0,
        },
    ]
    assert depth_warnings(None, hyps) == []  # the refined alternative moves a joint 90 mm only
    (w,) = depth_warnings(None, [hyps[0], dict(hyps[1], max_shift_mm=450.0), hyps[2]])
    assert "hypotheses/2" in w and "hypotheses/3" not in w and "left_upper_arm" not in w
    # one refined hypothesis only: the branch search decides
    assert depth_warnings(search, [hyps[0], hyps[2]])[0].startswith("depth ambiguous for right_forearm")


def test_unrefined_hypotheses_are_summarised_with_their_search_gap():
    from silfit.fitting.plausibility import hypothesis_summary

    hyps = [
        {"label": "keep", "energy": 100.0, "differs": [], "refined": True, "shift_mm": 0.0, "max_shift_mm": 0.0},
        {
            "label": "left_arm",
            "energy": 40.0,
            "differs": ["left_forearm"],
            "refined": False,
            "stage": "branches_1",
            "gap": 0.12,
            "shift_mm": 41.0,
            "max_shift_mm": 380.0,
        },
    ]
    rows = hypothesis_summary(hyps)
    assert rows[0]["refined"] and rows[0]["gap"] == 0.0 and rows[0]["max_shift_mm"] == 0.0
    assert rows[1] == {
        "rank": 2,
        "label": "left_arm",
        "energy": 40.0,
        "gap": 0.12,
        "differs": ["left_forearm"],
        "refined": False,
        "shift_mm": 41.0,
        "max_shift_mm": 380.0,
        "stage": "branches_1",
    }


def test_with_branches_refined_to_the_end_their_final_energies_decide_the_depth_warning():
    # the fit is the refined branch with the lowest final energy, which need not be the search's lowest:
    # the last search's energies (far from converged) no longer say whether an alternative is close
    from silfit.fitting.plausibility import (
        EARLY_SEARCH_MARGIN,
        EARLY_SEARCH_MIN_SHIFT_MM,
        HYPOTHESIS_MARGIN,
        MIN_SHIFT_MM,
        depth_warnings,
    )

    def record(*finals):
        return {
            "stage": "final",
            "kept": finals[0][0],
            "refined": True,
            "tried": [{"flip": f, "energy": e, "differs": d, "max_shift_mm": m} for f, e, d, m in finals],
        }

    def searched(stage, kept, *tried, shift=EARLY_SEARCH_MIN_SHIFT_MM):
        return {
            "stage": stage,
            "kept": kept,
            "tried": [{"flip": f, "energy": e, "max_shift_mm": shift} for f, e in tried],
        }

    late = searched("branches_late", "left_shin", ("keep", 100.0), ("left_shin", 108.0))  # "keep" 8 % below the kept
    far = record(("left_shin", 80.0, [], 0.0), ("keep", 80 * (1 + HYPOTHESIS_MARGIN) + 1, ["left_shin"], 500.0))
    assert depth_warnings([late]) and depth_warnings([late, far]) == []
    close = record(("left_shin", 80.0, [], 0.0), ("keep", 80 * (1 + HYPOTHESIS_MARGIN) - 1, ["left_shin"], 500.0))
    (w,) = depth_warnings([late, close])
    assert w.startswith("depth ambiguous for left_shin:") and "refined branch: keep" in w and "branch search" not in w
    near = record(("left_shin", 80.0, [], 0.0), ("keep", 81.0, ["left_shin"], MIN_SHIFT_MM - 1))
    assert depth_warnings([late, near]) == []  # close in energy, but no joint moves far
    assert depth_warnings([late, record(("left_shin", 80.0, [], 0.0))]) == []  # the refined ones agree
    # an earlier search's survivor never refined: close by that search's energies, the tighter margin
    first = searched("branches_1", "keep", ("keep", 200.0), ("right_forearm", 200 * (1 + EARLY_SEARCH_MARGIN) - 1))
    (w,) = depth_warnings([first, late, far])
    assert "right_forearm" in w and "branch search: right_forearm" in w
    first_far = searched("branches_1", "keep", ("keep", 200.0), ("right_forearm", 200 * (1 + EARLY_SEARCH_MARGIN) + 1))
    assert depth_warnings([first_far, late, far]) == []
    first_near = searched(
        "branches_1", "keep", ("keep", 200.0), ("right_forearm", 200.0), shift=EARLY_SEARCH_MIN_SHIFT_MM - 1
    )
    assert depth_warnings([first_near, late, far]) == []  # as close as can be, but no joint moves far
    # with --hypotheses K the record still decides (every refined branch; hypotheses keeps K of them), and
    # a branch also among the hypotheses is named by its folder
    hyps = [
        {"label": "left_shin", "energy": 80.0, "differs": []},
        {"label": "keep", "energy": close["tried"][1]["energy"], "differs": ["left_shin"], "max_shift_mm": 500.0},
    ]
    (w,) = depth_warnings([late, close], hyps)
    assert "hypotheses/2" in w and "refined branch" not in w
    assert "refined branch: keep" in depth_warnings([late, close], hyps[:1])[0]  # cut to K = 1: still read
    assert depth_warnings([late, far], hyps) == []  # the record's final energies, not the hypotheses' list
