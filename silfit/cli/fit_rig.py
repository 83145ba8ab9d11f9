"""``silfit fit --rig DIR``: one body seen by a calibrated rig, fitted in world coordinates.

``DIR`` is a rig folder as :func:`silfit.rig.load_rig` reads it (a ``cameras.json``
manifest, EasyMocap's ``intri.yml`` + ``extri.yml``, or one sub-folder per view with its
``camera.json``); each view holds ``keypoints.json`` and optionally ``mask.png`` and
``image.png``. Output: :func:`silfit.rig_pipeline.save_rig_fit`. A rig whose views hold
per-frame keypoints instead (video folders) is a rig video: :func:`silfit.cli.sequence.run_rig_sequence`.
"""
from __future__ import annotations

from pathlib import Path

from . import CLIError, note, warn


def run_rig(args) -> int:
    from ..fitting.rig_fit import has_wholebody_parts, rig_problem, usable_views
    from ..imagefile import read_rgb
    from ..priors import load_pose_prior
    from ..rig import load_rig
    from ..rig_pipeline import fit_rig, save_rig_fit
    from .common import choose_model, save_leaving_nothing_on_error, silhouette_config

    for flag in ("keypoints", "mask", "camera", "focal", "image", "image_size"):
        if getattr(args, flag, None):
            raise CLIError(f"--rig reads every view's files from the rig folder; --{flag.replace('_', '-')} is not used with it")
    from ..rig import is_rig_video

    if is_rig_video(args.rig):  # the views hold per-frame keypoints: a rig video
        from .sequence import run_rig_sequence

        return run_rig_sequence(args)
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")
    person = "largest" if args.person == "largest" else int(args.person)
    views, set_aside = usable_views(load_rig(args.rig), person, args.views.split(",") if args.views else None)
    # whole body: the views' hand and face points decide the model (as for one image) and are fitted with it
    parts = has_wholebody_parts([v.keypoints for v in views], person)
    model, model_note = choose_model(args.model, args.gender, parts)
    if parts and getattr(model, "kind", "smpl") != "smplx":
        model_note = f"{model.source} is an SMPL-layout model: hand and face keypoints are not fitted"
    if model_note:
        note(model_note)
    problem = rig_problem(views, person=person, model=model)
    images = {}
    for v in views:
        if v.image is not None:
            img = read_rgb(v.image, "image")
            cam = v.view.camera
            if (img.shape[1], img.shape[0]) != (cam.width, cam.height):
                raise CLIError(f"{v.image}: image is {img.shape[1]}x{img.shape[0]} but view {v.name}'s camera is "
                               f"{cam.width}x{cam.height}")  # fmt: skip
            images[v.name] = img
    pose_prior = load_pose_prior(args.pose_prior, dtype=model.dtype)
    warnings = set_aside + [w for v in views for w in v.warnings]
    if args.check_only:
        for w in warnings:
            warn(w)
        print(f"inputs OK ({len(views)} views)")
        return 0
    names = [v.name for v in views]
    result = fit_rig(problem, names, model, pose_prior, silhouette=not args.no_silhouette,
                     silhouette_config=silhouette_config(args), progress=not args.quiet)  # fmt: skip
    extra = {"rig": str(args.rig), "model": model.source, "warnings": warnings + result.metrics.get("warnings", [])}
    save_leaving_nothing_on_error(
        out, lambda: save_rig_fit(result, out, model.faces.cpu().numpy(), problem, images, extra, overwrite=args.overwrite,
                                  model=model))
    m = result.metrics
    line = f"wrote {out}: {len(views)} views, median reprojection error {m['reprojection_error_px']:.2f} px"
    if "iou_mean" in m:
        line += f", mean IoU {m['iou_mean']:.3f}"
    print(line)
    for w in extra["warnings"]:
        warn(w)
    return 0
