"""The keypoint stage: SMPLify in torch, batched.

Stages (each an independent per-sample L-BFGS, see :mod:`silfit.fitting.optim`):

1. ``init``: depth by similar triangles (the model's rest torso length vs the 2D torso
   length), translation from the 2D torso centre, in-plane roll from the 2D torso
   direction; two starts per sample, facing the camera and the 180-degree flipped one
   (a doubled batch).
2. ``camera``: ``global_orient`` and ``transl`` on the torso keypoints, with a depth
   regulariser towards the similar-triangles depth.
3. ``pose_1..3``: ``body_pose`` (+ orientation, translation) on all keypoints with the
   pose prior weight annealed from high to low. ``pose_1`` starts every placed start
   (facing / flipped) from several initial body poses (the zero pose and the pose prior's
   most probable means, ``starts.poses``), all in one batch; after ``decision_iters`` steps
   each sample keeps the start with the lowest energy: the torso alone cannot tell a side
   view's facing, the nose, ears and feet can, and a good initial pose avoids the wrong
   branch of the depth ambiguity of bent limbs.
   ``branches_1`` (after ``pose_2``, one view): the limb-branch search
   (:mod:`silfit.fitting.branches`, ``branches.search``).
4. ``shape``: ``betas`` (+ translation) with the L2 shape prior.
5. ``branches_late`` (one view, ``branches.late_iters``): the limb-branch search again, at the
   final stage's weights from the refined pose; its ``branches.refine`` (4) best go on (its ``carry``).
   ``settle`` (after a search only): each runs the final stage; the lowest energy goes on.
   ``branches_post`` (one view, ``branches.post_iters``): the search once more, from that converged
   fit; its ``branches.refine`` (4) best go on.
6. ``final``: everything together with the interpenetration penalty on (120 steps, a row stopping
   once a step lowers its energy by less than 1e-4; 40, every one run, where no search ran), on each
   branch still in play; the lowest final energy is the fit.

Several calibrated views (rigs): the body is placed from the triangulated torso, there is no flip
test and no branch search, and the ``points`` term (:class:`~silfit.fitting.terms.PointsTerm`, the
keypoints triangulated from the views) joins the pose, shape and final stages.

Whole-body fitting (an SMPL-X-layout model and the ``wholebody`` keypoint layout, SMPLify-X's
schedule): the body stages as above, the hand and face keypoint terms (``hands``, ``face``, each
its own robust scale) weigh nothing while the body is placed and are switched on and raised over
the later stages (``hands_face.hand_weights``/``face_weights`` per pose stage, then the final weights; a
``hands`` stage first starts each hand from its best library pose and wrist turn); the
hand poses, jaw and expression are free where their terms are on, with their priors (``hand_pose``:
:class:`~silfit.priors.smplx_priors.HandPosePrior`; ``jaw``, ``expression``: L2). A part with no
confident point (a missing hand, a body-only file) is held at rest in every stage by a gate
(:func:`~silfit.fitting.stages.gated`).

Data term: Geman-McClure (SMPLify's robust penalty, ``keypoint_term.sigma`` = 100) on residuals in
*normalised pixels*: each sample's residuals are scaled so the extent of its confident
keypoints is ``keypoint_term.norm_extent`` (500) pixels, which makes the weights independent of the
image resolution and of how large the person appears. Each keypoint is weighted by its
confidence times a per-keypoint weight (hips 0.5: SMPL's hip joints sit higher and
further inside than detectors' hip points). Zero-confidence keypoints contribute
nothing.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace
from typing import Optional, Sequence, Union

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..body import load_body_model, model_in_dtype
from ..camera import UPRIGHT_BACK_TO_CAMERA, UPRIGHT_FACING_CAMERA, Camera
from ..io.fit import model_record
from ..io.keypoints import LAYOUTS, KeypointSet
from ..priors import SphereCollisionModel, angle_prior, limit_violation, load_pose_prior, shape_prior
from ..priors.smplx_priors import body_prior_for
from .body import KeypointBody
from .hands_face import choose_hand_starts, part_gates, wholebody_terms
from .image_depth import ImageDepthTerm, cue_data, cue_disagrees, cue_hypotheses, demote_disagreeing, hard_calls
from .occlusion import OcclusionTerm
from .branches import LIMB_SEGMENTS, TORSO_SEGMENT, limb_hypotheses, turn_hypotheses
from .problem import ParameterLayout, Problem, stack_views
from .result import PARAM_NAMES, KeypointFitResult
from .aliases import Alias, flat_dict, grouped, renamed_fields
from .schedule_edits import keypoint_defaults, keypoint_stages
from .stages import Stage, check_stages, run_stage, stage_to_dict
from .terms import (
    DepthTerm,
    Energy,
    InterpenetrationTerm,
    JointSmoothnessTerm,
    KeypointTerm,
    PointsTerm,
    PriorTerm,
    RootSmoothnessTerm,
    evaluate,
)
from .triangulate import placement_to_world, projection_matrices, robust_triangulate, torso_placement, triangulate_views
from .threads import torch_threads

__all__ = [
    "BranchSearch",
    "HandsFace",
    "ImageDepthOptions",
    "KeypointFitConfig",
    "KeypointFitter",
    "KeypointTermOptions",
    "OcclusionOptions",
    "Solutions",
    "Starts",
    "TemporalOptions",
    "fit_keypoints",
    "prepare_keypoints",
]

_UPPER = ("left_shoulder", "right_shoulder", "neck")
_LOWER = ("left_hip", "right_hip", "mid_hip")
_TORSO_ALL = _UPPER + _LOWER
MIN_TORSO_KEYPOINTS = 3
#: the ``points`` term's units: a person's extent of about this many metres is ``norm_extent``
#: normalised pixels (the keypoint term's units)
POINTS_STATURE_M = 1.7
#: the whole-body parameters the hand and face terms free (the eyes stay at rest: no keypoint sees
#: their rotation, only the eyeball centres)
WHOLEBODY_HAND_PARAMS = ("left_hand_pose", "right_hand_pose")
WHOLEBODY_FACE_PARAMS = ("jaw_pose", "expression")
#: the defaults of :class:`KeypointFitConfig`'s stage fields: the cells of the literal tables
#: (:data:`~silfit.fitting.schedules.KEYPOINT_SCHEDULE`; the hand and face fields' ``WHOLEBODY_KEYPOINT_SCHEDULE``)
STAGE_DEFAULTS = keypoint_defaults()


def _stage_weights(old: str, field_name: str):
    """An ``Alias.put`` for ``old`` (one weight per pose stage) onto ``field_name`` (the pose stages' weights, then
    the final stage's): ``old`` must have one value per pose stage."""

    def put(current, value, keywords):
        n = len(keywords.get("pose_iters", KeypointFitConfig.__dataclass_fields__["pose_iters"].default))
        if len(value) != n:
            raise ValueError(
                f"KeypointFitConfig: pose_iters ({n}), {old} ({len(value)}): one weight per pose stage, the same "
                f"non-zero length (the final stage's is {field_name}'s last)"
            )
        return tuple(value) + (tuple(current)[-1],)

    return put


def _final_weight(current, value, keywords):
    """An ``Alias.put`` for an old ``final_*`` weight: the last value of its (stages then final) tuple."""
    return tuple(current)[:-1] + (float(value),)


def _last(weights):
    """An ``Alias.get`` for an old ``final_*`` weight."""
    return tuple(weights)[-1]


def _but_last(weights):
    """An ``Alias.get`` for an old per-pose-stage weight."""
    return tuple(weights)[:-1]


def shape_weights(value) -> tuple:
    """``KeypointFitConfig.shape_weight`` as ``(shape stage, final stage)``: a single number (or one value) is the
    shape stage's, the old meaning of the name (deprecated; the final stage's keeps its default)."""
    if np.ndim(value) == 0 or len(value) == 1:
        final = KeypointFitConfig.__dataclass_fields__["shape_weight"].default[-1]
        warnings.warn(
            f"KeypointFitConfig: a single shape_weight is deprecated: give (shape stage, final stage), "
            f"e.g. (20.0, 5.0); the final stage's kept at {final}",
            DeprecationWarning,
            stacklevel=5,
        )
        value = (float(np.ravel(value)[0]), final)
    if len(value) != 2:
        raise ValueError(f"KeypointFitConfig: shape_weight has {len(value)} values: give (shape stage, final stage)")
    return tuple(float(w) for w in value)


#: two hypotheses of a sample whose joints are this close (mean, metres) are one solution ...
DISTINCT_JOINTS_M = 0.03
#: ... unless a single joint is farther apart than this (metres): a forearm or shin turned the other
#: way in depth moves its end joint 0.2-0.5 m but the mean over 24 joints only 1-3 cm (issue 25)
DISTINCT_JOINT_MAX_M = 0.10
#: a segment whose direction differs by more than this (degrees) between two hypotheses "differs"
DIFFERS_DEG = 30.0


@dataclass(frozen=True)
class BranchSearch:
    """The limb-branch searches (:mod:`silfit.fitting.branches`) of the keypoint stage: after a pose stage
    (``branches_<r>``), at the final weights (``branches_late``) and from the fit (``branches_post``); the stage
    fields among these edit the table's rows (:mod:`silfit.fitting.schedule_edits`). Each field was
    ``KeypointFitConfig.branch_<name>`` (``late_branch_*``, ``post_branch_iters``), names that still work."""

    #: on: after pose stage ``after_stage`` (0-based), every segment pointing out of the image plane by at least
    #: ``min_depth_ratio`` (|cos| to the ray) is mirrored in depth (alone, and per whole limb), each hypothesis runs
    #: ``iters`` L-BFGS steps with that pose stage's weights plus interpenetration, and each sample keeps its lowest
    #: energy; ``rounds`` repeats the search from the kept pose.
    search: bool = STAGE_DEFAULTS["branch_search"]
    after_stage: int = STAGE_DEFAULTS["branch_after_stage"]
    iters: int = STAGE_DEFAULTS["branch_iters"]
    min_depth_ratio: float = STAGE_DEFAULTS["branch_min_depth_ratio"]
    whole_limbs: bool = STAGE_DEFAULTS["branch_whole_limbs"]
    #: a forearm or a shin is mirrored as an elbow or a knee can turn it (the upper segment twists, the
    #: hinge flexes: :func:`~silfit.fitting.branches.flip_segment`); off: the smallest turn at the hinge,
    #: which bends it sideways, so the priors pull the branch back before it is scored (issue 25: a hand
    #: at the chest fitted as an arm held out to the camera; why this default: docs/benchmarks/defaults.md)
    hinge: bool = STAGE_DEFAULTS["branch_hinge"]
    #: with ``hinge``, each hinge segment flipped alone by the smallest turn at its hinge is also a
    #: hypothesis (``<segment>/turn``; whole limbs, joint and root-turn hypotheses use the hinge flip only)
    hinge_turns: bool = STAGE_DEFAULTS["branch_hinge_turns"]
    #: a search's screen and its rows that go on (``carry``) take distinct poses first
    #: (:func:`best_distinct_per_group`): a hinge flip and its ``/turn`` copy that reached the same pose take one
    #: place, and the next distinct hypothesis the other (issue 25)
    distinct: bool = STAGE_DEFAULTS["branch_distinct"]
    #: also the joint hypotheses (:data:`~silfit.fitting.branches.JOINT_HYPOTHESES`: both legs,
    #: both arms, the torso's lean with the legs, the hip's tilt), screened with the others. Off by
    #: default (why: docs/benchmarks/defaults.md)
    joint: bool = STAGE_DEFAULTS["branch_joint"]
    #: each sample's lowest-energy hypotheses of the last branch search that run the rest of the
    #: schedule (at least ``2 * count`` with ``KeypointFitConfig.solutions.count`` > 1); the lowest final energy is
    #: the fit.
    #: As many of the late search's go on to ``settle`` where a search from the fit follows (``post_iters``)
    #: (1: the search's own choice). The search's energies a few dozen steps in are far from converged,
    #: so its choice follows how fast a branch converges, not where; branches refined to near their
    #: minima (``final_iters``) are chosen by the energy a fit is judged by (why this default:
    #: docs/benchmarks/defaults.md)
    refine: int = STAGE_DEFAULTS["branch_refine"]
    rounds: int = STAGE_DEFAULTS["branch_rounds"]
    #: hypotheses drop early: after ``screen_iters`` steps only each sample's
    #: ``survivors`` lowest-energy hypotheses (the unflipped pose among them or not)
    #: run the remaining steps (0: all run every step)
    screen_iters: int = STAGE_DEFAULTS["branch_screen_iters"]
    survivors: int = STAGE_DEFAULTS["branch_survivors"]
    #: a second branch search just before the final stage (0 steps: none), from the pose the
    #: earlier stages reached and with the final stage's weights (the energy a fit is judged by):
    #: the same hypotheses (:func:`~silfit.fitting.branches.limb_hypotheses`, the joint ones with
    #: ``joint``), screened after ``screen_iters`` steps, ``survivors`` run on.
    #: With ``KeypointFitConfig.solutions.count`` > 1 and no search from the fit (``post_iters`` 0) the alternatives are
    #: its survivors. Issue 25 (search failures: the fit's
    #: final energy above the truth's): the first search screens at the pose stage's heavy prior
    #: after a few steps, and the truth's branch was often cut there or never proposed (it needs a
    #: flip on top of another); a search at the final weights from the refined pose finds it (why this
    #: default: docs/benchmarks/defaults.md)
    late_iters: int = STAGE_DEFAULTS["late_branch_iters"]
    #: late searches in a row (each from the one before's pick)
    late_rounds: int = STAGE_DEFAULTS["late_branch_rounds"]
    #: root-turn hypotheses in the late search(es) (:func:`~silfit.fitting.branches.turn_hypotheses`:
    #: ``"mirror"`` the torso's yaw mirrored in depth, a number a turn in degrees), alone and with each
    #: limb flip; empty: none
    late_turns: tuple = ()
    #: survivors of the late search's screen (0: ``survivors``)
    late_survivors: int = 0
    #: a last branch search from the fit itself (0 steps: none): the late search's ``refine`` best
    #: run the final stage (``settle``; with no late search, the one pose the earlier stages reached)
    #: and the lowest final energy goes on; every segment of that fit
    #: pointing out of the image plane is mirrored (alone and per whole limb), each runs this many steps at
    #: the final weights (screened after half), and the ``refine`` best run the final stage again
    #: (``final``); the lowest final energy is the fit. From the converged fit a single flip often reaches
    #: the truth's basin where the late search, from an unconverged pose, cut it at its screen (issue 25's
    #: search failures: the fit's energy above the truth's; why this default: docs/benchmarks/defaults.md).
    #: 0: the schedule before
    post_iters: int = STAGE_DEFAULTS["post_branch_iters"]


@dataclass(frozen=True)
class HandsFace:
    """Whole-body fitting (an SMPL-X-layout model and the ``wholebody`` keypoints; :mod:`silfit.fitting.keypoint_stage`'s
    docstring): the hand and face terms' weights, robust scales, priors and the ``hands`` stage. Each field was
    ``KeypointFitConfig``'s own, by the same name, which still works; the stage fields among these edit the whole-body
    table's rows (:mod:`silfit.fitting.schedule_edits`)."""

    #: hand / face keypoint weights per pose stage (``None``: the table's, 0 in all but the last pose stage), in the
    #: shape stage and the final stage; robust scales (Geman-McClure sigma, normalised pixels) of the hand and face
    #: terms
    hand_weights: Optional[Sequence[float]] = None
    face_weights: Optional[Sequence[float]] = None
    final_hand_weight: float = STAGE_DEFAULTS["final_hand_weight"]
    final_face_weight: float = STAGE_DEFAULTS["final_face_weight"]
    hand_sigma: float = 50.0
    face_sigma: float = 50.0
    #: L-BFGS steps of a ``hands`` stage before the first pose stage with hand terms: the hands
    #: start from their best library pose and wrist turn (:func:`~silfit.fitting.hands_face.choose_hand_starts`)
    #: and are fitted with the body (held by its keypoints and priors; 0: no such stage, the hands start
    #: in that pose stage)
    hand_iters: int = STAGE_DEFAULTS["hand_iters"]
    #: priors of the parts, on wherever the parts are free
    hand_prior_weight: float = STAGE_DEFAULTS["hand_prior_weight"]
    jaw_weight: float = STAGE_DEFAULTS["jaw_weight"]
    expression_weight: float = STAGE_DEFAULTS["expression_weight"]


@dataclass(frozen=True)
class OcclusionOptions:
    """The occlusion cue (:mod:`silfit.fitting.occlusion`, the ``occlusion`` term) in choosing among the hypotheses
    refined to the end (``branches.refine`` or ``2 * solutions.count`` of them): a hypothesis' final energy counts
    ``1 + weight * n`` times, ``n`` the keypoints whose depth order disagrees with their confidence (a confident
    keypoint hidden behind the body, a low-confidence one in front: confidences at or below ``conf[0]`` expect
    hidden, at or above ``conf[1]`` visible). ``weight`` 0: off. Off by default (why: docs/benchmarks/defaults.md)"""

    weight: float = 0.0
    conf: Sequence[float] = (0.3, 0.6)


@dataclass(frozen=True)
class ImageDepthOptions:
    """The image depth cue (:mod:`silfit.fitting.image_depth`, the ``image_depth`` term; issue 54): each limb segment
    whose depth order the landmark model's 3D decides, charged where the fit turns it the other way, in the branch
    searches (their hypotheses ranked by it) and in every stage at the final weights. Problems without an image have
    no cue: the term is 0 and their fit is the same bit for bit."""

    #: the term's weight; 0 (the default): off, unless ``decide`` asks for the cue; 100 is the weight measured
    #: (docs/benchmarks/image-depth.md; why this default: docs/benchmarks/defaults.md)
    weight: float = 0.0
    #: the term's margin: a decided segment's depth cosine (along the ray) must reach this on the cue's side
    margin: float = 0.1
    #: the cue as a hard choice in the branch searches: the segments the cue calls (its gates passed) with a depth
    #: cosine of at least this are decided; each search also proposes each sample's pose with every decided segment
    #: turned to the cue's side (``image:<segments>``), and its screen, its pick, the settled pick and the choice
    #: among the refined branches rank the rows that agree with every decided side first (by their energies; where
    #: none agrees, by energy alone). ``None`` (the default): off. Problems without an image: unchanged bit for bit
    #: (docs/benchmarks/image-depth.md; why this default: docs/benchmarks/defaults.md)
    decide: Optional[float] = None
    #: with ``decide``: the searches' screens and the rows they carry on rank the agreeing rows first (on), or keep the
    #: energy's ranking with one place for each sample's best agreeing row (off: the other branches stay refined, as
    #: alternatives for the silhouette stage)
    decide_screens: bool = True
    #: with ``decide``: also in the search after the pose stages (``branches_<r>``, at their heavy prior, few steps
    #: in); off: only in the late search, the settled pick, the search from the fit and the final choice
    decide_early: bool = True


@dataclass(frozen=True)
class KeypointTermOptions:
    """The keypoint data term (:class:`~silfit.fitting.terms.KeypointTerm`; the module docstring): Geman-McClure with
    robust scale ``sigma`` on residuals in normalised pixels (each sample's confident keypoints span ``norm_extent``
    pixels; also the ``points`` term's unit, :data:`POINTS_STATURE_M`), each keypoint weighted by its confidence
    times ``hip_weight`` (the hips) and its ``weights`` entry (name -> extra weight). Each field was
    :class:`KeypointFitConfig`'s own (``weights``: ``keypoint_weights``), a name that still works."""

    sigma: float = 100.0
    norm_extent: float = 500.0
    hip_weight: float = 0.5
    weights: dict = field(default_factory=dict)  # name -> extra weight
    #: the model's keypoints at its surface landmarks where the layout has them (:func:`~silfit.layouts.keypoint_sources`)
    prefer_landmarks: bool = False


@dataclass(frozen=True)
class Starts:
    """Each sample's starts (the module docstring, ``init``): facing the camera and, with ``flip``, the 180-degree
    flipped one, each from ``poses`` initial body poses: the zero pose, then the pose prior's most probable mixture
    means; all run as one batch (the camera stage is shared by a facing's starts) and the lowest energy is kept
    (``KeypointFitConfig.flip_decision_stage``, ``decision_iters``); each start adds to the batched cost: ``poses``
    1 for the fastest batched throughput (why this default: docs/benchmarks/defaults.md). The fields were
    :class:`KeypointFitConfig`'s ``flip_test`` and ``init_poses``, names that still work."""

    flip: bool = True
    poses: int = 4


@dataclass(frozen=True)
class Solutions:
    """The distinct solutions returned (``KeypointFitResult.hypotheses``; ``silfit fit --hypotheses K``): the last
    branch search keeps each sample's ``max(branches.refine, 2 * count)`` lowest-energy hypotheses and runs the rest
    of the schedule on all of them; the lowest final energy is the fit, the ``count`` best distinct ones
    (:func:`distinct_hypotheses`) are returned as alternatives. Choosing the branch by the final energy, not the
    search stage's, is itself better, at a cost in time (docs/benchmarks/defaults.md; ``branches.refine`` does so
    by default). The fields were :class:`KeypointFitConfig`'s ``hypotheses``, ``hypothesis_joint_max_m`` and
    ``hypothesis_unrefined``, names that still work (the group is not called ``hypotheses``: that name stays the
    count's alias)."""

    count: int = 1
    #: :func:`distinct_hypotheses`: two solutions are distinct when their joints are
    #: :data:`DISTINCT_JOINTS_M` apart (mean) or any one joint more than this (metres; ``None``: the
    #: mean alone, the rule before issue 25's warnings; videos' branch choice keeps that one) ...
    joint_max_m: Optional[float] = DISTINCT_JOINT_MAX_M
    #: ... and where fewer than ``count`` refined ones are distinct, the branch searches' other
    #: survivors fill the list (``refined: False``; their energy is their search stage's, not final; rows that
    #: settled higher than the settled pick, ``stage`` ``settle``, carry their final-weight energy there and
    #: their gap to the fit's final energy)
    unrefined: bool = True


@dataclass(frozen=True)
class TemporalOptions:
    """The temporal terms (``smooth_joints``, ``smooth_root``; weight 0 in the single-image schedule, used by
    :mod:`silfit.fitting.sequence`): robust scale ``sigma`` in mm per frame^2 and the penalty ``robust``
    (``charbonnier`` or ``gm``). The fields were :class:`KeypointFitConfig`'s ``temporal_sigma`` and
    ``temporal_robust``, names that still work."""

    sigma: float = 10.0
    robust: str = "charbonnier"


@renamed_fields(
    pose_prior_weights=Alias("pose_weight", _but_last, _stage_weights("pose_prior_weights", "pose_weight")),
    final_pose_prior_weight=Alias("pose_weight", _last, _final_weight),
    angle_prior_weights=Alias("angle_weight", _but_last, _stage_weights("angle_prior_weights", "angle_weight")),
    final_angle_prior_weight=Alias("angle_weight", _last, _final_weight),
    final_shape_weight=Alias("shape_weight", _last, lambda w, v, kw: _final_weight(shape_weights(w), v, kw)),
    **grouped(
        "branches",
        late_branch_survivors="late_survivors",
        late_branch_rounds="late_rounds",
        late_branch_turns="late_turns",
        late_branch_iters="late_iters",
        post_branch_iters="post_iters",
        branch_min_depth_ratio="min_depth_ratio",
        branch_whole_limbs="whole_limbs",
        branch_hinge_turns="hinge_turns",
        branch_after_stage="after_stage",
        branch_screen_iters="screen_iters",
        branch_survivors="survivors",
        branch_distinct="distinct",
        branch_search="search",
        branch_refine="refine",
        branch_rounds="rounds",
        branch_hinge="hinge",
        branch_joint="joint",
        branch_iters="iters",
    ),
    **grouped("occlusion", occlusion_weight="weight", occlusion_conf="conf"),
    **grouped(
        "hands_face",
        hand_weights="hand_weights",
        face_weights="face_weights",
        final_hand_weight="final_hand_weight",
        final_face_weight="final_face_weight",
        hand_sigma="hand_sigma",
        face_sigma="face_sigma",
        hand_iters="hand_iters",
        hand_prior_weight="hand_prior_weight",
        jaw_weight="jaw_weight",
        expression_weight="expression_weight",
    ),
    **grouped(
        "keypoint_term",
        sigma="sigma",
        norm_extent="norm_extent",
        hip_weight="hip_weight",
        keypoint_weights="weights",
        prefer_landmarks="prefer_landmarks",
    ),
    **grouped("starts", flip_test="flip", init_poses="poses"),
    **grouped("solutions", hypotheses="count", hypothesis_joint_max_m="joint_max_m", hypothesis_unrefined="unrefined"),
    **grouped("temporal", temporal_sigma="sigma", temporal_robust="robust"),
    **grouped(
        "image_depth",
        image_depth_weight="weight",
        image_depth_margin="margin",
        image_depth_decide="decide",
        image_depth_decide_screens="decide_screens",
        image_depth_decide_early="decide_early",
    ),
)
@dataclass
class KeypointFitConfig:
    """Weights and iteration counts of the keypoint stage (defaults tuned on synthetic data)."""

    #: the keypoint data term (:class:`KeypointTermOptions`; once ``sigma``, ``norm_extent``, ``hip_weight``,
    #: ``keypoint_weights``, ``prefer_landmarks``, which still work)
    keypoint_term: KeypointTermOptions = field(default_factory=KeypointTermOptions)
    #: each sample's starts (:class:`Starts`; once ``flip_test``, ``init_poses``, which still work)
    starts: Starts = field(default_factory=Starts)
    #: after which pose sub-stage (0-based) each sample keeps the best of its starts
    flip_decision_stage: int = STAGE_DEFAULTS["flip_decision_stage"]
    #: steps of that sub-stage run with every start before choosing (0: the whole sub-stage);
    #: its remaining steps continue from the chosen start only
    decision_iters: int = STAGE_DEFAULTS["decision_iters"]
    robust: bool = True  # False: plain L2 data terms (keypoints and, several views, points; for comparisons)
    camera_iters: int = STAGE_DEFAULTS["camera_iters"]
    pose_iters: Sequence[int] = STAGE_DEFAULTS["pose_iters"]
    #: Annealed pose-prior weights of the pose stages, tuned for the shipped library mixture
    #: (:class:`~silfit.priors.LibraryMixturePrior`; about 10x the weights that suited the
    #: old split-normal default, whose energies are on a similar scale but which needed less
    #: pull; see ``benchmarks/bench_fit.py``). With ``pose_prior="limits"`` or SMPLify's
    #: ``gmm_08.pkl`` consider lower weights (the old defaults were 200, 40, 8 and 4).
    #: Then the final stage's (one name for the pose prior's weight, issue 26: ``pose_weight`` here,
    #: in :class:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig` and in
    #: :class:`~silfit.fitting.sequence.SequenceFitConfig`; the old ``pose_prior_weights`` (the pose
    #: stages') and ``final_pose_prior_weight`` still work).
    pose_weight: Sequence[float] = STAGE_DEFAULTS["pose_weight"]
    #: the angle prior's (the knees' and elbows' bend), the same way: one per pose stage, then the final stage's
    #: (issue 57; the old ``angle_prior_weights`` (the pose stages') and ``final_angle_prior_weight`` still work)
    angle_weight: Sequence[float] = STAGE_DEFAULTS["angle_weight"]
    shape_iters: int = STAGE_DEFAULTS["shape_iters"]
    #: the shape prior's: the shape stage's, then the final stage's (issue 57; the old ``final_shape_weight``
    #: still works, and a single number is the shape stage's, as the name meant before, with a warning)
    shape_weight: Sequence[float] = STAGE_DEFAULTS["shape_weight"]
    #: the final stage's L-BFGS steps; with ``branch_refine`` above 1 the hypotheses are chosen by the
    #: final energy, so this many steps bring it near its minimum (see ``branch_refine``; why this
    #: default: docs/benchmarks/defaults.md)
    final_iters: int = STAGE_DEFAULTS["final_iters"]
    #: ... but at most this many, every one run (no ``final_tol_change``), where no branch search ran
    #: (several views fix the limbs' depth, or ``branch_search`` off): no branches to choose among, and
    #: the rigs' numbers were measured so (``None``: ``final_iters`` always)
    final_iters_unsearched: Optional[int] = STAGE_DEFAULTS["final_iters_unsearched"]
    #: after a branch search, the final stage's rows stop once a step lowers their energy by less than this (relative; the
    #: optimiser's default, 1e-8, runs nearly every row all ``final_iters``); ``None``: the optimiser's default
    #: (why this default: docs/benchmarks/defaults.md)
    final_tol_change: Optional[float] = STAGE_DEFAULTS["final_tol_change"]
    limit_weight: float = STAGE_DEFAULTS["limit_weight"]
    interpenetration_weight: float = STAGE_DEFAULTS["interpenetration_weight"]
    depth_weight: float = STAGE_DEFAULTS["depth_weight"]
    #: several calibrated views: the ``points`` term (:class:`~silfit.fitting.terms.PointsTerm`, the
    #: keypoints triangulated from the views) in the pose stages and in the shape and final stages
    #: (0 for one view: nothing is triangulated). With two views the 2D terms alone could end with a
    #: limb in the wrong depth branch (one view agrees, the robust term bounds the other's residual),
    #: which this term holds (why this default, and ``final_points_weight``'s: docs/benchmarks/defaults.md)
    points_weight: float = STAGE_DEFAULTS["points_weight"]
    final_points_weight: float = STAGE_DEFAULTS["final_points_weight"]
    history: int = 10
    #: the floating-point type the stage computes in (``None``: the model's own). float64 by
    #: default: the optimiser amplifies last-bit differences (other SIMD kernels) into millimetres,
    #: and in float64 they are rarer and smaller (README, "Same inputs, same fit"; why this default:
    #: docs/benchmarks/defaults.md). Results are returned in float32 either way.
    dtype: Optional[str] = "float64"
    #: torch threads during the fit (the per-iteration tensors are small, so one thread
    #: avoids synchronisation overhead; ``None`` leaves torch's setting alone).
    threads: Optional[int] = 1
    #: the limb-branch searches (:class:`BranchSearch`; once ``branch_search``, ``branch_*``, ``late_branch_*``,
    #: ``post_branch_iters``, which still work)
    branches: BranchSearch = field(default_factory=BranchSearch)
    #: the distinct solutions returned (:class:`Solutions`; once ``hypotheses`` (the count), ``hypothesis_joint_max_m``,
    #: ``hypothesis_unrefined``, which still work)
    solutions: Solutions = field(default_factory=Solutions)
    #: the occlusion cue (:class:`OcclusionOptions`; once ``occlusion_weight``, ``occlusion_conf``, which still work)
    occlusion: OcclusionOptions = field(default_factory=OcclusionOptions)
    #: the image depth cue (:class:`ImageDepthOptions`; once ``image_depth_weight``, ``image_depth_margin``,
    #: ``image_depth_decide``, ``image_depth_decide_screens``, ``image_depth_decide_early``, which still work)
    image_depth: ImageDepthOptions = field(default_factory=ImageDepthOptions)
    #: the temporal terms (:class:`TemporalOptions`; once ``temporal_sigma``, ``temporal_robust``, which still work)
    temporal: TemporalOptions = field(default_factory=TemporalOptions)
    #: whole-body fitting (:class:`HandsFace`; its fields were the config's, names that still work)
    hands_face: HandsFace = field(default_factory=HandsFace)
    #: an explicit list of :class:`~silfit.fitting.stages.Stage` replacing the schedule
    #: the fields above describe (see :meth:`stages`)
    schedule: Optional[Sequence[Stage]] = None

    def __post_init__(self):
        n = len(self.pose_iters)
        self.pose_weight = tuple(float(w) for w in self.pose_weight)
        self.angle_weight = tuple(float(w) for w in self.angle_weight)
        self.shape_weight = shape_weights(self.shape_weight)
        if not (len(self.pose_weight) - 1 == len(self.angle_weight) - 1 == n) or n == 0:
            raise ValueError(
                f"KeypointFitConfig: pose_iters ({n}), pose_weight ({len(self.pose_weight)}: one per pose stage, then "
                f"the final stage's) and angle_weight ({len(self.angle_weight)}: the same) do not match"
            )
        if not 0 <= int(self.flip_decision_stage) < n:
            raise ValueError(
                f"KeypointFitConfig: flip_decision_stage {self.flip_decision_stage} is not a pose stage (0..{n - 1})"
            )
        if int(self.starts.poses) < 1:
            raise ValueError(f"KeypointFitConfig: starts.poses must be at least 1, got {self.starts.poses}")
        starts = (2 if self.starts.flip else 1) * int(self.starts.poses)
        b = self.branches
        if b.search and starts > 1 and min(b.after_stage, n - 1) < self.flip_decision_stage:
            raise ValueError(
                f"KeypointFitConfig: the branch search (after pose stage {b.after_stage}) needs the start "
                f"decided first (flip_decision_stage {self.flip_decision_stage})"
            )
        for name in ("hand_weights", "face_weights"):
            v = getattr(self.hands_face, name)
            if v is not None and len(v) != n:
                raise ValueError(f"KeypointFitConfig: hands_face.{name} has {len(v)} values, pose_iters {n}")
        if self.dtype not in (None, "float32", "float64"):
            raise ValueError(f"KeypointFitConfig: dtype must be 'float32', 'float64' or None, got {self.dtype!r}")
        if self.schedule is not None and not all(isinstance(s, Stage) for s in self.schedule):
            raise ValueError("KeypointFitConfig: schedule must be a list of silfit.fitting.stages.Stage")

    def stages(self, whole_body: bool = False) -> tuple:
        """The schedule as data: the literal table (:data:`~silfit.fitting.schedules.KEYPOINT_SCHEDULE`, with
        ``whole_body`` ``WHOLEBODY_KEYPOINT_SCHEDULE``) as it stands, or edited by the fields that differ from their
        defaults (which are the table's cells: :mod:`silfit.fitting.schedule_edits`): camera, pose_1..n (annealed
        priors; the best start of each sample is kept ``decision_iters`` steps into pose stage
        ``flip_decision_stage``; the branch search after pose stage ``branches.after_stage``), shape, ``branches_late``
        (the search again at the final weights, ``branches.late_iters``), ``settle`` and ``branches_post`` (its best
        settle, and a search from the best of them, ``branches.post_iters``), final (everything, with
        interpenetration); with ``whole_body`` the hand and face terms and parameters join as the module docstring
        says. ``schedule``: that list instead."""
        if self.schedule is not None:
            return tuple(self.schedule)
        return keypoint_stages(self, whole_body)

    def to_dict(self, whole_body: bool = False) -> dict:
        """The settings and the resulting schedule (saved with every fit)."""
        d = flat_dict(self, skip=("schedule",))  # the groups' fields by their flat names, as before them
        d["stages"] = [stage_to_dict(s) for s in self.stages(whole_body)]
        return d


def _names(layout):
    return LAYOUTS[layout]


def prepare_keypoints(keypoints, layout: Optional[str] = None) -> list:
    """Normalise API input to a list of :class:`KeypointSet` (validated)."""
    if isinstance(keypoints, KeypointSet):
        return [keypoints]
    if isinstance(keypoints, (list, tuple)) and keypoints and all(isinstance(k, KeypointSet) for k in keypoints):
        return list(keypoints)
    arr = np.asarray(keypoints.detach().cpu() if isinstance(keypoints, torch.Tensor) else keypoints, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"keypoints array has shape {arr.shape}, expected [K, 3] or [B, K, 3] of x, y, confidence")
    if layout is None:
        matches = [n for n, names in LAYOUTS.items() if len(names) == arr.shape[1]]
        if not matches:
            raise ValueError(
                f"keypoints array has {arr.shape[1]} points; expected 25 (body25), 17 (coco17) or 33 (blazepose33)"
            )
        layout = matches[0]
    return [KeypointSet(a[:, :2], a[:, 2], layout, source=f"<array>[{i}]") for i, a in enumerate(arr)]


def check_torso(ks: KeypointSet):
    names = ks.names
    have = [n for n in _TORSO_ALL if n in names and ks.conf[names.index(n)] > 0]
    up = [n for n in _UPPER if n in have]
    low = [n for n in _LOWER if n in have]
    if len(have) < MIN_TORSO_KEYPOINTS or not up or not low:
        raise ValueError(
            f"{ks.source}: only {len(have)} usable torso keypoint(s) ({', '.join(have) or 'none'}); need at least "
            f"{MIN_TORSO_KEYPOINTS} of {', '.join(n for n in _TORSO_ALL if n in names)} with confidence > 0, "
            f"including a shoulder/neck and a hip"
        )


def _resolve_cameras(sets, cameras, image_size, focal) -> list:
    B = len(sets)
    if cameras is None:
        if image_size is None:
            raise ValueError("no camera: give a camera (intrinsics) or the image size to derive the default one")
        sizes = [image_size] * B if isinstance(image_size[0], (int, float, np.integer)) else list(image_size)
        cams = [Camera.from_image_size(int(w), int(h), focal) for w, h in sizes]
    else:
        cams = [cameras] * B if isinstance(cameras, Camera) else list(cameras)
        if focal is not None:
            cams = [replace(c, fx=float(focal), fy=float(focal)) for c in cams]
    if len(cams) != B:
        raise ValueError(f"{len(cams)} cameras for {B} keypoint sets")
    return cams


#: energies of one sample's starts or hypotheses closer than this (relative to the lowest) count as
#: tied, and the earlier row wins: a choice between two starts that ended in the same minimum must
#: not follow the last bits of the arithmetic (another CPU's kernels), only the order of the starts
DECISION_RTOL = 1e-6


def best_per_group(
    energy: torch.Tensor, group: torch.Tensor, groups: int, count: int = 1, rtol: float = DECISION_RTOL
) -> torch.Tensor:
    """Row indices of the lowest finite energies of each group ``g < groups``: one per group
    in group order (``count=1``), or up to ``count`` per group, groups in order (rows with
    non-finite energies lose to any finite one). Energies are compared in steps of ``rtol``
    times the group's lowest (at least 1): within a step the earlier row ranks first."""
    f = torch.where(torch.isfinite(energy), energy.double(), torch.full_like(energy, math.inf, dtype=torch.float64))
    out = []
    for g in range(groups):
        rows = (group == g).nonzero().squeeze(1)
        fg = f[rows]
        low = fg.min()
        step = rtol * max(abs(float(low)), 1.0) if math.isfinite(float(low)) else 1.0
        key = torch.where(torch.isfinite(fg), torch.floor((fg - low) / step), fg)
        out.append(rows[torch.argsort(key, stable=True)[: max(1, int(count))]])
    return torch.cat(out)


def best_distinct_per_group(
    energy: torch.Tensor,
    group: torch.Tensor,
    groups: int,
    count: int,
    joints,
    min_m: float = DISTINCT_JOINTS_M,
    max_m: Optional[float] = DISTINCT_JOINT_MAX_M,
) -> torch.Tensor:
    """As :func:`best_per_group` with ``count``, but a row goes on only when its joints (``joints [rows, J, 3]``,
    metres) are distinct (:func:`is_distinct`) from those of every better row of its group already going on;
    where fewer than ``count`` are distinct, the best of the others fill the places (rows with non-finite
    energies only fill, as they rank: last). Rows in rank order per group, groups in order. Two hypotheses
    that reached the same pose (a hinge flip and its smallest turn, say) take one place, not two (issue 25)."""
    count = max(1, int(count))
    ranked = best_per_group(energy, group, groups, count=int(group.numel())).tolist()
    finite, of = torch.isfinite(energy).tolist(), group.tolist()
    out = []
    for g in range(groups):
        rows = [r for r in ranked if of[r] == g]
        kept: list = []
        for r in rows:
            if len(kept) == count:
                break
            if finite[r] and all(is_distinct(joints[r], joints[k], min_m, max_m) for k in kept):
                kept.append(r)
        fill = [r for r in rows if r not in kept][: count - len(kept)]
        chosen = set(kept + fill)
        out.append(torch.as_tensor([r for r in rows if r in chosen], dtype=torch.long))
    return torch.cat(out)


def joint_shift_mm(joints, reference) -> tuple:
    """``(mean, max)``: how far joints ``[J, 3]`` lie from ``reference`` ``[J, 3]`` (metres in,
    millimetres out), the mean over joints and the largest single joint's."""
    d = np.linalg.norm(np.asarray(joints, np.float64) - np.asarray(reference, np.float64), axis=-1)
    return 1000.0 * float(d.mean()), 1000.0 * float(d.max())


def is_distinct(joints, other, min_m: float = DISTINCT_JOINTS_M, max_m: Optional[float] = DISTINCT_JOINT_MAX_M) -> bool:
    """Two solutions (joints ``[J, 3]``, metres) are distinct when their joints are at least ``min_m``
    apart on average, or (``max_m`` not ``None``) any single joint is more than ``max_m`` apart."""
    mean_mm, max_mm = joint_shift_mm(joints, other)
    return mean_mm >= 1000.0 * min_m or (max_m is not None and max_mm > 1000.0 * max_m)


def differing_segments(joints, reference, names) -> list:
    """The limb and torso segments whose direction differs by more than :data:`DIFFERS_DEG`
    between joints ``[J, 3]`` and ``reference`` (``names``: the model's joint names)."""
    out = []
    for n, p, d in LIMB_SEGMENTS + (TORSO_SEGMENT,):
        a, c = names.index(p), names.index(d)
        u, v = joints[c] - joints[a], reference[c] - reference[a]
        cos = float(u @ v / max(np.linalg.norm(u) * np.linalg.norm(v), 1e-12))
        if math.degrees(math.acos(max(-1.0, min(1.0, cos)))) > DIFFERS_DEG:
            out.append(n)
    return out


def distinct_hypotheses(
    fitter,
    layout,
    state,
    energy,
    group,
    groups: int,
    labels,
    min_m: float = DISTINCT_JOINTS_M,
    score=None,
    occlusion=None,
    max_m: Optional[float] = DISTINCT_JOINT_MAX_M,
    unrefined=None,
):
    """``(hypotheses, best_rows)``: per sample ``b < groups``, its rows (``group == b``) refined to the
    end, lowest ``score`` (default: ``energy``) first, without those not distinct (:func:`is_distinct`,
    ``min_m``, ``max_m``) from a lower one, as ``[{"label", "energy", "params": {name: [w]}, "differs":
    [segment, ...], "refined", "shift_mm", "max_shift_mm"}]`` (``differs``: the limb and torso segments
    pointing more than :data:`DIFFERS_DEG` away from the best's; ``shift_mm``/``max_shift_mm``: the
    mean and largest joint distance to the best, :func:`joint_shift_mm`; with ``occlusion [rows]``, also
    each refined one's ``occlusion`` count); then, with ``unrefined`` (per sample, branch-search rows that
    did not run to the end: ``{"label", "energy", "gap", "stage", "params", "joints"}``), those distinct
    from every one before, smallest ``gap`` first, with ``refined: False``; and the best row of each sample."""
    rows = layout.rows(state)
    with torch.no_grad():
        joints = fitter.body(**rows).joints.double().numpy()
    names = fitter.model.joint_names
    order = best_per_group(energy if score is None else score, group, groups, count=int(group.shape[0]))
    out, best = [], []
    order, of = order.tolist(), group.tolist()  # read once, not per sample and row
    for b in range(groups):
        mine = [r for r in order if of[r] == b]
        kept = []  # (joints, row or unrefined record)
        for r in mine:
            if all(is_distinct(joints[r], j, min_m, max_m) for j, _ in kept):
                kept.append((joints[r], r))
        best.append(kept[0][1])
        for x in sorted((unrefined or [[]] * groups)[b], key=lambda x: x["gap"]):
            if all(is_distinct(x["joints"], j, min_m, max_m) for j, _ in kept):
                kept.append((x["joints"], x))
        hyps = []
        for j, r in kept:
            mean_mm, max_mm = joint_shift_mm(j, kept[0][0])
            common = {
                "differs": differing_segments(j, kept[0][0], names),
                "shift_mm": round(mean_mm, 1),
                "max_shift_mm": round(max_mm, 1),
            }
            if isinstance(r, dict):
                hyps.append(
                    {
                        "label": r["label"],
                        "energy": float(r["energy"]),
                        **common,
                        "params": r["params"],
                        "refined": False,
                        "stage": r["stage"],
                        "gap": float(r["gap"]),
                    }
                )
                continue
            hyps.append(
                {
                    "label": labels[r],
                    "energy": float(energy[r]),
                    **common,
                    "refined": True,
                    "params": {n: v[r].detach().cpu().numpy().astype(np.float32) for n, v in rows.items()},
                }
            )
            if occlusion is not None:
                hyps[-1]["occlusion"] = float(occlusion[r])
        out.append(hyps)
    return out, torch.as_tensor(best, dtype=torch.long)


class KeypointFitter:
    """Holds the model-derived pieces (reduced keypoint body, priors, collision spheres,
    the energy's terms and the validated schedule) so many batches can be fitted
    without rebuilding them."""

    def __init__(self, model=None, layout: str = "body25", config: Optional[KeypointFitConfig] = None, pose_prior=None):
        # the set-up's arithmetic (collision spheres, priors, the reduced body) with the stage's threads, so
        # its bits do not follow the process's thread count either (silfit.body.lbs, "No BLAS")
        config = config or KeypointFitConfig()
        with torch_threads(config.threads):
            self._setup(model, layout, config, pose_prior)

    def _setup(self, model, layout: str, config: KeypointFitConfig, pose_prior) -> None:
        if model is None:
            model = load_body_model(kind="smplx" if layout == "wholebody" else None)
        self.config = config
        #: the model the stage computes with: the caller's, or its copy in ``config.dtype``
        self.model = model if self.config.dtype is None else model_in_dtype(model, getattr(torch, self.config.dtype))
        self.layout = layout
        self.whole_body = layout == "wholebody"  # an SMPL-layout model refuses the layout (keypoint_sources)
        self.dtype = self.model.dtype
        self.body = KeypointBody(self.model, layout, self.config.keypoint_term.prefer_landmarks)
        if pose_prior is None or isinstance(pose_prior, str):
            pose_prior = load_pose_prior(pose_prior, dtype=self.dtype)
        self.pose_prior = body_prior_for(self.model, pose_prior)  # SMPL-X: the marginal over its 21 body joints
        self.collisions = SphereCollisionModel(self.model)
        self.params = ParameterLayout.of(self.model)
        names = _names(layout)
        w = np.ones(len(names))
        for i, n in enumerate(names):
            if n.endswith("hip"):
                w[i] = self.config.keypoint_term.hip_weight
            w[i] *= self.config.keypoint_term.weights.get(n, 1.0)
        self.kp_weights = torch.as_tensor(w, dtype=self.dtype) * self.body.kp_valid.to(self.dtype)
        self.torso_mask = torch.as_tensor([n in _TORSO_ALL for n in names], dtype=self.dtype)
        sigma = self.config.keypoint_term.sigma if self.config.robust else None
        terms = [
            KeypointTerm("keypoints", sigma),
            KeypointTerm("torso", sigma, mask=self.torso_mask),
            DepthTerm(),
            PointsTerm(
                sigma, self.config.keypoint_term.norm_extent / POINTS_STATURE_M
            ),  # L2 as the data term with robust=False
            PriorTerm("pose", self.pose_prior, "body_pose"),
            PriorTerm("angle", angle_prior, "body_pose"),
            PriorTerm("limits", limit_violation, "body_pose"),
            PriorTerm("shape", shape_prior, "betas"),
            OcclusionTerm(self.model, _names(layout), tuple(self.config.occlusion.conf)),
            InterpenetrationTerm(self.collisions),
            ImageDepthTerm(self.model.joint_names, self.config.image_depth.margin),
            JointSmoothnessTerm(sigma=self.config.temporal.sigma, kind=self.config.temporal.robust),
            RootSmoothnessTerm(sigma=self.config.temporal.sigma, kind=self.config.temporal.robust),
        ]
        if self.whole_body:
            terms = wholebody_terms(self.model, terms, sigma, self.config.hands_face, self.dtype)
        self.energy = Energy(terms)
        self.stages = self.config.stages(self.whole_body)
        check_stages(self.stages, self.energy, self.params)
        with torch.no_grad():
            kp = self.body(**self.model.zero_params(1)).keypoints
            self.rest_pelvis = self.model(**self.model.zero_params(1)).joints[0, 0].double().numpy()
        self.rest_keypoints = kp[0].double().numpy()

    # ------------------------------------------------------------------ init
    def _initial_placement(self, xy, conf, cam: Camera, flipped: bool):
        names = _names(self.layout)

        def mean_of(group, pts):
            sel = [names.index(n) for n in group if n in names and conf[names.index(n)] > 0]
            return pts[sel].mean(0)

        up2, low2 = mean_of(_UPPER, xy), mean_of(_LOWER, xy)
        up3, low3 = mean_of(_UPPER, self.rest_keypoints), mean_of(_LOWER, self.rest_keypoints)
        h2 = max(float(np.linalg.norm(up2 - low2)), 1.0)
        h3 = float(np.linalg.norm(up3 - low3))
        z0 = 0.5 * (cam.fx + cam.fy) * h3 / h2
        u = (up2 - low2) / h2
        roll = math.atan2(u[0], -u[1])
        base = Rotation.from_rotvec(UPRIGHT_BACK_TO_CAMERA if flipped else UPRIGHT_FACING_CAMERA)
        R = Rotation.from_rotvec([0.0, 0.0, roll]) * base
        c2 = 0.5 * (up2 + low2)
        c3 = 0.5 * (up3 + low3)
        target = np.array([(c2[0] - cam.cx) * z0 / cam.fx, (c2[1] - cam.cy) * z0 / cam.fy, z0])
        transl = target - R.apply(c3)
        return R.as_rotvec(), transl, z0

    def _initial_poses(self, count: int) -> list:
        """The zero pose, then the pose prior's most probable mixture means (if it has any)."""
        poses = [torch.zeros(self.model.num_body_pose, dtype=self.dtype)]
        means = getattr(self.pose_prior, "means", None)
        if means is not None and count > 1:
            constants = getattr(self.pose_prior, "constants", torch.zeros(len(means)))
            poses += [means[i].detach() for i in torch.argsort(constants)[: count - 1].tolist()]
        return poses[: max(1, count)]

    def _rig_placement(self, row):
        """``(global_orient, transl, z0 [C])`` of one frame seen by several calibrated views:
        the torso triangulated (:mod:`silfit.fitting.triangulate`) and the rest torso
        rotated onto it; ``z0`` the root's depth in each camera."""
        names = _names(self.layout)
        views = [o.view for o in row]
        ext = [v.extrinsics() for v in views]
        P = projection_matrices(
            [[v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy] for v in views],
            [e[0] for e in ext],
            [e[1] for e in ext],
        )
        xy = np.stack([o.keypoints.xy for o in row])
        conf = np.stack([o.keypoints.conf for o in row])
        torso = [names.index(n) for n in _TORSO_ALL if n in names]
        X, inliers, _ = robust_triangulate(P[:, :, :], xy[:, torso], conf[:, torso])
        w = (conf[:, torso] * inliers).sum(0) * self.kp_weights.numpy()[torso]
        try:
            orient, transl = torso_placement(self.rest_keypoints[torso], X, w, self.rest_pelvis)
        except ValueError:  # torso not triangulated: place it from the view that sees it best, as one image
            c = int(np.argmax([(conf[v, torso] > 0).sum() + conf[v, torso].sum() * 1e-3 for v in range(len(row))]))
            o = row[c]
            check_torso(o.keypoints)
            orient, transl, _ = self._initial_placement(o.keypoints.xy, o.keypoints.conf, o.view.camera, False)
            orient, transl = placement_to_world(orient, transl, *ext[c], self.rest_pelvis)
        z0 = [float((R @ transl + t)[2]) for R, t in ext]
        return orient, transl, z0

    def _problem_data(self, problems, flips):
        """Data and views ``[P, F, C, ...]`` of problems with ``C`` views, and the initial
        state for each facing in ``flips`` (rows ordered facing-major: row ``f * B + b``).
        One view: similar-triangles placement; several: triangulated (:meth:`_rig_placement`).
        The keypoint weights are divided by ``C`` (the data term is the views' mean)."""
        cfg, dt = self.config, self.dtype
        T = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=dt)  # noqa: E731
        F, C = problems[0].num_frames, problems[0].num_views
        target, weights, scale, z0, orient, transl, points = [], [], [], [], [], [], []
        for flip in flips:
            for p in problems:
                grid = p.grid()
                if len(grid[0]) != C:
                    raise ValueError(
                        f"problems of one batch must have the same number of views, got {C} and {len(grid[0])}"
                    )
                target.append([[o.keypoints.xy for o in row] for row in grid])
                weights.append([[o.keypoints.conf for o in row] for row in grid])
                ext = []
                for row in grid:
                    ext.append([])
                    for o in row:
                        vis = o.keypoints.xy[o.keypoints.conf > 0]
                        size = float((vis.max(0) - vis.min(0)).max()) if len(vis) else 1.0
                        ext[-1].append(cfg.keypoint_term.norm_extent / max(size, 1.0))
                scale.append(ext)
                if C == 1:
                    placed = [
                        self._initial_placement(row[0].keypoints.xy, row[0].keypoints.conf, row[0].view.camera, flip)
                        for row in grid
                    ]
                    placed = [(q[0], q[1], [q[2]]) for q in placed]
                else:
                    placed = [self._rig_placement(row) for row in grid]
                    points.append(
                        [
                            triangulate_views(
                                [o.view for o in row],
                                np.stack([o.keypoints.xy for o in row]),
                                np.stack([o.keypoints.conf for o in row]),
                            )
                            for row in grid
                        ]
                    )
                orient.append([q[0] for q in placed])
                transl.append([q[1] for q in placed])
                z0.append([q[2] for q in placed])
        data = {
            "target": T(target),
            "weights": T(weights) * self.kp_weights / C,
            "scale": T(scale),
            "z0": T(z0),
            "conf": T(weights),
        }
        if points:  # several views: the keypoints triangulated per frame (the ``points`` term)
            data["points3d"] = T([[q[0] for q in row] for row in points])
            data["points3d_weights"] = T([[q[1] for q in row] for row in points]) * self.kp_weights
        views = stack_views(problems * len(flips), dt)
        state = ParameterLayout(self.params.sizes, self.params.shared, F).zeros(len(target), dt)
        state["global_orient"], state["transl"] = T(orient), T(transl)
        return data, views, state

    # ------------------------------------------------------------------ fit
    def fit(
        self, keypoints, cameras=None, *, image_size=None, focal=None, progress: bool = False, depth_cues=None
    ) -> KeypointFitResult:
        """Fit keypoint sets (one or a batch); ``depth_cues``: per set a :class:`~silfit.fitting.image_depth.DepthCue`
        from its image, or ``None`` (no image: the fit is as without the argument)."""
        sets = prepare_keypoints(keypoints, self.layout)
        for ks in sets:
            if ks.layout != self.layout:
                raise ValueError(f"{ks.source}: keypoints are {ks.layout}, this fitter was built for {self.layout}")
            check_torso(ks)
        cams = _resolve_cameras(sets, cameras, image_size, focal)
        problems = [Problem.single(ks, cam) for ks, cam in zip(sets, cams)]
        with torch_threads(self.config.threads):
            state, info = self.fit_problems(problems, progress=progress, depth_cues=depth_cues)
        return self._result(state, info, sets, cams)

    def fit_problems(
        self,
        problems: Sequence[Problem],
        progress: bool = False,
        init: Optional[dict] = None,
        frame_weights=None,
        depth_cues=None,
    ):
        """Run the schedule on problems of equal frame and view counts (several views: the
        placement is triangulated, no flip test, no branch search).

        ``init`` (``{name: [B, w]}`` or ``[B, F, w]``) replaces the initial placement's
        values of the parameters it names (all starts begin there). ``frame_weights``
        (``[B, F]``, optional) scales each frame's keypoint data (0: a frame bridged by the
        temporal terms alone). ``depth_cues`` (per problem a :class:`~silfit.fitting.image_depth.DepthCue` or
        ``None``, optional): the image depth cue, the ``image_depth`` term's data (every frame alike).

        Returns ``(state, info)``: the parameters (shared ``[B, w]``, per-frame
        ``[B, F, w]``) and a dict with per-stage ``energies`` and ``terms`` ``[B]``,
        ``timings`` (seconds), ``flipped [B]`` and the data and views used."""
        B = len(problems)
        layout, facings, init_poses, (data, views, state) = self._starts(problems, init, frame_weights, depth_cues)
        sched = _ScheduleRun(
            self,
            layout,
            B,
            state,
            data,
            views,
            progress=progress,
            start_flip=torch.as_tensor(np.repeat(facings, B), dtype=torch.bool),
            group=torch.arange(B).repeat(len(facings)),
            calls=hard_calls(depth_cues, self.config.image_depth.decide),
        )
        decided = len(facings) * len(init_poses) == 1
        t_all = time.perf_counter()
        decided = self._run_stages(sched, init_poses, decided, problems[0].num_views)
        if not decided:  # a schedule without a decision stage: keep the best start at the end
            sched.take(best_per_group(sched.energies[self.stages[-1].name], sched.group, B))
        hypotheses, others = sched.choose()
        sched.timings["total"] = time.perf_counter() - t_all
        return sched.state, sched.info(hypotheses, others)

    def _starts(self, problems: Sequence[Problem], init: Optional[dict], frame_weights, depth_cues) -> tuple:
        """:meth:`fit_problems`' starts: ``(layout, facings, init_poses, (data, views, state))``, the rows facing-major
        (:meth:`_problem_data`) with ``init``, ``frame_weights`` and ``depth_cues`` applied."""
        cfg, dt = self.config, self.dtype
        B = len(problems)
        frames = {p.num_frames for p in problems}
        if len(frames) != 1:
            raise ValueError(f"problems of one batch must have the same number of frames, got {sorted(frames)}")
        layout = ParameterLayout(self.params.sizes, self.params.shared, frames.pop())
        # Starts: each facing (and the 180-degree flip) is placed by the camera stage, then
        # every placed start is combined with each initial body pose in the decision stage.
        # (several calibrated views: the triangulated torso gives the facing, no flip)
        views_per_frame = problems[0].num_views
        facings = (False, True) if cfg.starts.flip and views_per_frame == 1 else (False,)
        # a given body pose is the one start pose (with both facings when starts.flip is on)
        init_poses = self._initial_poses(1 if init and "body_pose" in init else cfg.starts.poses)
        data, views, state = self._problem_data(problems, facings)
        if frame_weights is not None:
            fw = torch.as_tensor(np.asarray(frame_weights, dtype=np.float64), dtype=dt).reshape(B, layout.frames)
            data["weights"] = data["weights"] * fw.repeat(len(facings), 1)[:, :, None, None]
            if "points3d_weights" in data:
                data["points3d_weights"] = data["points3d_weights"] * fw.repeat(len(facings), 1)[:, :, None]
        if self.whole_body:
            data.update(part_gates(data["weights"]))
        cue = cue_data(list(depth_cues) if depth_cues is not None else [None] * B, layout.frames)
        if cue is not None:  # the image depth cue's data (absent without one: the term is 0)
            data["image_depth"] = torch.as_tensor(np.tile(cue, (len(facings), 1, 1)), dtype=dt)
        for n, v in (init or {}).items():
            v = torch.as_tensor(np.asarray(v, dtype=np.float64), dtype=dt)
            shape = state[n].shape[1:]
            state[n] = v.reshape(B, *shape).repeat(len(facings), *([1] * len(shape)))
        return layout, facings, init_poses, (data, views, state)

    def _run_stages(self, sched: "_ScheduleRun", init_poses: list, decided: bool, views_per_frame: int) -> bool:
        """Every stage of the schedule on ``sched``'s rows (a search, the decision stage, or a plain run); whether the
        start is ``decided`` at the end."""
        for si, stage in enumerate(self.stages):
            if stage.options.get("hand_starts") and self.whole_body:
                sched.state = choose_hand_starts(
                    self.model,
                    self.body,
                    sched.layout,
                    sched.state,
                    sched.views,
                    sched.data,
                    self.config.hands_face.hand_sigma,
                )
            if "branches" in stage.options:
                if views_per_frame > 1:  # the views' data fixes the limbs' depth: no search (docs: rigs)
                    continue
                sched.branch_search(si, stage, decided)
                continue
            if stage.options.get("searched_only") and not sched.searched_any:  # settles searched branches: none here
                continue
            decide_after = stage.options.get("decide_after") if not decided else None
            if decide_after is None:
                if not sched.searched_any and "unsearched_iterations" in stage.options:  # no branches to choose among:
                    # fewer steps, every one run (the final stage as rigs were measured with)
                    opts = {k: v for k, v in stage.options.items() if k not in ("unsearched_iterations", "tol_change")}
                    stage = replace(
                        stage,
                        iterations=min(stage.iterations, int(stage.options["unsearched_iterations"])),
                        options=opts,
                    )
                sched.run(stage)
                continue
            sched.decide(stage, init_poses, decide_after)
            decided = True
        return decided

    def energy_at(self, params: dict, keypoints, cameras=None, *, image_size=None, focal=None, stage: str = "final"):
        """The energy of stage ``stage`` (default: the last, full one) at given parameters
        (``{name: [B, w]}``, e.g. the ground truth), per sample ``[B]``, with its terms.

        With the fit's own value (``result.energies[stage]``) this tells a search failure
        (the fit's energy above the truth's) from an energy whose minimum is wrong."""
        sets = prepare_keypoints(keypoints, self.layout)
        cams = _resolve_cameras(sets, cameras, image_size, focal)
        problems = [Problem.single(ks, cam) for ks, cam in zip(sets, cams)]
        data, views, _ = self._problem_data(problems, (False,))
        if self.whole_body:
            data.update(part_gates(data["weights"]))
        by_name = {s.name: s for s in self.stages}
        if stage not in by_name:
            raise ValueError(f"no stage {stage!r} in the schedule ({', '.join(by_name)})")
        state = {}
        for n in self.params.sizes:
            v = torch.as_tensor(np.asarray(params[n], dtype=np.float64), dtype=self.dtype).reshape(len(sets), -1)
            state[n] = v if self.params.is_shared(n) else v[:, None]
        with torch.no_grad(), torch_threads(self.config.threads):
            ev = evaluate(self.body, self.params, state, views, data)
            total, parts = self.energy(ev, by_name[stage].weights)
        return total.numpy(), {k: v.numpy() for k, v in parts.items()}

    def _result(self, state, info, sets, cams) -> KeypointFitResult:
        layout = info["layout"]
        rows = layout.rows(state)  # one frame per problem here
        with torch.no_grad():
            out = self.model(**rows)
            ev = evaluate(self.body, layout, state, info["views"], info["data"])
            proj = ev.keypoints_2d[:, 0, 0]
            err = (proj - info["data"]["target"][:, 0, 0]).norm(dim=-1).numpy()
        reproj = np.array([np.median(err[b][ks.conf > 0]) for b, ks in enumerate(sets)])
        np_ = lambda t: t.detach().cpu().numpy().astype(np.float32)  # noqa: E731
        extra = {n: np_(rows[n]) for n in layout.sizes if n not in PARAM_NAMES}
        return KeypointFitResult(
            **{n: np_(rows[n]) for n in PARAM_NAMES},
            extra_params=extra,
            cameras=cams,
            vertices=np_(out.vertices),
            joints=np_(out.joints),
            keypoints_2d=np_(proj),
            layout=self.layout,
            energies={k: np_(v) for k, v in info["energies"].items()},
            term_energies={s: {t: np_(v) for t, v in d.items()} for s, d in info["terms"].items()},
            timings=info["timings"],
            flipped=info["flipped"],
            reprojection_error=reproj,
            config=self.config.to_dict(self.whole_body),
            branches=info["branches"],
            branch_search=info["branch_search"],
            model=model_record(self.model),
            hypotheses=info.get("hypotheses"),
            alternatives=info.get("alternatives"),
        )


class _ScheduleRun:
    """One :meth:`KeypointFitter.fit_problems` run: the rows it carries (each problem's starts, then its branch
    hypotheses: ``state``, ``data``, ``views``, ``start_flip``, ``group`` the problem of each row), each stage's
    ``energies``, ``terms`` and ``timings``, and what the branch searches tried and kept (``chosen_branches``,
    ``searched``, ``search_rows``, ``unrefined``), stage by stage; :meth:`choose` ends it."""

    def __init__(
        self,
        fitter: "KeypointFitter",
        layout: ParameterLayout,
        B: int,
        state: dict,
        data: dict,
        views: dict,
        start_flip: torch.Tensor,
        group: torch.Tensor,
        progress: bool,
        calls: Optional[np.ndarray] = None,
    ):
        cfg = fitter.config
        self.fitter, self.layout, self.B, self.progress = fitter, layout, B, progress
        self.state, self.data, self.views, self.start_flip, self.group = state, data, views, start_flip, group
        self.energies, self.terms, self.timings = {}, {}, {}
        self.K = max(1, int(cfg.solutions.count))
        #: rows per sample from the last search to the end
        self.carry = max(int(cfg.branches.refine), 2 * self.K if self.K > 1 else 1)
        self.last_search = max([i for i, s in enumerate(fitter.stages) if "branches" in s.options], default=-1)
        self.occlusion_weight = (
            fitter.stages[self.last_search].options["branches"].get("occlusion", 0.0) if self.last_search >= 0 else 0.0
        )
        self.row_labels = None  # with carry > 1: each row's hypothesis after the last search
        self.carried = None  # each row's hypothesis after an earlier search whose best few go on (its ``carry``)
        self.searched_any = False  # whether a branch search ran (none with several views)
        self.chosen_branches = [[] for _ in range(B)]
        self.searched = [[] for _ in range(B)]  # per problem and branch stage: the hypotheses that ran to its end
        self.search_rows = [[] for _ in range(B)]  # per problem: (tried entry, its joints at the search's end, ...)
        self.unrefined = [[] for _ in range(B)]  # per problem: search rows not refined to the end (hypotheses > 1)
        self.calls = calls  # per problem the image cue's decided sides [B, S] (``image_depth.decide``), or None
        self.cue_on = True  # whether the search now running (and the choices after it) use the decided sides

    def info(self, hypotheses, others) -> dict:
        """:meth:`KeypointFitter.fit_problems`' ``info`` at the end (``hypotheses``, ``others``: :meth:`choose`'s)."""
        return {
            "energies": self.energies,
            "terms": self.terms,
            "timings": self.timings,
            "flipped": self.start_flip.numpy(),
            "branches": self.chosen_branches,
            "branch_search": self.searched,
            "hypotheses": hypotheses,
            "alternatives": others,
            "data": self.data,
            "views": self.views,
            "layout": self.layout,
        }

    def take(self, rows) -> None:
        """Keep these rows (in this order) of the state, data, views and the stages' records."""
        pick = lambda d: {k: v[rows] for k, v in d.items()}  # noqa: E731
        self.state, self.data, self.views = pick(self.state), pick(self.data), pick(self.views)
        self.start_flip, self.group = self.start_flip[rows], self.group[rows]
        for d in (self.energies, self.terms):
            for k in list(d):
                d[k] = d[k][rows] if isinstance(d[k], torch.Tensor) else {t: v[rows] for t, v in d[k].items()}

    def run(self, stage, iters=None, name=None) -> torch.Tensor:
        """Run ``stage`` (``iters`` of its steps) on every row, recorded as ``name``; its energies ``[rows]``."""
        f = self.fitter
        r = run_stage(
            stage,
            self.state,
            self.layout,
            f.energy,
            f.body,
            self.views,
            self.data,
            iterations=iters,
            history=f.config.history,
            progress=self.progress,
        )
        name = name or stage.name
        self.energies[name], self.terms[name], self.timings[name] = r.energy, r.terms, r.seconds
        return r.energy

    def rows_and_joints(self) -> tuple:
        """``(parameters by name [rows, ...], joints [rows, J, 3] float64)`` of every row now."""
        with torch.no_grad():
            now = self.layout.rows(self.state)
            return now, self.fitter.body(**now).joints.double().numpy()

    def joints(self) -> np.ndarray:
        """Every row's joints now (float64)."""
        return self.rows_and_joints()[1]

    def choice(self, f):
        """The scores the refined hypotheses are chosen by, and their occlusion counts (the cue on); rows against
        the image cue's decided sides ranked last (:meth:`demoted`)."""
        if not self.occlusion_weight:
            return self.demoted(f), None
        with torch.no_grad():
            occ = self.fitter.energy.terms["occlusion"](
                evaluate(self.fitter.body, self.layout, self.state, self.views, self.data)
            )
        return self.demoted(f * (1.0 + self.occlusion_weight * occ)), occ

    def camera(self) -> tuple:
        """Every row's (one) camera: ``(R [rows, 3, 3], t [rows, 3])``, float64."""
        return self.views["R"][:, 0, 0].double().numpy(), self.views["t"][:, 0, 0].double().numpy()

    def disagreeing(self) -> torch.Tensor:
        """``[rows]`` whether each row turns a segment the image cue decides the other way (``calls`` set)."""
        R, t = self.camera()
        calls = self.calls[self.group.numpy()]
        return torch.as_tensor(cue_disagrees(self.joints(), R, t, calls, self.fitter.model.joint_names).any(1))

    def demoted(self, score):
        """``score`` with the rows against the image cue's decided sides ranked after those that agree
        (:func:`~silfit.fitting.image_depth.demote_disagreeing`); ``score`` itself without decided sides."""
        if self.calls is None or not self.cue_on:
            return score
        return demote_disagreeing(score, self.group, self.B, self.disagreeing())

    def survivors_of(self, f, count, opts):
        """Each sample's ``count`` best rows by ``f``, distinct ones first (:func:`best_distinct_per_group`;
        the search options' ``distinct``, on where a schedule does not say, as ``hinge``): by energy alone
        with ``distinct`` false."""
        if not opts.get("distinct", True):
            return best_per_group(f, self.group, self.B, count)
        return best_distinct_per_group(f, self.group, self.B, count, self.joints())

    def screened(self, f, count, opts):
        """:meth:`survivors_of` with the image cue's decided sides (``image_depth.decide``): the agreeing rows first
        (``image_depth.decide_screens``), or by ``f`` with the last place of a sample none of whose rows agrees given
        to its best agreeing row (where it has one)."""
        if self.calls is None or not self.cue_on or self.fitter.config.image_depth.decide_screens:
            return self.survivors_of(self.demoted(f), count, opts)
        rows, against = self.survivors_of(f, count, opts).tolist(), self.disagreeing()
        best = best_per_group(torch.where(against, torch.full_like(f, math.inf), f), self.group, self.B).tolist()
        of, out = self.group.tolist(), []
        for b, a in enumerate(best):
            mine = [r for r in rows if of[r] == b]
            if math.isfinite(float(f[a])) and not against[a] and all(against[r] for r in mine):
                mine = (mine[:-1] if len(mine) >= count else mine) + [a]
            out += mine
        return torch.as_tensor(out, dtype=torch.long)

    def settle_pick(self, name) -> None:
        """Each sample's carried row with the lowest score after stage ``name`` (its final energy; the
        occlusion cue as in the final choice) goes on. The earlier search's record names it (``kept``) and
        lists the carried rows' energies there (``settled``, ranked as the pick was, the pick first); with
        hypotheses > 1 the others join the alternatives not refined to the end (their gap is set against the
        fit's final energy at the end: both are energies at the final weights)."""
        f = self.energies[name]
        score, _ = self.choice(f)
        group, carried = self.group, self.carried
        ranked = best_per_group(score, group, self.B, count=len(group)).tolist()  # near-ties as the pick treats them
        best = best_per_group(score, group, self.B)
        alternatives = self.K > 1 and self.fitter.config.solutions.unrefined
        now, joints = self.rows_and_joints() if alternatives else (None, None)
        of = group.tolist()  # read once, not per sample and row
        for b, r in enumerate(best.tolist()):
            mine = [i for i in ranked if of[i] == b]
            assert mine[0] == r
            record = self.searched[b][-1]
            if record["kept"] != "keep":  # that search's own pick, replaced by the settled one
                self.chosen_branches[b].pop()
            if carried[r] != "keep":
                self.chosen_branches[b].append(carried[r])
            record["kept"] = carried[r]
            record["settled"] = [{"flip": carried[i], "energy": float(f[i])} for i in mine]
            for i in mine[1:] if alternatives else ():
                self.unrefined[b].append(
                    {
                        "label": carried[i],
                        "energy": float(f[i]),
                        "stage": name,
                        "gap": None,
                        "joints": joints[i],
                        "params": {n: v[i].detach().cpu().numpy().astype(np.float32) for n, v in now.items()},
                    }
                )
        self.take(best)
        self.carried = None

    def branch_search(self, si: int, stage, decided: bool) -> None:
        """Stage ``si``, a branch search (:func:`~silfit.fitting.branches.limb_hypotheses`, module docstring):
        first an earlier search's carried rows settle (:meth:`settle_pick`); then every row's hypotheses are
        screened and run, each sample's best (``carry`` of them where they go on) kept, the rest recorded. A
        search needs one frame and a ``decided`` start (else ``ValueError``)."""
        fitter, B, cfg = self.fitter, self.B, self.fitter.config
        self.searched_any = True
        early = stage.name[len("branches_") :].isdigit()  # a search after the pose stages
        self.cue_on = cfg.image_depth.decide_early or not early
        if self.carried is not None:  # an earlier search's best rows ran on (its ``carry``): the best goes on
            self.settle_pick(fitter.stages[si - 1].name)
        if not decided or self.layout.frames != 1:
            raise ValueError(f"stage '{stage.name}': the branch search needs one frame and a decided start")
        opts = stage.options["branches"]
        labels = self.add_hypotheses(opts)
        screen, survivors = int(opts.get("screen_after", 0)), int(opts.get("survivors", 2))
        going_on = self.carry if si == self.last_search else int(opts.get("carry", 1))  # rows per sample after it
        survivors = max(survivors, going_on)  # (refined to the end or to the next search)
        # a few steps for all, then the best few go on; split even where no sample has hypotheses,
        # so a sample's steps (two optimiser runs) never depend on the others in its batch
        if 0 < screen < stage.iterations:
            f = self.run(stage, screen, f"{stage.name}_screen")
            rows = self.screened(f, survivors, opts)
            labels = [labels[r] for r in rows.tolist()]
            self.take(rows)
            f = self.run(stage, stage.iterations - screen)
        else:
            f = self.run(stage)
        score = self.demoted(f)  # (the energies themselves without the image cue's decided sides)
        keep = best_per_group(score, self.group, B)
        now = self.record_search(stage.name, f, labels, keep)
        if going_on > 1:  # the best few of each sample go on (to the end, or to the next search)
            keep = self.screened(f, going_on, opts)
            if si == self.last_search:
                self.row_labels = [labels[r] for r in keep.tolist()]
            else:
                self.carried = [labels[r] for r in keep.tolist()]
        if self.K > 1 and cfg.solutions.unrefined:  # the rows that stop here: alternatives not refined to the end
            self.record_unrefined(stage.name, f, keep, now)
        self.take(keep)

    def add_hypotheses(self, opts: dict) -> list:
        """Every row's branch hypotheses (a search's options ``opts``) appended as rows after the ``B`` kept ones;
        each row's label (``"keep"`` for those ``B``)."""
        fitter, B, dt = self.fitter, self.B, self.fitter.dtype
        hyps = limb_hypotheses(
            fitter.body,
            self.layout.rows(self.state),
            fitter.model.joint_names,
            fitter.model.parents,
            opts.get("min_depth_ratio", 0.3),
            opts.get("whole_limbs", True),
            opts.get("joint", False),
            opts.get("hinge", True),
            opts.get("hinge_turns", True),
        )
        if opts.get("turns"):
            hyps += turn_hypotheses(
                fitter.body,
                self.layout.rows(self.state),
                fitter.model.joint_names,
                fitter.model.parents,
                opts["turns"],
                opts.get("min_depth_ratio", 0.3),
                opts.get("whole_limbs", True),
                opts.get("hinge", True),
            )
        if self.calls is not None and self.cue_on:  # each decided segment turned to the image cue's side
            rows = self.layout.rows(self.state)
            calls = self.calls[self.group.numpy()]
            hyps += cue_hypotheses(
                fitter.body, rows, calls, fitter.model.joint_names, fitter.model.parents, self.camera(), opts
            )
        labels = ["keep"] * B + [h[1] for h in hyps]
        self.take(torch.cat([torch.arange(B), torch.as_tensor([h[0] for h in hyps], dtype=torch.long)]))
        for i, h in enumerate(hyps):  # a pose, or {parameter: value} (joint hypotheses)
            for n, v in (h[2] if isinstance(h[2], dict) else {"body_pose": h[2]}).items():
                self.state[n][B + i, 0] = v.to(dt)
        return labels

    def record_search(self, name: str, f, labels: list, keep) -> dict:
        """The search ``name``'s record per sample (its pick ``keep``, every row's energy ``f``: ``searched``,
        ``search_rows``, ``chosen_branches``); every row's parameters at its end."""
        group = self.group
        now, row_joints = self.rows_and_joints()  # each row's joints (and parameters) at the search's end
        for b, k in enumerate(keep.tolist()):
            if labels[k] != "keep":
                self.chosen_branches[b].append(labels[k])
            mine = sorted(torch.nonzero(group == b).flatten().tolist(), key=lambda r: float(f[r]))
            tried = [{"flip": labels[r], "energy": float(f[r])} for r in mine]
            self.searched[b].append({"stage": name, "kept": labels[k], "tried": tried})
            self.search_rows[b] += [(t, row_joints[r], r, k) for t, r in zip(tried, mine)]
        return now

    def record_unrefined(self, name: str, f, keep, now: dict) -> None:
        """The rows of search ``name`` not in ``keep`` (energies ``f``, parameters ``now``): alternatives not refined
        to the end (``unrefined``), with their gap to their sample's pick."""
        going = set(keep.tolist())
        for b in range(self.B):
            for t, j, r, k in self.search_rows[b][-len(self.searched[b][-1]["tried"]) :]:
                if r not in going:
                    self.unrefined[b].append(
                        {
                            "label": t["flip"],
                            "energy": t["energy"],
                            "stage": name,
                            "gap": (t["energy"] - float(f[k])) / max(abs(float(f[k])), 1e-12),
                            "joints": j,
                            "params": {n: v[r].detach().cpu().numpy().astype(np.float32) for n, v in now.items()},
                        }
                    )

    def decide(self, stage, init_poses: list, decide_after: int) -> None:
        """The decision stage: every placed start with each initial body pose, ``decide_after`` of its steps, each
        sample's best start kept, the rest of the stage from it."""
        H = len(init_poses)
        if H > 1:  # row h * N + r: placed start r with initial pose h
            N = self.state["body_pose"].shape[0]
            self.take(torch.arange(N).repeat(H))
            self.state["body_pose"] = torch.cat(
                [p.to(self.fitter.dtype).expand(N, self.layout.frames, -1) for p in init_poses], 0
            )
        together = decide_after if 0 < decide_after < stage.iterations else stage.iterations
        f = self.run(stage, together)  # every start
        self.take(best_per_group(f, self.group, self.B))
        if stage.iterations > together:  # the rest of the stage from the chosen start only
            self.run(stage, stage.iterations - together, f"{stage.name}_chosen")

    def record_cue_choice(self, best) -> None:
        """With the image cue's decided sides: the final choice's record (``searched``' last entry) names them
        (``image_depth``: ``decided`` segment and side, ``fit_agrees`` whether the fit, row ``best[b]``, has them)."""
        if self.calls is None:
            return
        against = self.disagreeing()
        names = [n for n, _, _ in LIMB_SEGMENTS]
        for b, r in enumerate(best.tolist()):
            if self.searched[b]:
                self.searched[b][-1]["image_depth"] = {
                    "decided": {n: "farther" if c > 0 else "nearer" for n, c in zip(names, self.calls[b]) if c},
                    "fit_agrees": not bool(against[r]),
                }

    def choose(self) -> tuple:
        """``(hypotheses, alternatives)``: where the last search carried several rows per sample to the end, each
        sample's lowest score (:meth:`choice`: its final energy, weighed by the occlusion cue where it is on) is
        the fit (its row kept), ``alternatives`` are the other distinct branches refined to the end, with their gap
        to the fit's energy, and ``hypotheses`` the ``K`` best distinct solutions (``None`` with ``K`` 1); both
        ``None`` where no rows were carried. Each search row's joint shift from the fit is recorded (metrics.json;
        depth warnings)."""
        fitter, B, K, cfg = self.fitter, self.B, self.K, self.fitter.config
        hypotheses = others = None
        if self.row_labels is not None:  # the fit: each sample's lowest final energy; the others as alternatives
            final = self.energies[fitter.stages[-1].name]
            score, occ = self.choice(final)
            fit_energy = final[best_per_group(score, self.group, B)].tolist()
            for b, alternatives in enumerate(
                self.unrefined
            ):  # settled rows: their gap to the fit, both at the final weights
                for x in alternatives:
                    if x["gap"] is None:
                        x["gap"] = (x["energy"] - fit_energy[b]) / max(abs(fit_energy[b]), 1e-12)
            hypotheses, best = distinct_hypotheses(
                fitter,
                self.layout,
                self.state,
                final,
                self.group,
                B,
                self.row_labels,
                score=score,
                occlusion=occ,
                max_m=cfg.solutions.joint_max_m,
                unrefined=self.unrefined if cfg.solutions.unrefined else None,
            )
            for b, h in enumerate(hypotheses):  # the branch chosen by the final energy, not the search's
                searched = self.searched[b]
                if searched and searched[-1]["kept"] != "keep":  # the search's pick, replaced below
                    self.chosen_branches[b].pop()
                if h[0]["label"] != "keep":
                    self.chosen_branches[b].append(h[0]["label"])
                if searched:
                    searched[-1]["kept"] = h[0]["label"]
                    # the distinct branches refined to the end, by their final energies: what chose the fit
                    # (metrics.json; plausibility.depth_warnings reads these rather than the search's)
                    searched.append(
                        {
                            "stage": fitter.stages[-1].name,
                            "kept": h[0]["label"],
                            "refined": True,
                            "tried": [
                                {
                                    "flip": x["label"],
                                    "energy": x["energy"],
                                    "differs": list(x["differs"]),
                                    "shift_mm": x["shift_mm"],
                                    "max_shift_mm": x["max_shift_mm"],
                                }
                                for x in h
                                if x["refined"]
                            ],
                        }
                    )
            # the other distinct branches refined to the end, with their gap to the fit's final energy
            # (KeypointFitResult.alternatives: the silhouette stage refines the close ones against a mask)
            others = [
                [
                    {**x, "gap": (x["energy"] - h[0]["energy"]) / max(abs(h[0]["energy"]), 1e-12)}
                    for x in h[1:]
                    if x["refined"]
                ]
                for h in hypotheses
            ]
            hypotheses = [h[:K] for h in hypotheses] if K > 1 else None
            self.record_cue_choice(best)
            self.take(best)
        if any(self.search_rows):  # every search row's joint shift (at its search's end) from the fit (metrics.json;
            fit_joints = self.joints()  # depth_warnings). Against the fit, not the search's kept row: a fit that moved
            for b, entries in enumerate(self.search_rows):  # far after a search is unsure too
                for t, j, *_ in entries:
                    mean_mm, max_mm = joint_shift_mm(j, fit_joints[b])
                    t["shift_mm"], t["max_shift_mm"] = round(mean_mm, 1), round(max_mm, 1)
        return hypotheses, others


def fit_keypoints(
    keypoints,
    camera: Union[Camera, Sequence[Camera], None] = None,
    model=None,
    *,
    image_size=None,
    focal: Optional[float] = None,
    layout: Optional[str] = None,
    config: Optional[KeypointFitConfig] = None,
    pose_prior=None,
    progress: bool = False,
) -> KeypointFitResult:
    """Fit SMPL to 2D keypoints of one person or a batch of people.

    ``keypoints``: a :class:`~silfit.io.keypoints.KeypointSet`, a list of them (a batch), or
    an array ``[K, 3]`` / ``[B, K, 3]`` of ``x, y, confidence`` (layout inferred from K:
    25 BODY_25, 17 COCO-17). ``camera``: one :class:`~silfit.camera.Camera` for all or one
    per sample; without it ``image_size=(W, H)`` (or a list) gives the documented default
    camera, ``focal`` overrides the focal length. ``model`` defaults to the shipped open
    body model; ``pose_prior``: ``None`` (shipped default), a ``gmm_08.pkl`` path or a
    module scoring ``body_pose [B, 69] -> [B]``.
    """
    sets = prepare_keypoints(keypoints, layout)
    fitter = KeypointFitter(model, sets[0].layout, config, pose_prior)
    return fitter.fit(sets, camera, image_size=image_size, focal=focal, progress=progress)
