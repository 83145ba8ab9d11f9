"""The demo: fit a shipped synthetic subject end to end and show what the silhouette adds.

Writes into the output folder::

    01_input.png               the image with its (noisy) keypoints
    02_mask.png                the person mask given to the fit
    03_keypoint_fit.png        keypoint-stage body over the image
    04_silhouette_fit.png      keypoint + silhouette body over the image
    05_silhouette_match.png    silhouette vs mask before | after (white both, red body only, blue mask only)
    06_iou_curve.png           IoU and energy per silhouette step
    07_vertex_error.png        per-vertex error against the ground truth, both methods, front and side
    summary.png                all of the above on one sheet
    report.md, report.json     the keypoint-only vs keypoint+silhouette table against ground truth
    fit/                       the full fit output (as ``silfit fit`` writes it)
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import numpy as np

from ..body import load_body_model
from ..eval.evaluate import FitParams, score_fit
from ..io.subjects import load_subject, read_image
from ..outputs import figures
from ..run import image_job, run, write
from ..synth import SynthConfig, generate_dataset

__all__ = ["default_subject", "run_demo", "report_table"]

#: The shipped synthetic set, beside the package in a source checkout.
SHIPPED_SET = Path(__file__).resolve().parents[2] / "data" / "synthetic"

ROWS = (
    ("mpjpe", "MPJPE (mm)"),
    ("pa_mpjpe", "PA-MPJPE (mm)"),
    ("pve", "PVE (mm)"),
    ("shape_pve", "shape-only PVE (mm)"),
    ("shape_pve_scaled", "shape-only PVE, stature aligned (mm)"),
    ("transl_err", "translation error (mm)"),
    ("reproj_px", "2D reprojection error (px)"),
    ("iou", "silhouette IoU"),
    ("time_s", "time (s)"),
)


def default_subject(out: Path, name: str = "subject_000") -> Path:
    """The shipped subject ``name``; without a source checkout (a pip install), the same
    kind of subject is generated into ``out`` with a fixed seed."""
    shipped = SHIPPED_SET / name
    if (shipped / "keypoints.json").is_file():
        return shipped
    target = out / "generated_subject"
    generate_dataset(target, 1, SynthConfig(seed=2024, size=256, noise_px=0.0), load_body_model(), progress=False)
    return target / "subject_000"


def _score(model, subject, params: dict, camera, seconds: float) -> dict:
    fit = FitParams(**{k: np.asarray(v).reshape(-1) for k, v in params.items()}, camera=camera)
    scores = score_fit(model, subject, fit, iou=True)
    scores["time_s"] = seconds
    return scores


def _table(before: dict, after: dict) -> str:
    lines = ["| metric | keypoints only | keypoints + silhouette | change |", "|---|---:|---:|---:|"]
    for key, label in ROWS:
        if key in before and key in after:
            a, b = before[key], after[key]
            change = f"{100 * (b - a) / a:+.0f} %" if a else "-"
            fmt = "{:.3f}" if key == "iou" else "{:.2f}" if key in ("reproj_px", "time_s") else "{:.1f}"
            lines.append(f"| {label} | {fmt.format(a)} | {fmt.format(b)} | {change} |")
    return "\n".join(lines)


def report_table(report: dict) -> str:
    """The table ``silfit demo`` prints, from its ``report.json`` (the README's demo table is this,
    written by ``tools/readme_demo.py``)."""
    return _table(report["keypoints_only"], report["keypoints_plus_silhouette"])


def _person_box(masks, margin: float = 0.12) -> tuple:
    """``(x0, y0, x1, y1)``: a square around the given masks (the person's and the fitted
    bodies'), for close-ups."""
    covered = np.logical_or.reduce(masks)
    mask = masks[0]
    ys, xs = np.nonzero(covered)
    cx, cy = (xs.min() + xs.max()) / 2, (ys.min() + ys.max()) / 2
    half = (1 + 2 * margin) * max(xs.max() - xs.min(), ys.max() - ys.min()) / 2
    H, W = mask.shape
    x0, y0 = int(max(0, cx - half)), int(max(0, cy - half))
    return x0, y0, int(min(W, cx + half + 1)), int(min(H, cy + half + 1))


def _crop(image: np.ndarray, box: tuple, min_size: int = 400) -> np.ndarray:
    """The box of ``image``, enlarged by a whole factor (nearest neighbour, so pixels stay
    visible) until its longer side is at least ``min_size``."""
    x0, y0, x1, y1 = box
    crop = image[y0:y1, x0:x1]
    factor = max(1, int(np.ceil(min_size / max(crop.shape[:2]))))
    return np.repeat(np.repeat(crop, factor, axis=0), factor, axis=1)


def _closeups(subject, fitted, kp_fit, faces: np.ndarray) -> dict:
    """The close-ups ``01_input.png`` to ``05_silhouette_match.png`` of the module docstring, by file name."""
    cam, kps = subject.camera, subject.keypoints
    box = _person_box([subject.mask, kp_fit.masks[0], fitted.masks[0]])
    close = lambda image: _crop(image, box)  # noqa: E731  (close-ups around the person)
    match = lambda body: close(figures.silhouette_comparison(body, subject.mask))  # noqa: E731
    pictures = {
        "01_input.png": close(figures.draw_keypoints(subject.image, kps.xy, figures.DETECTED, kps.conf)),
        "02_mask.png": close(np.repeat(subject.mask[..., None].astype(np.uint8) * 255, 3, axis=2)),
        "03_keypoint_fit.png": close(
            figures.fit_overlay(subject.image, kp_fit.vertices[0], faces, cam, kps.xy, None, kps.conf)
        ),
        "04_silhouette_fit.png": close(
            figures.fit_overlay(subject.image, fitted.vertices[0], faces, cam, kps.xy, None, kps.conf)
        ),
    }
    match_kp, match_sil = match(kp_fit.masks[0]), match(fitted.masks[0])
    pictures["05_silhouette_match.png"] = np.hstack(
        [match_kp, np.full((match_kp.shape[0], 6, 3), 128, np.uint8), match_sil]
    )
    return pictures


def _write_vertex_errors(subject, fitted, kp_fit, faces, path: Path) -> None:
    """``07_vertex_error.png``: the per-vertex error (mm, pelvis-aligned) of both fits on the ground truth."""
    gt_v = subject.gt.vertices
    pelvis = lambda v, j: v - j[0]  # noqa: E731  (PVE is pelvis-aligned)
    gt_j = subject.gt.joints
    errors = [
        1000 * np.linalg.norm(pelvis(kp_fit.vertices[0], kp_fit.joints[0]) - pelvis(gt_v, gt_j), axis=1),
        1000 * np.linalg.norm(pelvis(fitted.vertices[0], fitted.joints[0]) - pelvis(gt_v, gt_j), axis=1),
    ]
    figures.error_heatmap(gt_v, faces, errors, ["keypoints only", "keypoints + silhouette"], path)


def _write_summary(out: Path, pictures: dict) -> None:
    """``summary.png``: the close-ups and the two plots on one sheet."""
    sheet = [pictures[n] for n in sorted(pictures)] + [
        read_image(out / "06_iou_curve.png"),
        read_image(out / "07_vertex_error.png"),
    ]
    titles = [
        "input + keypoints",
        "mask",
        "keypoint fit",
        "keypoint + silhouette fit",
        "silhouette before | after",
        "silhouette stage",
        "per-vertex error (mm)",
    ]
    figures.contact_sheet(sheet, titles, out / "summary.png", columns=4)


def run_demo(out: Path, subject_dir: Optional[Path] = None, progress: bool = False, silhouette_config=None) -> dict:
    """Run the demo into ``out`` (see the module docstring); returns the report."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    subject = load_subject(subject_dir or default_subject(out), require=("keypoints", "camera", "mask", "gt"))
    model = load_body_model()
    faces = model.faces.cpu().numpy()
    cam, kps = subject.camera, subject.keypoints

    job = image_job(
        kps, subject.mask, cam, model=model, silhouette_config=silhouette_config, progress=progress, image=subject.image
    )
    job.mask_sources[(0, 0)] = str(subject.file("mask"))
    fitted = run(job)  # the path every mode takes (silfit.run)
    kp_fit, seconds = fitted.keypoint_fit, fitted.seconds
    write(fitted, out / "fit", overwrite=True)

    before = _score(model, subject, kp_fit.frame_params(0), cam, seconds["keypoints"])
    after = _score(model, subject, fitted.frame_params(0), cam, seconds["keypoints"] + seconds["silhouette"])
    table = _table(before, after)

    pictures = _closeups(subject, fitted, kp_fit, faces)
    for name, image in pictures.items():
        figures.write_png(out / name, image)
    figures.iou_curve(fitted.history, out / "06_iou_curve.png")
    _write_vertex_errors(subject, fitted, kp_fit, faces, out / "07_vertex_error.png")
    _write_summary(out, pictures)

    report = {
        "subject": str(subject.path),
        "keypoints_only": before,
        "keypoints_plus_silhouette": after,
        "silhouette_steps": fitted.metrics["silhouette_steps"],
        "warnings": fitted.warnings,
    }
    (out / "report.json").write_text(json.dumps(report, indent=2))
    (out / "report.md").write_text(f"# silfit demo: {subject.path.name}\n\n{table}\n")
    report["table"] = table
    return report
