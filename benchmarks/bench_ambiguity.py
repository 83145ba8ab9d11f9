"""Depth ambiguity: does the depth warning tell a user when a fit may be in the wrong branch?

Fits a generated hard set (``silfit synth --poses hard``: squats, kneeling, running, hands at the
face; front and back views) with the keypoint stage, twice: the default schedule, and
``hypotheses=K`` (``silfit fit --hypotheses K``). For each it prints, by the fit's PA-PVE against
the truth (good: below 60 mm, middling, bad: above 150 mm), how many fits carry the depth warning
(:func:`~silfit.fitting.plausibility.depth_warnings`): on good fits a warning is a false alarm, on bad ones a
hit. *Before* is the rule of main 802356a (with one hypothesis, the branch search's survivors within
:data:`~silfit.fitting.plausibility.SEARCH_MARGIN` of the kept one by the search's energies, moving a joint
:data:`~silfit.fitting.plausibility.SEARCH_MIN_SHIFT_MM`); *after* is today's (the ``branch_refine`` branches
refined to the end, by their final energies, within :data:`~silfit.fitting.plausibility.HYPOTHESIS_MARGIN`,
moving a joint :data:`~silfit.fitting.plausibility.MIN_SHIFT_MM`, as with ``--hypotheses K``; or an earlier
search's survivor within :data:`~silfit.fitting.plausibility.EARLY_SEARCH_MARGIN` moving a joint
:data:`~silfit.fitting.plausibility.EARLY_SEARCH_MIN_SHIFT_MM`). Both come
from one fit per subject and schedule (the fits are the same; only the warning differs), with the best
of the K hypotheses within 60 mm.

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

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch

from silfit import load_body_model
from silfit.camera import load_camera
from silfit.io.subjects import read_gt
from silfit.eval.metrics import pa_pve
from silfit.fitting import KeypointFitter
from silfit.fitting.keypoint_stage import KeypointFitConfig, Solutions
from silfit.io.keypoints import read_keypoints
from silfit.fitting.plausibility import depth_warnings

NAMES = ("betas", "body_pose", "global_orient", "transl")


def _fit(fitter, sets, cams, gts, model, batch):
    """Per subject: PA-PVE of the fit, the best of its hypotheses, the search record (with the refined
    branches' entry), the hypotheses, fit and truth energies."""
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=model.dtype)  # noqa: E731

    def pve(params, gt):
        with torch.no_grad():
            v = model(**{n: T(params[n]).reshape(1, -1) for n in NAMES}).vertices[0].numpy()
        return 1000 * float(pa_pve(v.astype(np.float64), gt.vertices))

    rows = []
    for i in range(0, len(sets), batch):
        res = fitter.fit(sets[i : i + batch], cams[i : i + batch], progress=False)
        e_truth, _ = fitter.energy_at(
            {n: np.stack([getattr(g, n) for g in gts[i : i + batch]]) for n in NAMES},
            sets[i : i + batch],
            cams[i : i + batch],
        )
        for j in range(len(res)):
            gt = gts[i + j]
            fit_pve = 1000 * float(pa_pve(res.vertices[j].astype(np.float64), gt.vertices))
            hyps = res.hypotheses[j] if res.hypotheses else None
            rows.append(
                {
                    "pve": fit_pve,
                    "search": res.branch_search[j],
                    "hyps": hyps,
                    "best": min([fit_pve] + [pve(h["params"], gt) for h in (hyps or [])[1:]]),
                    "e_fit": float(res.energies["final"][j]),
                    "e_truth": float(e_truth[j]),
                    "reproj": float(res.reprojection_error[j]),
                    "terms": {t: float(v[j]) for t, v in res.term_energies["final"].items()},
                }
            )
    return rows


#: main 802356a's margins for refined hypotheses (``--hypotheses K``); its search rule is today's
BEFORE = {"margin": 0.3, "min_shift_mm": 300.0}


def _warned(r, which, **rule):
    if which == "before":  # main 802356a: the search's energies (no refined entry)
        return bool(depth_warnings([s for s in r["search"] or [] if not s.get("refined")], r["hyps"], **BEFORE))
    return bool(depth_warnings(r["search"], r["hyps"], **rule))


def _table(rows, title, K):
    pve = np.array([r["pve"] for r in rows])
    good, bad = pve < 60, pve > 150
    mid = ~good & ~bad
    print(f"### {title}\n")
    print(
        f"PA-PVE mean {pve.mean():.1f} mm, median {np.median(pve):.1f} mm; good (< 60 mm) {good.sum()}, "
        f"middling {mid.sum()}, bad (> 150 mm) {bad.sum()} of {len(rows)}\n"
    )
    print(
        "| rule | fits warned | bad warned (hits) | middling warned | good warned (false alarms) |"
        + (f" best of {K} within 60 mm | alternatives offered (unrefined) |" if K > 1 else "")
    )
    print("|---|---:|---:|---:|---:|" + ("---:|---:|" if K > 1 else ""))
    for which in ("before", "after"):
        w = np.array([_warned(r, which) for r in rows])
        line = (
            f"| {which} | {w.sum()}/{len(rows)} | {(w & bad).sum()}/{bad.sum()} | {(w & mid).sum()}/{mid.sum()} "
            f"| {(w & good).sum()}/{good.sum()} |"
        )
        if K > 1:
            best = np.array([r["best"] for r in rows])
            offered = sum(len(r["hyps"] or []) - 1 for r in rows)
            unref = sum(not h.get("refined", True) for r in rows for h in (r["hyps"] or []))
            line += f" {(best <= 60).sum()}/{len(rows)} | {offered} ({unref}) |"
        print(line)
    print()


def _sweep(rows):
    pve = np.array([r["pve"] for r in rows])
    good, bad = pve < 60, pve > 150
    print(
        "| refined margin | min shift (mm) | earlier search's margin | its min shift (mm) | bad warned | good warned |"
    )
    print("|---:|---:|---:|---:|---:|---:|")
    for m in (0.05, 0.1, 0.2, 0.3):
        for s in (300, 400):
            for em in (0.0, 0.02, 0.05, 0.1):
                for es in (300, 400, 500):
                    w = np.array(
                        [
                            _warned(r, "after", margin=m, min_shift_mm=s, early_margin=em, early_min_shift_mm=es)
                            for r in rows
                        ]
                    )
                    print(
                        f"| {m:g} | {s:g} | {em:g} | {es:g} | {(w & bad).sum()}/{bad.sum()} | {(w & good).sum()}/{good.sum()} |"
                    )
    print()


def _bad_fits(rows, title):
    print(
        f"Bad fits (> 150 mm), {title}: is the truth's energy below the fit's (search failure) or not "
        "(the energy prefers the wrong branch)?\n"
    )
    print("| subject | PA-PVE (mm) | fit energy | truth energy | truth lower | warned before | warned after |")
    print("|---:|---:|---:|---:|---|---|---|")
    for i, r in enumerate(rows):
        if r["pve"] > 150:
            print(
                f"| {i} | {r['pve']:.0f} | {r['e_fit']:.1f} | {r['e_truth']:.1f} | "
                f"{'yes (search failure)' if r['e_truth'] < r['e_fit'] * (1 - 1e-3) else 'no'} "
                f"| {_warned(r, 'before')} | {_warned(r, 'after')} |"
            )
    higher = sum(r["e_truth"] > r["e_fit"] * (1 + 1e-3) for r in rows)
    print(f"\nAll subjects: truth energy above the fit's in {higher}/{len(rows)}\n")


def hard_set(n: int, seed: int, size: int, model, masks: bool = False):
    """``(keypoint sets, cameras, truths)`` of ``n`` generated hard subjects (``silfit synth --poses hard``,
    written to a temporary folder and read back with silfit's readers), with ``masks`` also their person
    masks; also :mod:`bench_energy_terms`, :mod:`bench_hypothesis_silhouette`."""
    from silfit.silhouette.masks import read_mask

    from silfit.synth.generate import generate_hard_dataset

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "hard"
        generate_hard_dataset(root, n, seed=seed, size=size, model=model, progress=False)
        dirs = sorted(d for d in root.iterdir() if (d / "keypoints.json").is_file())
        sets = [read_keypoints(d / "keypoints.json") for d in dirs]
        cams = [load_camera(d / "camera.json") for d in dirs]
        gts = [read_gt(d / "gt.npz") for d in dirs]
        if masks:
            return sets, cams, gts, [read_mask(d / "mask.png") for d in dirs]
    return sets, cams, gts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, default=8700)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--k", type=int, default=3, help="hypotheses of the second run (1: the default run only)")
    ap.add_argument("--sweep", action="store_true", help="also the after rule at other margins and shifts (tuning)")
    ap.add_argument("--save", type=Path, help="write each run's per-subject rows here (pickle; for offline tuning)")
    ap.add_argument(
        "--baseline",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="first fit with these KeypointFitConfig settings (repeatable; e.g. branches.post_iters=0: the "
        "schedule before the search from the fit)",
    )
    args = ap.parse_args()

    model = load_body_model()
    sets, cams, gts = hard_set(args.n, args.seed, args.size, model)
    print(f"# Depth warning on {len(sets)} hard subjects (seed {args.seed}), keypoint stage\n")
    runs = [("default fit", KeypointFitConfig())]
    if args.baseline:
        from silfit.runner.worker import keypoint_config

        if any("=" not in o for o in args.baseline):
            ap.error("--baseline takes NAME=VALUE")
        runs.insert(
            0, (f"baseline: {', '.join(args.baseline)}", keypoint_config(dict(o.split("=", 1) for o in args.baseline)))
        )
    if args.k > 1:
        runs.append((f"--hypotheses {args.k}", KeypointFitConfig(solutions=Solutions(count=args.k))))
    for title, config in runs:
        t0, c0 = time.perf_counter(), time.process_time()
        rows = _fit(KeypointFitter(model, config=config), sets, cams, gts, model, args.batch)
        failures = sum(r["e_truth"] < r["e_fit"] * (1 - 1e-3) for r in rows)
        print(
            f"{title}: CPU {(time.process_time() - c0) / len(rows):.2f} s per subject (the truth's energy included); "
            f"search failures (the truth's energy below the fit's) {failures}/{len(rows)}\n"
        )
        if args.save:
            import pickle

            args.save.write_bytes(
                pickle.dumps({**(pickle.loads(args.save.read_bytes()) if args.save.is_file() else {}), title: rows})
            )
        _table(rows, f"{title} ({time.perf_counter() - t0:.0f} s)", config.solutions.count)
        if args.sweep:
            _sweep(rows)
        _bad_fits(rows, title)


if __name__ == "__main__":
    main()
