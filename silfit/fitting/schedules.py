"""The schedules, as literal stage tables: one row per stage, weights by energy term.

The tables are the single source of the schedules: the configs' stage fields take their defaults
from these cells (:class:`~silfit.fitting.keypoint_stage.KeypointFitConfig`,
:class:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig`,
:class:`~silfit.fitting.sequence.SequenceFitConfig`), and a config's ``stages()`` is its table,
edited only where a field differs from its default (:mod:`silfit.fitting.schedule_edits`). A table
is also a valid ``schedule`` to start from: ``KeypointFitConfig(schedule=[...])`` runs any list of
stages. Every weight has one name, the term's (``pose``: the pose prior, whose config field is
``pose_weight`` in every config; ``angle``: ``angle_weight``; ``shape``: ``shape_weight``; ``limits``:
``limit_weight``). A row's weights are in the order the energy sums them. Each stage runs in
:func:`~silfit.fitting.stages.run_stage`, which dispatches on the optimiser column.
"""

from __future__ import annotations

import re

from .stages import Stage

__all__ = [
    "KEYPOINT_SCHEDULE",
    "SEQUENCE_SCHEDULE",
    "SILHOUETTE_SCHEDULE",
    "WHOLEBODY_KEYPOINT_SCHEDULE",
    "named",
    "row",
]

CAMERA = ("global_orient", "transl")
POSE = ("global_orient", "transl", "body_pose")
SHAPE = ("betas", "transl")
ALL = ("betas",) + POSE
HANDS = ("left_hand_pose", "right_hand_pose")
FACE = ("jaw_pose", "expression")
#: the keypoint stage's limb-branch search (:mod:`silfit.fitting.branches`)
BRANCHES = {
    "branches": {
        "min_depth_ratio": 0.3,
        "whole_limbs": True,
        "joint": False,
        "screen_after": 15,
        "survivors": 4,
        "hinge": True,
        "hinge_turns": True,
        "distinct": True,
    }
}
#: the late search's: its 4 best go on (``carry``) to settle; the search from the fit screens after 20 of its 40 steps
LATE_BRANCHES = {"branches": {**BRANCHES["branches"], "carry": 4}}
POST_BRANCHES = {"branches": {**BRANCHES["branches"], "screen_after": 20}}

#: the final stage's weights (also the late branch search's); ``points`` (the keypoints triangulated
#: from several views) is 0 for one view
FINAL = {
    "keypoints": 1.0,
    "pose": 40.0,
    "angle": 1.0,
    "limits": 1e4,
    "shape": 5.0,
    "interpenetration": 1e5,
    "points": 1.0,
}
#: single image (and the per-frame start of a video), SMPL: :class:`~silfit.fitting.keypoint_stage.KeypointFitConfig`
KEYPOINT_SCHEDULE = (
    #     name          free    weights (term: weight)                                                          iterations
    Stage("camera", CAMERA, {"torso": 1.0, "depth": 1e3}, 30),
    Stage(
        "pose_1",
        POSE,
        {"keypoints": 1.0, "pose": 2000.0, "angle": 10.0, "limits": 1e4, "points": 1.0},
        30,
        options={"decide_after": 20},
    ),  # each problem keeps its best start (facing x initial pose) after 20 steps
    Stage("pose_2", POSE, {"keypoints": 1.0, "pose": 400.0, "angle": 5.0, "limits": 1e4, "points": 1.0}, 30),
    Stage(
        "branches_1",
        POSE,
        {"keypoints": 1.0, "pose": 400.0, "angle": 5.0, "limits": 1e4, "points": 1.0, "interpenetration": 1e5},
        20,
        options=BRANCHES,
    ),
    Stage("pose_3", POSE, {"keypoints": 1.0, "pose": 80.0, "angle": 2.0, "limits": 1e4, "points": 1.0}, 40),
    Stage("shape", SHAPE, {"keypoints": 1.0, "shape": 20.0, "points": 1.0}, 20),
    # the limb-branch search again, at the final weights from the refined pose (issue 25); its 4 best go on
    Stage("branches_late", ALL, FINAL, 30, options=LATE_BRANCHES),
    # run by those 4, a row stopping once a step lowers its energy by less than 1e-4 (relative); the
    # lowest energy goes on (not run where no branch search ran: rigs)
    Stage("settle", ALL, FINAL, 120, options={"tol_change": 1e-4, "searched_only": True}),
    # the search from the settled fit (issue 25: a flip of the converged fit finds what the late one cut)
    Stage("branches_post", ALL, FINAL, 40, options=POST_BRANCHES),
    # run by branches.refine (4) hypotheses as settle; where no branch search ran (rigs, branches.search off)
    # 40 steps, every one run
    Stage("final", ALL, FINAL, 120, options={"unsearched_iterations": 40, "tol_change": 1e-4}),
)

#: whole body (an SMPL-X-layout model, the ``wholebody`` keypoints): the body's schedule, the hands started
#: from their best library pose (``hands``), then the hand and face terms on in the last pose stage and after
WHOLEBODY_KEYPOINT_SCHEDULE = KEYPOINT_SCHEDULE[:4] + (
    Stage(
        "hands",
        POSE + HANDS,
        {"keypoints": 1.0, "pose": 80.0, "angle": 2.0, "limits": 1e4, "points": 1.0, "hands": 1.0, "hand_pose": 2.0},
        30,
        options={"hand_starts": True},
    ),
    Stage(
        "pose_3",
        POSE + HANDS + FACE,
        {
            "keypoints": 1.0,
            "pose": 80.0,
            "angle": 2.0,
            "limits": 1e4,
            "points": 1.0,
            "hands": 1.0,
            "hand_pose": 2.0,
            "face": 1.0,
            "jaw": 50.0,
            "expression": 2.0,
        },
        40,
    ),
    Stage("shape", SHAPE, {"keypoints": 1.0, "shape": 20.0, "points": 1.0, "hands": 2.0, "face": 2.0}, 20),
    Stage(
        "branches_late",
        ALL + HANDS + FACE,
        {**FINAL, "hands": 2.0, "hand_pose": 2.0, "face": 2.0, "jaw": 50.0, "expression": 2.0},
        30,
        options=LATE_BRANCHES,
    ),
    Stage(
        "settle",
        ALL + HANDS + FACE,
        {**FINAL, "hands": 2.0, "hand_pose": 2.0, "face": 2.0, "jaw": 50.0, "expression": 2.0},
        120,
        options={"tol_change": 1e-4, "searched_only": True},
    ),
    Stage(
        "branches_post",
        ALL + HANDS + FACE,
        {**FINAL, "hands": 2.0, "hand_pose": 2.0, "face": 2.0, "jaw": 50.0, "expression": 2.0},
        40,
        options=POST_BRANCHES,
    ),
    Stage(
        "final",
        ALL + HANDS + FACE,
        {**FINAL, "hands": 2.0, "hand_pose": 2.0, "face": 2.0, "jaw": 50.0, "expression": 2.0},
        120,
        options={"unsearched_iterations": 40, "tol_change": 1e-4},
    ),
)

SIL_FREE = ("betas", "global_orient", "body_pose", "transl")
#: the silhouette stage's terms and weights other than the silhouette's own (every level)
SIL_PRIORS = {
    "keypoints": 0.02,
    "pose": 0.005,
    "limits": 1.0,
    "angle": 0.001,
    "shape": 0.005,
    "stay": 0.0,
    "keypoint_trust": 0.05,
    "beta_bound": 10.0,
}
#: Adam's settings of the rendered levels (:class:`~silfit.fitting.stages.AdamSettings`)
SIL_ADAM = {
    "lr": {"betas": 0.1, "global_orient": 0.02, "body_pose": 0.015, "transl": 0.01},
    "warmup": 10,
    "plateau_window": 12,
    "plateau_rtol": 0.003,
}

#: the silhouette stage: :class:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig` (no rendering in the
#: contour level; each rendered level's window has ``resolution`` pixels along its longer side and renders a
#: ``proxy_faces``-face render proxy)
SILHOUETTE_SCHEDULE = (
    #     name              free      weights                                                     iterations optimiser
    Stage(
        "contour",
        SIL_FREE,
        {"contour_inside": 0.2, "contour_cover": 0.2, **SIL_PRIORS},
        40,
        "lbfgs",
        {"resolution": 256},
    ),
    Stage(
        "silhouette_128",
        SIL_FREE,
        {"silhouette": 1.0, **SIL_PRIORS},
        30,
        "adam",
        {"resolution": 128, "proxy_faces": 3000, **SIL_ADAM},
    ),
    Stage(
        "silhouette_256",
        SIL_FREE,
        {"silhouette": 1.0, **SIL_PRIORS},
        20,
        "adam",
        {"resolution": 256, "proxy_faces": 5000, **SIL_ADAM},
    ),
)

#: a video's joint refinement (one problem of F frames, one shape):
#: :class:`~silfit.fitting.sequence.SequenceFitConfig` (windowed: a second pass of 40 steps with ``betas`` held)
SEQUENCE_SCHEDULE = (
    Stage(
        "sequence",
        ALL,
        {
            "keypoints": 1.0,
            "pose": 40.0,
            "angle": 1.0,
            "limits": 1e4,
            "smooth_joints": 1.0,
            "smooth_root": 1.0,
            "shape": 5.0,
        },
        100,
    ),
)


def named(table, pattern: str) -> list:
    """The rows of ``table`` whose name matches ``pattern`` (a regular expression, whole name), in order."""
    return [s for s in table if re.fullmatch(pattern, s.name)]


def row(table, name: str) -> Stage:
    """The row of ``table`` named ``name``."""
    for s in table:
        if s.name == name:
            return s
    raise KeyError(f"no stage {name!r} in the table ({', '.join(s.name for s in table)})")
