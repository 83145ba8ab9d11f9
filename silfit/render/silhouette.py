"""Differentiable silhouettes with Mitsuba 3 (``prb_projective``), torch in and torch out.

Camera convention
-----------------
The project's one convention (:mod:`silfit.camera`): vertices are in OpenCV camera
coordinates (x right, y down, z forward, metres); pixel ``(u, v)`` has its centre on
integer coordinates, ``u = fx * x / z + cx``, ``v = fy * y / z + cy``, and the image spans
``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.  The silhouette's pixel ``[v, u]`` is the fraction
of that pixel's square ``[u - 0.5, u + 0.5] x [v - 0.5, v + 0.5]`` covered by the mesh (box
reconstruction filter), so :func:`silfit.camera.project_points` and the rendered
silhouettes agree to sub-pixel precision.

How the camera reaches Mitsuba
------------------------------
Mitsuba's pixel ``i`` covers ``[i, i + 1)`` (an OpenCV ``K`` needs ``cx + 0.5``), its
perspective sensor has square pixels and looks along +z with x to the left.  Rather than
rebuilding or updating the sensor for every camera, each cached scene has one fixed
*canonical* sensor per resolution (``f0 = W`` pixels, principal point at the image
centre, ``to_world = scale(-1, -1, 1)``) and the vertices are mapped by the linear map

    x' = (fx * x + (cx - cx0) * z) / f0,   y' = (fy * y + (cy - cy0) * z) / f0,   z' = z

which keeps depth and every ray through the camera centre, so visibility is unchanged and
``f0 * x'/z' + cx0 == fx * x/z + cx`` exactly.  Any ``fx != fy``, principal point or crop
(region of interest) then reuses the same compiled kernels, and gradients flow through
the map in torch.

Rendering
---------
Two methods (``SilhouetteRenderer(method=...)``): ``"raycast"``, the default, is
:mod:`silfit.render.raycast` (Mitsuba/Embree answers ray tests; sampling, the visibility-edge
integral and all sums in torch; deterministic for any thread count).  ``"projective"`` is
the renderer described here:
a ``constant`` environment of radiance 1 behind the mesh, the mesh a black occluder,
``prb_projective`` with ``max_depth=1, sppc=0, sppi=0, sppp=edge_spp``; silhouette
``= 1 - image``.  The projective integrator adds the visibility-discontinuity (edge) term,
so ``d silhouette / d vertices`` moves the outline.  The scene is built once per (faces
topology, resolution, spp, edge spp) and cached; only vertex positions change between
calls (keep those fixed within a fit: Dr.Jit recompiles when a scene's structure changes).

Torch bridge: a ``torch.autograd.Function`` (not ``dr.wrap``).  A scene holds one set of
vertex positions and Mitsuba's backward pass renders the edge term with whatever the scene
holds at that time, so a render whose scene has since rendered other vertices (a batch,
several subjects per step, a target in between) puts its own vertices back and calls the
integrator's ``render_backward`` itself: every render gets its own gradient, whatever the
order of renders and ``backward()`` calls.  (With ``dr.wrap`` the earlier renders got no
gradient and the last one got theirs as well.)
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Optional, Sequence, Union

import numpy as np
import torch

from silfit.camera import Camera, project_points

from ._llvm import import_mitsuba
from .raycast import MeshEdges, NonManifoldMeshError, RaycastScene, render_views

#: Dr.Jit's thread count for ray-cast silfit.render made with ``threads="auto"`` (``None``: leave the pool as the
#: process has it, by default one thread per core); a Ray actor that reserves ``num_cpus`` CPUs sets it to that, and
#: a ``fit-dataset --workers`` process to 1 (:func:`silfit.runner.worker.process_fitter`), so workers sharing a
#: machine do not each run a pool of every core
AUTO_THREADS: Optional[int] = None

__all__ = [
    "SilhouetteRenderer",
    "RoiWindow",
    "render_silhouette",
    "get_silhouette_renderer",
    "roi_window",
    "paste_roi",
    "check_camera",
    "check_mesh",
]

_NEAR_CLIP = 1e-3
_FAR_CLIP = 1e4


# --------------------------------------------------------------------------- validation
def check_camera(camera) -> Camera:
    """A validated :class:`Camera` (accepts a Camera, a dict or an object with the six fields)."""
    if isinstance(camera, Camera):
        return camera
    if isinstance(camera, dict):
        fields = camera
    else:
        try:
            fields = {k: getattr(camera, k) for k in ("fx", "fy", "cx", "cy", "width", "height")}
        except AttributeError:
            raise ValueError(f"expected a silfit Camera, got {type(camera).__name__}") from None
    try:
        return Camera(**{k: fields[k] for k in ("fx", "fy", "cx", "cy", "width", "height")})
    except KeyError as err:
        raise ValueError(f"camera is missing field {err}") from None


def check_mesh(vertices: torch.Tensor, faces) -> tuple[torch.Tensor, np.ndarray]:
    """Validate ``vertices [V,3]`` or ``[B,V,3]`` and ``faces [F,3]``; returns (vertices, faces int32)."""
    if not isinstance(vertices, torch.Tensor):
        vertices = torch.as_tensor(np.asarray(vertices), dtype=torch.float32)
    if vertices.dim() not in (2, 3) or vertices.shape[-1] != 3:
        raise ValueError(f"vertices must have shape [V,3] or [B,V,3], got {list(vertices.shape)}")
    if vertices.shape[-2] == 0 or vertices.numel() == 0:
        raise ValueError("empty mesh: no vertices")
    if not bool(torch.isfinite(vertices.detach()).all()):
        raise ValueError("vertices contain NaN or infinite values")
    f = faces.detach().cpu().numpy() if isinstance(faces, torch.Tensor) else np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape [F,3], got {list(f.shape)}")
    if f.shape[0] == 0:
        raise ValueError("empty mesh: no faces")
    if not np.issubdtype(f.dtype, np.integer):
        if not np.all(np.mod(f, 1) == 0):
            raise ValueError("faces must hold integer vertex indices")
    nv = vertices.shape[-2]
    if f.min() < 0 or f.max() >= nv:
        raise ValueError(f"faces index vertices out of range [0, {nv}) (min {int(f.min())}, max {int(f.max())})")
    return vertices, np.ascontiguousarray(f, dtype=np.int32)


# --------------------------------------------------------------------------- camera mapping
def canonical_principal_point(width: int, height: int) -> tuple[float, float]:
    """OpenCV principal point of the fixed Mitsuba sensor (image centre)."""
    return width / 2.0 - 0.5, height / 2.0 - 0.5


def to_canonical(vertices: torch.Tensor, camera: Camera) -> torch.Tensor:
    """Map camera-frame vertices so the canonical sensor (focal ``W``, centred principal
    point) images them exactly where ``camera`` would (see the module docstring)."""
    f0 = float(camera.width)
    cx0, cy0 = canonical_principal_point(camera.width, camera.height)
    x, y, z = vertices.unbind(-1)
    xs = (camera.fx * x + (camera.cx - cx0) * z) / f0
    ys = (camera.fy * y + (camera.cy - cy0) * z) / f0
    return torch.stack([xs, ys, z], dim=-1)


# --------------------------------------------------------------------------- region of interest
@dataclass(frozen=True)
class RoiWindow:
    """A window ``[x0, x0 + width/scale) x [y0, y0 + height/scale)`` of the full image
    (pixel-edge coordinates) rendered at ``width x height`` pixels by ``camera``."""

    x0: float
    y0: float
    scale: float
    camera: Camera


def roi_window(
    vertices: torch.Tensor,
    camera: Camera,
    size: Union[int, tuple[int, int]] = 128,
    margin: float = 0.15,
    scale: Optional[float] = None,
) -> RoiWindow:
    """A window around the projected vertices with ``margin`` (fraction of the box) on each
    side, rendered at ``size`` (int or ``(width, height)``).  The window keeps the output's
    aspect ratio; ``scale`` (output pixels per image pixel) is chosen to fit unless given."""
    camera = check_camera(camera)
    out_w, out_h = (size, size) if isinstance(size, int) else (int(size[0]), int(size[1]))
    if out_w <= 0 or out_h <= 0:
        raise ValueError(f"ROI size must be positive, got {out_w}x{out_h}")
    with torch.no_grad():
        v = vertices.detach().reshape(-1, 3).to(torch.float64)
        v = v[v[:, 2] > _NEAR_CLIP]
        if v.shape[0] == 0:
            raise ValueError("no vertex lies in front of the camera")
        uv = project_points(v, camera)
        lo = uv.min(0).values - 0.5
        hi = uv.max(0).values + 0.5
    centre = (lo + hi) / 2
    extent = (hi - lo) * (1 + 2 * margin)
    if scale is None:
        scale = min(out_w / max(float(extent[0]), 1e-6), out_h / max(float(extent[1]), 1e-6))
    x0 = float(centre[0]) - out_w / scale / 2
    y0 = float(centre[1]) - out_h / scale / 2
    return RoiWindow(x0=x0, y0=y0, scale=float(scale), camera=camera.crop(x0, y0, out_w, out_h, scale))


def paste_roi(image: torch.Tensor, window: RoiWindow, full: Camera) -> torch.Tensor:
    """Place an ROI silhouette ``[..., h, w]`` rendered at integer offsets and scale 1 into a
    zero image of the ``full`` camera's size (a cheap inverse of the crop for display/loss)."""
    if window.scale != 1.0 or window.x0 != int(window.x0) or window.y0 != int(window.y0):
        raise ValueError("paste_roi needs a window with scale 1 and integer offsets")
    h, w = image.shape[-2:]
    out = image.new_zeros(*image.shape[:-2], full.height, full.width)
    x0, y0 = int(window.x0), int(window.y0)
    sx0, sy0 = max(0, -x0), max(0, -y0)
    dx0, dy0 = max(0, x0), max(0, y0)
    dx1, dy1 = min(full.width, x0 + w), min(full.height, y0 + h)
    if dx1 > dx0 and dy1 > dy0:
        out[..., dy0:dy1, dx0:dx1] = image[..., sy0 : sy0 + dy1 - dy0, sx0 : sx0 + dx1 - dx0]
    return out


# --------------------------------------------------------------------------- scene cache
def faces_key(faces: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(faces, dtype=np.int32).tobytes()).hexdigest()


class _SilhouetteScene:
    """One Mitsuba scene (fixed topology, resolution, spp, edge spp) and its torch bridge."""

    def __init__(
        self,
        mi,
        dr,
        faces: np.ndarray,
        n_vertices: int,
        width: int,
        height: int,
        spp: int,
        edge_spp: int,
        sampler: str = "independent",
    ):
        self.width, self.height, self.spp, self.edge_spp = width, height, spp, edge_spp
        self.lock = threading.RLock()
        mesh = mi.Mesh("body", n_vertices, faces.shape[0], has_vertex_normals=False)
        mesh_params = mi.traverse(mesh)
        mesh_params["faces"] = mi.UInt32(faces.reshape(-1).astype(np.uint32))
        mesh_params["vertex_positions"] = dr.zeros(mi.Float, 3 * n_vertices)
        mesh_params.update()
        fov = math.degrees(2.0 * math.atan(0.5))  # canonical focal length f0 = W
        self.scene = mi.load_dict(
            {
                "type": "scene",
                "integrator": {"type": "prb_projective", "max_depth": 1, "sppc": 0, "sppi": 0, "sppp": int(edge_spp)},
                "sensor": {
                    "type": "perspective",
                    "to_world": mi.ScalarTransform4f().scale([-1.0, -1.0, 1.0]),
                    "fov_axis": "x",
                    "fov": fov,
                    "near_clip": _NEAR_CLIP,
                    "far_clip": _FAR_CLIP,
                    "film": {
                        "type": "hdrfilm",
                        "width": int(width),
                        "height": int(height),
                        "sample_border": True,
                        "pixel_format": "luminance",
                        "rfilter": {"type": "box"},
                    },
                    "sampler": {"type": sampler, "sample_count": int(spp)},
                },
                "emitter": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
                "body": mesh,
            }
        )
        self.params = mi.traverse(self.scene)
        self.params.keep(["body.vertex_positions"])
        self.mi, self.dr = mi, dr
        self.generation = 0  # bumped whenever the scene's vertex positions change

    def render(self, verts: torch.Tensor, seed: int) -> torch.Tensor:
        """Silhouette ``[H, W]`` of ``verts [V, 3]`` (canonical frame, float32, contiguous);
        differentiable in torch when ``verts`` requires grad."""
        if torch.is_grad_enabled() and verts.requires_grad:
            return _RenderFunction.apply(verts, self, int(seed))
        self._set_vertices(verts, grad=False)
        img = self.mi.render(self.scene, spp=0, seed=int(seed))
        return 1.0 - img.torch()[..., 0]

    # The scene holds one set of vertex positions, and Mitsuba's backward pass renders the
    # edge term with whatever the scene holds *then*.  So the AD graph of a render is used
    # only while the scene still holds that render's vertices; after another render (a
    # batch, several subjects, a target rendered in between) the backward pass puts this
    # render's vertices back and calls the integrator's render_backward itself.
    def _set_vertices(self, verts: torch.Tensor, grad: bool):
        x = self.mi.Float(verts.detach().reshape(-1))
        if grad:
            self.dr.enable_grad(x)
        self.params["body.vertex_positions"] = x
        self.params.update()
        self.generation += 1
        return x

    def _forward(self, verts: torch.Tensor, seed: int):
        x = self._set_vertices(verts, grad=True)
        seed_grad = _grad_seed(seed)
        img = self.mi.render(self.scene, self.params, spp=0, seed=seed, seed_grad=seed_grad)
        return img, x, self.generation, seed_grad

    def _vertex_grad(self, state, verts: torch.Tensor, grad_sil: torch.Tensor) -> torch.Tensor:
        img, x, generation, seed_grad = state
        dr, mi = self.dr, self.mi
        grad_img = mi.TensorXf((-grad_sil).to(torch.float32).contiguous().reshape(*grad_sil.shape, 1))
        if generation == self.generation:  # the scene still holds these vertices
            dr.set_grad(img, grad_img)
            dr.enqueue(dr.ADMode.Backward, img)
            dr.traverse(dr.ADMode.Backward)
        else:
            x = self._set_vertices(verts, grad=True)
            self.scene.integrator().render_backward(self.scene, self.params, grad_img, seed=seed_grad, spp=0)
        g = dr.grad(x)
        return g.torch().reshape(verts.shape)


class _RenderFunction(torch.autograd.Function):
    """``silhouette = render(verts)`` with the vertex gradient from Mitsuba (see
    :meth:`_SilhouetteScene._vertex_grad`)."""

    @staticmethod
    def forward(ctx, verts, scene, seed):
        img, x, generation, seed_grad = scene._forward(verts, seed)
        ctx.scene, ctx.state = scene, (img, x, generation, seed_grad)
        ctx.save_for_backward(verts)
        return 1.0 - img.torch()[..., 0]

    @staticmethod
    def backward(ctx, grad_sil):
        (verts,) = ctx.saved_tensors
        with ctx.scene.lock:
            g = ctx.scene._vertex_grad(ctx.state, verts, grad_sil)
        ctx.state = None
        return g.to(device=verts.device, dtype=verts.dtype), None, None


def _grad_seed(seed: int) -> int:
    """The seed of the edge (backward) pass: decorrelated from the primal seed."""
    return (int(seed) * 0x9E3779B1 + 0x7F4A7C15) % (2**32 - 1) + 1


# --------------------------------------------------------------------------- renderer
class SilhouetteRenderer:
    """Differentiable silhouettes of one mesh topology (see the module docstring).

    ``renderer = SilhouetteRenderer(faces)``; ``renderer(vertices, camera)`` returns a
    ``[H, W]`` (or ``[B, H, W]``) float32 tensor in [0, 1] whose gradient reaches
    ``vertices``.  ``spp`` primal samples per pixel and ``edge_spp`` edge samples
    (``sppp``) are defaults overridable per call; each call draws a fresh seed from
    torch's generator (reproducible under ``torch.manual_seed``) unless ``seed`` is given.

    ``method``: ``"raycast"`` (default since issue 24, :mod:`silfit.render.raycast`: Mitsuba
    answers ray tests, torch does the sampling, the edge integral and every sum) or
    ``"projective"`` (Mitsuba's ``prb_projective`` integrator, the renderer before); a
    mesh with an edge shared by more than two faces falls back to ``"projective"``.
    :meth:`render_views` renders one body in several cameras (one acceleration-structure
    build for all with the ray-cast method).

    ``threads``: Dr.Jit's thread-pool size, set before each render (``None``: leave it
    alone). The pool is process-wide and stays so. ``"auto"`` (the default) is
    :data:`AUTO_THREADS` (``None`` unless a Ray actor or a ``--workers`` process set it) for the ray-cast method, which
    gives bit-identical silhouettes, gradients and fits for any thread count (tested per
    render and per silhouette-stage fit), and ``1`` for
    ``"projective"``: there one thread keeps the backward pass's scatter-adds in a fixed
    order, so a fixed seed gives bit-identical gradients and fits; with several, the same
    seed gave silhouette fits of PA-MPJPE 12.3-19.9 mm over 5 runs of 40 steps
    (tools/repro_silhouette.py). Before issue 24's threads part the ray-cast method ran one
    thread too.
    """

    def __init__(
        self,
        faces,
        spp: int = 4,
        edge_spp: int = 1,
        variant: Optional[str] = None,
        max_cached_scenes: int = 8,
        sampler: Optional[str] = None,
        threads: Union[int, None, str] = "auto",
        method: str = "raycast",
        edge_sampling: str = "random",
    ):
        f = faces.detach().cpu().numpy() if isinstance(faces, torch.Tensor) else np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
            raise ValueError(f"faces must be a non-empty [F,3] array, got shape {list(f.shape)}")
        if f.min() < 0:
            raise ValueError("faces contain negative vertex indices")
        self.faces = np.ascontiguousarray(f, dtype=np.int32)
        self.spp, self.edge_spp = _positive_int(spp, "spp"), _positive_int(edge_spp, "edge_spp")
        if method not in METHODS:
            raise ValueError(f"unknown silhouette method {method!r}; choose one of {', '.join(METHODS)}")
        if method == "raycast":
            try:
                MeshEdges(self.faces)
            except NonManifoldMeshError:
                method = "projective"  # the ray-cast method needs a 2-manifold mesh
        self.method = method
        if edge_sampling not in ("systematic", "random"):
            raise ValueError(f"edge_sampling must be 'systematic' or 'random', got {edge_sampling!r}")
        self.edge_sampling = edge_sampling  # ray-cast method: edge points independent, or evenly spaced (one offset)
        # independent samples by default: the stage's Adam settings were tuned with this noise; the
        # lower-noise stratified/systematic samples (same expectation) cost up to 6 mm PA-PVE on a
        # 4-view rig of benchmarks/bench_silhouette.py (method after-noisy is the default now)
        self.sampler = _check_sampler(sampler or "independent")
        self.mi, self.dr = import_mitsuba(variant)
        self.variant = self.mi.variant()
        self._scenes: "OrderedDict[tuple, _SilhouetteScene]" = OrderedDict()
        self._max_cached = int(max_cached_scenes)
        self._lock = threading.Lock()
        if threads == "auto":  # the ray-cast method's results do not depend on the thread count
            threads = AUTO_THREADS if method == "raycast" else 1
        self.threads = None if threads is None else _positive_int(threads, "threads")
        self._ray_scenes: dict = {}

    def _ray_scene(self, n_vertices: int):
        with self._lock:
            scene = self._ray_scenes.get(n_vertices)
            if scene is None:
                if self.mi.variant() != self.variant:
                    self.mi.set_variant(self.variant)
                scene = self._ray_scenes[n_vertices] = RaycastScene(self.mi, self.dr, self.faces, n_vertices)
            return scene

    def _set_threads(self) -> None:
        if self.threads is not None and self.dr.thread_count() != self.threads:
            self.dr.set_thread_count(self.threads)

    # ---- scenes
    def _scene(
        self, n_vertices: int, width: int, height: int, spp: int, edge_spp: int, sampler: str
    ) -> _SilhouetteScene:
        key = (n_vertices, width, height, spp, edge_spp, sampler)
        with self._lock:
            scene = self._scenes.get(key)
            if scene is None:
                if self.mi.variant() != self.variant:
                    self.mi.set_variant(self.variant)
                scene = _SilhouetteScene(
                    self.mi, self.dr, self.faces, n_vertices, width, height, spp, edge_spp, sampler
                )
                self._scenes[key] = scene
                while len(self._scenes) > self._max_cached:
                    self._scenes.popitem(last=False)
            else:
                self._scenes.move_to_end(key)
            return scene

    # ---- rendering
    def __call__(
        self,
        vertices: torch.Tensor,
        camera: Camera,
        spp: Optional[int] = None,
        edge_spp: Optional[int] = None,
        seed: Optional[int] = None,
        sampler: Optional[str] = None,
        edge_density: Optional[float] = None,
    ) -> torch.Tensor:
        """Silhouette of ``vertices [V,3]`` or ``[B,V,3]`` (camera frame) under ``camera``.

        ``sampler`` is a Mitsuba sampler plugin (``independent`` by default; ``stratified``
        or ``multijitter`` give much lower noise for reference renders, e.g. finite
        differences with a shared seed).  Batch element ``i`` uses ``seed + i``.
        ``edge_density``: the ray-cast method's edge points per pixel of contour-candidate
        length instead of ``edge_spp`` per image pixel (:func:`silfit.render.raycast.render_views`;
        ``None``: ``edge_spp``; the projective method ignores it)."""
        camera = check_camera(camera)
        vertices, _ = check_mesh(vertices, self.faces)
        spp = self.spp if spp is None else _positive_int(spp, "spp")
        edge_spp = self.edge_spp if edge_spp is None else _positive_int(edge_spp, "edge_spp")
        sampler = self.sampler if sampler is None else _check_sampler(sampler)
        batched = vertices.dim() == 3
        if self.method == "raycast":
            batch = vertices if batched else vertices[None]
            eye, zero = torch.eye(3), torch.zeros(3)
            out = torch.stack(
                [
                    self.render_views(
                        v,
                        [camera],
                        [eye],
                        [zero],
                        spp=spp,
                        edge_spp=edge_spp,
                        seeds=[fresh_seed() if seed is None else int(seed) + i],
                        sampler=sampler,
                        edge_density=edge_density,
                    )[0]
                    for i, v in enumerate(batch)
                ]
            )
            return out if batched else out[0]
        scene = self._scene(vertices.shape[-2], camera.width, camera.height, spp, edge_spp, sampler)
        batch = vertices if batched else vertices[None]
        out_dtype = vertices.dtype if vertices.is_floating_point() else torch.float32
        device = vertices.device
        images = []
        for i, verts in enumerate(batch):
            mapped = to_canonical(verts.to(torch.float32), camera).contiguous()
            if device.type != "cuda" or not self.variant.startswith("cuda"):
                mapped = mapped.cpu()
            s = fresh_seed() if seed is None else int(seed) + i
            if self.threads is not None and self.dr.thread_count() != self.threads:
                self.dr.set_thread_count(self.threads)  # deterministic accumulation (see the class docstring)
            with scene.lock:
                img = scene.render(mapped, s)
            images.append(img.to(device=device, dtype=out_dtype))
        out = torch.stack(images)
        return out if batched else out[0]

    def render_views(
        self,
        vertices: torch.Tensor,
        cameras: Sequence[Camera],
        rotations: Sequence[torch.Tensor],
        translations: Sequence[torch.Tensor],
        spp: Optional[int] = None,
        edge_spp: Optional[int] = None,
        seeds: Optional[Sequence[int]] = None,
        sampler: Optional[str] = None,
        edge_density: Optional[float] = None,
    ) -> list:
        """Silhouettes of one body ``vertices [V, 3]`` (any reference frame, e.g. the world)
        seen by several cameras with extrinsics ``R_i, t_i`` (camera-frame points ``R_i x +
        t_i``): a list of ``[H_i, W_i]`` tensors whose gradients reach ``vertices``.  The
        ray-cast method builds one acceleration structure for all views; the projective
        method renders each view from its own mapped copy.  ``seeds[i]``: view ``i``'s seed;
        ``edge_density``: as in :meth:`__call__`."""
        cameras = [check_camera(c) for c in cameras]
        vertices, _ = check_mesh(vertices, self.faces)
        if vertices.dim() != 2:
            raise ValueError("render_views takes one vertex set [V, 3]")
        if not (len(cameras) == len(rotations) == len(translations)):
            raise ValueError(f"{len(cameras)} cameras, {len(rotations)} rotations, {len(translations)} translations")
        spp = self.spp if spp is None else _positive_int(spp, "spp")
        edge_spp = self.edge_spp if edge_spp is None else _positive_int(edge_spp, "edge_spp")
        sampler = self.sampler if sampler is None else _check_sampler(sampler)
        seeds = (
            [fresh_seed() for _ in cameras]
            if seeds is None
            else [(fresh_seed() if s is None else int(s)) for s in seeds]
        )
        out_dtype = vertices.dtype if vertices.is_floating_point() else torch.float32
        device = vertices.device
        if self.method != "raycast":
            out = []
            for cam, R, t, s in zip(cameras, rotations, translations, seeds):
                R, t = torch.as_tensor(R).to(vertices.dtype), torch.as_tensor(t).to(vertices.dtype)
                out.append(self(vertices @ R.T + t, cam, spp=spp, edge_spp=edge_spp, seed=s, sampler=sampler))
            return out
        views = [
            (
                cam,
                torch.as_tensor(R).detach().to(torch.float64).cpu(),
                torch.as_tensor(t).detach().to(torch.float64).cpu(),
            )
            for cam, R, t in zip(cameras, rotations, translations)
        ]
        self._set_threads()
        verts = vertices.cpu() if vertices.device.type != "cpu" else vertices
        images = render_views(
            self._ray_scene(vertices.shape[0]),
            verts,
            views,
            spp,
            edge_spp,
            seeds,
            sampler != "independent",
            self.edge_sampling == "systematic",
            edge_density,
        )
        return [img.to(device=device, dtype=out_dtype) for img in images]

    def render_roi(
        self,
        vertices: torch.Tensor,
        camera: Camera,
        size: Union[int, tuple[int, int]] = 128,
        window: Optional[RoiWindow] = None,
        margin: float = 0.15,
        **kwargs,
    ) -> tuple[torch.Tensor, RoiWindow]:
        """Render only a window around the person at ``size``; returns ``(silhouette, window)``.

        ``window.camera`` is the crop camera (``Camera.crop``): compare the result with a
        target cut or resampled from the same window.  Give ``window`` to keep it fixed."""
        camera = check_camera(camera)
        if window is None:
            window = roi_window(vertices, camera, size=size, margin=margin)
        return self(vertices, window.camera, **kwargs), window

    def clear_cache(self) -> None:
        with self._lock:
            self._scenes.clear()
            self._ray_scenes.clear()


_DEFAULT_RENDERERS: "OrderedDict[str, SilhouetteRenderer]" = OrderedDict()


def get_silhouette_renderer(faces) -> SilhouetteRenderer:
    """A shared :class:`SilhouetteRenderer` per faces topology (its compiled scenes are kept
    across calls and fits; samples per pixel are chosen per call)."""
    f = faces.detach().cpu().numpy() if isinstance(faces, torch.Tensor) else np.asarray(faces)
    key = faces_key(f)
    renderer = _DEFAULT_RENDERERS.get(key)
    if renderer is None:
        renderer = SilhouetteRenderer(f)
        _DEFAULT_RENDERERS[key] = renderer
        while len(_DEFAULT_RENDERERS) > 4:
            _DEFAULT_RENDERERS.popitem(last=False)
    else:
        _DEFAULT_RENDERERS.move_to_end(key)
    return renderer


def render_silhouette(
    vertices: torch.Tensor, faces, camera: Camera, spp: int = 4, edge_spp: int = 1, seed: Optional[int] = None
) -> torch.Tensor:
    """Functional form: silhouette of ``vertices`` with ``faces`` under ``camera``.
    Renderers (and their compiled scenes) are cached per faces topology."""
    vertices, f = check_mesh(vertices, faces)
    return get_silhouette_renderer(f)(vertices, camera, spp=spp, edge_spp=edge_spp, seed=seed)


def fresh_seed() -> int:
    return int(torch.randint(0, 2**31 - 1, (1,)).item())


#: ``raycast``: rays through Mitsuba's acceleration structure, the rest in torch
#: (:mod:`silfit.render.raycast`); ``projective``: Mitsuba's ``prb_projective`` integrator
METHODS = ("raycast", "projective")

_SAMPLERS = ("independent", "stratified", "multijitter", "ldsampler", "orthogonal")


def _check_sampler(name: str) -> str:
    if name not in _SAMPLERS:
        raise ValueError(f"unknown sampler {name!r}; choose one of {', '.join(_SAMPLERS)}")
    return name


def _positive_int(value, name: str) -> int:
    if isinstance(value, bool) or int(value) != value or int(value) <= 0:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)
