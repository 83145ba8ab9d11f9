"""Fitting one body seen by a calibrated rig: the keypoint stage over all views in the world frame, and the
per-view diagnostics.

The problem comes from the rig's files through :func:`silfit.inputs.rig.rig_problem` (the fitting core reads no
file). The keypoint stage is :class:`~silfit.fitting.keypoint_stage.KeypointFitter` run on problems
with ``C`` views (one frame): the body is placed by triangulating its torso
(:mod:`silfit.fitting.triangulate`), every view's keypoints enter the data term (each
view normalised by the person's extent in it, the views averaged), the depth term pulls
the root toward its triangulated depth in every camera and the points term the body's keypoints
toward the triangulated ones. There is no flip test (the
triangulated shoulders and hips give the facing) and no limb-branch search: several views
fix a limb's depth, and the schedule starts from the body posed onto every triangulated
keypoint (:func:`pose_from_points`) instead of the rest pose, so that no limb has to climb
from the wrong depth branch (with two views the wrong branch could win: one view agrees with
it, and the robust data term sets the other view's limb aside; ``benchmarks/bench_rig.py --start
rest,points`` compares). The start alone did not hold: the pose stages' strong prior (weight 2000
first) pulled a limb off its triangulated place and the 2D terms of two views let it settle in the
other branch, so the stages keep the ``points`` term (:class:`~silfit.fitting.terms.PointsTerm`: the
body's keypoints against the triangulated ones, ``KeypointFitConfig.points_weight`` and
``final_points_weight``) to the end (the measurements: docs/benchmarks/defaults.md).
Parameters and meshes are in the world frame of the rig's extrinsics.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Dict, List, Sequence, Tuple

import numpy as np
import torch

from ..io.keypoints import LAYOUTS
from ..io.wholebody import part_slices
from ..priors import angle_prior, limit_violation
from .problem import Problem, View, stack_views
from .terms import evaluate
from .branches import align_segments
from .hands_face import GATED_PARTS, SILHOUETTE_PART_LR, wholebody_silhouette_inputs
from .triangulate import placement_to_world, triangulate_views
from .threads import torch_threads
from .keypoint_stage import POINTS_STATURE_M
from .optim import batched_lbfgs

__all__ = ["RigFit", "fit_rig_keypoints", "pose_from_points", "triangulated_keypoints", "wholebody_problem_inputs"]


#: the 3D start (:func:`pose_from_points`): its L-BFGS rounds (pose-prior weight, steps), the prior
#: annealed as in the keypoint stage's pose stages (metres to normalised pixels: ``POINTS_STATURE_M``)
POINTS_ROUNDS = ((100.0, 60), (20.0, 60))


@dataclass
class RigFit:
    """One rig subject's fit: world-frame SMPL parameters (``[w]`` each), vertices ``[V, 3]``,
    joints, and per view: projected keypoints ``[C, K, 2]``, median reprojection error ``[C]`` px."""

    params: Dict[str, np.ndarray]
    vertices: np.ndarray
    joints: np.ndarray
    keypoints_2d: np.ndarray
    reprojection_error: np.ndarray
    energies: Dict[str, float] = field(default_factory=dict)
    timings: Dict[str, float] = field(default_factory=dict)


def _median_errors(proj: np.ndarray, problem: Problem) -> np.ndarray:
    out = []
    for c, o in enumerate(problem.grid()[0]):
        ok = o.keypoints.conf > 0
        err = np.linalg.norm(proj[c] - o.keypoints.xy, axis=-1)
        out.append(float(np.median(err[ok])) if ok.any() else float("nan"))
    return np.asarray(out)


def camera_to_world(model, rows: Dict[str, torch.Tensor], views) -> Dict[str, torch.Tensor]:
    """Parameter rows of bodies placed in their view's camera frame, placed in the world
    frame instead (``views``: one :class:`~silfit.fitting.problem.View` per row; see
    :func:`~silfit.fitting.triangulate.placement_to_world`)."""
    with torch.no_grad():
        j = model(betas=rows["betas"]).joints[:, 0].double().numpy()
    placed = [
        placement_to_world(
            rows["global_orient"][b].double().numpy(), rows["transl"][b].double().numpy(), *view.extrinsics(), j[b]
        )
        for b, view in enumerate(views)
    ]
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=rows["transl"].dtype)  # noqa: E731
    return {**rows, "global_orient": T([q[0] for q in placed]), "transl": T([q[1] for q in placed])}


def in_first_camera(problem: Problem) -> Problem:
    """The problem with its views' extrinsics relative to its first view's camera (that camera at
    the origin, looking down +z): one view is then an image, several a rig in a frame that does
    not depend on where the world's origin and axes were put."""
    R0, t0 = problem.observations[0].view.extrinsics()
    obs = []
    for o in problem.observations:
        R, t = o.view.extrinsics()
        Rr = R @ R0.T
        obs.append(replace(o, view=View(o.view.camera, Rr, t - Rr @ t0)))
    return replace(problem, observations=obs)


def fit_rig_keypoints(
    fitter, problems: Sequence[Problem], progress: bool = False, start: str = "points"
) -> List[RigFit]:
    """The keypoint stage on one-frame rig problems of equal view counts (one batch).

    ``start`` (several views): ``"points"`` starts the schedule from :func:`pose_from_points`,
    ``"rest"`` from the placed rest pose and the prior's means (as before it existed), ``"both"``
    runs both and keeps each problem's lower final energy (twice the time).

    Each problem is fitted in its first camera's frame (:func:`in_first_camera`), then placed in
    the world by that camera's extrinsics (:func:`camera_to_world`): a one-view rig is a single
    image (similar-triangles placement, flip test, branch search: all assume the camera at the
    origin), and a rig's fit depends on the world frame's choice only through the rounding of the
    relative extrinsics (which the optimiser still amplifies, less than the L-BFGS path in world
    axis-angle did before; by how much: docs/benchmarks/defaults.md)."""
    problems = list(problems)
    run = [in_first_camera(p) for p in problems]
    with torch_threads(fitter.config.threads):
        state, info = _fit_from(fitter, run, progress, start)
        layout = info["layout"]
        rows = camera_to_world(fitter.model, layout.rows(state), [p.observations[0].view for p in problems])
        state = {n: (v if layout.is_shared(n) else v[:, None]) for n, v in rows.items()}
        info["views"] = stack_views(problems, fitter.dtype)
        with torch.no_grad():
            out = fitter.model(**rows)
            ev = evaluate(fitter.body, layout, state, info["views"], info["data"])
    proj = ev.keypoints_2d[:, 0].numpy()  # [B, C, K, 2]
    last = list(info["energies"])[-1]
    fits = []
    for b, p in enumerate(problems):
        fits.append(
            RigFit(
                params={n: rows[n][b].numpy().astype(np.float32) for n in layout.sizes},
                vertices=out.vertices[b].numpy().astype(np.float32),
                joints=out.joints[b].numpy().astype(np.float32),
                keypoints_2d=proj[b].astype(np.float32),
                reprojection_error=_median_errors(proj[b], p),
                energies={k: float(v[b]) for k, v in info["energies"].items()},
                timings={**info["timings"], "final_stage": last},
            )
        )
    return fits


def wholebody_problem_inputs(model, problems: Sequence[Problem], config) -> tuple:
    """What the silhouette stage needs to fit a whole-body mesh to problems of ``F`` frames x ``C``
    views (every observation with keypoints of the ``wholebody`` layout), as
    :func:`~silfit.fitting.hands_face.wholebody_silhouette_inputs` gives it for one image per problem:
    ``(config, problems, terms, weights, data)``; the problems' keypoints are the body points
    (the stage's own keypoint term), ``data["part_weights"]`` is ``[P, F, C, K]``. A part is
    optimised when every frame of every problem has it in at least one view (else it stays where the
    keypoint stage left it)."""
    grids = [p.grid() for p in problems]
    flat = [o for g in grids for row in g for o in row]
    if any(o.keypoints is None for o in flat):
        raise ValueError("a whole-body silhouette stage needs keypoints in every observation")
    cfg, body_sets, terms, weights, data = wholebody_silhouette_inputs(
        model, [o.keypoints for o in flat], config, model.dtype
    )
    P, F, C = len(problems), problems[0].num_frames, problems[0].num_views
    data = {"part_weights": data["part_weights"].reshape(P, F, C, -1)}
    sl = part_slices()
    conf = np.stack([o.keypoints.conf for o in flat]).reshape(P, F, C, -1)
    present = {
        part: bool((conf[..., sl[part]] > 0).any(-1).any(-1).all()) for part in ("hand_left", "hand_right", "face")
    }
    free = tuple(n for n, part in GATED_PARTS.items() if present[part])
    cfg = replace(
        cfg,
        optimise=tuple(n for n in cfg.optimise if n not in GATED_PARTS) + free,
        lr={**SILHOUETTE_PART_LR, **config.lr},
    )
    it = iter(body_sets)
    out = [
        Problem([replace(o, keypoints=next(it)) for row in g for o in row], shared=p.shared)
        for p, g in zip(problems, grids)
    ]
    return cfg, out, terms, weights, data


def triangulated_keypoints(problem: Problem, kp_weights: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """``(X [K, 3], w [K])``: every keypoint of a one-frame problem with several views
    triangulated from the views that agree (:func:`~silfit.fitting.triangulate.robust_triangulate`,
    in the problem's world frame), weighted by ``kp_weights [K]`` times the mean over the views of
    the confidence of the inlier views (0: not triangulated)."""
    row = problem.grid()[0]
    X, w = triangulate_views(
        [o.view for o in row], np.stack([o.keypoints.xy for o in row]), np.stack([o.keypoints.conf for o in row])
    )
    w = w * np.asarray(kp_weights, np.float64)
    ok = w > 0
    return np.where(ok[:, None], X, 0.0), np.where(ok, w, 0.0)


def pose_from_points(
    fitter, problems: Sequence[Problem], state: Dict[str, torch.Tensor], align: bool = True
) -> Dict[str, torch.Tensor]:
    """A start for one-frame problems with several views: the body posed onto its triangulated
    keypoints (:func:`triangulated_keypoints`) from the placed rest pose in ``state`` (the fitter's
    initial state, rows ``[B, 1, w]``).

    Two views at a wide angle fix every seen keypoint in 3D, so the limbs' depth is known before
    any 2D fit; the 2D energy alone, started from the rest pose or the prior's means, can settle
    with a limb in the wrong depth branch, where one view agrees and the robust term sets the
    other view's limb aside (with four views the majority pulls it back; with two, nothing does).
    Minimises the Geman-McClure distance (the keypoint stage's ``keypoint_term.sigma``, in normalised pixels:
    :data:`POINTS_STATURE_M` metres are ``keypoint_term.norm_extent`` pixels) to the points plus the pose,
    angle and limit priors, over ``global_orient``, ``transl`` and ``body_pose`` (``betas`` at 0),
    in :data:`POINTS_ROUNDS`. Returns ``{global_orient, transl, body_pose}`` rows ``[B, w]``."""
    cfg, dt = fitter.config, fitter.dtype
    pts = [triangulated_keypoints(p, fitter.kp_weights.double().numpy()) for p in problems]
    X = torch.as_tensor(np.stack([q[0] for q in pts]), dtype=dt)
    w = torch.as_tensor(np.stack([q[1] for q in pts]), dtype=dt)
    base = {n: (v[:, 0] if v.dim() == 3 else v).detach().clone() for n, v in state.items()}
    free = ("global_orient", "transl", "body_pose")
    sizes = [base[n].shape[1] for n in free]
    scale = cfg.keypoint_term.norm_extent / POINTS_STATURE_M
    sigma2 = float(cfg.keypoint_term.sigma) ** 2
    if align:
        base["body_pose"] = align_segments(
            fitter.body,
            base,
            X.double().numpy(),
            w.double().numpy(),
            fitter.model.joint_names,
            fitter.model.parents,
            LAYOUTS[fitter.layout],
        )
    x = torch.cat([base[n] for n in free], 1)
    for wp, iters in POINTS_ROUNDS:
        wa = cfg.angle_weight[min(1, len(cfg.angle_weight) - 2)]  # the second pose stage's (or the only one's)

        def fun(xr, idx):
            rows = {n: v[idx] for n, v in base.items()}
            rows.update(dict(zip(free, torch.split(xr, sizes, 1))))
            kp = fitter.body(**rows).keypoints
            d2 = ((kp - X[idx]) * scale).square().sum(-1)
            data = (w[idx] * sigma2 * d2 / (d2 + sigma2)).sum(-1)
            bp = rows["body_pose"]
            return data + wp * fitter.pose_prior(bp) + wa * angle_prior(bp) + cfg.limit_weight * limit_violation(bp)

        x, _, _ = batched_lbfgs(fun, x, max_iter=iters, history=cfg.history)
    return dict(zip(free, (v.detach() for v in torch.split(x, sizes, 1))))


def _fit_from(fitter, run, progress, start):
    if start not in ("points", "rest", "both"):
        raise ValueError(f"start must be 'points', 'rest' or 'both', got {start!r}")
    if start == "rest" or run[0].num_views < 2:
        return fitter.fit_problems(run, progress=progress)
    _, _, state0 = fitter._problem_data(run, (False,))
    init = pose_from_points(fitter, run, state0)
    state, info = fitter.fit_problems(run, progress=progress, init={k: v.numpy() for k, v in init.items()})
    if start == "points":
        return state, info
    state_r, info_r = fitter.fit_problems(run, progress=progress)
    last = list(info["energies"])[-1]
    better = torch.as_tensor(info_r["energies"][last] < info["energies"][last])
    for n in state:
        state[n][better] = state_r[n][better]
    info["energies"] = {
        k: torch.where(better, info_r["energies"][k], v) for k, v in info["energies"].items() if k in info_r["energies"]
    }
    return state, info


#: the rig's file readers moved to the input builders (issue 57: the fitting core reads no file)
MOVED_TO_INPUTS = ("fit_keypoints_of", "has_wholebody_parts", "rig_problem")


def __getattr__(name: str):
    """The file readers that moved to :mod:`silfit.inputs.rig`; the old names work for one release."""
    if name in MOVED_TO_INPUTS:
        from .._lazy import moved_function

        return moved_function(__name__, name, "silfit.inputs.rig")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
