"""The whole fit (keypoints, then silhouette) on shipped synthetic subjects."""

from pathlib import Path

import numpy as np
import pytest

from silfit.io.subjects import load_subject
from silfit.run import fit
from silfit.fitting.keypoint_stage import BranchSearch, KeypointFitConfig, Solutions, Starts
from silfit.fitting.silhouette_stage import MaskHandling, TrustRegion

SHIPPED = Path(__file__).resolve().parents[2] / "data" / "synthetic"
#: a few keypoint steps from one start, no branch search (the keypoint fit is only a start for these tests)
FEW_STEPS = KeypointFitConfig(
    camera_iters=5,
    pose_iters=(5, 5, 5),
    shape_iters=0,
    final_iters=0,
    starts=Starts(poses=1),
    branches=BranchSearch(search=False),
)


@pytest.fixture(scope="module")
def subject():
    s = load_subject(SHIPPED / "subject_000")
    assert s.gt.extras["noise_px"] == 0.0  # the noise-free subject the issue asks for
    return s


def test_silhouette_stage_raises_iou_on_a_noise_free_subject(open_model, subject):
    result = fit(subject.keypoints, subject.mask, subject.camera, model=open_model, progress=False)
    m = result.metrics
    print(f"IoU keypoint stage {m['iou_keypoint_stage']:.3f} -> silhouette stage {m['iou']:.3f}")
    assert m["iou"] > m["iou_keypoint_stage"]
    assert m["iou"] >= 0.9
    assert m["reprojection_error_px"] < 2.0  # the keypoints still hold
    assert result.vertices.shape == (open_model.num_vertices, 3)
    # no warning but the depth one: the branches refined to the end (branch_refine) within
    # plausibility.HYPOTHESIS_MARGIN that move a joint plausibility.MIN_SHIFT_MM (it may or may not fire here)
    assert not [w for w in m["warnings"] if not w.startswith("depth ambiguous")], m["warnings"]


def test_keypoints_only_when_no_mask(open_model, subject):
    result = fit(subject.keypoints, camera=subject.camera, model=open_model, progress=False)
    assert result.silhouette is None and result.metrics["stages"] == ["keypoints"]
    assert np.allclose(result.params["body_pose"], result.keypoint.body_pose[0])


def test_mask_that_misses_the_body_is_an_error(open_model, subject):
    far = np.zeros_like(subject.mask)
    far[:10, :10] = True  # a corner far from the person
    with pytest.raises(ValueError, match="does not overlap"):
        fit(subject.keypoints, far, subject.camera, model=open_model, progress=False)


def test_mask_of_another_size_is_an_error(open_model, subject):
    with pytest.raises(ValueError, match="256x128.*256x256"):
        fit(subject.keypoints, subject.mask[:128], subject.camera, model=open_model, progress=False)


def test_save_fit_leaves_nothing_when_a_write_fails(open_model, subject, tmp_path, monkeypatch):
    from silfit.outputs import figures
    from silfit import save_fit

    cfg = KeypointFitConfig(
        camera_iters=5, pose_iters=(5, 5, 5), shape_iters=0, final_iters=0, branches=BranchSearch(search=False)
    )
    result = fit(subject.keypoints, camera=subject.camera, model=open_model, keypoint_config=cfg, progress=False)
    faces = open_model.faces.numpy()
    old = tmp_path / "old"
    save_fit(result, old, faces, subject.keypoints)
    before = sorted(p.relative_to(old) for p in old.rglob("*"))

    def broken(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(figures, "write_png", broken)  # fails after params.npz and mesh.obj are written
    with pytest.raises(RuntimeError, match="disk full"):
        save_fit(result, tmp_path / "new", faces, subject.keypoints)
    with pytest.raises(RuntimeError, match="disk full"):
        save_fit(result, old, faces, subject.keypoints, overwrite=True)
    assert not (tmp_path / "new").exists()
    assert sorted(p.relative_to(old) for p in old.rglob("*")) == before  # the earlier output is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old"]  # no temporary folders left


def test_the_guard_keeps_the_keypoint_fit_when_the_silhouette_fit_is_less_plausible(open_model, subject, monkeypatch):
    """Issue 23's plausibility guard, wired in refine_batch: a refined fit the guard finds less
    plausible is replaced by the keypoint fit, with the guard's warning in the metrics."""
    import silfit.fitting.plausibility as pipeline
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.fitting.plausibility import GuardDecision

    calls = []

    def implausible(before, after, where=""):
        calls.append((before, after))
        return GuardDecision(
            "keypoints", ("stature 2.40 m",), (f"{where}: made the fit less plausible: kept the keypoint fit",)
        )

    monkeypatch.setattr(pipeline, "silhouette_guard", implausible)
    cfg = SilhouetteFitConfig(resolutions=(64,), iterations=(4,), contour_iterations=2)
    result = fit(
        subject.keypoints, subject.mask, subject.camera, model=open_model, silhouette_config=cfg, progress=False
    )
    m = result.metrics
    assert calls and {"reprojection_px", "max_abs_beta", "stature_m"} <= set(calls[0][0])
    assert m["silhouette_guard"] == {"kept": "keypoints", "less_plausible": ["stature 2.40 m"]}
    assert any("kept the keypoint fit" in w for w in m["warnings"])
    for k in ("betas", "body_pose", "transl"):
        assert np.allclose(np.asarray(result.params[k]).reshape(-1), result.keypoint.params(0)[k].reshape(-1))
    assert m["iou"] == m["iou_keypoint_stage"]
    off = fit(
        subject.keypoints,
        subject.mask,
        subject.camera,
        model=open_model,
        progress=False,
        silhouette_config=SilhouetteFitConfig(
            resolutions=(64,), iterations=(4,), contour_iterations=2, plausibility_guard=False
        ),
    )
    assert off.metrics["silhouette_guard"]["kept"] == "silhouette"
    assert not np.allclose(off.params["body_pose"], result.params["body_pose"])


def _known_seen_by_the_stage(monkeypatch, field: str = "known") -> list:
    """The ``field`` (``known``, ``cover_inner``) of every observation the silhouette stage is given, in order (a spy
    on it)."""
    import silfit.fitting.silhouette_stage as stage

    seen = []
    real = stage.fit_silhouette_problems

    def spy(model, problems, *args, **kwargs):
        seen.extend(getattr(o, field) for p in problems for o in p.observations)
        return real(model, problems, *args, **kwargs)

    monkeypatch.setattr(stage, "fit_silhouette_problems", spy)
    return seen


def test_a_leak_far_from_the_body_is_set_aside_with_a_note(open_model, subject, monkeypatch):
    """Issue 23: mask pixels far from the keypoint fit's body (a leak) reach the silhouette stage as
    unknown (``Observation.known``), with a note in the warnings; a mask without one passes none."""
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig

    seen = _known_seen_by_the_stage(monkeypatch)
    cfg = SilhouetteFitConfig(resolutions=(64,), iterations=(2,), contour_iterations=1)
    mask = subject.mask.copy()
    ys, xs = np.nonzero(mask)
    h = int(np.ptp(ys))
    y = int(ys.mean())
    mask[y - h // 10 : y + h // 10, xs.max() - 2 : xs.max() + h // 3] = True  # a block joined at the side
    leaky = fit(subject.keypoints, mask, subject.camera, model=open_model, silhouette_config=cfg, progress=False)
    far = min(mask.shape[1] - 1, xs.max() + h // 3 - 2)
    assert mask[y, far] and seen[-1] is not None and not seen[-1][y, far] and seen[-1][ys[0], xs[0]]
    assert any("far from the keypoint fit's body" in w for w in leaky.metrics["warnings"])
    off = SilhouetteFitConfig(
        resolutions=(64,),
        iterations=(2,),
        contour_iterations=1,
        mask=MaskHandling(leak_distance=0.0, hole_fraction=0.0),
    )
    fit(subject.keypoints, mask, subject.camera, model=open_model, silhouette_config=off, progress=False)
    assert seen[-1] is None


def test_a_mask_left_whole_by_the_trim_is_fitted_at_full_slope_near_its_edge(open_model, subject, monkeypatch):
    """``MaskHandling.untrimmed_inner`` (issue 55, the demo's IoU): a mask the clothing trim leaves whole and the
    keypoint fit's body matches (IoU at least ``whole_iou``: the clean render's) reaches the stage with its own
    ``cover_inner`` (``Observation.cover_inner``), a mask trimmed as clothing (grown all around) with none (the
    config's ``cover_inner``); ``None``, the trim off or a lower IoU: none."""
    import cv2
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig

    seen = _known_seen_by_the_stage(monkeypatch, "cover_inner")
    quick = dict(resolutions=(64,), iterations=(2,), contour_iterations=1, alternatives_margin=0.0)
    run = lambda person, **c: fit(  # noqa: E731
        subject.keypoints,
        person,
        subject.camera,
        model=open_model,
        silhouette_config=SilhouetteFitConfig(**quick, **c),
        progress=False,
    )
    run(subject.mask)
    assert seen[-1] == 1.0 != SilhouetteFitConfig().mask.cover_inner
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (13, 13))
    run(cv2.dilate(subject.mask.astype(np.uint8), disc).astype(bool))  # 6 px of clothing all around: trimmed
    assert seen[-1] is None
    run(subject.mask, mask=MaskHandling(untrimmed_inner=None))
    assert seen[-1] is None
    run(subject.mask, mask=MaskHandling(trim_clothing=False))  # the trim off: no mask judged whole
    assert seen[-1] is None
    run(subject.mask, mask=MaskHandling(whole_iou=0.99))  # the keypoint fit's body matches it less (IoU 0.92)
    assert seen[-1] is None


def test_concavities_are_unknown_only_in_a_mask_trimmed_as_clothing():
    """``SilhouetteFitConfig.concave_radius``: the keypoint fit's concavities are unknown in a mask
    trimmed as clothing (pure: no fitting)."""
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.fitting.image_fit import _known_pixels

    body = np.zeros((100, 100), bool)
    body[10:90, 30:50] = True  # torso and an arm 5 px beside it
    body[15:85, 55:62] = True
    mask = body.copy()
    mask[15:85, 50:55] = True  # clothing fills the gap
    cfg = SilhouetteFitConfig(mask=MaskHandling(leak_distance=0.0, hole_fraction=0.0))
    notes = [[], []]
    trimmed, untouched = _known_pixels([mask, mask], [body, body], cfg, ["a", "b"], notes, [True, False])
    assert trimmed is not None and not trimmed[20:80, 50:55].any() and trimmed[body].all()
    assert untouched is None and notes == [[], []]
    off = SilhouetteFitConfig(mask=MaskHandling(leak_distance=0.0, hole_fraction=0.0, concave_radius=0.0))
    assert _known_pixels([mask], [body], off, ["a"], [[]], [True]) == [None]


def test_an_even_layer_of_clothing_is_trimmed_by_the_outline_distances_median():
    """``mask.trim_upper``: the keypoint fit's body misplaced sideways puts the outline distances' quartile below the
    clothing's true thickness (24 px all around here). Misplaced by 2 px (quartile 22, median 24: within
    ``trim_upper_max`` of the mask's extent, 287 px, an even layer) the trim goes to the median; by 8 px (quartile
    16) the spread is taken for uneven clothing and the trim stays at the quartile (pure: no fitting)."""
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.fitting.image_fit import _trimmed_masks
    from silfit.silhouette import clothing_thickness, trim_clothing

    truth = np.zeros((400, 400), bool)
    truth[80:320, 160:240] = True
    mask = np.zeros_like(truth)
    mask[56:344, 136:264] = True  # 24 px of clothing all around

    def trimmed(body, **changes):
        cfg = SilhouetteFitConfig(mask=MaskHandling(**{"trim_max": 0.1, **changes}))  # 24 px within the cap
        (out,), _, (was,) = _trimmed_masks([mask], [body], cfg, ["a"])
        assert was
        return out

    near, far = np.roll(truth, 2, axis=1), np.roll(truth, 8, axis=1)
    (q_near, m_near), (q_far, m_far) = ([clothing_thickness(mask, b, q) for q in (0.25, 0.5)] for b in (near, far))
    assert (q_near, m_near, q_far, m_far) == pytest.approx((22, 24, 16, 24), abs=1.0)
    assert np.array_equal(trimmed(near), trim_clothing(mask, m_near))
    assert not np.array_equal(trimmed(near), trim_clothing(mask, q_near))
    assert np.array_equal(trimmed(near, trim_upper=None), trim_clothing(mask, q_near))
    assert np.array_equal(trimmed(far), trim_clothing(mask, q_far))
    assert np.array_equal(trimmed(far, trim_upper_max=0.05), trim_clothing(mask, m_far))
    for bad in ({"trim_upper": 1.5}, {"trim_upper_max": -0.1}, {"trim_upper": float("nan")}):
        with pytest.raises(ValueError, match="mask.trim_upper"):
            SilhouetteFitConfig(mask=MaskHandling(**bad))


def test_the_clothing_trim_leaves_something_known_to_fit():
    """A mask grown all around is trimmed (``trim_quantile``: the outline distances' quantile taken as its thickness),
    unless the trimmed mask keeps none of the pixels the caller trusts (``known``): then it is fitted untrimmed (the
    stage needs something to fit; pure: no fitting)."""
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.fitting.image_fit import _trimmed_masks

    body = np.zeros((100, 100), bool)
    body[20:80, 40:60] = True
    mask = np.zeros_like(body)
    mask[14:86, 34:66] = True  # 6 px of clothing all around
    cfg = SilhouetteFitConfig()
    (out,), (note,), (trimmed,) = _trimmed_masks([mask], [body], cfg, ["a"])
    assert trimmed and out.sum() < mask.sum() and note
    rim = mask & ~out  # only the trimmed rim is known: nothing left to fit
    (out,), (note,), (trimmed,) = _trimmed_masks([mask], [body], cfg, ["a"], [rim])
    assert not trimmed and np.array_equal(out, mask) and note == []
    with pytest.raises(ValueError, match="trim_quantile"):
        SilhouetteFitConfig(mask=MaskHandling(trim_quantile=1.5))
    with pytest.raises(ValueError, match="trust.free_ratio must be above 0"):
        SilhouetteFitConfig(trust=TrustRegion(free_ratio=0.0))


def test_the_hypothesis_that_refines_lowest_against_the_mask_is_kept(open_model, tmp_path):
    """``--hypotheses K`` with a mask (issue 25): every hypothesis goes through the silhouette stage and the
    lowest final energy is kept; metrics.json records each one's energy and which was kept (shipped subject 4:
    two distinct hypotheses, a few per cent apart by the keypoint stage's energy)."""
    from silfit.io.fit import read_fit
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit import save_fit

    subject = load_subject(SHIPPED / "subject_004")
    result = fit(
        subject.keypoints,
        subject.mask,
        subject.camera,
        model=open_model,
        progress=False,
        keypoint_config=KeypointFitConfig(solutions=Solutions(count=2)),
        silhouette_config=SilhouetteFitConfig(resolutions=(64,), iterations=(4,)),
    )
    hyps, record = result.keypoint.hypotheses[0], result.metrics["hypotheses_silhouette"]
    assert len(hyps) == 2 and len(record["energies"]) == len(record["iou"]) == 2
    assert record["kept"] == 1 + int(np.argmin(record["energies"]))  # (unless the guard turned it back)
    assert record["gap"] == pytest.approx((record["energies"][0] - min(record["energies"])) / record["energies"][0])
    moved = [w for w in result.metrics["warnings"] if w.startswith("depth branch chosen by the mask")]
    assert len(moved) == (record["kept"] != 1)
    # each hypothesis as a fit: refined against the mask, its keypoint-stage start kept beside it (hypotheses/<k>/)
    assert [h["rank"] for h in result.hypotheses] == [1, 2]
    for h, hyp, energy in zip(result.hypotheses, hyps, record["energies"]):
        assert h["record"]["params_from"] == "silhouette stage" and h["record"]["silhouette_energy"] == energy
        assert h["record"]["kept"] == (h["rank"] == record["kept"])
        assert all(np.array_equal(h["keypoint_params"][k], np.asarray(v)) for k, v in hyp["params"].items())
        assert not np.allclose(h["params"]["body_pose"], h["keypoint_params"]["body_pose"])  # the stage moved it
    kept = result.hypotheses[record["kept"] - 1]
    assert np.allclose(kept["vertices"], result.vertices) and np.allclose(
        kept["params"]["body_pose"], result.params["body_pose"]
    )
    out = save_fit(result, tmp_path / "fit", open_model.faces.numpy(), subject.keypoints, mask=subject.mask)
    for k in (1, 2):
        assert read_fit(out / "hypotheses" / str(k)).frame(0)["body_pose"] == pytest.approx(
            result.hypotheses[k - 1]["params"]["body_pose"].reshape(-1), abs=1e-6
        )
        assert (out / "hypotheses" / str(k) / "stages" / "keypoints" / "params.npz").is_file()
    assert (out / "hypotheses.png").is_file()


def test_choosing_a_hypothesis_by_the_silhouette_stage():
    """The lowest final energy of the stage's last level wins, a tie goes to the keypoint fit, a NaN energy
    never wins, and an alternative the plausibility guard would turn back (here: 0.5 m off its keypoints)
    gives way to the keypoint fit."""
    import sys

    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from silfit_toy_body import toy_model

    from silfit.camera import Camera, project_points
    from silfit.fitting.silhouette_stage import SilhouetteFitResult
    from silfit.fitting.image_fit import _choose_hypothesis
    from silfit.io.keypoints import KeypointSet, model_keypoints

    toy_body = toy_model()
    cam = Camera.from_image_size(320, 240)
    start = {
        "betas": np.zeros(10, np.float32),
        "body_pose": np.zeros(69, np.float32),
        "global_orient": np.array([np.pi, 0, 0], np.float32),
        "transl": np.array([0, 0.2, 3], np.float32),
    }
    out = toy_body(**{k: torch.as_tensor(v)[None] for k, v in start.items()})
    xy = project_points(model_keypoints(toy_body, out, "body25"), cam)[0].numpy()
    kps = KeypointSet(xy, np.ones(25), "body25")

    def refined(last, transl_x=0.0, first=5.0, levels=(0, 0, 1, 1), failed=False):
        params = {k: v[None].copy() for k, v in start.items()}
        params["transl"][0, 0] += transl_x
        return SilhouetteFitResult(
            params, {"level": list(levels), "energy": [first, 4.0, 3.0, last]}, 0.8, 0.9, 0.0, 4, [], failed=failed
        )

    def choose(*sils, starts=None):
        return _choose_hypothesis(toy_body, list(sils), starts or [start] * len(sils), kps, cam, "mask")

    assert choose(refined(2.0)) == (0, {})
    c, record = choose(refined(2.0), refined(1.5), refined(1.8))
    assert c == 1 and record["kept"] == 2 and record["energies"] == [2.0, 1.5, 1.8] and record["guard_reverted"] is None
    assert record["gap"] == pytest.approx(0.25)
    assert choose(refined(2.0), refined(2.0, first=0.1))[0] == 0  # a tie: the keypoint fit
    assert choose(refined(2.0), refined(float("nan")))[0] == 0
    # stopped early (a failure, or its last level not the others'): its energy is not compared
    c, record = choose(refined(2.0), refined(1.0, failed=True), refined(1.0, levels=(0, 0, 0, 0)))
    assert c == 0 and record["energies"] == [2.0, None, None]
    # the guard: less plausible than its own start, or than the keypoint fit (0.5 m off the keypoints from either)
    c, record = choose(refined(2.0), refined(1.0, transl_x=0.5))
    assert c == 0 and record["guard_reverted"] == 2
    moved = {**start, "transl": start["transl"] + np.array([0.5, 0, 0], np.float32)}
    assert choose(refined(2.0), refined(1.0, transl_x=0.5), starts=[start, moved]) == (
        0,
        {"energies": [2.0, 1.0], "iou": [0.9, 0.9], "kept": 1, "gap": 0.0, "guard_reverted": 2, "margin_held": None},
    )

    # the margin (SilhouetteFitConfig.choice_margin): an alternative 2 % below the keypoint fit keeps the fit's branch,
    # one 25 % below replaces it; at 0 the lowest energy wins
    def margin(m, *sils):
        return _choose_hypothesis(toy_body, list(sils), [start] * len(sils), kps, cam, "mask", True, m)

    c, record = margin(0.04, refined(2.0), refined(1.96))
    assert c == 0 and record["kept"] == 1 and record["margin_held"] == 2 and record["gap"] == 0.0
    assert margin(0.0, refined(2.0), refined(1.96))[0] == 1
    c, record = margin(0.04, refined(2.0), refined(1.96), refined(1.5))
    assert c == 2 and record["margin_held"] is None and record["gap"] == pytest.approx(0.25)
    # a keypoint fit whose energy does not compare (it failed) holds nothing back
    assert margin(0.04, refined(2.0, failed=True), refined(1.96))[0] == 1


def test_refine_batch_keeps_each_images_own_lowest_hypothesis(monkeypatch):
    """Two images with 2 and 3 hypotheses in one batch: each image keeps its own candidate of lowest final energy
    (the stage stubbed to return its starts with set energies), with its record and warning."""
    import sys

    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from silfit_toy_body import toy_model

    import silfit.fitting.silhouette_stage as stage
    from silfit.camera import Camera, project_points
    from silfit.fitting import KeypointFitter
    from silfit.fitting.image_fit import body_mask, refine_batch
    from silfit.io.keypoints import KeypointSet, model_keypoints

    model = toy_model()
    cam = Camera.from_image_size(320, 240)
    sets = []
    for x in (0.0, 0.1):
        out = model(global_orient=torch.tensor([[np.pi, 0, 0]]), transl=torch.tensor([[x, 0.2, 3.0]]))
        sets.append(
            KeypointSet(project_points(model_keypoints(model, out, "body25"), cam)[0].numpy(), np.ones(25), "body25")
        )
    cfg = FEW_STEPS
    kp = KeypointFitter(model, config=cfg).fit(sets, [cam, cam], progress=False)

    def marked(i, k):  # sample i's fit with body_pose[0] = 0.01 k: which candidate a result came from
        p = {n: np.array(v, dtype=np.float32) for n, v in kp.params(i).items()}
        p["body_pose"][0] = 0.01 * k
        return {"params": p, "energy": 1.0, "refined": True, "label": f"branch {k}", "differs": []}

    kp.hypotheses = [[marked(0, 0), marked(0, 1)], [marked(1, 0), marked(1, 1), marked(1, 2)]]
    finals = [2.0, 2.0, 1.0, 1.5, 1.2]  # problems: image 0, image 1, then 0's alternative, 1's two

    def stub(model, problems, inits, *args, **kwargs):
        assert len(problems) == len(inits) == len(finals)
        return [
            stage.SilhouetteFitResult(
                {n: np.asarray(v, np.float32).reshape(1, -1) for n, v in init.items()},
                {"level": [1, 1], "energy": [3.0, e]},
                0.8,
                0.9,
                1.0,
                2,
                [],
            )
            for init, e in zip(inits, finals)
        ]

    monkeypatch.setattr(stage, "fit_silhouette_problems", stub)
    faces = model.faces.cpu().numpy()
    masks = [body_mask(kp.vertices[i], faces, cam) for i in range(2)]
    res = refine_batch(model, kp, sets, masks, progress=False)
    assert [r.metrics["hypotheses_silhouette"]["kept"] for r in res] == [2, 3]
    assert res[0].params["body_pose"].reshape(-1)[0] == pytest.approx(0.01)
    assert res[1].params["body_pose"].reshape(-1)[0] == pytest.approx(0.02)
    assert res[1].metrics["hypotheses_silhouette"]["energies"] == [2.0, 1.5, 1.2]
    assert res[0].metrics["timings_s"]["silhouette"] == 2.0 and res[1].metrics["timings_s"]["silhouette"] == 3.0
    for r, k in zip(res, (2, 3)):
        assert any(w.startswith(f"depth branch chosen by the mask: hypothesis {k} ") for w in r.metrics["warnings"])
    # each image's own hypotheses as fits (hypotheses/<k>/), the kept one marked, with its stage energy
    assert [[h["record"]["kept"] for h in r.hypotheses] for r in res] == [[False, True], [False, False, True]]
    assert [[h["record"]["silhouette_energy"] for h in r.hypotheses] for r in res] == [[2.0, 1.0], [2.0, 1.5, 1.2]]
    assert [h["params"]["body_pose"].reshape(-1)[0] for h in res[1].hypotheses[1:]] == pytest.approx([0.01, 0.02])

    # without --hypotheses: the branches refined to the end within alternatives_margin of the fit's energy
    # (KeypointFitResult.alternatives; image 1's is 50 % above its fit: not refined)
    kp.hypotheses = None
    kp.alternatives = [
        [{**marked(0, 1), "label": "left_shin", "differs": ["left_shin"], "gap": 0.05}],
        [{**marked(1, 1), "label": "left_thigh", "differs": ["left_thigh"], "gap": 0.5}],
    ]
    finals[:] = [2.0, 2.0, 1.0]  # image 0, image 1, then 0's alternative
    res = refine_batch(model, kp, sets, masks, progress=False)
    assert res[0].metrics["hypotheses_silhouette"]["kept"] == 2 and "hypotheses_silhouette" not in res[1].metrics
    assert res[0].hypotheses == res[1].hypotheses == []  # the close alternatives are not hypotheses/<k>/
    assert res[0].params["body_pose"].reshape(-1)[0] == pytest.approx(0.01)
    assert any(
        w.startswith(
            "depth branch chosen by the mask: the keypoint stage's alternative turning left_shin "
            "(keypoint-stage energy +5.0% against its fit)"
        )
        for w in res[0].metrics["warnings"]
    )
    assert res[0].metrics["hypotheses_silhouette"]["alternatives"] == [
        {"label": "left_shin", "differs": ["left_shin"], "gap": 0.05, "max_shift_mm": None}
    ]
    assert not any("chosen by the mask" in w for w in res[1].metrics["warnings"])

    # the alternative only 2 % lower: the config's choice_margin (0.04) keeps the keypoint fit's branch; at 0 it wins
    finals[:] = [2.0, 2.0, 1.96]
    res = refine_batch(model, kp, sets, masks, progress=False)
    record = res[0].metrics["hypotheses_silhouette"]
    assert record["kept"] == 1 and record["margin_held"] == 2
    assert res[0].params["body_pose"].reshape(-1)[0] == pytest.approx(
        np.asarray(kp.params(0)["body_pose"]).reshape(-1)[0]
    )
    assert not any("chosen by the mask" in w for w in res[0].metrics["warnings"])
    res = refine_batch(model, kp, sets, masks, stage.SilhouetteFitConfig(choice_margin=0), progress=False)
    assert res[0].metrics["hypotheses_silhouette"]["kept"] == 2


def test_the_kept_hypothesis_holds_the_final_fit_whatever_the_guard_did(monkeypatch):
    """``--hypotheses K`` with a mask: ``hypotheses/<kept>/`` holds the final fit, also where the plausibility guard
    turned it back to the keypoint fit (it is still marked kept) and where the guard is off (``plausibility_guard``
    false: the refined one, not its keypoint fit). The stage stubbed to move every fit 0.5 m off the keypoints."""
    import sys

    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from silfit_toy_body import toy_model

    import silfit.fitting.silhouette_stage as stage
    from silfit.camera import Camera, project_points
    from silfit.fitting import KeypointFitter
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.fitting.image_fit import body_mask, refine_batch
    from silfit.io.keypoints import KeypointSet, model_keypoints

    model = toy_model()
    cam = Camera.from_image_size(320, 240)
    out = model(global_orient=torch.tensor([[np.pi, 0, 0]]), transl=torch.tensor([[0.0, 0.2, 3.0]]))
    sets = [KeypointSet(project_points(model_keypoints(model, out, "body25"), cam)[0].numpy(), np.ones(25), "body25")]
    cfg = FEW_STEPS
    kp = KeypointFitter(model, config=cfg).fit(sets, [cam], progress=False)
    other = {n: np.array(v, dtype=np.float32) for n, v in kp.params(0).items()}
    other["body_pose"][0] += 0.01
    kp.hypotheses = [
        [
            {"params": kp.params(0), "energy": 1.0, "refined": True, "label": "keep", "differs": []},
            {"params": other, "energy": 1.1, "refined": True, "label": "left_shin", "differs": []},
        ]
    ]

    def stub(model, problems, inits, *args, **kwargs):  # the keypoint fit refines lowest; every one far off
        moved = [{n: np.asarray(v, np.float32).reshape(1, -1) for n, v in init.items()} for init in inits]
        for p in moved:
            p["transl"] = p["transl"] + np.array([[0.5, 0, 0]], np.float32)
        return [
            stage.SilhouetteFitResult(p, {"level": [1, 1], "energy": [3.0, e]}, 0.8, 0.9, 1.0, 2, [])
            for p, e in zip(moved, (1.0, 2.0))
        ]

    monkeypatch.setattr(stage, "fit_silhouette_problems", stub)
    masks = [body_mask(kp.vertices[0], model.faces.cpu().numpy(), cam)]
    reverted = "keypoint stage (the silhouette stage's was less plausible)"
    for guarded, source in ((True, reverted), (False, "silhouette stage")):
        (res,) = refine_batch(model, kp, sets, masks, SilhouetteFitConfig(plausibility_guard=guarded), progress=False)
        assert res.metrics["silhouette_guard"]["kept"] == ("keypoints" if guarded else "silhouette")
        assert [h["record"]["kept"] for h in res.hypotheses] == [True, False]
        assert [h["record"]["params_from"] for h in res.hypotheses] == [source] * 2
        # a refinement set aside: its energy and IoU kept apart (hypotheses.png's title shows no IoU for it)
        assert [("silhouette_iou" in h["record"], "silhouette_discarded" in h["record"]) for h in res.hypotheses] == [
            (not guarded, guarded)
        ] * 2
        kept = res.hypotheses[0]
        assert np.array_equal(kept["vertices"], res.vertices)
        assert all(
            np.array_equal(np.asarray(kept["params"][n]).reshape(-1), np.asarray(v).reshape(-1))
            for n, v in res.params.items()
        )


def test_offered_alternatives():
    """Which of the keypoint stage's branches the silhouette stage refines too: ``--hypotheses K``'s after the fit;
    else the alternatives within ``alternatives_margin``, closest first, at most ``alternatives_max``; none at 0."""
    from types import SimpleNamespace

    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.fitting.image_fit import _offered_alternatives

    alts = [{"label": str(g), "gap": g} for g in (0.3, 0.05, 0.02, 0.08, 0.1)]

    class Kp(SimpleNamespace):
        def __len__(self):
            return 1

    def offered(config=SilhouetteFitConfig(), **kw):
        kp = Kp(**{"hypotheses": None, "alternatives": None, **kw})
        return [[a["label"] for a in one] for one in _offered_alternatives(kp, config)]

    assert offered(alternatives=[alts]) == [["0.02", "0.05"]]
    assert offered(SilhouetteFitConfig(alternatives_max=4), alternatives=[alts]) == [["0.02", "0.05", "0.08", "0.1"]]
    assert offered(SilhouetteFitConfig(alternatives_margin=0.0), alternatives=[alts]) == [[]]
    assert offered() == [[]]  # no branch refined (no search)
    hyps = [{"label": "fit"}, {"label": "a"}, {"label": "b"}]
    assert offered(hypotheses=[hyps], alternatives=[alts]) == [["a", "b"]]  # --hypotheses K: all of them


def test_a_jobs_unknown_pixels_reach_the_silhouette_stage(open_model, subject, monkeypatch):
    """Issue 55: a job's ``known`` map (``silfit fit --image``: the mask's pixels of other people) reaches the
    silhouette stage through silfit.run's one-image path: those pixels are unknown there."""
    import dataclasses

    from silfit.fitting.problem import Problem
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.run import image_job, run

    seen = _known_seen_by_the_stage(monkeypatch)
    cfg = SilhouetteFitConfig(resolutions=(64,), iterations=(2,), contour_iterations=1)
    job = image_job(subject.keypoints, subject.mask, subject.camera, model=open_model, silhouette_config=cfg)
    known = np.ones_like(subject.mask, dtype=bool)
    ys, xs = np.nonzero(subject.mask)
    known[ys.min() : ys.min() + 10, :] = False  # the top of the mask: another person's, say
    obs = job.problem.observations[0]
    run(dataclasses.replace(job, problem=Problem.single(obs.keypoints, obs.view.camera, obs.mask, known)))
    assert seen and seen[0] is not None and not seen[0][ys.min() + 2, xs[0]] and seen[0][ys.max(), xs[-1]]
