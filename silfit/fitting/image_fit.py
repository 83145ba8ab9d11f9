"""One image's core below :func:`silfit.run.run` (which :func:`silfit.fit` calls): keypoint
stage, then silhouette stage, batched over images (:func:`fit_problems`); results in memory
(:class:`FitResult`); on disk by the one writer, :func:`silfit.run.write` (:mod:`silfit.outputs.write`;
:func:`silfit.save_fit` for a :class:`FitResult` alone).

Output folder of one image (``silfit fit``)::

    params.npz, params.json    final SMPL parameters (betas, body_pose, global_orient, transl),
                               camera_intrinsics, image_size, vertices, joints, keypoints_2d
    mesh.obj                   the posed body in camera coordinates (OpenCV axes: x right, y down,
                               z forward, metres, the model's vertex order)
    mesh.glb, mesh.ply         with ``exports``: the body upright (x right, y up, z toward the
                               viewer), normals, the camera in the glTF (silfit.outputs.export)
    overlay.png                the final body over the image (or a grey canvas) + keypoints
    side.png                   the final body seen from the side, over the keypoint-stage body
                               (orange) when a silhouette was fitted
    silhouette.png             final silhouette vs the mask (white: both, red: body outside the
                               mask, blue: mask not covered, tan: mask treated as clothing, hair,
                               a leak or another person, not fitted)   [with a mask]
    iou_curve.png              IoU and energy per silhouette step   [with a mask]
    metrics.json               timings per stage, reprojection error, IoU before/after, warnings
    stages/keypoints/          the keypoint stage's params.npz, params.json and overlay.png
    hypotheses/<k>/            with ``--hypotheses K``: the k-th best distinct depth-branch solution
                               (1: the keypoint stage's best), its params.npz/params.json (its energy,
                               gap and the segments it turns in ``record``), mesh.obj; with a mask
                               refined against it, and stages/keypoints/ the keypoint stage's
    hypotheses.png             each hypothesis over the image and from the side   [--hypotheses K]

Everything is written into a temporary folder beside the target and moved into place at
the end, so a failed run leaves nothing half-written.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field, replace
from typing import List, Optional, Sequence, Union

import numpy as np
import torch

from silfit.render.offscreen import render_mask

from .._lazy import moved_function
from ..camera import Camera, project_points
from .keypoint_stage import KeypointFitter
from .result import KeypointFitResult
from .cores import Core, StageFailure, run_steps
from .refine import SilhouetteHooks, StageInputs, refine_silhouettes
from .silhouette_stage import SilhouetteFitConfig, SilhouetteFitResult
from ..io.keypoints import KeypointSet, model_keypoints
from .plausibility import depth_warnings, fit_warnings, guard_fit, hypothesis_summary, label_segments, mask_warnings
from ..eval.metrics import mask_iou
from ..silhouette.losses import clothing_thickness, concave_region, trim_clothing, unknown_regions
from ..silhouette.masks import validate_mask
from .hands_face import silhouette_inputs, wholebody_summary
from .image_depth import cue_from_image
from .problem import Problem

__all__ = [
    "FitResult",
    "fit_problem",
    "fit_problems",
    "StageFailure",
    "refine",
    "refine_batch",
    "ImageCore",
    "ImageRefinement",
    "body_mask",
]


@dataclass
class FitResult:
    """One image's fit: the keypoint stage's result, the silhouette stage's (if a mask was
    given), and the final parameters, mesh and metrics (numpy, no batch dimension)."""

    camera: Camera
    layout: str
    keypoint: KeypointFitResult
    silhouette: Optional[SilhouetteFitResult]
    params: dict
    vertices: np.ndarray
    joints: np.ndarray
    keypoints_2d: np.ndarray
    metrics: dict = field(default_factory=dict)
    #: rendered body masks ``[H, W]`` (bool) of the keypoint stage and of the final body, and ``fitted``: the
    #: mask pixels the silhouette stage fitted as body (not trimmed as clothing, not unknown), when a silhouette
    #: was fitted
    masks: dict = field(default_factory=dict)
    #: with ``--hypotheses K`` (:attr:`KeypointFitResult.hypotheses`), each hypothesis as a fit
    #: (:func:`_hypothesis_outputs`): ``{"rank", "params", "vertices", "keypoints_2d", "keypoint_params", "record"}``;
    #: ``params`` refined against the mask where there is one (``keypoint_params``: the keypoint stage's, else ``None``)
    hypotheses: list = field(default_factory=list)

    @property
    def final(self) -> KeypointFitResult:
        """The final parameters in the keypoint result's form (for saving and loading)."""
        arr = {k: np.asarray(v, dtype=np.float32).reshape(1, -1) for k, v in self.params.items()}  # [1, w] (one image)
        smpl = {k: v for k, v in arr.items() if k in ("betas", "body_pose", "global_orient", "transl")}
        return replace(
            self.keypoint,
            **smpl,
            extra_params={k: v for k, v in arr.items() if k not in smpl},
            vertices=self.vertices[None],
            joints=self.joints[None],
            keypoints_2d=self.keypoints_2d[None],
            reprojection_error=np.array([self.metrics.get("reprojection_error_px", np.nan)]),
        )


def body_mask(vertices: np.ndarray, faces: np.ndarray, camera: Camera) -> np.ndarray:
    """Binary mask of a camera-frame mesh (offscreen rasteriser, pixel-centre coverage)."""
    return render_mask(vertices, faces, camera)


def _pose(model, params: dict, layout: str, camera: Camera):
    t = {k: torch.as_tensor(np.asarray(v), dtype=model.dtype).reshape(1, -1) for k, v in params.items()}
    with torch.no_grad():
        out = model(**t)
        kp2d = project_points(model_keypoints(model, out, layout)[0], camera)
    return out.vertices[0].numpy(), out.joints[0].numpy(), kp2d.numpy()


def _run_record(keypoint_result: KeypointFitResult, silhouette: Optional[SilhouetteFitResult] = None) -> dict:
    """Each stage's term energies and the run's configuration, for ``metrics.json``."""
    terms = {
        f"keypoints.{stage}": {t: float(v[0]) for t, v in d.items()}
        for stage, d in keypoint_result.term_energies.items()
    }
    config = {"keypoint_stage": keypoint_result.config}
    if silhouette is not None:
        terms["silhouette"] = dict(silhouette.terms)
        config["silhouette_stage"] = silhouette.config
    return {"energy_terms": terms, "config": config}


def _stage_seconds(timings: dict) -> float:
    """A stage's seconds: its ``total`` where it records one, else the sum of its parts."""
    return float(timings["total"]) if "total" in timings else float(sum(timings.values()))


def _median_reprojection(kp2d: np.ndarray, keypoints: KeypointSet) -> float:
    err = np.linalg.norm(kp2d - keypoints.xy, axis=1)
    return float(np.median(err[keypoints.conf > 0]))


def _trimmed_masks(masks, body_masks, cfg: SilhouetteFitConfig, sources, known=None):
    """``(masks for the stage, notes per mask)``: a mask reaching beyond the keypoint fit's body
    all around (clothing) trimmed by that thickness (``SilhouetteFitConfig.trim_clothing``), unless
    that leaves none of its pixels the caller's ``known`` trusts (per mask; ``None``: all)."""
    out, notes, trimmed = [], [], []
    for mask, body, source, seen in zip(masks, body_masks, sources, known or [None] * len(masks)):
        ys, xs = np.nonzero(mask)
        extent = float(max(np.ptp(ys), np.ptp(xs))) if len(ys) else 0.0
        upper = cfg.mask.trim_upper
        quantiles = (float(cfg.mask.trim_quantile),) + (() if upper is None else (float(upper),))
        t, *deeper = clothing_thickness(mask, body, quantiles) if cfg.mask.trim_clothing and extent > 0 else (0.0,)
        trimmed.append(t > cfg.mask.trim_min * extent)
        if not trimmed[-1]:
            out.append(mask)
            notes.append([])
            continue
        if deeper and deeper[0] - t <= float(cfg.mask.trim_upper_max) * extent:  # an even layer: the upper quantile
            t = max(t, deeper[0])
        t = min(t, cfg.mask.trim_max * extent)
        out.append(trim_clothing(mask, t))
        if seen is not None and not (out[-1] & np.asarray(seen, dtype=bool)).any():  # nothing left to fit
            out[-1], trimmed[-1] = mask, False
            notes.append([])
            continue
        notes.append(
            [
                f"{source}: the mask reaches about {t:.0f} px beyond the keypoint fit's body all around (loose "
                "clothing, hair or a grown mask?): the silhouette stage fitted it trimmed by that much"
            ]
        )
    return out, notes, trimmed


def _known_pixels(masks, body_masks, cfg: SilhouetteFitConfig, sources, notes, trimmed) -> list:
    """Per mask, the pixels whose value the silhouette stage trusts (``None``: all): leaks far from
    the keypoint fit's body, small holes it covers and the concavities of its body are unknown
    (``SilhouetteFitConfig.leak_distance``, ``hole_fraction``, ``hole_covered``, ``concave_radius``: only for the
    masks ``trimmed`` as clothing with ``concave_trimmed_only``); a note in ``notes`` where a leak is set aside."""
    out = []
    for mask, body, source, note, cloth in zip(masks, body_masks, sources, notes, trimmed):
        ys, xs = np.nonzero(mask)
        extent = float(max(np.ptp(ys), np.ptp(xs))) if len(ys) else 0.0
        concave = float(cfg.mask.concave_radius) * extent
        if cfg.mask.concave_trimmed_only and not cloth:
            concave = 0.0
        known = unknown_regions(
            mask,
            body,
            float(cfg.mask.leak_distance) * extent,
            float(cfg.mask.hole_fraction),
            concave,
            float(cfg.mask.hole_covered),
        )
        far = 0 if known is None else int(np.count_nonzero(mask & ~known & ~concave_region(body, concave)))
        if far > 0.02 * len(ys):
            note.append(
                f"{source}: {100 * far / len(ys):.0f} % of the mask lies far from the keypoint fit's body (a leak "
                "into an object or the background?): the silhouette stage ignored it"
            )
        out.append(known)
    return out


def _guard(model, start: dict, params: dict, keypoints: KeypointSet, camera: Camera, kp2d: np.ndarray, where: str):
    """:func:`~silfit.fitting.plausibility.guard_fit` of one refined fit against the keypoint fit ``start`` it
    began from (median reprojection error, |betas|, stature)."""
    _, _, kp2d_start = _pose(model, start, keypoints.layout, camera)
    return guard_fit(
        model,
        _median_reprojection(kp2d_start, keypoints),
        start.get("betas"),
        _median_reprojection(kp2d, keypoints),
        params.get("betas"),
        where,
    )


def _choose_hypothesis(
    model, sils, starts, keypoints: KeypointSet, camera: Camera, where: str, guard: bool = True, margin: float = 0.0
) -> tuple:
    """``(index, record)``: which of one image's hypotheses, each refined by the silhouette stage (``sils``, from
    ``starts``; the keypoint fit first), is kept: the lowest final energy of the stage
    (:attr:`~silfit.fitting.silhouette_stage.SilhouetteFitResult.final_energy`) among those that ran to the
    last level without failing (energies of different resolutions do not compare), where it is more than ``margin``
    (relative) below the keypoint fit's (a keypoint fit whose energy does not compare is not held by it), unless the
    plausibility guard (``guard``) finds it less plausible than its own start or than the keypoint fit (then the
    keypoint fit's, as without hypotheses). ``record`` (``metrics.json``'s ``hypotheses_silhouette``; ``{}`` for one
    hypothesis): each one's final energy (``None``: not comparable) and IoU, the kept rank, its energy's gap below the
    keypoint fit's, ``guard_reverted``: the rank the guard set aside, if any, and ``margin_held``: the rank whose
    energy was lowest but not lower than the keypoint fit's by more than ``margin``
    (``SilhouetteFitConfig.choice_margin``, relative), if any: then the keypoint fit's branch is kept. A person mask
    hardly sees a limb mirrored in depth, yet on generated hard sets the branch that refines lowest against it is
    the better choice (on library poses only beyond ``margin``)
    (``benchmarks/bench_hypothesis_silhouette.py``; the numbers: docs/benchmarks/defaults.md)."""
    if len(sils) == 1:
        return 0, {}
    last = max((s.final_level for s in sils if s.final_level is not None), default=None)
    energies = [
        s.final_energy if (not s.failed and s.final_level == last and np.isfinite(s.final_energy)) else None
        for s in sils
    ]
    c = min(range(len(sils)), key=lambda k: (np.inf if energies[k] is None else energies[k], k))
    reverted = held = None
    if c and energies[0] is not None and energies[0] - energies[c] <= float(margin) * abs(energies[0]):
        c, held = 0, c + 1
    if c and guard:
        params = sils[c].params()
        _, _, kp2d = _pose(model, params, keypoints.layout, camera)
        if any(_guard(model, s, params, keypoints, camera, kp2d, where).reverted for s in (starts[c], starts[0])):
            c, reverted = 0, c + 1
    gap = (energies[0] - energies[c]) / abs(energies[0]) if energies[0] and energies[c] is not None else 0.0
    return c, {
        "energies": energies,
        "iou": [float(s.iou_end) for s in sils],
        "kept": c + 1,
        "gap": float(gap),
        "guard_reverted": reverted,
        "margin_held": held,
    }


def _hypothesis_outputs(
    model,
    hypotheses: list,
    keypoints: KeypointSet,
    camera: Camera,
    refined=None,
    choice: Optional[dict] = None,
    kept: Optional[int] = 1,
    where: str = "mask",
    guard: bool = True,
) -> list:
    """One image's ``--hypotheses K`` solutions (``hypotheses``: :attr:`KeypointFitResult.hypotheses`' entry) as fits,
    for :attr:`FitResult.hypotheses` (:func:`silfit.run.write` writes them to ``hypotheses/<rank>/``): each one's parameters
    posed, with ``record``: :func:`~silfit.fitting.plausibility.hypothesis_summary`'s row, ``kept`` (whether the final fit
    came from it: rank ``kept``; ``None``: none) and ``params_from`` (which stage's parameters these are).

    With ``refined`` (per hypothesis, the silhouette stage's result from it) and ``choice`` (:func:`_choose_hypothesis`'s
    record), each is the refined one with the stage's final energy and window IoU in its record, unless the
    plausibility guard (``guard``: ``SilhouetteFitConfig.plausibility_guard``) finds it less plausible than its own
    keypoint fit: then that, as for the fit itself (the kept one holds the final fit either way), and the discarded
    refinement's energy and IoU under ``silhouette_discarded``. ``keypoint_params``: the keypoint stage's (with
    ``refined``; else ``None``)."""
    out = []
    for k, (h, row) in enumerate(zip(hypotheses, hypothesis_summary(hypotheses))):
        start = {n: np.asarray(v) for n, v in h["params"].items()}
        params, record = start, {**row, "kept": row["rank"] == kept, "params_from": "keypoint stage"}
        if refined is not None:
            params = refined[k].params()
            record.update(
                params_from="silhouette stage", silhouette_energy=choice["energies"][k], silhouette_iou=choice["iou"][k]
            )
        vertices, _, kp2d = _pose(model, params, keypoints.layout, camera)
        if refined is not None and guard and _guard(model, start, params, keypoints, camera, kp2d, where).reverted:
            params, record["params_from"] = start, "keypoint stage (the silhouette stage's was less plausible)"
            record["silhouette_discarded"] = {
                "energy": record.pop("silhouette_energy"),
                "iou": record.pop("silhouette_iou"),
            }
            vertices, _, kp2d = _pose(model, params, keypoints.layout, camera)
        out.append(
            {
                "rank": row["rank"],
                "params": params,
                "vertices": vertices,
                "keypoints_2d": kp2d,
                "record": record,
                "keypoint_params": None if refined is None else start,
            }
        )
    return out


def _offered_alternatives(keypoint_result: KeypointFitResult, config: SilhouetteFitConfig) -> list:
    """Per sample, the keypoint stage's alternatives the silhouette stage refines too: with ``--hypotheses K``
    every one after the fit, else (:attr:`~silfit.fitting.KeypointFitResult.alternatives`) the branches refined to
    the end within ``config.alternatives_margin`` of the fit's final energy, closest first, at most
    ``config.alternatives_max`` (none with a margin of 0)."""
    n = len(keypoint_result)
    if keypoint_result.hypotheses is not None:
        return [list((h or [])[1:]) for h in keypoint_result.hypotheses]
    margin, most = float(getattr(config, "alternatives_margin", 0.0)), int(getattr(config, "alternatives_max", 0))
    if margin <= 0 or most <= 0 or keypoint_result.alternatives is None:
        return [[] for _ in range(n)]
    return [
        sorted((a for a in alts or [] if a["gap"] <= margin), key=lambda a: a["gap"])[:most]
        for alts in keypoint_result.alternatives
    ]


def _mask_choice_warning(hypotheses: bool, alternative: dict, c: int, choice: dict) -> str:
    """The warning of a fit whose depth branch the mask chose over the keypoint stage's: ``alternative`` (one of
    ``--hypotheses K``'s, ``hypotheses``, as ``hypotheses/<c + 1>``, or one of the close alternatives, named by the
    limbs it turns)."""
    if hypotheses:
        which = f"hypothesis {c + 1} (hypotheses/{c + 1})"
        prefer = "preferred hypothesis 1"
    else:
        turned = (
            ", ".join(alternative.get("differs") or label_segments(alternative["label"]))
            or "no limb by more than 45 deg"
        )
        which = (
            f"the keypoint stage's alternative turning {turned} (keypoint-stage energy {alternative['gap']:+.1%} "
            "against its fit)"
        )
        prefer = "preferred its fit"
    return (
        f"depth branch chosen by the mask: {which}, refined against the mask, ends {choice['gap']:.1%} below the "
        f"keypoint fit's silhouette-stage energy; the keypoint stage {prefer}: check a side view"
    )


def refine(
    model,
    keypoint_result: KeypointFitResult,
    keypoints: KeypointSet,
    mask: np.ndarray,
    config: Optional[SilhouetteFitConfig] = None,
    pose_prior=None,
    renderer=None,
    progress: bool = False,
    mask_source: str = "mask",
    known: Optional[np.ndarray] = None,
) -> FitResult:
    """The silhouette stage on top of a single-sample keypoint result (see :func:`silfit.run.fit`)."""
    return refine_batch(
        model, keypoint_result, [keypoints], [mask], config, pose_prior, renderer, progress, [mask_source], [known]
    )[0]


def _keypoint_fit_masks(keypoint_result, masks, mask_sources, faces) -> tuple:
    """``(masks, IoUs)`` of the keypoint fits' bodies against the checked ``masks``; a mask that does not overlap its
    body at all is refused (a wrong mask, or another image's keypoints)."""
    kp_masks, ious_before = [], []
    for i in range(len(masks)):
        camera = keypoint_result.cameras[i]
        validate_mask(masks[i], mask_sources[i], size=(camera.width, camera.height))
        kp_masks.append(body_mask(keypoint_result.vertices[i], faces, camera))
        ious_before.append(mask_iou(kp_masks[i], masks[i]))
        if ious_before[i] == 0.0:
            raise ValueError(
                f"{mask_sources[i]}: the mask does not overlap the body fitted to the keypoints at all "
                "(wrong mask, or keypoints of another image?)"
            )
    return kp_masks, ious_before


def _alternative_rows(offered, inits: list) -> tuple:
    """``(rows, candidates)``: the batch's problems, each image's own first, then its ``offered`` alternatives (their
    starts appended to ``inits``); ``candidates[i]``: image ``i``'s problems, the keypoint fit first."""
    n = len(offered)
    rows, candidates = list(range(n)), [[i] for i in range(n)]
    for i, hyps in enumerate(offered):
        for h in hyps:
            candidates[i].append(len(rows))
            rows.append(i)
            inits.append({k: np.asarray(v) for k, v in h["params"].items()})
    return rows, candidates


def _refined_metrics(
    one, sil, seconds: float, kp2d, keypoints, ious: tuple, guard, guarded: bool, warnings: list, choice
) -> dict:
    """An image's ``metrics.json`` after the silhouette stage: timings, reprojection errors and IoUs before and after
    (``ious``), the stage's steps, the guard's findings (what it kept: the silhouette stage's result where it is off,
    ``guarded`` false), warnings, the hypotheses' choice and the run record."""
    return {
        "stages": ["keypoints", "silhouette"],
        "timings_s": {
            **{f"keypoints.{k}": float(v) for k, v in one.timings.items()},
            "keypoints": _stage_seconds(one.timings),
            "silhouette": seconds,
        },
        "reprojection_error_px_keypoint_stage": float(one.reprojection_error[0]),
        "reprojection_error_px": _median_reprojection(kp2d, keypoints),
        "iou_keypoint_stage": ious[0],
        "iou": ious[1],
        "silhouette_steps": sil.steps,
        "silhouette_guard": {"kept": guard.keep if guarded else "silhouette", "less_plausible": list(guard.reasons)},
        "warnings": warnings,
        **({"hypotheses_silhouette": choice} if choice else {}),
        **_run_record(one, sil),
    }


def _apply_guard(model, start, init, params, posed, keypoints, camera, mask_source, guarded: bool, kp_mask, warnings):
    """The plausibility guard (:func:`silfit.fitting.plausibility.silhouette_guard`) on one refined fit: where it is less
    plausible than the keypoint fit it started from (and the guard is on), the keypoint fit ``init`` replaces it, with
    the guard's warnings appended to ``warnings``. Returns ``(guard, params, (vertices, joints, kp2d), final mask)``."""
    vertices, joints, kp2d = posed
    guard = _guard(model, start, params, keypoints, camera, kp2d, mask_source)
    if guard.reverted and guarded:
        params = {k: np.asarray(v) for k, v in init.items()}
        vertices, joints, kp2d = _pose(model, params, keypoints.layout, camera)
        warnings += list(guard.warnings)
    final_mask = kp_mask if guard.reverted and guarded else body_mask(vertices, model.faces.cpu().numpy(), camera)
    return guard, params, (vertices, joints, kp2d), final_mask


def refine_batch(
    model,
    keypoint_result: KeypointFitResult,
    keypoints: Sequence[KeypointSet],
    masks: Sequence[np.ndarray],
    config: Optional[SilhouetteFitConfig] = None,
    pose_prior=None,
    renderer=None,
    progress: bool = False,
    mask_sources: Optional[Sequence[str]] = None,
    known: Optional[Sequence[Optional[np.ndarray]]] = None,
) -> List[FitResult]:
    """The silhouette stage on a batch of keypoint results (sample ``i`` of ``keypoint_result`` with ``keypoints[i]``
    and ``masks[i]``): the one driver (:func:`~silfit.fitting.refine.refine_silhouettes`) with an image's hooks
    (:class:`ImageRefinement`)."""
    hooks = ImageRefinement(keypoint_result, keypoints, masks, mask_sources, known)
    return refine_silhouettes(model, hooks, config, pose_prior, renderer, progress)


def _free_ratio(config) -> Optional[float]:
    """The two-pass refit's ratio (``SilhouetteFitConfig.trust.free_ratio``; ``None``: one pass, as for a config
    without a trust region)."""
    return getattr(getattr(config, "trust", None), "free_ratio", None)


class ImageRefinement(SilhouetteHooks):
    """An image batch's hooks of the one silhouette driver (:func:`~silfit.fitting.refine.refine_silhouettes`): all
    subjects refined together, each with the keypoint stage's alternatives it offers (:func:`_offered_alternatives`:
    ``--hypotheses K``'s, else the close ones) as more problems of the batch; per image the lowest final energy is
    kept where it is more than ``choice_margin`` below the keypoint fit's (:func:`_choose_hypothesis`). ``known``:
    per image, the mask's pixels whose value is trusted (``None``: all; e.g. not the other people's, issue 55),
    joined to those the stage sets aside itself (leaks, holes, concavities). With
    ``SilhouetteFitConfig.trust.free_ratio``, two passes: first with the trust region before issue 55
    (:meth:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig.free_pass`), then the images that pass dragged off
    their keypoints (:func:`_dragged_images`), all their problems, with the trust region of the settings."""

    def __init__(self, keypoint_result: KeypointFitResult, keypoints, masks, mask_sources=None, known=None):
        n = len(keypoints)
        if len(keypoint_result) != n or len(masks) != n:
            raise ValueError(f"{len(keypoint_result)} keypoint results, {n} keypoint sets and {len(masks)} masks")
        self.keypoint_result, self.keypoints, self.known = keypoint_result, keypoints, known
        self.mask_sources = list(mask_sources or ["mask"] * n)
        self.masks = [np.asarray(m, dtype=bool) for m in masks]

    def prepare(self, model, config: SilhouetteFitConfig) -> SilhouetteFitConfig:
        """The masks per image (:func:`_batch_masks`)."""
        self.masks_of = _batch_masks(
            self.keypoint_result, self.masks, self.mask_sources, config, self.known, model.faces.cpu().numpy()
        )
        return config

    def starts(self, config: SilhouetteFitConfig) -> list:
        """The keypoint fits, then the alternatives they offer (issue 25; :func:`_alternative_rows`)."""
        self.inits = [self.keypoint_result.params(i) for i in range(len(self.keypoints))]
        self.offered = _offered_alternatives(self.keypoint_result, config)
        self.rows, self.candidates = _alternative_rows(self.offered, self.inits)
        self.passes = [{} for _ in self.candidates]
        return self.inits

    def inputs(self, model, problems: List[int], config: SilhouetteFitConfig) -> StageInputs:
        """Each problem with its image's mask and known pixels; the layout decides the terms (a whole-body mesh keeps
        its hand and face keypoints)."""
        _, ious_before, fit_masks, _, known, trimmed = self.masks_of
        rows, cameras = [self.rows[k] for k in problems], self.keypoint_result.cameras
        cfg, sets, terms, weights, data = silhouette_inputs(
            model, [self.keypoints[r] for r in rows], config, model.dtype
        )
        problems = [
            Problem.single(k, cameras[r], fit_masks[r], known[r], _cover_inner(config, trimmed[r], ious_before[r]))
            for k, r in zip(sets, rows)
        ]
        return StageInputs(problems, self.keypoints[0].layout, cfg, terms, weights, data)

    def first_pass(self, config: SilhouetteFitConfig) -> SilhouetteFitConfig:
        return config if _free_ratio(config) is None else config.free_pass()

    def refit(self, model, sils: list, config: SilhouetteFitConfig) -> List[int]:
        """With ``trust.free_ratio``: the problems of the images the free pass dragged off their keypoints."""
        if _free_ratio(config) is None:
            return []
        cameras = self.keypoint_result.cameras
        redo = _dragged_images(model, self.keypoints, cameras, self.candidates, self.inits, sils, config, self.passes)
        return [k for k, r in enumerate(self.rows) if r in redo]

    def refitted(self, problems: List[int], first: list) -> None:
        for k, sil in zip(problems, first):
            self.passes[self.rows[k]]["free_pass_seconds"] = (
                self.passes[self.rows[k]].get("free_pass_seconds", 0.0) + sil.seconds
            )

    def read_back(self, model, sils: list, config: SilhouetteFitConfig, seconds: float) -> List[FitResult]:
        """Per image its :class:`FitResult` (:class:`_RefinedBatch`), with the two passes' record."""
        guarded = getattr(config, "plausibility_guard", True)
        batch = _RefinedBatch(
            model,
            self.keypoint_result,
            self.keypoints,
            self.masks,
            self.mask_sources,
            guarded,
            self.masks_of,
            self.inits,
            self.offered,
            self.candidates,
            sils,
            float(getattr(config, "choice_margin", 0.0)),
        )
        return [_with_passes(batch.result(i), self.passes[i]) for i in range(len(self.keypoints))]


def _dragged_images(model, keypoints, cameras, candidates: list, inits: list, sils: list, config, passes: list) -> set:
    """The two-pass refit's images to refit with the trust region (``SilhouetteFitConfig.trust.free_ratio``): those
    whose free pass's kept candidate (:func:`_choose_hypothesis`, of ``sils``) ends with a median reprojection error
    above ``trust.free_ratio`` times their keypoint fit's (``inits[i]``); each image's errors recorded in
    ``passes[i]``."""
    redo = set()
    for i, rows in enumerate(candidates):
        k, camera = keypoints[i], cameras[i]
        guard = getattr(config, "plausibility_guard", True)
        margin = float(getattr(config, "choice_margin", 0.0))
        c, _ = _choose_hypothesis(
            model, [sils[r] for r in rows], [inits[r] for r in rows], k, camera, "mask", guard, margin
        )
        before = _median_reprojection(_pose(model, inits[i], k.layout, camera)[2], k)
        after = _median_reprojection(_pose(model, sils[rows[c]].params(), k.layout, camera)[2], k)
        refit = after > float(config.trust.free_ratio) * before
        passes[i].update(
            free_pass_reprojection_px=after, keypoint_stage_reprojection_px=before, refit_with_trust_region=refit
        )
        if refit:
            redo.add(i)
    return redo


def _with_passes(result: FitResult, passes: dict) -> FitResult:
    """``result`` with the two-pass refit's record (:func:`_dragged_images`) in its metrics (``silhouette_passes``),
    the free pass's seconds added to the stage's where the image was refitted; unchanged without it."""
    if passes:
        result.metrics["silhouette_passes"] = {k: v for k, v in passes.items() if k != "free_pass_seconds"}
        result.metrics["timings_s"]["silhouette"] += passes.get("free_pass_seconds", 0.0)
    return result


def _cover_inner(config: SilhouetteFitConfig, trimmed: bool, iou_before: float) -> Optional[float]:
    """A mask's own ``cover_inner`` (``Observation.cover_inner``; ``None``: the config's): ``mask.untrimmed_inner``
    for a mask the clothing trim ran on and left whole, which the keypoint fit's body already matches (IoU at least
    ``mask.whole_iou``): the body's own silhouette, nothing near its edge to forgive."""
    m = config.mask
    whole = m.trim_clothing and not trimmed and float(iou_before) >= float(m.whole_iou)
    return m.untrimmed_inner if whole else None


def _batch_masks(keypoint_result, masks: list, mask_sources: list, config, known, faces) -> tuple:
    """:class:`ImageRefinement`'s masks per image: ``(kp_masks, ious_before, fit_masks, trim_notes, known,
    trimmed)``, the keypoint fit's rendered masks and their IoUs with ``masks``, the masks fitted (trimmed) and the
    trim's notes, the pixels whose value is trusted (the stage's own, joined to the caller's ``known``; ``None``:
    all) and whether each mask was trimmed as clothing."""
    n = len(masks)
    kp_masks, ious_before = _keypoint_fit_masks(keypoint_result, masks, mask_sources, faces)
    fit_masks, trim_notes, trimmed = _trimmed_masks(masks, kp_masks, config, mask_sources, known)
    own = _known_pixels(fit_masks, kp_masks, config, mask_sources, trim_notes, trimmed)
    known = [
        k if g is None else (np.asarray(g, dtype=bool) if k is None else k & np.asarray(g, dtype=bool))
        for k, g in zip(own, list(known) if known is not None else [None] * n)
    ]
    return kp_masks, ious_before, fit_masks, trim_notes, known, trimmed


class _RefinedBatch:
    """:class:`ImageRefinement`'s batch after the silhouette stage: per image its inputs, masks (``masks_of``:
    ``(kp_masks, ious_before, fit_masks, trim_notes, known, trimmed)``, :func:`_batch_masks`) and its candidates'
    refined fits (``candidates[i]``: the rows of ``inits`` and ``sils``, its start first, then the ``offered``
    alternatives); :meth:`result` makes an image's :class:`FitResult`."""

    def __init__(
        self,
        model,
        keypoint_result,
        keypoints,
        masks,
        mask_sources,
        guarded: bool,
        masks_of: tuple,
        inits,
        offered,
        candidates,
        sils,
        choice_margin: float = 0.0,
    ):
        self.model, self.keypoint_result, self.keypoints = model, keypoint_result, keypoints
        self.choice_margin = choice_margin
        self.masks, self.mask_sources, self.guarded, self.cameras = (
            masks,
            mask_sources,
            guarded,
            keypoint_result.cameras,
        )
        self.kp_masks, self.ious_before, self.fit_masks, self.trim_notes, self.known, _ = masks_of
        self.inits, self.offered, self.candidates, self.sils = inits, offered, candidates, sils

    def result(self, i: int) -> FitResult:
        """Image ``i``'s fit: its candidate with the lowest final energy (beyond ``choice_margin``), under the
        plausibility guard."""
        model, keypoints, cameras, masks = self.model, self.keypoints, self.cameras, self.masks
        kr, candidates, inits, sils = self.keypoint_result, self.candidates, self.inits, self.sils
        one = kr[i]
        c, choice = self.choose(i)
        sil, start = sils[candidates[i][c]], inits[candidates[i][c]]
        params = sil.params()
        vertices, joints, kp2d = _pose(model, params, keypoints[i].layout, cameras[i])
        warnings = mask_warnings(masks[i], self.mask_sources[i]) + self.trim_notes[i] + list(sil.warnings)
        if c:
            warnings.append(_mask_choice_warning(kr.hypotheses is not None, self.offered[i][c - 1], c, choice))
        guard, params, (vertices, joints, kp2d), final_mask = _apply_guard(
            model,
            start,
            inits[i],
            params,
            (vertices, joints, kp2d),
            keypoints[i],
            cameras[i],
            self.mask_sources[i],
            self.guarded,
            self.kp_masks[i],
            warnings,
        )
        iou_after = mask_iou(final_mask, masks[i])
        if iou_after < self.ious_before[i] - 0.02:
            warnings.append(
                f"silhouette stage lowered the IoU ({self.ious_before[i]:.3f} -> {iou_after:.3f}); kept its result"
            )
        metrics = _refined_metrics(
            one,
            sil,
            float(sum(sils[k].seconds for k in candidates[i])),
            kp2d,
            keypoints[i],
            (self.ious_before[i], iou_after),
            guard,
            self.guarded,
            warnings,
            choice,
        )
        hypotheses = self.hypotheses(i, c, choice, sil)
        fitted = self.fit_masks[i] if self.known[i] is None else self.fit_masks[i] & self.known[i]
        return FitResult(
            cameras[i],
            keypoints[i].layout,
            one,
            sil,
            params,
            vertices,
            joints,
            kp2d,
            metrics,
            masks={"keypoint_stage": self.kp_masks[i], "final": final_mask, "fitted": fitted},
            hypotheses=hypotheses,
        )

    def choose(self, i: int) -> tuple:
        """``(c, choice)``: image ``i``'s candidate kept (:func:`_choose_hypothesis`) and the choice's record (with
        the close alternatives offered, where no ``--hypotheses K`` gave them)."""
        c, choice = _choose_hypothesis(
            self.model,
            [self.sils[k] for k in self.candidates[i]],
            [self.inits[k] for k in self.candidates[i]],
            self.keypoints[i],
            self.cameras[i],
            self.mask_sources[i],
            self.guarded,
            self.choice_margin,
        )
        if choice and self.keypoint_result.hypotheses is None:  # the close alternatives: which branches were refined
            choice["alternatives"] = [
                {
                    "label": a["label"],
                    "differs": list(a.get("differs") or []),
                    "gap": float(a["gap"]),
                    "max_shift_mm": a.get("max_shift_mm"),
                }
                for a in self.offered[i]
            ]
        return c, choice

    def hypotheses(self, i: int, c: int, choice, sil) -> list:
        """--hypotheses K: image ``i``'s each one refined, for hypotheses/<k>/; the final fit came from hypothesis
        ``c + 1`` (its refinement ``sil``, or where the guard turned it back its keypoint fit: the same guard,
        hypotheses/<c + 1> holds it too). Without: none."""
        if self.keypoint_result.hypotheses is None:
            return []
        return _hypothesis_outputs(
            self.model,
            self.keypoint_result.hypotheses[i] or [],
            self.keypoints[i],
            self.cameras[i],
            [self.sils[k] for k in self.candidates[i]],
            choice or {"energies": [sil.final_energy], "iou": [float(sil.iou_end)]},
            c + 1,
            self.mask_sources[i],
            self.guarded,
        )


def fit_problem(
    model, keypoints: KeypointSet, camera: Camera, mask: Optional[np.ndarray] = None, **options
) -> FitResult:
    """One image's core (:func:`fit_problems` for one image; a failure raises)."""
    (result,) = fit_problems(model, [keypoints], [camera], [mask], **options)
    if isinstance(result, Exception):
        raise result
    return result


_LAST_FITTER: list = []  # [(model, layout, config, pose prior), fitter]: the last fit_problems' fitter


def _keypoint_fitter(model, layout: str, config, pose_prior) -> KeypointFitter:
    """A :class:`KeypointFitter`, the previous call's where model, layout, settings and prior are
    the same (``fit-dataset`` fits batch after batch with them: building one costs its keypoint
    body's reductions, docs/benchmarks/defaults.md; a fitter holds no state from one fit to the next,
    so the fits are the same)."""
    if _LAST_FITTER:
        (m, lay, cfg, prior), fitter = _LAST_FITTER
        if m is model and lay == layout and prior is pose_prior and cfg == config:  # settings by value (a copy)
            return fitter
    fitter = KeypointFitter(model, layout, config, pose_prior)
    _LAST_FITTER[:] = [(model, layout, copy.deepcopy(config), pose_prior), fitter]
    return fitter


def _add_records(model, whole_body: bool, result: FitResult, keypoints: KeypointSet, cue, cue_record) -> None:
    """An image's fit's records and warnings, into its ``metrics``: the whole body's fitted parts, the image depth
    cue, the plausibility and depth-ambiguity warnings (limbs the image ``cue`` decides are not named), the branch
    search and the hypotheses (posed for ``hypotheses/<k>/`` where no silhouette stage refined them)."""
    if whole_body:  # which parts were fitted, which held at rest
        result.metrics["whole_body"], notes = wholebody_summary(keypoints)
        result.metrics["warnings"] = notes + result.metrics.get("warnings", [])
    hyps = (result.keypoint.hypotheses or [None])[0]
    search = (result.keypoint.branch_search or [None])[0]
    result.metrics["image_depth"] = cue_record
    decided = cue.decided() if cue is not None else ()
    result.metrics["warnings"] += fit_warnings(
        result.metrics, keypoints, result.vertices, result.params.get("betas")
    ) + depth_warnings(search, hyps, decided=decided)
    if search:  # every hypothesis the branch search ran to its end, with its energy
        result.metrics["branch_search"] = search
    if hyps is not None:  # hypotheses=K: every alternative's energy and the limbs it turns (metrics.json)
        result.metrics["hypotheses"] = hypothesis_summary(hyps)
        if not result.hypotheses:  # no silhouette stage: the keypoint stage's, posed (hypotheses/<k>/)
            result.hypotheses = _hypothesis_outputs(model, hyps, keypoints, result.camera)


def fit_problems(
    model,
    keypoints: Sequence[KeypointSet],
    cameras: Sequence[Camera],
    masks: Sequence[Optional[np.ndarray]],
    *,
    pose_prior=None,
    keypoint_config=None,
    silhouette_config=None,
    silhouette: bool = True,
    progress: bool = False,
    mask_sources: Optional[Sequence[str]] = None,
    isolate: bool = False,
    images: Optional[Sequence[Optional[np.ndarray]]] = None,
    people: Optional[Sequence] = None,
    known: Optional[Sequence[Optional[np.ndarray]]] = None,
) -> List[Union[FitResult, StageFailure]]:
    """Images' cores, keypoints already checked (:func:`silfit.run.check`), one layout: the steps of every fit
    (:func:`~silfit.fitting.cores.run_steps`) on an :class:`ImageCore`: the keypoint stage batched over all images,
    the silhouette stage batched over those with a mask (and ``silhouette``; ``known``: per image, the mask's pixels
    whose value is trusted, ``None``: all), each image's plausibility warnings
    (:func:`silfit.fitting.plausibility.fit_warnings`, depth ambiguity). With ``isolate``, a failing
    batch is fitted again image by image, and an image that still fails gets a
    :class:`StageFailure` in its place; without, the first error raises.

    ``images`` (per image an RGB array or ``None``): the image depth cue
    (:func:`~silfit.fitting.image_depth.cue_from_image`; ``people``: per image the detection its keypoints
    came from, reused) joins the keypoint stage where the settings' ``image_depth.weight`` or ``image_depth.decide`` is on;
    ``metrics.json``'s ``image_depth`` says what it decided (``"none"`` without an image)."""
    core = ImageCore(
        model,
        keypoints,
        cameras,
        masks,
        pose_prior=pose_prior,
        keypoint_config=keypoint_config,
        silhouette_config=silhouette_config,
        silhouette=silhouette,
        progress=progress,
        mask_sources=mask_sources,
        images=images,
        people=people,
        known=known,
    )
    return run_steps(core, isolate)


class ImageCore(Core):
    """Images of one layout, model and settings (:func:`fit_problems`' arguments) as the core of
    :func:`~silfit.fitting.cores.run_steps`: the keypoint stage batched (:class:`KeypointFitter`, with each
    image's depth cue), the silhouette stage on the images with a mask, refined as one per keypoint batch
    (:class:`ImageRefinement`), a :class:`FitResult` per image with its records (:func:`_add_records`)."""

    isolates_stages = True

    def __init__(
        self,
        model,
        keypoints: Sequence[KeypointSet],
        cameras: Sequence[Camera],
        masks: Sequence[Optional[np.ndarray]],
        *,
        pose_prior=None,
        keypoint_config=None,
        silhouette_config=None,
        silhouette: bool = True,
        progress: bool = False,
        mask_sources: Optional[Sequence[str]] = None,
        images: Optional[Sequence[Optional[np.ndarray]]] = None,
        people: Optional[Sequence] = None,
        known: Optional[Sequence[Optional[np.ndarray]]] = None,
    ):
        n = len(keypoints)
        self.model, self.keypoints, self.cameras, self.masks, self.size = model, keypoints, cameras, masks, n
        self.mask_sources, self.known = list(mask_sources or ["mask"] * n), known
        self.silhouette_config, self.silhouette, self.progress = silhouette_config, silhouette, progress
        self.fitter = _keypoint_fitter(model, keypoints[0].layout, keypoint_config, pose_prior)
        self.pose_prior = self.fitter.pose_prior
        self.cues, self.cue_records = _depth_cues(self.fitter, keypoints, images, people)

    def keypoint_stage(self, rows: list) -> list:
        """Per row: (the batch's result, its index there); timings shared out."""
        kp = self.fitter.fit(
            [self.keypoints[i] for i in rows],
            [self.cameras[i] for i in rows],
            progress=self.progress,
            depth_cues=[self.cues[i] for i in rows],
        )
        kp.timings = {k: float(v) / len(rows) for k, v in kp.timings.items()}
        return [(kp, j) for j in range(len(rows))]

    def silhouette_rows(self, rows: list, kp: dict) -> list:
        return [i for i in rows if self.masks[i] is not None and self.silhouette]

    def silhouette_hooks(self, rows: list, kp: dict):
        """Rows fitted in one keypoint batch (``kp``: :meth:`keypoint_stage`'s) are refined as one
        (:class:`ImageRefinement`)."""
        groups: dict = {}
        for i in rows:
            groups.setdefault(id(kp[i][0]), []).append(i)
        for group in groups.values():
            batch = kp[group[0]][0].select([kp[i][1] for i in group])
            yield (
                group,
                ImageRefinement(
                    batch,
                    [self.keypoints[i] for i in group],
                    [np.asarray(self.masks[i], dtype=bool) for i in group],
                    [self.mask_sources[i] for i in group],
                    None if self.known is None else [self.known[i] for i in group],
                ),
            )

    def results(self, kp: dict, refined: dict) -> list:
        return [self.result(i, kp[i], refined, self.cue_records[i]) for i in range(self.size)]

    def result(self, i: int, kp, refined: dict, cue_record) -> Union[FitResult, StageFailure]:
        """Image ``i``'s result from its keypoint stage's ``kp`` and, where it ran, its silhouette stage's (in
        ``refined``), with its records (:func:`_add_records`); a failure as a :class:`StageFailure`."""
        if isinstance(kp, StageFailure):
            return kp
        result = refined[i] if i in refined else _keypoint_only(self.model, kp[0][kp[1]], self.keypoints[i])
        if isinstance(result, StageFailure):
            result.partial = _keypoint_only(self.model, kp[0][kp[1]], self.keypoints[i])
            return result
        _add_records(self.model, self.fitter.whole_body, result, self.keypoints[i], self.cues[i], cue_record)
        return result


def _depth_cues(fitter, keypoints, images, people) -> tuple:
    """``(cues, records)`` per image: the image depth cue (``None`` without an image, or with the cue off or
    refused) and ``metrics.json``'s ``image_depth`` (``"none"`` without an image; ``"off"`` where the settings turn
    it off), with the landmark model's seconds."""

    n = len(keypoints)
    images = list(images) if images is not None else [None] * n
    people = list(people) if people is not None else [None] * n
    cues, records = [None] * n, ["none"] * n
    for i, (image, ks) in enumerate(zip(images, keypoints)):
        if image is None:
            continue
        decide = fitter.config.image_depth.decide
        if not fitter.config.image_depth.weight and decide is None:
            records[i] = "off"
            continue
        t0 = time.perf_counter()
        cues[i], records[i] = cue_from_image(image, ks, people[i])
        records[i]["seconds"] = round(time.perf_counter() - t0, 3)
        if decide is not None and cues[i] is not None:  # the sides the branch search takes as decided
            records[i]["branch_choice"] = cues[i].hard_record(decide)
    return cues, records


def _keypoint_only(model, kp_result: KeypointFitResult, keypoints: KeypointSet) -> FitResult:
    """The :class:`FitResult` of a one-image keypoint-stage result (no silhouette stage)."""
    vertices, joints, kp2d = _pose(model, kp_result.params(0), keypoints.layout, kp_result.camera)
    metrics = {
        "stages": ["keypoints"],
        "timings_s": {
            **{f"keypoints.{k}": float(v) for k, v in kp_result.timings.items()},
            "keypoints": _stage_seconds(kp_result.timings),
        },
        "reprojection_error_px": _median_reprojection(kp2d, keypoints),
        "warnings": [],
        **_run_record(kp_result),
    }
    return FitResult(
        kp_result.camera, keypoints.layout, kp_result, None, kp_result.params(0), vertices, joints, kp2d, metrics
    )


def __getattr__(name: str):
    """``save_fit`` moved to :mod:`silfit.outputs.write` (the one writer); the old name works for one release."""
    if name == "save_fit":
        return moved_function(__name__, name, "silfit.outputs.write")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
