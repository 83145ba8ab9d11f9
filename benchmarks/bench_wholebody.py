"""Whole-body keypoint fitting on fresh synthetic whole-body subjects (``bench_fit.py --whole-body N``).

Subjects: ``silfit synth --whole-body`` (library body and hand poses, expressions, jaw), all yaws, body
keypoint noise ``noise`` px, hands 0.5x and face 0.4x that (the generator's defaults), a seed no test
uses. Rows: the whole-body fit (SMPL-X-layout open model, ``wholebody`` layout), the same model fitted
to the body keypoints alone (hands, jaw, expression held at rest), and today's body-only fit (the open
SMPL-layout model, BODY_25; same template and vertex order, so PA-PVE compares directly).
Errors: :mod:`silfit.eval.score_wholebody` (mm; expression: RMS coefficient error).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np


def _errors(model, res, i, gt):
    from silfit.eval.score_wholebody import wholebody_errors

    pred = {"vertices": res.vertices[i], "joints": res.joints[i]}
    if "expression" in res.extra_params:
        pred["expression"] = res.extra_params["expression"][i]
    return wholebody_errors(model, pred, gt)


def _fit(fitter, sets, cams, batch):
    t0 = time.perf_counter()
    results = [fitter.fit(sets[s : s + batch], cams[s : s + batch], progress=False) for s in range(0, len(sets), batch)]
    return results, (time.perf_counter() - t0) / len(sets)


def _single_time(fitter, sets, cams, n):
    t0 = time.perf_counter()
    for i in range(n):
        fitter.fit(sets[i : i + 1], cams[i : i + 1], progress=False)
    return (time.perf_counter() - t0) / max(1, n)


def run_wholebody_benchmark(n=30, seed=41, noise=2.0, size=512, batch=16, singles=10, keep=None):
    import os

    from silfit.body import load_body_model
    from silfit.camera import load_camera
    from silfit.eval.metrics import pa_pve
    from silfit.fitting.keypoint_stage import KeypointFitter
    from silfit.synth.generate import SynthConfig, generate_dataset
    from silfit.io.wholebody import WholeBodyKeypoints, read_wholebody

    smplx, smpl = load_body_model(kind="smplx"), load_body_model()
    root = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="bench_wb_"))
    if not (root / "index.json").is_file():
        cfg = SynthConfig(seed=seed, size=size, noise_px=noise, clean=0, whole_body=True, frontal_first=False)
        generate_dataset(root, n, cfg, model=smplx)
    dirs = sorted(p for p in root.iterdir() if p.is_dir() and (p / "gt.npz").is_file())[:n]
    wbs = [read_wholebody(d / "keypoints.json") for d in dirs]
    cams = [load_camera(d / "camera.json") for d in dirs]
    gts = [dict(np.load(d / "gt.npz")) for d in dirs]
    whole = [w.as_keypoint_set() for w in wbs]
    body_only = [WholeBodyKeypoints(w.body, None, None, None, w.source).as_keypoint_set() for w in wbs]
    bodies = [w.body for w in wbs]

    rows = {}
    fx = KeypointFitter(smplx, "wholebody")
    fb = KeypointFitter(smpl, "body25")
    for label, fitter, sets in (
        ("whole body (SMPL-X model, body+hands+face)", fx, whole),
        ("body keypoints only (SMPL-X model, parts at rest)", fx, body_only),
        ("body only today (open SMPL model, BODY_25)", fb, bodies),
    ):
        results, t_batch = _fit(fitter, sets, cams, batch)
        t_single = _single_time(fitter, sets, cams, min(singles, len(sets)))
        errs = []
        for r in results:
            for i in range(len(r)):
                g = gts[len(errs)]
                if fitter is fb:
                    errs.append(
                        {"pa_pve_mm": 1000 * pa_pve(r.vertices[i].astype(np.float64), g["vertices"].astype(np.float64))}
                    )
                else:
                    errs.append(_errors(smplx, r, i, g))
        rows[label] = (errs, t_single, t_batch)
    print(
        f"\nWhole-body keypoint stage: {len(dirs)} fresh subjects (silfit synth --whole-body --seed {seed}, {size} px, "
        f"all yaws, body noise {noise:g} px, hands {0.5 * noise:g} px, face {0.4 * noise:g} px), CPU, load {os.getloadavg()[0]:.1f}"
    )
    keys = ("hand_pa_mm", "hand_wrist_mm", "face_pa_mm", "expression_err", "pa_pve_mm")
    print(
        "| fit | hand PA mm | hand wrist-aligned mm | face PA mm | expression RMS | PA-PVE mm | s/image single | s/image batch %d |"
        % batch
    )
    print("|---|---|---|---|---|---|---|---|")
    for label, (errs, t1, tb) in rows.items():
        cells = []
        for k in keys:
            v = [e[k] for e in errs if k in e]
            cells.append(f"{np.mean(v):.1f} / {np.median(v):.1f}" if v else "-")
        print(f"| {label} | " + " | ".join(cells) + f" | {t1:.2f} | {tb:.2f} |", flush=True)
    print(
        "(mean / median; PA: similarity Procrustes per part; the body-only rows keep hands, jaw and expression at rest)"
    )
    return rows
