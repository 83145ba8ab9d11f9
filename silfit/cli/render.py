"""``silfit render``: offscreen images of a fitted body or a mesh (pyrender on OSMesa).

Input is a fit file (``params.npz`` / ``params.json`` of any mode, read with
:func:`silfit.io.fit.read_fit`; evaluated with the shipped open model of the kind the file
records, or ``--model`` for the model file the fit was made with) or a mesh file (OBJ/PLY/...; read with trimesh). Vertices are drawn in the
camera frame of the project's convention (OpenCV axes, see :mod:`silfit.camera`): a rig's
world-frame fit is moved into its first view's camera frame. A video's fit draws frame
``--frame N`` (default 0), or with ``--frame all`` every frame into animated GIFs.

Outputs (PNG, in ``--out``):

* ``view_<name>.png`` for ``--views front,side,back`` (default ``front``) or
  ``view_turnNNN.png`` for ``--turntable N``: automatically framed, ``--size`` pixels.
* ``camera.png`` (and ``mask.png`` with ``--mask``) under ``--camera camera.json``.
* ``overlay.png`` with ``--overlay IMAGE``: the body blended over the image, under
  ``--camera``, else the camera stored in the parameter file, else the image's default.
* ``mask.png`` with ``--mask`` and no camera: the front view's binary mask.
* with ``--frame all``: the same names as ``.gif``, one picture per frame.

Everything is rendered before anything is written, and each PNG is written to a
temporary file and renamed, so an error leaves no partial PNG behind.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from . import CLIError

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")


def register(subparsers) -> None:
    p = subparsers.add_parser("render", help="render a fitted body or a mesh to PNG images (views, overlay, mask)")
    p.add_argument(
        "input",
        help="a fit's params.npz / params.json (an image, rig, video or whole-body fit) or a mesh file (OBJ/PLY)",
    )
    p.add_argument(
        "--model",
        help="SMPL / SMPL-X model file or folder, or 'open-smplx' (default: the model kind the fit "
        "file records, shipped open model)",
    )
    p.add_argument(
        "--frame",
        default="0",
        help="a video fit's frame index (0-based), or 'all' for an animated GIF per picture (default 0)",
    )
    p.add_argument("--fps", type=float, default=10.0, help="--frame all: GIF frame rate (default 10)")
    p.add_argument("--camera", help="camera.json (fx, fy, cx, cy, width, height): also render under this camera")
    p.add_argument("--overlay", metavar="IMAGE", help="blend the body over this image (writes overlay.png)")
    p.add_argument("--alpha", type=float, default=0.6, help="overlay opacity of the body (default 0.6)")
    p.add_argument(
        "--directions",
        dest="views",
        help="comma-separated directions to look from: front, side (=right), back, left (default: front)",
    )
    p.add_argument("--turntable", type=int, metavar="N", help="N views evenly spaced around the body")
    p.add_argument("--write-mask", dest="mask", action="store_true", help="also write a binary mask (mask.png)")
    p.add_argument("--size", default="512", help="view image size: N or WxH (default 512)")
    p.add_argument("--out", default=".", help="output folder (default: current folder)")
    from .flags import deprecated_alias

    deprecated_alias(p, "--views", "--directions")  # --views: a rig's camera names (silfit fit --rig)
    deprecated_alias(p, "--mask", "--write-mask")  # --mask: a mask file to fit to (silfit fit)
    p.set_defaults(func=run)


# --------------------------------------------------------------------------- inputs
def parse_size(text: str) -> tuple[int, int]:
    try:
        parts = [int(v) for v in str(text).lower().split("x")]
    except ValueError:
        raise CLIError(f"--size {text!r}: expected N or WxH, e.g. 512 or 640x480") from None
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) <= 0 or max(parts) > 8192:
        raise CLIError(f"--size {text!r}: expected N or WxH with sides in 1..8192")
    return parts[0], parts[1]


def fit_model(fit, choice: Optional[str]):
    """The body model for a fit file: ``--model`` (a file or folder, or ``open-smplx``), else the
    shipped open model of the kind the file records (SMPL-X where its parameters say so)."""
    from silfit import load_body_model

    if choice == "open-smplx":
        return load_body_model(kind="smplx")
    if choice:
        return load_body_model(choice)
    kind = fit.model["kind"] if fit.model else ("smplx" if "left_hand_pose" in fit.params else "smpl")
    return load_body_model(kind=kind)


def _frames(text: str, count: int, path: Path) -> list:
    if text == "all":
        return list(range(count))
    try:
        index = int(text)
    except ValueError:
        raise CLIError(f"--frame {text!r}: expected a frame index (0, 1, ...) or 'all'") from None
    if not 0 <= index < count:
        raise CLIError(f"--frame {index}: {path} holds {count} frame(s) (0..{count - 1})")
    return [index]


def load_vertices(args) -> tuple[list, np.ndarray, Optional[object]]:
    """(vertices per frame to draw [[V,3], ...], faces [F,3], stored camera or None) from the input file."""
    path = Path(args.input)
    if not path.exists():
        raise FileNotFoundError(f"{path}: input not found")
    suffix = path.suffix.lower()
    if suffix in (".npz", ".json"):
        import torch

        from silfit.io.fit import read_fit

        if args.model:  # the file read once, checked against the model given
            model = fit_model(None, args.model)
            fit = read_fit(path, require=(), sizes={**model.parameter_sizes, "betas": None})
        else:  # checked against the model it records
            fit = read_fit(path, require=())
            model = fit_model(fit, None)
        frames = _frames(args.frame, fit.num_frames, path)
        R, t = fit.extrinsics[0] if fit.extrinsics else (np.eye(3), np.zeros(3))
        out = []
        for f in frames:
            params = {k: torch.as_tensor(v.reshape(1, -1), dtype=model.dtype) for k, v in fit.frame(f).items()}
            with torch.no_grad():
                v = model(**params).vertices[0].double().numpy()
            out.append((v @ np.asarray(R).T + np.asarray(t)).astype(np.float32))  # world -> the first view's camera
        return out, model.faces.numpy(), fit.camera
    if args.frame != "0":
        raise CLIError(f"--frame {args.frame}: a mesh file has one frame")
    if suffix in MESH_SUFFIXES:
        import trimesh

        try:
            mesh = trimesh.load(path, force="mesh", process=False)
        except Exception as err:  # noqa: BLE001 - trimesh raises many kinds
            raise ValueError(f"{path}: not a readable mesh ({err})") from None
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0 or len(mesh.faces) == 0:
            raise ValueError(f"{path}: empty mesh (no vertices or faces)")
        return [np.asarray(mesh.vertices, dtype=np.float32)], np.asarray(mesh.faces, dtype=np.int64), None
    raise ValueError(f"{path}: unsupported input; give params.npz/params.json or a mesh ({', '.join(MESH_SUFFIXES)})")


def read_image(path: str) -> np.ndarray:
    from silfit.io.images import read_rgb

    return read_rgb(path, "image")


def write_png(path: Path, image: np.ndarray) -> None:
    """The one PNG writer (:func:`silfit.io.subjects.write_png`: atomic, no partial file on error)."""
    from silfit.io.subjects import write_png as write

    write(path, image)


def render_outputs(args) -> dict[str, np.ndarray]:
    """All requested images, keyed by file name (nothing is written here)."""
    from silfit.camera import Camera, load_camera
    from silfit.render import offscreen

    size = parse_size(args.size)
    if args.turntable is not None and args.views:
        raise CLIError("give either --directions or --turntable, not both")
    if not 0.0 <= args.alpha <= 1.0:
        raise CLIError(f"--alpha {args.alpha}: expected a value in [0, 1]")
    offscreen.view_angles(args.views, args.turntable)  # validates view names / N before any work
    camera = load_camera(args.camera) if args.camera else None
    background = read_image(args.overlay) if args.overlay else None

    frames, faces, stored_camera = load_vertices(args)
    if background is not None:
        h, w = background.shape[:2]
        overlay_camera = camera or stored_camera or Camera.from_image_size(w, h)
        if (overlay_camera.width, overlay_camera.height) != (w, h):
            raise CLIError(
                f"--overlay image is {w}x{h} but the camera is {overlay_camera.width}x{overlay_camera.height}"
            )
    per_frame = [
        _pictures(args, v, faces, camera, background, size, background is not None and overlay_camera) for v in frames
    ]
    if len(per_frame) == 1:
        return per_frame[0]
    return {name.replace(".png", ".gif"): np.stack([pics[name] for pics in per_frame]) for name in per_frame[0]}


def _pictures(args, vertices, faces, camera, background, size, overlay_camera) -> dict[str, np.ndarray]:
    """One frame's pictures, keyed by file name."""
    from silfit.render import offscreen

    vertices, faces = offscreen.mesh_arrays(vertices, faces)
    if not np.any(vertices[:, 2] > 0):
        raise ValueError("the body lies behind the camera (all z <= 0): is the mesh in camera coordinates?")
    images: dict[str, np.ndarray] = {}
    for name, image in offscreen.render_views(vertices, faces, views=args.views, turntable=args.turntable, size=size):
        images[f"view_{name}.png"] = image
    if camera is not None:
        r = offscreen.render_mesh(vertices, faces, camera)
        images["camera.png"] = np.where(r.mask[..., None], r.color, 255).astype(np.uint8)
        if args.mask:
            images["mask.png"] = (r.mask * 255).astype(np.uint8)
    elif args.mask:
        cam, moved = offscreen.framing_camera(vertices, *size)
        images["mask.png"] = (offscreen.render_mask(moved, faces, cam) * 255).astype(np.uint8)
    if background is not None:
        images["overlay.png"] = offscreen.overlay(background, vertices, faces, overlay_camera, alpha=args.alpha)
    return images


def run(args) -> int:
    images = render_outputs(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, image in images.items():
        if name.endswith(".gif"):
            from silfit.io.video import write_overlay_video

            write_overlay_video(out / name, list(image), args.fps)
        else:
            write_png(out / name, image)
        print(out / name)
    return 0
