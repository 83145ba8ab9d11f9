"""Depth ambiguity: does the depth warning tell a user when a fit may be in the wrong branch?

Fits a generated hard set (``silfit synth --poses hard``: squats, kneeling, running, hands at the
face; front and back views) with the keypoint stage, twice: the default schedule, and
``hypotheses=K`` (``silfit fit --hypotheses K``). For each it prints, by the fit's PA-PVE against
the truth (good: below 60 mm, middling, bad: above 150 mm), how many fits carry the depth warning
(:func:`~silfit.plausibility.depth_warnings`): on good fits a warning is a false alarm, on bad ones a
hit. *Before* is the rule of main before issue 25's warnings (energy margins 0.02 for refined
hypotheses and 0.1 for branch-search survivors, no joint-shift condition; hypotheses distinct by the
mean joint distance alone, refined ones only); *after* is today's (margins
:data:`~silfit.plausibility.HYPOTHESIS_MARGIN` and :data:`~silfit.plausibility.SEARCH_MARGIN`, an
alternative must move a joint :data:`~silfit.plausibility.MIN_SHIFT_MM` or, a search survivor,
:data:`~silfit.plausibility.SEARCH_MIN_SHIFT_MM`; distinct by
:func:`~silfit.fitting.keypoint_stage.is_distinct`, unrefined search survivors filling the list). Both
come from one fit per subject and schedule (the fits are the same; only the hypotheses kept and the
warning differ), with the best of the K hypotheses within 60 mm.

Per bad fit it prints whether the truth's energy is below the fit's (a search failure: a better
optimiser would find it) or not (the energy prefers the wrong branch).

    python benchmarks/bench_ambiguity.py --n 30 --seed 8700
    python benchmarks/bench_ambiguity.py --n 20 --seed 31 --sweep    # tuning: other margins / shifts
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
from silfit.eval.metrics import pa_pve
from silfit.fitting import KeypointFitter
from silfit.fitting import keypoint_stage as ks
from silfit.fitting.keypoint_stage import KeypointFitConfig
from silfit.keypoints import read_keypoints
from silfit.plausibility import depth_warnings

NAMES = ("betas", "body_pose", "global_orient", "transl")
BEFORE = {"margin": 0.02, "search_margin": 0.1, "min_shift_mm": 0.0, "search_min_shift_mm": 0.0}  # main's rule


def _fit(fitter, sets, cams, gts, model, batch):
    """Per subject: PA-PVE of the fit and of each hypothesis (after's and before's lists), the
    search record, both hypothesis lists, fit and truth energies."""
    original = ks.distinct_hypotheses
    before_lists = []

    def both(*a, **k):  # the hypotheses main would keep, from the same refined rows
        k0 = dict(k, max_m=None, unrefined=None)
        before_lists.extend(original(*a, **k0)[0])
        return original(*a, **k)

    ks.distinct_hypotheses = both
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=model.dtype)  # noqa: E731

    def pve(params, gt):
        with torch.no_grad():
            v = model(**{n: T(params[n]).reshape(1, -1) for n in NAMES}).vertices[0].numpy()
        return 1000 * float(pa_pve(v.astype(np.float64), gt.vertices))

    rows = []
    try:
        for i in range(0, len(sets), batch):
            before_lists.clear()
            res = fitter.fit(sets[i: i + batch], cams[i: i + batch], progress=False)
            e_truth, _ = fitter.energy_at({n: np.stack([getattr(g, n) for g in gts[i: i + batch]]) for n in NAMES},
                                          sets[i: i + batch], cams[i: i + batch])  # fmt: skip
            K = max(1, int(fitter.config.hypotheses))
            for j in range(len(res)):
                gt = gts[i + j]
                fit_pve = 1000 * float(pa_pve(res.vertices[j].astype(np.float64), gt.vertices))
                after = res.hypotheses[j] if res.hypotheses else None
                before = before_lists[j][:K] if before_lists else None
                rows.append({"pve": fit_pve, "search": res.branch_search[j], "after": after, "before": before,
                             "best_after": min([fit_pve] + [pve(h["params"], gt) for h in (after or [])[1:]]),
                             "best_before": min([fit_pve] + [pve(h["params"], gt) for h in (before or [])[1:]]),
                             "e_fit": float(res.energies["final"][j]), "e_truth": float(e_truth[j])})  # fmt: skip
    finally:
        ks.distinct_hypotheses = original
    return rows


def _warned(r, which, **rule):
    if which == "before":
        return bool(depth_warnings(r["search"], r["before"], **{**BEFORE, **rule}))
    return bool(depth_warnings(r["search"], r["after"], **rule))


def _table(rows, title, K):
    pve = np.array([r["pve"] for r in rows])
    good, bad = pve < 60, pve > 150
    mid = ~good & ~bad
    print(f"### {title}\n")
    print(f"PA-PVE mean {pve.mean():.1f} mm, median {np.median(pve):.1f} mm; good (< 60 mm) {good.sum()}, "
          f"middling {mid.sum()}, bad (> 150 mm) {bad.sum()} of {len(rows)}\n")
    print("| rule | fits warned | bad warned (hits) | middling warned | good warned (false alarms) |"
          + (f" best of {K} within 60 mm | alternatives offered (unrefined) |" if K > 1 else ""))
    print("|---|---:|---:|---:|---:|" + ("---:|---:|" if K > 1 else ""))
    for which in ("before", "after"):
        w = np.array([_warned(r, which) for r in rows])
        line = (f"| {which} | {w.sum()}/{len(rows)} | {(w & bad).sum()}/{bad.sum()} | {(w & mid).sum()}/{mid.sum()} "
                f"| {(w & good).sum()}/{good.sum()} |")
        if K > 1:
            best = np.array([r[f"best_{which}"] for r in rows])
            offered = sum(len(r[which] or []) - 1 for r in rows)
            unref = sum(not h.get("refined", True) for r in rows for h in (r[which] or []))
            line += f" {(best <= 60).sum()}/{len(rows)} | {offered} ({unref}) |"
        print(line)
    print()


def _sweep(rows):
    pve = np.array([r["pve"] for r in rows])
    good, bad = pve < 60, pve > 150
    print("| hypothesis margin | search margin | min shift (mm, both) | bad warned | good warned |")
    print("|---:|---:|---:|---:|---:|")
    for m, sm in ((0.02, 0.1), (0.1, 0.1), (0.2, 0.2), (0.3, 0.1), (0.3, 0.2), (0.5, 0.3)):
        for s in (0, 150, 200, 300, 400, 500):
            w = np.array([_warned(r, "after", margin=m, search_margin=sm, min_shift_mm=s, search_min_shift_mm=s) for r in rows])
            print(f"| {m:g} | {sm:g} | {s:g} | {(w & bad).sum()}/{bad.sum()} | {(w & good).sum()}/{good.sum()} |")
    print()


def _bad_fits(rows, title):
    print(f"Bad fits (> 150 mm), {title}: is the truth's energy below the fit's (search failure) or not "
          "(the energy prefers the wrong branch)?\n")
    print("| subject | PA-PVE (mm) | fit energy | truth energy | truth lower | warned before | warned after |")
    print("|---:|---:|---:|---:|---|---|---|")
    for i, r in enumerate(rows):
        if r["pve"] > 150:
            print(f"| {i} | {r['pve']:.0f} | {r['e_fit']:.1f} | {r['e_truth']:.1f} | "
                  f"{'yes (search failure)' if r['e_truth'] < r['e_fit'] * (1 - 1e-3) else 'no'} "
                  f"| {_warned(r, 'before')} | {_warned(r, 'after')} |")
    higher = sum(r["e_truth"] > r["e_fit"] * (1 + 1e-3) for r in rows)
    print(f"\nAll subjects: truth energy above the fit's in {higher}/{len(rows)}\n")


def hard_set(n: int, seed: int, size: int, model):
    """``(keypoint sets, cameras, truths)`` of ``n`` generated hard subjects (``silfit synth --poses hard``,
    written to a temporary folder and read back with silfit's readers); also :mod:`bench_energy_terms`."""
    from silfit.synth.generate import generate_hard_dataset

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "hard"
        generate_hard_dataset(root, n, seed=seed, size=size, model=model, progress=False)
        dirs = sorted(d for d in root.iterdir() if (d / "keypoints.json").is_file())
        sets = [read_keypoints(d / "keypoints.json") for d in dirs]
        cams = [load_camera(d / "camera.json") for d in dirs]
        gts = [read_gt(d / "gt.npz") for d in dirs]
    return sets, cams, gts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, default=8700)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--k", type=int, default=3, help="hypotheses of the second run (1: the default run only)")
    ap.add_argument("--sweep", action="store_true", help="also the after rule at other margins and shifts (tuning)")
    args = ap.parse_args()

    model = load_body_model()
    sets, cams, gts = hard_set(args.n, args.seed, args.size, model)
    print(f"# Depth warning on {len(sets)} hard subjects (seed {args.seed}), keypoint stage\n")
    runs = [("default fit", KeypointFitConfig())]
    if args.k > 1:
        runs.append((f"--hypotheses {args.k}", KeypointFitConfig(hypotheses=args.k)))
    for title, config in runs:
        t0 = time.perf_counter()
        rows = _fit(KeypointFitter(model, config=config), sets, cams, gts, model, args.batch)
        _table(rows, f"{title} ({time.perf_counter() - t0:.0f} s)", config.hypotheses)
        if args.sweep:
            _sweep(rows)
        _bad_fits(rows, title)


if __name__ == "__main__":
    main()
