"""``silfit fit``: SMPL from one image's keypoints, refined against its silhouette.

Runs :func:`silfit.pipeline.fit` and writes the output folder described in
:mod:`silfit.pipeline` (``params.npz``, ``params.json``, ``mesh.obj``, ``overlay.png``,
``silhouette.png``, ``iou_curve.png``, ``metrics.json``, ``stages/keypoints/``) into
``--out``, atomically: a failed run leaves no half-written output.
"""
from __future__ import annotations

import os
from pathlib import Path

from . import CLIError


def _int_list(text: str) -> tuple:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise CLIError(f"expected comma-separated integers, got {text!r}") from None
    if not values or min(values) <= 0:
        raise CLIError(f"expected positive integers, got {text!r}")
    return values


def register(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit SMPL to an image's 2D keypoints and person mask")
    p.add_argument("--keypoints", help="OpenPose BODY_25 / COCO-17 keypoint JSON (default: detected in --image, "
                   "with its mask unless --mask is given)")
    p.add_argument("--person", default="largest", help="person index in the keypoint file, or 'largest'")
    p.add_argument("--mask", help="person silhouette PNG (enables the silhouette stage)")
    cam = p.add_mutually_exclusive_group()
    cam.add_argument("--camera", help="camera.json with fx, fy, cx, cy, width, height")
    cam.add_argument("--focal", type=float, help="focal length in pixels (default: max(width, height))")
    p.add_argument("--image", help="the image (its size, EXIF focal length and the overlay; keypoints and mask "
                   "are detected in it when --keypoints is not given)")
    p.add_argument("--image-size", help="WxH when neither --camera, --image nor --mask gives the size")
    p.add_argument("--no-silhouette", action="store_true", help="stop after the keypoint stage")
    p.add_argument("--model", help="SMPL model file or folder (default: the shipped open body model)")
    p.add_argument("--gender", default="neutral", help="model gender when --model is a folder")
    p.add_argument("--pose-prior", help="pose prior: SMPLify gmm_08.pkl, a mixture .npz, or 'limits' "
                   "(default: the shipped pose-library mixture)")
    p.add_argument("--silhouette-resolutions", type=_int_list, metavar="R1,R2",
                   help="silhouette window sizes per level, coarse to fine (default 128,256)")
    p.add_argument("--silhouette-iterations", type=_int_list, metavar="N1,N2",
                   help="silhouette steps per level (default 60,50)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def _image_size(args):
    if args.image:
        import cv2

        if not os.path.exists(args.image):
            raise FileNotFoundError(f"{args.image}: image not found")
        img = cv2.imread(args.image, cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"{args.image}: not a readable image")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB), (img.shape[1], img.shape[0])
    if args.image_size:
        try:
            w, h = (int(v) for v in args.image_size.lower().split("x"))
        except ValueError:
            raise CLIError(f"--image-size {args.image_size!r}: expected WxH, e.g. 640x480") from None
        return None, (w, h)
    return None, None


def run(args) -> int:
    from dataclasses import replace

    from .. import load_body_model
    from ..camera import load_camera
    from ..fitting.silhouette_stage import SilhouetteFitConfig
    from ..keypoints import read_keypoints
    from ..pipeline import fit, save_fit
    from ..silhouette.masks import read_mask

    if args.mask and args.no_silhouette:
        raise CLIError("--mask and --no-silhouette contradict each other")
    out = Path(args.out)
    if out.exists() and not args.overwrite and (not out.is_dir() or any(out.iterdir())):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")
    person = args.person if args.person == "largest" else int(args.person)
    # From a photo (silfit.detect): EXIF focal length; keypoints and mask when not given.
    photo = None
    if args.image:
        from .detect import photo_inputs

        photo = photo_inputs(args.image, person, not args.keypoints, not (args.mask or args.no_silhouette))
    elif not args.keypoints:
        raise CLIError("no keypoints: give --keypoints KP.json, or --image PHOTO to detect them")
    keypoints = read_keypoints(args.keypoints, person=person) if args.keypoints else photo["keypoints"]
    image, size = (photo["image"], photo["size"]) if photo else _image_size(args)
    camera = load_camera(args.camera) if args.camera else None
    if camera is not None and size is not None and tuple(size) != (camera.width, camera.height):
        raise CLIError(f"{args.camera}: camera is {camera.width}x{camera.height} but the image is {size[0]}x{size[1]}")
    mask = None
    if args.mask:
        expected = (camera.width, camera.height) if camera is not None else size
        mask = read_mask(args.mask, size=expected)
        size = size or (mask.shape[1], mask.shape[0])
    elif photo and photo["mask"] is not None:
        mask = photo["mask"]
    focal, camera_source = args.focal, "camera file" if camera else ("--focal" if args.focal else "default max(W, H)")
    if camera is None and focal is None and photo and photo["focal"]:
        focal, camera_source = photo["focal"], photo["focal_source"]
    if camera is None and size is None:
        raise CLIError("no camera: give --camera C.json, or --image / --image-size / --mask for the default camera")

    model = load_body_model(args.model, gender=args.gender) if args.model else load_body_model()
    levels = {}
    if args.silhouette_resolutions:
        levels["resolutions"] = tuple(args.silhouette_resolutions)
    if args.silhouette_iterations:
        levels["iterations"] = tuple(args.silhouette_iterations)
    try:
        sil_config = replace(SilhouetteFitConfig(), **levels)
    except ValueError:
        raise CLIError("--silhouette-resolutions and --silhouette-iterations need the same number of levels") from None
    result = fit(keypoints, mask, camera, image_size=size, focal=focal, model=model,
                 pose_prior=args.pose_prior, silhouette_config=sil_config, progress=not args.quiet)  # fmt: skip
    extra = {"keypoints": args.keypoints and os.fspath(args.keypoints), "mask": args.mask, "image": args.image,
             "model": model.source, "camera_source": camera_source}  # fmt: skip
    if photo and photo["metrics"]:
        extra.update(photo["metrics"], warnings=photo["warnings"] + result.metrics.get("warnings", []))
        result.metrics["warnings"] = extra["warnings"]
    save_fit(result, out, model.faces.cpu().numpy(), keypoints, image, mask, extra, overwrite=args.overwrite)
    if not args.quiet:
        m = result.metrics
        line = f"wrote {out}: median reprojection error {m['reprojection_error_px']:.2f} px"
        if "iou" in m:
            line += f", IoU {m['iou_keypoint_stage']:.3f} -> {m['iou']:.3f}"
        print(line)
        for warning in m.get("warnings", []):
            print(f"warning: {warning}")
    return 0
