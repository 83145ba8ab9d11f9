"""``silfit detect``: person keypoints (OpenPose JSON) and mask (PNG) from a photo, with
the shipped BlazePose models; writes the folder described in :mod:`silfit.detect.output`."""

from __future__ import annotations

from . import CLIError, warn
from .common import check_out


def _positive_int(text: str) -> int:
    import argparse

    if not text.strip().isdigit() or int(text) <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return int(text)


def people_count(text: str) -> int:
    """``--people``: a positive integer, or ``all`` (0: every person found)."""
    if text.strip().lower() == "all":
        return 0
    return _positive_int(text)


def register(subparsers) -> None:
    p = subparsers.add_parser("detect", help="detect people in a photo: OpenPose keypoints JSON + mask PNG")
    p.add_argument("image", help="the photo (JPEG, PNG, ...)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument(
        "--layout",
        choices=("body25", "coco17", "blazepose33"),
        default="body25",
        help="keypoint layout written (default body25, what silfit fit uses)",
    )
    p.add_argument(
        "--people",
        type=people_count,
        default=1,
        metavar="N|all",
        help="detect up to N people, or every person found ('all': the detector also runs on tiles "
        "of the photo); default 1",
    )
    p.add_argument(
        "--min-score",
        type=float,
        default=0.5,
        help="person detector score threshold (default 0.5; lower finds more people seen from behind, "
        "and more things that are not people)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bars (as for every command; detect shows none: its result lines and warnings are printed)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from ..detect import DetectConfig
    from ..detect.output import detect_photo, save_detection

    out = Path(args.out)
    check_out(out, args.overwrite)
    if not 0.0 < args.min_score < 1.0:
        raise CLIError(f"--min-score {args.min_score}: expected a value between 0 and 1")
    photo, people = detect_photo(args.image, DetectConfig(min_score=args.min_score, max_people=args.people))
    save_detection(out, photo, people, layout=args.layout, overwrite=args.overwrite)
    print(f"wrote {out}: {len(people)} person(s) in {args.image} ({photo.size[0]}x{photo.size[1]})")
    for warning in photo.warnings():
        warn(warning)
    for i, p in enumerate(people):
        for warning in p.warnings():
            warn(f"person {i}: {warning}")
    return 0


def photo_inputs(image_path: str, person, detect: bool, want_mask: bool, detected=None) -> dict:
    """What ``silfit fit --image`` takes from the photo: its pixels (upright), the EXIF focal
    length and, when ``detect`` (no ``--keypoints``), the detected person's BODY_25
    keypoints, mask (if ``want_mask``) and ``known`` (with several people detected, the mask's pixels that are
    not the other people's: :meth:`~silfit.detect.person.Person.own_mask`; the silhouette stage neither fits
    nor avoids the others, ``None``: all known), detection summary and warnings. ``detected``: the
    ``(photo, people)`` of an earlier detection (``--people all``), reused."""
    from ..detect import DetectConfig
    from ..detect.output import detect_photo
    from ..detect.photo import read_photo

    out = {"keypoints": None, "mask": None, "known": None, "warnings": [], "metrics": {}}
    if detect:
        index = None if person == "largest" else int(person)
        photo, people = detected or detect_photo(image_path, DetectConfig(max_people=3 if index is None else index + 1))
        if index is not None and index >= len(people):
            raise CLIError(f"{image_path}: person {index} requested, {len(people)} detected")
        chosen = people[index or 0]
        out["keypoints"] = chosen.keypoint_set("body25", source=f"{image_path} (detected keypoints)")
        out["person"] = chosen  # its 3D landmarks: the image depth cue
        out["warnings"] = [f"detection: {w}" for w in chosen.warnings()]
        summary = chosen.to_dict()
        summary.pop("landmarks")
        out["metrics"]["detection"] = {"people_found": len(people), "person": index or 0, **summary}
        if want_mask:  # other people are not this person (issue 55): their regions of this person's mask unknown
            import numpy as np

            out["mask"] = chosen.mask()
            removed_px = out["mask"] & ~chosen.own_mask(people) if len(people) > 1 else np.zeros_like(out["mask"])
            out["known"] = ~removed_px if removed_px.any() else None
            removed = int(removed_px.sum())
            out["metrics"]["detection"]["mask_other_people_px"] = removed
            if removed > 0.02 * max(int(chosen.mask().sum()), 1):
                out["warnings"].append(
                    f"detection: {removed / chosen.mask().sum():.0%} of the person's mask belongs to the "
                    f"{len(people) - 1} other people detected: left out of the silhouette fit"
                )
    else:
        photo = read_photo(image_path)
    out["warnings"] = [*photo.warnings(), *out["warnings"]]
    out["image"], out["size"] = photo.image, photo.size
    out["focal"], out["focal_source"] = photo.focal()
    return out
