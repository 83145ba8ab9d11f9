"""Fitted meshes for other tools (``--export glb,ply``): binary glTF and PLY in an upright world frame.

**World frame** (every exported mesh): the fit's OpenCV camera frame (x right, y down, z forward,
metres) turned upright by 180 degrees about x: **x right, y up, z toward the viewer**, the camera at
the origin looking down -z (glTF's own camera convention, so the glTF camera node needs no
rotation). A point ``(x, y, z)`` of ``mesh.obj`` is ``(x, -y, -z)`` here. Vertex normals are
area-weighted over the triangles; the vertex order is the body model's.

- ``mesh.glb``: the body (positions, normals, triangles) and a ``camera`` node with the fit's
  intrinsics (perspective ``yfov`` from ``fy`` and the image height, ``aspectRatio`` width / height;
  the full ``fx, fy, cx, cy, width, height`` in the camera's ``extras``).
- ``mesh.ply``: the same body as ASCII PLY with normals.
- ``animation.glb`` (a video): one mesh whose base shape is the first frame with one morph target
  per frame (the frame minus the base) and an animation that switches the targets' weights
  frame by frame (``STEP``) at the video's frame rate; the camera as above.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Iterable, List, Optional, Sequence, Tuple

import numpy as np

from ..io.meshes import write_ply

__all__ = [
    "EXPORT_FORMATS",
    "WORLD_FRAME",
    "parse_formats",
    "to_upright",
    "vertex_normals",
    "write_glb",
    "write_fit_exports",
    "write_sequence_exports",
]

EXPORT_FORMATS = ("glb", "ply")
WORLD_FRAME = (
    "silfit upright camera frame: x right, y up, z toward the viewer (OpenCV camera frame rotated "
    "180 deg about x), metres; camera at the origin looking down -z"
)
_UPRIGHT = np.array([1.0, -1.0, -1.0])


def parse_formats(text: Optional[str], option: str = "--export") -> Tuple[str, ...]:
    """``"glb,ply"`` -> ``("glb", "ply")``; ``ValueError`` naming ``option`` for anything else."""
    if not text:
        return ()
    formats = tuple(dict.fromkeys(t.strip().lower() for t in str(text).split(",")))
    bad = [f for f in formats if f not in EXPORT_FORMATS]
    if bad or not formats:
        raise ValueError(f"{option} {text!r}: expected a comma-separated list of {', '.join(EXPORT_FORMATS)}")
    return formats


def to_upright(points: np.ndarray) -> np.ndarray:
    """OpenCV camera coordinates ``[..., 3]`` -> the upright world frame (x, -y, -z)."""
    return np.asarray(points, dtype=np.float64) * _UPRIGHT


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``[..., V, 3]`` of ``vertices [..., V, 3]``."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    flat = v.reshape(-1, v.shape[-2], 3)
    tri = flat[:, f]  # [B, F, 3, 3]
    fn = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])  # length = 2 x area
    n = np.zeros_like(flat)
    offset = (np.arange(len(flat)) * flat.shape[1])[:, None]
    for k in range(3):
        np.add.at(n.reshape(-1, 3), (f[None, :, k] + offset).reshape(-1), fn.reshape(-1, 3))
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    return (n / np.where(norm > 0, norm, 1.0)).reshape(v.shape)


# ---------------------------------------------------------------------------------------------- glTF
class _Buffer:
    """glTF buffer views and accessors over one binary blob."""

    def __init__(self):
        self.blob = bytearray()
        self.views: List[dict] = []
        self.accessors: List[dict] = []

    def add(self, array: np.ndarray, kind: str, target: Optional[int] = None, bounds: bool = False) -> int:
        component = {np.dtype(np.float32): 5126, np.dtype(np.uint32): 5125}[array.dtype]
        while len(self.blob) % 4:
            self.blob.append(0)
        data = np.ascontiguousarray(array).tobytes()
        view = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.blob += data
        self.views.append(view)
        count = int(array.size) if kind == "SCALAR" else int(array.shape[0])
        acc = {"bufferView": len(self.views) - 1, "componentType": component, "count": count, "type": kind}
        if bounds:
            flat = array.reshape(array.shape[0], -1) if kind != "SCALAR" else array.reshape(-1, 1)
            acc["min"] = [float(x) for x in flat.min(0)]
            acc["max"] = [float(x) for x in flat.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _camera(camera) -> dict:
    cam = {
        "type": "perspective",
        "name": "camera",
        "perspective": {
            "yfov": float(2 * np.arctan(camera.height / (2.0 * camera.fy))),
            "aspectRatio": float(camera.width / camera.height),
            "znear": 0.01,
        },
        "extras": {
            "intrinsics": {k: float(getattr(camera, k)) for k in ("fx", "fy", "cx", "cy", "width", "height")},
            "note": "OpenCV pinhole intrinsics in pixels; glTF keeps yfov and aspectRatio only",
        },
    }
    return cam


def write_glb(
    path: os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    camera=None,
    fps: float = 30.0,
    frame_numbers: Optional[Sequence[int]] = None,
) -> Path:
    """A binary glTF of ``vertices`` in OpenCV camera coordinates, written in the upright world frame
    (see the module docstring): ``[V, 3]`` one body; ``[N, V, 3]`` an animated body (morph target per
    frame, ``STEP`` weights at ``fps``). ``camera`` (a :class:`silfit.camera.Camera`) adds a camera node."""
    frames = to_upright(vertices)
    animated = frames.ndim == 3
    frames = frames if animated else frames[None]
    normals = vertex_normals(frames, faces)
    buf = _Buffer()
    indices = buf.add(np.asarray(faces, dtype=np.uint32).reshape(-1), "SCALAR", target=34963)
    base, base_n = frames[0].astype(np.float32), normals[0].astype(np.float32)
    prim = {
        "attributes": {"POSITION": buf.add(base, "VEC3", 34962, bounds=True), "NORMAL": buf.add(base_n, "VEC3", 34962)},
        "indices": indices,
        "mode": 4,
    }
    mesh = {"name": "body", "primitives": [prim]}
    gltf: dict = {
        "asset": {"version": "2.0", "generator": "silfit", "extras": {"frame": WORLD_FRAME}},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "body", "mesh": 0}],
        "meshes": [mesh],
    }
    if animated:
        n = len(frames)
        prim["targets"] = [
            {
                "POSITION": buf.add((frames[k] - frames[0]).astype(np.float32), "VEC3", 34962, bounds=True),
                "NORMAL": buf.add((normals[k] - normals[0]).astype(np.float32), "VEC3", 34962),
            }
            for k in range(n)
        ]
        mesh["weights"] = [0.0] * n
        mesh["extras"] = {
            "targetNames": [f"frame_{int(f)}" for f in (frame_numbers if frame_numbers is not None else range(n))]
        }
        times = buf.add((np.arange(n) / float(fps)).astype(np.float32), "SCALAR", bounds=True)
        weights = buf.add(np.eye(n, dtype=np.float32).reshape(-1), "SCALAR")
        gltf["animations"] = [
            {
                "name": "fit",
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}],
                "samplers": [{"input": times, "output": weights, "interpolation": "STEP"}],
            }
        ]
    if camera is not None:
        gltf["cameras"] = [_camera(camera)]
        gltf["nodes"].append({"name": "camera", "camera": 0})
        gltf["scenes"][0]["nodes"].append(1)
    while len(buf.blob) % 4:
        buf.blob.append(0)
    gltf.update(buffers=[{"byteLength": len(buf.blob)}], bufferViews=buf.views, accessors=buf.accessors)
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(buf.blob)
    path = Path(path)
    with open(path, "wb") as fh:
        fh.write(struct.pack("<4sII", b"glTF", 2, total))
        fh.write(struct.pack("<I4s", len(text), b"JSON") + text)
        fh.write(struct.pack("<I4s", len(buf.blob), b"BIN\0") + bytes(buf.blob))
    return path


# ---------------------------------------------------------------------------------------------- fits
def write_fit_exports(
    folder: os.PathLike, vertices: np.ndarray, faces: np.ndarray, camera, formats: Iterable[str]
) -> List[Path]:
    """One fit's ``mesh.glb`` / ``mesh.ply`` (``formats``) in ``folder``, from camera-frame ``vertices [V, 3]``."""
    folder, written = Path(folder), []
    for fmt in formats:
        if fmt == "glb":
            written.append(write_glb(folder / "mesh.glb", vertices, faces, camera))
        elif fmt == "ply":
            up = to_upright(vertices)
            write_ply(folder / "mesh.ply", up, faces, normals=vertex_normals(up, faces), comment=WORLD_FRAME)
            written.append(folder / "mesh.ply")
        else:
            raise ValueError(f"unknown export format {fmt!r} (one of {', '.join(EXPORT_FORMATS)})")
    return written


def write_sequence_exports(
    folder: os.PathLike,
    frames: np.ndarray,
    faces: np.ndarray,
    camera,
    formats: Iterable[str],
    frame_numbers: Sequence[int],
    fps: float,
) -> List[Path]:
    """A video fit's exports from camera-frame ``frames [N, V, 3]``: ``animation.glb`` (all frames) and
    ``meshes/frame_<n>.ply`` per frame."""
    folder, written = Path(folder), []
    for fmt in formats:
        if fmt == "glb":
            written.append(
                write_glb(folder / "animation.glb", frames, faces, camera, fps=fps, frame_numbers=frame_numbers)
            )
        elif fmt == "ply":
            (folder / "meshes").mkdir(exist_ok=True)
            for number, v in zip(frame_numbers, frames):
                up = to_upright(v)
                path = folder / "meshes" / f"frame_{int(number):012d}.ply"
                write_ply(path, up, faces, normals=vertex_normals(up, faces), comment=WORLD_FRAME)
                written.append(path)
        else:
            raise ValueError(f"unknown export format {fmt!r} (one of {', '.join(EXPORT_FORMATS)})")
    return written
