"""Fitting a video: one person over ``F`` frames of one camera (or of a calibrated rig's ``C``
cameras: a rig video), one shape for all frames.

:func:`fit_sequence` runs

1. **checks and bridging**: a frame with no keypoints, too few confident torso keypoints
   (as the single-image fit needs) or mostly outlier keypoints is *bridged*; a single
   keypoint that jumps away from its two neighbours' midpoint (by more than
   ``outlier_jump`` of the person's extent, while the neighbours agree) is dropped
   (:func:`keypoint_outliers`);
2. **per-frame initialisation**: the single-image keypoint stage on the usable frames as
   one batch (every ``init_stride``-th of them; the others are interpolated); then, with
   ``neighbour_starts``, each of those frames is fitted again from its previous and its next
   frame's fit (one start each, one batch) and keeps the lowest final energy of its three
   fits (:func:`~silfit.fitting.keypoint_stage.best_per_group`: near-ties keep its own fit). A
   frame stuck alone in a poor local minimum seldom is when started from the frame beside it
   (measured: docs/benchmarks/defaults.md, ``SequenceFitConfig.neighbour_starts``).
   With ``branch_choice.dp`` each frame's hypotheses and neighbour refits are candidates and the branch is
   chosen over time (:func:`branch_path`, a Viterbi programme; ``rebranched`` frames are recorded);
3. **consistent facings**: each frame's body-forward direction in the ground plane is
   compared along the sequence; the fewest frames whose facing contradicts their
   neighbours' (a 180-degree flip, the single image's classic ambiguity) are re-initialised
   from their neighbours (:func:`consistent_facings`, a two-label dynamic programme);
4. **joint refinement**: one :class:`~silfit.fitting.problem.Problem` of ``F`` frames with
   one shared ``betas``: keypoints, pose / angle / limit / shape priors and the temporal
   terms of :mod:`silfit.fitting.terms` (robust smoothness of the joints and of the
   root), started from the per-frame fits (bridged frames: interpolated from their
   neighbours, with data weight ``bridge_weight``), in the keypoint stage's own loop
   (:meth:`KeypointFitter.fit_problems` with an explicit schedule).

A rig video (``fit_sequence`` given the rig's views, ``frames[f][c]``) runs the same steps in the
rig's world frame: checks and outliers per view (a frame is bridged when no view has usable
keypoints; a view without usable keypoints in a frame others see has no data there), each frame
initialised by the rig's keypoint stage (:func:`~silfit.fitting.rig_fit.fit_rig_keypoints`: the
triangulated torso gives the facing, so no neighbour starts and, with several views, no facing
repair; a frame seen by one view only starts, as bridged frames do, from its neighbours'
interpolation, and keeps its data), and one refinement problem of ``F`` frames x ``C`` views (the
temporal weights scaled by ``views_smooth_scale``: the views fix the depth the smoothing resolves for
one camera).

A problem's L-BFGS row holds ``10 + F * 75`` numbers and one iteration evaluates the
reduced body ``F`` times, so memory and time grow linearly with ``F``; ``window`` splits a
long sequence into overlapping windows fitted as a batch of problems (each window's own
``betas``; the sequence's is their frame-weighted mean, then held fixed in a second pass).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Dict, List, Optional, Sequence

import numpy as np
import torch
from scipy.spatial.transform import Rotation, Slerp

from ..body import load_body_model
from ..camera import Camera, project_points
from ..io.keypoints import KeypointSet, model_keypoints
from ..io.wholebody import part_slices
from .keypoint_stage import (
    DISTINCT_JOINTS_M,
    BranchSearch,
    KeypointFitConfig,
    KeypointFitter,
    Solutions,
    Starts,
    best_per_group,
    check_torso,
)
from .problem import Observation, Problem, View
from .cores import Core
from .refine import SilhouetteHooks, StageInputs, refine_silhouettes
from .aliases import Alias, flat_dict, grouped, renamed_fields
from .plausibility import guard_fit, mask_warnings, reprojection_rise_warnings, shape_warnings
from .rig_fit import fit_rig_keypoints
from .schedule_edits import sequence_defaults, sequence_stages
from .terms import JointSmoothnessTerm, RootSmoothnessTerm
from .threads import torch_threads

__all__ = [
    "SequenceFitConfig",
    "SequenceFitResult",
    "consistent_facings",
    "fit_sequence",
    "interpolate_frames",
    "keypoint_outliers",
    "refine_sequence_silhouettes",
    "SequenceRefinement",
    "VideoCore",
    "viterbi",
    "pose_distances",
    "branch_path",
]

ROTATIONS = ("global_orient", "body_pose")


#: the defaults of :class:`SequenceFitConfig`'s stage fields: the cells of the literal table
#: (:data:`~silfit.fitting.schedules.SEQUENCE_SCHEDULE`)
STAGE_DEFAULTS = sequence_defaults()


@dataclass(frozen=True)
class BranchChoice:
    """The branch over time (the module docstring, step 2): with ``dp`` each frame's ``hypotheses`` best distinct
    keypoint-stage hypotheses (``KeypointFitConfig.solutions.count``) and its refits from its neighbours are its
    candidates, and a dynamic programme picks one per frame (:func:`branch_path`: each candidate's energy above the
    frame's lowest, over the sequence's typical energy, plus ``temporal_weight`` times the root-relative joint
    distance between consecutive frames' candidates over ``temporal_scale`` metres per frame) before the joint
    refinement, instead of each frame's lowest energy; ``rounds`` of refits from the neighbours' picks (one camera
    only; why these defaults: docs/benchmarks/defaults.md). Each field was :class:`SequenceFitConfig`'s
    ``branch_<name>`` (``dp``: ``branch_dp``), a name that still works."""

    dp: bool = True
    hypotheses: int = 3
    temporal_weight: float = 1.0
    temporal_scale: float = 0.02
    rounds: int = 2
    #: after the per-frame pass (and its neighbour refits or branch choice), one more round refits each
    #: frame from the picks of the frames these many away, both directions (:func:`_neighbour_sources`),
    #: and each frame keeps the lowest energy of its pick and these refits (near-ties: its pick): a right
    #: branch a few frames away reaches a run of frames whose own fits all took the wrong one. ``()`` or
    #: ``None``: no such round (why this default: docs/benchmarks/defaults.md)
    offsets: Optional[tuple] = (1, 2, 4)


@renamed_fields(
    pose_prior_weight=Alias("pose_weight"),
    angle_prior_weight=Alias("angle_weight"),
    **grouped(
        "branch_choice",
        branch_dp="dp",
        branch_hypotheses="hypotheses",
        branch_temporal_weight="temporal_weight",
        branch_temporal_scale="temporal_scale",
        branch_rounds="rounds",
        branch_offsets="offsets",
    ),
)
@dataclass
class SequenceFitConfig:
    """Settings of :func:`fit_sequence` (defaults tuned on ``silfit synth --videos`` data,
    see ``benchmarks/bench_sequence.py``)."""

    #: the per-frame initialisation (the single-image keypoint stage)
    #: (the single image's late branch search off and its first search's screen as before issue 25's
    #: change: the branch over time was tuned on these per-frame hypotheses)
    #: (the per-frame fit's final stage and branch choice as before issue 25's converged choice, too:
    #: ``final_iters`` 40, ``branches.refine`` 1, every step run; the joint refinement is what converges here;
    #: and no search from the fit, ``branches.post_iters`` 0)
    #: (the single image's 4 starting poses, not 2: a squat seen from the side hides one arm in its deep frames;
    #: why these defaults: docs/benchmarks/defaults.md)
    keypoint: KeypointFitConfig = field(
        default_factory=lambda: KeypointFitConfig(
            starts=Starts(poses=4),
            branches=BranchSearch(late_iters=0, screen_iters=10, survivors=3, refine=1, post_iters=0),
            final_iters=40,
            final_tol_change=None,
        )
    )
    init_stride: int = 1  # fit every n-th usable frame alone; interpolate the others
    iterations: int = STAGE_DEFAULTS["iterations"]  # joint refinement, L-BFGS steps
    joint_smooth_weight: float = STAGE_DEFAULTS["joint_smooth_weight"]
    root_smooth_weight: float = STAGE_DEFAULTS["root_smooth_weight"]
    #: the pose prior's (one name in every config, issue 26; old name ``pose_prior_weight``)
    pose_weight: float = STAGE_DEFAULTS["pose_weight"]
    #: the angle prior's (one name in every config, issue 57; old name ``angle_prior_weight``)
    angle_weight: float = STAGE_DEFAULTS["angle_weight"]
    limit_weight: float = STAGE_DEFAULTS["limit_weight"]
    shape_weight: float = STAGE_DEFAULTS["shape_weight"]
    interpenetration_weight: float = 0.0
    temporal_sigma: float = 10.0  # mm per frame^2 (Charbonnier)
    bridge_weight: float = 0.0  # data weight of bridged frames
    outlier_jump: float = 0.2  # share of the person's extent
    outlier_frame_share: float = 0.5  # a frame with more outlier keypoints than this is bridged
    facing_jump_cost: float = 10.0  # per 180-degree jump between neighbouring frames (vs 1 per re-initialised frame)
    #: fit each initialised frame again from its neighbours' fits and keep the lowest energy (module docstring)
    neighbour_starts: bool = True
    #: the branch over time (:class:`BranchChoice`; once ``branch_dp``, ``branch_hypotheses``,
    #: ``branch_temporal_weight``, ``branch_temporal_scale``, ``branch_rounds``, ``branch_offsets``, which still work)
    branch_choice: BranchChoice = field(default_factory=BranchChoice)
    window: int = 0  # frames per window (0: the whole sequence as one problem)
    overlap: int = 10
    window_pose_iterations: int = 40  # second pass (shared betas fixed) in windowed mode
    #: several calibrated views (a rig video): the temporal weights times this; the views fix the depth
    #: the smoothing resolves for one camera, and at full weight it flattens a run's bounce (why this
    #: default: docs/benchmarks/defaults.md)
    views_smooth_scale: float = 0.1

    def stages(self, free_betas: bool = True, iterations: Optional[int] = None, views: int = 1) -> tuple:
        """The joint refinement's one stage (``free_betas=False``: the windowed mode's second pass, the
        shape held; ``views``: a rig video's, the temporal weights scaled by ``views_smooth_scale``): the literal
        table :data:`~silfit.fitting.schedules.SEQUENCE_SCHEDULE`, its cells those of the fields that differ from
        their defaults (:func:`~silfit.fitting.schedule_edits.sequence_stages`)."""
        return sequence_stages(self, free_betas, iterations, views)

    def to_dict(self) -> dict:
        d = flat_dict(self, skip=("keypoint",), as_lists=False)  # the group's fields by their flat names, as before
        d["keypoint"] = self.keypoint.to_dict()
        return d


@dataclass
class SequenceFitResult:
    """Per-frame SMPL parameters of one camera's frames (camera coordinates, numpy
    float32): ``betas [L]`` (one shape), ``body_pose [F, 69]``, ``global_orient [F, 3]``,
    ``transl [F, 3]``, ``joints [F, 24, 3]``, ``keypoints_2d [F, K, 2]``; ``bridged [F]``
    (frames fitted from their neighbours), ``refaced [F]`` (facing re-initialised),
    ``outliers [F, K]`` (keypoints dropped as outliers), ``reprojection_error [F]``
    (median px, NaN for frames without keypoints), ``per_frame`` (the initialisation's
    parameters, the per-frame fit), ``timings`` (seconds) and ``config``."""

    betas: np.ndarray
    body_pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray
    camera: Camera
    joints: np.ndarray
    keypoints_2d: np.ndarray
    bridged: np.ndarray
    refaced: np.ndarray
    outliers: np.ndarray
    reprojection_error: np.ndarray
    per_frame: Dict[str, np.ndarray]
    timings: Dict[str, float]
    layout: str = "body25"
    config: dict = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)
    #: after :func:`refine_sequence_silhouettes`: soft IoU per frame (NaN without a mask) and at its start
    silhouette_iou: Optional[np.ndarray] = None
    silhouette_iou_start: Optional[float] = None
    #: after :func:`refine_sequence_silhouettes`: the keypoint stage's ``reprojection_error [F]``
    reprojection_error_keypoint_stage: Optional[np.ndarray] = None
    #: a whole-body (SMPL-X-layout) model's other parameters per frame ``[F, w]`` (hands and
    #: face from the per-frame fits, interpolated over frames without them, held in the refinement)
    extra: Dict[str, np.ndarray] = field(default_factory=dict)
    #: a rig video (:func:`fit_sequence` given views): the rig's views (world frame; ``camera`` is the
    #: first one's); then ``keypoints_2d`` is ``[F, C, K, 2]``, ``reprojection_error`` and
    #: ``silhouette_iou`` ``[F, C]``, ``outliers`` ``[F, C, K]`` and the parameters are in world coordinates
    views: Optional[list] = None
    #: frames whose per-frame start is not their lowest-energy hypothesis: the branch chosen over time
    #: (``SequenceFitConfig.branch_choice.dp``); all False without it
    rebranched: Optional[np.ndarray] = None

    @property
    def num_frames(self) -> int:
        return self.body_pose.shape[0]

    def params(self) -> Dict[str, np.ndarray]:
        """The model's parameter names: ``betas [L]``, the rest ``[F, w]`` (a whole-body model's
        hands, face and expression included)."""
        return {
            "betas": self.betas,
            "body_pose": self.body_pose,
            "global_orient": self.global_orient,
            "transl": self.transl,
            **self.extra,
        }

    def frame_params(self, f: int) -> Dict[str, np.ndarray]:
        return {n: v if n == "betas" else v[f] for n, v in self.params().items()}


# ----------------------------------------------------------------------------- pure pieces
def _extent(xy: np.ndarray, conf: np.ndarray) -> float:
    vis = xy[conf > 0]
    return float((vis.max(0) - vis.min(0)).max()) if len(vis) > 1 else 0.0


def keypoint_outliers(xy: np.ndarray, conf: np.ndarray, jump: float = 0.2) -> np.ndarray:
    """``bool [F, K]``: keypoint ``k`` of frame ``f`` is an outlier when it lies more than
    ``jump`` times the person's extent from the midpoint of frames ``f-1`` and ``f+1``
    while those two agree (are within ``jump`` of each other); needs both neighbours
    confident. ``xy [F, K, 2]``, ``conf [F, K]`` (0: missing)."""
    F, K = conf.shape
    out = np.zeros((F, K), dtype=bool)
    ext = np.array([_extent(xy[f], conf[f]) for f in range(F)])
    for f in range(1, F - 1):
        scale = max(ext[f - 1], ext[f + 1], 1.0)
        ok = (conf[f] > 0) & (conf[f - 1] > 0) & (conf[f + 1] > 0)
        mid = 0.5 * (xy[f - 1] + xy[f + 1])
        dev = np.linalg.norm(xy[f] - mid, axis=-1) / scale
        agree = np.linalg.norm(xy[f - 1] - xy[f + 1], axis=-1) / scale < jump
        out[f] = ok & agree & (dev > jump)
    return out


def interpolate_frames(params: Dict[str, np.ndarray], known: np.ndarray) -> Dict[str, np.ndarray]:
    """Per-frame parameters ``{name: [F, w]}`` with the frames where ``known`` is False
    replaced: rotations (``global_orient``, ``body_pose``, per joint) by spherical
    interpolation between the nearest known frames, others linearly; before the first and
    after the last known frame, that frame's values."""
    known = np.asarray(known, dtype=bool)
    idx = np.flatnonzero(known)
    if len(idx) == 0:
        raise ValueError("no frame to interpolate from")
    F = len(known)
    t = np.clip(np.arange(F, dtype=np.float64), idx[0], idx[-1])
    out = {}
    for name, v in params.items():
        v = np.asarray(v, dtype=np.float64)
        if v.ndim == 1 or len(idx) == F:
            out[name] = v.copy()
            continue
        if len(idx) == 1:
            out[name] = np.repeat(v[idx], F, 0)
            continue
        if name in ROTATIONS:
            J = v.shape[1] // 3
            res = np.empty((F, J, 3))
            for j in range(J):
                res[:, j] = Slerp(idx, Rotation.from_rotvec(v[idx, 3 * j : 3 * j + 3]))(t).as_rotvec()
            res = res.reshape(F, -1)
        else:
            res = np.stack([np.interp(t, idx, v[idx, c]) for c in range(v.shape[1])], 1)
        res[known] = v[known]
        out[name] = res
    return out


def body_forward(global_orient: np.ndarray) -> np.ndarray:
    """``[F, 2]``: the body's forward direction (+Z of SMPL's rest frame) in the camera's
    ground plane (x, z), unit length."""
    f = Rotation.from_rotvec(np.asarray(global_orient, dtype=np.float64).reshape(-1, 3)).apply([0.0, 0.0, 1.0])[
        :, [0, 2]
    ]
    return f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-9)


def consistent_facings(forward: np.ndarray, valid: np.ndarray, jump_cost: float = 10.0) -> np.ndarray:
    """``bool [F]``: frames whose facing to re-initialise, the fewest that make the sequence's
    facing continuous. A dynamic programme (:func:`viterbi`) over two labels per valid frame (keep, or
    turn by 180 degrees: cost 1), consecutive valid frames paying ``jump_cost *
    (1 - cos(angle)) / 2`` for the angle between their (label-adjusted) forward vectors."""
    idx = np.flatnonzero(valid)
    out = np.zeros(len(valid), dtype=bool)
    if len(idx) < 2:
        return out
    sign = np.array([1.0, -1.0])
    pair = [None] + [
        jump_cost * (1.0 - sign[:, None] * sign[None, :] * float(forward[idx[n - 1]] @ forward[idx[n]])) / 2.0
        for n in range(1, len(idx))
    ]  # [previous label, label]
    out[idx] = viterbi([np.array([0.0, 1.0])] * len(idx), pair).astype(bool)
    return out


def viterbi(unary: Sequence[np.ndarray], pairwise: Sequence[np.ndarray]) -> np.ndarray:
    """The labels (one per step) of the lowest total cost ``sum_n unary[n][l_n] + sum_n
    pairwise[n][l_{n-1}, l_n]``: ``unary[n]`` ``[H_n]`` (a step's own costs), ``pairwise[n]``
    ``[H_{n-1}, H_n]`` for ``n >= 1`` (``pairwise[0]`` is not read). Ties go to the lower label
    (deterministic). Returns ``int [N]`` (empty for no step)."""
    N = len(unary)
    if N == 0:
        return np.zeros(0, dtype=np.int64)
    cost = np.asarray(unary[0], dtype=np.float64)
    back = [np.zeros(len(cost), dtype=np.int64)]
    for n in range(1, N):
        total = cost[:, None] + np.asarray(pairwise[n], dtype=np.float64)  # [previous, current]
        back.append(total.argmin(0))
        cost = total.min(0) + np.asarray(unary[n], dtype=np.float64)
    labels = np.zeros(N, dtype=np.int64)
    labels[-1] = int(cost.argmin())
    for n in range(N - 1, 0, -1):
        labels[n - 1] = int(back[n][labels[n]])
    return labels


def pose_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[H_a, H_b]``: the mean distance between two sets of hypotheses' joints ``[H, J, 3]``, each
    relative to its own root joint (the body's pose and facing, not its place)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a, b = a - a[:, :1], b - b[:, :1]
    return np.linalg.norm(a[:, None] - b[None], axis=-1).mean(-1)


def branch_path(
    energies: Sequence[np.ndarray],
    joints: Sequence[np.ndarray],
    gaps: Sequence[int],
    temporal_weight: float = 1.0,
    temporal_scale: float = 0.02,
) -> np.ndarray:
    """Each frame's hypothesis (``int [N]``) chosen over time: :func:`viterbi` with unary = a frame's
    hypothesis energies ``energies[n] [H_n]`` less the frame's lowest, over the sequence's median
    lowest (so a unit is a typical frame's whole energy), and pairwise = ``temporal_weight`` times the
    root-relative joint distance between consecutive frames' hypotheses (:func:`pose_distances`,
    ``joints[n] [H_n, J, 3]``, metres) over ``temporal_scale`` (metres per frame) times their frame gap
    ``gaps[n]`` (``gaps[0]`` not read)."""
    N = len(energies)
    if N == 0:
        return np.zeros(0, dtype=np.int64)
    energies = [np.asarray(e, dtype=np.float64) for e in energies]
    low = np.array([e[np.isfinite(e)].min() if np.isfinite(e).any() else np.nan for e in energies])
    scale = max(float(np.median(np.abs(low[np.isfinite(low)]))) if np.isfinite(low).any() else 1.0, 1e-12)
    # a non-finite energy (a failed fit) is a candidate only when nothing else is left
    unary = [
        np.where(np.isfinite(e), (e - (lo if np.isfinite(lo) else 0.0)) / scale, 1e12) for e, lo in zip(energies, low)
    ]
    pair = [None] + [
        temporal_weight * pose_distances(joints[n - 1], joints[n]) / (temporal_scale * max(int(gaps[n]), 1))
        for n in range(1, N)
    ]
    return viterbi(unary, pair)


def _windows(F: int, window: int, overlap: int) -> List[int]:
    """Start frames of windows of ``window`` frames covering ``F`` frames, overlapping by
    at least ``overlap``; all windows have the same length (the last starts at ``F - window``)."""
    if window <= 0 or window >= F:
        return [0]
    step = max(window - overlap, 1)
    starts = list(range(0, F - window, step)) + [F - window]
    return sorted(set(starts))


# ----------------------------------------------------------------------------- the fit
def _frame_sets(frames: Sequence[Optional[KeypointSet]], layout: str, cfg: SequenceFitConfig):
    """Keypoint arrays with outliers dropped, and which frames are usable."""
    F = len(frames)
    K = len(next(ks for ks in frames if ks is not None).names)
    xy, conf = np.zeros((F, K, 2)), np.zeros((F, K))
    for f, ks in enumerate(frames):
        if ks is None:
            continue
        if ks.layout != layout:
            raise ValueError(f"{ks.source}: keypoints are {ks.layout}, the sequence's first frame is {layout}")
        xy[f], conf[f] = ks.xy, ks.conf
    outliers = keypoint_outliers(xy, conf, cfg.outlier_jump)
    conf_clean = np.where(outliers, 0.0, conf)
    usable = np.zeros(F, dtype=bool)
    for f, ks in enumerate(frames):
        if ks is None:
            continue
        n = max(int((conf[f] > 0).sum()), 1)
        if outliers[f].sum() / n > cfg.outlier_frame_share:
            continue
        try:
            check_torso(KeypointSet(xy[f], conf_clean[f], layout, source=ks.source))
        except ValueError:
            continue
        usable[f] = True
    return xy, conf_clean, outliers, usable


def _bridge_keypoints(xy, conf, usable) -> List[tuple]:
    """Keypoints for every frame: usable frames their own; the others the nearest usable
    frames' keypoints, interpolated (only for the initial placement: their data weight is
    ``bridge_weight``)."""
    idx = np.flatnonzero(usable)
    out = []
    for f in range(len(usable)):
        if usable[f]:
            out.append((xy[f], conf[f]))
            continue
        before, after = idx[idx < f], idx[idx > f]
        if len(before) and len(after):
            a, b = before[-1], after[0]
            w = (f - a) / (b - a)
            both = (conf[a] > 0) & (conf[b] > 0)
            if both.sum() >= 2:
                out.append(((1 - w) * xy[a] + w * xy[b], np.where(both, 1.0, 0.0)))
                continue
        g = before[-1] if len(before) and (not len(after) or f - before[-1] <= after[0] - f) else after[0]
        out.append((xy[g], conf[g]))
    return out


def _view_columns(grid, layout: str, cfg: SequenceFitConfig):
    """:func:`_frame_sets` for each view's column of ``grid [F][C]``: ``xy [F, C, K, 2]``, ``conf [F, C, K]``
    (outliers dropped), ``outliers [F, C, K]``, ``usable [F, C]`` (a view without any keypoints: zeros)."""
    F, C = len(grid), len(grid[0])
    K = len(next(ks for row in grid for ks in row if ks is not None).names)
    xy, conf = np.zeros((F, C, K, 2)), np.zeros((F, C, K))
    outliers, usable = np.zeros((F, C, K), dtype=bool), np.zeros((F, C), dtype=bool)
    for c in range(C):
        column = [row[c] for row in grid]
        if any(ks is not None for ks in column):
            xy[:, c], conf[:, c], outliers[:, c], usable[:, c] = _frame_sets(column, layout, cfg)
    return xy, conf, outliers, usable


def _view_keypoints(xy, conf, usable) -> List[List[tuple]]:
    """``[F][C]`` (xy, conf) for the refinement: a view's usable frames their own keypoints; in a frame
    usable in another view, none (confidence 0); in a bridged frame (no usable view) each view's
    :func:`_bridge_keypoints` from its own usable frames (only for the placement: data weight
    ``bridge_weight``)."""
    F, C = usable.shape
    frame_ok = usable.any(1)
    cols = [_bridge_keypoints(xy[:, c], conf[:, c], usable[:, c]) if usable[:, c].any() else None for c in range(C)]
    out = []
    for f in range(F):
        row = []
        for c in range(C):
            if cols[c] is None or (frame_ok[f] and not usable[f, c]):
                row.append((xy[f, c], np.zeros_like(conf[f, c])))
            else:
                row.append(cols[c][f])
        out.append(row)
    return out


def _keypoint_set(xy, conf, layout: str) -> KeypointSet:
    """A :class:`KeypointSet`, or for a view with no detection in a frame (every confidence 0, which
    :class:`KeypointSet` refuses) a set of that layout with zero confidences: no data there."""
    if np.any(np.asarray(conf) > 0):
        return KeypointSet(xy, conf, layout)
    empty = KeypointSet.__new__(KeypointSet)
    empty.xy, empty.conf = np.asarray(xy, np.float64), np.zeros(len(conf))
    empty.layout, empty.source = layout, "<no detection>"
    return empty


def _project_views(points: torch.Tensor, views, rig: bool) -> np.ndarray:
    """``[F, C, K, 2]``: points ``[F, K, 3]`` (camera frame for one camera's video, else world) in each view."""
    if not rig:
        return project_points(points, views[0].camera).numpy()[:, None]
    out = []
    for v in views:
        R, t = (torch.as_tensor(a, dtype=points.dtype) for a in v.extrinsics())
        out.append(project_points(points @ R.T + t, v.camera).numpy())
    return np.stack(out, 1)


def _initial_frames(usable_v: np.ndarray, rig: bool, stride: int) -> np.ndarray:
    """The frames the per-frame initialisation fits: every ``stride``-th usable frame and the last (a rig's frames
    seen by one view only are monocular: they start from the frames seen by several)."""
    usable = usable_v.any(1)
    seen = usable_v.sum(1) >= min(2, usable_v.shape[1]) if rig else usable
    seen = seen if seen.any() else usable
    init_frames = np.flatnonzero(seen)[:: max(stride, 1)]
    if np.flatnonzero(seen)[-1] not in init_frames:
        init_frames = np.append(init_frames, np.flatnonzero(seen)[-1])
    return init_frames


def _initialise_frames(
    model, layout, cfg, pose_prior, camera, views, rig: bool, columns, init_frames, progress, depth_cues=None
):
    """Step 2 of :func:`fit_sequence`: ``init_frames`` fitted as one batch (a rig's as one-frame rigs; one camera's with
    the branch choice over time or the neighbour and offset refits; ``depth_cues`` per frame). Returns ``(fitter, per, rebranched)``: the
    keypoint fitter, ``per[name] [F, size]`` (the frames not fitted zero) and the frames put on another depth branch."""
    xy_v, conf_v, usable_v = columns
    F = len(xy_v)
    rebranched = np.zeros(F, dtype=bool)
    fitter = KeypointFitter(model, layout, cfg.keypoint, pose_prior)
    names = tuple(fitter.params.sizes)
    with torch_threads(cfg.keypoint.threads):
        if rig:  # each frame as a one-frame rig (world frame); the triangulated torso starts it: no neighbour starts
            probs = [
                Problem(
                    [
                        Observation(
                            v, _keypoint_set(xy_v[f, c], conf_v[f, c] * usable_v[f, c], layout), frame=0, view_index=c
                        )
                        for c, v in enumerate(views)
                    ]
                )
                for f in init_frames
            ]
            fits = fit_rig_keypoints(fitter, probs, progress=progress)
            state = {n: torch.as_tensor(np.stack([fit.params[n] for fit in fits])) for n in names}
        else:
            probs = [Problem.single(KeypointSet(xy_v[f, 0], conf_v[f, 0], layout), camera) for f in init_frames]
            if cfg.branch_choice.dp:  # several hypotheses per frame; the branch is chosen over time (tuned on refined
                # hypotheses distinct by the mean joint distance alone: the rule before issue 25's warnings)
                fitter = KeypointFitter(
                    model,
                    layout,
                    replace(
                        cfg.keypoint,
                        solutions=Solutions(
                            count=max(int(cfg.branch_choice.hypotheses), 1), joint_max_m=None, unrefined=False
                        ),
                    ),
                    fitter.pose_prior,
                )
            cues = [depth_cues[f] for f in init_frames] if depth_cues is not None else None
            state, info = fitter.fit_problems(probs, progress=progress, depth_cues=cues)
            energy = info["energies"][fitter.stages[-1].name]
            if cfg.branch_choice.dp and len(probs) > 1:
                state, rebranched[init_frames], energy = _choose_branches(
                    model, layout, cfg.keypoint, fitter, probs, state, info, cfg, init_frames, progress
                )
            elif cfg.neighbour_starts and len(probs) > 1:
                state, energy = _refit_from_neighbours(
                    model, layout, cfg.keypoint, fitter, probs, state, info, progress
                )
            if cfg.branch_choice.offsets and len(probs) > 1:
                state, _ = _refit_from_offsets(
                    model,
                    layout,
                    cfg.keypoint,
                    fitter,
                    probs,
                    info["layout"].rows(state),
                    energy,
                    cfg.branch_choice.offsets,
                    progress,
                )
    per = {n: np.zeros((F, fitter.params.sizes[n])) for n in names}
    for n in names:
        v = state[n].double().numpy().reshape(len(init_frames), -1)
        per[n][init_frames] = v
    return fitter, per, rebranched


def _sequence_warnings(bridged: np.ndarray, refaced: np.ndarray, rebranched: np.ndarray) -> list:
    """The warnings of a sequence fit: frames bridged, refaced or put on another depth branch (the first ten named)."""
    F = len(bridged)
    warnings = []
    if bridged.any():
        warnings.append(
            f"{int(bridged.sum())} of {F} frame(s) bridged from their neighbours (no usable keypoints): "
            f"{', '.join(map(str, np.flatnonzero(bridged)[:10]))}{' ...' if bridged.sum() > 10 else ''}"
        )
    if refaced.any():
        warnings.append(f"{int(refaced.sum())} frame(s) had their facing re-initialised from their neighbours")
    if rebranched.any():
        warnings.append(
            f"{int(rebranched.sum())} frame(s) took another depth branch than their lowest-energy one, to agree "
            f"with their neighbours: {', '.join(map(str, np.flatnonzero(rebranched)[:10]))}"
            f"{' ...' if rebranched.sum() > 10 else ''}"
        )
    return warnings


def _refine_jointly(model, layout, cfg, pose_prior, views, columns, start: dict, betas0, names, progress):
    """Step 4 of :func:`fit_sequence`: every frame refined together from ``start`` (one shape ``betas0``, the temporal
    terms; bridged frames weighed by ``cfg.bridge_weight``), in overlapping windows where the video is longer than
    ``cfg.window`` (one shape over the windows, then their poses again). Returns ``(final, refiner)``."""
    xy_v, conf_v, usable_v = columns
    F, C = len(xy_v), len(views)
    usable = usable_v.any(1)
    kps = _view_keypoints(xy_v, conf_v, usable_v)
    weights = np.where(usable, 1.0, float(cfg.bridge_weight))
    refiner_cfg = replace(
        cfg.keypoint,
        starts=replace(cfg.keypoint.starts, flip=False, poses=1),
        branches=replace(cfg.keypoint.branches, search=False),
        temporal=replace(cfg.keypoint.temporal, sigma=cfg.temporal_sigma),
        schedule=cfg.stages(views=C),
    )
    refiner = KeypointFitter(model, layout, refiner_cfg, pose_prior)
    starts = _windows(F, int(cfg.window), int(cfg.overlap))
    L = F if len(starts) == 1 else int(cfg.window)

    def problems_and_init(betas):
        probs, init, fw = [], {n: [] for n in names}, []
        for s in starts:
            obs = [
                Observation(v, _keypoint_set(*kps[f][c], layout), frame=f - s, view_index=c)
                for f in range(s, s + L)
                for c, v in enumerate(views)
            ]
            probs.append(Problem(obs))
            for n in names:
                init[n].append(betas if n == "betas" else start[n][s : s + L])
            fw.append(weights[s : s + L])
        return probs, {n: np.stack(v) for n, v in init.items()}, np.stack(fw)

    with torch_threads(cfg.keypoint.threads):
        probs, init, fw = problems_and_init(betas0)
        state, info = refiner.fit_problems(probs, progress=progress, init=init, frame_weights=fw)
        if len(starts) > 1:  # one shape: the windows' mean (by frames), then the poses again with it fixed
            betas0 = state["betas"].double().numpy().mean(0)
            refiner.stages = cfg.stages(free_betas=False, iterations=cfg.window_pose_iterations, views=C)
            merged = _merge_windows({n: state[n].double().numpy() for n in names if n != "betas"}, starts, F)
            start = merged
            probs, init, fw = problems_and_init(betas0)
            state, info = refiner.fit_problems(probs, progress=progress, init=init, frame_weights=fw)
    final = _merge_windows({n: state[n].double().numpy() for n in names if n != "betas"}, starts, F)
    final["betas"] = state["betas"].double().numpy().mean(0) if len(starts) == 1 else betas0
    return final, refiner


def _frame_grid(frames, camera) -> tuple:
    """``(rig, views, grid, layout)`` of :func:`fit_sequence`'s inputs: ``grid[f][c]`` the keypoints of frame ``f`` in
    view ``c`` (one view for one camera's video); a frame without an entry per view, or no keypoints at all, is refused."""
    rig = not isinstance(camera, Camera)
    views = list(camera) if rig else [View(camera)]
    grid = [list(row) for row in frames] if rig else [[ks] for ks in frames]
    if any(len(row) != len(views) for row in grid):
        raise ValueError(f"every frame needs one entry per view ({len(views)})")
    if not grid or all(ks is None for row in grid for ks in row):
        raise ValueError("the sequence has no frame with keypoints")
    layout = next(ks for row in grid for ks in row if ks is not None).layout
    return rig, views, grid, layout


def _median_reprojection(kp2d, xy_v, conf_v, usable_v) -> np.ndarray:
    """``[F, C]`` the median distance (px) of each usable frame's and view's confident keypoints from the fit's; NaN
    elsewhere."""
    F, C = usable_v.shape
    err = np.linalg.norm(kp2d - xy_v, axis=-1)
    return np.array(
        [
            [
                np.median(err[f, c][conf_v[f, c] > 0]) if (conf_v[f, c] > 0).any() and usable_v[f, c] else np.nan
                for c in range(C)
            ]
            for f in range(F)
        ]
    )


def _refaced_frames(orient: np.ndarray, known: np.ndarray, views, rig: bool, jump_cost: float) -> np.ndarray:
    """Step 3 of :func:`fit_sequence`: the frames whose facing disagrees with their neighbours' (one view; several: the
    triangulated torso gives each frame's facing, none refaced)."""
    if len(views) != 1:
        return np.zeros(len(orient), dtype=bool)
    if rig:  # the facing as the view's camera sees it
        orient = (Rotation.from_matrix(views[0].extrinsics()[0]) * Rotation.from_rotvec(orient)).as_rotvec()
    return consistent_facings(body_forward(orient), known, jump_cost)


def _posed_outputs(refiner, final: dict, names, views, rig: bool, columns: tuple, outliers) -> tuple:
    """:func:`fit_sequence`'s outputs of the refined parameters ``final``: ``(joints, keypoints_2d, reprojection
    errors, outliers)`` (``columns``: :func:`_view_columns`' ``(xy, conf, usable)``; one camera: no view axis)."""
    xy_v, conf_v, usable_v = columns
    F = len(xy_v)
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=refiner.dtype)  # noqa: E731
    with torch.no_grad():
        rows = {n: T(np.repeat(final[n][None], F, 0) if n == "betas" else final[n]) for n in names}
        body = refiner.body(**rows)
        kp2d = _project_views(body.keypoints.double(), views, rig)  # [F, C, K, 2]
    reproj = _median_reprojection(kp2d, xy_v, conf_v, usable_v)
    if not rig:  # one camera's video: no view axis
        kp2d, reproj, outliers = kp2d[:, 0], reproj[:, 0], outliers[:, 0]
    return body.joints.numpy(), kp2d, reproj, outliers


def _sequence_timings(t0: float, t_init: float, t_refine: float, F: int) -> dict:
    """:func:`fit_sequence`'s ``timings`` (seconds; ``t0`` its start) of ``F`` frames."""
    return {
        "per_frame_init": t_init,
        "refine": t_refine,
        "total": time.perf_counter() - t0,
        "frames": F,
        "seconds_per_frame": (time.perf_counter() - t0) / F,
    }


def _refinement_start(per: dict, known, names: tuple, views, rig: bool, cfg: SequenceFitConfig) -> tuple:
    """Step 3 of :func:`fit_sequence`, from the per-frame fits ``per`` of the ``known`` frames: ``(refaced, betas0,
    per_frame, start)``, the frames refaced, the median shape, the per-frame fit interpolated (betas per frame too) and
    the refinement's start (the refaced frames interpolated too)."""
    refaced = _refaced_frames(per["global_orient"], known, views, rig, cfg.facing_jump_cost)
    betas0 = np.median(per["betas"][known], 0)
    per_frame = interpolate_frames(per, known)  # the per-frame fit (betas per frame too)
    start = interpolate_frames({n: per[n] for n in names if n != "betas"}, known & ~refaced)
    return refaced, betas0, per_frame, start


def _sequence_result(
    final: dict, names: tuple, posed: tuple, flags: tuple, per_frame: dict, timings: dict, views, camera, layout, cfg
) -> SequenceFitResult:
    """:func:`fit_sequence`'s result: the refined parameters ``final``, ``posed`` (:func:`_posed_outputs`), ``flags``
    per frame ``(bridged, refaced, rebranched)``, the per-frame fit; ``views`` a rig's (``None``: one camera's)."""
    joints, kp2d, reproj, outliers = posed
    bridged, refaced, rebranched = flags
    warnings = _sequence_warnings(bridged, refaced, rebranched)
    f32 = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    return SequenceFitResult(
        betas=f32(final["betas"]),
        body_pose=f32(final["body_pose"]),
        global_orient=f32(final["global_orient"]),
        transl=f32(final["transl"]),
        camera=camera,
        joints=f32(joints),
        keypoints_2d=f32(kp2d),
        bridged=bridged,
        refaced=refaced,
        rebranched=rebranched,
        outliers=outliers,
        reprojection_error=reproj,
        per_frame={n: f32(v) for n, v in per_frame.items()},
        extra={n: f32(final[n]) for n in names if n not in ("betas", "body_pose", "global_orient", "transl")},
        timings=timings,
        layout=layout,
        config=cfg.to_dict(),
        warnings=warnings,
        views=views,
    )


def fit_sequence(
    frames: Sequence,
    camera,
    model=None,
    *,
    config: Optional[SequenceFitConfig] = None,
    pose_prior=None,
    progress: bool = False,
    depth_cues: Optional[Sequence] = None,
) -> SequenceFitResult:
    """Fit one person over a sequence of frames of one camera, or of a calibrated rig (module docstring).

    ``depth_cues`` (one camera; per frame a :class:`~silfit.fitting.image_depth.DepthCue` from its image or
    ``None``): each frame's start fit and its hypotheses, from which the branch is chosen over time, carry the
    image depth cue (the ``image_depth`` term).

    ``frames``: one :class:`~silfit.io.keypoints.KeypointSet` per frame, ``None`` where no person was
    detected, with ``camera`` a :class:`~silfit.camera.Camera` (the fit in its frame); or, for a rig
    video, ``frames[f][c]`` per view with ``camera`` a list of :class:`~silfit.fitting.problem.View` s
    (the fit in their world frame: every frame's initialisation the rig's keypoint stage,
    :func:`~silfit.fitting.rig_fit.fit_rig_keypoints`; the refinement over frames x views). At least
    one frame must have usable keypoints (in some view)."""
    cfg = config or SequenceFitConfig()
    model = load_body_model() if model is None else model
    rig, views, grid, layout = _frame_grid(frames, camera)
    F = len(grid)
    t0 = time.perf_counter()
    xy_v, conf_v, outliers, usable_v = _view_columns(grid, layout, cfg)
    usable = usable_v.any(1)
    if not usable.any():
        raise ValueError(f"no frame of the sequence has enough confident torso keypoints (of {F} frames)")
    init_frames = _initial_frames(usable_v, rig, int(cfg.init_stride))

    # 2. per-frame initialisation, the usable frames as one batch
    fitter, per, rebranched = _initialise_frames(
        model, layout, cfg, pose_prior, camera, views, rig, (xy_v, conf_v, usable_v), init_frames, progress, depth_cues
    )
    names = tuple(fitter.params.sizes)
    t_init = time.perf_counter() - t0
    known = np.zeros(F, dtype=bool)
    known[init_frames] = True

    # 3. consistent facings (one view; several: the triangulated torso gives each frame's facing)
    refaced, betas0, per_frame, start = _refinement_start(per, known, names, views, rig, cfg)

    # 4. joint refinement
    bridged = ~usable
    t1 = time.perf_counter()
    final, refiner = _refine_jointly(
        model, layout, cfg, fitter.pose_prior, views, (xy_v, conf_v, usable_v), start, betas0, names, progress
    )
    t_refine = time.perf_counter() - t1

    # outputs
    joints, kp2d, reproj, outliers = _posed_outputs(
        refiner, final, names, views, rig, (xy_v, conf_v, usable_v), outliers
    )
    return _sequence_result(
        final,
        names,
        (joints, kp2d, reproj, outliers),
        (bridged, refaced, rebranched),
        per_frame,
        _sequence_timings(t0, t_init, t_refine, F),
        views if rig else None,
        views[0].camera,
        layout,
        cfg,
    )


def _fits_from(model, layout, config, fitter, probs, state, own, src, progress):
    """Frame ``own[m]``'s problem fitted from frame ``src[m]``'s parameters in ``state``, one start each,
    all in one batch: ``(state, energy [M])`` (energies of the final stage, as ``fitter``'s)."""
    again = KeypointFitter(
        model,
        layout,
        replace(
            config,
            starts=replace(config.starts, flip=False, poses=1),
            branches=replace(config.branches, search=False),
            solutions=replace(config.solutions, count=1),
            final_iters_unsearched=None,
        ),
        fitter.pose_prior,
    )
    # (the final stage as the frames' own fits ran it, so their energies compare)
    start = {k: v[torch.as_tensor(src)].double().numpy() for k, v in state.items()}
    nb_state, nb_info = again.fit_problems([probs[i] for i in own], progress=progress, init=start)
    return nb_state, nb_info["energies"][again.stages[-1].name]


def _neighbour_fits(model, layout, config, fitter, probs, state, progress):
    """Each frame fitted again from its previous and next frame's fit (the first frame from the next,
    the last from the previous), one start each, all in one batch: ``(frame [M], state, energy [M])``,
    row ``m`` a fit of frame ``frame[m]``'s problem (energies of the final stage, as ``fitter``'s)."""
    n = len(probs)
    src = [np.r_[1, np.arange(n - 1)]]  # the previous frame (the first frame: the next)
    if n > 2:
        src.append(np.r_[np.arange(1, n), n - 2])  # the next frame (the last frame: the previous)
    src = np.concatenate(src)
    own = np.tile(np.arange(n), len(src) // n)  # row m fits frame own[m], started from frame src[m]'s fit
    return (own, *_fits_from(model, layout, config, fitter, probs, state, own, src, progress))


def _refit_from_neighbours(model, layout, config, fitter, probs, state, info, progress):
    """Each frame fitted again from its previous and next frame's fit (:func:`_neighbour_fits`); each
    frame keeps the lowest final energy of its own fit and these (near-ties: its own). Returns the kept
    state and its energies ``[n]``."""
    n = len(probs)
    own, nb_state, nb_energy = _neighbour_fits(model, layout, config, fitter, probs, state, progress)
    energy = torch.cat([info["energies"][fitter.stages[-1].name], nb_energy])
    rows = best_per_group(energy, torch.cat([torch.arange(n), torch.as_tensor(own)]), n)
    return {k: torch.cat([v, nb_state[k].to(v.dtype)])[rows] for k, v in state.items()}, energy[rows]


def _neighbour_sources(i: int, n: int, offsets) -> List[int]:
    """The frames (of ``n``) whose picks start frame ``i``'s refits in the offsets round: ``i - o`` and
    ``i + o`` for each offset ``o`` in order, those inside the sequence, each once, never ``i`` itself."""
    out = []
    for o in offsets or ():
        for j in (i - int(o), i + int(o)):
            if 0 <= j < n and j != i and j not in out:
                out.append(j)
    return out


def _refit_from_offsets(model, layout, config, fitter, probs, state, energy, offsets, progress):
    """Each frame fitted again from the picks of the frames ``offsets`` away (:func:`_neighbour_sources`,
    one batch); each keeps the lowest final energy of its pick (``state`` ``{name: [n, w]}``, ``energy [n]``)
    and these refits (near-ties: its pick). Returns the kept state ``{name: [n, w]}`` and its energies ``[n]``."""
    n = len(probs)
    pairs = [(i, j) for i in range(n) for j in _neighbour_sources(i, n, offsets)]
    if not pairs:
        return state, torch.as_tensor(energy, dtype=torch.float64).reshape(-1)
    own, src = (np.array(a) for a in zip(*pairs))
    nb_state, nb_energy = _fits_from(model, layout, config, fitter, probs, state, own, src, progress)
    nb_rows = {k: v.reshape(len(own), -1) for k, v in nb_state.items()}
    energy = torch.cat([torch.as_tensor(energy, dtype=torch.float64).reshape(-1), nb_energy.double()])
    rows = best_per_group(energy, torch.cat([torch.arange(n), torch.as_tensor(own)]), n)
    return {k: torch.cat([v.double().reshape(n, -1), nb_rows[k].double()])[rows] for k, v in state.items()}, energy[
        rows
    ]


def _choose_branches(model, layout, config, fitter, probs, state, info, cfg, frames, progress):
    """The branch over time: each frame's candidates are its hypotheses (``info["hypotheses"]``, or its
    fit) and, with ``cfg.neighbour_starts``, its refits from its neighbours' fits (:func:`_neighbour_fits`);
    :func:`branch_path` picks one per frame (``frames``: the frames' indices, for the gaps). Each further
    round of ``cfg.branch_choice.rounds`` refits every frame from its neighbours' chosen candidates, adds those to
    the candidates and picks again (a right branch spreads one frame per round into a run of frames whose
    own fits all took the wrong one). Returns the chosen state (``{name: [n, w]}``) and ``rebranched [n]``:
    the frame's choice is not its lowest-energy candidate (joints more than ``DISTINCT_JOINTS_M`` apart, mean),
    and the chosen candidates' energies ``[n]``."""
    n = len(probs)
    last = fitter.stages[-1].name
    rows = info["layout"].rows(state)
    cand = {k: [] for k in rows}
    energy, owner = [], []

    def add(params, e, b):
        for k in cand:
            cand[k].append(np.asarray(params[k], dtype=np.float64).reshape(-1))
        energy.append(float(e))
        owner.append(int(b))

    def add_refits(start):
        own, nb_state, nb_energy = _neighbour_fits(model, layout, config, fitter, probs, start, progress)
        nb_rows = info["layout"].rows(nb_state)
        for m, b in enumerate(own.tolist()):
            add({k: v[m].double().numpy() for k, v in nb_rows.items()}, nb_energy[m], b)

    for b in range(n):
        hyps = (info.get("hypotheses") or [None] * n)[b]
        for h in hyps or [
            {"params": {k: v[b].double().numpy() for k, v in rows.items()}, "energy": info["energies"][last][b]}
        ]:
            add(h["params"], h["energy"], b)
    gaps = np.r_[1, np.diff(np.asarray(frames))]
    rounds = max(int(cfg.branch_choice.rounds), 1) if cfg.neighbour_starts and n > 1 else 1
    if cfg.neighbour_starts and n > 1:
        add_refits(state)
    for r in range(rounds):
        params = {k: np.stack(v) for k, v in cand.items()}
        e, own = np.asarray(energy), np.asarray(owner)
        with torch.no_grad():  # only the new candidates' joints would do; the sequence's are few enough
            joints = (
                fitter.body(**{k: torch.as_tensor(v, dtype=fitter.dtype) for k, v in params.items()})
                .joints.double()
                .numpy()
            )
        per = [np.flatnonzero(own == b) for b in range(n)]
        pick = branch_path(
            [e[i] for i in per],
            [joints[i] for i in per],
            gaps,
            cfg.branch_choice.temporal_weight,
            cfg.branch_choice.temporal_scale,
        )
        chosen = np.array([i[p] for i, p in zip(per, pick)])
        if r + 1 < rounds:
            add_refits({k: torch.as_tensor(v[chosen]) for k, v in params.items()})
    e = np.where(np.isfinite(e), e, np.inf)
    lowest = np.array([i[int(np.argmin(e[i]))] for i in per])  # the first of tied ones
    moved = np.linalg.norm(joints[chosen] - joints[lowest], axis=-1).mean(-1)
    return (
        {k: torch.as_tensor(v[chosen]) for k, v in params.items()},
        moved > DISTINCT_JOINTS_M,
        torch.as_tensor(e[chosen]),
    )


def _merge_windows(params: Dict[str, np.ndarray], starts: List[int], F: int) -> Dict[str, np.ndarray]:
    """Per-frame values ``[F, w]`` from windows ``[P, L, w]``: each frame from the window in
    which it lies farthest from an edge."""
    L = next(iter(params.values())).shape[1]
    owner, where, best = np.zeros(F, dtype=np.int64), np.zeros(F, dtype=np.int64), np.full(F, -1.0)
    for p, s in enumerate(starts):
        for i in range(L):  # distance to the window's nearest inner edge (a sequence end is no edge)
            margin = min(i if s > 0 else math.inf, L - 1 - i if s + L < F else math.inf)
            if margin > best[s + i]:
                best[s + i], owner[s + i], where[s + i] = margin, p, i
    return {n: v[owner, where] for n, v in params.items()}


# ----------------------------------------------------------------------------- silhouettes
#: weights of the temporal terms in the silhouette stage's energy (its terms are in window
#: pixels with normalised keypoint weights: about 1/20,000 of the keypoint stage's scale,
#: as its pose-prior weight is)
SILHOUETTE_TEMPORAL_WEIGHT = 5e-5


def _cut_off_frames(masks, views: int = 1) -> List[str]:
    """One warning naming the frames whose mask runs out of the image (:func:`silfit.fitting.plausibility.mask_warnings`);
    ``masks`` frame-major over ``views`` views."""
    cut = sorted({i // views for i, m in enumerate(masks) if m is not None and mask_warnings(m)})
    if not cut:
        return []
    return [
        f"frame(s) {', '.join(map(str, cut[:10]))}{' ...' if len(cut) > 10 else ''}: the person runs out of the image "
        "(cut off); the body beyond the border rests on the keypoints and priors only"
    ]


def finite_median(values) -> Optional[float]:
    """The median of the finite values (``None`` when there is none)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else None


def _mask_grid(masks, rig: bool) -> tuple:
    """``(mgrid, empty)``: ``mgrid[f][c]`` the masks per frame and view, an empty one (the person not segmented in
    that frame) as ``None`` (a frame without a silhouette term), and the frames that had one."""
    mgrid = [list(row) for row in masks] if rig else [[m] for m in masks]
    empty = sorted({f for f, row in enumerate(mgrid) for m in row if m is not None and not np.any(m)})
    return [[None if (m is not None and not np.any(m)) else m for m in row] for row in mgrid], empty


def _silhouette_observations(grid, mgrid, views, outliers, bridged) -> list:
    """The silhouette stage's observations per frame and view: the mask, and the keypoints without the outliers (none
    for a bridged frame; a whole-body set's hands and face at zero confidence: not optimised here)."""
    obs = []
    for f in range(len(grid)):
        for c, view in enumerate(views):
            ks = grid[f][c]
            if ks is not None and not bridged[f]:
                conf = np.where(outliers[f, c], 0.0, ks.conf)
                if ks.layout == "wholebody":  # hands and face stay as the keypoint fit left them (not optimised here)
                    conf = conf.copy()
                    conf[part_slices()["body"].stop :] = 0.0
                ks = KeypointSet(ks.xy, conf, ks.layout, ks.source) if (conf > 0).any() else None
            else:
                ks = None
            obs.append(Observation(view, ks, mgrid[f][c], frame=f, view_index=c))
    return obs


def _keypoint_reprojection(grid, kp2d, outliers, bridged) -> np.ndarray:
    """``[F, C]`` the median reprojection error (px) against the keypoints the keypoint stage's error was measured on
    (outliers and bridged frames left out; a whole-body fit's hands and face too), so before and after compare alike."""
    F, C = len(grid), len(grid[0]) if grid else 0
    reproj = np.full((F, C), np.nan)
    for f in range(F):
        for c in range(C):
            ks = grid[f][c]
            if ks is not None and not bridged[f]:
                ok = (ks.conf > 0) & ~outliers[f, c]
                if ok.any():
                    reproj[f, c] = np.median(np.linalg.norm(kp2d[f, c] - ks.xy, axis=-1)[ok])
    return reproj


def _with_parameters(result, p: dict, betas, joints, kp2d, reproj, timings, warnings) -> SequenceFitResult:
    """A copy of ``result`` with the silhouette stage's parameters ``p`` (one ``betas``), joints, projected keypoints
    and reprojection errors (the keypoint stage's kept beside), ``timings`` and ``warnings``."""
    return replace(
        result,
        betas=betas,
        body_pose=np.asarray(p["body_pose"], np.float32),
        extra={n: np.asarray(p[n], np.float32) for n in result.extra},
        global_orient=np.asarray(p["global_orient"], np.float32),
        transl=np.asarray(p["transl"], np.float32),
        joints=np.asarray(joints, np.float32),
        keypoints_2d=np.asarray(kp2d, np.float32),
        reprojection_error=reproj,
        reprojection_error_keypoint_stage=result.reprojection_error,
        timings=timings,
        warnings=warnings,
    )


def _posed_sequence(model, result: SequenceFitResult, p: dict, betas, names: list, views, grid, outliers) -> tuple:
    """:func:`refine_sequence_silhouettes`' parameters ``p`` (one ``betas``) posed: ``(joints, keypoints_2d,
    reprojection errors)`` per frame (and view, in a rig; one camera: no view axis)."""
    F, rig = result.num_frames, result.views is not None
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=model.dtype)  # noqa: E731
    with torch.no_grad():
        body = model(**{n: T(np.repeat(betas[None], F, 0) if n == "betas" else p[n]) for n in names})
        joints = body.joints.numpy()
        kp2d = _project_views(model_keypoints(model, body, result.layout).double(), views, rig)  # [F, C, K, 2]
    reproj = _keypoint_reprojection(grid, kp2d, outliers, result.bridged)
    if not rig:
        kp2d, reproj = kp2d[:, 0], reproj[:, 0]
    return joints, kp2d, reproj


def _refined_sequence_warnings(result: SequenceFitResult, sil, reproj, betas, mgrid, C: int, empty: list) -> list:
    """:func:`refine_sequence_silhouettes`' warnings where its result is kept: the keypoint fit's, the silhouette
    stage's, a risen reprojection error, the shape's, masks cut off at the image border, frames with an empty mask."""
    return (
        list(result.warnings)
        + list(sil.warnings)
        + reprojection_rise_warnings(finite_median(result.reprojection_error), finite_median(reproj))
        + shape_warnings(betas)
        + _cut_off_frames([m for row in mgrid for m in row], C)
        + ([f"{len(empty)} frame(s) with an empty mask had no silhouette term: {empty[:10]}"] if empty else [])
    )


def refine_sequence_silhouettes(
    model,
    result: SequenceFitResult,
    frames: Sequence[Optional[KeypointSet]],
    masks: Sequence[Optional[np.ndarray]],
    *,
    config=None,
    temporal_weight: float = SILHOUETTE_TEMPORAL_WEIGHT,
    pose_prior=None,
    progress: bool = False,
) -> SequenceFitResult:
    """The silhouette stage on a sequence fit: the one driver (:func:`~silfit.fitting.refine.refine_silhouettes`)
    with a video's hooks (:class:`SequenceRefinement`, which says what it returns)."""
    hooks = SequenceRefinement(result, frames, masks, temporal_weight)
    (out,) = refine_silhouettes(model, hooks, config, pose_prior, progress=progress)
    return out


class SequenceRefinement(SilhouetteHooks):
    """A sequence fit's hooks of the one silhouette driver (:func:`~silfit.fitting.refine.refine_silhouettes`): one
    problem of ``F`` frames (one shared ``betas``), each frame's mask (``None``: no silhouette term there) and
    keypoints (outliers and bridged frames left out), with the temporal terms of the keypoint refinement (weight
    ``temporal_weight``) in its energy. Read back as a copy of ``result`` with the refined parameters, joints,
    projected keypoints and reprojection errors (the keypoint stage's kept in ``reprojection_error_keypoint_stage``);
    ``per_frame`` is kept, and ``timings["silhouette"]`` and ``silhouette_iou`` (per frame, NaN without a mask) are
    added; a refined fit the plausibility guard finds less plausible is not kept.

    A rig video's fit (``result.views``): ``frames[f][c]`` and ``masks[f][c]`` per view, every view's
    mask rendered in its camera (the keypoint stage's extrinsics), results per frame and view."""

    def __init__(self, result: SequenceFitResult, frames, masks, temporal_weight: float = SILHOUETTE_TEMPORAL_WEIGHT):
        F = result.num_frames
        if len(masks) != F or len(frames) != F:
            raise ValueError(f"{len(masks)} masks and {len(frames)} keypoint frames for a fit of {F} frames")
        self.result, self.rig = result, result.views is not None
        self.views = result.views if self.rig else [View(result.camera)]
        self.grid = [list(row) for row in frames] if self.rig else [[ks] for ks in frames]
        self.mgrid, self.empty = _mask_grid(masks, self.rig)
        if all(m is None for row in self.mgrid for m in row):
            raise ValueError("the sequence's silhouette stage needs at least one non-empty mask")
        self.outliers = result.outliers if self.rig else result.outliers[:, None]
        if len(self.views) > 1:  # several views: the keypoint refinement's scale of the temporal weights
            temporal_weight = temporal_weight * float(result.config.get("views_smooth_scale", 1.0))
        self.temporal_weight = temporal_weight

    def prepare(self, model, config):
        """A small model rendered whole (no proxy)."""
        if config.proxy_faces and int(config.proxy_faces) >= int(model.faces.shape[0]):
            config = replace(config, proxy_faces=None)
        return config

    def starts(self, config) -> list:
        self.init = self.result.params()
        return [self.init]

    def inputs(self, model, problems: List[int], config) -> StageInputs:
        """The one problem (:func:`_silhouette_observations`) with the temporal terms (``result``'s
        ``temporal_sigma``)."""
        obs = _silhouette_observations(self.grid, self.mgrid, self.views, self.outliers, self.result.bridged)
        sigma, w = self.result.config.get("temporal_sigma", 10.0), self.temporal_weight
        terms = (JointSmoothnessTerm(sigma=sigma), RootSmoothnessTerm(sigma=sigma))
        return StageInputs([Problem(obs)], self.result.layout, config, terms, {"smooth_joints": w, "smooth_root": w})

    def read_back(self, model, sils: list, config, seconds: float) -> List[SequenceFitResult]:
        """The refined sequence, or (the plausibility guard) the keypoint fit's with the guard's warnings."""
        (sil,), result, F = sils, self.result, self.result.num_frames
        p = sil.params()
        betas = np.asarray(p["betas"], dtype=np.float32).reshape(-1)
        joints, kp2d, reproj = _posed_sequence(
            model, result, p, betas, list(self.init), self.views, self.grid, self.outliers
        )
        timings = dict(result.timings, silhouette=seconds, total=result.timings["total"] + seconds)
        timings["seconds_per_frame"] = timings["total"] / F
        # the plausibility guard, as for one image: a refined fit less plausible than the keypoint fit it started from
        # (median reprojection error over the frames, |betas|, stature) is not kept
        guard = guard_fit(
            model, finite_median(result.reprojection_error), result.betas, finite_median(reproj), betas, "video"
        )
        if guard.reverted and getattr(config, "plausibility_guard", True):
            warnings = list(result.warnings) + list(sil.warnings) + list(guard.warnings)
            return [replace(result, timings=timings, warnings=warnings)]
        warnings = _refined_sequence_warnings(result, sil, reproj, betas, self.mgrid, len(self.views), self.empty)
        out = _with_parameters(result, p, betas, joints, kp2d, reproj, timings, warnings)
        ious = np.array(sil.ious, dtype=np.float64).reshape(F, len(self.views))
        out.silhouette_iou, out.silhouette_iou_start = (ious if self.rig else ious[:, 0]), float(sil.iou_start)
        return [out]


class VideoCore(Core):
    """A video of one camera (``frames[f]``, ``masks[f]``, ``cameras`` its camera) or of a rig (``frames[f][c]``,
    ``masks[f][c]``, ``cameras`` the views) as the core of :func:`~silfit.fitting.cores.run_steps`: one row, the
    keypoint stage :func:`fit_sequence` (bridging, facings, the temporal terms; ``depth_cues`` per frame, or
    ``None``), then, with ``silhouette``, the sequence's silhouette stage (:class:`SequenceRefinement`).
    ``cue_records``: per frame what the image depth cue decided, for ``metrics.json`` (``None``: no cue)."""

    size = 1

    def __init__(
        self,
        frames,
        cameras,
        masks,
        model,
        config: SequenceFitConfig,
        *,
        pose_prior=None,
        progress: bool = False,
        silhouette: bool = False,
        silhouette_config=None,
        depth_cues: Optional[list] = None,
        cue_records: Optional[list] = None,
    ):
        self.frames, self.cameras, self.masks, self.model, self.config = frames, cameras, masks, model, config
        self.pose_prior, self.progress = pose_prior, progress
        self.silhouette, self.silhouette_config = silhouette, silhouette_config
        self.depth_cues, self.cue_records = depth_cues, cue_records  # per frame: the cue and its metrics.json record

    def keypoint_stage(self, rows: list) -> list:
        return [
            fit_sequence(
                self.frames,
                self.cameras,
                self.model,
                config=self.config,
                pose_prior=self.pose_prior,
                progress=self.progress,
                depth_cues=self.depth_cues,
            )
        ]

    def silhouette_rows(self, rows: list, kp: dict) -> list:
        return list(rows) if self.silhouette else []

    def silhouette_hooks(self, rows: list, kp: dict):
        yield rows, SequenceRefinement(kp[0], self.frames, self.masks)

    def results(self, kp: dict, refined: dict) -> List[SequenceFitResult]:
        return [refined.get(0, kp[0])]
