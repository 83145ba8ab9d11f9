"""``silfit fit --sequence DIR``: one person over a video's frames (per-frame OpenPose JSON).

Reads the frames (:func:`silfit.video.read_sequence`), fits them
(:func:`silfit.fitting.sequence.fit_sequence`: per-frame fits, consistent facings, a
joint refinement with one shape and temporal smoothness; frames without usable keypoints
bridged by their neighbours) and writes the folder of :func:`silfit.video.save_sequence_fit`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import CLIError, note, warn


def _camera(args, seq):
    from ..camera import Camera, camera_from_dict, load_camera
    from ..imagefile import image_file_size

    if args.camera or seq.camera:
        path = args.camera or seq.camera
        cam = load_camera(path)
        if args.focal is None:
            return cam, f"camera file {path}"
        cam = camera_from_dict({**cam.to_dict(), "fx": args.focal, "fy": args.focal}, "--focal")
        return cam, f"camera file {path} with --focal {args.focal:g}"
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
    return cam, f"--focal {args.focal:g}" if args.focal else "default focal max(W, H)"


def run_sequence(args) -> int:
    from ..fitting.sequence import SequenceFitConfig, fit_sequence
    from ..priors import load_pose_prior
    from ..video import read_sequence, save_sequence_fit
    from .common import choose_model, export_formats, save_leaving_nothing_on_error, silhouette_config

    for flag in ("keypoints", "mask", "image"):
        if getattr(args, flag, None):
            raise CLIError(f"--{flag} is for one image; with --sequence give the folders (--masks, --images)")
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")
    sil_config = silhouette_config(args)  # a bad flag is reported before any fitting
    seq = read_sequence(args.sequence, masks=args.masks, images=args.images, person=args.person)
    camera, camera_source = _camera(args, seq)
    # whole body: the frames' hand and face points decide the model (as for one image) and are fitted with it
    from ..wholebody import choose_fit_keypoints, read_wholebody_parts

    person = args.person if args.person == "largest" else int(args.person)
    parts = [read_wholebody_parts(p, person) if ks is not None else None for ks, p in zip(seq.frames, seq.files)]
    model, model_note = choose_model(args.model, args.gender, any(w is not None and w.has_parts for w in parts))
    if model_note:
        note(model_note)
    seq.frames = [None if ks is None else choose_fit_keypoints(ks, w, model)[0] for ks, w in zip(seq.frames, parts)]
    from ..plausibility import check_frames

    # the keypoints the fit will use get the checks of one image's (hands and face too)
    seq.frames, input_warnings = check_frames(seq.frames, camera.size, seq.numbers)
    pose_prior = load_pose_prior(args.pose_prior, dtype=model.dtype)
    masks = None
    if seq.masks and not args.no_silhouette:  # read (and checked) before --check-only answers
        from ..silhouette.masks import read_mask

        masks = [read_mask(seq.masks[n], size=(camera.width, camera.height), allow_empty=True) if n in seq.masks else None
                 for n in seq.numbers]  # fmt: skip
    if args.check_only:
        for warning in input_warnings:
            warn(warning)
        print(f"inputs OK: {len(seq.numbers)} frames ({seq.detected} with a person), {len(seq.masks)} masks, "
              f"{len(seq.images)} images; camera: {camera_source} (fx {camera.fx:g}, {camera.width}x{camera.height})")  # fmt: skip
        for warning in seq.warnings:
            warn(warning)
        return 0
    cfg = SequenceFitConfig()
    if args.sequence_iterations is not None:
        cfg.iterations = int(args.sequence_iterations)
    result = fit_sequence(seq.frames, camera, model, config=cfg, pose_prior=pose_prior, progress=not args.quiet)
    if masks is not None:
        from ..fitting.sequence import refine_sequence_silhouettes

        result = refine_sequence_silhouettes(model, result, seq.frames, masks, config=sil_config, pose_prior=pose_prior,
                                             progress=not args.quiet)  # fmt: skip
    result.warnings = list(seq.warnings) + input_warnings + list(result.warnings)
    extra = {"sequence": str(args.sequence), "model": model.source, "camera_source": camera_source,
             "silhouette": "run" if masks is not None else "not run (no masks)" if not seq.masks else "not run (--no-silhouette)",
             "warnings": list(result.warnings)}  # fmt: skip
    save_leaving_nothing_on_error(out, lambda: save_sequence_fit(
        result, out, model, seq, meshes=args.meshes, video=not args.no_video, fps=args.fps, extra_metrics=extra,
        overwrite=args.overwrite, exports=export_formats(args)))  # fmt: skip
    t = result.timings
    line = f"wrote {out}: {result.num_frames} frames, {int(result.bridged.sum())} bridged, {t['seconds_per_frame']:.2f} s per frame"
    if result.silhouette_iou is not None:
        line += f", silhouette IoU {result.silhouette_iou_start:.3f} -> {float(np.nanmean(result.silhouette_iou)):.3f}"
    print(line)
    for warning in result.warnings:
        warn(warning)
    return 0


def run_rig_sequence(args) -> int:
    """``silfit fit --rig DIR`` on a rig whose views are video folders (:func:`silfit.rig.load_rig_sequence`):
    :func:`silfit.rig_pipeline.fit_rig_sequence`, written by :func:`silfit.video.save_sequence_fit`."""
    from ..fitting.rig_fit import has_wholebody_parts
    from ..fitting.sequence import SequenceFitConfig
    from ..priors import load_pose_prior
    from ..rig import load_rig_sequence
    from ..rig_pipeline import check_rig_sequence, fit_rig_sequence, read_rig_sequence_masks
    from ..video import save_sequence_fit
    from .common import choose_model, save_leaving_nothing_on_error, silhouette_config

    for flag in ("masks", "images", "export"):
        if getattr(args, flag, None):
            raise CLIError(f"--{flag} with a rig video: each view's folder holds its frames' files (no exports: a rig's "
                           "world frame has no fixed up axis)")  # fmt: skip
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")
    sil_config = silhouette_config(args)
    person = args.person if args.person == "largest" else int(args.person)
    seq = load_rig_sequence(args.rig, person, args.views.split(",") if args.views else None)
    files = [p for c in range(len(seq.views)) for p in seq.files(c) if p is not None]
    parts = has_wholebody_parts(files, person)
    model, model_note = choose_model(args.model, args.gender, parts)
    if parts and getattr(model, "kind", "smpl") != "smplx":
        model_note = f"{model.source} is an SMPL-layout model: hand and face keypoints are not fitted"
    if model_note:
        note(model_note)
    seq, input_warnings = check_rig_sequence(seq, model, person)
    pose_prior = load_pose_prior(args.pose_prior, dtype=model.dtype)
    masks = None if args.no_silhouette else read_rig_sequence_masks(seq)
    if args.check_only:
        for warning in list(seq.warnings) + input_warnings:
            warn(warning)
        print(f"inputs OK: a rig video of {len(seq.numbers)} frames seen by {len(seq.views)} views "
              f"({', '.join(seq.names)}), masks {'read' if masks is not None else 'none'}")  # fmt: skip
        return 0
    cfg = SequenceFitConfig()
    if args.sequence_iterations is not None:
        cfg.iterations = int(args.sequence_iterations)
    result = fit_rig_sequence(seq, model, masks, config=cfg, pose_prior=pose_prior, silhouette_config=sil_config,
                              progress=not args.quiet)  # fmt: skip
    result.warnings = input_warnings + list(result.warnings)
    extra = {"rig": str(args.rig), "model": model.source,
             "silhouette": "run" if masks is not None else "not run (--no-silhouette)" if args.no_silhouette else "not run (no masks)",
             "warnings": list(result.warnings)}  # fmt: skip
    save_leaving_nothing_on_error(out, lambda: save_sequence_fit(
        result, out, model, seq, meshes=args.meshes, video=not args.no_video, fps=args.fps, extra_metrics=extra,
        overwrite=args.overwrite))  # fmt: skip
    line = (f"wrote {out}: a rig video of {result.num_frames} frames x {len(seq.views)} views, {int(result.bridged.sum())} "
            f"bridged, {result.timings['seconds_per_frame']:.2f} s per frame")  # fmt: skip
    if result.silhouette_iou is not None:
        line += f", silhouette IoU {result.silhouette_iou_start:.3f} -> {float(np.nanmean(result.silhouette_iou)):.3f}"
    print(line)
    for warning in result.warnings:
        warn(warning)
    return 0
