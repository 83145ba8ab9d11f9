"""Scoring rig fits (``silfit synth --cameras N`` datasets) against their world-frame truth.

Fit outputs: ``FITS/<subject>/<method>/params.npz`` in world coordinates, as ``silfit fit
--rig`` writes them (methods ``keypoints`` and ``silhouette``). Metrics per subject and
method (mm): ``pve_world`` (per-vertex error in world coordinates, no alignment at all:
placement, orientation, pose and shape together), ``pve`` (pelvis-aligned), ``pa_pve``,
``mpjpe``, ``pa_mpjpe``, ``transl_err`` (pelvis position, world), ``shape_pve``, ``facing_ok``
(the body's forward direction within 90 degrees of the truth's in the ground plane); ``reproj_px``
(mean over views of the fitted keypoints' error against the clean projections), ``iou``
(mean over the views of the rendered body against each view's mask), ``iou_worst`` (the
worst view), ``iou_views`` (every view's, a list) and ``time_s``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np
import torch

from ..body import load_body_model
from ..fitting.image_fit import body_mask
from ..fitting.problem import Problem
from ..inputs.rig import rig_problem
from ..fitting.rig_pipeline import view_vertices
from ..inputs import rig_job
from ..io.subjects import list_subjects, read_index, read_truth
from ..io.fit import read_fit
from ..io.keypoints import model_keypoints
from ..io.rig import load_rig, project_world
from ..run import keypoint_stage_fit, run_batch, write
from .evaluate import METRICS, facing_agrees, find_fits, markdown_table, summarise  # noqa: F401  (markdown_table: re-exported)
from .metrics import mask_iou, mpjpe, pa_mpjpe, pa_pve, pve, reprojection_error, shape_pve, translation_error

__all__ = ["evaluate_rig_dataset", "is_rig_dataset", "run_rig_fitter", "score_rig_fit", "subset_truth"]


def is_rig_dataset(dataset) -> bool:
    index = read_index(dataset)
    return bool(index and index.get("rig"))


def _load(subject_dir: Path):

    views = load_rig(subject_dir)
    return views, rig_problem(views), read_truth(subject_dir / "gt.npz")


def subset_truth(gt: dict, idx) -> dict:
    """The truth of a rig subject seen by its views ``idx`` only (per-view arrays subset)."""
    return {**gt, **{k: gt[k][list(idx)] for k in ("keypoints_2d_clean", "keypoints_visibility")}}


def score_rig_fit(model, views, problem, gt: dict, params: dict, iou: bool = True, timings=None) -> dict:
    """The metrics of one rig fit (world-frame ``params``) against the subject's truth."""
    t = lambda a: torch.as_tensor(np.asarray(a, np.float64)[None], dtype=model.dtype)  # noqa: E731
    with torch.no_grad():
        out = model(**{k: t(params[k]) for k in ("betas", "body_pose", "global_orient", "transl")})
        kp = model_keypoints(model, out, "body25")[0].double().numpy()
    verts = out.vertices[0].double().numpy()
    joints = out.joints[0].double().numpy()
    gv, gj = gt["vertices"].astype(np.float64), gt["joints"].astype(np.float64)
    m = {
        "pve_world": 1000 * pve(verts, gv, align=False),
        "pve": 1000 * pve(verts, gv, joints[0], gj[0]),
        "pa_pve": 1000 * pa_pve(verts, gv),
        "mpjpe": 1000 * mpjpe(joints, gj),
        "pa_mpjpe": 1000 * pa_mpjpe(joints, gj),
        "transl_err": 1000 * translation_error(joints[0], gj[0]),
        "shape_pve": 1000 * shape_pve(model, params["betas"], gt["betas"]),
        "facing_ok": 100.0 * float(facing_agrees(params["global_orient"], gt["global_orient"])),  # world y is down
    }
    reproj, ious = [], []
    faces = model.faces.cpu().numpy()
    for c, o in enumerate(problem.grid()[0]):
        cam = o.view.camera
        uv = project_world(kp, o.view)
        vis = gt["keypoints_visibility"][c] > 0
        if vis.any():
            reproj.append(reprojection_error(uv, gt["keypoints_2d_clean"][c], vis))
        if iou and o.mask is not None:
            ious.append(float(mask_iou(body_mask(view_vertices(verts, o.view), faces, cam), o.mask)))
    m["reproj_px"] = float(np.mean(reproj)) if reproj else float("nan")
    if ious:
        m["iou"], m["iou_worst"] = float(np.mean(ious)), float(np.min(ious))
    if timings:
        m["time_s"] = float(timings.get("total", sum(timings.values())))
    out = {k: float(v) for k, v in m.items()}
    if ious:
        out["iou_views"] = ious
    return out


def run_rig_fitter(
    subject_dirs: Sequence[Path],
    fits_root: Path,
    methods: Sequence[str],
    model,
    views: Optional[int] = None,
    progress: bool = False,
) -> dict:
    """Fit every rig subject through :func:`silfit.run.run_batch` (the keypoint stage batched
    over subjects, then the silhouette stage; ``views``: only the first ``views`` cameras), write
    ``fits_root/<subject>/<method>/`` (``keypoints``: the keypoint stage's fit, ``silhouette``:
    the final one); returns a status."""
    unknown = [m for m in methods if m not in ("keypoints", "silhouette")]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)} (expected keypoints, silhouette)")
    jobs = []
    for d in subject_dirs:
        v = load_rig(d)[: views or None]
        jobs.append(
            rig_job(
                rig_problem(v),
                [x.name for x in v],
                model,
                silhouette="silhouette" in methods,
                progress=progress,
                record={"subject": d.name},
            )
        )
    t0 = time.perf_counter()
    fits = run_batch(jobs, isolate=True)  # a subject that fails fails alone
    failed = []
    for d, fit in zip(subject_dirs, fits):
        if isinstance(fit, Exception):
            failed.append(f"{d.name}: {getattr(fit, 'error', fit)}")
            continue
        seconds = fit.seconds
        if "keypoints" in methods:
            kp = keypoint_stage_fit(fit)
            kp.metrics["timings"] = {"keypoints": seconds["keypoints"], "total": seconds["keypoints"]}
            write(kp, fits_root / d.name / "keypoints", overwrite=True)
        if "silhouette" in methods and fit.refined:
            fit.metrics["timings"] = {**seconds, "total": sum(seconds.values())}
            write(fit, fits_root / d.name / "silhouette", overwrite=True)
    done = [f for f in fits if not isinstance(f, Exception)]
    status = {
        "keypoints": f"ran on {len(done)} subjects in {time.perf_counter() - t0:.1f} s (batched, both stages)"
        + (f"; failed: {'; '.join(failed)}" if failed else "")
    }
    if "silhouette" in methods:
        status["silhouette"] = f"ran on {sum(f.refined for f in done)} subjects"
    return status


def _timings(folder: Path) -> dict:
    f = folder / "metrics.json"
    try:
        return {k: float(v) for k, v in json.loads(f.read_text()).get("timings", {}).items()}
    except (OSError, ValueError, AttributeError):
        return {}


def evaluate_rig_dataset(
    dataset,
    fits=None,
    model=None,
    run: bool = False,
    methods=("keypoints", "silhouette"),
    iou: bool = True,
    views: Optional[int] = None,
    progress: bool = False,
) -> dict:
    """Score (and with ``run``, or when there are no fits, first run) every rig subject."""
    dataset = Path(dataset)
    fits_root = Path(fits) if fits is not None else dataset / "fits"
    if model is None:
        model = load_body_model()
    dirs = list_subjects(dataset)
    status = {}
    if run or not any(find_fits(fits_root, d.name) for d in dirs):
        status = run_rig_fitter(dirs, fits_root, methods, model, views, progress)
    rows: List[dict] = []
    skipped, missing = [], []
    for d in dirs:
        found = find_fits(fits_root, d.name)
        if not found:
            missing.append(d.name)
            continue
        try:
            rig_views, problem, gt = _load(d)
        except (ValueError, FileNotFoundError, KeyError) as err:
            skipped.append({"subject": d.name, "path": str(d), "error": str(err)})
            continue
        for method, folder in found.items():
            try:
                fit = read_fit(folder)
                g = subset_truth(gt, range(views)) if views else gt
                m = score_rig_fit(
                    model, rig_views[: views or None], _subset(problem, views), g, fit.frame(0), iou, _timings(folder)
                )
            except (ValueError, FileNotFoundError) as err:
                skipped.append({"subject": d.name, "method": method, "path": str(folder), "error": str(err)})
                continue
            rows.append({"subject": d.name, "method": method, **m})
    report = {
        "dataset": str(dataset),
        "fits": str(fits_root),
        "rig": True,
        "units": {k: u for k, (_, u, _) in METRICS.items()},
        "methods": sorted({r["method"] for r in rows}),
        "num_subjects": len(dirs),
        "num_scored": len({r["subject"] for r in rows}),
        "summary": summarise(rows),
        "results": rows,
        "skipped": skipped,
        "missing_fits": missing,
    }
    if status:
        report["fitter"] = status
    return report


def _subset(problem, views):
    if not views:
        return problem
    return Problem([o for o in problem.observations if o.view_index < views], problem.shared)
