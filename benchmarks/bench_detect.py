"""Benchmark of the built-in person detection (silfit.detect) on rendered subjects; prints
Markdown tables.

Subjects: ``--n`` (default 30) generated with silfit's synthetic generator
(:func:`silfit.synth.generate_dataset`): poses from the pose library, all yaws, camera
elevation/roll, person sizes from ``--fill`` of the image, ``--truncation`` of them cut
by the image border, plain/textured backgrounds, ``--size`` pixels square, noise-free
keypoints (so the subject's ``keypoints.json`` is the truth).

Measured:

* detection rate (a person found), detection time per image (detector + 2 landmark passes);
* keypoint error (px) per BODY_25 joint: median over the subjects of the distance between
  the detected and the true projection, for joints inside the image and detected;
* mask IoU against the true mask;
* the fit's PA-PVE (mm, similarity Procrustes on all vertices) from the detected inputs vs
  from the true keypoints (and masks): keypoint stage on every detected subject (batched),
  keypoint + silhouette stage on the first ``--silhouette`` of them (slow: ~10 s each).

    python benchmarks/bench_detect.py --n 30 --silhouette 8
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np

from silfit import load_body_model
from silfit.io.subjects import list_subjects, load_subject
from silfit.detect import DetectConfig, DetectionError, detect_people
from silfit.eval.metrics import mask_iou, procrustes_align
from silfit.io.keypoints import BODY25_NAMES


def pa_pve_mm(vertices, gt_vertices) -> float:
    return float(1000 * np.linalg.norm(procrustes_align(vertices, gt_vertices) - gt_vertices, axis=-1).mean())


def generate(out: Path, n: int, seed: int, size: int, fill, truncation: float):
    from silfit.synth import SynthConfig, generate_dataset

    cfg = SynthConfig(
        seed=seed, size=size, noise_px=0.0, fill=tuple(fill), truncation_prob=truncation, background="mixed"
    )
    generate_dataset(out, n, cfg)
    return [load_subject(p) for p in list_subjects(out)]


def detect_all(subjects, min_score):
    rows = []
    detect_people(subjects[0].image)  # load the models once (not timed)
    for s in subjects:
        t = time.perf_counter()
        try:
            person = detect_people(s.image, DetectConfig(min_score=min_score), source=s.name)[0]
        except DetectionError:
            person = None
        dt = time.perf_counter() - t
        row = {"subject": s.name, "found": person is not None, "time_s": dt, "person": person}
        if person is not None:
            kp = person.keypoints("body25")
            truth = s.gt.extras["keypoints_2d_clean"]
            valid = (kp[:, 2] > 0) & (s.gt.extras["keypoints_visibility"] > 0)
            err = np.where(valid, np.linalg.norm(kp[:, :2] - truth, axis=1), np.nan)
            row.update(err=err, iou=mask_iou(person.mask(), s.mask))
        rows.append(row)
    return rows


def fit_keypoint_stage(model, subjects, keypoint_sets):
    from silfit import fit_keypoints

    res = fit_keypoints(keypoint_sets, [s.camera for s in subjects], model=model, progress=False)
    return [pa_pve_mm(res.vertices[i], s.gt.vertices) for i, s in enumerate(subjects)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--fill", type=float, nargs=2, default=(0.3, 0.9), help="person size range (fraction of the image)")
    ap.add_argument("--truncation", type=float, default=0.15, help="fraction of subjects cut by the image border")
    ap.add_argument("--silhouette", type=int, default=0, help="also run the silhouette stage on this many subjects")
    ap.add_argument("--min-score", type=float, default=DetectConfig().min_score, help="detector score threshold")
    ap.add_argument("--data", help="use this generated folder instead of a temporary one (kept)")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        data = Path(args.data) if args.data else Path(tmp) / "subjects"
        if data.exists() and any(data.iterdir()):
            subjects = [load_subject(p) for p in list_subjects(data)][: args.n]
        else:
            t = time.perf_counter()
            subjects = generate(data, args.n, args.seed, args.size, args.fill, args.truncation)
            print(f"generated {len(subjects)} subjects ({args.size} px) in {time.perf_counter() - t:.0f} s")
        rows = detect_all(subjects, args.min_score)
        low = sum(r["found"] for r in detect_all(subjects, 0.3))

    found = [r for r in rows if r["found"]]
    times = np.array([r["time_s"] for r in rows]) * 1000
    err = np.stack([r["err"] for r in found]) if found else np.zeros((0, 25))
    ious = np.array([r["iou"] for r in found])
    print(f"\n## Detection on {len(rows)} rendered subjects ({args.size} x {args.size} px, seed {args.seed})\n")
    print("| metric | value |\n|---|---:|")
    print(
        f"| detection rate (min score {args.min_score}) | {len(found)}/{len(rows)} ({100 * len(found) / len(rows):.0f} %) |"
    )
    print(f"| detection rate (min score 0.3) | {low}/{len(rows)} ({100 * low / len(rows):.0f} %) |")
    print(f"| keypoint error, median over all joints (px) | {np.nanmedian(err):.1f} |")
    print(f"| keypoint error, mean of per-subject medians (px) | {np.nanmean(np.nanmedian(err, axis=1)):.1f} |")
    print(f"| keypoint error, 90th percentile (px) | {np.nanpercentile(err, 90):.1f} |")
    print(f"| mask IoU mean / median / min | {ious.mean():.3f} / {np.median(ious):.3f} / {ious.min():.3f} |")
    print(f"| detection time mean / median (ms) | {times.mean():.0f} / {np.median(times):.0f} |")
    missed = [r["subject"] for r in rows if not r["found"]]
    if missed:
        print(f"\nmissed: {', '.join(missed)}")

    print("\n| joint | median error (px) | subjects |\n|---|---:|---:|")
    for k, name in enumerate(BODY25_NAMES):
        col = err[:, k]
        n = int(np.isfinite(col).sum())
        print(f"| {name} | {np.nanmedian(col):.1f} | {n} |" if n else f"| {name} | - | 0 |")

    model = load_body_model()
    fit_subjects = [s for s, r in zip(subjects, rows) if r["found"]]
    people = [r["person"] for r in found]
    t = time.perf_counter()
    detected = fit_keypoint_stage(model, fit_subjects, [p.keypoint_set() for p in people])
    t_kp = time.perf_counter() - t
    truth = fit_keypoint_stage(model, fit_subjects, [s.keypoints for s in fit_subjects])
    print(f"\n## Fit PA-PVE (mm) on the {len(fit_subjects)} detected subjects\n")
    print("| inputs | stage | mean | median | subjects |\n|---|---|---:|---:|---:|")
    print(f"| detected keypoints | keypoints | {np.mean(detected):.1f} | {np.median(detected):.1f} | {len(detected)} |")
    print(f"| true keypoints | keypoints | {np.mean(truth):.1f} | {np.median(truth):.1f} | {len(truth)} |")
    print(f"\n(keypoint stage batched: {t_kp:.0f} s for {len(detected)} subjects)")

    if args.silhouette:
        from silfit.run import fit

        k = min(args.silhouette, len(fit_subjects))
        res = {"detected": [], "true": [], "detected_kp": detected[:k], "true_kp": truth[:k]}
        t = time.perf_counter()
        for s, p in zip(fit_subjects[:k], people[:k]):
            r = fit(p.keypoint_set(), p.mask(), s.camera, model=model, progress=False)
            res["detected"].append(pa_pve_mm(r.vertices, s.gt.vertices))
            r = fit(s.keypoints, s.mask, s.camera, model=model, progress=False)
            res["true"].append(pa_pve_mm(r.vertices, s.gt.vertices))
        dt = (time.perf_counter() - t) / (2 * k)
        print(f"\n## Fit PA-PVE (mm), keypoints + silhouette, first {k} detected subjects ({dt:.0f} s per fit)\n")
        print("| inputs | keypoint stage mean / median | + silhouette mean / median |\n|---|---:|---:|")
        for name, kp_key, sil_key in (
            ("detected keypoints + mask", "detected_kp", "detected"),
            ("true keypoints + mask", "true_kp", "true"),
        ):
            a, b = res[kp_key], res[sil_key]
            print(f"| {name} | {np.mean(a):.1f} / {np.median(a):.1f} | {np.mean(b):.1f} / {np.median(b):.1f} |")


if __name__ == "__main__":
    main()
