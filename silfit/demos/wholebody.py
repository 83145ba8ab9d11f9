"""``silfit demo --whole-body``: fit a shipped whole-body subject (body, hands, face) and show the hands
and the face close up, fitted from the body keypoints alone (hands, jaw and expression at rest) and
from all of them (keypoint stage, then the silhouette stage on the whole-body mesh).

Writes into the output folder::

    closeups.png       rows: left hand, right hand, face; columns: the image with its keypoints,
                       the body-only fit, the whole-body keypoint fit, the whole-body fit + silhouette
    summary.png        the whole body (input, body-only fit, whole-body fit) above the close-ups
    report.md/.json    hand, face, expression and body errors against the ground truth, per method
    fit/               the whole-body fit's output folder (as ``silfit fit`` writes it)
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from ..body import load_body_model
from ..camera import load_camera
from ..eval.score_wholebody import wholebody_errors
from ..fitting import KeypointFitter
from ..io.images import read_rgb
from ..io.subjects import read_truth
from ..io.wholebody import WholeBodyKeypoints, part_slices, read_wholebody
from ..outputs import figures
from ..run import image_job, run, write
from ..silhouette.masks import read_mask
from ..synth import SynthConfig, generate_dataset

__all__ = ["run_wholebody_demo", "summary_panels"]

SHIPPED_WHOLEBODY = Path(__file__).resolve().parents[2] / "data" / "synthetic_wholebody"
ROWS = (
    ("hand_pa_mm", "hand error, Procrustes (mm)"),
    ("hand_wrist_mm", "hand error, wrist-aligned (mm)"),
    ("face_pa_mm", "face error, Procrustes (mm)"),
    ("expression_err", "expression error (RMS)"),
    ("pa_pve_mm", "body PA-PVE (mm)"),
    ("time_s", "time (s)"),
)
METHODS = ("body keypoints only", "whole-body keypoints", "whole-body + silhouette")
WHOLE_TITLES = ("input + whole-body keypoints", METHODS[0], METHODS[2])


def summary_panels(whole: list, closeups: list, closeup_titles: list, columns: int = 4) -> tuple:
    """``summary.png``'s cells and titles, as many of one as of the other: the whole-body pictures
    (:data:`WHOLE_TITLES`) on the first row, empty cells to the row's end, then the close-ups."""
    if len(whole) != len(WHOLE_TITLES) or len(closeups) != len(closeup_titles):
        raise ValueError(
            f"{len(whole)} + {len(closeups)} pictures for {len(WHOLE_TITLES)} + {len(closeup_titles)} titles"
        )
    pad = -len(whole) % columns
    return list(whole) + [None] * pad + list(closeups), list(WHOLE_TITLES) + [""] * pad + list(closeup_titles)


def _subject_dir(out: Path, subject_dir: Optional[Path]) -> Path:
    if subject_dir is not None:
        return Path(subject_dir)
    shipped = SHIPPED_WHOLEBODY / "subject_000"
    if (shipped / "keypoints.json").is_file():
        return shipped
    target = out / "generated_subject"  # a pip install: the same kind of subject, generated
    generate_dataset(
        target,
        1,
        SynthConfig(seed=2024, size=384, noise_px=0.0, whole_body=True),
        load_body_model(kind="smplx"),
        progress=False,
    )
    return target / "subject_000"


def _zoom(image, camera, box, size: int = 320):
    """The ``box`` of ``image`` magnified to ``size`` pixels (longer side) and the camera that sees it."""
    x0, y0, x1, y1 = box
    s = size / max(x1 - x0, y1 - y0)
    w, h = max(1, round((x1 - x0) * s)), max(1, round((y1 - y0) * s))
    crop = cv2.resize(np.ascontiguousarray(image[y0:y1, x0:x1]), (w, h), interpolation=cv2.INTER_LINEAR)
    cam = replace(
        camera, fx=camera.fx * s, fy=camera.fy * s, cx=(camera.cx - x0) * s, cy=(camera.cy - y0) * s, width=w, height=h
    )
    return crop, cam, (x0, y0, s)


def _box(xy, conf, W, H, margin: float = 0.35, min_px: int = 12):
    pts = xy[conf > 0] if (conf > 0).any() else xy
    lo, hi = pts.min(0), pts.max(0)
    c, half = (lo + hi) / 2, max(float((hi - lo).max()) * (0.5 + margin), min_px)
    x0, y0 = int(max(0, c[0] - half)), int(max(0, c[1] - half))
    return x0, y0, int(min(W, c[0] + half + 1)), int(min(H, c[1] + half + 1))


def _closeup_rows(image, cam, kps, vertices: list, faces) -> tuple:
    """``(rows, labels)``: per hand and the face (where its keypoints are seen), its box from the keypoints magnified,
    the keypoints, then each of ``vertices`` drawn at that magnification."""
    sl = part_slices()
    rows, labels = [], []
    for part, label in (("hand_left", "left hand"), ("hand_right", "right hand"), ("face", "face")):
        xy, conf = kps.xy[sl[part]], kps.conf[sl[part]]
        if not (conf > 0).any():
            continue
        crop, zcam, (x0, y0, s) = _zoom(image, cam, _box(xy, conf, cam.width, cam.height))
        zxy = (xy - [x0, y0]) * s
        row = [figures.draw_keypoints(crop, zxy, figures.DETECTED, conf)]
        for v in vertices:
            row.append(figures.fit_overlay(crop, v, faces, zcam, zxy, None, conf))
        rows.append(row)
        labels.append(label)
    return rows, labels


def _score_table(scores: dict) -> str:
    """The demo's Markdown table: a row per metric of :data:`ROWS`, a column per method of :data:`METHODS`."""
    lines = ["| metric | " + " | ".join(METHODS) + " |", "|---|" + "---:|" * len(METHODS)]
    for key, label in ROWS:
        cells = [scores[m].get(key) for m in METHODS]
        lines.append(
            f"| {label} | "
            + " | ".join("-" if c is None else f"{c:.2f}" if key == "expression_err" else f"{c:.1f}" for c in cells)
            + " |"
        )
    return "\n".join(lines)


def _read_subject(d: Path) -> tuple:
    """``(whole-body keypoints, camera, image, mask, ground truth)`` of a whole-body subject folder."""
    wb = read_wholebody(d / "keypoints.json")
    cam = load_camera(d / "camera.json")
    image = read_rgb(d / "image.png", "image")
    mask = read_mask(d / "mask.png", size=(cam.width, cam.height))
    gt = read_truth(d / "gt.npz")
    return wb, cam, image, mask, gt


def _score_fits(model, fits: dict, gt) -> dict:
    """Per method of ``fits`` (``(vertices, joints, expression, seconds)``): its errors against ``gt`` and time."""
    truth = {"vertices": gt["vertices"], "joints": gt["joints"], "expression": gt["expression"]}
    scores = {}
    for name, (v, j, e, t) in fits.items():
        scores[name] = {
            **wholebody_errors(model, {"vertices": v, "joints": j, "expression": e}, truth),
            "time_s": float(t),
        }
    return scores


def _write_pictures(out: Path, image, cam, kps, fits: dict, final_vertices, faces) -> None:
    """``closeups.png`` (each part's box from its keypoints, magnified, the fitted meshes drawn at that
    magnification) and ``summary.png``."""
    rows, labels = _closeup_rows(image, cam, kps, [v for v, _, _, _ in fits.values()], faces)
    sheet = [img for row in rows for img in row]
    titles = [f"{lab}: {col}" for lab in labels for col in ("input + keypoints",) + METHODS]
    figures.contact_sheet(sheet, titles, out / "closeups.png", columns=4)
    whole = [
        figures.draw_keypoints(image, kps.xy, figures.DETECTED, kps.conf),
        figures.fit_overlay(image, fits[METHODS[0]][0], faces, cam),
        figures.fit_overlay(image, final_vertices, faces, cam),
    ]
    figures.contact_sheet(*summary_panels(whole, sheet, titles), out / "summary.png", columns=4)


def run_wholebody_demo(
    out: Path, subject_dir: Optional[Path] = None, progress: bool = False, silhouette_config=None
) -> dict:
    """Run the demo into ``out`` (see the module docstring); returns the report."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    d = _subject_dir(out, subject_dir)
    wb, cam, image, mask, gt = _read_subject(d)
    model = load_body_model(kind="smplx")
    faces = model.faces.cpu().numpy()
    kps = wb.as_keypoint_set()

    t0 = time.perf_counter()
    body_only = KeypointFitter(model, "wholebody").fit(
        WholeBodyKeypoints(wb.body, None, None, None).as_keypoint_set(), cam, progress=progress
    )
    t_body = time.perf_counter() - t0
    t0 = time.perf_counter()
    fitted = run(image_job(kps, mask, cam, model=model, silhouette_config=silhouette_config, progress=progress))
    t_whole = time.perf_counter() - t0
    write(fitted, out / "fit", overwrite=True, images={(0, 0): image})  # fitted without the image, drawn on it
    kp_stage = fitted.keypoint_fit

    fits = {
        METHODS[0]: (body_only.vertices[0], body_only.joints[0], body_only.extra_params["expression"][0], t_body),
        METHODS[1]: (
            kp_stage.vertices[0],
            kp_stage.joints[0],
            kp_stage.params["expression"][0],
            fitted.seconds["keypoints"],
        ),
        METHODS[2]: (fitted.vertices[0], fitted.joints[0], fitted.params["expression"].reshape(-1), t_whole),
    }
    scores = _score_fits(model, fits, gt)
    _write_pictures(out, image, cam, kps, fits, fitted.vertices[0], faces)

    table = _score_table(scores)
    report = {
        "subject": str(d),
        "scores": scores,
        "warnings": fitted.warnings,
        "iou": {"keypoint_stage": fitted.metrics.get("iou_keypoint_stage"), "final": fitted.metrics.get("iou")},
    }
    (out / "report.json").write_text(json.dumps(report, indent=2))
    (out / "report.md").write_text(f"# silfit demo --whole-body: {d.name}\n\n{table}\n")
    report["table"] = table
    return report
