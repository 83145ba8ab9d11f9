"""``silfit fit``: SMPL from one image's keypoints, refined against its silhouette.

Runs :func:`silfit.pipeline.fit` and writes the output folder described in
:mod:`silfit.pipeline` (``params.npz``, ``params.json``, ``mesh.obj``, ``overlay.png``,
``silhouette.png``, ``iou_curve.png``, ``metrics.json``, ``stages/keypoints/``) into
``--out``, atomically: a failed run leaves no half-written output.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from . import CLIError, note, warn
from .common import choose_model, export_formats, save_leaving_nothing_on_error, silhouette_config  # noqa: F401


def _int_list(text: str) -> tuple:
    """An argparse type: raises ``ArgumentTypeError``, which argparse reports as a usage error (exit 2)."""
    import argparse

    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not values or min(values) <= 0:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {text!r}")
    return values


def register(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit SMPL to an image's 2D keypoints and person mask")
    p.add_argument("--rig", metavar="DIR", help="a calibrated camera rig: cameras.json (or EasyMocap intri.yml + "
                   "extri.yml, or one sub-folder per view with camera.json incl. R, t) and per view keypoints.json, "
                   "optional mask.png, image.png; fits in world coordinates (see README: Camera rigs)")
    p.add_argument("--views", metavar="A,B", help="--rig: fit only these views (names as in the rig), e.g. cam0,cam2")
    p.add_argument("--keypoints", help="OpenPose BODY_25 / COCO-17 keypoint JSON, or OpenPose whole-body JSON (hands "
                   "and face: fitted with an SMPL-X-layout model) (default: detected in --image, with its mask unless "
                   "--mask is given)")
    p.add_argument("--person", default="largest", help="person index in the keypoint file, or 'largest'")
    p.add_argument("--mask", help="person silhouette PNG (enables the silhouette stage)")
    cam = p.add_mutually_exclusive_group()
    cam.add_argument("--camera", help="camera.json with fx, fy, cx, cy, width, height")
    cam.add_argument("--focal", type=float, help="focal length in pixels (default: max(width, height); with --sequence "
                     "it replaces the focal length of a camera.json found beside the frames)")
    p.add_argument("--image", help="the image (its size, EXIF focal length and the overlay; keypoints and mask "
                   "are detected in it when --keypoints is not given)")
    p.add_argument("--image-size", help="WxH when neither --camera, --image nor --mask gives the size")
    p.add_argument("--no-silhouette", action="store_true", help="stop after the keypoint stage")
    p.add_argument("--model", help="SMPL or SMPL-X model file or folder, or 'open-smplx' for the shipped open whole-body "
                   "model (default: the shipped open body model; for keypoints with hands or face the shipped open "
                   "whole-body model)")
    p.add_argument("--gender", default="neutral", help="model gender when --model is a folder")
    p.add_argument("--pose-prior", help="pose prior: SMPLify gmm_08.pkl, a mixture .npz, or 'limits' "
                   "(default: the shipped pose-library mixture)")
    p.add_argument("--silhouette-resolutions", type=_int_list, metavar="R1,R2",
                   help="silhouette window sizes per level, coarse to fine (default 128,256)")
    p.add_argument("--silhouette-iterations", type=_int_list, metavar="N1,N2",
                   help="silhouette rendered steps per level (default 40,25, after the contour level)")
    seq = p.add_argument_group("videos (silfit.fitting.sequence)")
    seq.add_argument("--sequence", metavar="DIR", help="fit a video: a folder of per-frame OpenPose JSON files "
                     "(<video>_<frame 12 digits>_keypoints.json, or DIR/keypoints/ or DIR/openpose/ with masks/, images/, "
                     "camera.json beside)")
    seq.add_argument("--masks", metavar="DIR", help="--sequence: per-frame masks, matched by frame number")
    seq.add_argument("--images", metavar="DIR", help="--sequence: per-frame images (overlays), matched by frame number")
    seq.add_argument("--meshes", action="store_true", help="--sequence: also write meshes/frame_<n>.obj")
    seq.add_argument("--fps", type=float, default=30.0, help="--sequence: frame rate of overlay.gif (default 30)")
    seq.add_argument("--no-video", action="store_true", help="--sequence: only strip.png, no overlay.gif")
    seq.add_argument("--sequence-iterations", type=int, help="--sequence: joint refinement steps (default 100)")
    p.add_argument("--export", metavar="glb,ply", help="also write mesh.glb / mesh.ply (with --sequence: animation.glb, one "
                   "animated glTF of every frame / meshes/frame_<n>.ply): the body upright (x right, y up, z toward the "
                   "viewer: the camera frame turned 180 deg about x), vertex normals, the camera in the glTF")
    p.add_argument("--hypotheses", type=int, default=1, metavar="K",
                   help="also write the K best distinct keypoint-stage solutions of the limbs' depth branches to "
                        "hypotheses/<k>/params.npz (1: the fit's own), their energies and differing segments in "
                        "metrics.json (default 1: none)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--check-only", action="store_true",
                   help="read and check every input (files, sizes, keypoint plausibility), fit and write nothing")
    p.set_defaults(func=run)


def _image_size(args):
    if args.image:
        from ..imagefile import read_rgb

        img = read_rgb(args.image, "image")
        return img, (img.shape[1], img.shape[0])
    if args.image_size:
        from ..input_limits import check_image_size

        try:
            w, h = (int(v) for v in args.image_size.lower().split("x"))
        except ValueError:
            raise CLIError(f"--image-size {args.image_size!r}: expected WxH, e.g. 640x480") from None
        check_image_size(w, h, "--image-size", field="image size")
        return None, (w, h)
    return None, None


def _person(text: str):
    if text == "largest":
        return text
    try:
        return int(text)
    except ValueError:
        raise CLIError(f"--person {text!r}: expected a person index (0, 1, ...) or 'largest'") from None


@dataclass
class FitInputs:
    """Everything ``silfit fit`` reads, validated (see :func:`load_inputs`)."""

    keypoints: object
    image: Optional[np.ndarray]
    size: Optional[tuple]
    camera: object
    mask: Optional[np.ndarray]
    model: object
    pose_prior: object
    silhouette_config: object
    focal: Optional[float] = None
    camera_source: str = "default max(W, H)"
    photo: Optional[dict] = None


def load_inputs(args) -> FitInputs:
    """Read and check every input file and option of ``silfit fit`` (nothing is fitted or
    written): keypoints, image, camera, mask, body model, pose prior, silhouette settings."""
    from ..camera import Camera, camera_from_dict
    from ..errors import InputError
    from ..keypoints import read_keypoints
    from ..wholebody import read_wholebody_parts
    from ..priors import load_pose_prior
    from ..silhouette.masks import read_mask

    if args.mask and args.no_silhouette:
        raise CLIError("--mask and --no-silhouette contradict each other")
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")
    person = _person(args.person)
    # From a photo (silfit.detect): EXIF focal length; keypoints and mask when not given.
    photo = None
    if args.image:
        from .detect import photo_inputs

        photo = photo_inputs(args.image, person, not args.keypoints, not (args.mask or args.no_silhouette))
    elif not args.keypoints:
        raise CLIError("no keypoints: give --keypoints KP.json, or --image PHOTO to detect them")
    keypoints = read_keypoints(args.keypoints, person=person) if args.keypoints else photo["keypoints"]
    image, size = (photo["image"], photo["size"]) if photo else _image_size(args)
    camera, extrinsics_note = None, ""
    if args.camera:  # R, t (optional) checked as for rigs; one image is fitted in its camera's frame
        from ..camera import read_camera_file

        camera, R, t = read_camera_file(args.camera)
        if R is not None and (np.abs(R - np.eye(3)).max() > 1e-9 or np.abs(t).max() > 1e-9):
            extrinsics_note = " (its R, t not applied: one image is fitted in the camera's frame; --rig fits in the world frame)"
    if camera is not None and size is not None and tuple(size) != (camera.width, camera.height):
        raise CLIError(f"{args.camera}: camera is {camera.width}x{camera.height} but the image is {size[0]}x{size[1]}")
    mask = None
    if args.mask:
        expected = (camera.width, camera.height) if camera is not None else size
        mask = read_mask(args.mask, size=expected)
        size = size or (mask.shape[1], mask.shape[0])
    elif photo and photo["mask"] is not None:
        mask = photo["mask"]
    focal, camera_source = args.focal, "camera file" + extrinsics_note if camera else ("--focal" if args.focal else "default max(W, H)")
    if extrinsics_note:
        warn(f"{args.camera}: camera R, t not applied: one image is fitted in the camera's frame")
    if camera is None and focal is None and photo and photo["focal"]:
        focal, camera_source = photo["focal"], photo["focal_source"]
    if camera is None and size is None:
        raise CLIError("no camera: give --camera C.json, or --image / --image-size / --mask for the default camera")
    if args.focal is not None:  # the same plausibility bounds as a camera file's focal length
        base = camera or Camera.from_image_size(*size)
        camera_from_dict({**base.to_dict(), "fx": args.focal, "fy": args.focal}, "--focal")

    from ..wholebody import choose_fit_keypoints

    wholebody = read_wholebody_parts(args.keypoints, person) if args.keypoints else None
    model, model_note = choose_model(args.model, args.gender, wholebody is not None and wholebody.has_parts)
    if model_note:
        note(model_note)
    keypoints, choice_note = choose_fit_keypoints(keypoints, wholebody, model)
    if choice_note:
        note(choice_note)
    pose_prior = load_pose_prior(args.pose_prior, dtype=model.dtype)
    if getattr(pose_prior, "dim", model.num_body_pose) < model.num_body_pose:
        raise InputError(args.pose_prior or "--pose-prior (default)", f"the pose prior is over {pose_prior.dim} values, the model's body_pose has "
                         f"{model.num_body_pose}", field="means")  # fmt: skip
    sil_config = silhouette_config(args)
    return FitInputs(keypoints, image, size, camera, mask, model, pose_prior, sil_config, focal, camera_source, photo)


def run(args) -> int:
    if getattr(args, "views", None) and not getattr(args, "rig", None):
        raise CLIError("--views picks cameras of a rig; give --rig DIR")
    if getattr(args, "export", None) and getattr(args, "rig", None):
        raise CLIError("--export with --rig: not available (a rig's world frame has no fixed up axis); mesh.obj holds the body")
    export_formats(args)
    if getattr(args, "hypotheses", 1) != 1 and (args.sequence or getattr(args, "rig", None)):
        raise CLIError("--hypotheses with --sequence/--rig: not available (one image's depth branches only)")
    if args.sequence and getattr(args, "rig", None):
        raise ValueError("--sequence with --rig: fitting a rig's video is not available; choose one")
    if args.sequence:
        from .sequence import run_sequence

        return run_sequence(args)
    from ..pipeline import fit, save_fit

    if getattr(args, "rig", None):
        from .fit_rig import run_rig

        return run_rig(args)
    inp = load_inputs(args)
    if args.check_only:
        from ..plausibility import check_keypoints

        _, warnings = check_keypoints(inp.keypoints, inp.camera.size if inp.camera else inp.size)
        for warning in (inp.photo["warnings"] if inp.photo else []) + warnings:
            warn(warning)
        print("inputs OK")
        return 0
    out, model, keypoints, image, mask = Path(args.out), inp.model, inp.keypoints, inp.image, inp.mask
    kp_config = None
    if getattr(args, "hypotheses", 1) != 1:
        from ..fitting.keypoint_stage import KeypointFitConfig

        if not 1 <= args.hypotheses <= 20:
            raise CLIError(f"--hypotheses must be 1..20, got {args.hypotheses}")
        kp_config = KeypointFitConfig(hypotheses=args.hypotheses)
    result = fit(keypoints, mask, inp.camera, image_size=inp.size, focal=inp.focal, model=model, keypoint_config=kp_config,
                 pose_prior=inp.pose_prior, silhouette_config=inp.silhouette_config, progress=not args.quiet)  # fmt: skip
    extra = {"keypoints": args.keypoints and os.fspath(args.keypoints), "mask": args.mask, "image": args.image,
             "model": model.source, "camera_source": inp.camera_source}  # fmt: skip
    photo = inp.photo
    if photo and (photo["metrics"] or photo["warnings"]):
        extra.update(photo["metrics"], warnings=photo["warnings"] + result.metrics.get("warnings", []))
        result.metrics["warnings"] = extra["warnings"]
    save_leaving_nothing_on_error(
        out, lambda: save_fit(result, out, model.faces.cpu().numpy(), keypoints, image, mask, extra, overwrite=args.overwrite,
                             exports=export_formats(args)))
    m = result.metrics
    line = f"wrote {out}: median reprojection error {m['reprojection_error_px']:.2f} px"
    if "iou" in m:
        line += f", IoU {m['iou_keypoint_stage']:.3f} -> {m['iou']:.3f}"
    print(line)
    for warning in m.get("warnings", []):
        warn(warning)
    return 0
