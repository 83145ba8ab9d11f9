"""Fitting problems: observations indexed by (frame, view), and their parameters.

A *problem* is one body seen in ``F`` frames by ``C`` views (cameras). Each observation
``(frame, view)`` has its camera (intrinsics, and world-to-camera extrinsics ``R, t``,
identity by default), its keypoints and optionally a mask. The body has parameters per
frame (pose, orientation, translation) and parameters shared by all frames (the shape,
``betas``). One image is the problem with one frame and one view, and then the world
frame *is* the camera frame (identity extrinsics), as silfit's single-image outputs are.

A batch of problems of the same ``(F, C)`` is tensorised by :func:`stack_problems`;
the problem is the unit of the batch: the optimiser treats each problem as one
independent row (:mod:`silfit.fitting.optim`), its shared and per-frame parameters
packed side by side (:class:`ParameterLayout`), so there is no cross-talk between
problems while frames of one problem share their shape.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch

from ..camera import Camera

__all__ = ["Observation", "ParameterLayout", "Problem", "View", "world_to_camera"]


@dataclass(frozen=True)
class View:
    """A camera of a problem: intrinsics and world-to-camera extrinsics
    (``x_cam = R @ x_world + t``, OpenCV convention; identity when omitted)."""

    camera: Camera
    R: Optional[np.ndarray] = None
    t: Optional[np.ndarray] = None

    def extrinsics(self) -> Tuple[np.ndarray, np.ndarray]:
        R = np.eye(3) if self.R is None else np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        t = np.zeros(3) if self.t is None else np.asarray(self.t, dtype=np.float64).reshape(3)
        return R, t


@dataclass
class Observation:
    """What one view saw in one frame: 2D keypoints ``xy [K, 2]``, ``conf [K]`` (a
    :class:`~silfit.io.keypoints.KeypointSet` or ``None``) and an optional mask ``[H, W]``;
    ``known`` (bool ``[H, W]``, ``None``: everywhere): the pixels whose mask value is trusted;
    the silhouette stage treats the others like those beyond the image: unknown, no cost either
    way (:func:`silfit.silhouette.losses.unknown_regions`: leaks, small holes). ``cover_inner``: the
    mask-not-covered side's slope near the mask's edge for this mask (``None``: the config's
    ``mask.cover_inner``; the image path gives ``mask.untrimmed_inner`` to a mask not trimmed as clothing)."""

    view: View
    keypoints: object = None
    mask: Optional[np.ndarray] = None
    frame: int = 0
    view_index: int = 0
    known: Optional[np.ndarray] = None
    cover_inner: Optional[float] = None


@dataclass
class Problem:
    """Observations of one body, indexed by (frame, view); ``shared`` names the parameters
    that are one for all frames."""

    observations: List[Observation]
    shared: Tuple[str, ...] = ("betas",)

    @classmethod
    def single(cls, keypoints, camera: Camera, mask=None, known=None, cover_inner=None) -> "Problem":
        """One image: one frame, one view, identity extrinsics."""
        return cls([Observation(View(camera), keypoints, mask, known=known, cover_inner=cover_inner)])

    @property
    def num_frames(self) -> int:
        return 1 + max(o.frame for o in self.observations)

    @property
    def num_views(self) -> int:
        return 1 + max(o.view_index for o in self.observations)

    def grid(self) -> List[List[Observation]]:
        """Observations as ``[frame][view]``; every (frame, view) must be present once."""
        F, C = self.num_frames, self.num_views
        cells: List[List[Optional[Observation]]] = [[None] * C for _ in range(F)]
        for o in self.observations:
            if cells[o.frame][o.view_index] is not None:
                raise ValueError(f"problem has two observations for frame {o.frame}, view {o.view_index}")
            cells[o.frame][o.view_index] = o
        missing = [(f, c) for f in range(F) for c in range(C) if cells[f][c] is None]
        if missing:
            raise ValueError(f"problem lacks observations for (frame, view) {missing[:4]}")
        return cells  # type: ignore[return-value]


def world_to_camera(points: torch.Tensor, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """``R @ p + t`` for points ``[..., N, 3]`` with ``R [..., 3, 3]``, ``t [..., 3]``."""
    return (R[..., None, :, :] * points[..., :, None, :]).sum(-1) + t[..., None, :]  # not a GEMM (silfit.body.lbs)


def stack_views(problems: Sequence[Problem], dtype=torch.float64) -> Dict[str, torch.Tensor]:
    """Per-observation camera tensors ``[P, F, C, ...]``: ``intr`` (fx, fy, cx, cy), ``R``, ``t``."""
    intr, Rs, ts = [], [], []
    for p in problems:
        grid = p.grid()
        intr.append(
            [[[o.view.camera.fx, o.view.camera.fy, o.view.camera.cx, o.view.camera.cy] for o in row] for row in grid]
        )
        ext = [[o.view.extrinsics() for o in row] for row in grid]
        Rs.append([[e[0] for e in row] for row in ext])
        ts.append([[e[1] for e in row] for row in ext])
    T = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=dtype)  # noqa: E731
    return {"intr": T(intr), "R": T(Rs), "t": T(ts)}


@dataclass
class ParameterLayout:
    """Names and widths of a body's parameters, which are shared across frames, and how a
    problem's free parameters pack into one optimiser row.

    State tensors: shared parameters ``[P, w]``, per-frame ones ``[P, F, w]``.
    """

    sizes: Dict[str, int]
    shared: Tuple[str, ...] = ("betas",)
    frames: int = 1
    _order: Tuple[str, ...] = field(init=False, default=())

    def __post_init__(self):
        unknown = [n for n in self.shared if n not in self.sizes]
        if unknown:
            raise ValueError(f"shared parameter(s) {unknown} are not parameters of the model ({', '.join(self.sizes)})")
        self._order = tuple(self.sizes)

    @classmethod
    def of(cls, model, shared=("betas",), frames: int = 1) -> "ParameterLayout":
        return cls(dict(model.parameter_sizes), tuple(shared), int(frames))

    def is_shared(self, name: str) -> bool:
        return name in self.shared

    def zeros(self, P: int, dtype=torch.float64, device=None) -> Dict[str, torch.Tensor]:
        return {
            n: torch.zeros((P, w) if n in self.shared else (P, self.frames, w), dtype=dtype, device=device)
            for n, w in self.sizes.items()
        }

    def check_free(self, free: Sequence[str]) -> None:
        unknown = [n for n in free if n not in self.sizes]
        if unknown:
            raise ValueError(f"free parameter(s) {unknown} are not parameters of the model ({', '.join(self.sizes)})")

    def pack(self, state: Dict[str, torch.Tensor], free: Sequence[str]) -> torch.Tensor:
        """Free parameters of each problem as one row ``[P, D]``."""
        return torch.cat([state[n].reshape(state[n].shape[0], -1) for n in free], 1)

    def unpack(self, x: torch.Tensor, free: Sequence[str]) -> Dict[str, torch.Tensor]:
        widths = [self.sizes[n] * (1 if n in self.shared else self.frames) for n in free]
        parts = torch.split(x, widths, dim=1)
        return {
            n: part if n in self.shared else part.reshape(x.shape[0], self.frames, self.sizes[n])
            for n, part in zip(free, parts)
        }

    def rows(self, state: Dict[str, torch.Tensor]) -> Dict[str, torch.Tensor]:
        """Parameters per body row ``[P * F, w]`` (shared ones repeated over the frames)."""
        out = {}
        for n, v in state.items():
            if n in self.shared:
                v = v[:, None].expand(v.shape[0], self.frames, v.shape[-1])
            out[n] = v.reshape(-1, v.shape[-1])
        return out
