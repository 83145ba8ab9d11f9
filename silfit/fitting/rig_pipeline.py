"""The whole fit of one body seen by a calibrated rig (``silfit fit --rig``): the keypoint
stage over all views in the world frame (:mod:`silfit.fitting.rig_fit`), then, when the
views have masks, the silhouette stage rendering every view; results in memory
(:func:`fit_rig`); on disk by the one writer, :func:`silfit.run.write` (:mod:`silfit.outputs.write`).

Output folder (world coordinates: the frame of the rig's extrinsics)::

    params.npz, params.json   the fit file (silfit.io.fit: one frame, the rig's views with their
                              R, t; coordinates = "world"): parameters, vertices, joints,
                              keypoints_2d and reprojection error per view, the model
    mesh.obj                  the posed body in world coordinates (metres)
    cameras.json              the rig's cameras (silfit.io.rig manifest: intrinsics, R, t)
    metrics.json              per view: median reprojection error (px), IoU of the keypoint
                              stage and of the final body (views with masks); timings
    views/<name>/overlay.png  the final body over each view's image (or a grey canvas)
    views/<name>/silhouette.png   final silhouette vs the view's mask   [with a mask]
    stages/keypoints/params.npz   the keypoint stage's parameters         [with masks]

Written atomically (:func:`silfit.outputs.folder.atomic_folder`).

A rig video (``silfit fit --rig DIR`` on a rig whose views are video folders,
:func:`silfit.io.video.load_rig_sequence`; fitted by :func:`silfit.run.run`): the sequence fit of :mod:`silfit.fitting.sequence`
over frames x views in the world frame, written by :func:`silfit.run.write`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import List

import numpy as np
import torch

from ..body import load_body_model
from ..eval.metrics import mask_iou
from ..io.keypoints import KeypointSet, model_keypoints
from ..io.rig import project_world, to_camera
from .cores import Core, run_steps
from .hands_face import wholebody_summary
from .image_fit import body_mask
from .keypoint_stage import KeypointFitter
from .plausibility import fit_warnings, guard_fit, mask_warnings, shape_warnings
from .refine import SilhouetteHooks, StageInputs, refine_silhouettes
from .rig_fit import RigFit, fit_rig_keypoints, wholebody_problem_inputs
from .silhouette_stage import SilhouetteFitConfig

__all__ = ["RigCore", "RigRefinement", "RigResult", "fit_rig", "fit_rigs", "refine_rig_fits", "view_vertices"]


@dataclass
class RigResult:
    """A rig fit: final world-frame parameters and mesh, the keypoint stage's fit, the
    per-view metrics, and the silhouette stage's result (``None`` without masks)."""

    names: List[str]
    params: dict
    vertices: np.ndarray
    joints: np.ndarray
    keypoint: RigFit
    silhouette: object = None
    metrics: dict = field(default_factory=dict)
    masks: dict = field(default_factory=dict)  # view name -> rendered final mask


def view_vertices(vertices: np.ndarray, view) -> np.ndarray:
    """World-frame vertices in a view's camera frame (``R x + t``)."""
    return to_camera(vertices, view).astype(np.float32)


def _view_ious(vertices, faces, problem, names):
    ious, masks = {}, {}
    for name, o in zip(names, problem.grid()[0]):
        if o.mask is None:
            continue
        m = body_mask(view_vertices(vertices, o.view), faces, o.view.camera)
        masks[name], ious[name] = m, float(mask_iou(m, o.mask))
    return ious, masks


def disagreeing_views(names, errors, factor: float = 4.0, floor_px: float = 10.0) -> List[str]:
    """Warnings for views whose median reprojection error is ``factor`` times the other views'
    median and above ``floor_px``: a view the fit could not agree with (a wrong calibration,
    another person's keypoints), which the robust data term only damps."""
    errors = np.asarray(errors, dtype=np.float64)
    if np.isfinite(errors).sum() < 2:
        return []
    out = []
    for i, (n, e) in enumerate(zip(names, errors)):
        # against the other views' median: with two views the overall median is the mean of
        # the culprit's error and the other's, which never exceeds it 4 times, and nothing fired
        median = float(np.nanmedian(np.delete(errors, i)))
        if np.isfinite(e) and np.isfinite(median) and e > max(factor * median, floor_px):
            where = "in the other view" if len(errors) == 2 else "over the other views"
            hint = " (with two views either may be the wrong one)" if len(errors) == 2 else ""
            out.append(
                f"view {n}: median reprojection error {e:.1f} px against {median:.1f} px {where}; check its "
                f"calibration and that its keypoints are this person's{hint}"
            )
    return out


def view_warnings(names, problem, vertices, per_view: dict, betas=None) -> List[str]:
    """One image's fit warnings (:func:`silfit.fitting.plausibility.fit_warnings`: IoU, depth,
    reprojection error) for each view of a rig fit, from its metrics in ``per_view``."""
    out = []
    for name, o in zip(names, problem.grid()[0]):
        for w in fit_warnings(per_view[name], o.keypoints, view_vertices(vertices, o.view)):
            out.append(f"view {name}: {w}")
    return out + shape_warnings(betas)


def keypoint_stage_result(kp: RigFit, problem, names, faces) -> RigResult:
    ious, masks = _view_ious(kp.vertices, faces, problem, names)
    per_view = {n: {"reprojection_error_px": float(e)} for n, e in zip(names, kp.reprojection_error)}
    for n, v in ious.items():
        per_view[n]["iou_keypoint_stage"] = v
    metrics = {
        "views": per_view,
        "timings": {"keypoints": float(kp.timings["total"])},
        "reprojection_error_px": float(np.nanmedian(kp.reprojection_error)),
        "warnings": disagreeing_views(names, kp.reprojection_error)
        + view_warnings(names, problem, kp.vertices, per_view, kp.params.get("betas")),
    }
    if ious:
        metrics["iou_mean"] = float(np.mean(list(ious.values())))
    return RigResult(list(names), dict(kp.params), kp.vertices, kp.joints, kp, None, metrics, masks)


def fit_rig(
    problem,
    names,
    model=None,
    pose_prior=None,
    keypoint_config=None,
    silhouette: bool = True,
    silhouette_config=None,
    progress: bool = False,
) -> RigResult:
    """Fit one rig problem (:func:`silfit.inputs.rig.rig_problem`); ``names`` the views'
    names. With ``silhouette`` and at least one mask, the silhouette stage follows."""
    return fit_rigs([problem], [names], model, pose_prior, keypoint_config, silhouette, silhouette_config, progress)[0]


def fit_rigs(
    problems,
    names,
    model=None,
    pose_prior=None,
    keypoint_config=None,
    silhouette: bool = True,
    silhouette_config=None,
    progress: bool = False,
) -> List[RigResult]:
    """Fit rig problems of one keypoint layout (``names[i]``: problem ``i``'s view names): the steps of every fit
    (:func:`~silfit.fitting.cores.run_steps`) on a :class:`RigCore`: the keypoint stage batched over them, then the
    silhouette stage batched over those with a mask (with ``silhouette``); a result per problem, ``keypoint``
    holding its keypoint-stage fit."""
    core = RigCore(problems, names, model, pose_prior, keypoint_config, silhouette, silhouette_config, progress)
    return run_steps(core)


class RigCore(Core):
    """Rig problems of one keypoint layout (:func:`fit_rigs`' arguments) as the core of
    :func:`~silfit.fitting.cores.run_steps`: the keypoint stage in the world frame, batched
    (:func:`~silfit.fitting.rig_fit.fit_rig_keypoints`, the torso triangulated), the silhouette stage on the
    problems with a mask (:class:`RigRefinement`), a :class:`RigResult` per problem (with the whole body's parts)."""

    def __init__(self, problems, names, model, pose_prior, keypoint_config, silhouette, silhouette_config, progress):
        self.problems, self.names, self.size = list(problems), names, len(problems)
        self.model = load_body_model() if model is None else model
        layout = problems[0].observations[0].keypoints.layout
        self.fitter = KeypointFitter(self.model, layout, keypoint_config, pose_prior)  # no branch search with several
        # views: the final stage runs its ``unsearched_iterations`` (KeypointFitConfig.final_iters_unsearched)
        self.pose_prior, self.silhouette, self.silhouette_config = self.fitter.pose_prior, silhouette, silhouette_config
        self.progress = progress

    def keypoint_stage(self, rows: list) -> list:
        """Per row ``(RigFit, its keypoint-stage RigResult)``; the batch's seconds shared out."""
        t0 = time.perf_counter()
        kps = fit_rig_keypoints(self.fitter, [self.problems[i] for i in rows], progress=self.progress)
        share = (time.perf_counter() - t0) / len(rows)
        for kp in kps:
            kp.timings = {**kp.timings, "total": share}
        faces = self.model.faces.cpu().numpy()
        return [(kp, keypoint_stage_result(kp, self.problems[i], self.names[i], faces)) for kp, i in zip(kps, rows)]

    def silhouette_rows(self, rows: list, kp: dict) -> list:
        return [i for i in rows if self.silhouette and any(o.mask is not None for o in self.problems[i].observations)]

    def silhouette_hooks(self, rows: list, kp: dict):
        yield rows, RigRefinement([(self.names[i], self.problems[i], kp[i][0]) for i in rows])

    def results(self, kp: dict, refined: dict) -> List[RigResult]:
        """Each problem's refined result, or its keypoint stage's; the whole body's parts recorded."""
        out = [refined.get(i, kp[i][1]) for i in range(self.size)]
        if self.fitter.whole_body:  # which parts were fitted (seen in any view), which held at rest
            for problem, result in zip(self.problems, out):
                ks = [o.keypoints for o in problem.grid()[0]]
                seen = KeypointSet(ks[0].xy, np.max([k.conf for k in ks], 0), ks[0].layout, ks[0].source)
                result.metrics["whole_body"], notes = wholebody_summary(seen)
                result.metrics["warnings"] = notes + result.metrics.get("warnings", [])
        return out


def _check_masks_overlap(items, before) -> None:
    """Raise where a view's mask does not overlap the body fitted to the keypoints at all."""
    for (names, p, _), b in zip(items, before):
        zero = [n for n in names if b.metrics["views"][n].get("iou_keypoint_stage", 1.0) == 0.0]
        if zero:
            raise ValueError(
                f"view(s) {', '.join(zero)}: the mask does not overlap the body fitted to the keypoints at all"
            )


def _silhouette_inputs(model, problems, layout: str, config):
    """``(config, problems, extra)`` for the silhouette stage: with the whole-body layout, the whole-body mesh's
    inputs (hand and face keypoints kept, as for one image)."""
    extra = {}
    if layout == "wholebody":
        config, problems, *rest = wholebody_problem_inputs(model, problems, config or SilhouetteFitConfig())
        extra = dict(zip(("terms", "weights", "data"), rest))
    return config, problems, extra


def _posed_body(model, params: dict, layout: str):
    """``(body, world keypoints [K, 3] float64, vertices [V, 3] float32)`` of one parameter set."""

    t = lambda a: torch.as_tensor(np.asarray(a, np.float64)[None], dtype=model.dtype)  # noqa: E731
    with torch.no_grad():
        body = model(**{n: t(v) for n, v in params.items()})
        kp3 = model_keypoints(model, body, layout)[0].double().numpy()
    vertices = body.vertices[0].numpy().astype(np.float32)
    return body, kp3, vertices


def _rig_reprojection(kp3: np.ndarray, problem):
    """``(projections, median errors)``: the world keypoints projected into each view, and each view's median
    reprojection error (px; NaN without a confident keypoint)."""
    proj, errs = [], []
    for o in problem.grid()[0]:
        uv = project_world(kp3, o.view)
        proj.append(uv)
        ok = o.keypoints.conf > 0
        errs.append(float(np.median(np.linalg.norm(uv - o.keypoints.xy, axis=1)[ok])) if ok.any() else float("nan"))
    return proj, errs


def _kept_keypoint_result(b: RigResult, sil, guard) -> RigResult:
    """The keypoint-stage result ``b``, kept by the plausibility guard over the refined fit ``sil``."""
    b.metrics["warnings"] = list(b.metrics["warnings"]) + list(sil.warnings) + list(guard.warnings)
    b.metrics["silhouette_guard"] = {"kept": "keypoints", "less_plausible": list(guard.reasons)}
    b.metrics["timings"]["silhouette"] = float(sil.seconds)
    return b


def _refined_metrics(metrics: dict, names, p, sil, guard, ious: dict, errs, proj, vertices, betas) -> dict:
    """The keypoint stage's ``metrics`` updated in place with the refined fit's: errors, IoUs, warnings."""
    metrics["silhouette_guard"] = {"kept": "silhouette", "less_plausible": list(guard.reasons)}
    for n, e in zip(names, errs):
        metrics["views"][n]["reprojection_error_px_keypoint_stage"] = metrics["views"][n]["reprojection_error_px"]
        metrics["views"][n]["reprojection_error_px"] = e
    for n, v in ious.items():
        metrics["views"][n]["iou"] = v
    metrics.update(
        iou_mean_keypoint_stage=metrics.pop("iou_mean"),
        iou_mean=float(np.mean(list(ious.values()))),
        reprojection_error_px=float(np.nanmedian(errs)),
        keypoints_2d=np.asarray(proj),
        warnings=[
            w for n, o in zip(names, p.grid()[0]) if o.mask is not None for w in mask_warnings(o.mask, f"view {n}")
        ]
        + list(sil.warnings)
        + disagreeing_views(names, errs)
        + view_warnings(names, p, vertices, metrics["views"], betas),
        silhouette_steps=sil.steps,
    )
    metrics["timings"]["silhouette"] = float(sil.seconds)
    return metrics


def _refined_rig_result(model, faces, layout: str, config, item, b: RigResult, sil) -> RigResult:
    """One rig problem's result after the silhouette stage ``sil``, from its keypoint-stage result ``b``."""
    names, p, kp = item
    params = {n: np.asarray(v, np.float32).reshape(-1) for n, v in sil.parameters.items()}
    body, kp3, vertices = _posed_body(model, params, layout)
    proj, errs = _rig_reprojection(kp3, p)
    # the plausibility guard, as for one image (silfit.fitting.plausibility.silhouette_guard): a refined fit less
    # plausible than the keypoint fit it started from is not kept
    guard = guard_fit(
        model,
        b.metrics["reprojection_error_px"],
        kp.params.get("betas"),
        float(np.nanmedian(errs)),
        params.get("betas"),
        "rig",
    )
    if guard.reverted and getattr(config, "plausibility_guard", True):
        return _kept_keypoint_result(b, sil, guard)
    ious, masks = _view_ious(vertices, faces, p, names)
    metrics = _refined_metrics(b.metrics, names, p, sil, guard, ious, errs, proj, vertices, params.get("betas"))
    return RigResult(list(names), params, vertices, body.joints[0].numpy().astype(np.float32), kp, sil, metrics, masks)


def refine_rig_fits(model, items, config=None, pose_prior=None, progress: bool = False) -> List[RigResult]:
    """The silhouette stage on rig problems, every view with a mask rendered, from their keypoint fits: ``items``
    are ``(view names, problem, RigFit)`` with equal view counts; the one driver
    (:func:`~silfit.fitting.refine.refine_silhouettes`) with a rig's hooks (:class:`RigRefinement`)."""
    return refine_silhouettes(model, RigRefinement(items), config, pose_prior, progress=progress)


class RigRefinement(SilhouetteHooks):
    """Rig problems' hooks of the one silhouette driver (:func:`~silfit.fitting.refine.refine_silhouettes`):
    ``items`` are ``(view names, problem, RigFit)``; each problem starts from its keypoint fit, every view with a
    mask rendered; read back as a :class:`RigResult` from its keypoint-stage one (before/after, the plausibility
    guard)."""

    def __init__(self, items):
        self.items = list(items)
        self.layout = self.items[0][1].observations[0].keypoints.layout

    def prepare(self, model, config):
        """The keypoint-stage results; a view whose mask misses its keypoint fit's body refused."""
        self.faces = model.faces.cpu().numpy()
        self.before = [keypoint_stage_result(kp, p, names, self.faces) for names, p, kp in self.items]
        _check_masks_overlap(self.items, self.before)
        return config

    def starts(self, config) -> list:
        return [dict(kp.params) for _, _, kp in self.items]

    def inputs(self, model, problems: List[int], config) -> StageInputs:
        """The problems as they are, or the whole-body mesh's inputs (:func:`_silhouette_inputs`)."""
        config, chosen, extra = _silhouette_inputs(model, [self.items[k][1] for k in problems], self.layout, config)
        return StageInputs(chosen, self.layout, config, **extra)

    def read_back(self, model, sils: list, config, seconds: float) -> List[RigResult]:
        """Each problem's :class:`RigResult` (:func:`_refined_rig_result`; the guard reads ``config``)."""
        return [
            _refined_rig_result(model, self.faces, self.layout, config, it, b, sil)
            for it, b, sil in zip(self.items, self.before, sils)
        ]


def __getattr__(name: str):
    """``read_rig_sequence_masks`` moved to :mod:`silfit.inputs.rig` (the fitting core reads no file); the old name
    works for one release."""
    if name == "read_rig_sequence_masks":
        from .._lazy import moved_function

        return moved_function(__name__, name, "silfit.inputs.rig")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
