"""The silhouette stage on the open body model with the real Mitsuba renderer."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from silfit.render.offscreen import render_mask
from silfit.camera import Camera, project_points
from silfit.fitting.silhouette_stage import (
    SilhouetteFitConfig,
    choose_window,
    fit_silhouette,
    fit_silhouettes,
    window_target,
)
from silfit.eval.metrics import mask_iou

CAMERA = Camera.from_image_size(160, 160)
POSE = {
    "betas": np.zeros((1, 10), np.float32),
    "body_pose": np.zeros((1, 69), np.float32),
    "global_orient": np.array([[math.pi, 0.0, 0.0]], np.float32),
    "transl": np.array([[0.0, 0.15, 3.0]], np.float32),
}
# the rendered level alone (no contour level), as the bounds below were measured
FAST = SilhouetteFitConfig(
    resolutions=(64,),
    iterations=(30,),
    optimise=("transl",),
    w_keypoints=0.0,
    warmup=2,
    plateau_window=100,
    lr={"betas": 0.0, "body_pose": 0.0, "global_orient": 0.0, "transl": 0.01},
    contour_iterations=0,
    window_multiple=1,
)


def vertices(model, params):
    t = {k: torch.as_tensor(v) for k, v in params.items()}
    with torch.no_grad():
        return model(**t).vertices[0].numpy()


@pytest.fixture(scope="module")
def target_mask(open_model):
    shifted = dict(POSE, transl=POSE["transl"] + np.array([[0.08, 0.0, 0.0]], np.float32))
    return render_mask(vertices(open_model, shifted), open_model.faces.numpy(), CAMERA)


def test_window_target_matches_the_mask_at_scale_one():
    mask = np.zeros((40, 60), bool)
    mask[10:30, 20:35] = True
    from silfit.render.silhouette import RoiWindow

    window = RoiWindow(0.0, 0.0, 1.0, Camera(fx=50, fy=50, cx=29.5, cy=19.5, width=60, height=40))
    target, coverage = window_target(mask, window)
    assert np.array_equal(target.mask.numpy() > 0.5, mask)
    assert np.allclose(coverage, mask, atol=1e-6)


def test_window_covers_mask_and_body(open_model, target_mask):
    uv = project_points(torch.as_tensor(vertices(open_model, POSE)), CAMERA).numpy()
    window = choose_window(target_mask, uv, CAMERA, 64, margin=0.1)
    assert max(window.camera.width, window.camera.height) == 64
    # Every mask pixel and every projected vertex falls inside the window.
    ys, xs = np.nonzero(target_mask)
    for u, v in np.concatenate([np.stack([xs, ys], 1), uv]):
        wu, wv = (u + 0.5 - window.x0) * window.scale, (v + 0.5 - window.y0) * window.scale
        assert 0 <= wu <= window.camera.width and 0 <= wv <= window.camera.height


def test_window_sides_come_in_multiples():
    mask = np.zeros((160, 160), bool)
    mask[20:140, 60:99] = True  # a standing person's box: 39 x 120 pixels
    uv = np.array([[62.0, 25.0], [95.0, 135.0]])
    plain = choose_window(mask, uv, CAMERA, 96, margin=0.1)
    window = choose_window(mask, uv, CAMERA, 96, margin=0.1, multiple=16)
    cam = window.camera
    assert (plain.camera.width, plain.camera.height) == (31, 96)
    assert (cam.width, cam.height) == (32, 96) and window.scale == plain.scale  # only more margin
    ys, xs = np.nonzero(mask)
    for u, v in np.stack([xs, ys], 1):
        wu, wv = (u + 0.5 - window.x0) * window.scale, (v + 0.5 - window.y0) * window.scale
        assert 0 <= wu <= cam.width and 0 <= wv <= cam.height


@pytest.mark.parametrize("robust", [False, True])
def test_gradient_moves_a_shifted_body_toward_a_shifted_mask(open_model, target_mask, robust):
    iou_before = mask_iou(render_mask(vertices(open_model, POSE), open_model.faces.numpy(), CAMERA), target_mask)
    # edge points per window pixel (edge_density=None) and 4 rays per edge pixel, the sampling the bounds were
    # measured with: this 64 px, 30-step fit ends in one of two places by the seed's noise alone (IoU 0.94 or 0.90
    # with the plain cover term: seed 0 at 4 and at 16 edge points per contour pixel alike, seed 1 at 0.94), so the
    # bounds hold one sampling (with the default 2 rays the robust cover term ends at 0.933, dz 0.075)
    cfg = replace(
        FAST, mask=replace(FAST.mask, robust_cover=robust), render=replace(FAST.render, edge_density=None, spp=4)
    )
    result = fit_silhouette(open_model, POSE, CAMERA, target_mask, config=cfg, progress=False)
    dx, dy, dz = result.transl[0] - POSE["transl"][0]
    # The truth is (+0.08, 0, 0) m. Measured (deterministic renderer): 0.0846, -0.0026, +0.053 m.
    # The depth drifts because at this window's scale (0.54 px per image px) the energy's own
    # minimum lies beyond +0.06 m in depth (see the closing note of issue 18); the bound
    # is 1.5x the measured drift, so a larger bias or a stage that stops moving fails.
    assert 0.075 < dx < 0.095, dx
    assert abs(dy) < 0.006, dy
    assert -0.01 < dz < 0.08, dz
    iou_after = mask_iou(
        render_mask(vertices(open_model, result.params()), open_model.faces.numpy(), CAMERA), target_mask
    )
    # measured 0.443 -> 0.943 with the plain cover term; the robust one (issue 23: masks are supersets of
    # bodies, an uncovered mask pixel near its edge pulls at a quarter) stops short: 0.902
    assert iou_before < 0.45 and iou_after > (0.88 if robust else 0.92), (iou_before, iou_after)
    assert len(result.history["iou"]) == result.steps and result.iou_end > result.iou_start


def test_divergence_keeps_the_best_parameters(open_model, target_mask):
    wild = replace(
        FAST,
        iterations=(8,),
        lr={"betas": 0.0, "body_pose": 0.0, "global_orient": 0.0, "transl": 5.0},
        iou_collapse=0.05,
        warmup=1,
    )
    result = fit_silhouette(open_model, POSE, CAMERA, target_mask, config=wild, progress=False)
    assert result.warnings and "IoU collapsed" in result.warnings[0]
    assert np.all(np.isfinite(result.transl)) and abs(result.transl[0, 0] - POSE["transl"][0, 0]) < 1.0


def test_plateau_stops_a_level_early(open_model, target_mask):
    # an improvement threshold no step can meet: the level stops after 2 x window steps
    cfg = replace(FAST, plateau_window=3, plateau_rtol=10.0)
    result = fit_silhouette(open_model, POSE, CAMERA, target_mask, config=cfg, progress=False)
    assert result.steps == 6 and len(result.history["energy"]) == 6


def test_keypoint_term_is_off_without_keypoints(open_model, target_mask):
    cfg = replace(FAST, iterations=(2,), w_keypoints=0.02)
    kp = np.concatenate(
        [project_points(torch.as_tensor(vertices(open_model, POSE))[:25], CAMERA).numpy(), np.ones((25, 1))], 1
    )
    with_kp = fit_silhouette(open_model, POSE, CAMERA, target_mask, keypoints=kp, config=cfg, progress=False)
    without = fit_silhouette(open_model, POSE, CAMERA, target_mask, keypoints=None, config=cfg, progress=False)
    assert "keypoints" in with_kp.terms and with_kp.terms["keypoints"] > 0
    assert "keypoints" not in without.terms and set(without.history["keypoints"]) == {0.0}


def test_non_finite_energy_stops_and_keeps_the_start(open_model, target_mask):
    def nan_renderer(verts, camera, **kwargs):  # a renderer whose output is NaN (e.g. a degenerate mesh)
        return torch.full((camera.height, camera.width), float("nan")) + 0.0 * verts.sum()

    result = fit_silhouette(open_model, POSE, CAMERA, target_mask, config=FAST, renderer=nan_renderer, progress=False)
    assert result.warnings == ["step 0: non-finite energy; kept the best parameters so far"]
    assert result.steps == 0
    for name, value in POSE.items():
        np.testing.assert_array_equal(getattr(result, name), value)


# ----------------------------------------------------------------------------- batches
SHIFTS = (np.array([0.08, 0.0, 0.0]), np.array([0.0, -0.06, 0.0]), np.array([-0.05, 0.03, 0.0]))


def mask_of(model, shift):
    shifted = dict(POSE, transl=POSE["transl"] + np.asarray(shift, np.float32)[None])
    return render_mask(vertices(model, shifted), model.faces.numpy(), CAMERA)


def test_a_batch_moves_each_subject_toward_its_own_mask(open_model):
    masks = [mask_of(open_model, s) for s in SHIFTS]
    results = fit_silhouettes(open_model, [POSE] * 3, [CAMERA] * 3, masks, config=FAST, progress=False)
    for shift, mask, r in zip(SHIFTS, masks, results):
        moved = r.transl[0] - POSE["transl"][0]
        # x and y land within 2 cm of the truth; a subject pulled toward another's mask would miss by 5+ cm
        assert np.abs(moved[:2] - shift[:2]).max() < 0.02, (shift, moved)
        assert r.iou_end > r.iou_start + 0.1 and len(r.history["iou"]) == r.steps
        # and where it lands is where it lands alone, to the bit (same inputs, same fit: the body's
        # contractions are batch-invariant, each subject has its own seeded renders and Adam)
        alone = fit_silhouette(open_model, POSE, CAMERA, mask, config=FAST, progress=False)
        for name in ("betas", "body_pose", "global_orient", "transl"):
            np.testing.assert_array_equal(getattr(alone, name), getattr(r, name), err_msg=name)
        assert alone.steps == r.steps


def test_batch_of_one_equals_the_single_subject_call(open_model):
    mask = mask_of(open_model, SHIFTS[0])
    single = fit_silhouette(open_model, POSE, CAMERA, mask, config=FAST, progress=False)
    batch = fit_silhouettes(open_model, [POSE], [CAMERA], [mask], config=FAST, progress=False)[0]
    np.testing.assert_array_equal(single.transl, batch.transl)
    assert single.steps == batch.steps


# ----------------------------------------------------------------------------- problems: views and frames
from silfit.fitting.problem import Observation, Problem, View  # noqa: E402
from silfit.fitting.silhouette_stage import fit_silhouette_problems  # noqa: E402
from silfit.fitting.terms import Term  # noqa: E402

# A second camera on the body's right, looking along -x of the first camera's (world) frame.
SIDE_R = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
SIDE_T = -SIDE_R @ np.array([3.0, 0.15, 3.0])
TWO_VIEW = replace(FAST, iterations=(40,))


def view_mask(model, params, R=None, t=None):
    v = vertices(model, params)
    if R is not None:
        v = v @ R.T + t
    return render_mask(v, model.faces.numpy(), CAMERA)


def test_two_views_recover_the_depth_one_view_cannot(open_model):
    truth = dict(POSE, transl=POSE["transl"] + np.array([[0.05, 0.0, 0.12]], np.float32))
    front, side = view_mask(open_model, truth), view_mask(open_model, truth, SIDE_R, SIDE_T)
    problem = Problem(
        [Observation(View(CAMERA), None, front, 0, 0), Observation(View(CAMERA, SIDE_R, SIDE_T), None, side, 0, 1)]
    )
    two = fit_silhouette_problems(open_model, [problem], [POSE], config=TWO_VIEW, progress=False)[0]
    one = fit_silhouette(open_model, POSE, CAMERA, front, config=TWO_VIEW, progress=False)
    err_two = np.abs(two.transl[0] - truth["transl"][0])
    err_one = np.abs(one.transl[0] - truth["transl"][0])
    # The side view sees the depth as a lateral shift. Measured: two views 0.6, 0.7, 10 mm off in
    # x, y, z; the front view alone 2.7, 4.2, 27 mm (the front silhouette's scale barely changes
    # over 12 cm at 3 m). Bounds 1.5x the two-view errors, and the one view's depth 2x worse.
    assert err_two.max() < 0.015, (err_two, err_one)
    assert err_one[2] > 2 * err_two[2], (err_two, err_one)
    # soft IoU in each 64-px window (measured 0.86 and 0.84, from 0.37 at the start)
    assert len(two.ious) == 1 and len(two.ious[0]) == 2 and min(two.ious[0]) > 0.8, two.ious


def test_an_observation_without_a_mask_adds_nothing(open_model):
    front = view_mask(open_model, dict(POSE, transl=POSE["transl"] + np.array([[0.08, 0.0, 0.0]], np.float32)))
    problem = Problem(
        [Observation(View(CAMERA), None, front, 0, 0), Observation(View(CAMERA, SIDE_R, SIDE_T), None, None, 0, 1)]
    )
    two = fit_silhouette_problems(open_model, [problem], [POSE], config=FAST, progress=False)[0]
    one = fit_silhouette(open_model, POSE, CAMERA, front, config=FAST, progress=False)
    assert math.isnan(two.ious[0][1]) and two.ious[0][0] > 0.8  # window soft IoU, measured 0.88
    np.testing.assert_allclose(two.transl, one.transl, atol=1e-6)


def test_frames_of_a_problem_share_the_shape_and_move_on_their_own(open_model):
    shifts = (np.array([0.08, 0.0, 0.0]), np.array([0.0, -0.06, 0.0]))
    masks = [mask_of(open_model, s) for s in shifts]
    problem = Problem([Observation(View(CAMERA), None, m, f, 0) for f, m in enumerate(masks)])
    init = {k: (np.repeat(v, 2, 0) if k != "betas" else v[0]) for k, v in POSE.items()}
    r = fit_silhouette_problems(open_model, [problem], [init], config=FAST, progress=False)[0]
    assert r.betas.shape == (1, 10) and r.transl.shape == (2, 3) and r.body_pose.shape == (2, 69)
    for f, shift in enumerate(shifts):
        assert np.abs(r.transl[f, :2] - POSE["transl"][0, :2] - shift[:2]).max() < 0.02, (f, r.transl)
    assert len(r.ious) == 2 and min(i[0] for i in r.ious) > 0.8


class GoalTerm(Term):
    """|transl - goal|^2 per problem (``data['goal'] [P, 3]``): an extra term given by the caller."""

    name = "goal"

    def __call__(self, ev):
        return (ev.params["transl"][:, 0] - ev.data["goal"]).square().sum(-1)


def test_extra_terms_and_their_data_join_the_energy(open_model, target_mask):
    goal = torch.as_tensor(POSE["transl"] + np.array([[0.3, 0.0, 0.0]], np.float32))
    problem = Problem.single(None, CAMERA, target_mask)
    r = fit_silhouette_problems(
        open_model,
        [problem],
        [POSE],
        config=FAST,
        progress=False,
        terms=[GoalTerm()],
        weights={"goal": 100.0},
        data={"goal": goal},
    )[0]
    assert r.terms["goal"] > 0
    # the silhouette alone stops near +0.08 m; a strong pull toward +0.3 m takes the body further
    # (measured +0.106 m against +0.085 m alone; Adam's step size limits how far in 30 steps)
    alone = fit_silhouette_problems(open_model, [problem], [POSE], config=FAST, progress=False)[0]
    assert r.transl[0, 0] > alone.transl[0, 0] + 0.012, (r.transl, alone.transl)
    assert "goal" not in alone.terms
    with pytest.raises(ValueError, match="unknown energy term"):
        fit_silhouette_problems(open_model, [problem], [POSE], config=FAST, progress=False, weights={"gaol": 1.0})
    with pytest.raises(ValueError, match="leading problem axis"):
        fit_silhouette_problems(
            open_model,
            [problem],
            [POSE],
            config=FAST,
            progress=False,
            terms=[GoalTerm()],
            weights={"goal": 1.0},
            data={"goal": goal.repeat(2, 1)},
        )


# ----------------------------------------------------------------------------- the contour level (issue 24)
from silfit.fitting.body import MeshBody  # noqa: E402
from silfit.fitting.silhouette_stage import ContourBody, contour_vertex_index  # noqa: E402

# the contour level alone: L-BFGS on the contour terms, no rendered step after it
CONTOUR = replace(FAST, iterations=(0,), contour_iterations=15, contour_resolution=64)


def random_params(seed: int, rows: int = 2) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {
        "betas": torch.randn(rows, 10, generator=g),
        "body_pose": 0.3 * torch.randn(rows, 69, generator=g),
        "global_orient": torch.randn(rows, 3, generator=g),
        "transl": torch.randn(rows, 3, generator=g),
    }


def test_contour_body_poses_the_same_vertices_as_the_mesh(open_model):
    idx = contour_vertex_index(open_model, 500)
    assert 400 < len(idx) < 800 and np.all(np.diff(idx) > 0)
    params = random_params(3)
    with torch.no_grad():
        sub = ContourBody(open_model, "body25", idx)(**params)
        full = MeshBody(open_model, "body25")(**params)
    np.testing.assert_allclose(sub.vertices.numpy(), full.vertices[:, idx].numpy(), atol=2e-5)
    np.testing.assert_allclose(sub.keypoints.numpy(), full.keypoints.numpy(), atol=2e-4)  # landmarks: another path


def test_contour_bodies_kept_per_model(open_model):
    """The stage's reduced bodies are built once per model, layout and point set (issue 24's runtime part),
    again when an array of the model they mix is written in place."""
    from silfit.fitting.silhouette_stage import cached_contour_body

    made = []
    make = lambda: made.append(1) or contour_vertex_index(open_model, 300)  # noqa: E731
    a = cached_contour_body(open_model, "body25", ("vertices", 300), make)
    assert cached_contour_body(open_model, "body25", ("vertices", 300), make) is a and len(made) == 1
    assert cached_contour_body(open_model, "body25", ("vertices", 301), make) is not a and len(made) == 2
    assert isinstance(a, ContourBody)
    with torch.no_grad():
        open_model.v_template.add_(0.0)  # written in place (values unchanged): the kept body is rebuilt
    assert cached_contour_body(open_model, "body25", ("vertices", 300), make) is not a and len(made) == 3


def test_proxy_body_poses_the_render_proxy(open_model):
    """The rendered levels' evaluator (``proxy_body``): the render proxy's rest-pose mix of the
    model, posed directly, stays within millimetres of the proxy of the posed mesh (mean well under
    one); keypoints as the mesh's."""
    from silfit.render.proxy import get_proxy

    proxy = get_proxy(open_model.v_template, open_model.faces, 2000)
    params = random_params(4)
    with torch.no_grad():
        posed = ContourBody(open_model, "body25", proxy)(**params)
        full = MeshBody(open_model, "body25")(**params)
    gap = (posed.vertices - proxy(full.vertices)).norm(dim=-1)
    assert posed.vertices.shape == (2, proxy.n_vertices, 3)
    assert float(gap.mean()) < 5e-4 and float(gap.max()) < 1e-2, (float(gap.mean()), float(gap.max()))
    np.testing.assert_allclose(posed.keypoints.numpy(), full.keypoints.numpy(), atol=2e-4)


@pytest.mark.parametrize("robust", [False, True])
def test_contour_level_moves_a_shifted_body_without_rendering(open_model, target_mask, robust):
    def no_renderer(*args, **kwargs):  # the contour level renders nothing
        raise AssertionError("the contour level rendered")

    cfg = replace(CONTOUR, mask=replace(CONTOUR.mask, robust_cover=robust))
    result = fit_silhouette(open_model, POSE, CAMERA, target_mask, config=cfg, renderer=no_renderer, progress=False)
    assert result.steps == 0 and 0 < result.contour_iterations <= 15
    dx, dy, _ = result.transl[0] - POSE["transl"][0]
    # the truth is +0.08 m across; measured +0.078 and -0.001 m with the plain cover term, +0.085 and
    # -0.016 m with the robust one (issue 23: its pull within the clothing margin is a sixteenth)
    assert 0.06 < dx < 0.1 and abs(dy) < (0.025 if robust else 0.01), (dx, dy)


@pytest.mark.parametrize("robust", [False, True])
def test_contour_level_then_rendered_level(open_model, target_mask, robust):
    cfg = replace(
        FAST,
        iterations=(6,),
        contour_iterations=15,
        contour_resolution=64,
        mask=replace(FAST.mask, robust_cover=robust),
    )
    result = fit_silhouette(open_model, POSE, CAMERA, target_mask, config=cfg, progress=False)
    assert result.steps == 6 and result.contour_iterations > 0 and len(result.history["iou"]) == 6
    # the rendered level starts where the contour level left the body: already near the mask
    # (soft IoU at 64 px against 0.44 at the start; measured at the first rendered steps with the plain cover
    # term: 0.83-0.85 with the prb_projective renderer, 0.837-0.843 with the ray-cast one; with the robust
    # cover term, whose pull near the mask's edge is weaker, 0.83 and below)
    assert (
        result.iou_start > (0.75 if robust else 0.8) and abs(result.transl[0, 0] - POSE["transl"][0, 0] - 0.08) < 0.015
    )


def test_a_batch_with_the_contour_level_equals_single_runs(open_model):
    cfg = replace(FAST, iterations=(3,), contour_iterations=8, contour_resolution=64)
    masks = [mask_of(open_model, s) for s in SHIFTS]
    results = fit_silhouettes(open_model, [POSE] * 3, [CAMERA] * 3, masks, config=cfg, progress=False)
    for mask, r in zip(masks, results):
        alone = fit_silhouette(open_model, POSE, CAMERA, mask, config=cfg, progress=False)
        for name in ("betas", "body_pose", "global_orient", "transl"):
            np.testing.assert_array_equal(getattr(alone, name), getattr(r, name), err_msg=name)
        assert alone.contour_iterations == r.contour_iterations and alone.steps == r.steps


def test_a_fit_is_bit_identical_for_any_drjit_thread_count(open_model, target_mask):
    """The stage's default (ray-cast) renderer leaves Dr.Jit's thread pool as the process has it,
    and a fit is the same bits with one thread or two: Embree answers boolean ray tests and every
    sum is torch's (issue 24's threads part)."""
    from silfit.render._llvm import import_mitsuba

    _, dr = import_mitsuba()
    default = SilhouetteFitConfig()
    cfg = replace(
        FAST, iterations=(6,), optimise=default.optimise, lr=default.lr, contour_iterations=6, contour_resolution=64
    )
    previous = dr.thread_count()
    results = []
    try:
        for count in (2, 1, 2):
            dr.set_thread_count(count)
            results.append(fit_silhouette(open_model, POSE, CAMERA, target_mask, config=cfg, progress=False))
            assert dr.thread_count() == count  # the renderer left the pool alone
    finally:
        dr.set_thread_count(previous)
    assert results[0].steps == 6 and results[0].contour_iterations > 0
    for r in results[1:]:
        for name in ("betas", "body_pose", "global_orient", "transl"):
            np.testing.assert_array_equal(getattr(results[0], name), getattr(r, name), err_msg=name)
    # and the fit moved (a test that cannot fail proves nothing)
    assert abs(float(results[0].transl[0, 0]) - float(POSE["transl"][0, 0])) > 0.02


def test_legacy_schedule_has_no_contour_level():
    legacy = SilhouetteFitConfig.legacy()
    assert [s.name for s in legacy.stages()] == ["silhouette_128", "silhouette_256"]
    stages = SilhouetteFitConfig().stages()
    assert stages[0].name == "contour" and stages[0].optimiser == "lbfgs" and "silhouette" not in stages[0].weights
    assert all(s.optimiser == "adam" for s in stages[1:])
    with pytest.raises(ValueError, match="contour_iterations"):
        SilhouetteFitConfig(contour_iterations=-1)


def test_keypoint_trust_region_is_free_inside_and_quadratic_beyond():
    """Issue 23: the silhouette stage may move a confident keypoint's projection by up to ``tau``
    window pixels for nothing; beyond that it pays quadratically (a robust term alone saturates)."""
    from types import SimpleNamespace

    from silfit.fitting.silhouette_stage import KeypointTrustTerm, beta_bound

    P, F, C, K = 2, 1, 1, 3
    target = torch.zeros(P, F, C, K, 2, dtype=torch.float64)
    proj = target.clone()
    proj[0, 0, 0, 0, 0] = 4.0  # 4 image px = 8 window px at scale 2: inside tau = 10
    proj[1, 0, 0, 1, 0] = 10.0  # 20 window px: 10 beyond tau
    data = {
        "target": target,
        "weights": torch.tensor([1.0, 1.0, 0.0], dtype=torch.float64).expand(P, F, C, K),
        "scale": torch.full((P, F, C), 2.0, dtype=torch.float64),
        "trust_px": torch.full((P,), 10.0, dtype=torch.float64),
    }
    ev = SimpleNamespace(keypoints_2d=proj, data=data, F=F, C=C, per_problem=lambda v: v.reshape(P, -1).sum(1))
    e = KeypointTrustTerm()(ev)
    assert e[0].item() == 0.0 and e[1].item() == pytest.approx(100.0 / 2.0)  # (20 - 10)^2 over the 2 weighted points
    proj[1, 0, 0, 2, 0] = 1e3  # a point with confidence 0 costs nothing
    assert KeypointTrustTerm()(ev)[1].item() == pytest.approx(50.0)
    b = torch.tensor([[0.5, -2.5, 1.0], [3.5, 0.0, -4.5]], dtype=torch.float64)
    assert beta_bound(b, 2.5).tolist() == pytest.approx([0.0, 1.0 + 4.0])


def test_known_pixels_of_another_size_are_refused(open_model, target_mask):
    problem = Problem([Observation(View(CAMERA), None, target_mask, 0, 0, known=np.ones((10, 10), bool))])
    with pytest.raises(ValueError, match="known is 10x10 pixels"):
        fit_silhouette_problems(open_model, [problem], [POSE], config=FAST, progress=False)


def test_level_proxy_faces_pick_each_rendered_levels_proxy(open_model, target_mask, monkeypatch):
    """Issue 24's fourth part: a rendered level listed in ``level_proxy_faces`` renders that coarser
    proxy (at most ``proxy_faces``; a level not listed, the legacy schedule and a full-mesh config: none)."""
    import silfit.fitting.silhouette_stage as rs  # the stage calls the renderer by this name

    cfg = replace(FAST, iterations=(2,), proxy_faces=10000, level_proxy_faces={64: 2000})
    assert [s.options.get("proxy_faces") for s in cfg.stages()] == [2000]
    assert replace(cfg, level_proxy_faces={64: 20000}).stages()[0].options.get("proxy_faces") is None
    assert (
        replace(cfg, level_proxy_faces={"64": 2000}).stages()[0].options["proxy_faces"] == 2000
    )  # read back from JSON
    assert replace(cfg, proxy_faces=None).stages()[0].options.get("proxy_faces") is None
    assert all("proxy_faces" not in s.options for s in SilhouetteFitConfig.legacy().stages())
    assert [s.options.get("proxy_faces") for s in SilhouetteFitConfig().stages()[1:]] == [3000, 5000]
    seen = []
    real = rs.get_silhouette_renderer
    monkeypatch.setattr(rs, "get_silhouette_renderer", lambda faces: seen.append(len(faces)) or real(faces))
    result = fit_silhouette(open_model, POSE, CAMERA, target_mask, config=cfg, progress=False)
    # only the proxy a rendered level uses is built (not the 10,000-face one no level renders)
    assert seen == [2000] and result.steps == 2 and math.isfinite(result.iou_end)
    seen.clear()  # proxy_faces=None: the full mesh at every level
    result = fit_silhouette(
        open_model, POSE, CAMERA, target_mask, config=replace(cfg, proxy_faces=None), progress=False
    )
    assert seen == [len(open_model.faces)] and result.steps == 2
