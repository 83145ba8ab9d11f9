"""Real-photo conditions: the silhouette stage before and after issue 23, in one run.

Subjects from silfit's generator (fully visible, all yaws) under four conditions:
``clean`` masks; ``cut``: the image cut at mid-thigh (rows below the midpoint of the projected
hips and knees removed: mask, keypoints below the cut at confidence 0, the same camera with a
shorter image); ``clothing``: the mask dilated by 4 % of the person's height (loose clothes,
hair); ``leak``: a block as wide as 30 % of the person's height joined to the mask's side at the
hips (a segmentation leak into an object) and three small holes (discs of 2.5 % of the height,
deep inside the mask: segmentation gaps); ``detected``: keypoints and mask from
:func:`silfit.detect.detect_people` on the rendered image instead of the renderer (the subjects
the detector finds; their count is in the header); not in the default list, ``detected_kp`` (the
detector's keypoints with the true mask) and ``detected_mask`` (the true keypoints with the segmenter's
mask) tell which detected input the stage suffers from. Each subject is fitted once by the keypoint stage,
then by the silhouette stage per method: *original* (before issue 23: ``truncation_aware=False``,
no keypoint trust region, no bound on |beta|, the plain two-sided energy), *before* (issue 23's
first part, the plain energy, no clothing trim, no plausibility guard: HEAD before the second
part) and *after* (the defaults: the robust, capped mask-not-covered side, the clothing trim, leaks and small holes unknown and
the plausibility guard), *main* (the defaults before issue 23's third part: no leak or hole
set aside as unknown, ``leak_distance=0, hole_fraction=0``), *tight* (the defaults before the detected-input change: the keypoint
trust region at 3 % of the window, ``trust_fraction=0.03``); *noconcave* (the defaults before the concavity change: ``concave_radius=0``), *concaveall* (the
concavities unknown in every mask, ``concave_trimmed_only=False``); *weakprior* (the defaults before the
detected-input pose-prior change: ``pose_weight=0.002``); *closeoff* (the defaults before issue 25's close-alternatives
part: ``alternatives_margin=0``, the keypoint stage's branch only refined against the mask); ``--methods`` picks them, ``--set`` changes the after configuration
(tuning). The last column counts the subjects whose mask was trimmed as clothing and those
whose fit the guard replaced by the keypoint fit. Printed per condition: PA-PVE and PVE
(mm, against the whole true body), median reprojection error (px, visible keypoints), max |beta|,
IoU with the given mask (inside the image) and the stage's seconds; mean and worst.

    python benchmarks/bench_truncation.py --n 6 --seed 101 --methods original,before,main,after
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
from silfit.camera import Camera, load_camera, project_points
from silfit.io.subjects import read_gt, read_mask
from silfit.eval.metrics import procrustes_align
from silfit.fitting import KeypointFitter
from silfit.fitting.silhouette_stage import SilhouetteFitConfig
from silfit.runner.worker import config_with
from silfit.io.keypoints import KeypointSet, read_keypoints
from silfit.fitting.image_fit import refine_batch


def cut_subject(d: Path):
    """(keypoints, mask, camera, gt) of subject folder ``d`` with the image cut at mid-thigh."""
    gt = read_gt(d / "gt.npz")
    cam = load_camera(d / "camera.json")
    uv = project_points(torch.as_tensor(gt.joints), cam).numpy()
    kp = read_keypoints(d / "keypoints.json")
    hips = [kp.names.index(n) for n in ("mid_hip", "left_hip", "right_hip")]
    cut = int(round(0.5 * (uv[[1, 2], 1].mean() + uv[[4, 5], 1].mean())))
    cut = max(cut, int(np.ceil(kp.xy[hips, 1].max())) + 4)  # the hips stay in the image (a torso to fit)
    cut = min(max(cut, 16), cam.height - 1)
    conf = np.where(kp.xy[:, 1] < cut - 0.5, kp.conf, 0.0)
    short = Camera(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cut)
    mask = read_mask(d / "mask.png")[:cut]
    return KeypointSet(kp.xy, conf, kp.layout, source=str(d)), mask, short, gt


def _disc(px: int):
    """The elliptic structuring element of radius ``px`` that :func:`grow` and :func:`shrink` use."""
    import cv2

    k = 2 * int(px) + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))


def grow(mask: np.ndarray, px: int) -> np.ndarray:
    import cv2

    return cv2.dilate(mask.astype(np.uint8), _disc(px)).astype(bool)


def shrink(mask: np.ndarray, px: int) -> np.ndarray:
    """``mask`` eroded by :func:`grow`'s disc: ``shrink(grow(m, px), px)`` is ``m`` closed, what a perfect trim of a
    growth gives back (the gaps narrower than the growth stay filled)."""
    import cv2

    return cv2.erode(mask.astype(np.uint8), _disc(px)).astype(bool)


def leak(mask: np.ndarray, kp: KeypointSet, holes: int = 3) -> np.ndarray:
    """A block joined to the mask's side at the hips and ``holes`` small holes (discs of 2.5 % of
    the height, centred at the deepest mask pixels apart from one another: segmentation gaps)."""
    import cv2

    ys, xs = np.nonzero(mask)
    height = ys.max() - ys.min()
    hip_y = int(kp.xy[kp.names.index("mid_hip"), 1])
    out = mask.copy()
    x0 = xs.max() - 2
    out[max(hip_y - height // 10, 0) : hip_y + height // 10, x0 : x0 + int(0.3 * height)] = True
    r = max(1, int(round(0.025 * height)))
    depth = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 3)
    for _ in range(holes):
        y, x = np.unravel_index(int(np.argmax(depth)), depth.shape)
        if depth[y, x] <= r + 1:
            break
        cv2.circle(depth, (int(x), int(y)), 4 * r, 0.0, -1)  # the next hole elsewhere
        hole = np.zeros(mask.shape, np.uint8)
        cv2.circle(hole, (int(x), int(y)), r, 1, -1)
        out &= ~hole.astype(bool)
    return out


def detected(d: Path):
    """(keypoints, mask) of subject folder ``d`` from :func:`silfit.detect.detect_people` on its
    rendered image, or ``None`` when nobody is found."""
    from silfit.io.subjects import read_image
    from silfit.detect import DetectionError, detect_people

    try:
        person = detect_people(read_image(d / "image.png"), source=d.name)[0]
    except DetectionError:
        return None
    return person.keypoint_set(source=str(d)), person.mask()


def conditions(d: Path):
    """{condition: (keypoints, mask, camera)} and the truth of subject folder ``d``."""
    gt = read_gt(d / "gt.npz")
    kp, mask, cam = read_keypoints(d / "keypoints.json"), read_mask(d / "mask.png"), load_camera(d / "camera.json")
    height = np.ptp(np.nonzero(mask)[0])
    kc, mc, cc, _ = cut_subject(d)
    out = {
        "clean": (kp, mask, cam),
        "cut": (kc, mc, cc),
        "clothing": (kp, grow(mask, max(1, int(0.04 * height))), cam),
        "leak": (kp, leak(mask, kp), cam),
    }
    found = detected(d)
    if found is not None:
        out["detected"] = (found[0], found[1], cam)
        out["detected_kp"] = (found[0], mask, cam)  # which detected input costs: the keypoints with the true mask
        out["detected_mask"] = (kp, found[1], cam)  # and the true keypoints with the segmenter's mask
    return out, gt


#: the silhouette stage before issue 23 (no truncation, no keypoint trust region, no bound on |beta|,
#: the plain two-sided energy)
ORIGINAL = {
    "mask.truncation_aware": False,
    "w_trust": 0.0,
    "w_beta_bound": 0.0,
    "mask.robust_cover": False,
    "mask.trim_clothing": False,
    "plausibility_guard": False,
    "mask.leak_distance": 0.0,
    "mask.hole_fraction": 0.0,
    "alternatives_margin": 0.0,
}
#: before the clothing/leak-robust energy (issue 23's first part: truncation, trust region, beta bound)
BEFORE = {
    "mask.robust_cover": False,
    "mask.trim_clothing": False,
    "plausibility_guard": False,
    "mask.leak_distance": 0.0,
    "mask.hole_fraction": 0.0,
    "alternatives_margin": 0.0,
}
#: main before the leak/hole handling (issue 23's third part): no unknown leaks or holes
MAIN = {"mask.leak_distance": 0.0, "mask.hole_fraction": 0.0}
#: the defaults before the detected-input change: the keypoint trust region at 3 % of the window
TIGHT = {"trust.fraction": 0.03}
#: the defaults before the concavity change: no mask pixel in the keypoint fit's concavities unknown
NOCONCAVE = {"mask.concave_radius": 0.0}
#: the concavities unknown in every mask, not only in those trimmed as clothing
CONCAVEALL = {"mask.concave_trimmed_only": False}
#: the defaults before the detected-input change: the silhouette stage's pose prior at 0.002
WEAKPRIOR = dict(pose_weight=0.002)
#: the defaults before issue 25's close-alternatives part: only the keypoint stage's branch refined against the mask
#: (``original`` and ``before`` predate it too; the other methods are today's defaults with one change)
CLOSEOFF = dict(alternatives_margin=0.0)
METHODS = {
    "original": ORIGINAL,
    "before": BEFORE,
    "main": MAIN,
    "tight": TIGHT,
    "noconcave": NOCONCAVE,
    "concaveall": CONCAVEALL,
    "weakprior": WEAKPRIOR,
    "closeoff": CLOSEOFF,
    "after": {},
}


def _value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--conditions", default="clean,cut,clothing,leak,detected", help="comma-separated subset")
    ap.add_argument("--methods", default="main,after", help=f"comma-separated, of {', '.join(METHODS)}")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="change a SilhouetteFitConfig field of 'after' (tuning), repeatable",
    )
    ap.add_argument("--per-subject", action="store_true", help="also print each subject's PA-PVE (mm) per row")
    args = ap.parse_args()
    global _PER_SUBJECT
    _PER_SUBJECT = args.per_subject
    after = {k: _value(v) for k, v in (x.split("=", 1) for x in args.set)}
    methods = {m: (after if m == "after" else METHODS[m]) for m in args.methods.split(",")}

    from silfit.synth.generate import SynthConfig, generate_dataset

    model = load_body_model()
    with tempfile.TemporaryDirectory() as tmp:
        generate_dataset(
            Path(tmp) / "d", args.n, SynthConfig(seed=args.seed, size=args.size, noise_px=1.0), model=model
        )
        dirs = sorted(p for p in (Path(tmp) / "d").iterdir() if (p / "gt.npz").is_file())
        subjects = [conditions(d) for d in dirs]
    fitter = KeypointFitter(model)
    found = sum("detected" in c for c, _ in subjects)
    print(
        f"# Real-photo conditions: {len(subjects)} subjects per condition, detected: {found} found (seed {args.seed}, {args.size} px)"
        + (f"; after: {after}" if after else "")
        + "\n"
    )
    print(
        "| condition | method | PA-PVE mean / worst (mm) | PVE mean (mm) | reprojection median px (mean / worst) | max abs beta | IoU mean | s per image | trimmed / kept kp fit |"
    )
    print("|---|---|---|---:|---|---:|---:|---:|---:|")
    kp_cache = {}  # clean, clothing and leak share the keypoints: one keypoint fit
    for cond in args.conditions.split(","):
        have = [(c, g) for c, g in subjects if cond in c]  # "detected": the subjects the detector found
        if not have:
            print(f"| {cond} | (no subject) | | | | | | | |")
            continue
        sets, masks, cams = (list(x) for x in zip(*[c[cond] for c, _ in have]))
        gts = [g for _, g in have]
        # the detected conditions hold the subjects the detector found only: a keypoint fit of their own
        key = {"cut": "cut", "detected": "detected", "detected_kp": "detected", "detected_mask": "detected_mask"}.get(
            cond, "full"
        )
        if key not in kp_cache:
            kp_cache[key] = fitter.fit(sets, cams, progress=False)
        kp = kp_cache[key]
        _row(
            cond,
            "keypoints only",
            [_score(model, kp.params(i), g, None, reproj=float(kp.reprojection_error[i])) for i, g in enumerate(gts)],
            None,
        )
        for name, changes in methods.items():
            cfg = config_with(SilhouetteFitConfig, changes, stage="silhouette")
            t0 = time.perf_counter()
            fits = refine_batch(model, kp, sets, masks, cfg, fitter.pose_prior, progress=False)
            seconds = (time.perf_counter() - t0) / len(fits)
            _row(cond, name, [_score(model, f.params, g, f) for f, g in zip(fits, gts)], seconds)


def _score(model, params, gt, fit, reproj=None) -> dict:
    T = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64).reshape(1, -1), dtype=model.dtype)  # noqa: E731
    with torch.no_grad():
        v = (
            model(**{k: T(params[k]) for k in ("betas", "body_pose", "global_orient", "transl")})
            .vertices[0]
            .double()
            .numpy()
        )
    pa = 1000 * np.linalg.norm(procrustes_align(v, gt.vertices) - gt.vertices, axis=-1).mean()
    pve = 1000 * np.linalg.norm(v - gt.vertices, axis=-1).mean()
    m = fit.metrics if fit is not None else {}
    warnings = m.get("warnings", [])
    return {
        "pa": pa,
        "pve": pve,
        "reproj": m.get("reprojection_error_px", reproj),
        "beta": float(np.abs(params["betas"]).max()),
        "iou": m.get("iou", float("nan")),
        "trimmed": any("trimmed by" in w for w in warnings),
        "kept_kp": m.get("silhouette_guard", {}).get("kept") == "keypoints",
    }


_PER_SUBJECT = False


def _row(cond, name, rows, seconds) -> None:
    get = lambda k: np.array([r[k] for r in rows], dtype=np.float64)  # noqa: E731
    pa, rp = get("pa"), get("reproj")
    if _PER_SUBJECT:
        print(f"<!-- {cond} / {name}: PA-PVE per subject {' '.join(f'{x:.1f}' for x in pa)} -->")
    print(
        f"| {cond} | {name} | {pa.mean():.1f} / {pa.max():.1f} | {get('pve').mean():.1f} | {rp.mean():.1f} / {rp.max():.1f} | "
        f"{get('beta').max():.2f} | {np.nanmean(get('iou')) if np.isfinite(get('iou')).any() else float('nan'):.3f} | "
        f"{'' if seconds is None else f'{seconds:.1f}'} | {int(get('trimmed').sum())} / {int(get('kept_kp').sum())} |"
    )


if __name__ == "__main__":
    main()
