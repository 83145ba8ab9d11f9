"""``silfit render``: offscreen images of a fitted body or a mesh (pyrender on OSMesa).

Input is a fit's parameter file (``params.npz`` / ``params.json`` with the SMPL names
``betas, body_pose, global_orient, transl``; evaluated with the body model, ``--model``
to choose it) or a mesh file (OBJ/PLY/...; read with trimesh).  Either way the vertices
are taken to be in the camera frame of the project's convention (OpenCV axes, see
:mod:`silfit.camera`), as ``silfit fit`` writes them.

Outputs (PNG, in ``--out``):

* ``view_<name>.png`` for ``--views front,side,back`` (default ``front``) or
  ``view_turnNNN.png`` for ``--turntable N``: automatically framed, ``--size`` pixels.
* ``camera.png`` (and ``mask.png`` with ``--mask``) under ``--camera camera.json``.
* ``overlay.png`` with ``--overlay IMAGE``: the body blended over the image, under
  ``--camera``, else the camera stored in the parameter file, else the image's default.
* ``mask.png`` with ``--mask`` and no camera: the front view's binary mask.

Everything is rendered before anything is written, and each PNG is written to a
temporary file and renamed, so an error leaves no partial PNG behind.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Optional

import numpy as np

from . import CLIError

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")


def register(subparsers) -> None:
    p = subparsers.add_parser("render", help="render a fitted body or a mesh to PNG images (views, overlay, mask)")
    p.add_argument("input", help="params.npz / params.json (SMPL parameters) or a mesh file (OBJ/PLY)")
    p.add_argument("--model", help="SMPL model file or folder (default: the shipped open body model)")
    p.add_argument("--camera", help="camera.json (fx, fy, cx, cy, width, height): also render under this camera")
    p.add_argument("--overlay", metavar="IMAGE", help="blend the body over this image (writes overlay.png)")
    p.add_argument("--alpha", type=float, default=0.6, help="overlay opacity of the body (default 0.6)")
    p.add_argument("--views", help="comma-separated views: front, side (=right), back, left (default: front)")
    p.add_argument("--turntable", type=int, metavar="N", help="N views evenly spaced around the body")
    p.add_argument("--mask", action="store_true", help="also write a binary mask (mask.png)")
    p.add_argument("--size", default="512", help="view image size: N or WxH (default 512)")
    p.add_argument("--out", default=".", help="output folder (default: current folder)")
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


def read_params(path: Path, sizes: Optional[dict] = None) -> tuple[dict, Optional[object]]:
    """Model parameters (numpy ``[1, n]``; the ones present, the model zeroes the rest) and the
    camera stored with them, if any, read with :func:`silfit.fitio.read_fit`; ``sizes``:
    the model's parameter name -> width (default SMPL's)."""
    from silfit.fitio import read_fit

    fit = read_fit(path, require=(), sizes=sizes)
    return {k: v.astype(np.float32).reshape(1, -1) for k, v in fit.params.items()}, fit.camera


def load_vertices(args) -> tuple[np.ndarray, np.ndarray, Optional[object]]:
    """(vertices [V,3], faces [F,3], stored camera or None) from the input file."""
    path = Path(args.input)
    if not path.exists():
        raise FileNotFoundError(f"{path}: input not found")
    suffix = path.suffix.lower()
    if suffix in (".npz", ".json"):
        import torch

        from silfit import load_body_model

        model = load_body_model(args.model) if args.model else load_body_model()
        params, camera = read_params(path, {**model.parameter_sizes, "betas": None})
        with torch.no_grad():
            out = model(**{k: torch.as_tensor(v, dtype=model.dtype) for k, v in params.items()})
        return out.vertices[0].float().numpy(), model.faces.numpy(), camera
    if suffix in MESH_SUFFIXES:
        import trimesh

        try:
            mesh = trimesh.load(path, force="mesh", process=False)
        except Exception as err:  # noqa: BLE001 - trimesh raises many kinds
            raise ValueError(f"{path}: not a readable mesh ({err})") from None
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0 or len(mesh.faces) == 0:
            raise ValueError(f"{path}: empty mesh (no vertices or faces)")
        return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int64), None
    raise ValueError(f"{path}: unsupported input; give params.npz/params.json or a mesh ({', '.join(MESH_SUFFIXES)})")


def read_image(path: str) -> np.ndarray:
    from silfit.imagefile import read_rgb

    return read_rgb(path, "image")


# --------------------------------------------------------------------------- outputs
def write_png(path: Path, image: np.ndarray) -> None:
    """Write ``image`` to ``path`` through a temporary file in the same folder + rename."""
    from PIL import Image

    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".png.tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            Image.fromarray(image).save(fh, format="PNG")
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def render_outputs(args) -> dict[str, np.ndarray]:
    """All requested images, keyed by file name (nothing is written here)."""
    from silfit.camera import Camera, load_camera
    from renderers import offscreen

    size = parse_size(args.size)
    if args.turntable is not None and args.views:
        raise CLIError("give either --views or --turntable, not both")
    if not 0.0 <= args.alpha <= 1.0:
        raise CLIError(f"--alpha {args.alpha}: expected a value in [0, 1]")
    offscreen.view_angles(args.views, args.turntable)  # validates view names / N before any work
    camera = load_camera(args.camera) if args.camera else None
    background = read_image(args.overlay) if args.overlay else None

    vertices, faces, stored_camera = load_vertices(args)
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
        h, w = background.shape[:2]
        overlay_camera = camera or stored_camera or Camera.from_image_size(w, h)
        if (overlay_camera.width, overlay_camera.height) != (w, h):
            raise CLIError(
                f"--overlay image is {w}x{h} but the camera is {overlay_camera.width}x{overlay_camera.height}"
            )
        images["overlay.png"] = offscreen.overlay(background, vertices, faces, overlay_camera, alpha=args.alpha)
    return images


def run(args) -> int:
    images = render_outputs(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, image in images.items():
        write_png(out / name, image)
        print(out / name)
    return 0
