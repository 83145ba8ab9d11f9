"""Writing meshes: Wavefront OBJ and PLY (ASCII), vertex order preserved."""

from __future__ import annotations

import os
from typing import Optional

import numpy as np

__all__ = ["write_obj", "write_ply"]


def write_obj(path: os.PathLike, vertices: np.ndarray, faces: np.ndarray, comment: Optional[str] = None) -> None:
    """``vertices [V, 3]`` (metres) and 0-based ``faces [F, 3]`` as OBJ (1-based indices)."""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(f"# {comment or 'silfit: posed body in camera coordinates (OpenCV axes, metres)'}\n")
        # one formatting of all rows (the bytes np.savetxt writes row by row, at about a fifth of its time)
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3) + 1
        fh.write(("v %.6f %.6f %.6f\n" * len(v)) % tuple(v.ravel().tolist()))
        fh.write(("f %d %d %d\n" * len(f)) % tuple(f.ravel().tolist()))


def write_ply(
    path: os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    colors: Optional[np.ndarray] = None,
    normals: Optional[np.ndarray] = None,
    comment: Optional[str] = None,
) -> None:
    """ASCII PLY with optional per-vertex ``colors [V, 3]`` (uint8), ``normals [V, 3]`` and a header comment."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    columns, fmt = [v], ["%.6f %.6f %.6f"]
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("ply\nformat ascii 1.0\n")
        if comment:
            fh.write("".join(f"comment {line}\n" for line in comment.splitlines()))
        fh.write(f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n")
        if normals is not None:
            fh.write("property float nx\nproperty float ny\nproperty float nz\n")
            columns.append(np.asarray(normals, dtype=np.float64))
            fmt.append("%.6f %.6f %.6f")
        if colors is not None:
            fh.write("property uchar red\nproperty uchar green\nproperty uchar blue\n")
            columns.append(np.asarray(colors)[:, :3])
            fmt.append("%d %d %d")
        fh.write(f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
        np.savetxt(fh, np.hstack(columns), fmt=" ".join(fmt))
        np.savetxt(fh, np.hstack([np.full((len(f), 1), 3), f]), fmt="%d %d %d %d")
