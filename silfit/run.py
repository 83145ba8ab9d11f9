"""One path from inputs to outputs, for every mode (one image, a rig, a video; body or whole body)::

    inputs      an input builder (silfit.cli.jobs for the CLI; :func:`image_job` here for
                Python callers) reads the files and makes a Job
      -> Job        one person's observations over frames x views (a Problem: keypoints, masks,
                    views with their cameras and R, t), the body model and the settings
      -> run(job)   the checks every input gets (:func:`check`), the keypoint stage, the
                    silhouette stage (where masks exist), the plausibility warnings, the metrics
      -> Fit        the one result type: shared and per-frame parameters, per-(frame, view)
                    reprojection error and IoU, metrics and warnings
      -> write(fit, out)   the output folder (the fit file of silfit.fitio, meshes, pictures,
                    metrics.json), written atomically

The number of frames and views decides the keypoint stage's core (one image:
:class:`~silfit.fitting.keypoint_stage.KeypointFitter`; views of one frame:
:func:`~silfit.fitting.rig_fit.fit_rig_keypoints`, world frame; frames of one camera:
:func:`~silfit.fitting.sequence.fit_sequence`); the keypoint layout decides the model's terms
(body or whole body). Nothing above :func:`run` branches on the mode.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Union

import numpy as np

from .errors import InputError, interruption
from .fitting.problem import Observation, Problem
from .image_fit import StageFailure

__all__ = ["Job", "Fit", "StageFailure", "check", "fit", "run", "run_batch", "write", "image_job", "video_job"]


@dataclass
class Job:
    """What to fit: ``problem`` (observations over frames x views of one person; a frame's
    keypoints may be ``None``: no detection there), the body ``model`` and the settings.

    ``silhouette_config`` ``None``: the defaults; ``silhouette=False``: no silhouette stage
    even where masks exist. ``view_names`` name the views (warnings, output folders);
    ``frame_numbers`` the frames (a video's file numbers). ``warnings`` are the input readers'
    findings, carried into the result; ``record`` is copied into ``metrics.json`` (the input
    files, the camera's source, the model); ``images`` maps ``(frame, view)`` to an RGB image
    for the pictures; ``inputs`` is the reader's own object where a writer needs more (a
    video's :class:`~silfit.video.SequenceInput`); ``rig`` marks views of a calibrated rig
    (world coordinates; with one view too)."""

    problem: Problem
    model: Any = None
    view_names: Sequence[str] = ("camera",)
    pose_prior: Any = None
    keypoint_config: Any = None
    silhouette_config: Any = None
    sequence_config: Any = None
    silhouette: bool = True
    progress: bool = False
    frame_numbers: Optional[Sequence[int]] = None
    warnings: List[str] = field(default_factory=list)
    record: Dict[str, Any] = field(default_factory=dict)
    images: Dict[tuple, np.ndarray] = field(default_factory=dict)
    mask_sources: Dict[tuple, str] = field(default_factory=dict)
    inputs: Any = None
    #: the views are a calibrated rig (fitted in its world frame), even when only one is left
    rig: bool = False
    #: the frames are a video's (the sequence fit and the video's outputs), even when it has one frame
    video: bool = False
    #: ``(frame, view)`` -> the detected :class:`~silfit.detect.Person` the keypoints came from (its 3D landmarks
    #: give the image depth cue without running the landmark model again; absent: run on ``images``)
    people: Dict[tuple, Any] = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        return self.problem.num_frames

    @property
    def num_views(self) -> int:
        return self.problem.num_views

    @property
    def layout(self) -> str:
        return next(o.keypoints.layout for o in self.problem.observations if o.keypoints is not None)

    @property
    def has_masks(self) -> bool:
        return any(o.mask is not None for o in self.problem.observations)

    @property
    def mode(self) -> str:
        """``"image"``, ``"rig"`` or ``"video"`` (what the frames x views shape is called)."""
        return (
            "video" if (self.video or self.num_frames > 1) else "rig" if (self.rig or self.num_views > 1) else "image"
        )


@dataclass
class Fit:
    """The result of :func:`run` for any job.

    ``params``: ``betas [L]`` (one shape), every other parameter ``[F, w]``; ``vertices
    [F, V, 3]`` and ``joints [F, J, 3]`` in ``coordinates`` (``"camera"``: the one view's camera
    frame; ``"world"``: the rig's); ``keypoints_2d [F, C, K, 2]`` the final body's projections;
    ``reprojection_error [F, C]`` (median px, NaN where a view had no keypoints) and ``iou
    [F, C]`` (NaN without a mask); ``metrics`` what ``metrics.json`` holds (with
    ``warnings``); ``stage`` the core's own result (``FitResult``, ``RigResult`` or
    ``SequenceFitResult``), for the writer and for callers of the older functions."""

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
    each observation's keypoints through :func:`silfit.plausibility.check_keypoints` (points far
    outside the image dropped, degenerate sets refused). A refused set is an error for one
    image; a rig sets that view aside (a warning; an error if no view is left); a video fits
    that frame as one without a detection (bridged from its neighbours). Returns the job with
    the checked keypoints and the findings added to ``warnings``."""
    from .plausibility import check_frames, check_keypoints

    grid = job.problem.grid()
    F, C = len(grid), len(grid[0])
    names = list(job.view_names) if len(job.view_names) == C else [str(c) for c in range(C)]
    warnings = list(job.warnings)
    if job.mode != "video":
        kept, first = [], None
        for c, o in enumerate(grid[0]):
            try:
                ks, notes = check_keypoints(o.keypoints, o.view.camera.size)
            except InputError as err:
                if C == 1 and not job.rig:
                    raise
                first = first or err
                warnings.append(f"view {names[c]} set aside: {err}")
                continue
            warnings += [n if job.mode == "image" else f"view {names[c]}: {n}" for n in notes]
            kept.append((c, Observation(o.view, ks, o.mask, 0, len(kept), known=o.known)))
        if not kept:
            raise first
        problem = Problem([o for _, o in kept], job.problem.shared)
        names = [names[c] for c, _ in kept]
        images = {(0, i): job.images[(0, c)] for i, (c, _) in enumerate(kept) if (0, c) in job.images}
        sources = {(0, i): job.mask_sources[(0, c)] for i, (c, _) in enumerate(kept) if (0, c) in job.mask_sources}
    else:  # a video (of one camera or a rig): each view's frames as a video's; a view with no usable frame set aside
        numbers = list(job.frame_numbers) if job.frame_numbers is not None else list(range(F))
        kept, first = [], None
        for c in range(C):
            try:
                column, notes = check_frames([row[c].keypoints for row in grid], grid[0][c].view.camera.size, numbers)
            except InputError as err:
                if C == 1:
                    raise
                first = first or err
                warnings.append(f"view {names[c]} set aside: {err}")
                continue
            warnings += [n if C == 1 else f"view {names[c]}: {n}" for n in notes]
            kept.append((c, column))
        if not kept:
            raise first
        problem = Problem(
            [
                Observation(grid[f][c].view, column[f], grid[f][c].mask, f, i, known=grid[f][c].known)
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
            from dataclasses import replace as _replace

            job = _replace(job, inputs=job.inputs.select_views([c for c, _ in kept]))
    from dataclasses import replace

    return replace(
        job, problem=problem, view_names=names, warnings=_dedupe(warnings), images=images, mask_sources=sources
    )


# -------------------------------------------------------------------------------- run


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
    :class:`~silfit.image_fit.StageFailure`) gets its error in its place and the others go on;
    without, the first error raises."""
    out: List[Union[Fit, Exception, None]] = [None] * len(jobs)
    checked: Dict[int, Job] = {}
    for i, job in enumerate(jobs):
        try:
            if job.model is None:
                from dataclasses import replace

                from .body import load_body_model

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
    for key, rows in groups.items():
        if key[0] in ("image", "rig"):
            results = (_run_images if key[0] == "image" else _run_rigs)([checked[i] for i in rows], isolate)
        else:
            try:
                results = [_run_video(checked[rows[0]])]
            except Exception as err:  # noqa: BLE001 - one job's failure, kept in its place
                if not isolate or interruption(err) is not None:
                    raise
                results = [err]
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


def _run_images(jobs: Sequence[Job], isolate: bool) -> list:
    """One-image jobs of one layout, model and settings, batched (:func:`silfit.image_fit.fit_problems`)."""
    from .image_fit import fit_problems

    first = jobs[0]
    obs = [job.problem.observations[0] for job in jobs]
    results = fit_problems(
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
        isolate=isolate,
        images=[job.images.get((0, 0)) for job in jobs],
        people=[job.people.get((0, 0)) for job in jobs],
        known=[o.known for o in obs],
    )
    out = []
    for job, r in zip(jobs, results):
        if isinstance(r, Exception):
            out.append(r)
            continue
        m = r.metrics
        out.append(
            Fit(
                job,
                _params_per_frame(r.params, 1),
                _arr(r.vertices)[None],
                _arr(r.joints)[None],
                _arr(r.keypoints_2d)[None, None],
                np.array([[m.get("reprojection_error_px", np.nan)]], dtype=np.float64),
                np.array([[m.get("iou", np.nan)]], dtype=np.float64),
                "camera",
                m,
                r,
            )
        )
    return out


def _run_rigs(jobs: Sequence[Job], isolate: bool) -> list:
    """Rig jobs of one layout, model and settings, batched (:func:`silfit.rig_pipeline.fit_rigs`);
    isolated: a failing batch again job by job."""
    from .rig_pipeline import fit_rigs

    first = jobs[0]
    try:
        results = fit_rigs(
            [job.problem for job in jobs],
            [list(job.view_names) for job in jobs],
            first.model,
            first.pose_prior,
            first.keypoint_config,
            silhouette=first.silhouette,
            silhouette_config=first.silhouette_config,
            progress=first.progress,
        )
    except Exception as err:  # noqa: BLE001 - which job failed is found by fitting them alone
        if not isolate or interruption(err) is not None:
            raise
        return [err] if len(jobs) == 1 else [r for job in jobs for r in _run_rigs([job], isolate)]
    out = []
    for job, r in zip(jobs, results):
        names = list(job.view_names)
        views = r.metrics["views"]
        proj = r.metrics.get("keypoints_2d", r.keypoint.keypoints_2d)
        out.append(
            Fit(
                job,
                _params_per_frame(r.params, 1),
                _arr(r.vertices)[None],
                _arr(r.joints)[None],
                _arr(proj)[None],
                np.array([[views[n].get("reprojection_error_px", np.nan) for n in names]], dtype=np.float64),
                np.array([[views[n].get("iou", np.nan) for n in names]], dtype=np.float64),
                "world",
                r.metrics,
                r,
            )
        )
    return out


def _video_depth_cues(job: Job, frames) -> tuple:
    """``(cues, records)`` per frame of a one-camera video: the image depth cue of each frame with keypoints and an
    image (``job.images`` or the reader's ``--images``), else ``None``; ``(None, None)`` with no image or the cue off."""
    from .fitting.image_depth import cue_from_image
    from .fitting.sequence import SequenceFitConfig

    kp_cfg = (job.sequence_config or SequenceFitConfig()).keypoint
    paths = dict(getattr(job.inputs, "images", None) or {})
    numbers = list(job.frame_numbers) if job.frame_numbers is not None else list(range(len(frames)))
    if (not kp_cfg.image_depth_weight and kp_cfg.image_depth_decide is None) or not (job.images or paths):
        return None, None
    from .imagefile import read_rgb

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
    import torch

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
        from .rig_pipeline import disagreeing_views

        medians = [float(np.median(e[np.isfinite(e)])) if np.isfinite(e).any() else float("nan") for e in errors.T]
        warnings += disagreeing_views(list(job.view_names), medians)
    else:
        warnings += frame_warnings(frames, vertices, errors[:, 0], numbers)
    return warnings


def _video_metrics(result, errors: np.ndarray, warnings: List[str], silhouette: bool, numbers, cue_records) -> dict:
    """A video fit's ``metrics.json`` fields."""
    from .fitting.sequence import finite_median

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


def _run_video(job: Job) -> Fit:
    """A video of one camera (camera frame) or of a rig (world frame): the sequence fit
    (:func:`~silfit.fitting.sequence.fit_sequence`) and, where masks exist, its silhouette stage."""
    from .fitting.sequence import SequenceFitConfig, fit_sequence, refine_sequence_silhouettes

    grid = job.problem.grid()
    rig = job.rig or len(grid[0]) > 1
    frames = [[o.keypoints for o in row] for row in grid] if rig else [row[0].keypoints for row in grid]
    masks = [[o.mask for o in row] for row in grid] if rig else [row[0].mask for row in grid]
    cameras = [o.view for o in grid[0]] if rig else grid[0][0].view.camera
    cues, cue_records = (None, None) if rig else _video_depth_cues(job, frames)
    result = fit_sequence(
        frames,
        cameras,
        job.model,
        config=job.sequence_config or SequenceFitConfig(),
        pose_prior=job.pose_prior,
        progress=job.progress,
        depth_cues=cues,
    )
    silhouette = job.silhouette and any(o.mask is not None for o in job.problem.observations)
    if silhouette:
        result = refine_sequence_silhouettes(
            job.model,
            result,
            frames,
            masks,
            config=job.silhouette_config,
            pose_prior=job.pose_prior,
            progress=job.progress,
        )
    F, C = len(grid), len(grid[0])
    params = result.params()
    vertices = _sequence_vertices(job.model, params, F)
    errors = np.asarray(result.reprojection_error, np.float64).reshape(F, C)
    iou = (
        np.full((F, C), np.nan)
        if result.silhouette_iou is None
        else np.broadcast_to(np.asarray(result.silhouette_iou, np.float64).reshape(F, -1), (F, C)).copy()
    )
    numbers = list(job.frame_numbers) if job.frame_numbers is not None else list(range(F))
    warnings = _video_warnings(job, result, frames, vertices, errors, numbers, rig)
    metrics = _video_metrics(result, errors, warnings, silhouette, numbers, cue_records)
    result.warnings = metrics["warnings"]
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


def frame_warnings(frames, vertices, errors, numbers) -> List[str]:
    """One image's plausibility warnings (:func:`silfit.plausibility.fit_warnings`: depth,
    reprojection error against the person's extent) for every frame of a video, one line per
    kind of finding with the frames it concerns."""
    from .plausibility import fit_warnings

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
) -> Path:
    """Write a fit's output folder atomically (the fit file of :mod:`silfit.fitio`, the mesh(es),
    pictures, ``metrics.json``); ``exports`` (``"glb"``, ``"ply"``) adds upright meshes for
    other tools (not for rigs: a rig's world frame has no fixed up axis); ``meshes``, ``video``
    and ``fps`` are a video's (one OBJ per frame, the overlay GIF, its frame rate)."""
    job = fit.job
    model = job.model
    faces = model.faces.cpu().numpy()
    extra = {k: v for k, v in fit.metrics.items() if k in job.record}
    extra["warnings"] = list(fit.warnings)
    if job.mode == "image":
        from .image_fit import save_fit

        o = job.problem.observations[0]
        return save_fit(
            fit.stage,
            out,
            faces,
            o.keypoints,
            job.images.get((0, 0)),
            o.mask,
            extra,
            overwrite=overwrite,
            exports=exports,
        )
    if job.mode == "rig":
        from .rig_pipeline import save_rig_fit

        if exports:
            raise InputError(
                "--export", "not available for rigs (a rig's world frame has no fixed up axis); mesh.obj holds the body"
            )
        images = {job.view_names[c]: img for (f, c), img in job.images.items()}
        return save_rig_fit(fit.stage, out, faces, job.problem, images, extra, overwrite=overwrite, model=model)
    from .video import save_sequence_fit

    return save_sequence_fit(
        fit.stage,
        out,
        model,
        job.inputs,
        meshes=meshes,
        video=video,
        fps=fps,
        extra_metrics=extra,
        overwrite=overwrite,
        exports=exports,
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
    """Fit SMPL to one image (a :class:`~silfit.image_fit.FitResult`): keypoints (a :class:`KeypointSet` or ``[K, 3]`` array), then,
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


def image_job(
    keypoints,
    mask=None,
    camera=None,
    *,
    image_size=None,
    focal=None,
    model=None,
    pose_prior=None,
    keypoint_config=None,
    silhouette_config=None,
    progress: bool = False,
    image=None,
) -> Job:
    """A job for one image: keypoints (a :class:`~silfit.keypoints.KeypointSet` or ``[K, 3]``
    array), an optional ``mask [H, W]``, and ``camera`` or ``image_size=(W, H)`` (+ ``focal``)
    for the default camera."""
    from .camera import Camera
    from .fitting.keypoint_stage import prepare_keypoints

    sets = prepare_keypoints(keypoints)
    if len(sets) != 1:
        raise ValueError(f"one person's keypoints, got {len(sets)}; use fit_keypoints for batches")
    if camera is None:
        if image_size is None and mask is not None:
            image_size = (mask.shape[1], mask.shape[0])
        if image_size is None:
            raise ValueError("no camera: give a camera (intrinsics) or the image size to derive the default one")
        camera = Camera.from_image_size(int(image_size[0]), int(image_size[1]), focal)
    elif focal is not None:
        from dataclasses import replace

        camera = replace(camera, fx=float(focal), fy=float(focal))
    mask = None if mask is None else np.asarray(mask, dtype=bool)
    return Job(
        Problem.single(sets[0], camera, mask),
        model,
        pose_prior=pose_prior,
        keypoint_config=keypoint_config,
        silhouette_config=silhouette_config,
        progress=progress,
        images={} if image is None else {(0, 0): image},
    )


def video_job(
    frames,
    camera,
    model=None,
    *,
    masks=None,
    config=None,
    silhouette_config=None,
    pose_prior=None,
    progress: bool = False,
    numbers=None,
    inputs=None,
    warnings=(),
    record=None,
) -> Job:
    """A job for one camera's video: ``frames`` one :class:`~silfit.keypoints.KeypointSet` (or
    ``None``: no detection) per frame, ``masks`` one mask or ``None`` per frame, ``config`` a
    :class:`~silfit.fitting.sequence.SequenceFitConfig`; ``numbers`` the frame numbers and
    ``inputs`` the reader's :class:`~silfit.video.SequenceInput` (for the writer's pictures)."""
    from .fitting.problem import View

    masks = list(masks) if masks is not None else [None] * len(frames)
    view = View(camera)
    return Job(
        Problem([Observation(view, ks, m, f) for f, (ks, m) in enumerate(zip(frames, masks))]),
        model,
        pose_prior=pose_prior,
        silhouette_config=silhouette_config,
        sequence_config=config,
        progress=progress,
        frame_numbers=None if numbers is None else list(numbers),
        warnings=list(warnings),
        inputs=inputs,
        record=dict(record or {}),
        video=True,
    )
