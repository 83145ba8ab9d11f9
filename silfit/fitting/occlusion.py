"""Occlusion cues: does a hypothesis' depth order agree with the keypoints' confidences?

Detectors give a keypoint hidden behind the body a lower confidence (OpenPose does;
:mod:`silfit.synth` draws ``conf_occluded`` = 0.1-0.3 for self-occluded points against 0.6-1.0
for visible ones). Two limb-branch hypotheses that project to the same keypoints differ in
which keypoints the body hides: a thigh pointing toward the camera hides the hip, one pointing
away lets the knee go behind the pelvis. :func:`occlusion_cost` scores that: for each keypoint
the nearest surface along the camera ray through its 3D point (a point-in-triangle test of
the projected mesh, perspective-correct depth; no renderer), *hidden* when that surface is
nearer than the point by more than the keypoint's tolerance
(:data:`~silfit.layouts.KEYPOINT_DEPTH_TOLERANCE`: joint centres lie inside the limb);
a confident keypoint that is hidden, or a low-confidence one that is visible, costs one
(linearly between the ``conf_range`` ends: a confidence of ``lo`` or less expects hidden, of
``hi`` or more expects visible).

:class:`OcclusionTerm` is the named energy term (``occlusion``). It has no gradient (a hard
depth test): the keypoint stage uses it to *choose* among its limb-branch hypotheses
(``KeypointFitConfig.occlusion.weight``), never inside L-BFGS.
"""

from __future__ import annotations

from typing import Sequence, Tuple

import torch

from ..layouts import DEFAULT_DEPTH_TOLERANCE, KEYPOINT_DEPTH_TOLERANCE
from .problem import world_to_camera
from .terms import Evaluation, Term

__all__ = ["OcclusionTerm", "hidden_keypoints", "occlusion_cost", "occlusion_parts"]

#: confidences at or below the first expect a hidden keypoint, at or above the second a visible one
CONF_RANGE = (0.3, 0.6)


def surface_depth(
    vertices: torch.Tensor, faces: torch.Tensor, points: torch.Tensor, offset: float = 0.0
) -> torch.Tensor:
    """``[R, K]``: the depth (camera ``z``) of the nearest surface of each row's mesh
    (``vertices [R, V, 3]``, camera frame) along the ray through each of ``points [R, K, 3]``
    (camera frame); ``inf`` where the ray misses the mesh. With ``offset`` (normalised image
    units, about a pixel: ``1 / focal``) the farthest of five rays, the point's and four around it
    (as the synthetic data's visibility takes the farthest surface of 3 x 3 pixels: an edge pixel
    is no occlusion)."""
    f = faces.long()
    shifts = torch.tensor(
        [[0.0, 0.0]] + ([[offset, 0.0], [-offset, 0.0], [0.0, offset], [0.0, -offset]] if offset else []),
        dtype=torch.float64,
    )
    out = torch.full(points.shape[:2], float("inf"), dtype=torch.float64)
    for r in range(vertices.shape[0]):
        v = vertices[r].double()
        z = v[:, 2].clamp(min=1e-6)
        q = v[:, :2] / z[:, None]  # normalised image coordinates: the ray's direction
        tri = q[f]  # [T, 3, 2]
        inv = 1.0 / z[f]  # [T, 3]: 1/z is affine in the normalised image plane
        c = points[r].double()
        c = c[:, :2] / c[:, 2:3].clamp(min=1e-6)  # [K, 2]
        lo, hi = (tri.min(1).values - offset).float(), (tri.max(1).values + offset).float()
        cf = c.float()
        t, k = torch.nonzero((cf[None] >= lo[:, None]).all(-1) & (cf[None] <= hi[:, None]).all(-1), as_tuple=True)
        S = len(shifts)  # every candidate (triangle, keypoint) pair with each of the keypoint's rays
        t, k = t.repeat_interleave(S), k.repeat_interleave(S) * S + torch.arange(S).repeat(len(k))
        p = (c[:, None] + shifts[None]).reshape(-1, 2)  # [K * S, 2]
        a, e0, e1 = tri[t, 0], tri[t, 1] - tri[t, 0], tri[t, 2] - tri[t, 0]
        d = p[k] - a
        den = e0[:, 0] * e1[:, 1] - e1[:, 0] * e0[:, 1]
        ok = den.abs() > 1e-14
        den = torch.where(ok, den, torch.ones_like(den))
        ub = (d[:, 0] * e1[:, 1] - e1[:, 0] * d[:, 1]) / den
        uc = (e0[:, 0] * d[:, 1] - d[:, 0] * e0[:, 1]) / den
        ua = 1.0 - ub - uc
        inside = ok & (ua >= 0) & (ub >= 0) & (uc >= 0)
        depth = 1.0 / (ua * inv[t, 0] + ub * inv[t, 1] + uc * inv[t, 2]).clamp(min=1e-9)
        depth = torch.where(inside, depth, torch.full_like(depth, float("inf")))
        nearest = torch.full((p.shape[0],), float("inf"), dtype=torch.float64).scatter_reduce(0, k, depth, "amin")
        out[r] = nearest.reshape(-1, len(shifts)).max(1).values
    return out


def hidden_keypoints(
    vertices: torch.Tensor, faces: torch.Tensor, keypoints: torch.Tensor, tolerance: torch.Tensor, offset: float = 0.0
) -> torch.Tensor:
    """``bool [R, K]``: keypoints ``[R, K, 3]`` (camera frame) behind the surface of their row's
    mesh by more than ``tolerance [K]`` metres (``offset``: :func:`surface_depth`)."""
    d = surface_depth(vertices, faces, keypoints, offset)
    return (keypoints[..., 2].double() - d) > tolerance.double()[None]


def occlusion_parts(hidden: torch.Tensor, conf: torch.Tensor, conf_range: Tuple[float, float] = CONF_RANGE):
    """``(hidden_confident [R], visible_unsure [R])``: per row, the confident keypoints that are
    hidden and the low-confidence ones that are visible (each keypoint weighing between 0 and 1 by
    its confidence, linearly over ``conf_range``; confidence 0: not detected, no cost)."""
    lo, hi = conf_range
    c = conf.double()
    expect_visible = ((c - lo) / max(hi - lo, 1e-9)).clamp(0.0, 1.0)
    seen = c > 0
    h = hidden.double()
    return ((h * expect_visible) * seen).sum(-1), (((1.0 - h) * (1.0 - expect_visible)) * seen).sum(-1)


def occlusion_cost(
    hidden: torch.Tensor, conf: torch.Tensor, conf_range: Tuple[float, float] = CONF_RANGE
) -> torch.Tensor:
    """``[R]``: keypoints whose depth order disagrees with their confidence (:func:`occlusion_parts`, summed)."""
    a, b = occlusion_parts(hidden, conf, conf_range)
    return a + b


def keypoint_tolerances(names: Sequence[str]) -> torch.Tensor:
    return torch.as_tensor(
        [KEYPOINT_DEPTH_TOLERANCE.get(n, DEFAULT_DEPTH_TOLERANCE) for n in names], dtype=torch.float64
    )


class OcclusionTerm(Term):
    """``occlusion``: :func:`occlusion_cost` of the evaluated bodies against the keypoints'
    confidences (``data['conf'] [P, F, C, K]``) in every view (``ev.views``), summed over frames
    and views. No gradient: for choosing among hypotheses, not for an optimiser's stage."""

    name = "occlusion"

    def __init__(self, model, keypoint_names: Sequence[str], conf_range: Tuple[float, float] = CONF_RANGE):
        self.model, self.conf_range = model, tuple(conf_range)
        self.tolerance = keypoint_tolerances(keypoint_names)

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        with torch.no_grad():
            verts = self.model(**ev.rows).vertices  # [P * F, V, 3], world frame
            faces = self.model.faces
            P, F, C = ev.P, ev.F, ev.C
            V = verts.shape[1]
            verts = verts.reshape(P, F, 1, V, 3).expand(P, F, C, V, 3)
            kp = ev.body.keypoints
            kp = kp.reshape(P, F, 1, *kp.shape[1:]).expand(P, F, C, *kp.shape[1:])
            R, t = ev.views["R"].to(verts.dtype), ev.views["t"].to(verts.dtype)
            vc = world_to_camera(verts, R, t).reshape(P * F * C, V, 3)
            kc = world_to_camera(kp, R, t).reshape(P * F * C, -1, 3)
            hidden = hidden_keypoints(vc, faces, kc, self.tolerance)
            cost = occlusion_cost(hidden, ev.data["conf"].reshape(P * F * C, -1), self.conf_range)
        return ev.per_problem(cost.to(ev.keypoints_2d.dtype))
