"""Energy terms: small named objects, each returning one energy per problem ``[P]``.

A fit's energy is ``sum_t w_t * term_t`` over the named terms of :class:`Energy`, with
the weights of the current stage (:mod:`silfit.fitting.stages`). Every term reads an
:class:`Evaluation`: the body evaluated for the problems' parameter rows, its keypoints
projected into every observation's camera, and the observations' data tensors (all
indexed ``[P, F, C, ...]``: problem, frame, view). Terms over frames or views sum them,
so a problem's energy is one number whatever its number of frames and views.

Data each term expects in ``Evaluation.data``:

* :class:`KeypointTerm`: ``target [P,F,C,K,2]`` pixels, ``weights [P,F,C,K]``
  (confidence x per-keypoint weight, already normalised as the stage wants),
  ``scale [P,F,C]`` (pixels -> the stage's residual units);
* :class:`DepthTerm`: ``z0 [P,F,C]``, the depth the root should have in each camera;
* :class:`PointsTerm`: ``points3d [P,F,K,3]`` (world, metres) and ``points3d_weights [P,F,K]``,
  the keypoints triangulated from several views (absent: the term is 0);
* :class:`StayTerm`: ``start_<param>`` (the parameters to stay near);
* :class:`JointSmoothnessTerm`, :class:`RootSmoothnessTerm` (temporal, over a problem's
  frames, no data; problems of fewer than three frames give 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Iterable, Mapping, Optional

import torch

from ..body.lbs import axis_angle_to_matrix, sqrt
from ..camera import project_points
from .losses import reprojection_energy
from .problem import ParameterLayout, world_to_camera

__all__ = [
    "DepthTerm",
    "Energy",
    "Evaluation",
    "InterpenetrationTerm",
    "JointSmoothnessTerm",
    "KeypointTerm",
    "PointsTerm",
    "PriorTerm",
    "RootSmoothnessTerm",
    "StayTerm",
    "Term",
    "evaluate",
    "robust_penalty",
    "second_differences",
]


@dataclass
class Evaluation:
    """What the terms read; ``P`` problems, ``F`` frames, ``C`` views."""

    P: int
    F: int
    C: int
    params: Dict[str, torch.Tensor]  # shared [P, w], per-frame [P, F, w]
    rows: Dict[str, torch.Tensor]  # per body row [P * F, w]
    body: object  # BodyState of the rows (world frame)
    keypoints_2d: torch.Tensor  # [P, F, C, K, 2]
    root_camera: torch.Tensor  # [P, F, C, 3]: transl in each camera's frame
    data: Dict[str, torch.Tensor]
    extras: dict = field(default_factory=dict)  # diagnostics terms leave behind (e.g. IoU)
    views: Optional[Dict[str, torch.Tensor]] = None  # the cameras: intr, R, t [P, F, C, ...]

    def per_problem(self, values: torch.Tensor) -> torch.Tensor:
        """Sum ``[P]``, ``[P * F]``, ``[P, F]`` or ``[P, F, C]`` values per problem."""
        return values.reshape(self.P, -1).sum(1)


def evaluate(
    body, layout: ParameterLayout, params: Dict[str, torch.Tensor], views: Dict[str, torch.Tensor], data
) -> Evaluation:
    """Evaluate ``body`` (a :mod:`silfit.fitting.body` evaluator) for the problems' parameters
    and project its keypoints into every view (``views``: ``intr, R, t [P, F, C, ...]``)."""
    rows = layout.rows(params)
    state = body(**rows)
    P, F, C = views["intr"].shape[:3]
    kp = state.keypoints.reshape(P, F, 1, *state.keypoints.shape[1:]).expand(P, F, C, *state.keypoints.shape[1:])
    R, t = views["R"].to(kp.dtype), views["t"].to(kp.dtype)
    kp_cam = world_to_camera(kp, R, t)
    proj = project_points(kp_cam, views["intr"])
    root = rows["transl"].reshape(P, F, 1, 3)
    root_cam = world_to_camera(root.expand(P, F, C, 3)[..., None, :], R, t)[..., 0, :]
    return Evaluation(P, F, C, params, rows, state, proj, root_cam, data, views=views)


class Term:
    """A named energy term: ``term(evaluation) -> [P]``."""

    name: str = ""

    def __call__(self, ev: Evaluation) -> torch.Tensor:  # pragma: no cover - interface
        raise NotImplementedError


class KeypointTerm(Term):
    """Robust reprojection: ``sum_k w_k * rho(scale * (proj_k - target_k))`` per observation
    (Geman-McClure with ``sigma``, or plain L2 with ``sigma=None``), summed over
    observations. ``mask [K]`` restricts it to some keypoints (e.g. the torso)."""

    def __init__(
        self,
        name: str = "keypoints",
        sigma: Optional[float] = 100.0,
        mask: Optional[torch.Tensor] = None,
        weights_key: str = "weights",
    ):
        self.name, self.sigma, self.mask, self.weights_key = name, sigma, mask, weights_key

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        d = ev.data
        K = ev.keypoints_2d.shape[-2]
        w = d[self.weights_key]  # ``weights``, or another key of the same shape (a part's own weights)
        weights = w if self.mask is None else w * self.mask.to(w.dtype)
        e = reprojection_energy(
            ev.keypoints_2d.reshape(-1, K, 2),
            d["target"].reshape(-1, K, 2),
            weights.reshape(-1, K),
            d["scale"].reshape(-1),
            self.sigma,
        )
        return ev.per_problem(e)


class DepthTerm(Term):
    """``(z_root - z0)^2`` per observation: the root's depth in the camera against a guess
    (the similar-triangles depth of the initialisation)."""

    name = "depth"

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        return ev.per_problem((ev.root_camera[..., 2] - ev.data["z0"]) ** 2)


class PointsTerm(Term):
    """Robust distance of the body's keypoints to their triangulated 3D points:
    ``sum_k w_k * rho(scale * |X_k - x_k|)`` per frame (Geman-McClure with ``sigma``, plain L2 with
    ``sigma=None`` as :class:`KeypointTerm`; ``scale``
    metres to the keypoint term's normalised pixels; ``mask [K]``: some keypoints only, e.g. the body's
    of the whole-body layout), 0 for problems without ``points3d`` (one view).
    Two views' 2D terms can settle with a limb in the wrong depth branch (one view agrees, the
    other's residual is bounded by the robust penalty); the triangulated point has no such branch."""

    name = "points"

    def __init__(self, sigma: Optional[float] = 100.0, scale: float = 500.0 / 1.7, mask: Optional[torch.Tensor] = None):
        self.sigma, self.scale, self.mask = None if sigma is None else float(sigma), float(scale), mask

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        if "points3d" not in ev.data:
            return ev.keypoints_2d.new_zeros(ev.P)
        X = ev.data["points3d"]
        kp = ev.body.keypoints.reshape(X.shape)
        d2 = ((kp - X) * self.scale).square().sum(-1)
        w = ev.data["points3d_weights"] if self.mask is None else ev.data["points3d_weights"] * self.mask.to(d2.dtype)
        if self.sigma is None:
            return ev.per_problem(w * d2)
        s2 = self.sigma**2
        return ev.per_problem(w * s2 * d2 / (d2 + s2))


class PriorTerm(Term):
    """``fn(parameter) -> [rows]`` summed per problem: pose, angle, limit and shape priors.

    ``parameter`` may be a tuple of names with ``fn`` a tuple of as many functions (e.g. one prior
    per hand): their sum."""

    def __init__(self, name: str, fn, parameter):
        self.name, self.fn, self.parameter = name, fn, parameter

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        names, fns = (self.parameter, self.fn) if isinstance(self.parameter, tuple) else ((self.parameter,), (self.fn,))
        total = 0
        for n, fn in zip(names, fns):
            value = ev.params[n]
            total = total + ev.per_problem(fn(value.reshape(-1, value.shape[-1])))
        return total


class InterpenetrationTerm(Term):
    """Self-intersection of the posed body (``collisions(betas, transforms) -> [rows]``)."""

    name = "interpenetration"

    def __init__(self, collisions):
        self.collisions = collisions

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        return ev.per_problem(self.collisions(ev.rows["betas"], ev.body.transforms))


class StayTerm(Term):
    """``|param - start|^2``: a pull toward given parameters (``data['start_<param>']``)."""

    def __init__(self, parameter: str = "body_pose", name: str = "stay"):
        self.name, self.parameter = name, parameter

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        diff = ev.params[self.parameter] - ev.data[f"start_{self.parameter}"]
        return ev.per_problem(diff.reshape(ev.P, -1).square())


def second_differences(x: torch.Tensor) -> torch.Tensor:
    """``x[:, t+1] - 2 x[:, t] + x[:, t-1]`` along the frame axis 1: ``[P, F, ...] -> [P, F-2, ...]``
    (the discrete acceleration per frame squared)."""
    return x[:, 2:] - 2.0 * x[:, 1:-1] + x[:, :-2]


def robust_penalty(sq: torch.Tensor, sigma: Optional[float], kind: str = "charbonnier") -> torch.Tensor:
    """A robust penalty of squared residual norms ``sq``: ``"charbonnier"`` (pseudo-Huber,
    ``2 sigma^2 (sqrt(1 + sq / sigma^2) - 1)``: quadratic below ``sigma``, linear above, so a
    large true acceleration costs in proportion, not squared), ``"gm"`` (Geman-McClure,
    ``sigma^2 sq / (sigma^2 + sq)``: bounded) or plain ``sq`` when ``sigma`` is ``None``.
    All are ``~ sq`` for ``sq << sigma^2``."""
    if sigma is None:
        return sq
    s2 = float(sigma) ** 2
    if kind == "charbonnier":
        return 2.0 * s2 * (sqrt(1.0 + sq / s2) - 1.0)
    if kind == "gm":
        return s2 * sq / (s2 + sq)
    raise ValueError(f"unknown robust penalty {kind!r} (expected charbonnier or gm)")


class JointSmoothnessTerm(Term):
    """Temporal smoothness of the joints' world positions: ``sum_t sum_j rho(|scale *
    a_tj|^2)`` with ``a`` the second difference over frames (:func:`second_differences`) of
    ``ev.body.joints`` (``[P*F, J, 3]``, metres; ``scale`` 1000: millimetres) and ``rho``
    :func:`robust_penalty` with ``sigma`` (mm per frame^2) so a true fast motion (a swing, a
    kick) is penalised linearly, not flattened."""

    def __init__(
        self,
        name: str = "smooth_joints",
        sigma: Optional[float] = 10.0,
        kind: str = "charbonnier",
        scale: float = 1000.0,
    ):
        self.name, self.sigma, self.kind, self.scale = name, sigma, kind, float(scale)

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        joints = ev.body.joints
        if ev.F < 3:
            return joints.new_zeros(ev.P)
        a = second_differences(joints.reshape(ev.P, ev.F, *joints.shape[1:])) * self.scale
        return robust_penalty((a * a).sum(-1), self.sigma, self.kind).reshape(ev.P, -1).sum(1)


class RootSmoothnessTerm(Term):
    """Temporal smoothness of the root's motion: the second difference over frames of the
    translation (``transl``, metres x ``scale``) and of the root orientation's rotation
    matrix (``global_orient``; x ``rotation_scale``, i.e. the motion of points that far from
    the root, in the same units), each through :func:`robust_penalty`."""

    def __init__(
        self,
        name: str = "smooth_root",
        sigma: Optional[float] = 10.0,
        kind: str = "charbonnier",
        scale: float = 1000.0,
        rotation_scale: float = 500.0,
    ):
        self.name, self.sigma, self.kind = name, sigma, kind
        self.scale, self.rotation_scale = float(scale), float(rotation_scale)

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        transl, orient = ev.params["transl"], ev.params["global_orient"]  # [P, F, 3]
        if ev.F < 3:
            return transl.new_zeros(ev.P)
        a = second_differences(transl) * self.scale
        rot = axis_angle_to_matrix(orient.reshape(-1, 3)).reshape(ev.P, ev.F, 9)
        b = second_differences(rot) * self.rotation_scale
        e = robust_penalty((a * a).sum(-1), self.sigma, self.kind) + robust_penalty(
            (b * b).sum(-1), self.sigma, self.kind
        )
        return e.sum(1)


class Energy:
    """A sum of named terms with per-stage weights.

    ``energy(ev, weights) -> (total [P], parts {name: [P]})``; a term whose weight is zero
    or absent is not evaluated. Weight names that are not terms are an error (a
    misspelled weight must not silently drop a term)."""

    def __init__(self, terms: Iterable[Term]):
        self.terms: Dict[str, Term] = {}
        for t in terms:
            if not t.name or t.name in self.terms:
                raise ValueError(f"energy terms need distinct names, got {t.name!r} twice or empty")
            self.terms[t.name] = t

    @property
    def names(self) -> tuple:
        return tuple(self.terms)

    def check(self, weights: Mapping[str, float], where: str = "stage") -> None:
        unknown = sorted(set(weights) - set(self.terms))
        if unknown:
            raise ValueError(f"{where}: unknown energy term(s) {', '.join(unknown)} (known: {', '.join(self.terms)})")
        bad = [k for k, v in weights.items() if not isinstance(v, (int, float)) or v != v or v < 0]
        if bad:
            raise ValueError(f"{where}: weight(s) of {', '.join(bad)} must be non-negative numbers")

    def __call__(self, ev: Evaluation, weights: Mapping[str, float]):
        total = None
        parts = {}
        for name, w in weights.items():
            if not w:
                continue
            value = self.terms[name](ev)
            parts[name] = value
            total = w * value if total is None else total + w * value
        if total is None:
            total = torch.zeros(ev.P, dtype=ev.keypoints_2d.dtype)
        return total, parts
