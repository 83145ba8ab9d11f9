"""Fitting one body seen by a calibrated rig: the problem from a rig folder, the keypoint
stage over all views in the world frame, and the per-view diagnostics.

The keypoint stage is :class:`~silfit.fitting.keypoint_stage.KeypointFitter` run on problems
with ``C`` views (one frame): the body is placed by triangulating its torso
(:mod:`silfit.fitting.triangulate`), every view's keypoints enter the data term (each
view normalised by the person's extent in it, the views averaged), the depth term pulls
the root toward its triangulated depth in every camera. There is no flip test (the
triangulated shoulders and hips give the facing) and no limb-branch search (several views
fix a limb's depth). Parameters and meshes are in the world frame of the rig's extrinsics.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Dict, List, Sequence

import numpy as np
import torch

from ..keypoints import read_keypoints
from .problem import Observation, Problem, View, stack_views
from .terms import evaluate
from .triangulate import placement_to_world
from .threads import torch_threads

__all__ = ["RigFit", "fit_keypoints_of", "fit_rig_keypoints", "has_wholebody_parts", "rig_problem",
           "wholebody_problem_inputs"]


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


def fit_keypoints_of(path, model=None, person="largest"):
    """The keypoints ``model`` is fitted to from one OpenPose file: its body (BODY_25 / COCO-17) for
    an SMPL-layout model (or no model), the ``wholebody`` layout (hands and face; absent parts at
    confidence 0) for an SMPL-X-layout one (:func:`silfit.wholebody.choose_fit_keypoints`)."""
    ks = read_keypoints(path, person=person)
    if model is None or getattr(model, "kind", "smpl") != "smplx":
        return ks
    from ..wholebody import choose_fit_keypoints, read_wholebody_parts

    return choose_fit_keypoints(ks, read_wholebody_parts(path, person), model)[0]


def has_wholebody_parts(paths, person="largest") -> bool:
    """Whether any of these OpenPose files holds confident hand or face points (they pick the
    whole-body model when none is given, as for one image)."""
    from ..errors import InputError
    from ..wholebody import read_wholebody_parts

    for path in paths:
        try:
            parts = read_wholebody_parts(path, person)
        except InputError:  # that view's keypoints are set aside when read (e.g. no person ``person`` there)
            continue
        if parts is not None and parts.has_parts:
            return True
    return False


def rig_problem(views, person="largest", with_masks: bool = True, model=None) -> Problem:
    """A one-frame :class:`Problem` from :func:`silfit.rig.load_rig`'s views: each view's
    keypoints (OpenPose; checked as one image's are, :func:`silfit.plausibility.check_keypoints`,
    with the notes added to the view's warnings) and, when present and ``with_masks``, its mask
    (checked against the camera's size). With an SMPL-X-layout ``model`` the keypoints are the
    ``wholebody`` layout (:func:`fit_keypoints_of`)."""
    from ..plausibility import check_keypoints
    from ..silhouette.masks import read_mask

    obs = []
    for c, v in enumerate(views):
        cam = v.view.camera
        ks, notes = check_keypoints(fit_keypoints_of(v.keypoints, model, person), cam.size)
        v.warnings.extend(n for n in notes if n not in v.warnings)
        mask = read_mask(v.mask, size=(cam.width, cam.height)) if (with_masks and v.mask is not None) else None
        obs.append(Observation(v.view, ks, mask, frame=0, view_index=c))
    return Problem(obs)


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
    placed = [placement_to_world(rows["global_orient"][b].double().numpy(), rows["transl"][b].double().numpy(),
                                 *view.extrinsics(), j[b]) for b, view in enumerate(views)]  # fmt: skip
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


def fit_rig_keypoints(fitter, problems: Sequence[Problem], progress: bool = False) -> List[RigFit]:
    """The keypoint stage on one-frame rig problems of equal view counts (one batch).

    Each problem is fitted in its first camera's frame (:func:`in_first_camera`), then placed in
    the world by that camera's extrinsics (:func:`camera_to_world`): a one-view rig is a single
    image (similar-triangles placement, flip test, branch search: all assume the camera at the
    origin), and a rig's fit depends on the world frame's choice only through the rounding of the
    relative extrinsics (which the optimiser still amplifies: 3-5 mm mean on the two-view test
    subject; the L-BFGS path in world axis-angle moved it by 6.4 mm before)."""
    problems = list(problems)
    run = [in_first_camera(p) for p in problems]
    with torch_threads(fitter.config.threads):
        state, info = fitter.fit_problems(run, progress=progress)
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
        fits.append(RigFit(
            params={n: rows[n][b].numpy().astype(np.float32) for n in layout.sizes},
            vertices=out.vertices[b].numpy().astype(np.float32), joints=out.joints[b].numpy().astype(np.float32),
            keypoints_2d=proj[b].astype(np.float32), reprojection_error=_median_errors(proj[b], p),
            energies={k: float(v[b]) for k, v in info["energies"].items()},
            timings={**info["timings"], "final_stage": last},
        ))  # fmt: skip
    return fits


def wholebody_problem_inputs(model, problems: Sequence[Problem], config) -> tuple:
    """What the silhouette stage needs to fit a whole-body mesh to problems of ``F`` frames x ``C``
    views (every observation with keypoints of the ``wholebody`` layout), as
    :func:`~silfit.fitting.wholebody.wholebody_silhouette_inputs` gives it for one image per problem:
    ``(config, problems, terms, weights, data)``; the problems' keypoints are the body points
    (the stage's own keypoint term), ``data["part_weights"]`` is ``[P, F, C, K]``. A part is
    optimised when every frame of every problem has it in at least one view (else it stays where the
    keypoint stage left it)."""
    from .wholebody import GATED_PARTS, SILHOUETTE_PART_LR, wholebody_silhouette_inputs
    from ..wholebody import part_slices

    grids = [p.grid() for p in problems]
    flat = [o for g in grids for row in g for o in row]
    if any(o.keypoints is None for o in flat):
        raise ValueError("a whole-body silhouette stage needs keypoints in every observation")
    cfg, body_sets, terms, weights, data = wholebody_silhouette_inputs(model, [o.keypoints for o in flat], config, model.dtype)
    P, F, C = len(problems), problems[0].num_frames, problems[0].num_views
    data = {"part_weights": data["part_weights"].reshape(P, F, C, -1)}
    sl = part_slices()
    conf = np.stack([o.keypoints.conf for o in flat]).reshape(P, F, C, -1)
    present = {part: bool((conf[..., sl[part]] > 0).any(-1).any(-1).all()) for part in ("hand_left", "hand_right", "face")}
    free = tuple(n for n, part in GATED_PARTS.items() if present[part])
    cfg = replace(cfg, optimise=tuple(n for n in cfg.optimise if n not in GATED_PARTS) + free,
                  lr={**SILHOUETTE_PART_LR, **config.lr})  # fmt: skip
    it = iter(body_sets)
    out = [Problem([replace(o, keypoints=next(it)) for row in g for o in row], shared=p.shared) for p, g in zip(problems, grids)]
    return cfg, out, terms, weights, data
