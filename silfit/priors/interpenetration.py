"""Interpenetration penalty on spheres placed along each body part.

Spheres are derived once from the body model (any SMPL-layout model):

* every vertex belongs to the part (joint) with its largest skinning weight;
* a part's vertices are cut into slices along the part's principal axis (of the mean
  shape's rest mesh); each slice is one sphere, its centre the mean of the slice's
  vertices and its radius ``shrink`` x the RMS distance of those vertices from the
  part axis; both are recomputed from the shaped rest vertices, so they follow
  ``betas`` (a heavier body gets bigger spheres);
* posed, a sphere moves rigidly with its part's skinning transform.

Two spheres are tested only if their parts are at least ``min_tree_distance`` apart
in the kinematic tree (not the same part, parent/child or siblings, ...) and they do
not already touch in the rest (T-) pose of the mean shape (plus ``rest_margin``), so the
penalty is zero for the T-pose. Energy per sample: ``sum relu(r_a + r_b - |c_a - c_b|)^2``
(metres^2), whose gradient pushes overlapping parts apart.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
import torch
from torch import nn

__all__ = ["SphereCollisionModel"]


def _tree_distances(parents) -> np.ndarray:
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


class SphereCollisionModel(nn.Module):
    def __init__(
        self,
        model,
        slice_length: float = 0.06,
        max_spheres_per_part: int = 8,
        shrink: float = 0.8,
        min_tree_distance: int = 3,
        rest_margin: float = 0.01,
    ):
        super().__init__()
        dtype = model.v_template.dtype
        v = model.v_template.detach().double().cpu().numpy()
        W = model.lbs_weights.detach().double().cpu().numpy()
        part_of = W.argmax(1)
        J = W.shape[1]
        members, seg, sphere_part, axes = [], [], [], []
        for j in range(J):
            idx = np.flatnonzero(part_of == j)
            if len(idx) < 8:
                continue
            pts = v[idx]
            mean = pts.mean(0)
            _, _, vt = np.linalg.svd(pts - mean, full_matrices=False)
            axis = vt[0]
            proj = (pts - mean) @ axis
            lo, hi = np.quantile(proj, [0.01, 0.99])
            n = int(np.clip(np.ceil((hi - lo) / slice_length), 1, max_spheres_per_part))
            edges = np.linspace(lo, hi, n + 1)
            edges[0], edges[-1] = -np.inf, np.inf
            for s in range(n):
                sel = idx[(proj >= edges[s]) & (proj < edges[s + 1])]
                if len(sel) < 4:
                    continue
                members.append(sel)
                seg.append(np.full(len(sel), len(sphere_part)))
                sphere_part.append(j)
                axes.append(axis)
        S = len(sphere_part)
        self.num_spheres = S
        member_idx = np.concatenate(members)
        seg_idx = np.concatenate(seg)
        counts = np.bincount(seg_idx, minlength=S).astype(np.float64)
        self.register_buffer("member_idx", torch.as_tensor(member_idx, dtype=torch.long))
        self.register_buffer("seg_idx", torch.as_tensor(seg_idx, dtype=torch.long))
        self.register_buffer("counts", torch.as_tensor(counts, dtype=dtype))
        self.register_buffer("sphere_part", torch.as_tensor(sphere_part, dtype=torch.long))
        self.register_buffer("axes", torch.as_tensor(np.stack(axes), dtype=dtype))
        self.register_buffer("v_template", model.v_template.detach().clone())
        self.register_buffer("shapedirs", model.shapedirs.detach().clone())
        self.shrink = float(shrink)

        tree = _tree_distances(model.parents)
        sp = np.asarray(sphere_part)
        far = tree[sp[:, None], sp[None, :]] >= min_tree_distance
        iu = np.triu(np.ones((S, S), dtype=bool), 1)
        cand = far & iu
        # Drop pairs that already touch at the rest pose of the mean shape.
        with torch.no_grad():
            c, r = self.rest_spheres(torch.zeros(1, self.shapedirs.shape[-1], dtype=torch.float64), dtype=torch.float64)
            d = torch.cdist(c[0], c[0]).numpy()
            gap = d - (r[0][:, None] + r[0][None, :]).numpy()
        cand &= gap > rest_margin
        a, b = np.nonzero(cand)
        self.register_buffer("pair_a", torch.as_tensor(a, dtype=torch.long))
        self.register_buffer("pair_b", torch.as_tensor(b, dtype=torch.long))

    def rest_spheres(self, betas: torch.Tensor, dtype: Optional[torch.dtype] = None):
        """Rest-pose centres ``[B, S, 3]`` and radii ``[B, S]`` for ``betas [B, L]``."""
        dtype = dtype or betas.dtype
        vt = self.v_template.to(dtype)
        sd = self.shapedirs[..., : betas.shape[-1]].to(dtype)
        vm = vt[self.member_idx][None] + torch.einsum("bl,vcl->bvc", betas.to(dtype), sd[self.member_idx])  # [B, M, 3]
        B, S = vm.shape[0], self.num_spheres
        counts = self.counts.to(dtype)
        centres = torch.zeros(B, S, 3, dtype=dtype, device=vm.device).index_add_(1, self.seg_idx, vm) / counts[:, None]
        rel = vm - centres[:, self.seg_idx]
        ax = self.axes.to(dtype)[self.seg_idx]  # [M, 3]
        perp = rel - (rel * ax).sum(-1, keepdim=True) * ax
        ms = torch.zeros(B, S, dtype=dtype, device=vm.device).index_add_(1, self.seg_idx, (perp * perp).sum(-1))
        radii = self.shrink * (ms / counts + 1e-12).sqrt()
        return centres, radii

    def posed_spheres(self, betas: torch.Tensor, transforms: torch.Tensor, transl: Optional[torch.Tensor] = None):
        """Posed centres and radii given the skinning transforms ``[B, J, 4, 4]``
        (rest point -> posed point) of :func:`silfit.body.lbs.forward_kinematics`."""
        c, r = self.rest_spheres(betas, transforms.dtype)
        T = transforms[:, self.sphere_part]  # [B, S, 4, 4]
        posed = (T[..., :3, :3] @ c[..., None])[..., 0] + T[..., :3, 3]
        if transl is not None:
            posed = posed + transl[:, None]
        return posed, r

    def penalty(self, centres: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        """``[B]`` sum of squared overlaps (m^2) over the tested sphere pairs."""
        d2 = ((centres[:, self.pair_a] - centres[:, self.pair_b]) ** 2).sum(-1)
        d = (d2 + 1e-12).sqrt()
        overlap = torch.relu(radii[:, self.pair_a] + radii[:, self.pair_b] - d)
        return (overlap * overlap).sum(-1)

    def forward(self, betas: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
        c, r = self.posed_spheres(betas, transforms)
        return self.penalty(c, r)
