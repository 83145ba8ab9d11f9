"""Plausibility of a fit's input and output: pure functions, no fitting.

* :func:`check_keypoints` runs before a fit. Keypoints lying more than
  :data:`OUTSIDE_MARGIN` image sizes outside the image are **treated as missing**
  (confidence 0, coordinates 0) with a warning; degenerate sets are **refused** with an
  :class:`~silfit.errors.InputError`: every keypoint at (nearly) one place, a person
  less than :data:`MIN_PERSON_PX` pixels tall, a torso (shoulder/neck centre to hip
  centre) shorter than :data:`MIN_TORSO_FRACTION` of the person.
* :func:`fit_warnings` runs after a fit and returns warnings (strings) for results that
  are probably wrong: a final silhouette IoU below :data:`MIN_IOU` or far below the
  keypoint stage's (:data:`IOU_DROP`), a body at an absurd depth (outside
  :data:`DEPTH_RANGE_M`, or partly behind the camera), a median reprojection error above
  :data:`MAX_REPROJECTION_FRACTION` of the person's height in the image, a silhouette stage
  that moved the body away from the keypoints (its reprojection error above
  :data:`MAX_REPROJECTION_RISE` times the keypoint stage's and :data:`MIN_REPROJECTION_RISE_PX`
  more), a shape outside the shape space's plausible range (:data:`MAX_ABS_BETA`).
* :func:`silhouette_guard` runs after a silhouette stage: when the refined fit is less
  plausible than the keypoint fit it started from (reprojection error above
  :data:`GUARD_REPROJECTION_RISE` times the keypoint stage's, |betas| beyond
  :data:`MAX_ABS_BETA`, a stature outside :data:`STATURE_RANGE_M`, each only where the keypoint
  fit was not already so), it says to keep the keypoint fit, with a warning. It takes numbers
  (:func:`fit_summary` makes them) and holds no model; the one silhouette driver's hooks
  (:func:`silfit.fitting.refine.refine_silhouettes`) for images (:class:`silfit.fitting.image_fit.ImageRefinement`),
  rigs (:class:`silfit.fitting.rig_pipeline.RigRefinement`) and videos
  (:class:`silfit.fitting.sequence.SequenceRefinement`) all call it when they read the stage's results back.
* :func:`mask_warnings`: a mask that runs out of the image (the person cut off);
  :func:`depth_warnings`: a depth branch the keypoints cannot decide.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import torch

from ..errors import InputError
from ..io.keypoints import KeypointSet
from .branches import JOINT_HYPOTHESES, LIMB_SEGMENTS, TORSO_SEGMENT

__all__ = [
    "GuardDecision",
    "body_stature",
    "branch_gap",
    "depth_warnings",
    "check_frames",
    "check_keypoints",
    "fit_summary",
    "EARLY_SEARCH_MARGIN",
    "EARLY_SEARCH_MIN_SHIFT_MM",
    "SEARCH_MIN_SHIFT_MM",
    "fit_warnings",
    "guard_fit",
    "hypothesis_summary",
    "mask_warnings",
    "moves_a_joint",
    "person_extent",
    "reprojection_rise_warnings",
    "shape_warnings",
    "silhouette_guard",
]


#: Keypoints farther than this many image widths/heights outside the image are dropped.
OUTSIDE_MARGIN = 1.0
#: The confident keypoints must span at least this many pixels (the longer side of their box).
MIN_PERSON_PX = 16.0
#: Shoulder/neck centre to hip centre must be at least this share of the person's extent.
MIN_TORSO_FRACTION = 0.05
#: Final silhouette IoU below this is reported.
MIN_IOU = 0.5
#: A final IoU this much below the keypoint stage's is reported.
IOU_DROP = 0.1
#: Plausible camera-to-body distances, metres.
DEPTH_RANGE_M = (0.3, 100.0)
#: Median reprojection error above this share of the person's extent is reported.
MAX_REPROJECTION_FRACTION = 0.15

#: A silhouette stage whose median reprojection error is this many times the keypoint stage's ...
MAX_REPROJECTION_RISE = 2.0
#: ... and at least this many pixels more is reported (it traded the keypoints for the mask).
MIN_REPROJECTION_RISE_PX = 3.0
#: A mask covering at least this share of an image side runs out of the image there.
MIN_BORDER_RUN = 0.02
#: :func:`depth_warnings`: a branch refined to the end (``branches.refine``, ``--hypotheses K``) within this
#: relative final energy of the fit ...
HYPOTHESIS_MARGIN = 0.1
#: ... that moves some joint at least this far from the fit (mm, its ``max_shift_mm``) ...
MIN_SHIFT_MM = 400.0
#: ... or a survivor of an earlier branch search (one whose rows did not go on to the end) within this
#: relative energy of its kept one ...
EARLY_SEARCH_MARGIN = 0.05
#: ... moving a joint this far from the fit: the refined branches all come from the last search, so a
#: basin the first search weighed and dropped shows only there. With the search from the fit
#: (``branches.post_iters``) the late search is an earlier one too, and its ``kept`` is the branch that *settled*
#: lowest: a late row the search ranked below it, or within the margin, counts (the search and the converged
#: energies disagree). Why these defaults (this and ``EARLY_SEARCH_MARGIN``): docs/benchmarks/defaults.md
EARLY_SEARCH_MIN_SHIFT_MM = 500.0
#: ... and where no branch was refined to the end (``branches.refine`` 1: a video's per-frame start), a
#: branch-search survivor within this relative energy of the kept one (its search stage's energies,
#: 20-30 steps in) ...
SEARCH_MARGIN = 0.1
#: ... whose joints at its search's end lie at least this far from the fit's (mm: the branch, and
#: how far the fit moved after that search; why this default: docs/benchmarks/defaults.md)
SEARCH_MIN_SHIFT_MM = 400.0
#: Shape coefficients beyond this many standard deviations are reported.
MAX_ABS_BETA = 3.0

#: The silhouette guard keeps the keypoint fit when the refined fit's reprojection error is
#: above this many times the keypoint fit's ...
GUARD_REPROJECTION_RISE = 1.5
#: ... and at least this many pixels more (a rise within the keypoints' own noise is no sign).
GUARD_MIN_RISE_PX = 1.0
#: Plausible standing heights (metres) of an adult body in the shape space.
STATURE_RANGE_M = (1.2, 2.1)

_UPPER = ("neck", "left_shoulder", "right_shoulder")
_LOWER = ("mid_hip", "left_hip", "right_hip")


def person_extent(keypoints: KeypointSet) -> float:
    """The longer side (pixels) of the box around the keypoints with confidence > 0."""
    vis = keypoints.xy[keypoints.conf > 0]
    return float((vis.max(0) - vis.min(0)).max()) if len(vis) else 0.0


def _centre(keypoints: KeypointSet, names: Sequence[str]) -> Optional[np.ndarray]:
    idx = [keypoints.names.index(n) for n in names if n in keypoints.names]
    idx = [i for i in idx if keypoints.conf[i] > 0]
    return keypoints.xy[idx].mean(0) if idx else None


def check_keypoints(keypoints: KeypointSet, image_size: Optional[tuple] = None) -> tuple[KeypointSet, list]:
    """``(keypoints, warnings)``: far-outside points dropped (see the module docstring),
    degenerate sets refused with :class:`~silfit.errors.InputError`. ``image_size`` is
    ``(W, H)``; without it the outside check is skipped."""
    source = keypoints.source
    warnings = []
    xy, conf = keypoints.xy.copy(), keypoints.conf.copy()
    if image_size is not None:
        w, h = float(image_size[0]), float(image_size[1])
        outside = (
            (xy[:, 0] < -OUTSIDE_MARGIN * w)
            | (xy[:, 0] > (1 + OUTSIDE_MARGIN) * w)
            | (xy[:, 1] < -OUTSIDE_MARGIN * h)
            | (xy[:, 1] > (1 + OUTSIDE_MARGIN) * h)
        ) & (conf > 0)
        if not (conf[~outside] > 0).any():
            raise InputError(source, f"every keypoint lies far outside the {w:.0f}x{h:.0f} image: no person to fit")
        if outside.any():
            names = ", ".join(keypoints.names[i] for i in np.flatnonzero(outside))
            warnings.append(
                f"{source}: keypoint(s) {names} lie more than {OUTSIDE_MARGIN:g} image size(s) outside "
                f"the {w:.0f}x{h:.0f} image; treated as missing"
            )
            xy[outside], conf[outside] = 0.0, 0.0
            keypoints = KeypointSet(xy, conf, keypoints.layout, source=source)
    extent = person_extent(keypoints)
    if extent < MIN_PERSON_PX:
        raise InputError(
            source,
            f"the keypoints span only {extent:.1f} px (all at nearly one place?); silfit needs a person at "
            f"least {MIN_PERSON_PX:g} px tall",
        )
    upper, lower = _centre(keypoints, _UPPER), _centre(keypoints, _LOWER)
    if upper is not None and lower is not None:
        torso = float(np.linalg.norm(upper - lower))
        if torso < MIN_TORSO_FRACTION * extent:
            raise InputError(
                source,
                f"the torso (shoulders/neck to hips) is {torso:.1f} px long, under {MIN_TORSO_FRACTION:.0%} "
                f"of the person's {extent:.0f} px: degenerate keypoints",
            )
    return keypoints, warnings


def check_frames(
    frames: Sequence[Optional[KeypointSet]], image_size: Optional[tuple] = None, numbers: Optional[Sequence[int]] = None
) -> tuple[list, list]:
    """:func:`check_keypoints` for each frame of a video: far-outside points dropped, and a
    frame whose keypoints would be refused becomes a frame without a detection (``None``: the
    sequence fit bridges it from its neighbours). Returns ``(frames, warnings)``, one warning
    per kind of finding with the frame numbers (``numbers``, default the indices)."""
    numbers = list(range(len(frames))) if numbers is None else list(numbers)
    out, dropped, refused = [], [], []
    for n, ks in zip(numbers, frames):
        if ks is None:
            out.append(None)
            continue
        try:
            ks, notes = check_keypoints(ks, image_size)
        except InputError as err:
            refused.append((n, str(err)))
            out.append(None)
            continue
        if notes:
            dropped.append(n)
        out.append(ks)
    if not any(ks is not None for ks in out) and refused:
        raise InputError(
            refused[0][1].partition(": ")[0],
            f"no frame has usable keypoints; frame {refused[0][0]}: {refused[0][1].partition(': ')[2]}",
        )
    warnings = []
    if dropped:
        warnings.append(
            f"frame(s) {_frame_list(dropped)}: keypoint(s) more than {OUTSIDE_MARGIN:g} image size(s) outside "
            "the image treated as missing"
        )
    if refused:
        warnings.append(
            f"frame(s) {_frame_list([n for n, _ in refused])}: unusable keypoints, fitted as frames without "
            f"a detection (first: {refused[0][1]})"
        )
    return out, warnings


def _frame_list(numbers: Sequence[int], limit: int = 10) -> str:
    return ", ".join(map(str, numbers[:limit])) + (f" ... ({len(numbers)} in all)" if len(numbers) > limit else "")


def fit_warnings(metrics: dict, keypoints: KeypointSet, vertices: np.ndarray, betas=None) -> list:
    """Warnings for an implausible fit, from its ``metrics`` (``iou``,
    ``iou_keypoint_stage``, ``reprojection_error_px``, ``reprojection_error_px_keypoint_stage``),
    the keypoints it was fitted to, the final ``vertices [V, 3]`` (camera coordinates, metres)
    and, when given, its shape ``betas``."""
    warnings = []
    iou, iou_kp = metrics.get("iou"), metrics.get("iou_keypoint_stage")
    if iou is not None:
        if iou < MIN_IOU:
            warnings.append(
                f"final silhouette IoU is only {iou:.3f}: the mask and the body disagree "
                "(a wrong, noisy or partial mask?)"
            )
        if iou_kp is not None and iou < iou_kp - IOU_DROP:
            warnings.append(f"final silhouette IoU {iou:.3f} is far below the keypoint fit's {iou_kp:.3f}")
    z = np.asarray(vertices, dtype=np.float64)[:, 2]
    depth = float(np.median(z))
    if not np.isfinite(z).all():
        warnings.append("the fitted body has non-finite vertices")
    elif (z <= 0).any():
        warnings.append(f"part of the fitted body lies behind the camera (nearest vertex at z = {z.min():.2f} m)")
    elif not DEPTH_RANGE_M[0] <= depth <= DEPTH_RANGE_M[1]:
        warnings.append(
            f"the fitted body is {depth:.2f} m from the camera, outside the plausible "
            f"{DEPTH_RANGE_M[0]:g}-{DEPTH_RANGE_M[1]:g} m (wrong focal length or keypoint scale?)"
        )
    err, extent = metrics.get("reprojection_error_px"), person_extent(keypoints)
    if err is not None and extent > 0 and not err <= MAX_REPROJECTION_FRACTION * extent:
        warnings.append(
            f"median reprojection error {err:.1f} px is {err / extent:.0%} of the person's {extent:.0f} px "
            "extent: the body does not match the keypoints"
        )
    return (
        warnings
        + reprojection_rise_warnings(metrics.get("reprojection_error_px_keypoint_stage"), err)
        + shape_warnings(betas)
    )


def reprojection_rise_warnings(before: Optional[float], after: Optional[float]) -> list:
    """A warning when the silhouette stage's median reprojection error ``after`` is above
    :data:`MAX_REPROJECTION_RISE` times the keypoint stage's ``before`` and
    :data:`MIN_REPROJECTION_RISE_PX` more (none when either is missing)."""
    if (
        before is None
        or after is None
        or not (after > MAX_REPROJECTION_RISE * before and after > before + MIN_REPROJECTION_RISE_PX)
    ):
        return []
    return [
        f"the silhouette stage moved the body away from the keypoints (median reprojection error {before:.1f} -> "
        f"{after:.1f} px): the mask may hold clothing, objects or other people, or the person is cut off by the image "
        "border; compare with stages/keypoints"
    ]


def mask_warnings(mask: np.ndarray, source: str = "mask") -> list:
    """A warning when the person's mask runs along the image border (at least
    :data:`MIN_BORDER_RUN` of a side): the person is cut off there; the silhouette stage treats
    what lies beyond as unknown (:mod:`silfit.silhouette.losses`), so that part of the body rests
    on the keypoints and priors only."""
    m = np.asarray(mask, dtype=bool)
    sides = {"top": m[0], "bottom": m[-1], "left": m[:, 0], "right": m[:, -1]}
    cut = [name for name, row in sides.items() if row.mean() >= MIN_BORDER_RUN]
    if not cut:
        return []
    return [
        f"{source}: the person runs out of the image at the {' and '.join(cut)} edge(s) (cut off): the body beyond "
        "the border is fitted from the keypoints and priors alone; check the side view"
    ]


def branch_gap(search) -> Optional[float]:
    """The relative energy gap ``(E_other - E_kept) / E_kept`` between the hypothesis the
    branch search kept and the best other one, smallest over its stages (``search``: a
    :attr:`~silfit.fitting.KeypointFitResult.branch_search` entry; ``None`` when no other
    hypothesis ran to the end). Negative where a search's kept row is the one that settled lowest
    after it (``settled``), not its own lowest."""
    gaps = []
    for stage in search or []:
        if stage.get("refined"):  # the refined branches' final energies: not a search's
            continue
        tried = stage["tried"]
        kept = next(t["energy"] for t in tried if t["flip"] == stage["kept"])
        others = [t["energy"] for t in tried if t["flip"] != stage["kept"]]
        if others:
            gaps.append((min(others) - kept) / max(abs(kept), 1e-12))
    return min(gaps) if gaps else None


def hypothesis_summary(hypotheses) -> list:
    """``metrics.json``'s record of :attr:`~silfit.fitting.KeypointFitResult.hypotheses` (one
    sample's): rank (``hypotheses/<rank>/``), the branch it started from, its energy, its gap to the
    best (relative), the segments it turns away from the best, how far its joints lie from the best's
    (``shift_mm``: mean, ``max_shift_mm``: the largest) and whether it was refined to the end (an
    unrefined one, ``refined: False``, is a branch-search survivor: its energy and gap are its search
    stage's, named in ``stage``; or, ``stage`` ``settle``, a late-search row that settled higher than the pick:
    its energy at the final weights and its gap to the fit's)."""
    if not hypotheses:
        return []
    e0 = hypotheses[0]["energy"]
    out = []
    for k, h in enumerate(hypotheses, 1):
        refined = h.get("refined", True)
        row = {
            "rank": k,
            "label": h["label"],
            "energy": float(h["energy"]),
            "gap": float((h["energy"] - e0) / max(abs(e0), 1e-12) if refined else h["gap"]),
            "differs": list(h["differs"]),
            "refined": bool(refined),
        }
        row.update({key: float(h[key]) for key in ("shift_mm", "max_shift_mm") if key in h})
        if not refined:
            row["stage"] = h.get("stage")
        out.append(row)
    return out


def moves_a_joint(alternative, min_shift_mm: float = MIN_SHIFT_MM) -> bool:
    """Whether an alternative (a hypothesis or a branch-search ``tried`` entry) moves some joint at
    least ``min_shift_mm`` from the fit (its ``max_shift_mm``; one without it, recorded before joint
    shifts were, counts as moving)."""
    shift = alternative.get("max_shift_mm")
    return shift is None or float(shift) >= min_shift_mm


def label_segments(label: str) -> list:
    """The limb and torso segments a hypothesis' label flips (``keep``: none; a root turn, ``yaw`` or
    ``turn+30``, is named ``facing``; ``/turn`` says how a hinge segment was flipped)."""
    joint = dict(JOINT_HYPOTHESES)
    if label in joint:
        return [seg for part in joint[label] for seg in part]
    known = {s[0] for s in LIMB_SEGMENTS + (TORSO_SEGMENT,)} | {"hip"}
    facing = ["facing"] if label.startswith(("yaw", "turn")) else []
    return facing + [seg.split("/")[0] for seg in label.split("+") if seg.split("/")[0] in known]


@dataclass
class _CloseAlternatives:
    """The close alternatives :func:`depth_warnings` found, in order: per alternative, the segments it turns
    (``close``), where it is named (``where``), its largest joint shift (mm or ``None``) and the margin it is
    within (``used``)."""

    close: list = field(default_factory=list)
    where: list = field(default_factory=list)
    shifts: list = field(default_factory=list)
    used: list = field(default_factory=list)

    def add(self, segments: list, where: str, shift, margin: float) -> None:
        """One more close alternative."""
        self.close.append(segments)
        self.where.append(where)
        self.shifts.append(shift)
        self.used.append(margin)

    def without(self, decided: Sequence[str]) -> "_CloseAlternatives":
        """The alternatives that turn something besides the ``decided`` segments, those not named."""
        keep = [k for k, c in enumerate(self.close) if not c or any(s not in decided for s in c)]
        return _CloseAlternatives(
            [[s for s in self.close[k] if s not in decided] for k in keep],
            [self.where[k] for k in keep],
            [self.shifts[k] for k in keep],
            [self.used[k] for k in keep],
        )


def _refined_hypotheses(refined: list, hypotheses) -> list:
    """Every branch refined to choose the fit (the last refined entry's ``tried``) as a hypothesis, named by its
    ``hypotheses/k`` folder where it is among ``hypotheses``."""
    rank = {h["label"]: k for k, h in enumerate(hypotheses or [], 1) if h.get("refined", True)}
    return [
        {
            "label": t["flip"],
            "energy": t["energy"],
            "differs": t.get("differs"),
            "max_shift_mm": t.get("max_shift_mm"),
            "where": f"hypotheses/{rank[t['flip']]}" if t["flip"] in rank else f"refined branch: {t['flip']}",
        }
        for t in refined[-1]["tried"]
    ]


def _add_close_hypotheses(found: _CloseAlternatives, hyps: list, margin: float, min_shift_mm: float) -> None:
    """The hypotheses after the first within ``margin`` of its energy that move a joint ``min_shift_mm``."""
    e0 = hyps[0]["energy"] if hyps else 0.0
    for k, h in enumerate(hyps[1:], 2):
        if h["energy"] - e0 <= margin * abs(e0) and moves_a_joint(h, min_shift_mm):
            found.add(
                list(h.get("differs") or []) or label_segments(h["label"]) or label_segments(hyps[0]["label"]),
                h.get("where", f"hypotheses/{k}"),
                h.get("max_shift_mm"),
                margin,
            )


def _add_close_survivors(found: _CloseAlternatives, searches: list, margin: float, min_shift_mm: float) -> None:
    """The branch searches' survivors within ``margin`` of their search's kept row that move a joint
    ``min_shift_mm``."""
    for stage in searches:
        kept = next(t["energy"] for t in stage["tried"] if t["flip"] == stage["kept"])
        for t in stage["tried"]:
            if (
                t["flip"] != stage["kept"]
                and t["energy"] - kept <= margin * abs(kept)
                and moves_a_joint(t, min_shift_mm)
            ):
                found.add(
                    label_segments(t["flip"]) or label_segments(stage["kept"]),
                    f"branch search: {t['flip']}",
                    t.get("max_shift_mm"),
                    margin,
                )


def _depth_message(found: _CloseAlternatives, written: bool) -> list:
    """The one warning naming the segments the close alternatives turn (``written``: ``--hypotheses K`` given)."""
    segs = sorted({s for c in found.close for s in c}) or ["a limb"]
    moved = [float(m) for m in found.shifts if m is not None]
    by = f", moving a joint up to {max(moved) / 1000:.2f} m" if moved else ""
    where = list(dict.fromkeys(found.where))  # each alternative named once (several searches can keep the same one)
    return [
        f"depth ambiguous for {', '.join(segs)}: an alternative fit within {max(found.used):.0%} of the energy turns "
        f"{'it' if len(segs) == 1 else 'them'} the other way{by} ({', '.join(where)}); the keypoints cannot tell "
        "which: check a side view" + ("" if written else " (silfit fit --hypotheses 3 writes the alternatives)")
    ]


def depth_warnings(
    search,
    hypotheses=None,
    margin: float = HYPOTHESIS_MARGIN,
    search_margin: float = SEARCH_MARGIN,
    min_shift_mm: float = MIN_SHIFT_MM,
    search_min_shift_mm: float = SEARCH_MIN_SHIFT_MM,
    early_margin: float = EARLY_SEARCH_MARGIN,
    early_min_shift_mm: float = EARLY_SEARCH_MIN_SHIFT_MM,
    decided: Sequence[str] = (),
) -> list:
    """One warning naming the limbs whose depth neither the keypoints nor the image decide, or none
    (``decided``: the segments the image depth cue decided, :mod:`silfit.fitting.image_depth`: an alternative
    that turns only those is not close, and they are not named).

    An alternative is *close* when it lies within a relative energy margin of the fit and moves some
    joint far from it (:func:`moves_a_joint`):

    - a branch refined to the end within ``margin`` of the fit's final energy, moving a joint
      ``min_shift_mm``: the ``"refined"`` entry of ``search`` (the sample's
      :attr:`~silfit.fitting.KeypointFitResult.branch_search`: every branch refined to choose the fit, by
      its final energy; one also among ``hypotheses`` is named by its ``hypotheses/k`` folder), or, in
      results without that entry, ``hypotheses`` (one sample's
      :attr:`~silfit.fitting.KeypointFitResult.hypotheses`, ``--hypotheses K``) where two or more were refined;
    - with refined branches, also a survivor of an earlier search (not the last, whose best rows were
      refined) within ``early_margin`` of its kept row by that search's energies, moving a joint
      ``early_min_shift_mm``;
    - where no branch was refined (``branches.refine`` 1, results recorded before it), a survivor of any
      search within ``search_margin`` of its kept row, moving a joint ``search_min_shift_mm``.

    The limbs named are the segments the close alternatives turn away from the fit (``differs``), or
    those their label flips (the kept one's, for an unflipped alternative). Measured on the generated
    hard set (``benchmarks/bench_ambiguity.py``: fits above 150 mm warned, fits below 60 mm warned)."""
    found = _CloseAlternatives()
    hyps = [h for h in hypotheses or [] if h.get("refined", True)]
    searches = [s for s in search or [] if not s.get("refined")]
    refined = [s for s in search or [] if s.get("refined")]
    if refined:  # every branch refined to choose the fit (hypotheses keeps only K of them): named by its folder
        hyps = _refined_hypotheses(refined, hypotheses)
    if len(hyps) > 1 or refined:
        _add_close_hypotheses(found, hyps, margin, min_shift_mm)
        # the last search's best went on to the end; the earlier ones' survivors by their own rule
        searches, search_margin, search_min_shift_mm = searches[:-1], early_margin, early_min_shift_mm
    _add_close_survivors(found, searches, search_margin, search_min_shift_mm)
    if decided:  # the image decides these segments: an alternative turning nothing else is no ambiguity
        found = found.without(decided)
    if not found.close:
        return []
    return _depth_message(found, hypotheses is not None)  # --hypotheses K: the alternatives among its K are written


def shape_warnings(betas) -> list:
    """A warning for shape coefficients beyond :data:`MAX_ABS_BETA` (none for ``None``)."""
    b = np.abs(np.asarray([] if betas is None else betas, dtype=np.float64)).reshape(-1)
    if not b.size or b.max() <= MAX_ABS_BETA:
        return []
    return [
        f"implausible body shape: |betas| up to {b.max():.1f} (beyond {MAX_ABS_BETA:g} standard deviations of the "
        "shape space)"
    ]


@dataclass(frozen=True)
class GuardDecision:
    """What :func:`silhouette_guard` decided: ``keep`` is ``"silhouette"`` (the refined fit)
    or ``"keypoints"`` (the fit the stage started from); ``reasons`` say why the refined fit is
    less plausible (empty when kept); ``warnings`` are for ``metrics.json`` and the console."""

    keep: str
    reasons: tuple = ()
    warnings: tuple = ()

    @property
    def reverted(self) -> bool:
        return self.keep == "keypoints"


def body_stature(model, betas) -> float:
    """Standing height (metres) of the body with shape ``betas`` in the rest pose: the
    vertical extent of the shaped template (no pose, so no fitting is involved)."""
    b = torch.as_tensor(np.asarray(betas, dtype=np.float64).reshape(1, -1), dtype=model.v_template.dtype)
    dirs = model.shapedirs[..., : b.shape[1]]
    v = model.v_template + torch.einsum("bl,vcl->bvc", b, dirs)[0]
    y = v[:, 1].detach().cpu().numpy()
    return float(y.max() - y.min())


def fit_summary(reprojection_px, betas, stature_m) -> dict:
    """The numbers :func:`silhouette_guard` compares, of one fit."""
    b = np.abs(np.asarray([] if betas is None else betas, dtype=np.float64)).reshape(-1)
    return {
        "reprojection_px": None if reprojection_px is None else float(reprojection_px),
        "max_abs_beta": float(b.max()) if b.size else 0.0,
        "stature_m": None if stature_m is None else float(stature_m),
    }


def _implausible(s: dict) -> dict:
    """{reason: text} of one fit summary's own implausibilities (shape and stature)."""
    out = {}
    if s["max_abs_beta"] > MAX_ABS_BETA:
        out["betas"] = f"|betas| up to {s['max_abs_beta']:.1f} (beyond {MAX_ABS_BETA:g})"
    h = s.get("stature_m")
    if h is not None and not STATURE_RANGE_M[0] <= h <= STATURE_RANGE_M[1]:
        out["stature"] = f"stature {h:.2f} m (outside {STATURE_RANGE_M[0]:g}-{STATURE_RANGE_M[1]:g} m)"
    return out


def guard_fit(model, before_px, before_betas, after_px, after_betas, where: str = "") -> GuardDecision:
    """:func:`silhouette_guard` of a refined fit against the keypoint fit it started from, given their
    median reprojection errors and shapes (statures from ``model``'s shape space, :func:`body_stature`;
    ``None`` for a model without one of that form): the one call images, rigs and videos make."""

    def stature(betas):
        if betas is None:
            return None
        try:
            return body_stature(model, betas)
        except (AttributeError, KeyError, RuntimeError):
            return None

    return silhouette_guard(
        fit_summary(before_px, before_betas, stature(before_betas)),
        fit_summary(after_px, after_betas, stature(after_betas)),
        where,
    )


def silhouette_guard(keypoint_fit: dict, refined: dict, where: str = "") -> GuardDecision:
    """Keep the silhouette stage's ``refined`` fit unless it is less plausible than the
    ``keypoint_fit`` it started from (both :func:`fit_summary` dicts): its median reprojection
    error above :data:`GUARD_REPROJECTION_RISE` times the keypoint fit's (and
    :data:`GUARD_MIN_RISE_PX` more), |betas| beyond :data:`MAX_ABS_BETA` or a stature outside
    :data:`STATURE_RANGE_M` where the keypoint fit had none of these. ``where`` names the
    image, frame or view in the warning. A refined fit that is implausible in the same way as
    the keypoint fit is kept (the keypoint fit is no better), with no warning here."""
    reasons = []
    before, after = keypoint_fit.get("reprojection_px"), refined.get("reprojection_px")
    if (
        before is not None
        and after is not None
        and np.isfinite(before)
        and (
            not np.isfinite(after) or (after > GUARD_REPROJECTION_RISE * before and after > before + GUARD_MIN_RISE_PX)
        )
    ):
        reasons.append(f"reprojection error {before:.1f} -> {after:.1f} px")
    old = _implausible(keypoint_fit)
    reasons += [text for key, text in _implausible(refined).items() if key not in old]
    if not reasons:
        return GuardDecision("silhouette")
    at = f"{where}: " if where else ""
    warning = (
        f"{at}the silhouette stage made the fit less plausible ({'; '.join(reasons)}): kept the keypoint fit "
        "instead (the mask may hold clothing, objects or other people, or the person is cut off)"
    )
    return GuardDecision("keypoints", tuple(reasons), (warning,))
