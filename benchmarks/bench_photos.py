"""Real photographs of people: detect, fit (keypoints, then the silhouette stage before and after
issue 23's robust energy), and print what can be checked without 3D truth.

Photos: those shipped inside installed packages (scikit-image's ``astronaut`` and ``camera``,
matplotlib's ``grace_hopper``), plus ``--extra`` files or wheels (every ``assets/*.jpg`` in a
``.whl``; e.g. ultralytics' wheel holds ``bus.jpg``, a street scene with four people, and
``zidane.jpg``, two football coaches cut off at the waist: ``pip download ultralytics --no-deps``).
Nothing is downloaded at run time.

Every person detected in a photo leaves the others' masks (issue 55: :meth:`silfit.detect.person.Person.own_mask`,
as ``silfit fit --image`` does; ``--whole-mask``: before it). Per photo and person (the largest; ``--people all``:
every person detected), printed as a table:
median reprojection error of the keypoint stage, of the silhouette stage *before* (issue 23's
first part: truncation-aware, keypoint trust region, beta bound; the plain mask energy; no
clothing trim, no plausibility guard) and *after* (the defaults; ``--set FIELD=VALUE``: one changed), max |beta| and stature (m)
before/after, the share of the final body's vertices projected outside the image, the IoU with the mask of
the keypoint fit and of the final fit, whether the silhouette stage's result was kept or turned back by the
plausibility guard, and the after fit's warnings (shortened). A contact sheet (per person: the final body over the photo, and the
side view over the keypoint fit in orange) goes to ``docs/photos_sheet.png`` (``--sheet``).

    python benchmarks/bench_photos.py --extra ultralytics-8.4.190-py3-none-any.whl --people all
"""

from __future__ import annotations

import argparse
import tempfile
import time
import zipfile
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np

BEFORE = {
    "mask.robust_cover": False,
    "mask.trim_clothing": False,
    "plausibility_guard": False,
    "mask.leak_distance": 0.0,
    "mask.hole_fraction": 0.0,
}


def shipped_photos() -> list:
    """``(name, path)`` of photos of people inside installed packages."""
    out = []
    try:
        import skimage

        for name in ("astronaut", "camera"):
            p = Path(skimage.__file__).parent / "data" / f"{name}.png"
            if p.is_file():
                out.append((name, p))
    except ImportError:
        pass
    try:
        import matplotlib

        p = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
        if p.is_file():
            out.append(("grace_hopper", p))
    except ImportError:
        pass
    return out


def extra_photos(paths, tmp: Path) -> list:
    out = []
    for path in map(Path, paths):
        if path.suffix == ".whl":
            with zipfile.ZipFile(path) as z:
                for member in sorted(z.namelist()):
                    if "/assets/" in member and member.lower().endswith((".jpg", ".jpeg", ".png")):
                        target = tmp / Path(member).name
                        target.write_bytes(z.read(member))
                        out.append((target.stem, target))
        else:
            out.append((path.stem, path))
    return out


def _short(warning: str) -> str:
    keys = [
        ("kept the keypoint fit", "guard: kept kp fit"),
        ("person cut off", "cut off"),
        ("trimmed by", "clothing trimmed"),
        ("runs out of the image", "cut off"),
        ("lower body not visible", "lower body hidden"),
        ("depth ambiguous", "depth ambiguous"),
        ("moved the body away", "reprojection rise"),
        ("implausible body shape", "|betas| > 3"),
        ("far from the keypoint fit's body", "leak ignored"),
        ("IoU", "low IoU"),
    ]
    for key, text in keys:
        if key in warning:
            return text
    return warning[:40]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--extra", action="append", default=[], help="more photos: image files or wheels (assets/*.jpg)")
    ap.add_argument("--people", choices=("largest", "all"), default="largest")
    ap.add_argument("--sheet", default=str(Path(__file__).resolve().parents[1] / "docs" / "photos_sheet.png"))
    ap.add_argument("--only", help="comma-separated photo names (default: all)")
    ap.add_argument("--no-before", action="store_true", help="skip the 'before' silhouette stage (faster)")
    ap.add_argument(
        "--whole-mask",
        action="store_true",
        help="each person's whole mask (before issue 55: the other people detected not taken out)",
    )
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="change a field of 'after'")
    args = ap.parse_args()
    from bench_truncation import _value

    changes = {k: None if v.lower() == "none" else _value(v) for k, v in (x.split("=", 1) for x in args.set)}

    from silfit.outputs import figures
    from silfit.body import load_body_model
    from silfit.camera import project_points
    from silfit.detect import DetectConfig
    from silfit.detect.output import detect_photo
    from silfit.errors import InputError
    from silfit.fitting import KeypointFitter
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.runner.worker import config_with
    from silfit.fitting.image_fit import refine
    from silfit.fitting.plausibility import body_stature, check_keypoints, fit_warnings

    import torch

    model = load_body_model()
    faces = model.faces.cpu().numpy()
    fitter = KeypointFitter(model)
    rows, panels, titles = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        photos = shipped_photos() + extra_photos(args.extra, Path(tmp))
        if args.only:
            photos = [(n, p) for n, p in photos if n in args.only.split(",")]
        print(f"# Real photos: {len(photos)} ({', '.join(n for n, _ in photos)}), people: {args.people}\n")
        print(
            "| photo | person | reprojection px kp / before / after | after / kp | max abs beta before / after | "
            "stature m before / after | body outside image | IoU kp / after | kept | s | warnings (after) |"
        )
        print("|---|---:|---|---:|---|---|---:|---|---|---:|---|")
        for name, path in photos:
            try:  # every person detected: the others leave each one's mask (issue 55), as silfit fit --image does
                photo, people = detect_photo(path, DetectConfig(max_people=0 if args.people == "all" else 3))
            except InputError as e:
                print(f"| {name} | - | {e} | | | | | | |")
                continue
            focal, _ = photo.focal()
            for i, person in enumerate(people if args.people == "all" else people[:1]):
                t0 = time.perf_counter()
                kp = person.keypoint_set(source=f"{name} person {i}")
                mask, known = person.mask(), None
                if len(people) > 1 and not args.whole_mask:  # the other people's part of the mask: unknown
                    known = ~(mask & ~person.own_mask(people))
                kp, notes = check_keypoints(kp, photo.size)
                kp_fit = fitter.fit([kp], image_size=photo.size, focal=focal, progress=False)
                fits = {
                    "after": refine(
                        model,
                        kp_fit,
                        kp,
                        mask,
                        config_with(SilhouetteFitConfig, changes, stage="silhouette"),
                        fitter.pose_prior,
                        progress=False,
                        mask_source=f"{name} mask",
                        known=known,
                    )
                }
                if not args.no_before:
                    fits["before"] = refine(
                        model,
                        kp_fit,
                        kp,
                        mask,
                        config_with(SilhouetteFitConfig, BEFORE, stage="silhouette"),
                        fitter.pose_prior,
                        progress=False,
                        mask_source=f"{name} mask",
                    )
                seconds = time.perf_counter() - t0
                after = fits["after"]
                m = after.metrics
                warnings = list(m["warnings"]) + fit_warnings(m, kp, after.vertices, after.params.get("betas")) + notes
                warnings += [f"detection: {w}" for w in person.warnings()]
                cam = after.camera
                uv = project_points(torch.as_tensor(after.vertices, dtype=torch.float64), cam).numpy()
                outside = float(
                    np.mean((uv[:, 0] < 0) | (uv[:, 0] > cam.width) | (uv[:, 1] < 0) | (uv[:, 1] > cam.height))
                )
                beta = {k: float(np.abs(f.params["betas"]).max()) for k, f in fits.items()}
                height = {k: body_stature(model, f.params["betas"]) for k, f in fits.items()}
                rp = {k: f.metrics["reprojection_error_px"] for k, f in fits.items()}
                b = lambda d, k: f"{d[k]:.2f}" if k in d else "-"  # noqa: E731
                short = sorted({_short(w) for w in warnings})
                reasons = m.get("silhouette_guard", {}).get("less_plausible", [])
                if reasons:
                    short = [
                        f"guard: kept kp fit ({', '.join(reasons)})" if w.startswith("guard") else w for w in short
                    ]
                rows.append((name, i, m["reprojection_error_px_keypoint_stage"], rp, beta, height, outside, short))
                kept = m.get("silhouette_guard", {}).get("kept", "silhouette")
                r0 = m["reprojection_error_px_keypoint_stage"]
                print(
                    f"| {name} | {i} | {r0:.2f} / {b(rp, 'before')} / {rp['after']:.2f} | {rp['after'] / r0:.2f} | "
                    f"{b(beta, 'before')} / {beta['after']:.2f} | {b(height, 'before')} / {height['after']:.2f} | "
                    f"{outside:.0%} | {m['iou_keypoint_stage']:.3f} / {m['iou']:.3f} | "
                    f"{'silhouette' if kept == 'silhouette' else 'turned back'} | {seconds:.0f} | {'; '.join(short)} |",
                    flush=True,
                )
                front = figures.fit_overlay(photo.image, after.vertices, faces, cam, kp.xy, None, kp.conf)
                scale = 360 / max(front.shape[:2])
                if scale < 1:
                    import cv2

                    front = cv2.resize(
                        front, (int(front.shape[1] * scale), int(front.shape[0] * scale)), interpolation=cv2.INTER_AREA
                    )
                panels += [front, figures.side_view(after.vertices, faces, after.keypoint.vertices[0], size=(288, 360))]
                titles += [f"{name} #{i}: final", f"{name} #{i}: side (orange: kp fit)"]
    if panels:
        Path(args.sheet).parent.mkdir(parents=True, exist_ok=True)
        figures.contact_sheet(panels, titles, args.sheet, columns=4)
        print(f"\ncontact sheet: {args.sheet}")


if __name__ == "__main__":
    main()
