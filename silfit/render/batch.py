"""Several subjects' silhouettes in one Mitsuba render: tiles of one film.

Each subject ``i`` has its own vertices ``[V, 3]`` (its camera frame) and its own window
camera ``w_i x h_i`` (e.g. :attr:`silfit.render.silhouette.RoiWindow.camera`).  The film is a
grid of cells of ``max w x max h`` pixels separated by ``gap`` pixels; subject ``i``'s
window maps to the sub-rectangle of cell ``i`` through a *tile camera* (its camera with the
principal point shifted by the cell's offset and the film's size), and its vertices go
through :func:`silfit.render.silhouette.to_canonical` for that tile camera, so one sensor
renders all tiles and ``f0 * x'/z' + cx0`` lands every subject exactly where its own camera
would put it, plus the offset.  All subjects share one mesh (the faces repeated with
offsets) in one scene, cached per (topology, number of subjects, film size, spp, edge spp).

Only the projection decides which tile a subject lands in, so subjects do not occlude
each other; a subject whose projection leaves its window by more than ``gap`` pixels would
spill into a neighbouring tile, and is rendered alone instead (same result, one more
call).  Gradients reach each subject's vertices through torch; a loss on one tile gives no
gradient to the others (their edges lie in their own tiles).

The renderer's noise differs from single renders (one seed for the whole film, the edge
samples spread over all subjects' edges), but the estimate is the same: a batch equals
single renders within the Monte Carlo noise.
"""

from __future__ import annotations

import math
import threading
from typing import List, Optional, Sequence

import numpy as np
import torch

from silfit.camera import Camera, project_points

from .silhouette import SilhouetteRenderer, fresh_seed, check_camera, check_mesh, faces_key, to_canonical

__all__ = ["BatchSilhouetteRenderer", "TileLayout", "tile_layout", "render_batch", "get_batch_renderer"]


class TileLayout:
    """Cells of ``cell_w x cell_h`` pixels in ``columns`` columns, ``gap`` pixels apart
    (also around the border): ``offsets[i] = (x, y)`` of subject ``i``'s cell in the film."""

    def __init__(self, n: int, cell_w: int, cell_h: int, gap: int):
        self.n, self.cell_w, self.cell_h, self.gap = n, cell_w, cell_h, gap
        # the most square grid without empty cells (n prime: one row)
        self.columns = next(c for c in range(int(math.ceil(math.sqrt(n))), n + 1) if n % c == 0)
        self.rows = int(math.ceil(n / self.columns))
        self.width = self.columns * (cell_w + gap) + gap
        self.height = self.rows * (cell_h + gap) + gap
        self.offsets = [
            (gap + (i % self.columns) * (cell_w + gap), gap + (i // self.columns) * (cell_h + gap)) for i in range(n)
        ]

    def tile_camera(self, i: int, camera: Camera) -> Camera:
        """The film-sized camera that images like ``camera`` shifted into cell ``i``."""
        ox, oy = self.offsets[i]
        return Camera(
            fx=camera.fx, fy=camera.fy, cx=camera.cx + ox, cy=camera.cy + oy, width=self.width, height=self.height
        )


def tile_layout(cameras: Sequence[Camera], gap: int = 4) -> TileLayout:
    """The layout for windows ``cameras`` (cells as large as the largest window)."""
    return TileLayout(len(cameras), max(c.width for c in cameras), max(c.height for c in cameras), int(gap))


class BatchSilhouetteRenderer:
    """Silhouettes of several subjects of one topology (module docstring).

    ``mode='tiled'`` renders all subjects in tiles of one film per Mitsuba call;
    ``'separate'`` renders each subject with its own cached scene (one call each, the
    same results and gradients); ``'auto'`` is the faster one measured (tiles).
    ``renderer(vertices, cameras)`` with ``vertices`` a list of ``[V, 3]`` tensors (or a
    ``[B, V, 3]`` tensor) and one camera per subject returns a list of ``[h_i, w_i]``
    silhouettes whose gradients reach each subject's vertices."""

    def __init__(
        self, faces, spp: int = 4, edge_spp: int = 1, gap: int = 4, variant: Optional[str] = None, mode: str = "auto"
    ):
        if mode not in ("auto", "tiled", "separate"):
            raise ValueError(f"mode must be 'auto', 'tiled' or 'separate', got {mode!r}")
        self.single = SilhouetteRenderer(faces, spp=spp, edge_spp=edge_spp, variant=variant)
        # 'auto': tiles (measured faster on the CPU from 8 subjects on, equal at 4: see
        # benchmarks/bench_render.py --only batch; not measured on a GPU yet)
        self.mode = "tiled" if mode == "auto" else mode
        self._slots: List[SilhouetteRenderer] = [self.single]
        self.faces, self.spp, self.edge_spp = self.single.faces, self.single.spp, self.single.edge_spp
        if int(gap) < 0:
            raise ValueError(f"gap must be >= 0 pixels, got {gap}")
        self.gap = int(gap)
        self.variant = self.single.variant
        self._tiled: dict = {}
        self._lock = threading.Lock()
        self.last_fallbacks = 0  # subjects rendered alone in the last call (spill)

    def _slot(self, i: int) -> SilhouetteRenderer:
        """Subject ``i``'s own renderer (own scenes), so that each subject's scene still
        holds its vertices at the backward pass (no BVH rebuild there)."""
        with self._lock:
            while len(self._slots) <= i:
                self._slots.append(
                    SilhouetteRenderer(self.faces, spp=self.spp, edge_spp=self.edge_spp, variant=self.variant)
                )
            return self._slots[i]

    def _tiled_renderer(self, n: int) -> SilhouetteRenderer:
        with self._lock:
            r = self._tiled.get(n)
            if r is None:
                nv = int(self.faces.max()) + 1
                faces = np.concatenate([self.faces + i * nv for i in range(n)])
                r = SilhouetteRenderer(faces, spp=self.spp, edge_spp=self.edge_spp, variant=self.variant)
                self._tiled[n] = r
            return r

    def __call__(
        self,
        vertices,
        cameras: Sequence[Camera],
        spp: Optional[int] = None,
        edge_spp: Optional[int] = None,
        seed: Optional[int] = None,
        sampler: Optional[str] = None,
        edge_density: Optional[float] = None,
    ) -> List[torch.Tensor]:
        verts = [
            check_mesh(v, self.faces)[0]
            for v in (list(vertices) if not isinstance(vertices, torch.Tensor) or vertices.dim() == 3 else [vertices])
        ]
        cameras = [check_camera(c) for c in cameras]
        if len(verts) != len(cameras):
            raise ValueError(f"got {len(verts)} vertex sets but {len(cameras)} cameras")
        if not verts:
            return []
        if len({v.shape[0] for v in verts}) != 1:
            raise ValueError("all subjects must have the same number of vertices")
        seed = fresh_seed() if seed is None else int(seed)
        kw = dict(spp=spp, edge_spp=edge_spp, sampler=sampler)
        if edge_density is not None:  # the ray-cast method's edge points per pixel of contour length
            kw["edge_density"] = edge_density
        if self.mode == "separate":
            self.last_fallbacks = 0
            return [self._slot(i)(v, c, seed=seed + i, **kw) for i, (v, c) in enumerate(zip(verts, cameras))]
        layout = tile_layout(cameras, self.gap)
        inside = [_stays_in_window(v, c, self.gap) for v, c in zip(verts, cameras)]
        tiled = [i for i, ok in enumerate(inside) if ok]
        out: List[Optional[torch.Tensor]] = [None] * len(verts)
        self.last_fallbacks = len(verts) - len(tiled)
        for i in (i for i, ok in enumerate(inside) if not ok):
            out[i] = self._slot(i)(verts[i], cameras[i], seed=seed + 1 + i, **kw)
        if len(tiled) == 1:
            i = tiled[0]
            out[i] = self.single(verts[i], cameras[i], seed=seed, **kw)
        elif tiled:
            sub = tile_layout([cameras[i] for i in tiled], self.gap) if len(tiled) < len(verts) else layout
            film_cam = sub.tile_camera(0, cameras[tiled[0]])
            mapped = [
                to_canonical(verts[i].to(torch.float32), sub.tile_camera(k, cameras[i])) for k, i in enumerate(tiled)
            ]
            # to_canonical of the film camera is the identity map for the film's canonical
            # sensor: render the mapped vertices with an identity-mapping camera.
            film = self._tiled_renderer(len(tiled))(
                torch.cat(mapped), _canonical_camera(film_cam.width, film_cam.height), seed=seed, **kw
            )
            for k, i in enumerate(tiled):
                ox, oy = sub.offsets[k]
                img = film[oy : oy + cameras[i].height, ox : ox + cameras[i].width]
                out[i] = img.to(dtype=verts[i].dtype if verts[i].is_floating_point() else torch.float32)
        return out


def _canonical_camera(width: int, height: int) -> Camera:
    """The camera whose :func:`to_canonical` map is the identity (focal W, centred)."""
    return Camera(
        fx=float(width), fy=float(width), cx=width / 2.0 - 0.5, cy=height / 2.0 - 0.5, width=width, height=height
    )


def _stays_in_window(vertices: torch.Tensor, camera: Camera, gap: int) -> bool:
    """Whether every vertex is in front of the camera and projects within ``gap`` pixels of
    the window (then the mesh's projection, their convex hull's, does too)."""
    with torch.no_grad():
        v = vertices.detach().to(torch.float64)
        if not bool((v[:, 2] > 1e-3).all()):
            return False
        uv = project_points(v, camera)
        lo, hi = uv.min(0).values, uv.max(0).values
        return bool(
            lo[0] >= -0.5 - gap
            and lo[1] >= -0.5 - gap
            and hi[0] <= camera.width - 0.5 + gap
            and hi[1] <= camera.height - 0.5 + gap
        )


_BATCH_RENDERERS: dict = {}


def get_batch_renderer(faces, mode: str = "auto") -> BatchSilhouetteRenderer:
    """A shared :class:`BatchSilhouetteRenderer` per faces topology."""
    f = faces.detach().cpu().numpy() if isinstance(faces, torch.Tensor) else np.asarray(faces)
    key = (faces_key(f), mode)
    r = _BATCH_RENDERERS.get(key)
    if r is None:
        r = _BATCH_RENDERERS[key] = BatchSilhouetteRenderer(f, mode=mode)
    return r


def render_batch(
    vertices,
    cameras: Sequence[Camera],
    faces,
    spp: int = 4,
    edge_spp: int = 1,
    seed: Optional[int] = None,
    mode: str = "auto",
) -> List[torch.Tensor]:
    """Functional form of :class:`BatchSilhouetteRenderer` (silfit.render cached per topology)."""
    return get_batch_renderer(faces, mode)(vertices, cameras, spp=spp, edge_spp=edge_spp, seed=seed)
