"""Interpenetration penalty on spheres that sit inside the body surface.

The spheres are derived once per body model (any SMPL-layout model), on the rest mesh of
the mean shape, so that parts whose surfaces only touch pay nothing and parts pushed into
each other pay about the square of the depth:

* **inscribed balls**: at every vertex the largest ball that touches it from inside and
  holds no other vertex (shrinking-ball medial axis, :func:`shrinking_balls`); a sparse
  cover is kept per part (largest first, a ball dropped when its centre lies within the
  radius of a kept one; balls under ``relative_radius`` x the part's largest dropped);
* a ball belongs to the part with the largest mean skinning weight over its
  ``neighbours`` nearest vertices, moves with the skinning transforms blended by those
  mean weights, and its radius is the distance from its centre to the nearest of those
  vertices, minus ``margin``: centres and vertices are linear in ``betas`` (precomputed
  blend-shape means), so the spheres follow the shape;
* **calibration**: on the pose library and a few deep-flexion poses
  (:func:`calibration_poses`), each ball is posed and shrunk until no vertex of its own
  part(s) enters it, so the skinned surface does not cut it near a joint;
* two balls are tested only if the joints that carry them (mean weight above ``support``)
  are at least ``min_tree_distance`` apart in the kinematic tree, and they do not already
  touch at the rest pose. Energy per sample: ``sum relu(r_a + r_b - |c_a - c_b|)^2``
  (metres^2), whose gradient pushes overlapping parts apart.

On the open body model poses whose surfaces touch (arms hanging against the sides, a hand
on the head, hands resting on the thighs, arms crossed) cost 0, and a limb pushed through
another costs about the square of the depth (``benchmarks/bench_interpenetration.py``; the
numbers, against the former surface-sized spheres: docs/benchmarks/defaults.md).

**Cost.** Most rows of a fit have no overlapping pair, and an overlapping row a few dozen. So
:meth:`SphereCollisionModel.forward` poses every sphere *without* a gradient (each radius's nearest
neighbour found by accumulating the shape directions one at a time; all pairwise distances), keeps
the overlapping tested pairs, and forms only those pairs' spheres again with the gradient. The
value and gradient are the dense definition's (a test checks both against it in float64). Forward
and backward cost less than the dense evaluation (every pair and every neighbour with the gradient),
and the keypoint stage runs faster (``bench_interpenetration.py``, ``--module`` on the previous file;
the timings: docs/benchmarks/defaults.md). A row's value does
not depend on the batch (the pairs' squared overlaps are summed with ``index_add``, one after another).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Dict, Optional

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from ..body import lbs, model as body_model
from ..body.lbs import (
    axis_angle_to_matrix,
    blend_shapes,
    forward_kinematics,
    padded_nonzeros,
    per_row,
    pose_correctives,
    skin_vertices,
    sqrt,
    vertices_to_joints,
)
from ..poses.library import POSE_LIBRARY, arm, build_pose, elbow, knee, leg, mirror_pose, trunk

__all__ = ["SphereCollisionModel", "tree_distances", "vertex_normals"]


def tree_distances(parents) -> np.ndarray:
    """``[J, J]`` number of bones between two joints of the kinematic tree ``parents``."""
    J = len(parents)
    adj = [[] for _ in range(J)]
    for j, p in enumerate(parents):
        if p >= 0:
            adj[j].append(p)
            adj[p].append(j)
    dist = np.full((J, J), J + 1, dtype=np.int64)
    for s in range(J):
        dist[s, s] = 0
        frontier = [s]
        while frontier:
            nxt = []
            for a in frontier:
                for b in adj[a]:
                    if dist[s, b] > dist[s, a] + 1:
                        dist[s, b] = dist[s, a] + 1
                        nxt.append(b)
            frontier = nxt
    return dist


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals ``[V, 3]`` (outward for an outward-wound mesh)."""
    v = np.asarray(vertices, dtype=np.float64)
    n = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, faces[:, k], n)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)


def shrinking_balls(vertices: np.ndarray, normals: np.ndarray, max_radius: float = 0.2, iters: int = 30):
    """Maximal inscribed ball touching each vertex (the shrinking-ball medial-axis method):
    ``(centres [V, 3], radii [V])``; a ball centred ``r`` behind the vertex along its
    inward normal, shrunk until no other vertex lies inside it."""
    tree = cKDTree(vertices)
    V = len(vertices)
    r = np.full(V, float(max_radius))
    ids = np.arange(V)
    active = ids
    for _ in range(iters):
        c = vertices[active] - r[active, None] * normals[active]
        d, q = tree.query(c, k=2)
        # The nearest vertex other than the touching one.
        other = np.where(q[:, 0] == active, q[:, 1], q[:, 0])
        dist = np.where(q[:, 0] == active, d[:, 1], d[:, 0])
        shrink = dist < r[active] * (1 - 1e-6)
        if not shrink.any():
            break
        a = active[shrink]
        dv = vertices[a] - vertices[other[shrink]]
        along = (dv * normals[a]).sum(1)
        r_new = np.where(along > 1e-9, (dv * dv).sum(1) / (2 * np.maximum(along, 1e-9)), 0.0)
        r[a] = np.minimum(r[a], r_new)
        active = a
    return vertices - r[:, None] * normals, r


def _select_balls(centres, radii, label, min_radius: float, relative_radius: float, spacing: float):
    """Indices of a sparse cover of the medial balls: per label, balls of radius at least
    ``min_radius`` and ``relative_radius`` x the label's largest, largest first, a ball
    kept unless its centre lies within ``spacing`` x (its or a kept ball's radius) of a
    kept ball's centre."""
    keep = []
    for j in np.unique(label):
        own = label == j
        floor = max(min_radius, relative_radius * radii[own].max())
        cand = np.flatnonzero(own & (radii >= floor))
        cand = cand[np.argsort(-radii[cand], kind="stable")]
        chosen = []
        for i in cand:
            if chosen:
                d = np.linalg.norm(centres[chosen] - centres[i], axis=1)
                if (d < spacing * np.maximum(radii[chosen], radii[i])).any():
                    continue
            chosen.append(i)
        keep += chosen
    return np.asarray(sorted(keep), dtype=np.int64)


def _nearest(points: np.ndarray, vertices: np.ndarray, k: int):
    """``(indices [Q, k], distances [Q, k])`` of the ``k`` vertices nearest each point."""
    d, i = cKDTree(vertices).query(points, k=k)
    return i, d


def calibration_poses() -> np.ndarray:
    """``[P, 69]`` poses the spheres are checked on at construction: the pose library and
    its mirror images, plus deep flexion of every limb (knees, hips with knees, elbows,
    arms down / across / overhead, trunk bent)."""
    lib = [p.body_pose for p in POSE_LIBRARY.values()]
    spine = lambda f: {f"spine{i}": trunk(f / 3) for i in (1, 2, 3)}  # noqa: E731
    extremes = [
        {
            "left_hip": leg("L", flex=130, abd=15),
            "left_knee": knee(150),
            "right_hip": leg("R", flex=-40),
            "right_knee": knee(150),
        },
        {"left_hip": leg("L", flex=100, abd=-20), "right_hip": leg("R", flex=100, abd=-20), **spine(70)},
        {
            "left_shoulder": arm("L", (0.05, -1, 0)),
            "left_elbow": elbow("L", 150),
            "right_shoulder": arm("R", (0.3, -0.2, 1), internal=60),
            "right_elbow": elbow("R", 150),
        },
        {
            "left_shoulder": arm("L", (0.1, 1, 0.1)),
            "left_elbow": elbow("L", 150),
            "right_shoulder": arm("R", (0.05, -1, -0.3), internal=-40),
            "right_elbow": elbow("R", 120),
            **spine(-40),
        },
    ]
    poses = lib + [build_pose(e) for e in extremes]
    return np.stack(poses + [mirror_pose(p) for p in poses])


def _mean_shape_posed(model, body_pose: torch.Tensor, chunk: int = 16) -> tuple:
    """``(vertices [P, V, 3], transforms [P, J, 4, 4])`` of the mean shape in ``body_pose [P, 69]``, float64,
    without BLAS (``blas=False``: :mod:`silfit.body.lbs`, "No BLAS"): MKL's GEMMs round the skinned
    vertices otherwise on an Intel Xeon with AVX-512 than on an AMD EPYC, which changed the spheres' radius
    scales in their last bits and so a float64 keypoint fit (docs/benchmarks/defaults.md)."""
    v = model.v_template.double()[None]
    joints = vertices_to_joints(model.J_regressor.double(), v)
    full = torch.cat([torch.zeros(len(body_pose), 3, dtype=torch.float64), body_pose], 1)
    # a whole-body model: SMPL's first 21 joints are its body, the rest (jaw, eyes, fingers) at rest
    full = torch.cat(
        [full[:, : 3 * model.num_joints], full.new_zeros(len(full), max(0, 3 * model.num_joints - full.shape[1]))], 1
    )
    rot = axis_angle_to_matrix(full.reshape(len(body_pose), -1, 3))
    _, T = forward_kinematics(rot, joints.expand(len(body_pose), -1, -1), model.parents, model._levels)
    weights = model.lbs_weights.double()
    posedirs = None if model.posedirs is None else model.posedirs.double()
    verts = []
    for s in range(0, len(body_pose), chunk):
        vp = v if posedirs is None else v + pose_correctives(rot[s : s + chunk], posedirs, blas=False)
        verts.append(skin_vertices(vp.expand(len(rot[s : s + chunk]), -1, -1), T[s : s + chunk], weights, blas=False))
    return torch.cat(verts), T


def _supports(weights: np.ndarray, threshold: float) -> np.ndarray:
    """``bool [S, J]``: the joints with mean skinning weight above ``threshold`` (and the largest)."""
    sup = weights > threshold
    sup[np.arange(len(weights)), weights.argmax(1)] = True
    return sup


def _set_distance(sup: np.ndarray, tree: np.ndarray) -> np.ndarray:
    """``[S, S]`` smallest tree distance between the support joints of two spheres."""
    big = tree.max() + 1
    d = np.full((len(sup), len(sup)), big)
    for j in range(tree.shape[0]):
        for k in range(tree.shape[0]):
            m = sup[:, j][:, None] & sup[:, k][None, :]
            d[m] = np.minimum(d[m], tree[j, k])
    return d


def _posed_scale(model, centres, radii, weights, own, chunk: int = 16) -> np.ndarray:
    """Per sphere, ``min(1, min over the calibration poses of the distance from its posed
    centre to its own surface (the vertices of the parts it is not tested against) / its
    rest radius)``: a sphere that the skinned surface around it would cut in some pose
    (near a joint) is shrunk to stay inside. The calibration poses are not mirrored; the
    scale is made symmetric by taking the smaller of a sphere's and its mirror image's."""
    poses = torch.as_tensor(calibration_poses(), dtype=torch.float64)[:, : model.num_body_pose]
    dt = model.dtype
    c, w = torch.as_tensor(centres, dtype=dt), torch.as_tensor(weights, dtype=dt)
    with torch.no_grad():
        verts, T = (t.to(dt) for t in _mean_shape_posed(model, poses, chunk))
        # broadcast products, not GEMMs (silfit.body.lbs, "No BLAS")
        R = per_row(lambda m: (w[None, :, :, None, None] * m[:, None]).sum(2), T[..., :3, :3])
        t = per_row(lambda m: (w[None, :, :, None] * m[:, None]).sum(2), T[..., :3, 3])
        pc = (R * c[:, None, :]).sum(-1) + t  # [P, S, 3]
        best = torch.empty(len(centres), dtype=dt)
        # Spheres with the same own surface share one distance computation.
        _, group = np.unique(own, axis=0, return_inverse=True)
        for g in np.unique(group):
            members = torch.as_tensor(np.flatnonzero(group == g))
            vi = torch.as_tensor(np.flatnonzero(own[int(members[0])]))
            best[members] = (
                torch.cdist(pc[:, members], verts[:, vi], compute_mode="donot_use_mm_for_euclid_dist").amin(-1).amin(0)
            )
    scale = np.minimum(1.0, best.double().numpy() / np.maximum(radii, 1e-9))
    mirrored = centres * np.array([-1.0, 1.0, 1.0])
    partner, d = _nearest(mirrored, centres, 1)
    return np.where(d < 1e-3, np.minimum(scale, scale[partner]), scale)


def build_spheres(
    model,
    neighbours: int = 24,
    margin: float = 0.004,
    min_radius: float = 0.008,
    relative_radius: float = 0.4,
    spacing: float = 1.0,
    support: float = 0.1,
    min_tree_distance: int = 3,
    rest_margin: float = 0.0,
    own_distance: int = 0,
) -> dict:
    """The sphere set of a body model as numpy arrays (see the module docstring)."""
    v = model.v_template.detach().double().cpu().numpy()
    sd = model.shapedirs.detach().double().cpu().numpy()
    W = model.lbs_weights.detach().double().cpu().numpy()
    faces = model.faces.detach().cpu().numpy()
    centres, _ = shrinking_balls(v, vertex_normals(v, faces))
    nb, dist = _nearest(centres, v, neighbours)
    # Each ball belongs to the part with the largest skinning weight around it.
    w = W[nb].mean(1)
    label = w.argmax(1)
    sel = _select_balls(centres, dist.min(1), label, min_radius + margin, relative_radius, spacing)
    centres, nb, w, part, rest_r = centres[sel], nb[sel], w[sel], label[sel], dist[sel].min(1)
    w = w / w.sum(1, keepdims=True)
    tree = tree_distances(model.parents)
    sup = _supports(w, support)
    # Its own surface: the vertices of its support joints' parts (and their tree neighbours up to `own_distance`).
    near = (tree[None] <= own_distance) & sup[:, :, None]  # [S, J, J]
    own = near.any(1)[:, W.argmax(1)]  # [S, V]
    scale = _posed_scale(model, centres, rest_r, w, own)
    radii = scale * rest_r - margin
    S = len(centres)
    far = _set_distance(sup, tree) >= min_tree_distance
    gap = np.linalg.norm(centres[:, None] - centres[None], axis=-1) - (radii[:, None] + radii[None, :])
    a, b = np.nonzero(far & np.triu(np.ones((S, S), dtype=bool), 1) & (gap > rest_margin))
    return {
        "centre_template": centres,
        "centre_dirs": sd[nb].mean(1),
        "neighbour_template": v[nb],
        "neighbour_dirs": sd[nb],
        "sphere_weights": w,
        "radius_scale": scale,
        "sphere_part": part,
        "pair_a": a,
        "pair_b": b,
    }


_CACHE: Dict[tuple, dict] = {}
#: the arrays :func:`build_spheres` returns (a cached file without one of them is rebuilt)
_SPHERE_ARRAYS = (
    "centre_template",
    "centre_dirs",
    "neighbour_template",
    "neighbour_dirs",
    "sphere_weights",
    "radius_scale",
    "sphere_part",
    "pair_a",
    "pair_b",
)


def sphere_cache_dir() -> Path:
    """Where sphere sets are cached on disk: ``$SILFIT_CACHE_DIR/spheres`` (default
    ``~/.cache/silfit/spheres``), beside the render proxies (:func:`silfit.render.proxy.proxy_cache_dir`)."""
    root = os.environ.get("SILFIT_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "silfit")
    return Path(root) / "spheres"


def _disk_key(key: tuple) -> str:
    """The cache file's name for the in-memory ``key``: also the code that builds the spheres (this
    module and the body model's, so any change to them rebuilds) and torch's version."""
    h = hashlib.blake2b(digest_size=16)
    h.update(repr((key, torch.__version__)).encode())
    for module in (__file__, lbs.__file__, body_model.__file__):
        h.update(Path(module).read_bytes())
    return h.hexdigest()


def _load_spheres(path: Path) -> Optional[dict]:
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: np.asarray(z[name]) for name in _SPHERE_ARRAYS}
    except Exception:  # noqa: BLE001 - any unreadable cache file (missing, truncated, ...) is rebuilt
        return None
    S = len(arrays["centre_template"])
    ok = all(
        len(arrays[n]) == S
        for n in (
            "centre_dirs",
            "neighbour_template",
            "neighbour_dirs",
            "sphere_weights",
            "radius_scale",
            "sphere_part",
        )
    ) and len(arrays["pair_a"]) == len(arrays["pair_b"])
    return arrays if ok else None


def _save_spheres(path: Path, arrays: dict) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(tmp, **{name: arrays[name] for name in _SPHERE_ARRAYS})
        os.replace(tmp, path)  # atomic: processes building the same set at once each write a whole file
    except OSError:
        pass  # the cache is an optimisation; a read-only home still works


def cached_spheres(model, margin: float = 0.004, disk_cache: bool = True, **settings) -> dict:
    """:func:`build_spheres` once per body model and settings: in memory, and on disk
    (:func:`sphere_cache_dir`; the arrays round-trip exactly, so a fit is the same bits either way).
    Building takes seconds (docs/benchmarks/defaults.md), once per process (each Ray actor, each
    ``silfit`` call) without the file."""
    key = _cache_key(model, margin, settings)
    if key not in _CACHE:
        path = sphere_cache_dir() / f"{_disk_key(key)}.npz" if disk_cache else None
        arrays = _load_spheres(path) if path is not None else None
        if arrays is None:
            arrays = build_spheres(model, margin=margin, **settings)
            if path is not None:
                _save_spheres(path, arrays)
        _CACHE[key] = arrays
    return _CACHE[key]


def _cache_key(model, margin: float = 0.004, settings: Optional[dict] = None) -> tuple:
    return (_model_key(model), float(margin), tuple(sorted((settings or {}).items())))


def _model_key(model) -> str:
    """A digest of the arrays the spheres are built from (the same model loaded twice hits the cache)."""
    h = hashlib.blake2b(digest_size=16)
    for name in ("v_template", "shapedirs", "lbs_weights", "J_regressor", "faces_tensor"):
        h.update(np.ascontiguousarray(getattr(model, name).detach().cpu().numpy()).tobytes())
    h.update(repr(tuple(model.parents)).encode())
    return h.hexdigest()


class SphereCollisionModel(nn.Module):
    """``SphereCollisionModel(model)(betas [B, L], transforms [B, J, 4, 4]) -> [B]``; see the
    module docstring. The sphere set is built once per body model (cached by content, in memory
    and on disk: :func:`cached_spheres`)."""

    def __init__(self, model, margin: float = 0.004, **settings):
        super().__init__()
        arrays = cached_spheres(model, margin, **settings)
        dtype = model.v_template.dtype
        for name, value in arrays.items():
            t = torch.as_tensor(np.ascontiguousarray(value))
            self.register_buffer(
                name, (t.long() if name in ("pair_a", "pair_b", "sphere_part") else t.to(dtype)).clone()
            )
        self.num_spheres = S = len(arrays["centre_template"])
        mask = torch.zeros(S, S, dtype=dtype)
        mask[self.pair_a, self.pair_b] = 1.0
        self.register_buffer("pair_mask", mask)
        self.margin = float(margin)
        # Derived from the arrays above (not saved in a state dict): the tested pairs as booleans; the radius's
        # offsets (neighbour vertex - centre), linear in the shape, rounded once from float64, also by shape direction.
        self.register_buffer("pair_tested", mask > 0, persistent=False)
        a = {name: np.asarray(arrays[name], dtype=np.float64) for name in _SPHERE_ARRAYS[:4]}
        offset_dirs = torch.as_tensor(a["neighbour_dirs"] - a["centre_dirs"][:, None]).to(dtype)
        self.register_buffer(
            "offset_template",
            torch.as_tensor(a["neighbour_template"] - a["centre_template"][:, None]).to(dtype),
            persistent=False,
        )
        self.register_buffer("offset_dirs", offset_dirs, persistent=False)  # [S, K, 3, L]
        self.register_buffer(
            "offset_dirs_by_beta", offset_dirs.permute(3, 0, 1, 2).contiguous(), persistent=False
        )  # [L, S, K, 3]
        # Each sphere's blend over the joints that carry it (2.6 of 24 on average; zero-padded to the most).
        carry_joint, carry_weight = padded_nonzeros(self.sphere_weights)
        self.register_buffer("carry_joint", carry_joint, persistent=False)
        self.register_buffer("carry_weight", carry_weight, persistent=False)

    def rest_spheres(self, betas: torch.Tensor, dtype: Optional[torch.dtype] = None):
        """Rest-pose centres ``[B, S, 3]`` and radii ``[B, S]`` for ``betas [B, L]``: a radius is
        ``radius_scale`` times the distance to the nearest of the sphere's neighbour vertices, minus
        the margin."""
        dtype = dtype or betas.dtype
        b = betas.to(dtype)
        c = self.centre_template.to(dtype) + blend_shapes(b, self.centre_dirs.to(dtype))
        return c, self._all_radii(b, self._nearest(b))

    def _nearest(self, b: torch.Tensor) -> torch.Tensor:
        """``[B, S]`` the index of each sphere's nearest neighbour vertex (no gradient): the offsets
        accumulated one shape direction at a time, elementwise (batch-invariant, and far faster than
        a product over the shape axis with 10 values innermost)."""
        with torch.no_grad():
            tmpl, dirs = self.offset_template.to(b.dtype), self.offset_dirs_by_beta.to(b.dtype)  # dirs [L, S, K, 3]
            off = tmpl.expand(b.shape[0], *tmpl.shape).clone()
            for i in range(min(b.shape[1], len(dirs))):
                off.addcmul_(b[:, i, None, None, None], dirs[i])
            return (off * off).sum(-1).argmin(-1)

    def _all_radii(self, b: torch.Tensor, nearest: torch.Tensor) -> torch.Tensor:
        """``[B, S]`` every sphere's radius, given ``nearest`` (:meth:`_nearest`)."""
        return self._radii(b, torch.arange(self.num_spheres, device=b.device).expand_as(nearest), nearest)

    def _radii(self, b: torch.Tensor, sphere: torch.Tensor, nearest: torch.Tensor) -> torch.Tensor:
        """Radii of spheres ``sphere [B, ...]`` (rows of ``b [B, L]``) with their nearest neighbours'
        indices ``nearest``, with the gradient (the minimum's is the nearest one's)."""
        tmpl, dirs = self.offset_template.to(b.dtype), self.offset_dirs.to(b.dtype)
        L = min(b.shape[1], dirs.shape[-1])
        lead = (slice(None),) + (None,) * (sphere.ndim - 1)
        near = tmpl[sphere, nearest] + (b[lead + (None, slice(0, L))] * dirs[sphere, nearest][..., :L]).sum(-1)
        return self.radius_scale.to(b.dtype)[sphere] * sqrt((near * near).sum(-1) + 1e-12) - self.margin

    def _posed_centres(
        self, b: torch.Tensor, transforms: torch.Tensor, sphere: Optional[torch.Tensor] = None
    ) -> torch.Tensor:
        """Posed centres (no translation) of every sphere, ``[B, S, 3]``, or of spheres
        ``sphere [B, ...]``, ``[B, ..., 3]``."""
        # Gathers from tensors that carry the gradient are index_select (backward: index_add, in order), not
        # advanced indexing, whose backward (index_put_ accumulating) adds in parallel with more than one thread.
        dt, (B, J) = transforms.dtype, transforms.shape[:2]
        T34 = transforms[:, :, :3, :]
        if sphere is None:
            c = self.centre_template.to(dt) + blend_shapes(b, self.centre_dirs.to(dt))
            S, k = self.carry_joint.shape
            Tk = T34.index_select(1, self.carry_joint.reshape(-1)).reshape(B, S, k, 3, 4)
            w = self.carry_weight.to(dt)
        else:
            L = min(b.shape[1], self.centre_dirs.shape[-1])
            lead = (slice(None),) + (None,) * (sphere.ndim - 1)
            c = self.centre_template.to(dt)[sphere] + (
                b[lead + (None, slice(0, L))] * self.centre_dirs.to(dt)[sphere][..., :L]
            ).sum(-1)
            at = torch.arange(B, device=b.device)[lead + (None,)] * J + self.carry_joint[sphere]  # [B, ..., k]
            Tk = T34.reshape(B * J, 3, 4).index_select(0, at.reshape(-1)).reshape(*at.shape, 3, 4)
            w = self.carry_weight.to(dt)[sphere]
        # the sphere's transform blended over the joints that carry it, as a product and a sum (body.lbs)
        Tw = (w[..., None, None] * Tk).sum(-3)
        return (Tw[..., :3] * c[..., None, :]).sum(-1) + Tw[..., 3]

    def posed_spheres(self, betas: torch.Tensor, transforms: torch.Tensor, transl: Optional[torch.Tensor] = None):
        """Posed centres and radii given the skinning transforms ``[B, J, 4, 4]``
        (rest point -> posed point) of :func:`silfit.body.lbs.forward_kinematics`."""
        b = betas.to(transforms.dtype)
        posed = self._posed_centres(b, transforms)
        if transl is not None:
            posed = posed + transl[:, None]
        return posed, self._all_radii(b, self._nearest(b))

    def overlapping_pairs(self, centres: torch.Tensor, radii: torch.Tensor) -> tuple:
        """``(row, a, b)``: the tested pairs whose spheres overlap, in order (row, then ``a``, ``b``)."""
        with torch.no_grad():
            d = torch.cdist(centres, centres, compute_mode="donot_use_mm_for_euclid_dist")
            hit = ((radii[:, :, None] + radii[:, None, :]) > d) & self.pair_tested
            return hit.nonzero(as_tuple=True)

    @staticmethod
    def _sum_squared_overlaps(rows: int, row, ca, cb, ra, rb) -> torch.Tensor:
        overlap = torch.relu(ra + rb - torch.linalg.vector_norm(ca - cb, dim=-1))
        # index_add on the CPU adds in order, one after another: a row's sum does not depend on the other rows
        return torch.zeros(rows, dtype=ca.dtype, device=ca.device).index_add(0, row, overlap * overlap)

    def penalty(self, centres: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        """``[B]`` sum of squared overlaps (m^2) over the tested sphere pairs that overlap."""
        row, a, b = self.overlapping_pairs(centres, radii)
        B, S = radii.shape
        flat_c, flat_r = centres.reshape(B * S, 3), radii.reshape(B * S)
        ia, ib = row * S + a, row * S + b  # index_select, not advanced indexing (_posed_centres)
        return self._sum_squared_overlaps(
            B,
            row,
            flat_c.index_select(0, ia),
            flat_c.index_select(0, ib),
            flat_r.index_select(0, ia),
            flat_r.index_select(0, ib),
        )

    def forward(self, betas: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
        """The penalty ``[B]``. Every sphere is posed without a gradient to find the overlapping
        pairs (a few dozen of the 10172 at most, most rows none); only those pairs' spheres are
        posed again with it, so the backward pass costs next to nothing."""
        b = betas.to(transforms.dtype)
        if len(b) != len(transforms):  # one shape for every row, as a broadcast
            b = b.expand(len(transforms), -1)
        with torch.no_grad():
            nearest = self._nearest(b)
            row, pa, pb = self.overlapping_pairs(self._posed_centres(b, transforms), self._all_radii(b, nearest))
        pair = torch.stack([pa, pb], 1)[:, :, None]  # [N, 2, 1]: "rows" of one sphere each
        rb, tb = b.index_select(0, row), transforms.index_select(0, row)  # (_posed_centres)
        centres = self._posed_centres(rb, tb, pair)[:, :, 0]  # [N, 2, 3]
        radii = self._radii(rb, pair, nearest[row[:, None, None], pair])[:, :, 0]  # [N, 2]
        return self._sum_squared_overlaps(len(b), row, centres[:, 0], centres[:, 1], radii[:, 0], radii[:, 1])
