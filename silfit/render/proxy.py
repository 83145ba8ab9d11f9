"""Render proxies: a coarser mesh whose vertices are a fixed linear function of a body's.

The silhouette renderer's forward cost follows the triangle count, so the silhouette
stage can render a decimated copy of the body instead of the full mesh.  Skinning, shape
and pose stay exact (they run on the full model); only the rasterised outline is coarser.

Construction (once per topology, :func:`build_proxy`)
-----------------------------------------------------
1. Quadric-error decimation (``fast_simplification``) of the *template* mesh to
   ``n_faces`` triangles gives the proxy's faces and, for each proxy vertex, a position
   ``p`` (the quadric optimum, which sits slightly *outside* the surface on convex parts
   and so keeps the outline from shrinking).
2. Each ``p`` is written as an **affine** combination ``p = sum_j w_j v_j`` (``sum w = 1``)
   of ``K`` template vertices: the three corners of the nearest template triangle plus
   the nearest other vertices.  The weights solve a small ridge problem
   ``min |V w - p|^2 + ridge |w - b|^2`` with ``b`` the barycentric coordinates of the
   closest surface point, so they stay bounded.  Affine weights commute with rigid motions
   and follow the local deformation of skinning.

So ``proxy_vertices = P @ model_vertices`` with a fixed sparse ``P [Vp, V]``
(``K`` entries per row): :meth:`RenderProxy.apply` computes it with a gather (batched,
differentiable in torch), :meth:`RenderProxy.matrix` gives ``P`` as a torch sparse tensor.

Caching (:func:`get_proxy`): in memory per (template, faces, n_faces, options) and on disk
under ``$SILFIT_CACHE_DIR`` (default ``~/.cache/silfit``)``/proxy/<sha1>.npz``, keyed by a
hash of the template, the faces and the options.  The disk cache is an optimisation only:
a missing, unreadable or stale file is rebuilt (about 1 s for the open body).
"""

from __future__ import annotations

import hashlib
import os
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import fast_simplification
import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from .silhouette import SilhouetteRenderer

__all__ = [
    "DEFAULT_PROXY_FACES",
    "ProxySilhouetteRenderer",
    "RenderProxy",
    "proxy_renderer",
    "build_proxy",
    "get_proxy",
    "proxy_cache_dir",
]

#: Proxy size that keeps the open body's silhouette IoU >= 0.995 against the full mesh
#: (10,000 of 26,692 faces; see benchmarks/bench_render.py --proxy).
DEFAULT_PROXY_FACES = 10000

_FORMAT = 1  # bump when the construction changes (invalidates disk caches)


@dataclass(frozen=True, eq=False)
class RenderProxy:
    """A coarse mesh ``faces [Fp, 3]`` whose vertex ``i`` is
    ``sum_k weights[i, k] * model_vertices[indices[i, k]]`` (rows sum to 1)."""

    faces: np.ndarray  # [Fp, 3] int32, indexes proxy vertices
    indices: np.ndarray  # [Vp, K] int64, model vertex indices
    weights: np.ndarray  # [Vp, K] float32
    n_model_vertices: int

    @property
    def n_vertices(self) -> int:
        return int(self.indices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    def apply(self, vertices: torch.Tensor) -> torch.Tensor:
        """Proxy vertices ``[..., Vp, 3]`` of model vertices ``[..., V, 3]`` (differentiable)."""
        if vertices.shape[-2] != self.n_model_vertices or vertices.shape[-1] != 3:
            raise ValueError(f"proxy expects vertices [..., {self.n_model_vertices}, 3], got {list(vertices.shape)}")
        idx, w = self._tensors(vertices.device, vertices.dtype)
        gathered = vertices[..., idx.reshape(-1), :].reshape(*vertices.shape[:-2], *idx.shape, 3)
        return (gathered * w[..., None]).sum(-2)

    __call__ = apply

    def matrix(self, dtype=torch.float32, device=None) -> torch.Tensor:
        """``P [Vp, V]`` as a sparse COO tensor: ``proxy = P @ vertices [V, 3]``."""
        rows = np.repeat(np.arange(self.n_vertices), self.indices.shape[1])
        idx = torch.as_tensor(np.stack([rows, self.indices.reshape(-1)]))
        val = torch.as_tensor(self.weights.reshape(-1), dtype=dtype)
        with warnings.catch_warnings():  # torch flags sparse COO as beta
            warnings.simplefilter("ignore", UserWarning)
            return torch.sparse_coo_tensor(idx, val, (self.n_vertices, self.n_model_vertices), device=device).coalesce()

    def _tensors(self, device, dtype):
        key = (str(device), dtype)
        cache = self.__dict__.setdefault("_torch_cache", {})
        if key not in cache:
            cache[key] = (
                torch.as_tensor(self.indices, device=device),
                torch.as_tensor(self.weights, device=device, dtype=dtype),
            )
        return cache[key]


# --------------------------------------------------------------------------- construction
def build_proxy(
    template: np.ndarray,
    faces: np.ndarray,
    n_faces: int,
    neighbours: int = 10,
    ridge: float = 1e-7,
    aggressiveness: float = 3.0,
) -> RenderProxy:
    """Decimate ``(template [V,3], faces [F,3])`` to about ``n_faces`` triangles and express
    each new vertex as fixed affine weights over ``neighbours`` template vertices (see the
    module docstring).  ``ridge`` (m^2) trades exact reproduction of the decimated position
    against weights close to the nearest surface point's barycentric coordinates.
    ``aggressiveness`` is ``fast_simplification``'s ``agg``: lower keeps the outline better
    (on the open body at 8,000 faces: agg 3 gives IoU 0.994, agg 7 0.991, agg 10 0.986)
    but below about 2 stops short of ``n_faces``."""
    template = np.ascontiguousarray(template, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if template.ndim != 2 or template.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"template must be [V,3] and faces [F,3], got {list(template.shape)} and {list(faces.shape)}")
    if not 4 <= int(n_faces) <= faces.shape[0]:
        raise ValueError(f"n_faces must lie in [4, {faces.shape[0]}], got {n_faces}")
    if neighbours < 3:
        raise ValueError(f"neighbours must be at least 3, got {neighbours}")
    if int(n_faces) == faces.shape[0]:
        points, new_faces = template, faces
    else:
        points, new_faces = fast_simplification.simplify(
            template.astype(np.float32), faces.astype(np.int32), target_count=int(n_faces), agg=float(aggressiveness)
        )
        points = np.asarray(points, dtype=np.float64)
    tri, bary = _closest_surface_points(template, faces, points)
    indices = _neighbourhoods(template, faces[tri], points, int(neighbours))
    prior = np.zeros(indices.shape)
    prior[:, :3] = bary
    weights = _affine_weights(template[indices], points, prior, float(ridge))
    return RenderProxy(
        faces=np.ascontiguousarray(new_faces, dtype=np.int32),
        indices=indices,
        weights=weights.astype(np.float32),
        n_model_vertices=int(template.shape[0]),
    )


def _closest_surface_points(template, faces, points, k: int = 8):
    """For each point: the nearest template triangle (among those around its ``k`` nearest
    vertices) and the barycentric coordinates of the closest point on it."""
    _, nn = cKDTree(template).query(points, k=k)
    # vertex -> incident faces (CSR)
    order = np.argsort(faces.reshape(-1), kind="stable")
    face_of = order // 3
    starts = np.searchsorted(faces.reshape(-1)[order], np.arange(template.shape[0] + 1))
    counts = np.diff(starts)
    point_ids, cand = [], []
    for j in range(k):
        v = nn[:, j]
        c = counts[v]
        point_ids.append(np.repeat(np.arange(len(points)), c))
        cand.append(face_of[np.concatenate([np.arange(s, s + n) for s, n in zip(starts[v], c)])])
    pi, fi = np.concatenate(point_ids), np.concatenate(cand)
    closest = trimesh.triangles.closest_point(template[faces[fi]], points[pi])
    dist = np.linalg.norm(closest - points[pi], axis=1)
    order = np.lexsort((fi, dist, pi))  # per point: smallest distance first (ties: lowest face)
    first = np.r_[True, pi[order][1:] != pi[order][:-1]]
    sel = order[first]
    tri = fi[sel]
    bary = trimesh.triangles.points_to_barycentric(template[faces[tri]], closest[sel])
    bary = np.clip(bary, 0.0, None)
    return tri, bary / bary.sum(1, keepdims=True)


def _neighbourhoods(template, corners, points, k: int) -> np.ndarray:
    """``[Vp, k]`` template vertex indices: the triangle's three corners first, then the
    nearest other vertices."""
    _, nn = cKDTree(template).query(points, k=k + 3)
    taken = (nn[:, :, None] == corners[:, None, :]).any(-1)
    rank = np.argsort(taken, axis=1, kind="stable")[:, : k - 3]
    others = np.take_along_axis(nn, rank, axis=1)
    return np.ascontiguousarray(np.concatenate([corners, others], axis=1), dtype=np.int64)


def _affine_weights(neigh, points, prior, ridge: float) -> np.ndarray:
    """Solve ``min |A w - p|^2 + ridge |w - prior|^2`` s.t. ``sum w = 1`` per point
    (``neigh [N, K, 3]``) through the KKT system."""
    n, k, _ = neigh.shape
    A = neigh.transpose(0, 2, 1)  # [N, 3, K]
    kkt = np.zeros((n, k + 1, k + 1))
    kkt[:, :k, :k] = np.einsum("nik,nil->nkl", A, A) + ridge * np.eye(k)
    kkt[:, :k, k] = 1.0
    kkt[:, k, :k] = 1.0
    rhs = np.concatenate([np.einsum("nik,ni->nk", A, points) + ridge * prior, np.ones((n, 1))], axis=1)
    return np.linalg.solve(kkt, rhs[..., None])[:, :k, 0]


# --------------------------------------------------------------------------- caching
_MEMORY: dict = {}
_LOCK = threading.Lock()


def proxy_cache_dir() -> Path:
    """Where proxies are cached on disk: ``$SILFIT_CACHE_DIR/proxy`` (default ``~/.cache/silfit/proxy``)."""
    root = os.environ.get("SILFIT_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "silfit")
    return Path(root) / "proxy"


def _key(template: np.ndarray, faces: np.ndarray, n_faces: int, options: tuple) -> str:
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(template, dtype=np.float32).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    h.update(repr((_FORMAT, int(n_faces), options)).encode())
    return h.hexdigest()


def get_proxy(
    template,
    faces,
    n_faces: int,
    neighbours: int = 10,
    ridge: float = 1e-7,
    aggressiveness: float = 3.0,
    disk_cache: bool = True,
) -> RenderProxy:
    """The cached :func:`build_proxy` of ``template [V,3]`` / ``faces [F,3]`` (numpy or
    torch), e.g. ``get_proxy(model.v_template, model.faces, DEFAULT_PROXY_FACES)``."""
    t = template.detach().cpu().numpy() if isinstance(template, torch.Tensor) else np.asarray(template)
    f = faces.detach().cpu().numpy() if isinstance(faces, torch.Tensor) else np.asarray(faces)
    key = _key(t, f, n_faces, (int(neighbours), float(ridge), float(aggressiveness)))
    with _LOCK:
        proxy = _MEMORY.get(key)
        if proxy is not None:
            return proxy
        path = proxy_cache_dir() / f"{key}.npz" if disk_cache else None
        proxy = _load(path, t.shape[0]) if path is not None else None
        if proxy is None:
            proxy = build_proxy(t, f, n_faces, neighbours=neighbours, ridge=ridge, aggressiveness=aggressiveness)
            if path is not None:
                _save(path, proxy)
        _MEMORY[key] = proxy
        return proxy


def _load(path: Path, n_model_vertices: int) -> Optional[RenderProxy]:
    try:
        with np.load(path) as z:
            proxy = RenderProxy(
                faces=z["faces"].astype(np.int32),
                indices=z["indices"].astype(np.int64),
                weights=z["weights"].astype(np.float32),
                n_model_vertices=int(z["n_model_vertices"]),
            )
    except Exception:  # noqa: BLE001 - any unreadable cache file (truncated zip, EOF, ...) is rebuilt
        return None
    ok = (
        proxy.n_model_vertices == n_model_vertices
        and proxy.indices.shape == proxy.weights.shape
        and proxy.faces.ndim == 2
        and proxy.faces.shape[1] == 3
        and proxy.faces.size > 0
        and int(proxy.faces.max()) < proxy.n_vertices
        and int(proxy.indices.max()) < n_model_vertices
    )
    return proxy if ok else None


def _save(path: Path, proxy: RenderProxy) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(
            tmp,
            faces=proxy.faces,
            indices=proxy.indices,
            weights=proxy.weights,
            n_model_vertices=np.int64(proxy.n_model_vertices),
        )
        os.replace(tmp, path)
    except OSError:
        pass  # the cache is an optimisation; a read-only home still works


# --------------------------------------------------------------------------- renderer
class ProxySilhouetteRenderer:
    """Drop-in for :class:`silfit.render.silhouette.SilhouetteRenderer` (e.g. the ``renderer``
    argument of ``fit_silhouette``): ``renderer(vertices [V,3] or [B,V,3], camera, ...)``
    renders the proxy of the model's vertices; gradients reach the model's vertices."""

    def __init__(self, proxy: RenderProxy, **renderer_options):
        self.proxy = proxy
        self.renderer = SilhouetteRenderer(proxy.faces, **renderer_options)
        self.faces = self.renderer.faces

    def __call__(self, vertices: torch.Tensor, camera, **kwargs) -> torch.Tensor:
        return self.renderer(self.proxy(vertices), camera, **kwargs)

    def render_views(self, vertices: torch.Tensor, cameras, rotations, translations, **kwargs):
        return self.renderer.render_views(self.proxy(vertices), cameras, rotations, translations, **kwargs)

    def render_roi(self, vertices: torch.Tensor, camera, **kwargs):
        return self.renderer.render_roi(self.proxy(vertices), camera, **kwargs)


def proxy_renderer(model, n_faces: int = DEFAULT_PROXY_FACES) -> ProxySilhouetteRenderer:
    """A cached :class:`ProxySilhouetteRenderer` of ``model`` (``v_template``, ``faces``)."""
    proxy = get_proxy(model.v_template, model.faces, n_faces)
    key = ("renderer", id(proxy))
    with _LOCK:
        r = _MEMORY.get(key)
        if r is None:
            r = _MEMORY[key] = ProxySilhouetteRenderer(proxy)
        return r
