"""Depth ambiguity on the default image path: generated hard subjects, keypoint stage then silhouettes, before and after.

Issue 25's targets are measured on generated hard sets (``silfit synth --poses hard``: squats, kneeling,
running, hands at the face; front and back views) with the default image path: the keypoint stage in
batches of ``--batch`` and :func:`silfit.fitting.image_fit.refine_batch` (the silhouette stage with its clothing
trim and plausibility guard) against the generator's noise-free masks. This runs that path twice on the
same subjects, *before* with the keypoint settings of ``--baseline`` (the older behaviour, kept behind its
option) and *after* with today's defaults, and prints per run:

* PA-PVE of the keypoint stage's fit and of the fit with silhouettes (mean / median), fits above 150 mm;
* how many fits above 150 mm carry the depth warning (:func:`~silfit.fitting.plausibility.depth_warnings`) and how
  many below 60 mm carry one too (false alarms);
* search failures: the truth's keypoint energy (:meth:`~silfit.fitting.KeypointFitter.energy_at`) below the
  fit's; the truth's shape and the keypoints' noise make this a lower bound on the search's misses;
* CPU seconds per subject of each stage.

Seeds run in parallel processes (``--workers``, one torch thread each), so every fit is the same as in one.

    python benchmarks/bench_hard_set.py --seeds 15300,15301 --baseline branches.hinge=False
    python benchmarks/bench_hard_set.py --seeds 15400,15401 --silhouette-baseline choice_margin=0

``--silhouette-baseline``: the before run's :class:`SilhouetteFitConfig` settings instead (today's keypoint stage).
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch
from bench_ambiguity import NAMES, hard_set

from silfit import load_body_model
from silfit.eval.metrics import pa_pve
from silfit.fitting import KeypointFitter
from silfit.fitting.silhouette_stage import SilhouetteFitConfig
from silfit.fitting.image_fit import refine_batch
from silfit.fitting.plausibility import depth_warnings
from silfit.runner.worker import config_with, keypoint_config


def run_seed(seed: int, n: int, size: int, batch: int, settings: dict, silhouette: dict = None) -> list:
    """Per subject of seed ``seed``: PA-PVE of the keypoint fit and with silhouettes (mm), the depth
    warning, fit and truth energies and CPU seconds, with the keypoint ``settings`` and the silhouette stage's
    ``silhouette`` settings (``{}``/``None``: defaults)."""
    torch.set_num_threads(1)
    model = load_body_model()
    sets, cams, gts, masks = hard_set(n, seed, size, model, masks=True)
    fitter = KeypointFitter(model, config=keypoint_config(dict(settings)))
    sil_config = config_with(SilhouetteFitConfig, dict(silhouette or {}), stage="silhouette")
    rows = []
    for b in range(0, n, batch):
        sl = slice(b, b + batch)
        t0 = time.process_time()
        kp = fitter.fit(sets[sl], cams[sl], progress=False)
        t_kp = time.process_time() - t0
        e_truth, _ = fitter.energy_at(
            {k: np.stack([getattr(g, k) for g in gts[sl]]) for k in NAMES}, sets[sl], cams[sl]
        )
        t0 = time.process_time()
        res = refine_batch(model, kp, sets[sl], masks[sl], sil_config, pose_prior=fitter.pose_prior, progress=False)
        t_sil = time.process_time() - t0
        for j, r in enumerate(res):
            gt = gts[b + j]
            rows.append(
                {
                    "seed": seed,
                    "i": b + j,
                    "t_kp": t_kp / len(res),
                    "t_sil": t_sil / len(res),
                    "kp": 1000 * float(pa_pve(kp.vertices[j].astype(np.float64), gt.vertices)),
                    "sil": 1000 * float(pa_pve(r.vertices.astype(np.float64), gt.vertices)),
                    "warned": bool(depth_warnings(kp.branch_search[j])),
                    "e_fit": float(kp.energies["final"][j]),
                    "e_truth": float(e_truth[j]),
                }
            )
    return rows


def table(runs: dict) -> None:
    print(
        "| run | subjects | keypoint stage PA-PVE mean / median (mm) | with silhouettes mean / median | > 150 mm | "
        "> 150 mm warned | < 60 mm warned | search failures | CPU s / subject (keypoints, silhouettes) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, rows in runs.items():
        kp, sil = np.array([r["kp"] for r in rows]), np.array([r["sil"] for r in rows])
        w = np.array([r["warned"] for r in rows])
        fail = sum(r["e_truth"] < r["e_fit"] * (1 - 1e-3) for r in rows)
        print(
            f"| {name} | {len(rows)} | {kp.mean():.1f} / {np.median(kp):.1f} | {sil.mean():.1f} / {np.median(sil):.1f} | "
            f"{(sil > 150).sum()} | {(w & (sil > 150)).sum()}/{(sil > 150).sum()} | {(w & (sil < 60)).sum()}/{(sil < 60).sum()} | "
            f"{fail}/{len(rows)} | {np.mean([r['t_kp'] for r in rows]):.2f}, {np.mean([r['t_sil'] for r in rows]):.2f} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="15300,15301", help="comma-separated generator seeds, --n subjects each")
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--batch", type=int, default=8, help="subjects per keypoint-stage batch")
    ap.add_argument(
        "--baseline",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="the before run's KeypointFitConfig settings (repeatable); none: today's defaults only",
    )
    ap.add_argument(
        "--silhouette-baseline",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="the before run's SilhouetteFitConfig settings (repeatable), with today's keypoint stage",
    )
    ap.add_argument("--workers", type=int, default=2, help="parallel processes (one seed and run each)")
    args = ap.parse_args()
    if any("=" not in o for o in args.baseline + args.silhouette_baseline):
        ap.error("--baseline and --silhouette-baseline take NAME=VALUE")
    seeds = [int(s) for s in args.seeds.split(",")]
    runs = {"after (today's defaults)": ({}, {})}
    if args.baseline or args.silhouette_baseline:
        name = f"before ({', '.join(args.baseline + args.silhouette_baseline)})"
        split = lambda opts: dict(o.split("=", 1) for o in opts)  # noqa: E731
        runs = {name: (split(args.baseline), split(args.silhouette_baseline)), **runs}
    for settings, silhouette in runs.values():  # a bad setting: one line now, not after the other runs
        try:
            keypoint_config(dict(settings))
            config_with(SilhouetteFitConfig, dict(silhouette), stage="silhouette")
        except ValueError as e:
            ap.error(str(e))
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
        jobs = {
            (name, s): pool.submit(run_seed, s, args.n, args.size, args.batch, *settings)
            for name, settings in runs.items()
            for s in seeds
        }
        out = {name: [r for s in seeds for r in jobs[name, s].result()] for name in runs}
    print(
        f"# {args.n} hard subjects per seed, seeds {args.seeds}, {args.size} px, the default image path "
        f"({time.perf_counter() - t0:.0f} s wall, {args.workers} processes)\n"
    )
    table(out)
    if len(out) == 2:
        before, after = out.values()
        d = np.array([a["sil"] - b["sil"] for a, b in zip(after, before)])
        moved = [
            f"{a['seed']}/{a['i']}: {b['sil']:.0f} -> {a['sil']:.0f}"
            for a, b in zip(after, before)
            if abs(a["sil"] - b["sil"]) > 30
        ]
        print(
            f"\nWith silhouettes, after against before: {(d < -10).sum()} subjects better by more than 10 mm, "
            f"{(d > 10).sum()} worse; moved by more than 30 mm (seed/subject: before -> after): {', '.join(moved) or 'none'}"
        )


if __name__ == "__main__":
    main()
