"""``silfit fit``'s input builders: the command line's files and flags -> one
:class:`silfit.inputs.Job` (one image or photo, a rig, a video, a rig video). Each reads and checks its files
(one reader per format: :mod:`silfit.io.keypoints`, :mod:`silfit.silhouette.masks`,
:mod:`silfit.camera`, :mod:`silfit.io.rig`, :mod:`silfit.io.video`, :mod:`silfit.io.images`), says the
command line's notes and ends by calling the builder every caller uses (:mod:`silfit.inputs`); it fits
nothing: :func:`silfit.run.run` does the rest for all of them.
"""

from __future__ import annotations

import os

import numpy as np

from .. import inputs as builders
from ..fitting.problem import Observation, Problem
from ..inputs import Job
from . import CLIError, note, warn
from .common import check_out, choose_model, keypoint_settings, silhouette_config

__all__ = ["build_job", "image_job", "rig_job", "video_job", "describe_inputs"]


def _person(text: str):
    if text == "largest":
        return text
    try:
        return int(text)
    except ValueError:
        raise CLIError(f"--person {text!r}: expected a person index (0, 1, ...) or 'largest'") from None


def _check_out(args) -> None:
    check_out(args.out, args.overwrite)


def _parse_size(text: str) -> tuple:
    from ..io.limits import check_image_size

    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise CLIError(f"--image-size {text!r}: expected WxH, e.g. 640x480") from None
    check_image_size(w, h, "--image-size", field="image size")
    return w, h


def _pose_prior(args, model):
    from ..errors import InputError
    from ..priors import load_pose_prior

    pose_prior = load_pose_prior(args.pose_prior, dtype=model.dtype)
    if getattr(pose_prior, "dim", model.num_body_pose) < model.num_body_pose:
        raise InputError(
            args.pose_prior or "--pose-prior (default)",
            f"the pose prior is over {pose_prior.dim} values, the model's body_pose has {model.num_body_pose}",
            field="means",
        )
    return pose_prior


def _with_focal(camera, focal: float, what: str = "--focal"):
    """``camera`` with focal length ``focal`` (checked as a camera file's focal length is)."""
    from ..camera import camera_from_dict

    return camera_from_dict({**camera.to_dict(), "fx": focal, "fy": focal}, what)


def build_job(args) -> Job:
    """The job ``silfit fit``'s arguments describe (a video, a rig or one image)."""
    if getattr(args, "views", None) and not getattr(args, "rig", None):
        raise CLIError("--views picks cameras of a rig; give --rig DIR")
    if args.sequence and getattr(args, "rig", None):
        raise CLIError(
            "--sequence with --rig: a rig video is --rig DIR alone (its views' folders hold the per-frame files)"
        )
    if getattr(args, "hypotheses", 1) != 1 and (args.sequence or getattr(args, "rig", None)):
        raise CLIError("--hypotheses with --sequence/--rig: not available (one image's depth branches only)")
    if getattr(args, "export", None) and getattr(args, "rig", None):
        raise CLIError(
            "--export with --rig: not available (a rig's world frame has no fixed up axis); mesh.obj holds the body"
        )
    if args.sequence:
        return video_job(args)
    if getattr(args, "rig", None):
        from ..io.video import is_rig_video

        return rig_video_job(args) if is_rig_video(args.rig) else rig_job(args)
    return image_job(args)


def _photo_inputs(args, person):
    """``--image``'s inputs (:func:`silfit.cli.detect.photo_inputs`: keypoints and mask detected where not given),
    or ``None`` without ``--image`` (then ``--keypoints`` is required)."""
    if args.image:
        from .detect import photo_inputs

        return photo_inputs(
            args.image,
            person,
            not args.keypoints,
            not (args.mask or args.no_silhouette),
            getattr(args, "detected", None),
        )
    if not args.keypoints:
        raise CLIError("no keypoints: give --keypoints KP.json, or --image PHOTO to detect them")
    return None


def _camera_file(path, size) -> tuple:
    """``(camera, camera_source)`` from ``--camera``; its R, t (optional) checked as for rigs, not applied: one
    image is fitted in its camera's frame. The camera's size must be the image's ``size`` (when known)."""
    from ..camera import read_camera_file

    camera, R, t = read_camera_file(path)
    camera_source = "camera file"
    if R is not None and (np.abs(R - np.eye(3)).max() > 1e-9 or np.abs(t).max() > 1e-9):
        camera_source += (
            " (its R, t not applied: one image is fitted in the camera's frame; --rig fits in the world frame)"
        )
        warn(f"{path}: camera R, t not applied: one image is fitted in the camera's frame")
    if size is not None and tuple(size) != (camera.width, camera.height):
        raise CLIError(f"{path}: camera is {camera.width}x{camera.height} but the image is {size[0]}x{size[1]}")
    return camera, camera_source


def _image_mask(args, photo, camera, size) -> tuple:
    """``(mask, known, size)``: ``--mask`` (the size from it when not known yet), else the photo's detected mask
    and its known pixels, else none."""
    from ..silhouette.masks import read_mask

    mask, known = None, None
    if args.mask:
        mask = read_mask(args.mask, size=(camera.width, camera.height) if camera is not None else size)
        size = size or (mask.shape[1], mask.shape[0])
    elif photo and photo["mask"] is not None:
        mask, known = photo["mask"], photo.get("known")
    return mask, known, size


def _default_camera(args, photo, size) -> tuple:
    """``(camera, camera_source)`` without ``--camera``: the default camera of the image size, its focal length
    from ``--focal`` or else the photo's (EXIF)."""
    from ..camera import Camera

    if size is None:
        raise CLIError("no camera: give --camera C.json, or --image / --image-size / --mask for the default camera")
    camera = Camera.from_image_size(*size)
    camera_source = "default max(W, H)"
    if args.focal is not None:
        camera, camera_source = _with_focal(camera, args.focal), "--focal"
    elif photo and photo["focal"]:
        camera, camera_source = _with_focal(camera, photo["focal"], photo["focal_source"]), photo["focal_source"]
    return camera, camera_source


def _model_and_keypoints(args, person, keypoints) -> tuple:
    """``(model, keypoints)``: the body model (:func:`silfit.cli.common.choose_model`; whole-body keypoints pick
    the whole-body model) and the keypoints it fits (:func:`silfit.io.wholebody.choose_fit_keypoints`), each
    choice's note said."""
    from ..io.wholebody import choose_fit_keypoints, read_wholebody_parts

    wholebody = read_wholebody_parts(args.keypoints, person) if args.keypoints else None
    model, model_note = choose_model(args.model, args.gender, wholebody is not None and wholebody.has_parts)
    if model_note:
        note(model_note)
    keypoints, choice_note = choose_fit_keypoints(keypoints, wholebody, model)
    if choice_note:
        note(choice_note)
    return model, keypoints


def _hypotheses_base(args):
    """The keypoint stage's base settings for ``--hypotheses K`` (the K best distinct depth-branch solutions,
    hypotheses/<k>/), or ``None`` (the default) for K = 1."""
    base = None
    if getattr(args, "hypotheses", 1) != 1:
        from ..fitting.keypoint_stage import KeypointFitConfig, Solutions

        if not 1 <= args.hypotheses <= 20:
            raise CLIError(f"--hypotheses must be 1..20, got {args.hypotheses}")
        base = KeypointFitConfig(solutions=Solutions(count=args.hypotheses))
    return base


def image_job(args) -> Job:
    """One image (or photo: keypoints, mask and EXIF focal length detected when not given)."""
    from ..io.keypoints import read_keypoints

    if args.mask and args.no_silhouette:
        raise CLIError("--mask and --no-silhouette contradict each other")
    _check_out(args)
    person = _person(args.person)
    photo = _photo_inputs(args, person)
    keypoints = read_keypoints(args.keypoints, person=person) if args.keypoints else photo["keypoints"]
    image, size = (
        (photo["image"], photo["size"]) if photo else (None, _parse_size(args.image_size) if args.image_size else None)
    )
    warnings = list(photo["warnings"]) if photo else []
    camera, camera_source = _camera_file(args.camera, size) if args.camera else (None, None)
    mask, known, size = _image_mask(args, photo, camera, size)
    if camera is None:
        camera, camera_source = _default_camera(args, photo, size)
    model, keypoints = _model_and_keypoints(args, person, keypoints)
    record = {
        "keypoints": args.keypoints and os.fspath(args.keypoints),
        "mask": args.mask,
        "image": args.image,
        "model": model.source,
        "camera_source": camera_source,
        **(photo["metrics"] if photo else {}),
    }
    base = _hypotheses_base(args)
    return builders.image_job(
        keypoints,
        mask,
        camera,
        model=model,
        pose_prior=_pose_prior(args, model),
        keypoint_config=keypoint_settings(args, base),
        silhouette_config=silhouette_config(args),
        silhouette=not args.no_silhouette,
        progress=not args.quiet,
        known=known,
        warnings=warnings,
        record=record,
        image=image,
        mask_source=args.mask or "mask",
        detected_person=photo.get("person") if photo else None,
    )


def rig_job(args) -> Job:
    """One body seen by a calibrated rig (:func:`silfit.io.rig.load_rig`: a ``cameras.json``
    manifest, EasyMocap's ``intri.yml`` + ``extri.yml``, or one sub-folder per view with its
    ``camera.json``; each view holds ``keypoints.json`` and optionally ``mask.png`` and
    ``image.png``), fitted in world coordinates; ``--views`` picks cameras."""
    from ..errors import InputError
    from ..inputs.rig import fit_keypoints_of
    from ..io.images import read_rgb
    from ..io.rig import load_rig, select_views
    from ..silhouette.masks import read_mask

    for flag in ("keypoints", "mask", "camera", "focal", "image", "image_size"):
        if getattr(args, flag, None):
            raise CLIError(
                f"--rig reads every view's files from the rig folder; --{flag.replace('_', '-')} is not used with it"
            )
    _check_out(args)
    person = _person(args.person)
    views = select_views(load_rig(args.rig), args.views.split(",") if args.views else None)
    # whole body: the views' hand and face points decide the model (as for one image) and are fitted with it
    model = _rig_model(args, [v.keypoints for v in views], person)
    obs, names, images, warnings, first = [], [], {}, [], None
    for v in views:
        try:
            ks = fit_keypoints_of(v.keypoints, model, person)
        except InputError as err:  # a view without usable keypoints is set aside (as check() does with refused ones)
            first = first or err
            warnings.append(f"view {v.name} set aside: {err}")
            continue
        cam = v.view.camera
        mask = (
            read_mask(v.mask, size=(cam.width, cam.height)) if v.mask is not None else None
        )  # IoU even without the stage
        if v.image is not None:
            img = read_rgb(v.image, "image")
            if (img.shape[1], img.shape[0]) != (cam.width, cam.height):
                raise CLIError(
                    f"{v.image}: image is {img.shape[1]}x{img.shape[0]} but view {v.name}'s camera is "
                    f"{cam.width}x{cam.height}"
                )
            images[(0, len(obs))] = img
        warnings += list(v.warnings)
        obs.append(Observation(v.view, ks, mask, 0, len(obs)))
        names.append(v.name)
    if not obs:
        raise first
    return builders.rig_job(
        Problem(obs),
        names,
        model,
        pose_prior=_pose_prior(args, model),
        keypoint_config=keypoint_settings(args),
        silhouette_config=silhouette_config(args),
        silhouette=not args.no_silhouette,
        progress=not args.quiet,
        warnings=warnings,
        record={"rig": str(args.rig), "model": model.source},
        images=images,
    )


def _rig_model(args, keypoint_files, person):
    """The model of a rig (or rig video): ``--model``, else the shipped whole-body model when any view's
    keypoint file has hand or face points (with a note), else the body model."""
    from ..inputs.rig import has_wholebody_parts

    parts = has_wholebody_parts([f for f in keypoint_files if f is not None], person)
    model, model_note = choose_model(args.model, args.gender, parts)
    if parts and getattr(model, "kind", "smpl") != "smplx":
        model_note = f"{model.source} is an SMPL-layout model: hand and face keypoints are not fitted"
    if model_note:
        note(model_note)
    return model


def rig_video_job(args) -> Job:
    """A rig video: a rig folder whose views' folders are video folders (:func:`silfit.io.video.load_rig_sequence`:
    the rig's cameras, each view's per-frame OpenPose JSON with optional ``masks/`` and ``images/``,
    frames matched across views by number), fitted over frames x views in the world frame."""
    from ..fitting.sequence import SequenceFitConfig
    from ..io.video import load_rig_sequence
    from ..inputs.rig import read_rig_sequence_masks
    from ..io.wholebody import choose_fit_keypoints, read_wholebody_parts

    for flag in ("keypoints", "mask", "camera", "focal", "image", "image_size", "masks", "images"):
        if getattr(args, flag, None):
            raise CLIError(f"--{flag.replace('_', '-')} with a rig video: each view's folder holds its frames' files")
    _check_out(args)
    sil_config = silhouette_config(args)
    person = _person(args.person)
    seq = load_rig_sequence(args.rig, person, args.views.split(",") if args.views else None)
    C = len(seq.views)
    files = [seq.files(c) for c in range(C)]
    model = _rig_model(args, [p for column in files for p in column], person)
    frames = [
        [
            ks
            if ks is None or getattr(model, "kind", "smpl") != "smplx"
            else choose_fit_keypoints(ks, read_wholebody_parts(files[c][f], person), model)[0]
            for c, ks in enumerate(row)
        ]
        for f, row in enumerate(seq.frames)
    ]
    masks = read_rig_sequence_masks(seq)  # [F][C] or None; read (and checked) before --check-only answers
    cfg = SequenceFitConfig()
    cfg.keypoint = keypoint_settings(args, cfg.keypoint)  # each frame's start
    if args.sequence_iterations is not None:
        cfg.iterations = int(args.sequence_iterations)
    silhouette = (
        "run"
        if masks is not None and not args.no_silhouette
        else "not run (--no-silhouette)"
        if args.no_silhouette
        else "not run (no masks)"
    )
    return builders.rig_video_job(
        frames,
        [v.view for v in seq.views],
        seq.names,
        model,
        masks=masks,
        config=cfg,
        silhouette_config=sil_config,
        pose_prior=_pose_prior(args, model),
        silhouette=not args.no_silhouette,
        progress=not args.quiet,
        numbers=seq.numbers,
        inputs=seq,
        warnings=seq.warnings,
        record={"rig": str(args.rig), "model": model.source, "silhouette": silhouette},
    )


def _video_camera(args, seq):
    from ..camera import Camera, load_camera
    from ..io.images import image_file_size

    if args.camera or seq.camera:
        path = args.camera or seq.camera
        cam = load_camera(path)
        if args.focal is None:
            return cam, f"camera file {path}"
        return _with_focal(cam, args.focal), f"camera file {path} with --focal {args.focal:g}"
    size = None
    if args.image_size:
        size = _parse_size(args.image_size)
    else:
        for files, what in ((seq.images, "image"), (seq.masks, "mask")):
            if files:
                size = image_file_size(next(iter(files.values())), what)
                break
    if size is None:
        raise CLIError("no camera: give --camera C.json, or --images / --masks / --image-size for the default camera")
    cam = Camera.from_image_size(*size)
    if args.focal is not None:
        cam = _with_focal(cam, args.focal)
    return cam, f"--focal {args.focal:g}" if args.focal else "default focal max(W, H)"


def video_job(args) -> Job:
    """One person over a video's frames (:func:`silfit.io.video.read_sequence`: per-frame
    OpenPose JSON, masks and images matched by frame number, a ``camera.json`` beside)."""
    from ..fitting.sequence import SequenceFitConfig
    from ..silhouette.masks import read_mask
    from ..io.video import read_sequence
    from ..io.wholebody import choose_fit_keypoints, read_wholebody_parts

    for flag in ("keypoints", "mask", "image"):
        if getattr(args, flag, None):
            raise CLIError(f"--{flag} is for one image; with --sequence give the folders (--masks, --images)")
    _check_out(args)
    sil_config = silhouette_config(args)  # a bad flag is reported before any reading
    seq = read_sequence(args.sequence, masks=args.masks, images=args.images, person=args.person)
    camera, camera_source = _video_camera(args, seq)
    # whole body: the frames' hand and face points decide the model (as for one image) and are fitted with it
    person = _person(args.person)
    parts = [read_wholebody_parts(p, person) if ks is not None else None for ks, p in zip(seq.frames, seq.files)]
    model, model_note = choose_model(args.model, args.gender, any(w is not None and w.has_parts for w in parts))
    if model_note:
        note(model_note)
    frames = [None if ks is None else choose_fit_keypoints(ks, w, model)[0] for ks, w in zip(seq.frames, parts)]
    masks = [None] * len(frames)
    if seq.masks and not args.no_silhouette:  # read (and checked) before --check-only answers
        masks = [
            read_mask(seq.masks[n], size=(camera.width, camera.height), allow_empty=True) if n in seq.masks else None
            for n in seq.numbers
        ]
    cfg = SequenceFitConfig()
    cfg.keypoint = keypoint_settings(args, cfg.keypoint)  # each frame's start
    if args.sequence_iterations is not None:
        cfg.iterations = int(args.sequence_iterations)
    silhouette = (
        "run"
        if any(m is not None for m in masks)
        else "not run (no masks)"
        if not seq.masks
        else "not run (--no-silhouette)"
    )
    return builders.video_job(
        frames,
        camera,
        model,
        masks=masks,
        config=cfg,
        silhouette_config=sil_config,
        pose_prior=_pose_prior(args, model),
        progress=not args.quiet,
        numbers=seq.numbers,
        inputs=seq,
        warnings=seq.warnings,
        record={
            "sequence": str(args.sequence),
            "model": model.source,
            "camera_source": camera_source,
            "silhouette": silhouette,
        },
        silhouette=not args.no_silhouette,
    )


def describe_inputs(job: Job) -> str:
    """``--check-only``'s line: what will be fitted, with which camera."""
    if job.mode == "video" and job.num_views > 1 or job.mode == "video" and job.rig:
        return (
            f"inputs OK: a rig video of {job.num_frames} frames seen by {job.num_views} views "
            f"({', '.join(job.view_names)}), masks {'read' if job.has_masks else 'none'}"
        )
    if job.mode == "video":
        seq, cam = job.inputs, job.problem.observations[0].view.camera
        return (
            f"inputs OK: {len(seq.numbers)} frames ({seq.detected} with a person), {len(seq.masks)} masks, "
            f"{len(seq.images)} images; camera: {job.record['camera_source']} (fx {cam.fx:g}, {cam.width}x{cam.height})"
        )
    if job.mode == "rig":
        return f"inputs OK ({job.num_views} views)"
    cam = job.problem.observations[0].view.camera
    return f"inputs OK; camera: {job.record.get('camera_source')} (fx {cam.fx:g}, {cam.width}x{cam.height})"
