"""Depth ambiguity: which energy term makes the truth cost more than a wrong-branch fit?

Fits a generated hard set (``silfit synth --poses hard``) with the keypoint stage and evaluates the
final stage's energy, term by term (weighted as in the final stage), at the fit and at the truth
(:meth:`~silfit.fitting.KeypointFitter.energy_at`). The truth itself is not a minimum of the energy
(the keypoints are noisy), so it is also refined: the final stage alone, started from the truth
("truth refined"). Per variant (a pose prior and/or weights) it prints:

* PA-PVE of the fit (mean, median, above 150 mm), search failures (the truth's or the refined truth's
  energy below the fit's: a better search would find it) and "truth costlier" (the refined truth's
  energy above the fit's: the energy prefers another basin, no search helps);
* per term, the mean of ``w * (term at truth - term at fit)`` (raw truth and refined truth), how often
  the term is the largest contributor to a truth costlier than the fit, and how often it alone
  decides (without it the truth would cost less).

    python benchmarks/bench_energy_terms.py --n 30 --seed 8950 --subjects
    python benchmarks/bench_energy_terms.py --n 20 --seed 8650 --variants default final_pose10 limits /tmp/wider.npz

(``/tmp/wider.npz``: e.g. ``tools/build_pose_prior.py --out /tmp/wider.npz --reg-deg 9``.) The raw truth's
energy is not the right comparison (bench_ambiguity.py's "truth lower" uses it): the noise puts it far above
its own basin's minimum; the refined truth's is. A refined truth costlier than the fit but within
:data:`APART_MM` of it is the same pose with the shape prior not yet settled, not another branch.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch

from bench_ambiguity import hard_set  # noqa: E402 - benchmarks/ is the script's folder
from silfit import load_body_model
from silfit.eval.metrics import pa_pve
from silfit.fitting import KeypointFitter
from silfit.fitting.keypoint_stage import KeypointFitConfig, prepare_keypoints
from silfit.runner.worker import config_with
from silfit.fitting.problem import Problem

NAMES = ("betas", "body_pose", "global_orient", "transl")
#: a refined truth this far (PA-PVE between the two meshes) from the fit is in another basin
APART_MM = 50.0


def _variants():
    """name -> (config kwargs, pose prior (None: default)). Final-stage and pose-stage weights as listed."""
    d = KeypointFitConfig().pose_weight
    return {
        "default": ({}, None),
        "final_pose20": ({"pose_weight": d[:-1] + (20.0,)}, None),
        "final_pose10": ({"pose_weight": d[:-1] + (10.0,)}, None),
        "limits": ({"pose_weight": (200.0, 40.0, 8.0, 4.0)}, "limits"),
        "late2": ({"branches.late_rounds": 2}, None),
        "yaw": ({"branches.late_turns": ("mirror",)}, None),
        "turn30": ({"branches.late_turns": (30.0, -30.0)}, None),
        "surv8": ({"branches.late_survivors": 8}, None),
        "long60": ({"branches.late_iters": 60, "branches.late_survivors": 6}, None),
        "refine3": ({"branches.refine": 3}, None),
        "late2s6": ({"branches.late_rounds": 2, "branches.late_survivors": 6}, None),
        "ratio15": ({"branches.min_depth_ratio": 0.15}, None),
        "ratio15s6": ({"branches.min_depth_ratio": 0.15, "branches.late_survivors": 6}, None),
    }


def _fit_rows(fitter, sets, cams, gts, model, batch, refine, diagnose=False):
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=model.dtype)  # noqa: E731

    def pve(params, gt, j):
        with torch.no_grad():
            v = model(**{n: T(params[n][j]).reshape(1, -1) for n in NAMES}).vertices[0].numpy()
        return 1000 * float(pa_pve(v.astype(np.float64), gt.vertices))

    final = fitter.stages[-1]
    weights = {k: float(v) for k, v in final.weights.items() if v}
    refiner = None
    if refine:
        cfg = replace(
            fitter.config,
            schedule=[replace(final, iterations=refine)],
            starts=replace(fitter.config.starts, flip=False),
            solutions=replace(fitter.config.solutions, count=1),
            branches=replace(fitter.config.branches, refine=0),
        )
        refiner = KeypointFitter(model, config=cfg, pose_prior=fitter.pose_prior)
    rows = []
    for i in range(0, len(sets), batch):
        s, c, g = sets[i : i + batch], cams[i : i + batch], gts[i : i + batch]
        res = fitter.fit(s, c, progress=False)
        fit_p = {n: getattr(res, n) for n in NAMES}
        truth_p = {n: np.stack([getattr(x, n) for x in g]) for n in NAMES}
        e_fit, t_fit = fitter.energy_at(fit_p, s, c)
        e_tr, t_tr = fitter.energy_at(truth_p, s, c)
        if refiner is not None:
            problems = [Problem.single(k, cam) for k, cam in zip(prepare_keypoints(s, fitter.layout), res.cameras)]
            state, _ = refiner.fit_problems(problems, init={n: truth_p[n] for n in NAMES})
            ref_p = {n: (state[n][:, 0] if state[n].dim() == 3 else state[n]).detach().numpy() for n in NAMES}
            e_ref, t_ref = fitter.energy_at(ref_p, s, c)
            mixed = {}
            if diagnose:  # the final stage from the fit with the truth's orientation, and from the truth's pose
                for tag, take in (("orient", ("global_orient",)), ("pose", ("body_pose",)), ("flips", None)):
                    init = {n: (truth_p[n] if take and n in take else fit_p[n]) for n in NAMES}
                    if take is None:  # the fit with the truth's depth branches: no truth pose
                        init["body_pose"], flipped = truth_flips(fitter, fit_p, truth_p)
                        for j, f_ in enumerate(flipped):
                            mixed.setdefault("needed", {})[j] = f_
                    st, _ = refiner.fit_problems(problems, init=init)
                    p_ = {n: (st[n][:, 0] if st[n].dim() == 3 else st[n]).detach().numpy() for n in NAMES}
                    mixed[tag] = (fitter.energy_at(p_, s, c)[0], p_)
                needed = mixed.pop("needed", {})
        for j in range(len(s)):
            r = {
                "pve": pve(fit_p, g[j], j),
                "e_fit": float(e_fit[j]),
                "e_truth": float(e_tr[j]),
                "fit": {k: weights[k] * float(t_fit[k][j]) for k in weights},
                "truth": {k: weights[k] * float(t_tr[k][j]) for k in weights},
            }
            if refiner is not None:
                r.update(
                    e_ref=float(e_ref[j]),
                    ref={k: weights[k] * float(t_ref[k][j]) for k in weights},
                    pve_ref=pve(ref_p, g[j], j),
                    apart=pve(ref_p, _Verts(res.vertices[j]), j),
                )
                for tag, (e_, p_) in mixed.items():
                    r[f"e_{tag}"], r[f"pve_{tag}"] = float(e_[j]), pve(p_, g[j], j)
                if mixed:
                    r["needed"] = needed.get(j, [])
            rows.append(r)
    return rows, list(weights)


def truth_flips(fitter, fit_p, truth_p, min_ratio=0.15):
    """The fit's ``body_pose`` with every limb segment (upper first) flipped in depth
    (:func:`~silfit.fitting.branches.flip_segment`) where it points to the other side of the image plane
    than the truth's (the truth's depth ratio at least ``min_ratio``), and the flipped segments per subject.
    Each by the smallest turn at its proximal joint (``hinge=False``), as the README's numbers were measured."""
    from silfit.fitting.branches import LIMB_SEGMENTS, flip_segment

    body, names, parents = fitter.body, fitter.model.joint_names, fitter.model.parents
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=fitter.model.dtype)  # noqa: E731

    def ratios(rows):
        with torch.no_grad():
            j = body(**rows).joints.double().numpy()
        out = {}
        for seg, p, d in LIMB_SEGMENTS:
            a, b = j[:, names.index(p)], j[:, names.index(d)]
            ray = 0.5 * (a + b)
            out[seg] = ((b - a) * ray).sum(-1) / np.linalg.norm(b - a, axis=-1) / np.linalg.norm(ray, axis=-1)
        return out

    truth = ratios({n: T(v) for n, v in truth_p.items()})
    rows = {n: T(v).clone() for n, v in fit_p.items()}
    flipped = [[] for _ in range(rows["body_pose"].shape[0])]
    for seg, _, _ in LIMB_SEGMENTS:
        now = ratios(rows)[seg]
        for k in np.nonzero((np.sign(now) != np.sign(truth[seg])) & (np.abs(truth[seg]) >= min_ratio))[0].tolist():
            rows["body_pose"][k] = flip_segment(
                body, {n: v[k : k + 1] for n, v in rows.items()}, seg, names, parents, hinge=False
            )[0]
            flipped[k].append(seg)
    return rows["body_pose"].numpy(), flipped


class _Verts:  # PA-PVE between two fits: the fit's vertices as the reference
    def __init__(self, v):
        self.vertices = np.asarray(v, dtype=np.float64)


def _subjects(name, rows):
    print(
        f"\n{name}: per subject (energies of the final stage; 'apart': PA-PVE between the fit and the refined truth)\n"
    )
    diag = "e_orient" in rows[0]
    print(
        "| subject | fit PA-PVE | refined truth PA-PVE | apart (mm) | fit energy | truth | refined truth | largest cause |"
        + (
            " fit + truth's orient: energy, PA-PVE | fit + truth's pose: energy, PA-PVE | fit + truth's flips: energy, "
            "PA-PVE | flips needed |"
            if diag
            else ""
        )
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---|" + ("---:|---:|---:|---|" if diag else ""))
    for i, r in enumerate(rows):
        diffs = {k: r["ref"][k] - r["fit"][k] for k in r["fit"]}
        cause = max(diffs, key=diffs.get) if r["e_ref"] > r["e_fit"] * (1 + 1e-3) else "-"
        print(
            f"| {i} | {r['pve']:.0f} | {r['pve_ref']:.0f} | {r['apart']:.0f} | {r['e_fit']:.1f} | {r['e_truth']:.1f} "
            f"| {r['e_ref']:.1f} | {cause} ({diffs.get(cause, 0):+.1f}) |"
            + (
                f" {r['e_orient']:.1f}, {r['pve_orient']:.0f} | {r['e_pose']:.1f}, {r['pve_pose']:.0f} | {r['e_flips']:.1f}, "
                f"{r['pve_flips']:.0f} | {'+'.join(r['needed']) or '-'} |"
                if diag
                else ""
            )
        )


def _summary(name, rows, seconds):
    pve = np.array([r["pve"] for r in rows])
    fail = sum(r["e_truth"] < r["e_fit"] * (1 - 1e-3) or r.get("e_ref", np.inf) < r["e_fit"] * (1 - 1e-3) for r in rows)
    costlier = sum(r.get("e_ref", r["e_truth"]) > r["e_fit"] * (1 + 1e-3) for r in rows)
    other = sum(
        r.get("e_ref", r["e_truth"]) > r["e_fit"] * (1 + 1e-3) and r.get("apart", np.inf) > APART_MM for r in rows
    )
    ref = np.array([r.get("pve_ref", np.nan) for r in rows])
    return (
        f"| {name} | {pve.mean():.1f} | {np.median(pve):.1f} | {(pve > 150).sum()}/{len(rows)} | {fail}/{len(rows)} "
        f"| {costlier}/{len(rows)} | {other}/{len(rows)} | {np.nanmean(ref):.1f} | {seconds / len(rows):.2f} |"
    )


def _terms(name, rows, terms, which):
    """Per term: mean w*(which - fit), and among subjects where ``which`` costs more than the fit, how often the
    term is the largest contributor and how often it alone decides."""
    key_e = "e_ref" if which == "ref" else "e_truth"
    print(
        f"\n{name}: per term, {'refined truth' if which == 'ref' else 'truth'} minus fit (weighted; "
        f"costlier in {sum(r[key_e] > r['e_fit'] * (1 + 1e-3) for r in rows)}/{len(rows)})\n"
    )
    print("| term | mean | median | truth higher | largest cause | decides alone |")
    print("|---|---:|---:|---:|---:|---:|")
    for t in terms:
        d = np.array([r[which][t] - r["fit"][t] for r in rows])
        largest = decides = 0
        for r in rows:
            D = r[key_e] - r["e_fit"]
            if D <= abs(r["e_fit"]) * 1e-3:
                continue
            diffs = {k: r[which][k] - r["fit"][k] for k in terms}
            largest += max(diffs, key=diffs.get) == t
            decides += diffs[t] > D
        print(f"| {t} | {d.mean():+.2f} | {np.median(d):+.2f} | {(d > 0).sum()}/{len(rows)} | {largest} | {decides} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=8650)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--batch", type=int, default=10)
    ap.add_argument(
        "--variants",
        nargs="*",
        default=["default"],
        help=f"of {', '.join(_variants())}, or PATH.npz (a mixture prior at the default weights)",
    )
    ap.add_argument("--refine", type=int, default=100, help="L-BFGS steps of the final stage from the truth (0: none)")
    ap.add_argument("--subjects", action="store_true", help="per-subject rows (the first variant)")
    ap.add_argument(
        "--diagnose",
        action="store_true",
        help="with --subjects: also the final stage (--refine steps) "
        "from the fit with the truth's global orientation, with the truth's body pose, and with the truth's "
        "depth branches (the fit's limb segments flipped where the truth's point the other way)",
    )
    ap.add_argument("--only", help="comma-separated indices of the generated subjects to fit (e.g. the failures)")
    ap.add_argument("--terms", action="store_true", help="the per-term tables for every variant (default: the first)")
    args = ap.parse_args()

    model = load_body_model()
    sets, cams, gts = hard_set(args.n, args.seed, args.size, model)
    if args.only:  # a subset of the generated subjects (their indices among the n)
        keep = [int(i) for i in args.only.split(",")]
        sets, cams, gts = [sets[i] for i in keep], [cams[i] for i in keep], [gts[i] for i in keep]
    table = {}
    known = _variants()
    for v in args.variants:
        kw, prior = known[v] if v in known else ({}, v)
        t0 = time.process_time()
        fitter = KeypointFitter(model, config=config_with(KeypointFitConfig, kw), pose_prior=prior)
        rows, terms = _fit_rows(fitter, sets, cams, gts, model, args.batch, args.refine, args.diagnose)
        table[v] = (rows, terms, time.process_time() - t0)
        print(f"(done {v}: {time.process_time() - t0:.0f} CPU s)", flush=True)
    print(f"\n# Energy terms at truth and fit, {len(sets)} hard subjects (seed {args.seed}), keypoint stage\n")
    print(
        f"| variant | PA-PVE mean (mm) | median | > 150 mm | search failures | truth costlier | costlier, other basin "
        f"(> {APART_MM:g} mm apart) | refined truth PA-PVE | CPU s / subject (fit + truth refine) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for v, (rows, terms, sec) in table.items():
        print(_summary(v, rows, sec))
    for k, (v, (rows, terms, sec)) in enumerate(table.items()):
        if k == 0 or args.terms:
            _terms(v, rows, terms, "truth")
            if args.refine:
                _terms(v, rows, terms, "ref")
            if args.refine and args.subjects and k == 0:
                _subjects(v, rows)


if __name__ == "__main__":
    main()
