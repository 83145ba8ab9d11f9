"""One path from inputs to outputs, for every mode (one image, a rig, a video; body or whole body)::

    inputs      an input builder (:mod:`silfit.inputs`: one image, a rig, a video, a rig video, a
                dataset item; the command line's :mod:`silfit.cli.jobs` reads the files and calls
                them) makes a Job
      -> Job        one person's observations over frames x views (a Problem: keypoints, masks,
                    views with their cameras and R, t), the body model and the settings
      -> run(job)   the checks every input gets (:func:`check`), the keypoint stage, the
                    silhouette stage (where masks exist), the plausibility warnings, the metrics
      -> Fit        the one result type: shared and per-frame parameters, per-(frame, view)
                    reprojection error and IoU, metrics and warnings
      -> write(fit, out)   the output folder (the fit file of silfit.io.fit, meshes, pictures,
                    metrics.json), written atomically, its parts chosen by the frames and views
                    (:mod:`silfit.outputs.write`)

Every group of jobs goes through the same steps (:func:`_fit_group`): the number of frames and views (the
job's ``mode``) chooses a core (:data:`CORES`: an image batch,
:class:`~silfit.fitting.image_fit.ImageCore`; views of one frame, :class:`~silfit.fitting.rig_pipeline.RigCore`,
world frame; frames of one camera or of a rig, :class:`~silfit.fitting.sequence.VideoCore`), then
:func:`~silfit.fitting.cores.run_steps` runs its keypoint stage (multi-start and branch search, triangulation,
bridging and the temporal terms are the core's), the one silhouette driver
(:func:`~silfit.fitting.refine.refine_silhouettes`) on the core's hooks where masks exist, and its results, each
made a :class:`Fit`. The keypoint layout decides the model's terms (body or whole body). Nothing above :func:`run`
branches on the mode.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Union

import numpy as np
import torch

from .body import load_body_model
from .body.model import SMPL_PARAMETER_NAMES
from .errors import InputError, interruption
from .fitting.problem import Problem
from .fitting.cores import StageFailure, run_steps
from .fitting.image_depth import cue_from_image
from .fitting.image_fit import FitResult, ImageCore
from .fitting.plausibility import check_frames, check_keypoints, fit_warnings
from .fitting.rig_pipeline import RigCore, disagreeing_views, keypoint_stage_result
from .fitting.sequence import SequenceFitConfig, VideoCore, finite_median
from .inputs.image import image_job
from .inputs.job import Job
from .inputs.rig import rig_video_job
from .inputs.video import video_job
from .io.images import read_rgb
from .outputs.write import write_folder

__all__ = [
    "Job",
    "Fit",
    "StageFailure",
    "check",
    "fit",
    "run",
    "run_batch",
    "write",
    "keypoint_stage_fit",
    "image_job",
    "video_job",
    "fit_sequence",
]


@dataclass
class Fit:
    """The result of :func:`run` for any job.

    ``params``: ``betas [L]`` (one shape), every other parameter ``[F, w]``; ``vertices
    [F, V, 3]`` and ``joints [F, J, 3]`` in ``coordinates`` (``"camera"``: the one view's camera
    frame; ``"world"``: the rig's); ``keypoints_2d [F, C, K, 2]`` the final body's projections;
    ``reprojection_error [F, C]`` (median px, NaN where a view had no keypoints) and ``iou
    [F, C]`` (NaN without a mask); ``metrics`` what ``metrics.json`` holds (with
    ``warnings``); ``keypoint_fit`` the keypoint stage's result as a :class:`Fit` of its own, ``seconds`` per stage,
    ``history`` the silhouette stage's steps and ``masks`` the final body's rendered masks: the same names for every
    mode. ``stage`` is the core's own record (``FitResult``, ``RigResult`` or ``SequenceFitResult``): read by these
    properties, by the writer (:func:`silfit.outputs.write.stage_parts`) and by the evaluator for the keypoint
    stage's energies; the older functions (``silfit.fit``, ``silfit.fit_sequence``) return it."""

    job: Job
    params: Dict[str, np.ndarray]
    vertices: np.ndarray
    joints: np.ndarray
    keypoints_2d: np.ndarray
    reprojection_error: np.ndarray
    iou: np.ndarray
    coordinates: str
    metrics: dict
    stage: Any

    @property
    def warnings(self) -> List[str]:
        return self.metrics.setdefault("warnings", [])

    @property
    def num_frames(self) -> int:
        return self.vertices.shape[0]

    def frame_params(self, f: int) -> Dict[str, np.ndarray]:
        return {n: v if n == "betas" else v[f] for n, v in self.params.items()}

    @property
    def camera(self):
        """The first view's camera: the frame an image's or a one-camera video's parameters are in (a rig's are in
        the world frame, ``coordinates == "world"``: this is then its first view's intrinsics only)."""
        return self.job.problem.observations[0].view.camera

    @cached_property
    def keypoint_fit(self) -> Optional["Fit"]:
        """The keypoint stage's result as a :class:`Fit` of its own where :attr:`refined` (an image, a rig);
        ``None`` where this fit is the keypoint stage's (no mask; a rig whose guard kept the keypoint fit), and for
        a video (whose per-frame fits are written under ``stages/per_frame``). Its ``iou`` is the keypoint stage's
        body against the mask, its ``masks`` that body's rendered masks."""
        if self.job.mode == "video" or not self.refined:
            return None
        if self.job.mode == "rig":
            return keypoint_stage_fit(self)
        return _image_keypoint_fit(self.job, self.stage)

    @property
    def refined(self) -> bool:
        """Whether the silhouette stage ran and its record is kept, by mode: an image's wherever it ran (the
        plausibility guard's verdict in ``metrics["silhouette_guard"]``: this fit may be the keypoint stage's), a
        rig's only where the guard kept its result, a video's wherever it ran."""
        if self.job.mode == "video":
            return "silhouette" in self.stage.timings
        return self.stage.silhouette is not None

    @property
    def seconds(self) -> Dict[str, float]:
        """Seconds per stage: ``keypoints``, and ``silhouette`` where it ran (every hypothesis' share included)."""
        if self.job.mode == "video":
            t = self.stage.timings
            sil = t.get("silhouette")
            return {
                "keypoints": float(t["total"] - (sil or 0.0)),
                **({} if sil is None else {"silhouette": float(sil)}),
            }
        t = self.metrics["timings_s" if self.job.mode == "image" else "timings"]
        return {k: float(t[k]) for k in ("keypoints", "silhouette") if k in t}

    @property
    def history(self) -> Optional[dict]:
        """One image's silhouette stage per step (``level``, ``energy``, ``silhouette``, ``keypoints``, ``iou``
        lists); ``None`` without that stage, and for rigs and videos (their stage is batched over views or frames)."""
        if self.job.mode != "image" or not self.refined:
            return None
        return self.stage.silhouette.history

    @property
    def masks(self) -> Dict[int, np.ndarray]:
        """Per view ``c`` (one frame) the final body's rendered mask ``[H, W]`` (bool), where a mask was fitted;
        empty for a video."""
        if self.job.mode == "image":
            return {0: self.stage.masks["final"]} if "final" in self.stage.masks else {}
        if self.job.mode == "rig":
            return {c: self.stage.masks[n] for c, n in enumerate(self.job.view_names) if n in self.stage.masks}
        return {}

    def summary(self) -> str:
        """One line for the console: frames, views, reprojection error, IoU."""
        m = self.metrics
        parts = []
        if self.num_frames > 1 or "bridged_count" in m:
            parts.append(f"{self.num_frames} frames")
            if "bridged_count" in m:
                parts.append(f"{m['bridged_count']} bridged, {m['seconds_per_frame']:.2f} s per frame")
        if self.iou.shape[1] > 1:
            parts.append(f"{self.iou.shape[1]} views")
        err = m.get("reprojection_error_px")
        if err is not None:
            parts.append(f"median reprojection error {err:.2f} px")
        before = _finite_mean(
            m.get("iou_keypoint_stage", m.get("iou_mean_keypoint_stage", m.get("silhouette_iou_start")))
        )
        after = _finite_mean(self.iou)
        if np.isfinite(after):
            parts.append(
                f"IoU {before:.3f} -> {after:.3f}" if before is not None and np.isfinite(before) else f"IoU {after:.3f}"
            )
        return ", ".join(parts)


def _finite_mean(values) -> Optional[float]:
    if values is None:
        return None
    a = np.asarray(values, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else float("nan")


# -------------------------------------------------------------------------------- checks


def _dedupe(items: Sequence[str]) -> List[str]:
    seen, out = set(), []
    for w in items:
        if w not in seen:
            seen.add(w)
            out.append(w)
    return out


def check(job: Job) -> Job:
    """The checks every input gets, before anything is fitted (and all ``--check-only`` runs):
    each view's keypoints through :func:`silfit.fitting.plausibility.check_keypoints` (points far
    outside the image dropped, degenerate sets refused; a video's frames through
    :func:`~silfit.fitting.plausibility.check_frames`). A refused set is an error for one
    image; a rig sets that view aside (a warning; an error if no view is left); a video fits
    that frame as one without a detection (bridged from its neighbours), and sets aside a view with no usable
    frame. Returns the job with the checked keypoints and the findings added to ``warnings``."""
    grid = job.problem.grid()
    F, C = len(grid), len(grid[0])
    names = list(job.view_names) if len(job.view_names) == C else [str(c) for c in range(C)]
    numbers = list(job.frame_numbers) if job.frame_numbers is not None else list(range(F))
    plain = job.mode == "image" or (job.mode == "video" and C == 1)  # its notes without the view's name
    warnings = list(job.warnings)
    kept, first = [], None
    for c in range(C):
        try:
            column, notes = _checked_view(job.mode, [row[c].keypoints for row in grid], grid[0][c].view, numbers)
        except InputError as err:
            if C == 1:
                raise
            first = first or err
            warnings.append(f"view {names[c]} set aside: {err}")
            continue
        warnings += [n if plain else f"view {names[c]}: {n}" for n in notes]
        kept.append((c, column))
    if not kept:
        raise first
    problem = Problem(
        [
            replace(grid[f][c], keypoints=column[f], frame=f, view_index=i)  # (its other fields as they were)
            for f in range(F)
            for i, (c, column) in enumerate(kept)
        ],
        job.problem.shared,
    )
    names = [names[c] for c, _ in kept]
    index = {c: i for i, (c, _) in enumerate(kept)}  # a view's pictures and mask sources follow it
    images = {(f, index[c]): v for (f, c), v in job.images.items() if c in index}
    sources = {(f, index[c]): v for (f, c), v in job.mask_sources.items() if c in index}
    if len(kept) < C and hasattr(job.inputs, "select_views"):  # the reader's object follows (a rig video's)
        job = replace(job, inputs=job.inputs.select_views([c for c, _ in kept]))
    return replace(
        job, problem=problem, view_names=names, warnings=_dedupe(warnings), images=images, mask_sources=sources
    )


# -------------------------------------------------------------------------------- run


def _checked_view(mode: str, column: list, view, numbers: list) -> tuple:
    """``(keypoints per frame, notes)`` of one view's ``column`` (its keypoints per frame) after the checks: one
    frame's set refused raises; a video's refused frames become frames without a detection."""
    if mode == "video":
        return check_frames(column, view.camera.size, numbers)
    ks, notes = check_keypoints(column[0], view.camera.size)
    return [ks], notes


def run(job: Job) -> Fit:
    """Fit a job (module docstring): checks, keypoint stage, silhouette stage, warnings."""
    (fit,) = run_batch([job])
    if isinstance(fit, Exception):
        raise fit.error if isinstance(fit, StageFailure) else fit
    return fit


def run_batch(jobs: Sequence[Job], isolate: bool = False) -> List[Union[Fit, Exception]]:
    """Fit several jobs, one :class:`Fit` each, in order: one-image jobs that share a layout,
    model and settings go through the keypoint stage as one batch and through the silhouette
    stage as one batch (as ``fit-dataset`` and ``eval`` feed them); rigs and videos one by one.
    With ``isolate``, a job that fails (its checks, or a stage:
    :class:`~silfit.fitting.cores.StageFailure`) gets its error in its place and the others go on;
    without, the first error raises."""
    out: List[Union[Fit, Exception, None]] = [None] * len(jobs)
    checked: Dict[int, Job] = {}
    for i, job in enumerate(jobs):
        try:
            if job.model is None:
                job = replace(job, model=load_body_model())
            checked[i] = check(job)
        except InputError as err:
            if not isolate:
                raise
            out[i] = err
    groups: Dict[tuple, List[int]] = {}
    for i, job in checked.items():
        key = (
            (
                job.mode,
                job.layout,
                id(job.model),
                id(job.pose_prior),
                id(job.keypoint_config),
                id(job.silhouette_config),
                job.silhouette,
                job.progress,
            )
            if job.mode in ("image", "rig")
            else (job.mode, i)
        )
        groups.setdefault(key, []).append(i)
    for rows in groups.values():
        results = _fit_group([checked[i] for i in rows], isolate)
        for i, fit in zip(rows, results):
            if isinstance(fit, Fit):
                job = fit.job
                fit.metrics["warnings"] = _dedupe(list(job.warnings) + list(fit.metrics.get("warnings", [])))
                ran = fit.metrics.get("silhouette")  # the core's word on whether the stage ran wins over the reader's
                fit.metrics.update({k: v for k, v in job.record.items() if k != "warnings"})
                if ran == "not run" and fit.metrics.get("silhouette") == "run":
                    fit.metrics["silhouette"] = "not run (no view with masks left)"
            out[i] = fit
    return out  # type: ignore[return-value]


def _arr(v) -> np.ndarray:
    return np.asarray(v, dtype=np.float32)


def _params_per_frame(params: dict, F: int) -> Dict[str, np.ndarray]:
    """``betas [L]``, every other parameter ``[F, w]``."""
    return {n: _arr(v).reshape(-1) if n == "betas" else _arr(v).reshape(F, -1) for n, v in params.items()}


def _fit_group(jobs: Sequence[Job], isolate: bool) -> list:
    """The steps every group of jobs goes through, whatever its frames x views: the core its mode needs
    (:data:`CORES`: an image batch, a rig batch, a video), then :func:`~silfit.fitting.cores.run_steps` (the
    keypoint stage, the silhouette stage where masks exist: the one driver, the results), then one :class:`Fit`
    per job. With ``isolate``: an image batch's stages isolate their rows themselves (a failing image gets a
    :class:`StageFailure`); a rig batch or a video that fails is fitted again job by job, and a job that still
    fails gets its error in its place."""
    build, to_fit = CORES[jobs[0].mode]
    try:
        core = build(jobs)
        results = run_steps(core, isolate and core.isolates_stages)
        return [r if isinstance(r, Exception) else to_fit(job, core, r) for job, r in zip(jobs, results)]
    except Exception as err:  # noqa: BLE001 - which job failed is found by fitting them alone
        if not isolate or jobs[0].mode == "image" or interruption(err) is not None:
            raise
        return [err] if len(jobs) == 1 else [r for job in jobs for r in _fit_group([job], isolate)]


def _image_core(jobs: Sequence[Job]) -> ImageCore:
    """One-image jobs of one layout, model and settings as one batch (:class:`~silfit.fitting.image_fit.ImageCore`)."""
    first = jobs[0]
    obs = [job.problem.observations[0] for job in jobs]
    return ImageCore(
        first.model,
        [o.keypoints for o in obs],
        [o.view.camera for o in obs],
        [o.mask for o in obs],
        pose_prior=first.pose_prior,
        keypoint_config=first.keypoint_config,
        silhouette_config=first.silhouette_config,
        silhouette=first.silhouette,
        progress=first.progress,
        mask_sources=[job.mask_sources.get((0, 0), "mask") for job in jobs],
        images=[job.images.get((0, 0)) for job in jobs],
        people=[job.people.get((0, 0)) for job in jobs],
        known=[o.known for o in obs],
    )


def _image_fit(job: Job, core, r) -> Fit:
    """The :class:`Fit` of an image job's :class:`~silfit.fitting.image_fit.FitResult` (:func:`image_result_fit`)."""
    return image_result_fit(job, r)


def image_result_fit(job: Job, r) -> Fit:
    """The :class:`Fit` of one image's :class:`~silfit.fitting.image_fit.FitResult` (its metrics the result's own;
    its parameters the SMPL ones first, then a whole body's others, as the fit files of one image list them)."""
    m = r.metrics
    params = {**{n: r.params[n] for n in SMPL_PARAMETER_NAMES if n in r.params}, **r.params}
    return Fit(
        job,
        _params_per_frame(params, 1),
        _arr(r.vertices)[None],
        _arr(r.joints)[None],
        _arr(r.keypoints_2d)[None, None],
        np.array([[m.get("reprojection_error_px", np.nan)]], dtype=np.float64),
        np.array([[m.get("iou", np.nan)]], dtype=np.float64),
        "camera",
        m,
        r,
    )


def _image_keypoint_fit(job: Job, r) -> Fit:
    """One image's keypoint stage (of its :class:`~silfit.fitting.image_fit.FitResult` ``r``) as a :class:`Fit`:
    :func:`image_result_fit` of a ``FitResult`` whose parameters, body and record are the keypoint stage's."""
    kp, m = r.keypoint, r.metrics
    metrics = {
        "stages": ["keypoints"],
        "timings_s": {"keypoints": m["timings_s"]["keypoints"]},
        "reprojection_error_px": m.get("reprojection_error_px_keypoint_stage", np.nan),
        "iou": m.get("iou_keypoint_stage", np.nan),
        "warnings": [],
    }
    masks = {"final": r.masks["keypoint_stage"]} if "keypoint_stage" in r.masks else {}
    stage = FitResult(
        r.camera, r.layout, kp, None, kp.params(0), kp.vertices[0], kp.joints[0], kp.keypoints_2d[0], metrics, masks
    )
    return image_result_fit(job, stage)


def _rig_core(jobs: Sequence[Job]) -> RigCore:
    """Rig jobs of one layout, model and settings as one batch (:class:`~silfit.fitting.rig_pipeline.RigCore`)."""
    first = jobs[0]
    return RigCore(
        [job.problem for job in jobs],
        [list(job.view_names) for job in jobs],
        first.model,
        first.pose_prior,
        first.keypoint_config,
        first.silhouette,
        first.silhouette_config,
        first.progress,
    )


def _rig_fit(job: Job, core, r) -> Fit:
    """The :class:`Fit` of a rig job's :class:`~silfit.fitting.rig_pipeline.RigResult`."""
    return _rig_views_fit(job, r, "iou")


def _rig_views_fit(job: Job, r, iou: str) -> Fit:
    """The :class:`Fit` of a rig job's :class:`~silfit.fitting.rig_pipeline.RigResult` (``iou``: the views' IoU field)."""
    names = list(job.view_names)
    views = r.metrics["views"]
    proj = r.metrics.get("keypoints_2d", r.keypoint.keypoints_2d)
    return Fit(
        job,
        _params_per_frame(r.params, 1),
        _arr(r.vertices)[None],
        _arr(r.joints)[None],
        _arr(proj)[None],
        np.array([[views[n].get("reprojection_error_px", np.nan) for n in names]], dtype=np.float64),
        np.array([[views[n].get(iou, np.nan) for n in names]], dtype=np.float64),
        "world",
        r.metrics,
        r,
    )


def keypoint_stage_fit(fit: Fit) -> Fit:
    """A rig fit's keypoint stage alone, as a :class:`Fit` of its own (:func:`write` makes the folder a fit
    without a silhouette stage would have; its ``metrics`` are the stage's, without the job's ``record``)."""
    if fit.job.mode != "rig":
        raise ValueError(f"keypoint_stage_fit: a rig's fit only, not a fit of mode {fit.job.mode!r}")
    job = fit.job
    kp = keypoint_stage_result(fit.stage.keypoint, job.problem, list(job.view_names), job.model.faces.cpu().numpy())
    return _rig_views_fit(job, kp, "iou_keypoint_stage")


def _video_depth_cues(job: Job, frames) -> tuple:
    """``(cues, records)`` per frame of a one-camera video: the image depth cue of each frame with keypoints and an
    image (``job.images`` or the reader's ``--images``), else ``None``; ``(None, None)`` with no image or the cue off."""
    kp_cfg = (job.sequence_config or SequenceFitConfig()).keypoint
    paths = dict(getattr(job.inputs, "images", None) or {})
    numbers = list(job.frame_numbers) if job.frame_numbers is not None else list(range(len(frames)))
    if (not kp_cfg.image_depth.weight and kp_cfg.image_depth.decide is None) or not (job.images or paths):
        return None, None
    cues, records = [None] * len(frames), ["none"] * len(frames)
    for f, (ks, number) in enumerate(zip(frames, numbers)):
        image = job.images.get((f, 0))
        if image is None and number in paths:
            image = read_rgb(paths[number], "image")
        if ks is not None and image is not None:
            cues[f], records[f] = cue_from_image(image, ks)
    return cues, records


def _sequence_vertices(model, params: dict, F: int) -> np.ndarray:
    """The posed vertices ``[F, V, 3]`` of a sequence's parameters (``betas`` shared over the frames)."""
    with torch.no_grad():

        def T(n, a):
            return torch.as_tensor(
                np.repeat(np.asarray(a)[None], F, 0) if n == "betas" else np.asarray(a), dtype=model.dtype
            )

        return model(**{n: T(n, a) for n, a in params.items()}).vertices.numpy()


def _video_warnings(job: Job, result, frames, vertices, errors: np.ndarray, numbers, rig: bool) -> List[str]:
    """The sequence fit's warnings and, for a rig, the views the fit could not agree with, or, for one camera,
    each frame's plausibility warnings (:func:`frame_warnings`)."""
    warnings = list(result.warnings)
    if rig:  # a view the fit could not agree with (the rule of one frame's rig, on each view's median)
        medians = [float(np.median(e[np.isfinite(e)])) if np.isfinite(e).any() else float("nan") for e in errors.T]
        warnings += disagreeing_views(list(job.view_names), medians)
    else:
        warnings += frame_warnings(frames, vertices, errors[:, 0], numbers)
    return warnings


def _video_metrics(result, errors: np.ndarray, warnings: List[str], silhouette: bool, numbers, cue_records) -> dict:
    """A video fit's ``metrics.json`` fields."""
    metrics = {
        "reprojection_error_px": finite_median(errors),
        "warnings": _dedupe(warnings),
        "silhouette": "run" if silhouette else "not run",
        "bridged_count": int(np.sum(result.bridged)),
        "seconds_per_frame": float(result.timings["seconds_per_frame"]),
        "image_depth": "none"
        if cue_records is None
        else {  # per frame: the segments the image decided
            str(n): sorted(r.get("decided", {})) if isinstance(r, dict) else r for n, r in zip(numbers, cue_records)
        },
    }
    if silhouette and getattr(result, "silhouette_iou_start", None) is not None:  # the summary's "IoU a -> b"
        metrics["silhouette_iou_start"] = float(result.silhouette_iou_start)
    return metrics


def _video_core(jobs: Sequence[Job]) -> VideoCore:
    """A video job of one camera or of a rig (:class:`~silfit.fitting.sequence.VideoCore`): its frames, cameras and
    masks, and for one camera the frames' image depth cues (:func:`_video_depth_cues`)."""
    (job,) = jobs
    grid = job.problem.grid()
    rig = job.rig or len(grid[0]) > 1
    frames = [[o.keypoints for o in row] for row in grid] if rig else [row[0].keypoints for row in grid]
    masks = [[o.mask for o in row] for row in grid] if rig else [row[0].mask for row in grid]
    cameras = [o.view for o in grid[0]] if rig else grid[0][0].view.camera
    cues, cue_records = (None, None) if rig else _video_depth_cues(job, frames)
    silhouette = job.silhouette and any(o.mask is not None for o in job.problem.observations)
    config = job.sequence_config or SequenceFitConfig()
    return VideoCore(
        frames,
        cameras,
        masks,
        job.model,
        config,
        pose_prior=job.pose_prior,
        progress=job.progress,
        silhouette=silhouette,
        silhouette_config=job.silhouette_config,
        depth_cues=cues,
        cue_records=cue_records,
    )


def _video_fit(job: Job, core: VideoCore, result) -> Fit:
    """The :class:`Fit` of a video job's :class:`~silfit.fitting.sequence.SequenceFitResult` (camera frame for one
    camera, world frame for a rig): posed vertices, per-(frame, view) errors and IoU, warnings and metrics."""
    fit = sequence_result_fit(job, result, {})
    F, C = fit.reprojection_error.shape
    rig = job.rig or C > 1
    numbers = list(job.frame_numbers) if job.frame_numbers is not None else list(range(F))
    warnings = _video_warnings(job, result, core.frames, fit.vertices, fit.reprojection_error, numbers, rig)
    fit.metrics = _video_metrics(result, fit.reprojection_error, warnings, core.silhouette, numbers, core.cue_records)
    result.warnings = fit.metrics["warnings"]
    return fit


def sequence_result_fit(job: Job, result, metrics: dict) -> Fit:
    """The :class:`Fit` of a :class:`~silfit.fitting.sequence.SequenceFitResult` over ``job``'s frames x views (its
    vertices posed from its parameters), with ``metrics``."""
    grid = job.problem.grid()
    F, C = len(grid), len(grid[0])
    rig = job.rig or C > 1
    params = result.params()
    vertices = _sequence_vertices(job.model, params, F)
    errors = np.asarray(result.reprojection_error, np.float64).reshape(F, C)
    iou = (
        np.full((F, C), np.nan)
        if result.silhouette_iou is None
        else np.broadcast_to(np.asarray(result.silhouette_iou, np.float64).reshape(F, -1), (F, C)).copy()
    )
    return Fit(
        job,
        _params_per_frame(params, F),
        _arr(vertices),
        _arr(result.joints),
        _arr(result.keypoints_2d).reshape(F, C, -1, 2),
        errors,
        iou,
        "world" if rig else "camera",
        metrics,
        result,
    )


#: mode (frames x views) -> (its core from a group of jobs, a result of the core as a :class:`Fit`)
CORES = {"image": (_image_core, _image_fit), "rig": (_rig_core, _rig_fit), "video": (_video_core, _video_fit)}


def frame_warnings(frames, vertices, errors, numbers) -> List[str]:
    """One image's plausibility warnings (:func:`silfit.fitting.plausibility.fit_warnings`: depth,
    reprojection error against the person's extent) for every frame of a video, one line per
    kind of finding with the frames it concerns."""
    kinds: Dict[str, list] = {}
    for f, ks in enumerate(frames):
        if ks is None:
            continue
        err = errors[f]
        metrics = {"reprojection_error_px": float(err)} if np.isfinite(err) else {}
        for w in fit_warnings(metrics, ks, vertices[f]):
            key = re.sub(r"[-+]?\d[\d.e+-]*", "#", w)
            kinds.setdefault(key, [w, []])[1].append(numbers[f])
    out = []
    for first, found in kinds.values():
        shown = ", ".join(map(str, found[:10])) + (" ..." if len(found) > 10 else "")
        out.append(
            f"frame(s) {shown}: {first}"
            if len(found) == 1
            else f"{len(found)} frame(s) ({shown}), e.g. frame {found[0]}: {first}"
        )
    return out


# -------------------------------------------------------------------------------- outputs


def write(
    fit: Fit,
    out,
    *,
    overwrite: bool = False,
    exports: Sequence[str] = (),
    meshes: bool = False,
    video: bool = True,
    fps: float = 30.0,
    extra: Optional[dict] = None,
    images: Optional[Dict[tuple, np.ndarray]] = None,
) -> Path:
    """Write a fit's output folder atomically (the fit file of :mod:`silfit.io.fit`, the mesh(es),
    pictures, ``metrics.json``); the one writer of output folders (its parts chosen by the fit's
    frames and views). ``exports`` (``"glb"``, ``"ply"``) adds upright meshes for other tools (not
    for rigs: a rig's world frame has no fixed up axis); ``meshes``, ``video`` and ``fps`` are a
    video's (one OBJ per frame, the overlay GIF, its frame rate). ``extra``: more ``metrics.json``
    fields (over the fit's own); ``images``: ``(frame, view)`` -> the RGB image to draw an image's
    or a rig's pictures on, over the job's (a fit run without its image; a video's come from its
    reader)."""
    return write_folder(
        fit, out, overwrite=overwrite, exports=exports, meshes=meshes, video=video, fps=fps, extra=extra, images=images
    )


# -------------------------------------------------------------------------------- builders for Python callers


def fit(
    keypoints,
    mask: Optional[np.ndarray] = None,
    camera=None,
    *,
    image_size: Optional[tuple] = None,
    focal: Optional[float] = None,
    model=None,
    pose_prior=None,
    keypoint_config=None,
    silhouette_config=None,
    progress: bool = False,
    image: Optional[np.ndarray] = None,
):
    """Fit SMPL to one image (a :class:`~silfit.fitting.image_fit.FitResult`): keypoints (a :class:`KeypointSet` or ``[K, 3]`` array), then,
    if ``mask [H, W]`` (bool) is given, refine against the silhouette.

    ``camera`` or ``image_size=(W, H)`` (+ optional ``focal``) define the camera, as for
    :func:`silfit.fit_keypoints`. ``model`` defaults to the shipped open body model. ``image`` (uint8 RGB
    ``[H, W, 3]``): the landmark model's 3D on it decides limbs' depth order (the image depth cue,
    :mod:`silfit.fitting.image_depth`; ``metrics["image_depth"]``). The same path as every other mode
    (:func:`run` on :func:`image_job`).
    """
    job = image_job(
        keypoints,
        mask,
        camera,
        image_size=image_size,
        focal=focal,
        model=model,
        pose_prior=pose_prior,
        keypoint_config=keypoint_config,
        silhouette_config=silhouette_config,
        progress=progress,
        image=image,
    )
    return run(job).stage


def fit_sequence(
    frames,
    camera,
    model=None,
    *,
    masks=None,
    config=None,
    silhouette_config=None,
    pose_prior=None,
    progress: bool = False,
    images=None,
):
    """Fit one person over a video's frames (a :class:`~silfit.fitting.sequence.SequenceFitResult`, as
    :func:`silfit.fitting.sequence.fit_sequence` gives it): the same path as every other mode (:func:`run` on
    :func:`video_job`, or for a rig's views :func:`silfit.inputs.rig_video_job`), so the frames get the checks every
    input gets (:func:`check`: a frame whose keypoints are refused is bridged) and the result the video's
    plausibility warnings.

    ``frames``: one :class:`~silfit.io.keypoints.KeypointSet` (or ``None``) per frame with ``camera`` a
    :class:`~silfit.camera.Camera`; or ``frames[f][c]`` per view with ``camera`` a list of
    :class:`~silfit.fitting.problem.View` s (a rig video, in its world frame). ``masks`` (``masks[f]`` or
    ``masks[f][c]``, ``None`` where there is none): the silhouette stage follows. ``images`` (one camera; per frame
    an RGB array or ``None``): the image depth cue (:mod:`silfit.fitting.image_depth`)."""

    if isinstance(camera, (list, tuple)):
        if images is not None:
            raise ValueError("fit_sequence: images (the image depth cue) are for one camera's video, not a rig's")
        names = [str(c) for c in range(len(camera))]
        job = rig_video_job(
            frames, camera, names, model, masks=masks, config=config, silhouette_config=silhouette_config
        )
    else:
        job = video_job(frames, camera, model, masks=masks, config=config, silhouette_config=silhouette_config)
    job = replace(job, pose_prior=pose_prior, progress=progress)
    pictures = {(f, 0): image for f, image in enumerate(images or []) if image is not None}
    return run(replace(job, images=pictures)).stage
