"""Scoring fits against ground truth over a dataset: ``silfit eval``.

Layout of the fit outputs this module reads (``FITS`` defaults to ``<DATASET>/fits``)::

    FITS/<subject>/<method>/params.npz     one folder per method, e.g. keypoints/, silhouette/
    FITS/<subject>/<method>/metrics.json   optional: {"timings": {stage: seconds, ...}, ...}
    FITS/<subject>/params.npz              a single unnamed method (reported as "fit")

``params.npz`` holds the SMPL parameters ``betas [L], body_pose [69], global_orient [3],
transl [3]`` (a leading batch dimension of 1 is accepted) whose model output is in the
camera frame, and optionally ``camera_intrinsics [fx, fy, cx, cy]`` + ``image_size [W, H]``
(the camera the fit used; default: the subject's ``camera.json``). This is what
``silfit fit --out <dir>`` and :meth:`silfit.fitting.KeypointFitResult.save` write. Stage
times are read from ``metrics.json`` (``timings`` / ``timings_s`` (``silfit fit``'s) / ``time_per_stage`` / ``stage_times``,
or a ``time_s`` total) or else from ``params.json``'s ``timings``.

Metrics per subject and method (lengths in mm): ``mpjpe`` (24 SMPL joints, pelvis-aligned),
``pa_mpjpe`` (similarity Procrustes), ``pve`` (pelvis-aligned per-vertex error), ``shape_pve``
(PVE of the T-posed bodies: the shape error alone), ``transl_err`` (pelvis position error in
the camera frame), ``reproj_px`` (fitted BODY_25 keypoints under the fit's camera vs the
noise-free ground-truth projections, over in-image keypoints), ``iou`` (rendered fitted mask
vs ``mask.png``) and ``time_s`` (+ ``time_<stage>``).

Whole-body sets (an SMPL-X-layout model; subjects whose ``gt.npz`` holds the SMPL-X parameters) add
(:mod:`silfit.eval.score_wholebody`): ``hand_pa`` / ``hand_wrist`` (each hand's vertices after Procrustes /
after aligning its wrist), ``face_pa`` and ``expression_err``. ``evaluate_dataset`` picks the shipped
open whole-body model for a dataset whose keypoint files hold hand or face points.

A subject whose files are missing or malformed is skipped with its path and field in the
report's ``skipped`` list; the others are still scored.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..body import load_body_model
from ..camera import Camera, project_points
from ..errors import InputError
from ..fitting import KeypointFitter, prepare_keypoints
from ..fitting.image_fit import StageFailure
from ..inputs import image_job
from ..io.subjects import SUBJECT_FILES, SubjectError, list_subjects, load_subject
from ..io.fit import PARAM_SIZES as PARAM_FIELDS
from ..io.fit import read_fit as read_fit_file
from ..io.keypoints import model_keypoints
from ..io.wholebody import choose_fit_keypoints, read_wholebody_parts
from ..outputs.folder import atomic_folder
from ..run import run_batch, write
from .metrics import mask_iou, mpjpe, pa_mpjpe, pa_pve, pve, reprojection_error, shape_pve, translation_error
from .score_wholebody import wholebody_errors

__all__ = [
    "METRICS",
    "PARAM_FIELDS",
    "FitParams",
    "read_fit",
    "find_fits",
    "score_fit",
    "evaluate_dataset",
    "run_fitter",
    "summarise",
    "markdown_table",
    "plot_errors",
    "FitterUnavailable",
]

SMPL_NAMES = ("betas", "body_pose", "global_orient", "transl")
#: Metric key -> (label, unit, lower is better).
METRICS = {
    "mpjpe": ("MPJPE", "mm", True),
    "pa_mpjpe": ("PA-MPJPE", "mm", True),
    "pve": ("PVE", "mm", True),
    "pve_world": ("PVE, world frame, no alignment (rigs)", "mm", True),
    "pa_pve": ("PA-PVE", "mm", True),
    "shape_pve": ("Shape PVE (T-pose)", "mm", True),
    "shape_pve_scaled": ("Shape PVE, stature aligned", "mm", True),
    "transl_err": ("Translation error", "mm", True),
    "reproj_px": ("2D reprojection error", "px", True),
    "iou": ("Silhouette IoU", "", False),
    "iou_worst": ("Silhouette IoU, worst view (rigs)", "", False),
    "energy_fit": ("Keypoint-stage energy at the fit", "", True),
    "energy_truth": ("Keypoint-stage energy at the truth", "", True),
    "search_failure": ("Search failures (fit energy above the truth's)", "%", True),
    "facing_ok": ("Facing correct (within 90 degrees)", "%", False),
    "hand_pa": ("Hand error, Procrustes", "mm", True),
    "hand_wrist": ("Hand error, wrist-aligned", "mm", True),
    "face_pa": ("Face error, Procrustes", "mm", True),
    "expression_err": ("Expression error (RMS coefficient)", "", True),
    "time_s": ("Time", "s", True),
}
#: a fit whose keypoint-stage energy exceeds the truth's by more than this share is a search failure
SEARCH_FAILURE_RTOL = 1e-4
#: Preferred method order in tables and plots.
METHOD_ORDER = ("keypoints", "silhouette", "fit")


class FitterUnavailable(RuntimeError):
    """The fitter (``silfit.fitting``) cannot run the requested method here."""


@dataclass
class FitParams:
    betas: np.ndarray
    body_pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray
    camera: Optional[Camera] = None
    timings: Dict[str, float] = field(default_factory=dict)
    path: Optional[Path] = None
    #: a whole-body fit's other SMPL-X parameters (``expression``, ``jaw_pose``, hand poses, ...)
    extra: Dict[str, np.ndarray] = field(default_factory=dict)


# ----------------------------------------------------------------------------- reading fits
def read_fit(folder: os.PathLike, model=None) -> FitParams:
    """Read ``params.npz`` (with :func:`silfit.io.fit.read_fit`; the parameters of ``model``, default
    SMPL's) + ``metrics.json`` / ``params.json`` timings of one fit folder."""
    folder = Path(folder)
    sizes = None if model is None else {**model.parameter_sizes, "betas": None}
    fit = read_fit_file(folder / "params.npz", require=SMPL_NAMES, sizes=sizes)
    if fit.num_frames != 1:
        raise SubjectError(
            fit.path, "frames", f"holds {fit.num_frames} frames; score videos with silfit eval on a sequence dataset"
        )
    params = fit.frame(0)
    smpl = {k: v for k, v in params.items() if k in SMPL_NAMES}
    extra = {k: v for k, v in params.items() if k not in SMPL_NAMES}
    return FitParams(**smpl, camera=fit.camera, timings=_read_timings(folder), path=folder, extra=extra)


def _read_timings(folder: Path) -> Dict[str, float]:
    for name in ("metrics.json", "params.json"):
        f = folder / name
        if not f.is_file():
            continue
        try:
            data = json.loads(f.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, OSError):
            continue
        if not isinstance(data, dict):
            continue
        for key in ("timings", "timings_s", "time_per_stage", "stage_times", "times"):
            t = data.get(key)
            if isinstance(t, dict):
                out = {
                    str(k): float(v) for k, v in t.items() if isinstance(v, (int, float)) and not isinstance(v, bool)
                }
                if key == "timings_s":  # silfit fit's metrics.json: whole stages, not their "keypoints.<stage>" parts
                    out = {k: v for k, v in out.items() if "." not in k}
                if out:
                    return out
        for key in ("time_s", "total_time_s", "seconds"):
            if isinstance(data.get(key), (int, float)):
                return {"total": float(data[key])}
    return {}


def find_fits(fits_root: os.PathLike, subject: str) -> Dict[str, Path]:
    """``{method: folder}`` of the fits of one subject (see the module docstring)."""
    d = Path(fits_root) / subject
    if not d.is_dir():
        return {}
    found = {p.name: p for p in sorted(d.iterdir()) if p.is_dir() and (p / "params.npz").is_file()}
    if (d / "params.npz").is_file():
        found["fit"] = d
    return dict(sorted(found.items(), key=lambda kv: (_method_rank(kv[0]), kv[0])))


def _method_rank(m: str) -> int:
    return METHOD_ORDER.index(m) if m in METHOD_ORDER else len(METHOD_ORDER)


# ----------------------------------------------------------------------------- scoring
def score_fit(model, subject, fit: FitParams, iou: bool = True) -> Dict[str, float]:
    """All metrics of one fit against one subject's ground truth (see the module docstring)."""
    gt = subject.gt
    if gt is None:
        raise SubjectError(subject.file("gt"), "<file>", "ground truth (gt.npz) is needed to score a fit")
    camera = fit.camera or subject.camera
    dt = model.dtype
    t = lambda a: torch.as_tensor(np.asarray(a)[None], dtype=dt, device=model.device)  # noqa: E731
    nb = model.num_betas
    betas = fit.betas[:nb]
    extra = {k: t(v) for k, v in fit.extra.items() if k in model.parameter_sizes}
    with torch.no_grad():
        out = model(
            betas=t(betas),
            body_pose=t(fit.body_pose),
            global_orient=t(fit.global_orient),
            transl=t(fit.transl),
            **extra,
        )
        kp = model_keypoints(model, out, "body25")[0]
        kp2d = project_points(kp.double(), camera).cpu().numpy()
    verts = out.vertices[0].cpu().double().numpy()
    joints = out.joints[0].cpu().double().numpy()

    m: Dict[str, float] = {}
    gj = gt.joints
    if gj.shape == joints.shape:
        m["mpjpe"] = 1000 * mpjpe(joints, gj)
        m["pa_mpjpe"] = 1000 * pa_mpjpe(joints, gj)
        m["transl_err"] = 1000 * translation_error(joints[0], gj[0])
    if gt.vertices.shape == verts.shape:
        m["pve"] = 1000 * pve(verts, gt.vertices, joints[0], gj[0])
        m["pa_pve"] = 1000 * pa_pve(verts, gt.vertices)
    if getattr(model, "kind", "smpl") == "smplx" and gt.vertices.shape == verts.shape and gj.shape == joints.shape:
        e = wholebody_errors(
            model,
            {"vertices": verts, "joints": joints, "expression": fit.extra.get("expression")},
            {"vertices": gt.vertices, "joints": gj, "expression": gt.extras.get("expression")},
        )
        m.update({k[: -len("_mm")]: v for k, v in e.items() if k in ("hand_pa_mm", "hand_wrist_mm", "face_pa_mm")})
        if "expression_err" in e:
            m["expression_err"] = e["expression_err"]
    m.update(_search_gap(fit.path))
    m["facing_ok"] = 100.0 * float(facing_agrees(fit.global_orient, gt.global_orient))
    fit_betas = np.pad(betas, (0, nb - len(betas)))
    m["shape_pve"] = 1000 * shape_pve(model, fit_betas, gt.betas[:nb])
    m["shape_pve_scaled"] = 1000 * shape_pve(model, fit_betas, gt.betas[:nb], scale=True)

    clean = gt.extras.get("keypoints_2d_clean")
    if clean is not None and clean.shape == kp2d.shape:
        vis = gt.extras.get("keypoints_visibility")
        valid = (np.asarray(vis) > 0) if vis is not None else np.ones(len(clean), bool)
        m["reproj_px"] = reprojection_error(kp2d, clean, valid)
    elif subject.keypoints is not None and subject.keypoints.xy.shape == kp2d.shape:
        m["reproj_px"] = reprojection_error(kp2d, subject.keypoints.xy, subject.keypoints.conf > 0)

    if iou and subject.mask is not None:
        try:
            from silfit.render.offscreen import render_mask

            cam = camera if (camera.width, camera.height) == subject.mask.shape[::-1] else subject.camera
            m["iou"] = mask_iou(render_mask(verts.astype(np.float32), model.faces.cpu().numpy(), cam), subject.mask)
        except ImportError:  # no offscreen renderer: IoU not available
            pass

    if fit.timings:
        total = fit.timings.get("total", sum(v for k, v in fit.timings.items() if k != "total"))
        m["time_s"] = float(total)
        for k, v in fit.timings.items():
            if k != "total":
                m[f"time_{k}"] = float(v)
    return {k: float(v) for k, v in m.items()}


def facing_agrees(orient, gt_orient) -> bool:
    """Whether the body's forward direction (rest +Z) is within 90 degrees of the truth's,
    in the camera's ground plane (x, z)."""
    f = Rotation.from_rotvec(np.asarray(orient, np.float64).reshape(3)).apply([0.0, 0.0, 1.0])
    g = Rotation.from_rotvec(np.asarray(gt_orient, np.float64).reshape(3)).apply([0.0, 0.0, 1.0])
    return bool(f[0] * g[0] + f[2] * g[2] > 0)


def search_gap(energy_fit: float, energy_truth: float) -> Dict[str, float]:
    """The keypoint-stage energies at the fit and at the truth, and whether the search failed
    (the fit's energy above the truth's: the optimiser missed a better minimum)."""
    fail = energy_fit > energy_truth + SEARCH_FAILURE_RTOL * abs(energy_truth)
    return {"energy_fit": float(energy_fit), "energy_truth": float(energy_truth), "search_failure": 100.0 * float(fail)}


def _search_gap(folder: Optional[Path]) -> Dict[str, float]:
    """The search gap a fit's ``metrics.json`` records (``search``: energies at fit and truth)."""
    f = None if folder is None else Path(folder) / "metrics.json"
    if f is None or not f.is_file():
        return {}
    try:
        rec = json.loads(f.read_text(encoding="utf-8")).get("search")
        return search_gap(float(rec["energy_fit"]), float(rec["energy_truth"]))
    except (ValueError, TypeError, KeyError, AttributeError, json.JSONDecodeError):
        return {}


# ----------------------------------------------------------------------------- the fitter
def _fit_keypoint_sets(subjects: Sequence, model) -> list:
    """The keypoints each subject is fitted to: with a whole-body (SMPL-X-layout) model, hands and face from the
    same files."""
    if getattr(model, "kind", "smpl") == "smplx":  # whole-body: hands and face from the same files
        return [
            choose_fit_keypoints(s.keypoints, read_wholebody_parts(s.file("keypoints"), 0), model)[0] for s in subjects
        ]
    return prepare_keypoints([s.keypoints for s in subjects])


def _fitter_jobs(sets: list, subjects: Sequence, methods: Sequence[str], model, progress: bool) -> list:
    """One :class:`silfit.inputs.Job` per subject (:func:`silfit.inputs.image_job`; a subject's image.png gives the
    image depth cue)."""
    return [
        image_job(
            k,
            s.mask,
            s.camera,
            model=model,
            silhouette="silhouette" in methods,
            progress=progress,
            mask_source=str(s.file("mask")),
            image=s.image,
        )
        for k, s in zip(sets, subjects)
    ]


def _failed_keypoint_stage(fits: list) -> dict:
    """``{subject number: error}`` of the subjects whose keypoints were refused (silfit.run.check) or whose keypoint
    stage failed (a failed silhouette stage keeps its keypoint fit)."""
    return {
        i: (f.error if isinstance(f, StageFailure) else f)
        for i, f in enumerate(fits)
        if isinstance(f, Exception) and not (isinstance(f, StageFailure) and f.stage == "silhouette")
    }


def _search_records(subjects: Sequence, sets: list, fits: list, bad: dict, model) -> list:
    """Per subject, the keypoint-stage energy at the fit and at the truth (``None`` without ground truth for every
    subject, or where the subject failed)."""
    if not all(s.gt is not None for s in subjects):
        return [None] * len(subjects)
    fitter = KeypointFitter(model, sets[0].layout)
    truth = {k: np.stack([s.gt.params()[k][0] for s in subjects]) for k in model.parameter_names}
    e_truth, _ = fitter.energy_at(truth, sets, [s.camera for s in subjects])
    last = fitter.stages[-1].name
    return [
        None if i in bad else {"energy_fit": float(_keypoint_result(f).energies[last][0]), "energy_truth": float(b)}
        for i, (f, b) in enumerate(zip(fits, e_truth))
    ]


def _write_keypoint_fits(subjects: Sequence, fits: list, bad: dict, fits_root, batched_over: int, search: list):
    """Each subject's keypoint fit into ``fits_root/<subject>/keypoints/`` (written beside its place, then moved in)."""
    for i, s in enumerate(subjects):  # each fit folder is written beside its place, then moved in
        if i in bad:
            continue
        kp = _keypoint_result(fits[i])
        with atomic_folder(Path(fits_root) / s.name / "keypoints", overwrite=True) as tmp:
            kp.save(tmp)
            record = {
                "timings": {k: float(v) for k, v in kp.timings.items()},
                "batched_over": batched_over,
                "search": search[i],
                "image_depth": getattr(fits[i], "metrics", {}).get("image_depth"),
            }
            (tmp / "metrics.json").write_text(json.dumps(record, indent=2))


def _write_silhouette_fits(subjects: Sequence, fits: list, bad: dict, fits_root, search) -> str:
    """Each subject's silhouette fit into ``fits_root/<subject>/silhouette/``; returns the method's status."""
    ran, failed = 0, []
    for i, (s, f) in enumerate(zip(subjects, fits)):
        if i in bad:
            failed.append(f"{s.name}: {bad[i]}")
        elif s.mask is None:
            failed.append(f"{s.name}: no mask")
        elif isinstance(f, StageFailure):
            failed.append(f"{s.name}: {f.error}")
        else:
            timings = dict(f.seconds)
            timings["total"] = sum(timings.values())
            extra = {"timings": timings, "search": search[i]}
            write(f, Path(fits_root) / s.name / "silhouette", overwrite=True, extra=extra)
            ran += 1
    return f"ran on {ran} subjects" + (f"; failed: {'; '.join(failed)}" if failed else "")


def run_fitter(
    subjects: Sequence,
    fits_root: os.PathLike,
    methods: Sequence[str],
    model,
    progress: bool = False,
    silhouette_batch: int = 8,
) -> Dict[str, str]:
    """Run the fitter over loaded subjects, writing ``fits_root/<subject>/<method>/``.

    ``keypoints``: the keypoint stage, batched over all subjects. ``silhouette``: the
    silhouette stage per subject, starting from the keypoint stage's result (run once and
    shared when both methods are asked for). Returns ``{method: status}``; raises
    :class:`FitterUnavailable` when nothing can run."""
    unknown = [m for m in methods if m not in ("keypoints", "silhouette")]
    if unknown:
        raise FitterUnavailable(f"unknown method(s) {', '.join(unknown)} (expected keypoints, silhouette)")
    status = {}
    t0 = time.perf_counter()
    sets = _fit_keypoint_sets(subjects, model)
    # every subject through the one path (silfit.run): both stages batched, in chunks of silhouette_batch
    chunk = max(1, int(silhouette_batch)) if "silhouette" in methods else len(subjects)
    jobs = _fitter_jobs(sets, subjects, methods, model, progress)
    fits = [f for c in range(0, len(jobs), chunk) for f in run_batch(jobs[c : c + chunk], isolate=True)]
    # a subject whose keypoints are refused (silfit.run.check) or whose keypoint stage fails fails alone
    bad = _failed_keypoint_stage(fits)
    if len(bad) == len(fits):
        raise next(iter(bad.values()))
    elapsed = time.perf_counter() - t0
    search = _search_records(subjects, sets, fits, bad, model)  # the keypoint-stage energy at the truth vs at the fit
    if "keypoints" in methods:
        _write_keypoint_fits(subjects, fits, bad, fits_root, min(chunk, len(subjects)), search)
        status["keypoints"] = (
            f"ran on {len(subjects) - len(bad)} subjects in {elapsed:.1f} s (batched; per-subject times are batch "
            "averages)" + (f"; failed: {'; '.join(f'{subjects[i].name}: {e}' for i, e in bad.items())}" if bad else "")
        )
    if "silhouette" in methods:
        status["silhouette"] = _write_silhouette_fits(subjects, fits, bad, fits_root, search)
    return status


def _keypoint_result(fit):
    """The keypoint stage's result of a :class:`silfit.run.Fit` (or of a failed silhouette stage)."""
    return (fit.partial if isinstance(fit, StageFailure) else fit.stage).keypoint


# ----------------------------------------------------------------------------- a dataset
def evaluate_dataset(
    dataset: os.PathLike,
    fits: Optional[os.PathLike] = None,
    model=None,
    run: bool = False,
    methods: Sequence[str] = ("keypoints", "silhouette"),
    iou: bool = True,
    progress: bool = False,
) -> dict:
    """Score the fits of every subject of ``dataset``; with ``run`` (or when ``fits`` holds no
    fit at all) run the fitter first. Returns the report (JSON-ready dict)."""
    dataset = Path(dataset)
    fits_root = Path(fits) if fits is not None else dataset / "fits"
    subject_dirs = list_subjects(dataset)
    if model is None:
        model = load_body_model(kind="smplx" if _whole_body_dataset(subject_dirs) else None)
    if not subject_dirs:
        raise FileNotFoundError(
            f"{dataset}: no subject folders found (expected index.json or sub-folders with keypoints.json)"
        )

    skipped: List[dict] = []
    loaded = []
    for d in subject_dirs:
        try:
            s = load_subject(d, require=("keypoints", "camera", "gt"))
        except (SubjectError, ValueError, FileNotFoundError) as err:
            skipped.append({"subject": d.name, "path": str(d), "error": str(err), **_field_of(err)})
            continue
        loaded.append(s)

    fitter_status = {}
    have_any = any(find_fits(fits_root, s.name) for s in loaded)
    if (run or not have_any) and loaded:
        fitter_status = run_fitter(loaded, fits_root, methods, model, progress=progress)

    rows: List[dict] = []
    missing: List[str] = []
    for s in loaded:
        found = find_fits(fits_root, s.name)
        if not found:
            missing.append(s.name)
            continue
        for method, folder in found.items():
            try:
                fit = read_fit(folder, model)
                metrics = score_fit(model, s, fit, iou=iou)
            except (SubjectError, ValueError, FileNotFoundError) as err:
                skipped.append(
                    {"subject": s.name, "method": method, "path": str(folder), "error": str(err), **_field_of(err)}
                )
                continue
            rows.append({"subject": s.name, "method": method, **metrics})

    report = {
        "dataset": str(dataset),
        "fits": str(fits_root),
        "units": {k: u for k, (_, u, _) in METRICS.items()},
        "methods": sorted({r["method"] for r in rows}, key=lambda m: (_method_rank(m), m)),
        "num_subjects": len(subject_dirs),
        "num_scored": len({r["subject"] for r in rows}),
        "summary": summarise(rows),
        "results": rows,
        "skipped": skipped,
        "missing_fits": missing,
    }
    if fitter_status:
        report["fitter"] = fitter_status
    return report


def _whole_body_dataset(subject_dirs) -> bool:
    """The first subject's keypoint file holds hand or face points (OpenPose whole-body JSON)."""
    for d in subject_dirs[:1]:
        try:
            wb = read_wholebody_parts(Path(d) / SUBJECT_FILES["keypoints"], 0)
        except ValueError:
            return False
        return wb is not None and wb.has_parts
    return False


def _field_of(err: Exception) -> dict:
    if isinstance(err, InputError):
        return {"file": err.source, "field": err.field}
    return {}


def summarise(rows: Iterable[dict]) -> Dict[str, Dict[str, dict]]:
    """``{method: {metric: {"mean", "median", "n"}}}`` over the result rows (NaNs ignored)."""
    rows = list(rows)
    out: Dict[str, Dict[str, dict]] = {}
    for method in sorted({r["method"] for r in rows}, key=lambda m: (_method_rank(m), m)):
        mrows = [r for r in rows if r["method"] == method]
        keys = [k for k in METRICS if any(k in r for r in mrows)]
        keys += sorted({k for r in mrows for k in r if k.startswith("time_") and k != "time_s"})
        out[method] = {}
        for k in keys:
            vals = np.array([r[k] for r in mrows if k in r and np.isfinite(r[k])], dtype=np.float64)
            if len(vals):
                out[method][k] = {"mean": float(vals.mean()), "median": float(np.median(vals)), "n": int(len(vals))}
    return out


def markdown_table(report: dict) -> str:
    """A Markdown table: one row per metric, mean and median per method."""
    summary = report["summary"]
    methods = report.get("methods") or list(summary)
    if not methods:
        return "_no fits were scored_"
    keys = [k for k in METRICS if any(k in summary[m] for m in methods)]
    keys += sorted({k for m in methods for k in summary[m] if k.startswith("time_") and k != "time_s"})
    head = "| metric | " + " | ".join(f"{m} mean | {m} median" for m in methods) + " |"
    sep = "|---|" + "---:|---:|" * len(methods)
    lines = [head, sep]
    for k in keys:
        if k in METRICS:
            label, unit, _ = METRICS[k]
        else:
            label, unit = f"Time: {k[5:]}", "s"
        label = f"{label} ({unit})" if unit else label
        cells = []
        for m in methods:
            s = summary[m].get(k)
            cells += ["-", "-"] if s is None else [_fmt(s["mean"], k), _fmt(s["median"], k)]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    n = ", ".join(f"{m}: {len({r['subject'] for r in report['results'] if r['method'] == m})}" for m in methods)
    lines.append("")
    lines.append(f"Subjects scored per method: {n}. Skipped: {len(report['skipped'])}.")
    return "\n".join(lines)


def _fmt(v: float, key: str) -> str:
    if key.startswith("energy"):
        return f"{v:.4g}"
    if key.startswith("iou"):
        return f"{v:.3f}"
    if key.startswith("time"):
        return f"{v:.2f}"
    return f"{v:.1f}"


def plot_errors(report: dict, path: os.PathLike, metrics: Sequence[str] = ("mpjpe", "pa_mpjpe", "pve", "iou")) -> Path:
    """Per-subject bars of a few metrics, one colour per method, saved as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = report["results"]
    methods = report.get("methods") or sorted({r["method"] for r in rows})
    subjects = list(dict.fromkeys(r["subject"] for r in rows))
    metrics = [k for k in metrics if any(k in r for r in rows)] or ["mpjpe"]
    fig, axes = plt.subplots(
        len(metrics), 1, figsize=(max(6.0, 0.45 * len(subjects) + 2), 2.4 * len(metrics)), squeeze=False
    )
    width = 0.8 / max(1, len(methods))
    x = np.arange(len(subjects))
    for ax, k in zip(axes[:, 0], metrics):
        label, unit, _ = METRICS.get(k, (k, "", True))
        for j, m in enumerate(methods):
            by = {r["subject"]: r.get(k, np.nan) for r in rows if r["method"] == m}
            ax.bar(x + (j - (len(methods) - 1) / 2) * width, [by.get(s, np.nan) for s in subjects], width, label=m)
        ax.set_ylabel(f"{label} ({unit})" if unit else label, fontsize=8)
        ax.grid(axis="y", alpha=0.3)
        ax.set_xticks(x)
        ax.set_xticklabels(
            [s.replace("subject_", "") for s in subjects], fontsize=7, rotation=90 if len(subjects) > 30 else 0
        )
    axes[0, 0].legend(fontsize=8)
    axes[0, 0].set_title(f"Per-subject errors: {Path(report['dataset']).name}", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
