"""Benchmark of rig fitting: one body seen by 1, 2, 4 and 8 calibrated cameras; prints Markdown tables.

One synthetic set of ``--subjects`` rig subjects (:mod:`silfit.synth.camera_rigs`: library poses,
all yaws, shape from the prior, 8 cameras on a ring at varied heights, ``--noise`` px
keypoint noise, ``--size`` px images; seed ``--seed``, which no test uses). Each view
count uses evenly spread cameras of the same rig (1: view 0; 2: views 0, 2 (90 degrees
apart); 4: views 0, 2, 4, 6; 8: all), so every row sees the same bodies.

Per view count: the keypoint stage on all subjects (one batch), then the silhouette stage
(every view with its mask rendered) on the first ``--silhouette`` subjects (it costs about
one render per view and step). Metrics (:func:`silfit.eval.score_rig.score_rig_fit`, mm):
PA-PVE, PVE in world coordinates without any alignment, shape error (T-posed PVE), mean
and worst-view IoU, seconds per subject.

    python benchmarks/bench_rig.py --subjects 30 --silhouette 4 --seed 1515 --keep /tmp/rig30
    python benchmarks/bench_rig.py --subjects 30 --silhouette 0 --seed 1515 --keep /tmp/rig30   # keypoints only, same set
    python benchmarks/bench_rig.py --subjects 30 --silhouette 0 --views 2,4 --start rest,points   # issue 25: the 3D start

    python benchmarks/bench_rig.py --subjects 30 --silhouette 0 --views 2,3,4 --rings --points 0,1   # issue 25: 2-view rigs

``--rings``: each view count gets its own rig set, as ``silfit synth --cameras N`` makes them
(N cameras on a ring, two at 90 degrees; same seed, so the same bodies) instead of subsets of
one 8-camera ring. ``--points`` compares weights of the keypoint stage's ``points`` term
(``KeypointFitConfig.points_weight`` and ``final_points_weight``; 0: the stage before it).

``--start rest`` is the keypoint stage as it was before the start from the triangulated keypoints
(:func:`silfit.fitting.rig_fit.pose_from_points`); the summary line gives the 2-view over 4-view
ratio of the world PVE per start.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np

from silfit import load_body_model
from silfit.eval.score_rig import score_rig_fit, subset_truth
from silfit.fitting.keypoint_stage import KeypointFitConfig, KeypointFitter
from silfit.fitting.problem import Problem
from silfit.fitting.rig_fit import fit_rig_keypoints
from silfit.inputs.rig import rig_problem
from silfit.io.rig import load_rig
from silfit.fitting.rig_pipeline import refine_rig_fits
from silfit.synth.generate import SynthConfig
from silfit.synth.camera_rigs import RigConfig, generate_rig_dataset

SUBSETS = {1: [0], 2: [0, 2], 4: [0, 2, 4, 6], 8: list(range(8))}
TARGETS = {"pve_world": 25.0, "shape_pve": 10.0}  # 4 views (issue 15)


def subset(problem: Problem, idx) -> Problem:
    obs = [o for o in problem.observations if o.view_index in idx]
    from dataclasses import replace

    return Problem([replace(o, view_index=idx.index(o.view_index)) for o in obs], problem.shared)


def method_name(start: str, points) -> str:
    name = "keypoints" if start == "points" else f"keypoints ({start} start)"
    return name if points is None else f"{name}, points {points:g}"


def table(rows, title):
    keys = [
        ("pa_pve", "PA-PVE"),
        ("pve_world", "PVE world"),
        ("shape_pve", "shape"),
        ("iou", "IoU"),
        ("iou_worst", "IoU worst view"),
        ("reproj_px", "reproj px"),
        ("facing_ok", "facing ok %"),
    ]
    print(f"\n### {title}\n")
    print("| views | method | subjects | " + " | ".join(f"{k} mean / median" for _, k in keys) + " | s / subject |")
    print("|---:|---|---:|" + "---:|" * (len(keys) + 1))
    for (C, method), rs in rows.items():
        cells = []
        for k, _ in keys:
            v = np.array([r[k] for r in rs["metrics"] if k in r])
            fmt = "{:.3f}" if k.startswith("iou") else "{:.1f}"
            cells.append(f"{fmt.format(v.mean())} / {fmt.format(np.median(v))}" if len(v) else "-")
        print(f"| {C} | {method} | {len(rs['metrics'])} | " + " | ".join(cells) + f" | {rs['seconds']:.1f} |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--subjects", type=int, default=30)
    ap.add_argument("--silhouette", type=int, default=4, help="subjects also refined by the silhouette stage (0: none)")
    ap.add_argument("--views", default="1,2,4,8")
    ap.add_argument("--seed", type=int, default=1515)
    ap.add_argument("--noise", type=float, default=2.0)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument(
        "--start",
        default="points",
        help="comma-separated starts of the keypoint stage (silfit.fitting.rig_fit.fit_rig_keypoints: points, "
        "rest, both); the silhouette stage refines the last one's fits",
    )
    ap.add_argument("--rings", action="store_true", help="one rig set per view count (silfit synth --cameras N)")
    ap.add_argument(
        "--points", default=None, help="comma-separated weights of the points term to compare (default: the config's)"
    )
    ap.add_argument("--keep", help="keep the generated rig dataset in this folder (reused when it holds one)")
    args = ap.parse_args(argv)
    model = load_body_model()
    root = Path(args.keep or tempfile.mkdtemp(prefix="bench_rig_"))
    t0 = time.perf_counter()
    counts = [int(c) for c in args.views.split(",")]

    def load_set(folder, views):
        if not (args.keep and (folder / "index.json").is_file()):  # else: the kept set of an earlier run
            generate_rig_dataset(
                folder,
                args.subjects,
                SynthConfig(seed=args.seed, size=args.size, noise_px=args.noise),
                RigConfig(views=views),
                model=model,
            )
        out = []
        for i in range(args.subjects):
            d = folder / f"subject_{i:03d}"
            views = load_rig(d)
            gt = np.load(d / "gt.npz")
            out.append((views, rig_problem(views), {k: gt[k] for k in gt.files}))
        return out

    sets = {C: load_set(root / f"views_{C}", C) for C in counts} if args.rings else {None: load_set(root, 8)}
    print(f"{args.subjects} subjects per set ready in {time.perf_counter() - t0:.0f} s ({root})")
    weights = [None] if args.points is None else [float(w) for w in args.points.split(",")]
    fitters = {
        w: KeypointFitter(model)
        if w is None
        else KeypointFitter(model, config=KeypointFitConfig(points_weight=w, final_points_weight=w))
        for w in weights
    }
    fitter = fitters[weights[-1]]
    rows = {}
    for C in counts:
        subjects = sets[C] if args.rings else sets[None]
        idx = list(range(C)) if args.rings else SUBSETS[C]
        probs = [subset(p, idx) for _, p, _ in subjects]
        vsel = [[v[i] for i in idx] for v, _, _ in subjects]
        truth = [subset_truth(g, idx) for _, _, g in subjects]
        for w in weights:
            for start in args.start.split(","):
                t = time.perf_counter()
                fits = fit_rig_keypoints(fitters[w], probs, start=start)
                kp_s = (time.perf_counter() - t) / len(probs)
                method = method_name(start, w)
                rows[(C, method)] = {
                    "seconds": kp_s,
                    "metrics": [
                        score_rig_fit(model, v, p, g, f.params) for v, p, f, g in zip(vsel, probs, fits, truth)
                    ],
                }
        n = min(args.silhouette, len(probs))
        if n:
            t = time.perf_counter()
            res = refine_rig_fits(
                model,
                [([x.name for x in v], p, f) for v, p, f in zip(vsel[:n], probs[:n], fits[:n])],
                pose_prior=fitter.pose_prior,
            )
            sil_s = (time.perf_counter() - t) / n
            rows[(C, "keypoints (same subjects)")] = {"seconds": kp_s, "metrics": rows[(C, method)]["metrics"][:n]}
            rows[(C, "+ silhouette")] = {
                "seconds": kp_s + sil_s,
                "metrics": [score_rig_fit(model, v, p, g, r.params) for v, p, r, g in zip(vsel, probs, res, truth)],
            }
        print(f"{C} views done ({time.perf_counter() - t0:.0f} s)", flush=True)
    table(
        rows,
        f"Rigs: {args.subjects} subjects (seed {args.seed}, {args.noise} px noise, {args.size} px), "
        f"silhouette stage on {min(args.silhouette, args.subjects)}",
    )
    for method in dict.fromkeys(m for _, m in rows):
        if (2, method) in rows and (4, method) in rows:
            two, four = (np.array([m["pve_world"] for m in rows[(c, method)]["metrics"]]) for c in (2, 4))
            print(
                f"{method}: PVE world 2 views {two.mean():.1f} mm (max {two.max():.1f}) / 4 views {four.mean():.1f} mm "
                f"(max {four.max():.1f}) = {two.mean() / four.mean():.2f}x (target <= 1.5x)"
            )
    if (4, "keypoints") in rows:
        for method in ("keypoints", "+ silhouette"):
            if (4, method) in rows:
                ms = rows[(4, method)]["metrics"]
                parts = [f"{k} mean {np.mean([m[k] for m in ms]):.1f} mm (target <= {v:g})" for k, v in TARGETS.items()]
                print(f"4 views, {method}: " + "; ".join(parts))


if __name__ == "__main__":
    main()
