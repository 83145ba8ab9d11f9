"""The one writer of output folders: :func:`write_folder` (which :func:`silfit.run.write` is) writes a
:class:`~silfit.run.Fit`'s folder atomically (:func:`silfit.outputs.folder.atomic_folder`), made of parts chosen
by the fit's frames x views::

    every fit            params.npz, params.json   the fit file of silfit.io.fit, from the Fit's parameters,
                                                   joints, keypoints_2d and per-view reprojection error (one
                                                   frame: its vertices; a video: its frame numbers), in the
                                                   Fit's coordinates
                         stages/<stage>/           the stage's own fit files (the keypoint stage's; a video's
                                                   per-frame fits), with the same views
                         metrics.json              the Fit's metrics and the caller's fields
    world coordinates    cameras.json              the rig's cameras (silfit.io.rig manifest)
    one frame            mesh.obj                  the posed body (one view: mesh.glb / mesh.ply exports)
                         overlay.png               the body over each view's image, and silhouette.png where the
                                                   view has a mask (one view: in the folder; a rig's views:
                                                   views/<name>/)
    one image            side.png, iou_curve.png, stages/keypoints/overlay.png, hypotheses/, hypotheses.png
    a video              strip.png, overlay.gif, meshes/frame_<n>.obj (``meshes``), animation.glb and
                         meshes/frame_<n>.ply (``exports``, one camera)

What only the core's own result (``Fit.stage``: ``FitResult``, ``RigResult``, ``SequenceFitResult``) holds is read
in one place, :func:`stage_parts`: the fit file's record, the stages' fit files, the rendered masks, an image's
keypoint-stage body, IoU history and hypotheses, a video's metrics.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np
import torch

from ..errors import InputError
from ..fitting.problem import Observation, Problem, View
from ..fitting.rig_pipeline import view_vertices
from ..fitting.sequence import finite_median
from ..inputs.job import Job
from ..io.fit import write_fit
from ..io.images import read_rgb
from ..io.meshes import write_obj
from ..io.rig import write_cameras_json
from ..io.video import write_overlay_video
from . import figures
from .export import write_fit_exports, write_sequence_exports
from .folder import atomic_folder

__all__ = ["StageFit", "StageParts", "save_fit", "save_sequence_fit", "stage_parts", "write_folder"]


@dataclass
class StageFit:
    """One of a stage's own fit files (``stages/<name>/``), written with the fit's views and coordinates."""

    folder: str
    params: dict
    vertices: Optional[np.ndarray] = None
    joints: Optional[np.ndarray] = None
    keypoints_2d: Optional[np.ndarray] = None
    reprojection_error: Optional[np.ndarray] = None
    record: Optional[dict] = None


@dataclass
class StageParts:
    """What a fit's folder needs that only the core's own result holds (:func:`stage_parts`)."""

    #: the fit file's ``params.json`` record (an image: the keypoint stage's energies, timings, configuration;
    #: a rig: timings; a video: ``bridged``, ``refaced``, ``rebranched`` per frame)
    record: dict
    #: the stages' fit files (an image's and a rig's keypoint stage with a silhouette stage; a video's per-frame fits)
    stage_fits: List[StageFit] = field(default_factory=list)
    #: view -> ``(the final body's rendered mask, the mask pixels fitted as body or None)``: silhouette.png
    masks: Dict[int, tuple] = field(default_factory=dict)
    #: one image with a silhouette stage: the keypoint stage's ``(vertices [V, 3], keypoints_2d [K, 2])``
    keypoint_body: Optional[tuple] = None
    #: one image with a silhouette stage: the stage's IoU and energy per step (iou_curve.png)
    history: Optional[dict] = None
    #: one image with ``--hypotheses K``: each hypothesis as a fit (hypotheses/)
    hypotheses: list = field(default_factory=list)
    #: a video: the sequence result, for its ``metrics.json`` (:func:`video_metrics`)
    sequence: Any = None


def stage_parts(fit) -> StageParts:
    """The one place the writer reads ``fit.stage`` (the module docstring)."""
    stage, mode = fit.stage, fit.job.mode
    if mode == "image":
        kp, sil = stage.keypoint, stage.silhouette is not None
        parts = StageParts(stage.final.record(0), hypotheses=list(stage.hypotheses))
        pick = lambda name: None if getattr(kp, name) is None else getattr(kp, name)[0]  # noqa: E731
        params = {name: kp.params(0)[name] for name in kp.parameter_names}
        parts.stage_fits.append(
            StageFit(
                "stages/keypoints", params, pick("vertices"), pick("joints"), pick("keypoints_2d"), None, kp.record(0)
            )
        )
        if sil:
            parts.keypoint_body = (kp.vertices[0], kp.keypoints_2d[0])
            parts.masks[0] = (stage.masks["final"], stage.masks.get("fitted"))
            parts.history = stage.silhouette.history
        return parts
    if mode == "rig":
        parts = StageParts({"timings": fit.metrics.get("timings", {})})
        if stage.silhouette is not None:
            kp = stage.keypoint
            errors = np.asarray(kp.reprojection_error, np.float32)[None]
            proj = np.asarray(kp.keypoints_2d)[None]
            parts.stage_fits.append(StageFit("stages/keypoints", kp.params, kp.vertices, kp.joints, proj, errors))
        parts.masks = {c: (stage.masks[n], None) for c, n in enumerate(fit.job.view_names) if n in stage.masks}
        return parts
    flags = {"bridged": stage.bridged.tolist(), "refaced": stage.refaced.tolist()}
    if stage.rebranched is not None:
        flags["rebranched"] = stage.rebranched.tolist()
    return StageParts(flags, [StageFit("stages/per_frame", stage.per_frame)], sequence=stage)


# ----------------------------------------------------------------------------- the writer
def write_folder(
    fit,
    out,
    *,
    overwrite: bool = False,
    exports: Sequence[str] = (),
    meshes: bool = False,
    video: bool = True,
    fps: float = 30.0,
    extra: Optional[dict] = None,
    images: Optional[Dict[tuple, np.ndarray]] = None,
    faces: Optional[np.ndarray] = None,
    model=None,
    layout: Optional[str] = None,
) -> Path:
    """Write ``fit``'s output folder atomically, its parts chosen by its frames x views (the module docstring; the
    arguments as :func:`silfit.run.write`'s). ``faces``, ``model`` (the body model or its record, for the fit
    files) and ``layout``: the job's unless given (a result written without its job: :func:`save_fit`)."""
    job = fit.job
    if images and job.mode == "video":
        raise ValueError("write: a video's pictures come from its reader (job.inputs), not from images=")
    world = fit.coordinates == "world"
    if exports and world:
        if job.mode == "video":
            raise ValueError("exports of a rig video: not available (a rig's world frame has no fixed up axis)")
        raise InputError(
            "--export", "not available for rigs (a rig's world frame has no fixed up axis); mesh.obj holds the body"
        )
    model = job.model if model is None else model
    layout = job.layout if layout is None else layout
    faces = job.model.faces.cpu().numpy() if faces is None else faces
    fields = {k: v for k, v in fit.metrics.items() if k in job.record}
    fields["warnings"] = list(fit.warnings)
    fields.update(extra or {})
    pictures = {**job.images, **(images or {})}
    parts = stage_parts(fit)
    out = Path(out)
    with atomic_folder(out, overwrite) as tmp:
        write_fit_files(tmp, fit, parts, model, layout)
        if world:
            write_cameras_json(tmp / "cameras.json", list(zip(job.view_names, views_of(fit))))
        if job.mode == "video":
            gif = write_frames(tmp, fit, job.model, faces, meshes, video, exports, fps)
            metrics = video_metrics(parts.sequence, fit, gif, fields)
        else:
            write_frame(tmp, fit, faces, model, layout, pictures, parts, exports)
            metrics = one_frame_metrics(fit, layout, fields)
        (tmp / "metrics.json").write_text(json.dumps(metrics, indent=2, default=float))
    return out


def views_of(fit) -> list:
    """The fit's views (:class:`~silfit.fitting.problem.View`: camera, R, t), in order."""
    return [o.view for o in fit.job.problem.grid()[0]]


def write_fit_files(tmp: Path, fit, parts: StageParts, model, layout: str) -> None:
    """``params.npz`` / ``params.json`` (:func:`silfit.io.fit.write_fit`) from the Fit's fields, and the stages' fit
    files with the same views: one image's error is in its record (as the keypoint stage's is), not an array."""
    job, views = fit.job, views_of(fit)
    where = dict(cameras=[v.camera for v in views], layout=layout, model=model)
    if fit.coordinates == "world":
        where.update(coordinates="world", extrinsics=[v.extrinsics() for v in views], views=list(job.view_names))
    if job.mode == "video":
        where["frame_numbers"] = frame_numbers(fit)
    write_fit(
        tmp,
        fit.params,
        vertices=fit.vertices if job.mode != "video" else None,
        joints=fit.joints,
        keypoints_2d=fit.keypoints_2d,
        reprojection_error=fit.reprojection_error if job.mode != "image" else None,
        record=parts.record,
        **where,
    )
    for s in parts.stage_fits:
        write_fit(
            tmp / s.folder,
            s.params,
            vertices=s.vertices,
            joints=s.joints,
            keypoints_2d=s.keypoints_2d,
            reprojection_error=s.reprojection_error,
            record=s.record,
            **where,
        )


def frame_numbers(fit) -> list:
    """The fit's frame numbers (a video's file numbers, else 0, 1, ...)."""
    numbers = fit.job.frame_numbers
    return list(numbers) if numbers is not None else list(range(fit.num_frames))


def one_frame_metrics(fit, layout: str, fields: dict) -> dict:
    """One frame's ``metrics.json``: the Fit's metrics (one image: with its camera and layout) and ``fields``."""
    if fit.job.mode == "image":
        metrics = dict(fit.metrics)
        metrics["camera"] = views_of(fit)[0].camera.to_dict()
        metrics["layout"] = layout
    else:
        metrics = {k: v for k, v in fit.metrics.items() if k != "keypoints_2d"}
    metrics.update(fields)
    return metrics


# ----------------------------------------------------------------------------- one frame: an image, a rig
def write_frame(tmp: Path, fit, faces: np.ndarray, model, layout: str, pictures: dict, parts: StageParts, exports):
    """One frame's ``mesh.obj`` (and one view's ``exports``), each view's pictures and one image's own."""
    vertices = fit.vertices[0]
    if fit.coordinates == "world":
        write_obj(tmp / "mesh.obj", vertices, faces, "silfit: posed body in world coordinates (rig extrinsics, metres)")
    else:
        write_obj(tmp / "mesh.obj", vertices, faces)
    if exports:
        write_fit_exports(tmp, vertices, faces, views_of(fit)[0].camera, exports)
    write_view_pictures(tmp, fit, faces, pictures, parts)
    if fit.job.mode == "image":
        write_image_pictures(tmp, fit, faces, model, layout, pictures.get((0, 0)), parts)


def write_view_pictures(tmp: Path, fit, faces: np.ndarray, pictures: dict, parts: StageParts) -> None:
    """Each view's ``overlay.png`` (the body over its image, or a grey canvas, with its keypoints) and, where it has a
    mask, ``silhouette.png``: in the folder for one image, in ``views/<name>/`` for a rig's views."""
    world = fit.coordinates == "world"
    for c, o in enumerate(fit.job.problem.grid()[0]):
        folder = tmp / "views" / fit.job.view_names[c] if world else tmp
        folder.mkdir(parents=True, exist_ok=True)
        vertices = view_vertices(fit.vertices[0], o.view) if world else fit.vertices[0]
        ks = o.keypoints
        overlay = figures.fit_overlay(
            pictures.get((0, c)),
            vertices,
            faces,
            o.view.camera,
            None if ks is None else ks.xy,
            fit.keypoints_2d[0, c],
            None if ks is None else ks.conf,
        )
        figures.write_png(folder / "overlay.png", overlay)
        if o.mask is not None and c in parts.masks:
            final, fitted = parts.masks[c]
            figures.write_png(folder / "silhouette.png", figures.silhouette_comparison(final, o.mask, fitted))


def write_image_pictures(tmp: Path, fit, faces: np.ndarray, model, layout: str, image, parts: StageParts) -> None:
    """One image's ``side.png`` (over the keypoint-stage body, orange, with a silhouette stage); with a silhouette
    stage the keypoint stage's ``stages/keypoints/overlay.png`` and ``iou_curve.png``; ``hypotheses/``."""
    o, vertices = fit.job.problem.observations[0], fit.vertices[0]
    reference = None if parts.keypoint_body is None else parts.keypoint_body[0]
    figures.write_png(tmp / "side.png", figures.side_view(vertices, faces, reference))
    if parts.keypoint_body is not None:
        kp_xy, kp_conf = (None, None) if o.keypoints is None else (o.keypoints.xy, o.keypoints.conf)
        kp_vertices, kp_2d = parts.keypoint_body
        overlay = figures.fit_overlay(image, kp_vertices, faces, o.view.camera, kp_xy, kp_2d, kp_conf)
        figures.write_png(tmp / "stages" / "keypoints" / "overlay.png", overlay)
        figures.iou_curve(parts.history, tmp / "iou_curve.png")
    if parts.hypotheses:  # --hypotheses K: hypotheses/<k>/ and hypotheses.png
        write_hypotheses(tmp, fit, faces, model, layout, image, parts)


def hypothesis_title(h: dict, silhouette: bool) -> str:
    """A :func:`write_hypotheses` tile's title: rank, what it turns, its energy gap (and the mask's IoU)."""
    r = h["record"]
    turns = r.get("differs") or []
    what = (
        "the keypoint fit's branch"
        if r["rank"] == 1
        else (
            "turns " + (", ".join(turns) if len(turns) <= 2 else f"{len(turns)} segments")
            if turns
            else f"from branch {r['label']}, no limb turned"
        )
    )
    line = f"keypoint energy {r['gap']:+.1%}" + ("" if r.get("refined", True) else " (search stage)")
    if silhouette and r.get("silhouette_iou") is not None:
        line += f", IoU {r['silhouette_iou']:.3f}"
    return f"{r['rank']}{' (kept)' if r['kept'] else ''}: {what}\n{line}"


def write_hypotheses(tmp: Path, fit, faces: np.ndarray, model, layout: str, image, parts: StageParts) -> None:
    """``hypotheses/<rank>/`` (``params.npz``/``params.json`` with the hypothesis' record, ``mesh.obj``, and where the
    silhouette stage refined it ``stages/keypoints/``, the keypoint stage's) and ``hypotheses.png``: each hypothesis
    over the image and from the side, over the final fit (orange) where it differs."""
    o, final = fit.job.problem.observations[0], fit.vertices[0]
    camera = o.view.camera
    kp_xy, kp_conf = (None, None) if o.keypoints is None else (o.keypoints.xy, o.keypoints.conf)
    silhouette = parts.keypoint_body is not None
    tiles, titles = [], []
    for h in parts.hypotheses:
        d = tmp / "hypotheses" / str(h["rank"])
        write_fit(
            d,
            h["params"],
            [camera],
            layout=layout,
            model=model,
            vertices=h["vertices"],
            keypoints_2d=h["keypoints_2d"],
            record=h["record"],
        )
        write_obj(d / "mesh.obj", h["vertices"], faces)
        if h["keypoint_params"] is not None:
            record = {"rank": h["rank"], "params_from": "keypoint stage"}
            write_fit(
                d / "stages" / "keypoints", h["keypoint_params"], [camera], layout=layout, model=model, record=record
            )
        same = np.allclose(h["vertices"], final, atol=1e-6)
        tiles += [
            figures.fit_overlay(image, h["vertices"], faces, camera, kp_xy, h["keypoints_2d"], kp_conf),
            figures.side_view(
                h["vertices"], faces, None if same else final, labels=(f"hypothesis {h['rank']}", "final fit")
            ),
        ]
        titles += [hypothesis_title(h, silhouette), "from the side" + ("" if same else " (orange: the final fit)")]
    figures.contact_sheet(tiles, titles, tmp / "hypotheses.png", columns=2 * min(len(parts.hypotheses), 3))


# ----------------------------------------------------------------------------- a video: frames of one camera or a rig
def posed_frames(fit, model) -> List[np.ndarray]:
    """Each frame's posed vertices ``[V, 3]``, the model run on one frame's parameters at a time (as the video's
    pictures and meshes have always been drawn: a batch of frames may differ in the last bits)."""
    posed = []
    for f in range(fit.num_frames):
        p = fit.frame_params(f)
        with torch.no_grad():
            out = model(**{k: torch.as_tensor(np.asarray(v)[None], dtype=model.dtype) for k, v in p.items()})
        posed.append(out.vertices[0].numpy())
    return posed


def write_frames(tmp: Path, fit, model, faces: np.ndarray, meshes: bool, video: bool, exports, fps: float):
    """A video's ``meshes/frame_<n>.obj`` (``meshes``), ``exports`` (animation.glb, meshes/frame_<n>.ply;
    :func:`silfit.outputs.export.write_sequence_exports`), ``strip.png`` and with ``video`` ``overlay.gif`` (its path,
    or ``None``: returned)."""
    numbers = frame_numbers(fit)
    posed = posed_frames(fit, model)
    if meshes:
        (tmp / "meshes").mkdir()
        for f, v in enumerate(posed):
            write_obj(tmp / "meshes" / f"frame_{numbers[f]:012d}.obj", v, faces)
    if exports:
        write_sequence_exports(tmp, np.stack(posed), faces, views_of(fit)[0].camera, exports, numbers, fps)
    strip_stride = max(1, -(-fit.num_frames // 8))
    pics = [frame_picture(fit, f, posed[f], faces) for f in range(0, fit.num_frames, 1 if video else strip_stride)]
    strip = pics[::strip_stride] if video else pics
    figures.write_png(tmp / "strip.png", np.concatenate(strip, axis=1))
    if not video:
        return None
    return write_overlay_video(tmp / "overlay.gif", pics, fps)


def frame_picture(fit, f: int, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Frame ``f``'s overlay (the body and its keypoints' projections over the frame's image, or a grey canvas; a
    rig's views side by side), the images read from the video's reader (``job.inputs``; none without one)."""
    seq, number = fit.job.inputs, frame_numbers(fit)[f]
    world = fit.coordinates == "world"
    if seq is None:  # a job made in Python, without a reader: no images
        files = [{}] * len(views_of(fit))
    else:
        files = [v.images for v in seq.videos] if world else [seq.images]
    row = []
    for c, view in enumerate(views_of(fit)):
        img = read_rgb(files[c][number], "image") if number in files[c] else None
        if world:
            R, t = view.extrinsics()
            v = (vertices @ R.T + t).astype(np.float32)
        row.append(figures.fit_overlay(img, v if world else vertices, faces, view.camera, None, fit.keypoints_2d[f, c]))
    if not world:
        return row[0]
    height = max(r.shape[0] for r in row)
    return np.concatenate([np.pad(r, ((0, height - r.shape[0]), (0, 0), (0, 0))) for r in row], axis=1)


def video_metrics(result, fit, gif, fields: dict) -> dict:
    """A video's ``metrics.json``: frames, bridged, refaced and rebranched frames, outliers, reprojection errors,
    timings, warnings, the camera (a rig video: its views and cameras, world coordinates), the overlay video, the
    configuration and, with the silhouette stage, the IoUs (``result``: the sequence fit, the stage's own)."""
    rig, views = fit.coordinates == "world", views_of(fit)
    numbers = frame_numbers(fit)
    finite = result.reprojection_error[np.isfinite(result.reprojection_error)]
    metrics = {
        "frames": len(numbers),
        "first_frame": numbers[0],
        "last_frame": numbers[-1],
        "bridged_frames": [numbers[i] for i in np.flatnonzero(result.bridged)],
        "refaced_frames": [numbers[i] for i in np.flatnonzero(result.refaced)],
        # the frames whose depth branch the choice over time changed (SequenceFitConfig.branch_choice.dp)
        "rebranched_frames": [numbers[i] for i in np.flatnonzero(result.rebranched)]
        if result.rebranched is not None
        else [],
        "outlier_keypoints": int(result.outliers.sum()),
        "reprojection_error_px": float(np.median(finite)) if len(finite) else None,
        **(
            {"reprojection_error_px_keypoint_stage": finite_median(result.reprojection_error_keypoint_stage)}
            if result.reprojection_error_keypoint_stage is not None
            else {}
        ),
        "timings": result.timings,
        "warnings": list(result.warnings),
        **(
            {"views": list(fit.job.view_names), "cameras": [v.camera.to_dict() for v in views], "coordinates": "world"}
            if rig
            else {"camera": views[0].camera.to_dict()}
        ),
        "overlay_video": gif.name if gif else None,
        "config": result.config,
        **fields,
    }
    if result.silhouette_iou is not None:
        metrics["silhouette_iou_start"] = result.silhouette_iou_start
        clean = lambda v: None if not np.isfinite(v) else float(v)  # noqa: E731
        metrics["silhouette_iou"] = [[clean(v) for v in row] if rig else clean(row) for row in result.silhouette_iou]
    return metrics


# ----------------------------------------------------------------------------- a core's result without its job
def save_fit(
    result,
    out,
    faces: np.ndarray,
    keypoints=None,
    image: Optional[np.ndarray] = None,
    mask: Optional[np.ndarray] = None,
    extra_metrics: Optional[dict] = None,
    overwrite: bool = False,
    exports: Sequence[str] = (),
) -> Path:
    """One image's :class:`~silfit.fitting.image_fit.FitResult` (``silfit.fit``'s) written by :func:`write_folder`
    (the folder of ``silfit fit``, :mod:`silfit.fitting.image_fit`'s docstring), atomically: ``keypoints``,
    ``image`` and ``mask`` the fit's inputs; ``exports`` (``"glb"``, ``"ply"``) adds ``mesh.glb`` / ``mesh.ply``."""
    from ..run import image_result_fit

    job = Job(
        Problem([Observation(View(result.camera), keypoints, mask)]), images={} if image is None else {(0, 0): image}
    )
    return write_folder(
        image_result_fit(job, result),
        out,
        overwrite=overwrite,
        exports=exports,
        extra=extra_metrics,
        faces=faces,
        model=result.keypoint.model,
        layout=result.layout,
    )


def save_sequence_fit(
    result,
    out,
    model,
    sequence,
    *,
    meshes: bool = False,
    video: bool = True,
    fps: float = 30.0,
    extra_metrics: Optional[dict] = None,
    overwrite: bool = False,
    exports: Sequence[str] = (),
) -> Path:
    """A :class:`~silfit.fitting.sequence.SequenceFitResult` (``silfit.fit_sequence``'s) written by
    :func:`write_folder`, atomically: ``sequence`` its reader's :class:`~silfit.io.video.SequenceInput` (a rig
    video's :class:`~silfit.io.video.RigSequence`: the frames' numbers and images); ``meshes``, ``video``, ``fps``
    and ``exports`` as :func:`silfit.run.write`'s."""
    from ..run import sequence_result_fit

    rig = result.views is not None
    views = list(result.views) if rig else [View(result.camera)]
    F = result.num_frames
    job = Job(
        Problem([Observation(v, None, None, f, c) for f in range(F) for c, v in enumerate(views)]),
        model=model,
        view_names=list(sequence.names) if rig else ("camera",),
        frame_numbers=list(sequence.numbers),
        inputs=sequence,
        rig=rig,
        video=True,
    )
    fit = sequence_result_fit(job, result, {"warnings": list(result.warnings)})
    return write_folder(
        fit,
        out,
        overwrite=overwrite,
        exports=exports,
        meshes=meshes,
        video=video,
        fps=fps,
        extra=extra_metrics,
        layout=result.layout,
    )
