"""Depth order from the image (issue 54): the BlazePose GHUM landmark model's learned 3D landmarks
(:attr:`silfit.detect.Person.world`, metres, hip-centred, z away from the camera) as per-segment
evidence of which end of a limb segment is nearer the camera, the one thing 2D keypoints cannot tell.

:func:`depth_cue` turns one landmark set into a :class:`DepthCue`: per limb segment of
:data:`~silfit.fitting.branches.LIMB_SEGMENTS` a sign (+1: the distal joint lies farther from the
camera than the proximal one, -1: nearer) and a confidence in [0, 1]. Scale-free: a segment's call is
its depth cosine ``dz / |v|`` in the landmark model's 3D (its metric lengths are not reliable), and the
confidence is the smaller visibility of its two ends times a ramp of that cosine, 0 for a near-flat call
(below ``off_below``: where the model's own errors lie) and 1 from ``full_at``. A set whose 2D disagrees
with the keypoints being fitted is refused whole when its left and right fit the keypoints better
swapped (a mirrored reading), and a segment whose ends lie far from their keypoints is off.

:class:`ImageDepthTerm` (the energy term ``image_depth``) reads the cue per problem
(``data["image_depth"] [P, F, S]``: sign times confidence) and charges each decided segment whose
depth cosine in the fit (along the camera's optical axis, as the landmark model's z) is not at least
``margin`` on the cue's side: ``sum_s c_s * relu(margin - sign_s * cos_s)^2``. Nothing for a fit already on the cue's side,
so it ranks the branch search's hypotheses (their energies) and holds the final stage on the image's
branch; 0 (not evaluated against any data) for a problem without an image.

Pure functions of arrays, except the term (torch).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import List, Optional, Sequence

import numpy as np
import torch

from ..detect import DetectConfig, DetectionError, detect_people
from ..detect.geometry import ROI
from .branches import LIMB_SEGMENTS, LIMBS, depth_ratios, flip_segment
from .problem import world_to_camera
from .terms import Evaluation, Term

__all__ = [
    "DepthCue",
    "ImageDepthConfig",
    "ImageDepthTerm",
    "SEGMENTS",
    "cue_data",
    "cue_from_image",
    "cue_disagrees",
    "cue_hypotheses",
    "demote_disagreeing",
    "hard_calls",
    "depth_cue",
    "landmark_agreement",
    "match_person",
    "matched_person",
    "person_cue",
]

#: the limb segments the cue speaks for: (segment, proximal joint, distal joint), SMPL and BlazePose names alike
SEGMENTS = LIMB_SEGMENTS
_PAIRS = (
    ("left_shoulder", "right_shoulder"),
    ("left_elbow", "right_elbow"),
    ("left_wrist", "right_wrist"),
    ("left_hip", "right_hip"),
    ("left_knee", "right_knee"),
    ("left_ankle", "right_ankle"),
)
_LIMB_POINTS = tuple(n for pair in _PAIRS for n in pair)


@dataclass(frozen=True)
class ImageDepthConfig:
    """The cue's gates (defaults measured on generated renders: ``benchmarks/bench_image_depth.py``)."""

    #: a segment's depth cosine in the landmark model's 3D below this: a near-flat call, off
    off_below: float = 0.4
    #: ... and from this on full confidence (a linear ramp between)
    full_at: float = 0.6
    #: a landmark end below this visibility switches its segment off (above: confidence times visibility)
    min_visibility: float = 0.5
    #: a segment whose end lies farther than this (share of the keypoints' extent) from its keypoint is off
    max_disagreement: float = 0.05
    #: the whole set is refused when its left/right pairs fit the keypoints swapped better than this share
    #: of their direct distance (a mirrored reading of the person)
    swap_ratio: float = 0.7
    #: read the person twice, in the image and in its mirror image (:func:`mirrored_person`), and keep only the
    #: calls both readings make (:func:`agreed_cue`): the landmark model's confident errors are rarely repeated
    mirror: bool = False


@dataclass
class DepthCue:
    """Per segment of :data:`SEGMENTS`: ``sign`` (+1 distal farther, -1 nearer, 0 off), ``confidence``
    [0, 1] and the landmark model's depth cosine ``ratio``; ``refused``: why the whole set was refused."""

    sign: np.ndarray
    confidence: np.ndarray
    ratio: np.ndarray
    refused: Optional[str] = None
    notes: List[str] = field(default_factory=list)

    @property
    def names(self) -> tuple:
        return tuple(s[0] for s in SEGMENTS)

    def weights(self) -> np.ndarray:
        """``[S]`` sign times confidence (the term's data)."""
        return self.sign * self.confidence

    def decided(self) -> List[str]:
        return [n for n, w in zip(self.names, self.weights()) if w != 0]

    def hard_signs(self, threshold: float) -> np.ndarray:
        """``[S]`` the cue's sign on the segments it calls (its gates passed) with a depth cosine of at least
        ``threshold``, 0 elsewhere: the calls the branch search takes as decided (``image_depth.decide``)."""
        return np.where((self.confidence > 0) & (np.abs(self.ratio) >= threshold), self.sign, 0.0)

    def hard_record(self, threshold: float) -> dict:
        """``metrics.json``'s ``image_depth`` ``branch_choice``: the segments whose side :meth:`hard_signs` decides."""
        signs = self.hard_signs(threshold)
        return {
            "threshold": float(threshold),
            "segments": {n: "farther" if s > 0 else "nearer" for n, s in zip(self.names, signs) if s},
        }

    def to_dict(self) -> dict:
        """``metrics.json``'s ``image_depth``: the decided segments with their call and confidence."""
        out = {
            "decided": {
                n: {
                    "distal": "farther" if s > 0 else "nearer",
                    "confidence": round(float(c), 3),
                    "depth_cosine": round(float(r), 3),
                }
                for n, s, c, r in zip(self.names, self.sign, self.confidence, self.ratio)
                if s and c
            },
            "undecided": [n for n in self.names if n not in self.decided()],
        }
        if self.refused:
            out["refused"] = self.refused
        if self.notes:
            out["notes"] = list(self.notes)
        return out


def _off(reason: str) -> DepthCue:
    S = len(SEGMENTS)
    return DepthCue(np.zeros(S), np.zeros(S), np.zeros(S), refused=reason)


def landmark_agreement(landmarks_xy: np.ndarray, landmark_names: Sequence[str], keypoints) -> tuple:
    """``(direct [n], swapped, direct_sum, extent)``: each limb landmark's 2D distance to its keypoint
    (``keypoints``: a :class:`~silfit.io.keypoints.KeypointSet`; ``nan`` where the keypoint has no confidence),
    in shares of the keypoints' extent, for :data:`_LIMB_POINTS`; and over the left/right pairs both sides
    of which are seen, the summed distances read swapped and direct."""
    names = list(keypoints.names)
    conf = np.asarray(keypoints.conf, np.float64)
    vis = keypoints.xy[conf > 0]
    extent = float((vis.max(0) - vis.min(0)).max()) if len(vis) >= 2 else 1.0
    extent = max(extent, 1.0)
    lm = {n: np.asarray(landmarks_xy[list(landmark_names).index(n)], np.float64) for n in _LIMB_POINTS}
    kp = {n: keypoints.xy[names.index(n)] for n in _LIMB_POINTS if n in names and conf[names.index(n)] > 0}
    direct = np.array([np.linalg.norm(lm[n] - kp[n]) / extent if n in kp else np.nan for n in _LIMB_POINTS])
    d_sum = s_sum = 0.0
    for a, b in _PAIRS:
        if a in kp and b in kp:
            d_sum += np.linalg.norm(lm[a] - kp[a]) + np.linalg.norm(lm[b] - kp[b])
            s_sum += np.linalg.norm(lm[a] - kp[b]) + np.linalg.norm(lm[b] - kp[a])
    return direct, s_sum / extent, d_sum / extent, extent


def depth_cue(
    world: np.ndarray,
    visibility: np.ndarray,
    landmark_names: Sequence[str],
    xy: Optional[np.ndarray] = None,
    keypoints=None,
    config: Optional[ImageDepthConfig] = None,
) -> DepthCue:
    """The per-segment depth evidence of one landmark set (module docstring): ``world [L, 3]`` (z away from
    the camera), ``visibility [L]`` in [0, 1], ``landmark_names`` naming the ``L`` landmarks; with ``xy [L, 2]``
    and ``keypoints`` (the set being fitted) the 2D agreement gates (a mirrored set refused, a segment whose
    end is far from its keypoint off)."""
    cfg = config or ImageDepthConfig()
    names = list(landmark_names)
    world = np.asarray(world, np.float64)
    vis = np.asarray(visibility, np.float64)
    if not np.isfinite(world).all():
        return _off("the landmark model's 3D holds non-finite values")
    far = set()
    notes = []
    if keypoints is not None and xy is not None:
        direct, swapped, d_sum, _ = landmark_agreement(np.asarray(xy, np.float64), names, keypoints)
        if d_sum > 0 and swapped < cfg.swap_ratio * d_sum:
            return _off(
                f"the landmarks' left and right fit the keypoints better swapped ({swapped:.2f} against "
                f"{d_sum:.2f} keypoint extents): a mirrored reading"
            )
        far = {n for n, d in zip(_LIMB_POINTS, direct) if not np.isfinite(d) or d > cfg.max_disagreement}
        if far:
            notes.append(f"landmarks far from (or without) their keypoints: {', '.join(sorted(far))}")
    S = len(SEGMENTS)
    sign, conf, ratio = np.zeros(S), np.zeros(S), np.zeros(S)
    for s, (_, p, d) in enumerate(SEGMENTS):
        v = world[names.index(d)] - world[names.index(p)]
        r = float(v[2] / max(np.linalg.norm(v), 1e-9))
        ratio[s] = r
        v_min = min(vis[names.index(p)], vis[names.index(d)])
        if p in far or d in far or v_min < cfg.min_visibility or abs(r) < cfg.off_below:
            continue
        ramp = min(1.0, (abs(r) - cfg.off_below) / max(cfg.full_at - cfg.off_below, 1e-9))
        sign[s], conf[s] = np.sign(r), ramp * v_min
    return DepthCue(sign, conf, ratio, notes=notes)


def person_cue(person, keypoints=None, config: Optional[ImageDepthConfig] = None) -> DepthCue:
    """:func:`depth_cue` of a detected :class:`~silfit.detect.Person` (landmarks outside the image count as
    not visible)."""
    vis = np.where(person.in_image(), person.visibility, 0.0)
    return depth_cue(person.world, vis, person.names, person.xy, keypoints, config)


def match_person(people: Sequence, keypoints) -> Optional[int]:
    """The index of the detected person whose limb landmarks lie nearest the keypoints (median, in shares of the
    keypoints' extent; read swapped where that is nearer, so a mirrored reading is still found and then refused
    by :func:`depth_cue`); ``None`` when none lies within a tenth of the extent."""
    best, best_err = None, 0.1
    for i, p in enumerate(people):
        direct, swapped, d_sum, _ = landmark_agreement(p.xy, p.names, keypoints)
        err = float(np.nanmedian(direct)) if np.isfinite(direct).any() else np.inf
        if d_sum > 0:
            err = min(err, err * swapped / d_sum)
        if err < best_err:
            best, best_err = i, err
    return best


def cue_from_image(image: np.ndarray, keypoints, person=None, config: Optional[ImageDepthConfig] = None) -> tuple:
    """``(cue or None, record)`` for fitting ``keypoints`` on ``image`` (uint8 RGB): ``person`` (the detection the
    keypoints came from) or else the landmark model run on the image and the person whose limb landmarks lie
    nearest the keypoints (:func:`match_person`; the most confident first, then everyone found); ``record`` is
    ``metrics.json``'s ``image_depth`` (:meth:`DepthCue.to_dict`, or why there is no cue)."""
    if person is None:
        person, why = matched_person(image, keypoints)
        if person is None:
            return None, {"refused": why}
    cue = person_cue(person, keypoints, config)
    if config is not None and config.mirror and not cue.refused:
        other = mirrored_person(image, keypoints)
        cue = agreed_cue(cue, None if other is None else person_cue(other, keypoints, config))
    return (None if cue.refused else cue), cue.to_dict()


def _other_side(name: str) -> str:
    """``left_x`` <-> ``right_x`` (other names unchanged)."""
    if name.startswith("left"):
        return "right" + name[4:]
    return "left" + name[5:] if name.startswith("right") else name


def _mirrored_roi(roi, width: int):
    """A region of the flipped image in the image (``x -> width - 1 - x``: its centre's x, its angle negated)."""
    return ROI(width - 1 - roi.cx, roi.cy, roi.size, -roi.angle)


def unmirror_person(person):
    """A person detected in the horizontally flipped image, read back in the image: ``x -> W - 1 - x`` (pixel
    centres on integers), left and right landmarks swapped, the 3D's x negated (its z, the depth, unchanged), the
    regions mirrored too (their centres' x, their angles negated)."""
    names = list(person.names)
    swap = [names.index(_other_side(n)) for n in names]
    W = person.image_size[0]
    xy = person.xy[swap].copy()
    xy[:, 0] = W - 1 - xy[:, 0]
    world = person.world[swap].copy()
    world[:, 0] = -world[:, 0]
    return replace(
        person,
        xy=xy,
        z=person.z[swap],
        visibility=person.visibility[swap],
        presence=person.presence[swap],
        world=world,
        mask_prob=person.mask_prob[:, ::-1],
        detector_roi=_mirrored_roi(person.detector_roi, W),
        roi=_mirrored_roi(person.roi, W),
    )


def matched_person(image: np.ndarray, keypoints, mirror: bool = False) -> tuple:
    """``(person, None)``: the landmark model run on ``image`` and the person whose limb landmarks lie nearest the
    keypoints (:func:`match_person`; the most confident person first, the landmark model's cost once, then
    everyone found), or ``(None, why)``. With ``mirror``, the model reads the horizontally flipped image and its
    people are read back (:func:`unmirror_person`) before matching."""
    seen = np.ascontiguousarray(np.asarray(image)[:, ::-1]) if mirror else image
    for most in (1, 0):
        try:
            people = detect_people(seen, DetectConfig(max_people=most))
        except DetectionError as err:
            return None, f"no landmarks: {err}"
        if mirror:
            people = [unmirror_person(p) for p in people]
        i = match_person(people, keypoints)
        if i is not None:
            return people[i], None
    return None, "no person the landmark model found lies on the keypoints"


def mirrored_person(image: np.ndarray, keypoints) -> Optional[object]:
    """The landmark model's second reading of the person on ``keypoints``: run on the horizontally flipped image,
    read back and matched to the keypoints (:func:`matched_person`); ``None`` where none matches. The model is not
    equivariant to the flip, so the two readings' errors are partly independent."""
    return matched_person(image, keypoints, mirror=True)[0]


def agreed_cue(a: DepthCue, b: Optional[DepthCue]) -> DepthCue:
    """The calls two readings agree on (the same sign, both on): per segment the smaller confidence and the
    flatter depth cosine; a segment either reading leaves off or that they call differently is off."""
    if b is None or b.refused:
        return DepthCue(np.zeros_like(a.sign), np.zeros_like(a.confidence), a.ratio, a.refused, list(a.notes))
    same = (a.sign == b.sign) & (a.sign != 0) & (a.confidence > 0) & (b.confidence > 0)
    ratio = np.where(np.abs(a.ratio) <= np.abs(b.ratio), a.ratio, b.ratio)
    conf = np.where(same, np.minimum(a.confidence, b.confidence), 0.0)
    return DepthCue(np.where(same, a.sign, 0.0), conf, ratio, a.refused, list(a.notes))


def cue_data(cues: Sequence[Optional[DepthCue]], frames: int = 1) -> Optional[np.ndarray]:
    """``[P, F, S]`` the term's data for problems with cues (``None``: no image, zeros), or ``None`` when no
    problem has one (the data key then stays absent and the fit is unchanged)."""
    if all(c is None for c in cues):
        return None
    S = len(SEGMENTS)
    w = np.stack([np.zeros(S) if c is None else c.weights() for c in cues])
    return np.repeat(w[:, None, :], frames, axis=1)


def hard_calls(cues: Optional[Sequence[Optional[DepthCue]]], threshold: Optional[float]) -> Optional[np.ndarray]:
    """``[P, S]`` per problem the cue's decided sides (:meth:`DepthCue.hard_signs`; zeros without a cue), or ``None``
    where ``threshold`` is ``None`` or no cue decides a segment (the branch search is then as without a cue)."""
    if threshold is None or cues is None or all(c is None for c in cues):
        return None
    S = len(SEGMENTS)
    calls = np.stack([np.zeros(S) if c is None else c.hard_signs(float(threshold)) for c in cues])
    return calls if calls.any() else None


def cue_disagrees(joints: np.ndarray, R: np.ndarray, t: np.ndarray, calls: np.ndarray, joint_names) -> np.ndarray:
    """``[rows, S]`` whether each row's pose (``joints [rows, J, 3]``, seen by a camera ``R [rows, 3, 3]``,
    ``t [rows, 3]``) turns a segment the other way than its decided side ``calls [rows, S]`` (+1 the distal joint
    farther, -1 nearer, 0 undecided: never disagrees)."""
    names = list(joint_names)
    p = [names.index(a) for _, a, _ in SEGMENTS]
    d = [names.index(b) for _, _, b in SEGMENTS]
    cam = np.einsum("rij,rkj->rki", R, joints) + t[:, None, :]
    dz = cam[:, d, 2] - cam[:, p, 2]
    return calls * dz < 0


def demote_disagreeing(score: torch.Tensor, group: torch.Tensor, groups: int, disagree: torch.Tensor) -> torch.Tensor:
    """``score [rows]`` with each sample's rows that ``disagree`` (with the image cue's decided sides) lifted above
    every finite score of its rows (their order among themselves kept), where the sample has a finite row that
    agrees; a sample none of whose rows agrees keeps its scores (the energy chooses). Ranked by
    :func:`~silfit.fitting.keypoint_stage.best_per_group`, the rows that agree come first."""
    out = score.clone()
    finite = torch.isfinite(score)
    for g in range(groups):
        mine = (group == g) & finite
        if not (mine & ~disagree).any() or not (mine & disagree).any():
            continue
        low, high = score[mine].min(), score[mine].max()
        lift = 2.0 * (float(high - low) + max(abs(float(low)), 1.0))  # past the highest, beyond best_per_group's steps
        out[mine & disagree] = score[mine & disagree] + lift
    return out


def cue_hypotheses(body, rows: dict, calls: np.ndarray, names, parents, camera: tuple, opts: dict) -> list:
    """Hypotheses ``(row, label, body_pose)``: each row whose pose turns a decided segment (``calls [rows, S]``,
    :func:`hard_calls`; seen by ``camera``, ``(R [rows, 3, 3], t [rows, 3])``) the other way, with each such segment
    mirrored to the cue's side in turn (:func:`~silfit.fitting.branches.flip_segment`, upper segments first, each
    checked after the flips before it), labelled ``image:<segment>+...``; not where the flips are a single segment or
    a whole limb that :func:`~silfit.fitting.branches.limb_hypotheses` proposes already (a search's options ``opts``:
    ``min_depth_ratio``, ``whole_limbs``, ``hinge``)."""
    rows = dict(rows)
    ratios = depth_ratios(body, rows, names)
    flipped = [[] for _ in range(len(calls))]
    for s, (seg, _, _) in enumerate(SEGMENTS):
        with torch.no_grad():
            joints = body(**rows).joints.double().numpy()
        dis = cue_disagrees(joints, camera[0], camera[1], calls, names)[:, s]
        if not dis.any():
            continue
        pose = flip_segment(body, rows, seg, names, parents, opts.get("hinge", True))
        rows["body_pose"] = torch.where(torch.as_tensor(dis)[:, None], pose, rows["body_pose"])
        for r in np.nonzero(dis)[0].tolist():
            flipped[r].append(seg)
    low = opts.get("min_depth_ratio", 0.3)
    proposed = {(r, (n,)) for n, _, _ in SEGMENTS for r in np.nonzero(ratios[n] >= low)[0].tolist()}
    if opts.get("whole_limbs", True):
        proposed |= {
            (r, limb) for limb in LIMBS for r in np.nonzero(np.maximum(*(ratios[n] for n in limb)) >= low)[0].tolist()
        }
    return [
        (r, "image:" + "+".join(segs), rows["body_pose"][r])
        for r, segs in enumerate(flipped)
        if segs and (r, tuple(segs)) not in proposed
    ]


class ImageDepthTerm(Term):
    """The ``image_depth`` energy term (module docstring): ``sum_s c_s * relu(margin - sign_s * cos_s)^2`` over the
    decided segments, ``cos_s`` the fit's depth cosine of segment ``s`` (``dz / |v|`` in each view's camera); 0 for problems without ``data["image_depth"]``."""

    name = "image_depth"

    def __init__(self, joint_names: Sequence[str], margin: float = 0.1):
        names = list(joint_names)
        self.proximal = [names.index(p) for _, p, _ in SEGMENTS]
        self.distal = [names.index(d) for _, _, d in SEGMENTS]
        self.margin = float(margin)

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        w = ev.data.get("image_depth")
        if w is None:
            return ev.keypoints_2d.new_zeros(ev.P)
        J = ev.body.joints
        joints = J.reshape(ev.P, ev.F, 1, *J.shape[1:]).expand(ev.P, ev.F, ev.C, *J.shape[1:])
        cam = world_to_camera(joints, ev.views["R"].to(J.dtype), ev.views["t"].to(J.dtype))
        v = cam[..., self.distal, :] - cam[..., self.proximal, :]
        cos = v[..., 2] / v.norm(dim=-1).clamp_min(1e-9)  # [P, F, C, S]: along the optical axis, as the cue's
        w = w.to(J.dtype)[:, :, None, :]
        e = w.abs() * torch.relu(self.margin - torch.sign(w) * cos).square()
        return e.reshape(ev.P, -1).sum(1)
