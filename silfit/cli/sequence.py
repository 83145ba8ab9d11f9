"""``silfit fit --sequence DIR``: one person over a video's frames (per-frame OpenPose JSON).

Reads the frames (:func:`silfit.video.read_sequence`), fits them
(:func:`silfit.fitting.sequence.fit_sequence`: per-frame fits, consistent facings, a
joint refinement with one shape and temporal smoothness; frames without usable keypoints
bridged by their neighbours) and writes the folder of :func:`silfit.video.save_sequence_fit`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import CLIError


def _camera(args, seq):
    from ..camera import Camera, camera_from_dict, load_camera
    from ..imagefile import image_file_size

    if args.camera or seq.camera:
        return load_camera(args.camera or seq.camera), "camera file"
    size = None
    if args.image_size:
        try:
            size = tuple(int(v) for v in args.image_size.lower().split("x"))
        except ValueError:
            raise CLIError(f"--image-size {args.image_size!r}: expected WxH, e.g. 640x480") from None
    else:
        for files, what in ((seq.images, "image"), (seq.masks, "mask")):
            if files:
                size = image_file_size(next(iter(files.values())), what)
                break
    if size is None:
        raise CLIError("no camera: give --camera C.json, or --images / --masks / --image-size for the default camera")
    cam = Camera.from_image_size(*size)
    if args.focal is not None:
        cam = camera_from_dict({**cam.to_dict(), "fx": args.focal, "fy": args.focal}, "--focal")
    return cam, "--focal" if args.focal else "default max(W, H)"


def run_sequence(args) -> int:
    from .. import load_body_model
    from ..fitting.sequence import SequenceFitConfig, fit_sequence
    from ..priors import load_pose_prior
    from ..video import read_sequence, save_sequence_fit
    from .fit import save_leaving_nothing_on_error, silhouette_config

    for flag in ("keypoints", "mask", "image"):
        if getattr(args, flag, None):
            raise CLIError(f"--{flag} is for one image; with --sequence give the folders (--masks, --images)")
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")
    sil_config = silhouette_config(args)  # a bad flag is reported before any fitting
    seq = read_sequence(args.sequence, masks=args.masks, images=args.images, person=args.person)
    camera, camera_source = _camera(args, seq)
    model = load_body_model(args.model, gender=args.gender) if args.model else load_body_model()
    pose_prior = load_pose_prior(args.pose_prior, dtype=model.dtype)
    masks = None
    if seq.masks and not args.no_silhouette:  # read (and checked) before --check-only answers
        from ..silhouette.masks import read_mask

        masks = [read_mask(seq.masks[n], size=(camera.width, camera.height), allow_empty=True) if n in seq.masks else None
                 for n in seq.numbers]  # fmt: skip
    if args.check_only:
        print(f"inputs OK: {len(seq.numbers)} frames ({seq.detected} with a person), {len(seq.masks)} masks, "
              f"{len(seq.images)} images")  # fmt: skip
        for warning in seq.warnings:
            print(f"warning: {warning}")
        return 0
    cfg = SequenceFitConfig()
    if args.sequence_iterations is not None:
        cfg.iterations = int(args.sequence_iterations)
    result = fit_sequence(seq.frames, camera, model, config=cfg, pose_prior=pose_prior, progress=not args.quiet)
    if masks is not None:
        from ..fitting.sequence import refine_sequence_silhouettes

        result = refine_sequence_silhouettes(model, result, seq.frames, masks, config=sil_config, pose_prior=pose_prior,
                                             progress=not args.quiet)  # fmt: skip
    extra = {"sequence": str(args.sequence), "model": model.source, "camera_source": camera_source,
             "silhouette": "run" if masks is not None else "not run (no masks)" if not seq.masks else "not run (--no-silhouette)",
             "warnings": [*seq.warnings, *result.warnings]}  # fmt: skip
    save_leaving_nothing_on_error(out, lambda: save_sequence_fit(
        result, out, model, seq, meshes=args.meshes, video=not args.no_video, fps=args.fps, extra_metrics=extra,
        overwrite=args.overwrite))  # fmt: skip
    if not args.quiet:
        t = result.timings
        line = f"wrote {out}: {result.num_frames} frames, {int(result.bridged.sum())} bridged, {t['seconds_per_frame']:.2f} s per frame"
        if result.silhouette_iou is not None:
            line += f", silhouette IoU {result.silhouette_iou_start:.3f} -> {float(np.nanmean(result.silhouette_iou)):.3f}"
        print(line)
        for warning in extra["warnings"]:
            print(f"warning: {warning}")
    return 0
