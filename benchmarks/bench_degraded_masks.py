"""Degraded masks (issue 55): does the silhouette stage still beat the keypoints alone when the mask is
not the body's?

Subjects from silfit's generator (fully visible, all yaws, 1 px keypoint noise), under four conditions
(the helpers of ``bench_truncation.py``): ``clean`` masks; ``clothing``: the mask dilated by 4 % of the
person's height; ``cut``: the image cut at mid-thigh; ``second``: a second person (the next subject's mask
and keypoints, shifted sideways so that their box overlaps this person's by ``--overlap`` of its width)
joined to the mask, as a segmenter run around one of two people standing close marks both. The second
person is detected too: the methods that take other people out (``after``) get their mask and keypoints, and the
pixels of the joined mask that are the second person's are unknown to the stage
(:func:`silfit.silhouette.people.own_mask`, the radius 6 % of their extent, this person's own skeleton kept
within 4 % of theirs, as ``Person.own_mask``). A fifth condition, not in the default ``--conditions``: ``closed``,
the clean mask grown as ``clothing`` and eroded back by the same disc (a perfect trim: the gaps narrower than the
growth stay filled).

Methods: *keypoints only*; *main* (the silhouette stage before issue 55: the trust region of 6 % of the
window around the detections, the fill side as strong as the inside side, the whole mask);
*current* (issue 55's stage before the two-pass refit: one pass with the trust region around the keypoint stage's
fit, ``trust_free_ratio=None``, ``trim_quantile=0.25``); *twopass* (the two-pass refit, ``trust_free_ratio=1.3``,
``trim_quantile=0.5``); *after* (the defaults); *prev* (the defaults before the demo's IoU change: every small hole
of the mask unknown, the shallow fill side near the edge of every mask); *after, no subtraction* (``second`` only: the
defaults on the joined mask); *oracle* (the defaults, but every mask trimmed by the true growth, which the bench knows:
``clothing``'s dilation, 0 elsewhere, in place of :func:`~silfit.silhouette.losses.clothing_thickness`'s estimate;
the estimate against the truth per subject is printed under the table); *margin0* (the defaults, but the lowest final
energy chooses between the keypoint fit's depth branch and its close alternatives, ``choice_margin=0``: before issue
55's depth-branch part); *quartile* (the defaults, but every clothing trim as deep as the outline distances' quartile,
``mask.trim_upper=None``: before the even layer's deeper trim).
``--decompose`` adds a table of where each method's error lies: PA-PVE with the fit's pose and the true shape
(``betas``), with the true ``body_pose`` and the fit's shape (the alignment removes the global rotation), and the
mean distance in pixels between the fit's and the truth's vertices projected into the image (the error in the image
plane, the only part a mask from this camera can show; hidden vertices too).
Printed per condition: PA-PVE and PVE (mm, against the whole true body), the median reprojection error (px),
IoU with the given mask, how many fits the plausibility guard turned back, the gain of keypoints +
silhouette over keypoints only in PA-PVE, and per subject the most the stage worsened a fit's PA-PVE and how many
it worsened by more than 5 mm. The ``main`` method runs main's settings in this branch's code: with them the
stage computes what main's does (the trust region's older path, the fill side's weight 1, the whole mask).

    python benchmarks/bench_degraded_masks.py --n 8 --seed 5501
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch

from bench_truncation import _score, cut_subject, grow, shrink
from silfit import load_body_model
from silfit.camera import load_camera, project_points
from silfit.io.subjects import read_gt, read_mask
from silfit.fitting import KeypointFitter, image_fit
from silfit.fitting.silhouette_stage import SilhouetteFitConfig
from silfit.runner.worker import config_with
from silfit.fitting.image_fit import refine_batch
from silfit.io.keypoints import KeypointSet, read_keypoints
from silfit.silhouette.people import own_mask

#: the silhouette stage before issue 55 (its trust region around the detections, 6 % of the window; the
#: mask-not-covered side as strong as the inside side)
MAIN = {
    "trust.from_start": False,
    "trust.fraction": 0.06,
    "w_trust": 0.05,
    "mask.cover_weight": 1.0,
    "trust.free_ratio": None,
    "mask.trim_quantile": 0.25,
    "mask.trim_upper": None,
}
#: the stage after issue 55, before the two-pass refit: one pass with the trust region around the keypoint stage's fit,
#: the clothing trim at the outline distances' quartile
CURRENT = {"trust.free_ratio": None, "mask.trim_quantile": 0.25, "mask.trim_upper": None}
#: the defaults with one change (tuning; ``--methods``)
VARIANTS = {
    "weakfill": {"mask.cover_weight": 0.5},
    "fill1": {"mask.cover_weight": 1.0},
    "oldtrust": MAIN,
    "current": CURRENT,
    "twopass": {"trust.free_ratio": 1.3, "mask.trim_quantile": 0.5},
    "twopass25": {"trust.free_ratio": 1.3, "mask.trim_quantile": 0.25},
    "q40": {"mask.trim_quantile": 0.4},
    "q50": {"mask.trim_quantile": 0.5},
    "c35": {"mask.concave_radius": 0.035},
    "q50c35": {"mask.trim_quantile": 0.5, "mask.concave_radius": 0.035},
    "w05": dict(w_trust=0.5),
    "med50": {"trust.median": 0.5},
    "w02med50": {"w_trust": 0.2, "trust.median": 0.5},
    # the demo's IoU (issue 55, docs/benchmarks/real-photos.md "`silfit demo` IoU"): ``prev``, the defaults before
    # it (every small hole unknown, ``cover_inner`` for every mask); the tries: every mask's small holes known
    # (background), the mask-not-covered side at full slope near the edge of every mask, both, and 10 more steps
    "prev": {"mask.hole_covered": 0.0, "mask.untrimmed_inner": None},
    "holes0": {"mask.hole_fraction": 0.0, "mask.hole_covered": 0.0, "mask.untrimmed_inner": None},
    "h0i1": {"mask.hole_fraction": 0.0, "mask.cover_inner": 1.0, "mask.hole_covered": 0.0},
    "h0i1it": {"mask.hole_fraction": 0.0, "mask.cover_inner": 1.0, "mask.hole_covered": 0.0, "iterations": (30, 30)},
    "it30": {"iterations": (30, 30)},
    # the depth-branch choice (issue 55): ``margin0``, before it (the lowest final energy keeps its branch)
    "margin0": {"choice_margin": 0.0},
    # the trim's depth (issue 55): ``quartile``, before it (the trim as deep as the outline distances' quartile)
    "quartile": {"mask.trim_upper": None},
}


KEEP = 0.04  # as Person.own_mask: within 4 % of the person's extent of their own skeleton, a pixel stays theirs


#: per mask (its bytes): the true growth in pixels, and the thickness estimates the stage computed (the oracle method)
TRUTH: dict = {}
ESTIMATES: list = []


def oracle_thickness(on: bool):
    """``clothing_thickness`` for the stage: it records the estimate against the truth and returns the truth when
    ``on`` (the oracle), the estimate otherwise."""
    from silfit.silhouette import losses

    estimate_of = losses.clothing_thickness

    def thickness(mask, body, quantile=0.25, points=600):
        est = estimate_of(mask, body, quantile, points)
        truth = TRUTH.get(np.asarray(mask, dtype=bool).tobytes())
        ESTIMATES.append((est if np.ndim(est) == 0 else est[0], truth))  # the first quantile's (trim_quantile)
        if not on or truth is None:
            return est
        return float(truth) if np.ndim(est) == 0 else tuple(float(truth) for _ in est)

    return estimate_of, thickness


def shift(mask: np.ndarray, dx: int) -> np.ndarray:
    out = np.zeros_like(mask)
    if dx >= 0:
        out[:, dx:] = mask[:, : mask.shape[1] - dx]
    else:
        out[:, :dx] = mask[:, -dx:]
    return out


def second_person(mask, kp, other_mask, other_kp, overlap: float):
    """(joined mask, other's shifted mask, other's shifted keypoints): the other person placed beside this one
    (to the side with more room) with their boxes overlapping by ``overlap`` of this person's width."""
    xs, oxs = np.nonzero(mask)[1], np.nonzero(other_mask)[1]
    width = xs.max() - xs.min()
    right = xs.mean() < mask.shape[1] / 2
    if right:  # other's left edge at this person's right edge minus the overlap
        dx = int(round(xs.max() - overlap * width - oxs.min()))
    else:
        dx = int(round(xs.min() + overlap * width - oxs.max()))
    moved = shift(other_mask, dx)
    xy = other_kp.xy + np.array([dx, 0.0])
    return mask | moved, moved, KeypointSet(xy, other_kp.conf, other_kp.layout, source="second")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--seed", type=int, default=5501)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--overlap", type=float, default=0.3)
    ap.add_argument("--conditions", default="clean,clothing,cut,second")
    ap.add_argument("--methods", default="main,after")
    ap.add_argument("--per-subject", action="store_true", help="print each subject's PA-PVE under the table")
    ap.add_argument(
        "--decompose",
        action="store_true",
        help="print each method's PA-PVE with the true shape, with the true body_pose, and its vertices' error in the image",
    )
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="change a field of 'after'")
    args = ap.parse_args()
    from bench_truncation import _value

    after = {k: None if v.lower() == "none" else _value(v) for k, v in (x.split("=", 1) for x in args.set)}
    from silfit.synth.generate import SynthConfig, generate_dataset

    model = load_body_model()
    with tempfile.TemporaryDirectory() as tmp:
        generate_dataset(
            Path(tmp) / "d", args.n, SynthConfig(seed=args.seed, size=args.size, noise_px=1.0), model=model
        )
        dirs = sorted(p for p in (Path(tmp) / "d").iterdir() if (p / "gt.npz").is_file())
        raw = [
            (
                read_keypoints(d / "keypoints.json"),
                read_mask(d / "mask.png"),
                load_camera(d / "camera.json"),
                read_gt(d / "gt.npz"),
                cut_subject(d),
            )
            for d in dirs
        ]
    subjects = []  # per subject: {condition: (keypoints, mask, camera, others)}, gt
    for i, (kp, mask, cam, gt, (kc, mc, cc, _)) in enumerate(raw):
        height = np.ptp(np.nonzero(mask)[0])
        okp, omask = raw[(i + 1) % len(raw)][0], raw[(i + 1) % len(raw)][1]
        joined, moved, mkp = second_person(mask, kp, omask, okp, args.overlap)
        grown_px = max(1, int(0.04 * height))
        grown = grow(mask, grown_px)
        closed = shrink(grown, grown_px)
        for m, px in ((mask, 0), (grown, grown_px), (mc, 0), (joined, 0), (closed, 0)):
            TRUTH[np.asarray(m, dtype=bool).tobytes()] = px
        subjects.append(
            (
                {
                    "clean": (kp, mask, cam, ()),
                    "clothing": (kp, grown, cam, ()),
                    "cut": (kc, mc, cc, ()),
                    "second": (kp, joined, cam, ((moved, mkp),)),
                    "closed": (kp, closed, cam, ()),
                },
                gt,
            )
        )
    fitter = KeypointFitter(model)
    print(
        f"# Degraded masks: {len(subjects)} subjects (seed {args.seed}, {args.size} px, second person's overlap "
        f"{args.overlap:.0%})" + (f"; after: {after}" if after else "") + "\n"
    )
    print(
        "| condition | method | PA-PVE mean / worst (mm) | vs keypoints only | PVE mean (mm) | reprojection median px | "
        "IoU mean | turned back | most worsened (mm) / fits worse by > 5 mm | s per image |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    kp_cache, estimates, each, parts, kp_parts = {}, {}, {}, {}, {}
    for cond in args.conditions.split(","):
        sets, masks, cams, others = (list(x) for x in zip(*[c[cond] for c, _ in subjects]))
        gts = [g for _, g in subjects]
        key = "cut" if cond == "cut" else "full"
        if key not in kp_cache:
            kp_cache[key] = fitter.fit(sets, cams, progress=False)
        kp = kp_cache[key]
        base = [_score(model, kp.params(i), g, None, reproj=float(kp.reprojection_error[i])) for i, g in enumerate(gts)]
        ref = float(np.mean([r["pa"] for r in base]))
        _row(cond, "keypoints only", base, ref, None)
        each[(cond, "keypoints only")] = [r["pa"] for r in base]
        if args.decompose:  # the keypoint fits' once per keypoint fit (the conditions but cut share one)
            if key not in kp_parts:
                kp_parts[key] = [decompose(model, kp.params(i), g, c) for i, (g, c) in enumerate(zip(gts, cams))]
            parts[(cond, "keypoints only")] = kp_parts[key]
        ref_each = np.array([r["pa"] for r in base])
        runs = [
            (m, MAIN if m == "main" else {**after, **VARIANTS.get(m, {})}, m != "main") for m in args.methods.split(",")
        ]
        from silfit.silhouette import losses

        if cond == "second" and "after" in args.methods.split(","):
            runs.append(("after, no subtraction", after, False))
        for name, changes, subtract in runs:
            cfg = config_with(SilhouetteFitConfig, changes, stage="silhouette")
            known = None
            if subtract:  # the other person's region of the mask unknown (Person.own_mask, as silfit fit --image)
                own = [
                    own_mask(
                        m,
                        (k.xy, k.conf, k.names),
                        [(om, ok.xy, ok.conf, ok.names, 0.06 * _extent(ok)) for om, ok in o],
                        keep=KEEP * _extent(k),
                    )
                    for m, k, o in zip(masks, sets, others)
                ]
                known = [None if np.array_equal(o, m) else ~(m & ~o) for o, m in zip(own, masks)]
            t0 = time.perf_counter()
            ESTIMATES.clear()
            # the stage reads the estimate through silfit.fitting.image_fit's own name (imported from losses)
            estimate_of, patched = oracle_thickness(name == "oracle")
            losses.clothing_thickness = image_fit.clothing_thickness = patched
            try:
                fits = refine_batch(model, kp, sets, masks, cfg, fitter.pose_prior, progress=False, known=known)
            finally:
                losses.clothing_thickness = image_fit.clothing_thickness = estimate_of
            estimates[(cond, name)] = list(ESTIMATES)
            seconds = (time.perf_counter() - t0) / len(fits)
            rows = [_score(model, f.params, g, f) for f, g in zip(fits, gts)]
            for r, f, m in zip(rows, fits, masks):  # IoU with the given mask (the whole of it)
                from silfit.eval.metrics import mask_iou

                r["iou"] = mask_iou(f.masks["final"], m)
            _row(cond, name, rows, ref, seconds, ref_each)
            each[(cond, name)] = [r["pa"] for r in rows]
            if args.decompose:
                parts[(cond, name)] = [decompose(model, f.params, g, c) for f, g, c in zip(fits, gts, cams)]
    if args.per_subject:
        print("\n| condition | method | PA-PVE per subject (mm) |\n|---|---|---|")
        for (cond, name), pa in each.items():
            print(f"| {cond} | {name} | {' '.join(f'{v:.1f}' for v in pa)} |")
    if parts:
        print(
            "\n| condition | method | PA-PVE (mm) | with the true shape | with the true body_pose | vertices in the image "
            "(px) |\n|---|---|---:|---:|---:|---:|"
        )
        for (cond, name), p in parts.items():
            a = np.mean(np.array(p), axis=0)
            print(f"| {cond} | {name} | {np.mean(each[cond, name]):.1f} | {a[0]:.1f} | {a[1]:.1f} | {a[2]:.2f} |")
    print("\n| condition | method | true growth px per subject | estimate px per subject |\n|---|---|---|---|")
    for (cond, name), pairs in estimates.items():
        if pairs:
            truth = " ".join("?" if t is None else str(t) for _, t in pairs)
            print(f"| {cond} | {name} | {truth} | {' '.join(f'{e:.1f}' for e, _ in pairs)} |")


def decompose(model, params: dict, gt, camera) -> tuple:
    """(PA-PVE with the true ``betas``, PA-PVE with the true ``body_pose``, mean distance in pixels between the fit's
    and the truth's vertices projected by ``camera``) of one fit (mm, mm, px)."""
    from silfit.eval.metrics import pa_pve

    def vertices(p):
        T = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64).reshape(1, -1), dtype=model.dtype)  # noqa: E731
        with torch.no_grad():
            names = ("betas", "body_pose", "global_orient", "transl")
            return model(**{k: T(p[k]) for k in names}).vertices[0].double()

    g = gt.vertices
    betas = np.zeros(np.size(params["betas"]))
    n = min(betas.size, np.size(gt.betas))
    betas[:n] = np.ravel(gt.betas)[:n]
    v = vertices(params)
    image = project_points(v, camera) - project_points(torch.as_tensor(g, dtype=v.dtype), camera)
    return (
        1000 * pa_pve(vertices({**params, "betas": betas}).numpy(), g),
        1000 * pa_pve(vertices({**params, "body_pose": gt.body_pose}).numpy(), g),
        float(image.norm(dim=-1).mean()),
    )


def _extent(kp: KeypointSet) -> float:
    pts = kp.xy[kp.conf > 0.1]
    return float((pts.max(0) - pts.min(0)).max()) if len(pts) >= 2 else 0.0


def _row(cond, name, rows, ref, seconds, ref_each=None) -> None:
    get = lambda k: np.array([r[k] for r in rows], dtype=np.float64)  # noqa: E731
    pa = get("pa")
    worse = "" if ref_each is None else f"{(pa - ref_each).max():+.1f} / {int(np.sum(pa - ref_each > 5.0))}"
    gain = "" if seconds is None else f"{100 * (ref - pa.mean()) / ref:+.1f} %"
    iou = get("iou")
    print(
        f"| {cond} | {name} | {pa.mean():.1f} / {pa.max():.1f} | {gain} | {get('pve').mean():.1f} | "
        f"{np.median(get('reproj')):.2f} | {np.nanmean(iou) if np.isfinite(iou).any() else float('nan'):.3f} | "
        f"{int(get('kept_kp').sum())} | {worse} | {'' if seconds is None else f'{seconds:.1f}'} |",
        flush=True,
    )


if __name__ == "__main__":
    main()
