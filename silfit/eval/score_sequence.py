"""Scoring sequence fits (``silfit synth --videos`` datasets) against their per-frame truth.

Methods: ``per_frame`` (the single-image keypoint stage on every frame, the fits a
sequence fit starts from: ``FITS/<seq>/temporal/stages/per_frame/params.npz``) and
``temporal`` (the joint refinement with one shape and the temporal terms:
``FITS/<seq>/temporal/params.npz``). Metrics per sequence: PA-MPJPE and MPJPE (mean over
frames, mm), acceleration error (mm/frame^2, pelvis-aligned joints, see
:func:`silfit.eval.metrics.acceleration_error`), shape error (shape-only PVE of the T-posed
bodies, mm; per-frame fits: the mean over frames of each frame's shape), the PA-MPJPE of
bridged frames, and seconds per frame.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import torch
from tqdm import tqdm

from ..body import load_body_model
from ..camera import load_camera
from ..errors import InputError, interruption
from ..inputs import video_job
from ..io.fit import read_fit
from ..io.subjects import read_truth
from ..io.video import read_sequence
from ..run import run as run_job, write
from ..synth.motion import SEQUENCE_FORMAT
from .metrics import acceleration_error, mpjpe, pa_mpjpe, shape_pve

__all__ = ["SEQUENCE_METRICS", "evaluate_sequences", "is_sequence_dataset", "score_sequence", "sequence_table"]

#: metric -> (label, unit)
SEQUENCE_METRICS = {
    "pa_mpjpe": ("PA-MPJPE", "mm"),
    "mpjpe": ("MPJPE", "mm"),
    "accel": ("acceleration error", "mm/frame^2"),
    "shape": ("shape error (T-pose PVE)", "mm"),
    "pa_mpjpe_bridged": ("PA-MPJPE of bridged frames", "mm"),
    "seconds_per_frame": ("seconds per frame", "s"),
}
METHODS = ("per_frame", "temporal")


def _index(dataset: Path) -> Optional[dict]:
    f = Path(dataset) / "index.json"
    if not f.is_file():
        return None
    try:
        return json.loads(f.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise InputError(f, f"not valid JSON ({err})") from None


def is_sequence_dataset(dataset: os.PathLike) -> bool:
    """Whether ``dataset`` is a ``silfit synth --videos`` dataset (its ``index.json`` says so)."""
    index = _index(Path(dataset))
    return isinstance(index, dict) and index.get("format") == SEQUENCE_FORMAT


def _joints(model, params: Dict[str, np.ndarray], F: int) -> np.ndarray:
    T = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=model.dtype)  # noqa: E731
    betas = np.asarray(params["betas"])
    betas = np.repeat(betas[None], F, 0) if betas.ndim == 1 else betas
    with torch.no_grad():
        out = model(
            betas=T(betas),
            body_pose=T(params["body_pose"]),
            global_orient=T(params["global_orient"]),
            transl=T(params["transl"]),
        )
    return out.joints.double().cpu().numpy()


def score_sequence(model, gt: Dict[str, np.ndarray], params: Dict[str, np.ndarray], bridged=None) -> Dict[str, float]:
    """Metrics (mm) of one sequence fit ``params`` (``betas [L]`` or ``[F, L]``, the rest
    ``[F, w]``) against the truth ``gt`` (``gt.npz`` of a synthetic sequence)."""
    F = int(np.asarray(gt["body_pose"]).shape[0])
    if np.asarray(params["body_pose"]).shape[0] != F:
        raise ValueError(f"the fit has {np.asarray(params['body_pose']).shape[0]} frames, the truth {F}")
    pred = _joints(model, params, F)
    true = np.asarray(gt["joints"], dtype=np.float64)
    pa = np.asarray(pa_mpjpe(pred, true)) * 1000
    betas = np.asarray(params["betas"])
    shape = (
        shape_pve(model, betas, gt["betas"])
        if betas.ndim == 1
        else np.mean(shape_pve(model, betas, np.repeat(gt["betas"][None], F, 0)))
    )
    row = {
        "pa_mpjpe": float(pa.mean()),
        "mpjpe": float(np.mean(mpjpe(pred, true)) * 1000),
        "accel": acceleration_error(pred, true) * 1000 if F >= 3 else float("nan"),  # needs 3 frames
        "shape": float(shape) * 1000,
    }
    if bridged is not None and np.any(bridged):
        row["pa_mpjpe_bridged"] = float(pa[np.asarray(bridged, dtype=bool)].mean())
    return row


def _fit_sequence(d: Path, out: Path, model, config) -> None:
    """Fit the sequence in ``d`` through the one path (silfit.run), as silfit fit --sequence, into ``out``."""
    seq = read_sequence(d)  # through the one path (silfit.run), as silfit fit --sequence
    job = video_job(
        seq.frames,
        load_camera(d / "camera.json"),
        model,
        config=config,
        progress=False,
        numbers=seq.numbers,
        inputs=seq,
        warnings=seq.warnings,
    )
    write(run_job(job), out, video=False, overwrite=True)


def _read_sequence_fit(d: Path, out: Path, model, run: bool, config) -> tuple:
    """``(truth, metrics.json, temporal fit, per-frame fit)`` of the sequence in ``d`` (fitted first with ``run`` or
    when ``out`` holds no fit)."""
    gt = read_truth(d / "gt.npz")
    if run or not (out / "params.npz").is_file():
        _fit_sequence(d, out, model, config)
    metrics = json.loads((out / "metrics.json").read_text(encoding="utf-8"))
    fit = read_fit(out, sizes={**model.parameter_sizes, "betas": None})
    per = read_fit(out / "stages" / "per_frame", sizes={**model.parameter_sizes, "betas": None})
    return gt, metrics, fit, per


def _sequence_rows(model, name: str, gt, metrics: dict, fit, per) -> List[dict]:
    """The result rows (``per_frame``, ``temporal``) of one sequence."""
    rows = []
    t, F = metrics.get("timings", {}), fit.num_frames
    bridged = np.isin(fit.frame_numbers, metrics.get("bridged_frames", []))
    every = lambda f: {n: np.repeat(v, F, 0) if v.shape[0] == 1 else v for n, v in f.params.items()}  # noqa: E731
    for method, params, seconds in (
        ("per_frame", every(per), t.get("per_frame_init")),
        ("temporal", every(fit), t.get("total")),
    ):
        row = {"subject": name, "method": method, **score_sequence(model, gt, params, bridged)}
        if seconds is not None:
            row["seconds_per_frame"] = float(seconds) / F
        rows.append(row)
    return rows


def _sequence_summary(rows: List[dict]) -> dict:
    """``{method: {metric: {"mean", "median", "n"}}}`` over the result rows (NaNs ignored)."""
    summary = {}
    for m in METHODS:
        mrows = [r for r in rows if r["method"] == m]
        summary[m] = {}
        for k in SEQUENCE_METRICS:
            vals = np.array([r[k] for r in mrows if k in r and np.isfinite(r[k])])
            if len(vals):
                summary[m][k] = {"mean": float(vals.mean()), "median": float(np.median(vals)), "n": int(len(vals))}
    return summary


def evaluate_sequences(
    dataset: os.PathLike,
    fits: Optional[os.PathLike] = None,
    model=None,
    run: bool = False,
    progress: bool = False,
    config=None,
) -> dict:
    """Score every sequence of ``dataset`` (fitting it first with ``run`` or when no fit
    exists: ``FITS/<seq>/temporal/``, written by :func:`silfit.run.write`)."""
    root = Path(dataset)
    index = _index(root)
    if not is_sequence_dataset(root):
        raise InputError(
            root / "index.json", "not a sequence dataset (expected format silfit-synthetic-sequence)", field="format"
        )
    model = load_body_model() if model is None else model
    fits_root = Path(fits) if fits else root / "fits"
    rows: List[dict] = []
    skipped: List[dict] = []
    names = [s["name"] for s in index.get("sequences", [])]
    iterator = names
    if progress:
        iterator = tqdm(names, desc="silfit eval (sequences)", unit="sequence")
    for name in iterator:
        try:
            gt, metrics, fit, per = _read_sequence_fit(root / name, fits_root / name / "temporal", model, run, config)
        except (ValueError, OSError) as err:
            if interruption(err) is not None:  # stopped while writing: not this subject's failure
                raise
            skipped.append({"subject": name, "error": " ".join(str(err).split())})
            continue
        rows += _sequence_rows(model, name, gt, metrics, fit, per)
    return {
        "dataset": str(root),
        "kind": "sequence",
        "methods": list(METHODS),
        "results": rows,
        "summary": _sequence_summary(rows),
        "skipped": skipped,
        "missing_fits": [],
    }


def sequence_table(report: dict, methods: Sequence[str] = METHODS) -> str:
    """A Markdown table: one row per metric, mean and median per method, and the ratio
    ``per_frame / temporal`` of the means."""
    summary = report["summary"]
    lines = [
        "| metric | " + " | ".join(f"{m} mean | {m} median" for m in methods) + " | per-frame / temporal |",
        "|---|" + "---:|---:|" * len(methods) + "---:|",
    ]
    for k, (label, unit) in SEQUENCE_METRICS.items():
        cells, means = [], []
        for m in methods:
            s = summary.get(m, {}).get(k)
            cells += (
                ["-", "-"]
                if s is None
                else [
                    f"{s['mean']:.2f}" if unit == "s" else f"{s['mean']:.1f}",
                    f"{s['median']:.2f}" if unit == "s" else f"{s['median']:.1f}",
                ]
            )
            means.append(None if s is None else s["mean"])
        ratio = f"{means[0] / means[-1]:.2f}x" if None not in means and means[-1] else "-"
        lines.append(f"| {label} ({unit}) | " + " | ".join(cells) + f" | {ratio} |")
    n = len({r["subject"] for r in report["results"]})
    lines += ["", f"Sequences scored: {n}. Skipped: {len(report['skipped'])}."]
    return "\n".join(lines)
