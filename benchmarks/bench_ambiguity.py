"""Depth ambiguity: does the branch search's energy gap tell a user when a fit may be in the wrong branch?

For each subject the keypoint stage records the limb-branch hypotheses that ran to the end of
the branch search and their final energies (``KeypointFitResult.branch_search``). The *gap* is
the relative energy difference between the kept hypothesis and the best other one,
``(E_other - E_kept) / E_kept``. A small gap means the keypoints hardly prefer the kept
branch. This script fits a generated hard set (``silfit synth --poses hard``: squats,
kneeling, running, hands at the face; front and back views) and prints, per gap bin, how
many fits fall there and their PA-MPJPE, and how well a warning at each threshold separates
bad fits (PA-MPJPE above ``--bad-mm``) from good ones (``faces_camera`` against the truth is
also checked).

    python benchmarks/bench_ambiguity.py --n 40 --seed 7
    python benchmarks/bench_ambiguity.py --n 20 --seed 4711 --set hypotheses=3   # issue 25: K branches refined

Also printed: the keypoint stage's PA-PVE (mean, fits above 150 mm), search failures (the fit's
final energy above the truth's, :meth:`~silfit.fitting.KeypointFitter.energy_at`), with
``--set hypotheses=K`` the best of the K hypotheses' PA-PVE (fits within 60 mm), and how many fits
carry the depth warning image fits emit (:func:`~silfit.plausibility.depth_warnings`) above 150 mm and
below 60 mm (false alarms). ``--set occlusion_weight=0.01`` turns the occlusion cue on.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from silfit import load_body_model
from silfit.camera import load_camera
from silfit.dataset import read_gt
from silfit.eval.metrics import pa_mpjpe, pa_pve
from silfit.fitting.keypoint_stage import KeypointFitConfig
from silfit.fitting import KeypointFitter
from silfit.fitting.result import faces_camera
from silfit.keypoints import read_keypoints
from silfit.plausibility import branch_gap, depth_warnings


MARGINS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--bad-mm", type=float, default=90.0)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="KeypointFitConfig override (Python literal)")
    args = ap.parse_args()
    import ast

    config = KeypointFitConfig(**{k: ast.literal_eval(v) for k, v in (a.split("=", 1) for a in args.set)})

    from silfit.synth.generate import generate_hard_dataset

    model = load_body_model()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "hard"
        generate_hard_dataset(root, args.n, seed=args.seed, size=args.size, model=model, progress=False)
        dirs = sorted(d for d in root.iterdir() if (d / "keypoints.json").is_file())
        sets = [read_keypoints(d / "keypoints.json") for d in dirs]
        cams = [load_camera(d / "camera.json") for d in dirs]
        gts = [read_gt(d / "gt.npz") for d in dirs]
    fitter = KeypointFitter(model, config=config)
    t0 = time.perf_counter()
    rows = []
    for i in range(0, len(sets), args.batch):
        res = fitter.fit(sets[i: i + args.batch], cams[i: i + args.batch], progress=False)
        T = lambda a: torch.as_tensor(a, dtype=model.dtype)  # noqa: E731
        with torch.no_grad():
            joints = model(**{n: T(getattr(res, n)) for n in ("betas", "body_pose", "global_orient", "transl")}).joints.numpy()
        names = ("betas", "body_pose", "global_orient", "transl")
        e_truth, _ = fitter.energy_at({n: np.stack([getattr(g, n) for g in gts[i: i + args.batch]]) for n in names},
                                      sets[i: i + args.batch], cams[i: i + args.batch])  # fmt: skip
        for j in range(len(res)):
            gt = gts[i + j]
            err = 1000 * float(np.mean(pa_mpjpe(joints[j][None].astype(np.float64), gt.joints[None])))
            pve = 1000 * float(pa_pve(res.vertices[j].astype(np.float64), gt.vertices))
            best_of = pve
            for h in (res.hypotheses[j] if res.hypotheses else [])[1:]:
                with torch.no_grad():
                    v = model(**{n: T(h["params"][n][None]) for n in names}).vertices[0].numpy()
                best_of = min(best_of, 1000 * float(pa_pve(v.astype(np.float64), gt.vertices)))
            truth_faces = faces_camera(gt.global_orient, gt.transl)
            rows.append({"gap": branch_gap(res.branch_search[j]), "pa": float(err),
                         "facing_ok": faces_camera(res.global_orient[j], res.transl[j]) == truth_faces,
                         "start_flipped_matches_back": bool(res.flipped[j]) == (not truth_faces), "pve": pve,
                         "best_of": best_of, "fail": bool(res.energies["final"][j] > e_truth[j] * (1 + 1e-3)),
                         "warned": bool(depth_warnings(res.branch_search[j], res.hypotheses[j] if res.hypotheses else None)),
                         "warned_at": {m: bool(depth_warnings(res.branch_search[j], res.hypotheses[j] if res.hypotheses else None,
                                                              margin=m, search_margin=m)) for m in MARGINS},
                         "warned_last_at": {m: bool(depth_warnings(res.branch_search[j][-1:], None, search_margin=m))
                                            for m in MARGINS}})  # fmt: skip
    seconds = time.perf_counter() - t0
    gaps = np.array([r["gap"] if r["gap"] is not None else np.inf for r in rows])
    pa = np.array([r["pa"] for r in rows])
    bad = pa > args.bad_mm
    print(f"# Depth ambiguity on {len(rows)} hard subjects (seed {args.seed}); keypoint stage {seconds:.0f} s\n")
    print(f"faces_camera agrees with the truth: {sum(r['facing_ok'] for r in rows)}/{len(rows)}; "
          f"start_flipped == truly back-facing: {sum(r['start_flipped_matches_back'] for r in rows)}/{len(rows)}\n")
    pve = np.array([r["pve"] for r in rows])
    best = np.array([r["best_of"] for r in rows])
    print(f"settings: {' '.join(args.set) or 'defaults'}\n")
    print("| PA-PVE mean (mm) | PA-PVE median | fits > 150 mm | search failures | best of the hypotheses: mean | within 60 mm |")
    print("|---:|---:|---:|---:|---:|---:|")
    print(f"| {pve.mean():.1f} | {np.median(pve):.1f} | {(pve > 150).sum()}/{len(rows)} | {sum(r['fail'] for r in rows)}/{len(rows)} "
          f"| {best.mean():.1f} | {(best <= 60).sum()}/{len(rows)} |\n")
    warned = np.array([r["warned"] for r in rows])
    print("Depth warning (plausibility.depth_warnings, as image fits emit it):\n")
    print("| fits warned | fits > 150 mm warned | fits 60-150 mm warned | fits < 60 mm warned (false alarms) |")
    print("|---:|---:|---:|---:|")
    mid = (pve >= 60) & (pve <= 150)
    print(f"| {warned.sum()}/{len(rows)} | {(warned & (pve > 150)).sum()}/{(pve > 150).sum()} | {(warned & mid).sum()}/{mid.sum()} "
          f"| {(warned & (pve < 60)).sum()}/{(pve < 60).sum()} |\n")
    print("The same with other margins (refined hypotheses' and the branch search's alike):\n")
    print("| margin | searches | fits warned | fits > 150 mm warned | fits < 60 mm warned |")
    print("|---:|---|---:|---:|---:|")
    for key, which in (("warned_at", "every search"), ("warned_last_at", "the last search only")):
        for m in MARGINS:
            w = np.array([r[key][m] for r in rows])
            print(f"| {m:g} | {which} | {w.sum()} | {(w & (pve > 150)).sum()}/{(pve > 150).sum()} "
                  f"| {(w & (pve < 60)).sum()}/{(pve < 60).sum()} |")
    print()
    print("| gap (E_other - E_kept) / E_kept | fits | mean PA-MPJPE (mm) | bad (> %g mm) |" % args.bad_mm)
    print("|---|---:|---:|---:|")
    edges = [0.0, 0.02, 0.05, 0.1, 0.2, 0.5, np.inf]
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (gaps >= lo) & (gaps < hi)
        if sel.any():
            print(f"| {lo:g} - {hi:g} | {sel.sum()} | {pa[sel].mean():.1f} | {bad[sel].sum()} |")
    print(f"| no alternative ran to the end | {np.isinf(gaps).sum()} | "
          f"{pa[np.isinf(gaps)].mean() if np.isinf(gaps).any() else float('nan'):.1f} | {bad[np.isinf(gaps)].sum()} |")
    print("\n| warn when gap < | warned | bad among warned | bad not warned | good warned |")
    print("|---:|---:|---:|---:|---:|")
    for thr in (0.02, 0.05, 0.1, 0.2):
        w = gaps < thr
        print(f"| {thr:g} | {w.sum()} | {(w & bad).sum()} | {(~w & bad).sum()} | {(w & ~bad).sum()} |")


if __name__ == "__main__":
    main()
