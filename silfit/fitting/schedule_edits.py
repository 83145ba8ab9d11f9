"""A config's schedule: its literal table (:mod:`silfit.fitting.schedules`), edited where a field asks.

The tables are the schedules. A config's stage fields take their defaults from the tables' cells
(:func:`keypoint_defaults`), and its ``stages()`` returns its table as it stands unless a field differs
from its default (``changed``: the names of those fields); then each such field rewrites the cells it
names, and only those (:func:`keypoint_stages`):

* a weight field sets its term's weight in the rows that carry it (``pose_weight``: each pose row's,
  then the final weights' rows'; ``limit_weight``: every row's ``limits``; a zero ``points_weight``
  removes the term); an iterations field its rows' iterations; an option field its option;
* a field that adds or removes rows does so from the table's rows as templates: ``branch_search``,
  ``branch_rounds``, ``late_branch_iters``/``late_branch_rounds``, ``post_branch_iters``, ``shape_iters``,
  ``final_iters`` (0: no such rows), ``hand_iters`` (0: no ``hands`` row, the hands start in their pose
  row), ``pose_iters`` of another length (a pose row more or less: the last pose row's copy), the rows that
  follow a pose row (``hands`` before it, the branch searches after it: ``branch_after_stage``) taking
  that pose row's weights as in the table.

A row's weights keep the order the energy sums them in (the table's; a term a field adds goes where
:data:`TERM_ORDER` puts it), so an edit gives what the same stages written out would.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import replace
from typing import Mapping, Optional

from .aliases import flat_names, flat_value
from .schedules import (
    FACE,
    HANDS,
    KEYPOINT_SCHEDULE,
    SEQUENCE_SCHEDULE,
    SILHOUETTE_SCHEDULE,
    WHOLEBODY_KEYPOINT_SCHEDULE,
    named,
    row,
)
from .stages import Stage

__all__ = [
    "BRANCH_KEYS",
    "TERM_ORDER",
    "changed_fields",
    "keypoint_defaults",
    "keypoint_stages",
    "sequence_defaults",
    "sequence_stages",
    "silhouette_defaults",
    "silhouette_stages",
    "with_cells",
]

POSE_ROW = r"pose_\d+"
SEARCH_ROW = r"branches_\d+"
LATE_ROW = r"branches_late(_\d+)?"
#: the rows at the final stage's weights
FINAL_ROWS = (LATE_ROW, "settle", "branches_post", "final")
#: the config fields of a branch search's options (``options["branches"]``), by option
BRANCH_KEYS = {
    "branch_min_depth_ratio": "min_depth_ratio",
    "branch_whole_limbs": "whole_limbs",
    "branch_joint": "joint",
    "branch_screen_iters": "screen_after",
    "branch_survivors": "survivors",
    "branch_hinge": "hinge",
    "branch_hinge_turns": "hinge_turns",
    "branch_distinct": "distinct",
}
PART_TERMS = ("hands", "hand_pose", "face", "jaw", "expression")
#: where a term goes in a row's weights (the tables' order, the order the energy sums them)
TERM_ORDER = (
    "keypoints",
    "torso",
    "depth",
    "pose",
    "angle",
    "limits",
    "shape",
    "interpenetration",
    "image_depth",
    "points",
) + PART_TERMS


def keypoint_defaults() -> dict:
    """:class:`~silfit.fitting.keypoint_stage.KeypointFitConfig`'s stage fields' defaults, read from
    :data:`~silfit.fitting.schedules.KEYPOINT_SCHEDULE` (the hand and face fields' from
    ``WHOLEBODY_KEYPOINT_SCHEDULE``)."""
    k, wb = KEYPOINT_SCHEDULE, WHOLEBODY_KEYPOINT_SCHEDULE
    poses, final, search, late = named(k, POSE_ROW), row(k, "final"), row(k, "branches_1"), row(k, "branches_late")
    decide = next(i for i, s in enumerate(poses) if "decide_after" in s.options)
    names = [s.name for s in k]
    return {
        "camera_iters": row(k, "camera").iterations,
        "depth_weight": row(k, "camera").weights["depth"],
        "pose_iters": tuple(s.iterations for s in poses),
        "pose_weight": tuple(s.weights["pose"] for s in poses + [final]),
        "angle_weight": tuple(s.weights["angle"] for s in poses + [final]),
        "flip_decision_stage": decide,
        "decision_iters": poses[decide].options["decide_after"],
        "shape_iters": row(k, "shape").iterations,
        "shape_weight": (row(k, "shape").weights["shape"], final.weights["shape"]),
        "final_iters": final.iterations,
        "final_iters_unsearched": final.options.get("unsearched_iterations"),
        "final_tol_change": final.options.get("tol_change"),
        "limit_weight": final.weights["limits"],
        "interpenetration_weight": final.weights["interpenetration"],
        "points_weight": poses[0].weights.get("points", 0.0),
        "final_points_weight": final.weights.get("points", 0.0),
        "branch_search": bool(named(k, SEARCH_ROW)),
        "branch_after_stage": len(named(k[: names.index(search.name)], POSE_ROW)) - 1,
        "branch_iters": search.iterations,
        "branch_rounds": len(named(k, SEARCH_ROW)),
        **{name: search.options["branches"][key] for name, key in BRANCH_KEYS.items()},
        "late_branch_iters": late.iterations,
        "late_branch_rounds": len(named(k, LATE_ROW)),
        "branch_refine": late.options["branches"]["carry"],
        "post_branch_iters": row(k, "branches_post").iterations,
        "hand_iters": row(wb, "hands").iterations,
        "hand_prior_weight": row(wb, "final").weights["hand_pose"],
        "jaw_weight": row(wb, "final").weights["jaw"],
        "expression_weight": row(wb, "final").weights["expression"],
        "final_hand_weight": row(wb, "final").weights["hands"],
        "final_face_weight": row(wb, "final").weights["face"],
    }


def differs(value, default) -> bool:
    """Whether a field's value is not its default (a value that does not compare, e.g. an array: differs)."""
    try:
        return bool(value != default)
    except (TypeError, ValueError):
        return True


def changed_fields(config, skip=("schedule",)) -> frozenset:
    """The names of ``config``'s (a dataclass) fields that differ from their defaults; a group's fields (a field
    holding a dataclass, its fields once flat: :func:`~silfit.fitting.aliases.grouped`) by their flat names too."""
    flat = flat_names(type(config))
    out = set()
    for f in dataclasses.fields(config):
        if f.name in skip:
            continue
        value, default = (
            getattr(config, f.name),
            f.default if f.default is not dataclasses.MISSING else f.default_factory(),
        )
        if differs(value, default):
            out.add(f.name)
            out.update(old for old, sub in flat.get(f.name, ()) if differs(getattr(value, sub), getattr(default, sub)))
    return frozenset(out)


def with_cells(weights: Mapping, cells: Mapping) -> dict:
    """``weights`` with ``cells`` set (a ``None`` cell removes its term), in :data:`TERM_ORDER` (other terms
    after, in their order)."""
    w = {k: v for k, v in {**weights, **cells}.items() if v is not None}
    return {**{k: w[k] for k in TERM_ORDER if k in w}, **{k: v for k, v in w.items() if k not in TERM_ORDER}}


def parts(cfg, hands, face) -> tuple:
    """``(weights, free)`` the hand and face parts add to a row whose hand and face keypoint weights are these."""
    w, free = {}, ()
    if hands:
        w.update(hands=hands, hand_pose=cfg.hands_face.hand_prior_weight)
        free += HANDS
    if face:
        w.update(face=face, jaw=cfg.hands_face.jaw_weight, expression=cfg.hands_face.expression_weight)
        free += FACE
    return w, free


def without_parts(stage: Stage) -> tuple:
    """``(weights, free)`` of ``stage`` without the hand and face parts'."""
    return (
        {k: v for k, v in stage.weights.items() if k not in PART_TERMS},
        tuple(p for p in stage.free if p not in HANDS + FACE),
    )


@dataclasses.dataclass(frozen=True)
class Edit:
    """What edits a table: the config, the names of its fields that differ from their defaults, and whether the
    schedule is the whole body's."""

    cfg: object
    changed: frozenset
    whole_body: bool = False

    def get(self, name: str, table_value, convert=None):
        """Field ``name``'s value (through ``convert``) where it changed, else the table's ``table_value``."""
        if name not in self.changed:
            return table_value
        value = flat_value(self.cfg, name)
        return value if convert is None else convert(value)

    def cells(self, **cells: tuple) -> dict:
        """``term: (field, value)``: the cells whose field changed, ``term: value``."""
        return {term: value for term, (name, value) in cells.items() if name in self.changed}


def term_or_none(value) -> Optional[float]:
    """A weight that is off (0) removes its term: ``None``; else the weight as a float."""
    return float(value) if value else None


def keypoint_stages(cfg, whole_body: bool = False) -> tuple:
    """:meth:`KeypointFitConfig.stages <silfit.fitting.keypoint_stage.KeypointFitConfig.stages>`: the table
    (``WHOLEBODY_KEYPOINT_SCHEDULE`` with ``whole_body``, else ``KEYPOINT_SCHEDULE``; a copy), edited by the fields
    that differ from their defaults (the module docstring)."""
    table = WHOLEBODY_KEYPOINT_SCHEDULE if whole_body else KEYPOINT_SCHEDULE
    changed = changed_fields(cfg)
    if not changed:
        return copy.deepcopy(table)
    e = Edit(cfg, changed, whole_body)
    out = [camera_row(row(table, "camera"), e)] + pose_block(table, e)
    if cfg.shape_iters:
        out.append(shape_row(row(table, "shape"), e))
    b = cfg.branches
    if b.search and b.late_iters:
        hypotheses = int(cfg.solutions.count)
        carry = max(int(b.refine), 2 * hypotheses if hypotheses > 1 else 1)
        out += late_rows(named(table, LATE_ROW)[0], e, carry if cfg.final_iters and b.post_iters else 1)
    if cfg.final_iters:
        if b.search and b.post_iters:
            out += [settle_row(row(table, "settle"), e), post_row(row(table, "branches_post"), e)]
        out.append(final_row(row(table, "final"), e))
    return tuple(out)


def camera_row(t: Stage, e: Edit) -> Stage:
    """The camera row: ``camera_iters``, ``depth_weight``."""
    cells = e.cells(depth=("depth_weight", e.cfg.depth_weight))
    return replace(t, weights=with_cells(t.weights, cells), iterations=e.get("camera_iters", t.iterations))


def pose_parts(poses: list, e: Edit, n: int) -> tuple:
    """The hand and face keypoint weights of the ``n`` pose rows: ``hand_weights``, ``face_weights``, or (``None``)
    the table's pose rows' (``n`` other than theirs: 0 but in the last, the table's last's); 0 but whole body."""
    if not e.whole_body:
        return (0.0,) * n, (0.0,) * n

    def per_pose(given, term):
        if given is not None:
            return tuple(given)
        if n == len(poses):
            return tuple(p.weights.get(term, 0.0) for p in poses)
        return (0.0,) * (n - 1) + (poses[-1].weights.get(term, 0.0),)

    return per_pose(e.cfg.hands_face.hand_weights, "hands"), per_pose(e.cfg.hands_face.face_weights, "face")


#: the fields of the pose rows' hand and face terms, and of their options
POSE_PART_FIELDS = frozenset({"hand_weights", "face_weights", "hand_prior_weight", "jaw_weight", "expression_weight"})
POSE_OPTION_FIELDS = frozenset({"decision_iters", "flip_decision_stage", "hand_iters", "hand_weights"})


def pose_block(table, e: Edit) -> list:
    """The pose rows (``pose_iters``: one per pose stage), each with the ``hands`` row before it where the hands start
    there, and the branch searches after pose row ``branch_after_stage``."""
    cfg, poses = e.cfg, named(table, POSE_ROW)
    n = len(cfg.pose_iters)
    hw, fw = pose_parts(poses, e, n)
    after = min(int(cfg.branches.after_stage), n - 1)
    out = []
    for i in range(n):
        p = pose_row(poses[min(i, len(poses) - 1)], i, e, (hw, fw), n != len(poses))
        if hw[i] and not any(hw[:i]) and cfg.hands_face.hand_iters:
            out.append(hands_row(row(table, "hands"), p, e, hw[i]))
        out.append(p)
        if cfg.branches.search and i == after:
            out += search_rows(named(table, SEARCH_ROW)[0], p, e)
    return out


def pose_row(t: Stage, i: int, e: Edit, part_weights: tuple, recount: bool) -> Stage:
    """Pose row ``i`` (0-based) from the table's row ``t`` (``recount``: the number of pose rows changed):
    ``pose_iters``, ``pose_weight``, ``angle_weight``, ``limit_weight``, ``points_weight``, the hand and face
    terms (``part_weights``: per pose row) and the options (``decide_after``, ``hand_starts``)."""
    cfg, (hw, fw) = e.cfg, part_weights
    cells = e.cells(
        pose=("pose_weight", cfg.pose_weight[i]),
        angle=("angle_weight", cfg.angle_weight[i]),
        limits=("limit_weight", cfg.limit_weight),
        points=("points_weight", term_or_none(cfg.points_weight)),
    )
    weights, free = with_cells(t.weights, cells), t.free
    if e.whole_body and (recount or e.changed & POSE_PART_FIELDS):
        base, base_free = without_parts(t)
        part_w, part_free = parts(cfg, hw[i], fw[i])
        weights, free = {**with_cells(base, cells), **part_w}, base_free + part_free
    options = t.options
    if recount or e.changed & POSE_OPTION_FIELDS:
        rest = {k: v for k, v in t.options.items() if k not in ("decide_after", "hand_starts")}
        options = {**({"decide_after": int(cfg.decision_iters)} if i == cfg.flip_decision_stage else {}), **rest}
        if hw[i] and not any(hw[:i]) and not cfg.hands_face.hand_iters:
            options["hand_starts"] = True
    iterations = int(cfg.pose_iters[i]) if "pose_iters" in e.changed else t.iterations
    return replace(t, name=f"pose_{i + 1}", free=free, weights=weights, iterations=iterations, options=options)


def hands_row(t: Stage, pose: Stage, e: Edit, hands: float) -> Stage:
    """The ``hands`` row before pose row ``pose``: its weights without parts, the hands' keypoints (``hands``) and
    prior; ``hand_iters``."""
    base, _ = without_parts(pose)
    weights = {**base, "hands": hands, "hand_pose": e.cfg.hands_face.hand_prior_weight}
    return replace(t, weights=weights, iterations=e.get("hand_iters", t.iterations, int))


def search_rows(t: Stage, pose: Stage, e: Edit) -> list:
    """The branch searches after pose row ``pose`` (``branch_rounds``): its weights and free parameters, the
    interpenetration term (and the image depth cue's); ``branch_iters`` and the branch options."""
    cfg = e.cfg
    weights = {
        **pose.weights,
        "interpenetration": e.get("interpenetration_weight", t.weights["interpenetration"]),
        **({"image_depth": float(cfg.image_depth.weight)} if cfg.image_depth.weight else {}),
    }
    b = branch_options(t.options["branches"], e)
    return [
        replace(
            t,
            name=f"branches_{r + 1}",
            free=pose.free,
            weights=weights,
            iterations=e.get("branch_iters", t.iterations, int),
            options={**t.options, "branches": dict(b)},
        )
        for r in range(int(cfg.branches.rounds))
    ]


def branch_options(table_options: Mapping, e: Edit) -> dict:
    """A branch search's ``options["branches"]`` from the table's: the branch fields that changed, the occlusion
    cue's weight (``occlusion.weight``); without the late search's ``turns`` and ``carry``."""
    b = {k: v for k, v in table_options.items() if k not in ("carry", "turns", "occlusion")}
    for name, key in BRANCH_KEYS.items():
        if name in e.changed:
            b[key] = flat_value(e.cfg, name)
    if e.cfg.occlusion.weight:
        b["occlusion"] = float(e.cfg.occlusion.weight)
    return b


def shape_row(t: Stage, e: Edit) -> Stage:
    """The shape row: ``shape_iters``, ``shape_weight``'s first, ``final_points_weight``, the final hand and face
    keypoint weights."""
    cfg = e.cfg
    cells = e.cells(
        shape=("shape_weight", cfg.shape_weight[0]),
        points=("final_points_weight", term_or_none(cfg.final_points_weight)),
    )
    if e.whole_body and e.changed & {"final_hand_weight", "final_face_weight"}:
        cells.update(hands=cfg.hands_face.final_hand_weight or None, face=cfg.hands_face.final_face_weight or None)
    return replace(t, weights=with_cells(t.weights, cells), iterations=e.get("shape_iters", t.iterations))


FINAL_PART_FIELDS = frozenset(
    {"final_hand_weight", "final_face_weight", "hand_prior_weight", "jaw_weight", "expression_weight"}
)


def at_final_weights(t: Stage, e: Edit) -> Stage:
    """Row ``t`` (one of :data:`FINAL_ROWS`) with the final weights' fields that changed: ``pose_weight``'s,
    ``angle_weight``'s and ``shape_weight``'s last, ``limit_weight``, ``interpenetration_weight``,
    ``image_depth.weight``, ``final_points_weight``, the final hand and face terms (and their parameters)."""
    cfg = e.cfg
    cells = e.cells(
        pose=("pose_weight", cfg.pose_weight[-1]),
        angle=("angle_weight", cfg.angle_weight[-1]),
        limits=("limit_weight", cfg.limit_weight),
        shape=("shape_weight", cfg.shape_weight[-1]),
        interpenetration=("interpenetration_weight", cfg.interpenetration_weight),
        image_depth=("image_depth", term_or_none(cfg.image_depth.weight)),
        points=("final_points_weight", term_or_none(cfg.final_points_weight)),
    )
    free = t.free
    if e.whole_body and e.changed & FINAL_PART_FIELDS:
        part_w, part_free = parts(cfg, cfg.hands_face.final_hand_weight, cfg.hands_face.final_face_weight)
        cells.update({k: part_w.get(k) for k in PART_TERMS})
        free = without_parts(t)[1] + part_free
    return replace(t, weights=with_cells(t.weights, cells), free=free)


def late_rows(t: Stage, e: Edit, carry: int) -> list:
    """The late searches (``late_branch_rounds``: ``branches_late``, ``branches_late_<r>``) at the final weights:
    ``late_branch_iters``, the branch options, ``late_branch_turns``, ``late_branch_survivors``, and the last one's
    ``carry`` where it is above 1."""
    cfg = e.cfg
    b = branch_options(t.options["branches"], e)
    if cfg.branches.late_turns:
        b["turns"] = list(cfg.branches.late_turns)
    if cfg.branches.late_survivors:
        b["survivors"] = int(cfg.branches.late_survivors)
    rounds = max(1, int(cfg.branches.late_rounds))
    base = at_final_weights(t, e)
    return [
        replace(
            base,
            name="branches_late" if r == 0 else f"branches_late_{r + 1}",
            iterations=e.get("late_branch_iters", t.iterations, int),
            options={**t.options, "branches": {**b, **({"carry": carry} if r == rounds - 1 and carry > 1 else {})}},
        )
        for r in range(rounds)
    ]


def settle_row(t: Stage, e: Edit) -> Stage:
    """``settle``: ``final_iters``, ``final_tol_change``."""
    options = t.options
    if "final_tol_change" in e.changed:
        tol = e.cfg.final_tol_change
        rest = {k: v for k, v in t.options.items() if k != "tol_change"}
        options = {**({} if tol is None else {"tol_change": float(tol)}), **rest}
    return replace(at_final_weights(t, e), iterations=e.get("final_iters", t.iterations), options=options)


def post_row(t: Stage, e: Edit) -> Stage:
    """``branches_post``, the search from the fit: ``post_branch_iters`` (its screen after half of them) and the
    branch options."""
    b = branch_options(t.options["branches"], e)
    b["screen_after"] = e.get("post_branch_iters", t.options["branches"]["screen_after"], lambda v: int(v) // 2)
    iterations = e.get("post_branch_iters", t.iterations, int)
    return replace(at_final_weights(t, e), iterations=iterations, options={**t.options, "branches": b})


def final_row(t: Stage, e: Edit) -> Stage:
    """``final``: ``final_iters``, ``final_iters_unsearched`` (an option where below ``final_iters``),
    ``final_tol_change``."""
    cfg, options = e.cfg, t.options
    if e.changed & {"final_iters", "final_iters_unsearched", "final_tol_change"}:
        unsearched, tol = cfg.final_iters_unsearched, cfg.final_tol_change
        rest = {k: v for k, v in t.options.items() if k not in ("unsearched_iterations", "tol_change")}
        options = (
            {} if unsearched is None or unsearched >= cfg.final_iters else {"unsearched_iterations": int(unsearched)}
        )
        options = {**options, **({} if tol is None else {"tol_change": float(tol)}), **rest}
    return replace(at_final_weights(t, e), iterations=e.get("final_iters", t.iterations), options=options)


#: :class:`~silfit.fitting.sequence.SequenceFitConfig`'s weight fields, by term
SEQUENCE_TERMS = {
    "pose_weight": "pose",
    "angle_weight": "angle",
    "limit_weight": "limits",
    "shape_weight": "shape",
    "joint_smooth_weight": "smooth_joints",
    "root_smooth_weight": "smooth_root",
}


def sequence_defaults() -> dict:
    """:class:`~silfit.fitting.sequence.SequenceFitConfig`'s stage fields' defaults, read from
    :data:`~silfit.fitting.schedules.SEQUENCE_SCHEDULE`."""
    t = row(SEQUENCE_SCHEDULE, "sequence")
    return {"iterations": t.iterations, **{name: t.weights[term] for name, term in SEQUENCE_TERMS.items()}}


def sequence_stages(cfg, free_betas: bool = True, iterations: Optional[int] = None, views: int = 1) -> tuple:
    """:meth:`SequenceFitConfig.stages <silfit.fitting.sequence.SequenceFitConfig.stages>`: the table's one row,
    its weights those of the fields that differ from their defaults (the table's), the temporal ones times
    ``views_smooth_scale`` for several ``views``, ``interpenetration_weight`` where not 0; ``free_betas`` off: the
    shape held (no ``betas``, no ``shape`` term); ``iterations``: that many steps (else ``iterations``')."""
    t = row(SEQUENCE_SCHEDULE, "sequence")
    e = Edit(cfg, changed_fields(cfg, skip=("keypoint",)))
    k = 1.0 if views <= 1 else cfg.views_smooth_scale
    weights = {**t.weights, **e.cells(**{term: (name, getattr(cfg, name)) for name, term in SEQUENCE_TERMS.items()})}
    weights.update({term: k * weights[term] for term in ("smooth_joints", "smooth_root")})
    if not free_betas:
        weights.pop("shape")
    if cfg.interpenetration_weight:
        weights["interpenetration"] = cfg.interpenetration_weight
    free = t.free if free_betas else tuple(p for p in t.free if p != "betas")
    steps = e.get("iterations", t.iterations, int) if iterations is None else int(iterations)
    return (replace(t, free=free, weights=weights, iterations=steps, options=copy.deepcopy(t.options)),)


LEVEL_ROW = r"silhouette_\d+"
#: :class:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig`'s weight fields, by term
SILHOUETTE_TERMS = {
    "w_contour_inside": "contour_inside",
    "w_contour_cover": "contour_cover",
    "w_silhouette": "silhouette",
    "w_keypoints": "keypoints",
    "pose_weight": "pose",
    "limit_weight": "limits",
    "angle_weight": "angle",
    "shape_weight": "shape",
    "w_stay": "stay",
    "w_trust": "keypoint_trust",
    "w_beta_bound": "beta_bound",
}
#: its Adam settings fields (the rendered levels' options but ``lr``), each with its type
ADAM_FIELDS = {"warmup": int, "plateau_window": int, "plateau_rtol": float}


def silhouette_defaults() -> dict:
    """:class:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig`'s stage fields' defaults, read from
    :data:`~silfit.fitting.schedules.SILHOUETTE_SCHEDULE` (the weights: the contour level's contour terms, the first
    rendered level's others)."""
    contour, levels = row(SILHOUETTE_SCHEDULE, "contour"), named(SILHOUETTE_SCHEDULE, LEVEL_ROW)
    weights = {**contour.weights, **levels[0].weights}
    return {
        "resolutions": tuple(s.options["resolution"] for s in levels),
        "iterations": tuple(s.iterations for s in levels),
        "contour_iterations": contour.iterations,
        "contour_resolution": contour.options["resolution"],
        **{name: weights[term] for name, term in SILHOUETTE_TERMS.items()},
        "lr": dict(levels[0].options["lr"]),
        **{name: levels[0].options[name] for name in ADAM_FIELDS},
        "level_proxy_faces": {s.options["resolution"]: s.options["proxy_faces"] for s in levels},
        "optimise": levels[0].free,
    }


def silhouette_stages(cfg) -> tuple:
    """:meth:`SilhouetteFitConfig.stages <silfit.fitting.silhouette_stage.SilhouetteFitConfig.stages>`: the table's
    contour level (where ``contour_iterations``), then one rendered level per resolution of ``resolutions`` (the
    table's row of that resolution, else a copy of its last), each edited by the fields that differ from their
    defaults (the table's)."""
    e = Edit(cfg, changed_fields(cfg))
    cells = e.cells(**{term: (name, getattr(cfg, name)) for name, term in SILHOUETTE_TERMS.items()})
    levels = named(SILHOUETTE_SCHEDULE, LEVEL_ROW)
    by_resolution = {s.options["resolution"]: s for s in levels}
    contour = ()
    if cfg.contour_iterations:
        t = row(SILHOUETTE_SCHEDULE, "contour")
        options = {**t.options, "resolution": e.get("contour_resolution", t.options["resolution"], int)}
        iterations = e.get("contour_iterations", t.iterations, int)
        free = tuple(cfg.optimise) if "optimise" in e.changed else t.free
        contour = (replace(t, free=free, weights=in_place(t.weights, cells), iterations=iterations, options=options),)
    return contour + tuple(
        level_row(by_resolution.get(int(r), levels[-1]), e, cells, int(r), int(it))
        for r, it in zip(cfg.resolutions, cfg.iterations)
    )


def in_place(weights: Mapping, cells: Mapping) -> dict:
    """``weights`` with the ``cells`` of its terms set, in its order (the others not added)."""
    return {k: cells.get(k, v) for k, v in weights.items()}


def level_row(t: Stage, e: Edit, cells: Mapping, resolution: int, iterations: int) -> Stage:
    """A rendered level at ``resolution`` from the table's row ``t``: its weights' ``cells``, ``iterations`` where
    ``iterations`` or ``resolutions`` changed, the render proxy's faces (``proxy_faces``, ``level_proxy_faces``),
    the learning rates (``lr`` of ``optimise``) and Adam's settings."""
    cfg, o = e.cfg, t.options
    renumbered = "resolutions" in e.changed
    faces = o.get("proxy_faces")
    if renumbered or e.changed & {"proxy_faces", "level_proxy_faces"}:
        faces = cfg.level_faces(resolution)
    lr = {k: cfg.lr[k] for k in cfg.optimise} if e.changed & {"lr", "optimise"} else o["lr"]
    rest = {k: v for k, v in o.items() if k not in ("resolution", "proxy_faces", "lr", *ADAM_FIELDS)}
    options = {
        "resolution": resolution,
        **({} if faces is None else {"proxy_faces": faces}),
        "lr": lr,
        **{name: e.get(name, o[name], convert) for name, convert in ADAM_FIELDS.items()},
        **rest,
    }
    return replace(
        t,
        name=f"silhouette_{resolution}",
        free=tuple(cfg.optimise) if "optimise" in e.changed else t.free,
        weights=in_place(t.weights, cells),
        iterations=iterations if renumbered or "iterations" in e.changed else t.iterations,
        options=options,
    )
