"""``silfit fit``: SMPL from one image's keypoints (and, later, its silhouette).

Writes ``params.npz``, ``params.json``, ``mesh.obj`` (posed body in the camera frame,
OpenCV axes, the model's vertex order), ``overlay.png`` and ``metrics.json`` into
``--out``. Everything is written to a temporary folder beside it and moved into place
at the end, so a failed run leaves no half-written output.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from . import CLIError


def register(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit SMPL to an image's 2D keypoints (and silhouette)")
    p.add_argument("--keypoints", required=True, help="OpenPose BODY_25 / COCO-17 keypoint JSON")
    p.add_argument("--person", default="largest", help="person index in the keypoint file, or 'largest'")
    cam = p.add_mutually_exclusive_group()
    cam.add_argument("--camera", help="camera.json with fx, fy, cx, cy, width, height")
    cam.add_argument("--focal", type=float, help="focal length in pixels (default: from the image size)")
    p.add_argument("--image", help="the image (for its size and the overlay)")
    p.add_argument("--image-size", help="WxH when neither --camera nor --image is given")
    p.add_argument("--mask", help="person silhouette (enables silhouette refinement)")
    p.add_argument("--no-silhouette", action="store_true", help="keypoint stage only")
    p.add_argument("--model", help="SMPL model file or folder (default: the shipped open body model)")
    p.add_argument("--pose-prior", help="SMPLify gmm_08.pkl (default: the shipped joint-limit prior)")
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
        return img, (img.shape[1], img.shape[0])
    if args.image_size:
        try:
            w, h = (int(v) for v in args.image_size.lower().split("x"))
        except ValueError:
            raise CLIError(f"--image-size {args.image_size!r}: expected WxH, e.g. 640x480") from None
        return None, (w, h)
    return None, None


def write_obj(path, vertices, faces) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# silfit fit: posed body in camera coordinates (OpenCV axes, metres)\n")
        np.savetxt(fh, vertices, fmt="v %.6f %.6f %.6f")
        np.savetxt(fh, np.asarray(faces) + 1, fmt="f %d %d %d")


def draw_overlay(image, vertices, faces, camera, keypoints_xy=None, fitted_xy=None, conf=None):
    """The projected mesh filled over the image (or a blank canvas), plus keypoints."""
    import cv2

    H, W = camera.height, camera.width
    canvas = np.full((H, W, 3), 255, np.uint8) if image is None else image.copy()
    if canvas.shape[:2] != (H, W):
        canvas = cv2.resize(canvas, (W, H))
    z = np.maximum(vertices[:, 2], 1e-6)
    uv = np.stack([camera.fx * vertices[:, 0] / z + camera.cx, camera.fy * vertices[:, 1] / z + camera.cy], 1)
    mask = np.zeros((H, W), np.uint8)
    tris = np.round(uv[np.asarray(faces)] * 16).astype(np.int32)  # 4 fractional bits
    front = vertices[np.asarray(faces)][:, :, 2].min(1) > 1e-3
    cv2.fillPoly(mask, list(tris[front]), 255, lineType=cv2.LINE_8, shift=4)
    colour = np.array([255, 160, 80], np.float32)  # BGR: light blue
    sel = mask > 0
    canvas[sel] = (0.45 * canvas[sel] + 0.55 * colour).astype(np.uint8)
    if keypoints_xy is not None:
        for k, (x, y) in enumerate(keypoints_xy):
            if conf is None or conf[k] > 0:
                cv2.circle(canvas, (int(round(x)), int(round(y))), 3, (0, 200, 0), -1)
    if fitted_xy is not None:
        for x, y in fitted_xy:
            if np.isfinite(x) and np.isfinite(y):
                cv2.circle(canvas, (int(round(x)), int(round(y))), 2, (0, 0, 220), -1)
    return canvas


def _silhouette_stage():
    try:
        from ..fitting import silhouette_stage  # noqa: F401
    except ImportError:
        return None
    return silhouette_stage


def run(args) -> int:
    from .. import load_body_model
    from ..camera import load_camera
    from ..fitting import KeypointFitter, prepare_keypoints
    from ..keypoints import read_keypoints

    if args.mask and args.no_silhouette:
        raise CLIError("--mask and --no-silhouette contradict each other")
    if args.mask:
        if not os.path.exists(args.mask):
            raise FileNotFoundError(f"{args.mask}: mask not found")
        if _silhouette_stage() is None:
            raise CLIError(
                "silhouette refinement is not available in this version of silfit; "
                "run with --no-silhouette (and without --mask) for the keypoint stage only"
            )
        raise CLIError("silhouette refinement is not wired into 'silfit fit' yet; use --no-silhouette")

    out = Path(args.out)
    if out.exists() and not args.overwrite and any(out.iterdir()):
        raise CLIError(f"{out}: output folder exists and is not empty (use --overwrite)")
    person = args.person if args.person == "largest" else int(args.person)
    ks = read_keypoints(args.keypoints, person=person)
    image, size = _image_size(args)
    camera = load_camera(args.camera) if args.camera else None
    if camera is None and size is None:
        raise CLIError("no camera: give --camera C.json, or --image / --image-size for the default camera")
    if camera is not None and size is not None and tuple(size) != (camera.width, camera.height):
        raise CLIError(f"{args.camera}: camera is {camera.width}x{camera.height} but the image is {size[0]}x{size[1]}")

    model = load_body_model(args.model) if args.model else load_body_model()
    sets = prepare_keypoints(ks)
    fitter = KeypointFitter(model, layout=ks.layout, pose_prior=args.pose_prior)
    result = fitter.fit(sets, camera, image_size=size, focal=args.focal, progress=not args.quiet)

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        result.save(tmp)
        faces = model.faces.cpu().numpy()
        write_obj(tmp / "mesh.obj", result.vertices[0], faces)
        import cv2

        overlay = draw_overlay(image, result.vertices[0], faces, result.camera, ks.xy, result.keypoints_2d[0], ks.conf)
        cv2.imwrite(str(tmp / "overlay.png"), overlay)
        metrics = {
            "keypoints": os.fspath(args.keypoints),
            "layout": ks.layout,
            "stages": ["keypoints"],
            "reprojection_error_median_px": float(result.reprojection_error[0]),
            "flipped_start_kept": bool(result.flipped[0]),
            "energies": {k: float(v[0]) for k, v in result.energies.items()},
            "timings_s": {k: float(v) for k, v in result.timings.items()},
            "camera": result.camera.to_dict(),
            "model": model.source,
            "pose_prior": getattr(fitter.pose_prior, "source", "custom"),
        }
        (tmp / "metrics.json").write_text(json.dumps(metrics, indent=2))
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if not args.quiet:
        print(f"wrote {out} (median reprojection error {result.reprojection_error[0]:.2f} px)")
    return 0
