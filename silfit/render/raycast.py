"""The ``raycast`` silhouette method: Mitsuba/Embree traces the rays, torch does the rest.

:class:`silfit.render.silhouette.SilhouetteRenderer` renders with this method by default
(``method="raycast"``; ``"projective"`` is Mitsuba's ``prb_projective`` integrator, the
method before issue 24).  The silhouette and its gradient are the same quantities as the
projective integrator's, estimated with fewer rays and with every reduction in torch:

Silhouette (pixel coverage, box filter)
    The coverage of a closed mesh changes only across the image of its *contour
    candidates*: edges whose two faces face opposite ways seen from the camera (and
    boundary edges).  Those segments are projected in torch and every pixel they touch
    (dilated by one pixel) is an *edge pixel*; it gets ``spp`` rays (independent, or
    stratified with a sampler other than ``"independent"``) through its square.  Every other pixel has
    constant coverage over its square and over its 4-connected component of such pixels,
    so one ray through one pixel of each component gives the exact value of all.

Gradient (visibility-edge term)
    ``d sum(g * S) / d x = integral over the contour of g(p) (v(p) . n(p)) dl``: ``N =
    edge_spp * W * H`` points (or, with ``edge_density``, ``ceil(edge_density * L)`` for
    ``L`` pixels of candidate length, at most ``edge_spp * W * H``: a fixed density along the
    contour, not a count per image pixel) are drawn uniformly along the projected candidate segments
    (independently, or evenly spaced with one random offset: ``edge_sampling="systematic"``); a point counts where a ray just outside the
    segment (``1e-4`` px from it, on the side away from its faces) misses the mesh, i.e.
    where the segment is the visible outline.  ``g`` is the loss's gradient at the pixel
    holding the point and ``v . n`` the outward normal speed of the segment's endpoints,
    interpolated; the projection's Jacobian at the segments' endpoints takes it back to the
    vertices (``RaycastScene.analytic_grad = False``: torch's autograd through the projection).
    Each point weighs ``L / N`` (the same estimator for any ``N``: the density changes the
    noise, not the expectation).

All rays of a call (coverage and edge points, every view) go to one Embree query
(``Scene.ray_test``), whose results do not depend on Dr.Jit's thread count or the order
of work, and all sums are torch reductions in a fixed order: a seed gives bit-identical
silhouettes and gradients whatever the number of threads.  Random numbers come from a
counter-based hash of (seed, pixel, sample), so a pixel's samples do not depend on which
other pixels are edge pixels (finite differences with one seed stay consistent).

One scene (one acceleration structure) per (topology) holds one set of vertex positions;
the views of a body (a rig) are rays from several camera centres into it, so a rig step
rebuilds the structure once, not once per view.  The edge points and their visibility are
computed in the forward pass, so the backward pass needs no renderer at all.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import List, Optional, Sequence

import cv2
import numpy as np
import torch

from silfit.camera import Camera

__all__ = ["MeshEdges", "RaycastScene", "NonManifoldMeshError"]

_NEAR = 1e-3  # metres: candidate segments with an endpoint nearer than this are dropped
_EDGE_EPS = 1e-4  # px: the outside ray's distance from the candidate segment (the bias, from contour folds
# thinner than this counted twice, measured +0.8 % at 1e-3 px, +0.09 % at 1e-4 px)
_MARK_SPACING = 0.5  # px between the points that mark a segment's pixels
_EYE = torch.eye(3, dtype=torch.float64)


class NonManifoldMeshError(ValueError):
    """An edge is shared by more than two faces (the ray-cast method needs a 2-manifold)."""


class MeshEdges:
    """The unique edges of a triangle mesh with the faces on each side (``face_b = -1``
    on a boundary) and each edge's opposite vertex in ``face_a``."""

    def __init__(self, faces: np.ndarray):
        f = np.ascontiguousarray(faces, dtype=np.int64)
        F = f.shape[0]
        half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])  # [3F, 2]
        opposite = np.concatenate([f[:, 2], f[:, 0], f[:, 1]])
        face_of = np.tile(np.arange(F), 3)
        key = np.sort(half, axis=1)
        order = np.lexsort((face_of, key[:, 1], key[:, 0]))
        key, opposite, face_of = key[order], opposite[order], face_of[order]
        first = np.r_[True, (key[1:] != key[:-1]).any(1)]
        starts = np.flatnonzero(first)
        counts = np.diff(np.r_[starts, len(key)])
        if counts.max() > 2:
            raise NonManifoldMeshError(f"{int((counts > 2).sum())} edges are shared by more than two faces")
        self.edges = torch.as_tensor(key[starts])  # [E, 2]
        self.face_a = torch.as_tensor(face_of[starts])
        self.opposite_a = torch.as_tensor(opposite[starts])
        second = np.where(counts == 2, starts + 1, starts)
        self.face_b = torch.as_tensor(np.where(counts == 2, face_of[second], -1))
        self.faces = torch.as_tensor(f)


# --------------------------------------------------------------------------- random numbers
_M1 = -0x40A7B892E31B1A47  # 0xbf58476d1ce4e5b9 as int64
_M2 = -0x6B2FB644ECCEEE15  # 0x94d049bb133111eb as int64
_GOLDEN = -0x61C8864680B583EB  # 0x9e3779b97f4a7c15 as int64


def _lsr(x: torch.Tensor, k: int) -> torch.Tensor:
    return (x >> k) & ((1 << (64 - k)) - 1)


def hash_uniform(seed: int, stream: int, index: torch.Tensor) -> torch.Tensor:
    """Uniform numbers in [0, 1) (float64, 24 bits) from a counter-based hash (splitmix64)
    of ``(seed, stream, index)``: the same on every machine and thread count."""
    base = ((int(seed) & 0xFFFFFFFF) << 24) ^ (int(stream) << 56)
    x = index.to(torch.int64) * _GOLDEN + base
    x = x ^ _lsr(x, 30)
    x = x * _M1
    x = x ^ _lsr(x, 27)
    x = x * _M2
    x = x ^ _lsr(x, 31)
    return _lsr(x, 40).to(torch.float64) * (1.0 / (1 << 24))


# --------------------------------------------------------------------------- one view
@dataclass
class _ViewRays:
    """The rays of one view in one query, and what turns their hits into the silhouette."""

    camera: Camera
    edge_pixels: torch.Tensor  # [Pe] flat pixel indices with spp rays each
    labels: Optional[torch.Tensor]  # [H*W] component of each non-edge pixel (-1: edge pixel)
    n_components: int
    spp: int
    # edge points (for the gradient)
    sample_edge: torch.Tensor  # [N] index into the view's candidate list
    sample_t: torch.Tensor  # [N] position along the projected segment (0..1)
    sample_pixel: torch.Tensor  # [N] flat pixel index (-1: outside the window)
    candidates: torch.Tensor  # [Ec] edge indices (into MeshEdges.edges)
    normals: torch.Tensor  # [Ec, 2] unit outward normal of each projected segment (window px)
    step: float  # image length per edge point (px)
    n_rays: int = 0
    touched: Optional[torch.Tensor] = None  # [H, W] pixels some ray of the view passes through


def _project(points: torch.Tensor, cam: Camera) -> torch.Tensor:
    z = points[..., 2]
    return torch.stack([cam.fx * points[..., 0] / z + cam.cx, cam.fy * points[..., 1] / z + cam.cy], -1)


def _boxes_touch(vc: torch.Tensor, faces: torch.Tensor, cam: Camera, mask: torch.Tensor) -> torch.Tensor:
    """Per face: whether its projected bounding box holds a pixel of ``mask [H, W]`` (any
    face with a corner near or behind the camera counts)."""
    H, W = mask.shape
    z = vc[:, 2]
    uv = _project(vc, cam)
    c = uv[faces]  # [F, 3, 2]
    lo = torch.floor(c.min(1).values + 0.5)
    hi = torch.floor(c.max(1).values + 0.5)
    x0, y0 = lo[:, 0].clamp(0, W - 1).to(torch.int64), lo[:, 1].clamp(0, H - 1).to(torch.int64)
    x1, y1 = hi[:, 0].clamp(0, W - 1).to(torch.int64), hi[:, 1].clamp(0, H - 1).to(torch.int64)
    sat = torch.zeros(H + 1, W + 1, dtype=torch.int64)
    sat[1:, 1:] = mask.to(torch.int64).cumsum(0).cumsum(1)
    count = sat[y1 + 1, x1 + 1] - sat[y0, x1 + 1] - sat[y1 + 1, x0] + sat[y0, x0]
    inside = (hi[:, 0] >= 0) & (lo[:, 0] <= W - 1) & (hi[:, 1] >= 0) & (lo[:, 1] <= H - 1)
    near = (z[faces] <= _NEAR).any(1)
    return near | (inside & (count > 0))


def _dilate(mask: torch.Tensor) -> torch.Tensor:
    """``mask [H, W]`` (bool) dilated by the 3x3 square (zero padding): the same bits as a
    3x3 max-pool, with two separable passes of boolean slices."""
    rows = mask.clone()
    rows[1:] |= mask[:-1]
    rows[:-1] |= mask[1:]
    out = rows.clone()
    out[:, 1:] |= rows[:, :-1]
    out[:, :-1] |= rows[:, 1:]
    return out


def _directions(xy: torch.Tensor, cam: Camera) -> torch.Tensor:
    """Camera-frame unit directions of the rays through image points ``xy [N, 2]`` (float64)."""
    d = torch.stack([(xy[:, 0] - cam.cx) / cam.fx, (xy[:, 1] - cam.cy) / cam.fy, torch.ones_like(xy[:, 0])], -1)
    return d / d.norm(dim=-1, keepdim=True)


class RaycastScene:
    """One Mitsuba scene holding a mesh of fixed topology (module docstring)."""

    #: the edge integral's vertex gradient from the projection's Jacobian at the used endpoints (``False``: torch's
    #: autograd through the projection of every vertex, before issue 24's runtime part; the same gradients, bit for
    #: bit in the fits measured)
    analytic_grad = True

    def __init__(self, mi, dr, faces: np.ndarray, n_vertices: int, cull: bool = True):
        self.mi, self.dr = mi, dr
        self.cull = bool(cull)
        self.edges = MeshEdges(faces)
        self.n_vertices = int(n_vertices)
        self.lock = threading.RLock()
        mesh = mi.Mesh("body", int(n_vertices), faces.shape[0], has_vertex_normals=False)
        mp = mi.traverse(mesh)
        mp["faces"] = mi.UInt32(np.ascontiguousarray(faces, dtype=np.uint32).reshape(-1))
        mp["vertex_positions"] = dr.zeros(mi.Float, 3 * int(n_vertices))
        mp.update()
        self.scene = mi.load_dict({"type": "scene", "body": mesh})
        self.params = mi.traverse(self.scene)
        self.params.keep(["body.vertex_positions", "body.faces"])
        self.closed = bool((self.edges.face_b >= 0).all())
        self._held: Optional[tuple] = None

    # ---- the acceleration structure
    def set_vertices(self, verts: torch.Tensor, faces: Optional[torch.Tensor] = None) -> None:
        """Put ``verts [V, 3]`` (the frame the rays are given in) and the face subset
        ``faces`` (indices; ``None``: all) into the scene: one acceleration-structure build."""
        v = verts.detach().to(torch.float32).contiguous()
        held = self._held
        if (
            held is not None
            and torch.equal(held[0], v)
            and (
                (faces is None and held[1] is None)
                or (faces is not None and held[1] is not None and torch.equal(held[1], faces))
            )
        ):
            return
        if faces is not None or (held is not None and held[1] is not None):
            f = self.edges.faces if faces is None else self.edges.faces[faces]
            self.params["body.faces"] = self.mi.UInt32(f.to(torch.int32).reshape(-1).contiguous())
        self.params["body.vertex_positions"] = self.mi.Float(v.reshape(-1))
        self.params.update()
        self._held = (v.clone(), None if faces is None else faces.clone())

    def visible_faces(self, towards: Sequence[tuple], touched: Sequence[tuple] = ()) -> Optional[torch.Tensor]:
        """Indices of the faces some ray of the call can meet first, or ``None`` (all): a ray
        from outside a closed, consistently oriented mesh meets a face turned towards it
        first (``towards``: per camera, :meth:`_facing`'s values; nearly edge-on faces are
        kept), and a ray through pixel ``p`` only meets faces whose image covers ``p``
        (``touched``: per camera ``(vertices in its frame, camera, [H, W] pixels its rays
        pass through)``; a face's bounding box is tested)."""
        if not self.closed or not self.cull:
            return None
        f = self.edges.faces
        keep = torch.zeros(f.shape[0], dtype=torch.bool)
        for i, (d, scale) in enumerate(towards):
            front = torch.nonzero(d < 1e-3 * scale).squeeze(1)
            if i < len(touched):  # the boxes of the faces turned towards the camera only
                vc, cam, mask = touched[i]
                front = front[_boxes_touch(vc, f[front], cam, mask)]
            keep[front] = True
        if bool(keep.all()):
            return None
        return torch.nonzero(keep).squeeze(1)

    def _facing(self, vc: torch.Tensor) -> tuple:
        """``(d, scale)`` per face for vertices in a camera's frame: ``d < 0`` where the face
        turns its outer side to the camera (orientation from the signed volume), ``scale =
        |n| |a|`` (for the edge-on tolerance)."""
        f = self.edges.faces
        a, b, c = vc[f[:, 0]], vc[f[:, 1]], vc[f[:, 2]]
        n = torch.linalg.cross(b - a, c - a)
        d = (n * a).sum(-1)
        if float(d.sum()) < 0:  # 6 x signed volume < 0: faces wound inwards
            d = -d
        return d, n.norm(dim=-1) * a.norm(dim=-1)

    def ray_test(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """Whether each ray ``origins [N, 3] + s directions [N, 3]`` (s > 0) hits the mesh."""
        if origins.shape[0] == 0:
            return torch.zeros(0, dtype=torch.bool)
        mi = self.mi
        o = origins.to(torch.float32).contiguous()
        d = directions.to(torch.float32).contiguous()
        ray = mi.Ray3f(
            mi.Point3f(mi.Float(o[:, 0]), mi.Float(o[:, 1]), mi.Float(o[:, 2])),
            mi.Vector3f(mi.Float(d[:, 0]), mi.Float(d[:, 1]), mi.Float(d[:, 2])),
        )
        hit = self.scene.ray_test(ray)
        return mi.Int32(hit).torch().to(torch.bool)

    # ---- rendering
    def render(
        self,
        verts: torch.Tensor,
        views: Sequence[tuple],
        spp: int,
        edge_spp: int,
        seeds: Sequence[int],
        stratified: bool,
        need_grad: bool,
        systematic: bool = True,
        edge_density: Optional[float] = None,
    ):
        """Silhouettes of ``verts [V, 3]`` seen by ``views`` (``(camera, R [3,3], t [3])``:
        camera-frame points are ``R x + t``); returns ``(images, states)`` where each
        state holds what the view's backward pass needs (``None`` without ``need_grad``)."""
        with torch.no_grad():
            v64 = verts.detach().to(torch.float64)
            vcs = [v64 @ R.to(torch.float64).T + t.to(torch.float64) for _, R, t in views]
            towards = [self._facing(vc) for vc in vcs]
            plans, origins, directions = [], [], []
            for (cam, R, t), seed, vc, (d, _) in zip(views, seeds, vcs, towards):
                R64, t64 = R.to(torch.float64), t.to(torch.float64)
                plan, xy_cam = self._plan(
                    vc, d < 0, cam, spp, edge_spp, int(seed), stratified, need_grad, systematic, edge_density
                )
                centre = -(R64.T @ t64)
                d = _directions(xy_cam, cam)
                if not torch.equal(R64, _EYE):  # camera -> reference frame: R^T d (the identity: d, bit for bit)
                    d = d @ R64
                plans.append(plan)
                origins.append(centre.expand(d.shape[0], 3))
                directions.append(d)
            self.set_vertices(
                verts, self.visible_faces(towards, [(vc, p.camera, p.touched) for vc, p in zip(vcs, plans)])
            )
            hits = self.ray_test(torch.cat(origins), torch.cat(directions))
            images, states, start = [], [], 0
            for plan in plans:
                h = hits[start : start + plan.n_rays]
                start += plan.n_rays
                img, state = self._finish(plan, h, need_grad)
                images.append(img)
                states.append(state)
        return images, states

    def _plan(
        self, vc, facing, cam: Camera, spp, edge_spp, seed, stratified, need_grad, systematic=True, edge_density=None
    ):
        W, H = cam.width, cam.height
        idx, u0, seg, length, normal = _candidate_segments(self.edges, vc, facing, cam)
        marked = _edge_pixel_mask(u0, seg, length, W, H)
        edge_pixels = torch.nonzero(marked).squeeze(1)
        labels, n_comp, reps = self._components(marked, W, H)

        # ---- coverage rays: spp per edge pixel, one per component
        ys, xs = (edge_pixels // W).to(torch.float64), (edge_pixels % W).to(torch.float64)
        n_e = edge_pixels.numel()
        sample_ids = (edge_pixels[:, None] * spp + torch.arange(spp)[None, :]).reshape(-1)
        ju, jv = hash_uniform(seed, 1, sample_ids), hash_uniform(seed, 2, sample_ids)
        m = int(round(math.sqrt(spp)))
        if stratified and m * m == spp:
            k = torch.arange(spp).repeat(n_e)
            ju, jv = ((k % m).to(torch.float64) + ju) / m, ((k // m).to(torch.float64) + jv) / m
        cover_xy = torch.stack([xs.repeat_interleave(spp) + ju - 0.5, ys.repeat_interleave(spp) + jv - 0.5], -1)
        rep_xy = torch.stack([(reps % W).to(torch.float64), (reps // W).to(torch.float64)], -1)

        # ---- edge points (gradient only)
        if need_grad and idx.numel():
            e, t, pixel, edge_xy, step = _edge_points(
                u0, seg, length, normal, W, H, seed, edge_spp, systematic, edge_density
            )
        else:
            e = t = pixel = torch.zeros(0, dtype=torch.int64)
            edge_xy = torch.zeros(0, 2, dtype=torch.float64)
            step = 0.0
        xy = torch.cat([cover_xy, rep_xy, edge_xy])
        plan = _ViewRays(cam, edge_pixels, labels, n_comp, spp, e, t, pixel, idx, normal, step, xy.shape[0])
        touched = marked.clone()
        touched[reps] = True
        plan.touched = touched.reshape(H, W)
        return plan, xy

    @staticmethod
    def _components(marked: torch.Tensor, W: int, H: int):
        """4-connected components of the pixels that are not edge pixels: labels per pixel
        (``-1`` on edge pixels), their count and one pixel of each (flat indices)."""
        free = (~marked).reshape(H, W).numpy().astype(np.uint8)
        n, lab = cv2.connectedComponents(free, connectivity=4, ltype=cv2.CV_32S)
        lab = torch.as_tensor(lab.reshape(-1).astype(np.int64)) - 1  # edge pixels -> -1
        if n <= 1:
            return lab, 0, torch.zeros(0, dtype=torch.int64)
        free = lab >= 0
        # each component's representative: its first pixel next to an edge pixel (so the rays of
        # a view only meet faces whose image touches the edge pixels or their one-pixel ring),
        # else its first pixel
        ring = torch.nonzero(_dilate(marked.reshape(H, W)).reshape(-1) & free).squeeze(1)  # flat indices, ascending
        reps = torch.full((n - 1,), H * W, dtype=torch.int64)
        reps.scatter_reduce_(0, lab[ring], ring, reduce="amin")
        lonely = reps == H * W
        if bool(lonely.any()):
            first = torch.full((n - 1,), H * W, dtype=torch.int64)
            pix = torch.nonzero(free).squeeze(1)
            first.scatter_reduce_(0, lab[pix], pix, reduce="amin")
            reps = torch.where(lonely, first, reps)
        return lab, n - 1, reps

    def _finish(self, plan: _ViewRays, hits: torch.Tensor, need_grad: bool):
        cam = plan.camera
        n_cover = plan.edge_pixels.numel() * plan.spp
        cover, rep, edge = (
            hits[:n_cover],
            hits[n_cover : n_cover + plan.n_components],
            hits[n_cover + plan.n_components :],
        )
        if (
            plan.n_components
        ):  # each pixel off the edge pixels takes its component's ray (an edge pixel: 0, then its own)
            img = torch.cat([torch.zeros(1, dtype=torch.float32), rep.to(torch.float32)])[plan.labels + 1]
        else:
            img = torch.zeros(cam.height * cam.width, dtype=torch.float32)
        if n_cover:
            img[plan.edge_pixels] = cover.reshape(-1, plan.spp).to(torch.float32).mean(1)
        img = img.reshape(cam.height, cam.width)
        if not need_grad:
            return img, None
        outline = torch.nonzero(~edge).squeeze(1)  # the ray just outside the segment misses: the outline there
        state = {
            "edge": plan.sample_edge[outline],
            "t": plan.sample_t[outline],
            "pixel": plan.sample_pixel[outline],
            "candidates": plan.candidates,
            "normals": plan.normals,
            "step": plan.step,
            "camera": cam,
        }
        return img, state

    # ---- gradient
    def vertex_grad(
        self, verts: torch.Tensor, R: torch.Tensor, t: torch.Tensor, state: dict, grad_img: torch.Tensor
    ) -> torch.Tensor:
        """``d sum(grad_img * S) / d verts`` of one view (the edge integral, module docstring)."""
        g = grad_img.detach().to(torch.float64).reshape(-1)
        out = torch.zeros(verts.shape, dtype=torch.float64)
        if state["edge"].numel() == 0:
            return out
        w = g[state["pixel"]] * state["step"]
        n_c = state["candidates"].numel()
        t_s = state["t"]
        n_s = state["normals"][state["edge"]]
        G0 = torch.zeros(n_c, 2, dtype=torch.float64).index_add_(0, state["edge"], (w * (1 - t_s))[:, None] * n_s)
        G1 = torch.zeros(n_c, 2, dtype=torch.float64).index_add_(0, state["edge"], (w * t_s)[:, None] * n_s)
        used = torch.unique(state["edge"])
        ends = self.edges.edges[state["candidates"][used]]  # [U, 2] vertex indices
        R64 = R.to(torch.float64)
        if not self.analytic_grad:  # torch's autograd through the projection (before issue 24's runtime part)
            with torch.enable_grad():
                x = verts.detach().to(torch.float64).requires_grad_(True)
                vc = x @ R64.T + t.to(torch.float64)
                cam = state["camera"]
                s = (_project(vc[ends[:, 0]], cam) * G0[used]).sum() + (_project(vc[ends[:, 1]], cam) * G1[used]).sum()
                (grad,) = torch.autograd.grad(s, x)
            return grad
        # the projection's Jacobian at the used endpoints only: d(G . proj(p)) / dp for p = R x + t
        cam = state["camera"]
        ends = ends.T.reshape(-1)  # [2U]: first endpoints, then second ones
        G = torch.cat([G0[used], G1[used]])  # [2U, 2]
        vc = verts.detach().to(torch.float64)[ends] @ R64.T + t.to(torch.float64)
        inv_z = 1.0 / vc[:, 2]
        gx, gy = G[:, 0] * cam.fx * inv_z, G[:, 1] * cam.fy * inv_z
        d_vc = torch.stack([gx, gy, -(gx * vc[:, 0] + gy * vc[:, 1]) * inv_z], -1)  # [2U, 3]
        return out.index_add_(0, ends, d_vc @ R64)


class RaycastRender(torch.autograd.Function):
    """``images = render(verts)`` for several views of one vertex set; the gradient is the
    edge integral of each view (:meth:`RaycastScene.vertex_grad`)."""

    @staticmethod
    def forward(ctx, verts, scene, views, states, *images):
        ctx.scene, ctx.views, ctx.states = scene, views, states
        ctx.save_for_backward(verts)
        images = tuple(img.clone() for img in images)
        return images if len(images) > 1 else images[0]

    @staticmethod
    def backward(ctx, *grads):
        (verts,) = ctx.saved_tensors
        total = torch.zeros(verts.shape, dtype=torch.float64)
        for (cam, R, t), state, g in zip(ctx.views, ctx.states, grads):
            if g is None or state is None:
                continue
            total += ctx.scene.vertex_grad(verts, R, t, state, g)
        return (total.to(dtype=verts.dtype, device=verts.device), None, None, None) + (None,) * len(grads)


def render_views(
    scene: RaycastScene,
    verts: torch.Tensor,
    views: Sequence[tuple],
    spp: int,
    edge_spp: int,
    seeds: Sequence[int],
    stratified: bool,
    systematic: bool = True,
    edge_density: Optional[float] = None,
) -> List[torch.Tensor]:
    """Silhouettes ``[H, W]`` (float32) of ``verts [V, 3]`` in each view ``(camera, R, t)``,
    differentiable with respect to ``verts`` when it requires grad.  ``edge_density``: edge
    points per pixel of contour-candidate length (``None``: ``edge_spp`` per image pixel);
    it changes the gradient's noise only, never the image."""
    if edge_density is not None and not (float(edge_density) > 0 and math.isfinite(float(edge_density))):
        raise ValueError(f"edge_density must be a positive number or None, got {edge_density!r}")
    need_grad = torch.is_grad_enabled() and verts.requires_grad
    with scene.lock:
        images, states = scene.render(
            verts, views, spp, edge_spp, seeds, stratified, need_grad, systematic, edge_density
        )
    if not need_grad:
        return images
    out = RaycastRender.apply(verts, scene, list(views), states, *images)
    return list(out) if isinstance(out, tuple) else [out]


def _candidate_segments(E, vc, facing, cam: Camera):
    """The silhouette's candidate edges (faces facing opposite ways, or a boundary), in front of the camera and
    not degenerate on screen: their indices, projected first endpoints, screen segments, lengths and the
    normals pointing away from their faces (only their endpoints gathered: a few hundred of the mesh's edges)."""
    idx = torch.nonzero((E.face_b < 0) | (facing[E.face_a] != facing[E.face_b.clamp(min=0)])).squeeze(1)
    p0, p1, q = vc[E.edges[idx, 0]], vc[E.edges[idx, 1]], vc[E.opposite_a[idx]]
    front = torch.nonzero((p0[:, 2] > _NEAR) & (p1[:, 2] > _NEAR) & (q[:, 2] > _NEAR)).squeeze(1)
    idx, p0, p1, q = idx[front], p0[front], p1[front], q[front]
    u0, u1, uq = _project(p0, cam), _project(p1, cam), _project(q, cam)
    seg = u1 - u0
    length = seg.norm(dim=-1)
    keep = torch.nonzero(length > 1e-9).squeeze(1)
    idx, u0, u1, uq, seg, length = idx[keep], u0[keep], u1[keep], uq[keep], seg[keep], length[keep]
    normal = torch.stack([-seg[:, 1], seg[:, 0]], -1) / length[:, None]
    side = ((uq - u0) * normal).sum(-1)
    normal = torch.where((side > 0)[:, None], -normal, normal)  # away from the faces
    return idx, u0, seg, length, normal


def _edge_pixel_mask(u0, seg, length, W: int, H: int) -> torch.Tensor:
    """The edge pixels, flat ``[H * W]`` booleans: every pixel a candidate segment touches, dilated by one."""
    marked = torch.zeros(H * W, dtype=torch.bool)
    if length.numel():
        counts = (length / _MARK_SPACING).ceil().to(torch.int64) + 1
        seg_of = torch.repeat_interleave(torch.arange(length.numel()), counts)
        first = torch.cumsum(counts, 0) - counts
        k = torch.arange(seg_of.numel()) - first[seg_of]
        tt = k.to(torch.float64) / (counts[seg_of] - 1).clamp(min=1).to(torch.float64)
        pts = u0[seg_of] + tt[:, None] * seg[seg_of]
        px = torch.floor(pts + 0.5).to(torch.int64)
        inside = (px[:, 0] >= -1) & (px[:, 0] <= W) & (px[:, 1] >= -1) & (px[:, 1] <= H)
        px = px[inside]
        grid = torch.zeros(H + 2, W + 2, dtype=torch.bool)
        grid[px[:, 1] + 1, px[:, 0] + 1] = True
        marked = _dilate(grid)[1:-1, 1:-1].reshape(-1)
    return marked


def _edge_points(u0, seg, length, normal, W: int, H: int, seed, edge_spp, systematic, edge_density):
    """The gradient's edge points along the candidate segments (at least one segment): their segment ``e``,
    position ``t`` on it, image pixel, screen position (nudged off the edge, away from the faces) and the length
    of segment one point stands for."""
    total = float(length.sum())
    if edge_density is None:  # a count per image pixel (before issue 24's speed part)
        N = int(edge_spp) * W * H
    else:  # a density along the candidate segments, never more points than the count per pixel
        N = max(1, min(math.ceil(float(edge_density) * total), int(edge_spp) * W * H))
    cum = torch.cumsum(length, 0)
    if systematic:  # evenly spaced, one random offset
        s = (torch.arange(N, dtype=torch.float64) + float(hash_uniform(seed, 3, torch.zeros(1, dtype=torch.int64)))) * (
            total / N
        )
    else:  # independent uniform positions
        s = hash_uniform(seed, 4, torch.arange(N)) * total
    e = torch.searchsorted(cum, s, right=True).clamp(max=length.numel() - 1)
    t = ((s - (cum[e] - length[e])) / length[e]).clamp(0.0, 1.0)
    pts = u0[e] + t[:, None] * seg[e]
    px = torch.floor(pts + 0.5).to(torch.int64)
    inside = torch.nonzero((px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)).squeeze(1)
    e, t, pts, px = e[inside], t[inside], pts[inside], px[inside]
    pixel = px[:, 1] * W + px[:, 0]
    return e, t, pixel, pts + _EDGE_EPS * normal[e], total / N
