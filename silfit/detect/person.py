"""People in a photo: the BlazePose person detector, then the landmark model on each
person's rotated region, twice (the second region comes from the first pass's
landmarks), with landmarks and the person mask mapped back to image pixels.

Steps, as MediaPipe's pose graphs run them:

1. the whole image, letterboxed into the detector's 224 x 224 input (values in [-1, 1]);
   SSD decoding (:mod:`.anchors`), score >= ``min_score``, weighted NMS (:mod:`.nms`); with
   several people wanted also overlapping tiles (:func:`detector_regions`: the detector,
   made for one dominant person, misses people small in the whole image), whose detections
   overlapping none of the whole image's are added;
2. per detection, the region from its hip centre and full-body scale point (side: twice
   their distance, times 1.25; rotated so the body is upright in the crop);
3. the landmark model on that region (if it sees no pose there, on a wider one:
   ``retry_scales``), then on the region its own auxiliary hip-centre and scale
   landmarks give (``passes``), keeping the last pass that saw a pose;
4. each person in turn, up to ``max_people``, the most confident first (detector score
   times pose presence); a second reading of a person already found (masks overlapping
   by IoU > 0.5, or lying mostly inside one person's or all kept people's masks:
   ``max_contained``) is dropped, and so is a further reading whose mask spreads far beyond
   its own landmarks (:func:`mask_in_box`: background clutter).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np

from ..errors import InputError
from ..io.keypoints import KeypointSet
from ..silhouette.people import own_mask
from .anchors import DETECTOR_INPUT, decode_detections
from .geometry import ROI, roi_from_alignment_points, warp_to_crop
from .landmarks import NUM_LANDMARKS, ROI_SCALE, mask_in_image, roi_from_landmarks, run_landmark_model
from .layout import BLAZEPOSE33_NAMES, LOWER_BODY, blazepose_to_layout
from .models import load_model
from .nms import box_iou, weighted_nms

__all__ = [
    "DetectConfig",
    "DetectionError",
    "Person",
    "detect_people",
    "detect_candidates",
    "detector_regions",
    "mask_in_box",
]


class DetectionError(InputError):
    """No usable person in the image (the message says why)."""


@dataclass(frozen=True)
class DetectConfig:
    #: detector score threshold (MediaPipe's min_detection_confidence). Lower finds more
    #: people seen from behind or very close (on 32 renders: 0.5 missed 5, 0.3 missed 2) but
    #: lets non-people through: at 0.3 the scikit-image logo (a snake) passes as a person,
    #: with pose presence 1.0, so the landmark model's check does not catch it
    min_score: float = 0.5
    nms_iou: float = 0.3
    min_presence: float = 0.5  # landmark model's pose presence (min_tracking_confidence)
    passes: int = 2  # landmark passes per person
    #: wider first regions tried (as multiples of the detector's scale-point radius) when
    #: the landmark model sees no pose in the standard one (unusual poses, e.g. bent over)
    retry_scales: tuple = (1.6,)
    refine_heatmap: bool = True
    #: people wanted (0: all found)
    max_people: int = 1
    #: with more than one person wanted, the detector also runs on overlapping square tiles of
    #: these sides (fractions of the image's longer side; three tiles per side length), so people
    #: small in the letterboxed whole image are found; ``()``: the whole image only
    tiles: tuple = (0.4, 0.6, 0.8)
    #: a reading whose mask lies this much (share of its own area) inside a person already
    #: kept is the same person (a part of them: legs, a second region)
    max_contained: float = 0.6
    #: a further person's mask must lie this much inside their landmarks' box (:func:`mask_in_box`)
    min_mask_in_box: float = 0.7
    #: a person whose landmarks span fewer pixels (longest side of their box) is too small
    min_person_px: float = 40.0
    #: confidence below which a landmark counts as not visible
    visible_threshold: float = 0.5
    #: confidence of landmarks the model extrapolates outside the image: 0 drops them,
    #: except the hips, which keep this much so that a fit of a truncated torso can proceed
    outside_hip_conf: float = 0.2


@dataclass
class Person:
    """One detected person; coordinates in image pixels (pixel centres on integers)."""

    score: float  # detector score
    presence_score: float  # landmark model's pose presence on the final region
    detector_roi: ROI
    roi: ROI
    xy: np.ndarray  # [33, 2]
    z: np.ndarray  # [33]
    visibility: np.ndarray  # [33]
    presence: np.ndarray  # [33]
    world: np.ndarray  # [33, 3]
    mask_prob: np.ndarray  # [H, W] float32
    image_size: tuple  # (W, H)
    config: DetectConfig = field(default_factory=DetectConfig, repr=False)

    @property
    def names(self) -> tuple:
        return BLAZEPOSE33_NAMES

    def in_image(self) -> np.ndarray:
        W, H = self.image_size
        x, y = self.xy[:, 0], self.xy[:, 1]
        return (x >= -0.5) & (x <= W - 0.5) & (y >= -0.5) & (y <= H - 0.5)

    def confidence(self) -> np.ndarray:
        """Per-landmark confidence for fitting ``[33]``: the model's visibility where the
        landmark lies in the image (floored at 0.1: an occluded landmark the model still
        places is weak evidence, not none), 0 outside it except the hips (see
        :attr:`DetectConfig.outside_hip_conf`)."""
        inside = self.in_image()
        conf = np.where(inside, np.maximum(self.visibility, 0.1), 0.0)
        for name in ("left_hip", "right_hip"):
            i = BLAZEPOSE33_NAMES.index(name)
            if not inside[i]:
                conf[i] = self.config.outside_hip_conf
        return conf

    def keypoints(self, layout: str = "body25") -> np.ndarray:
        """``[K, 3]`` (x, y, confidence) in ``layout`` (``body25`` or ``coco17``)."""
        return blazepose_to_layout(self.xy, self.confidence(), layout)

    def keypoint_set(self, layout: str = "body25", source: str = "<detected>"):
        kp = self.keypoints(layout)
        return KeypointSet(kp[:, :2], kp[:, 2], layout, source=source)

    def mask(self, threshold: float = 0.5) -> np.ndarray:
        """The person mask ``bool [H, W]``."""
        return self.mask_prob > threshold

    def own_mask(
        self, others: Sequence["Person"], radius: float = 0.06, keep: float = 0.04, threshold: float = 0.5
    ) -> np.ndarray:
        """The person mask less the other people's regions (:func:`silfit.silhouette.people.own_mask`, issue 55):
        each of ``others``' mask and the neighbourhood of their landmarks (``radius`` of their extent) where
        nearer their skeleton than this person's, except within ``keep`` of this person's extent of their own
        skeleton."""
        own = (self.xy, self.confidence(), BLAZEPOSE33_NAMES)
        rest = [
            (p.mask(threshold), p.xy, p.confidence(), BLAZEPOSE33_NAMES, float(radius) * p.extent_px())
            for p in others
            if p is not self
        ]
        return own_mask(self.mask(threshold), own, rest, keep=float(keep) * self.extent_px())

    def extent_px(self) -> float:
        """Longest side of the box of the landmarks inside the image."""
        pts = self.xy[self.in_image() & (self.visibility > 0.1)]
        return float((pts.max(0) - pts.min(0)).max()) if len(pts) >= 2 else 0.0

    def box(self) -> np.ndarray:
        """``[4]`` x_min, y_min, x_max, y_max of all 33 landmarks."""
        return np.concatenate([self.xy.min(0), self.xy.max(0)])

    def not_visible(self) -> List[str]:
        """Landmarks outside the image or below the visibility threshold."""
        vis = self.in_image() & (self.visibility >= self.config.visible_threshold)
        return [n for n, v in zip(BLAZEPOSE33_NAMES, vis) if not v]

    def lower_body_visible(self) -> bool:
        hidden = set(self.not_visible())
        return not all(n in hidden for n in LOWER_BODY)

    def cut_off_edges(self) -> List[str]:
        """Image edges that landmarks lie beyond (the person is cut off there)."""
        W, H = self.image_size
        x, y = self.xy[:, 0], self.xy[:, 1]
        edges = {"left": x < -0.5, "right": x > W - 0.5, "top": y < -0.5, "bottom": y > H - 0.5}
        return [e for e, m in edges.items() if m.any()]

    def warnings(self) -> List[str]:
        out = []
        edges = self.cut_off_edges()
        if edges:
            outside = [n for n, i in zip(BLAZEPOSE33_NAMES, self.in_image()) if not i]
            out.append(
                f"person cut off at the image's {' and '.join(edges)} edge: {', '.join(outside)} outside the image"
            )
        if not self.lower_body_visible():
            out.append(
                "lower body not visible (knees, ankles and feet outside the image or occluded): "
                "the fit follows the visible part only"
            )
        return out

    def to_dict(self) -> dict:
        """A JSON-ready summary (landmarks with visibility/presence, regions, warnings)."""
        conf = self.confidence()
        return {
            "score": round(float(self.score), 4),
            "presence": round(float(self.presence_score), 4),
            "detector_roi": self.detector_roi.to_dict(),
            "roi": self.roi.to_dict(),
            "extent_px": round(self.extent_px(), 1),
            "mask_area_px": int(self.mask().sum()),
            "landmarks": {
                name: {
                    "x": round(float(self.xy[i, 0]), 2),
                    "y": round(float(self.xy[i, 1]), 2),
                    "z": round(float(self.z[i]), 2),
                    "visibility": round(float(self.visibility[i]), 4),
                    "presence": round(float(self.presence[i]), 4),
                    "confidence": round(float(conf[i]), 4),
                }
                for i, name in enumerate(BLAZEPOSE33_NAMES)
            },
            "not_visible": self.not_visible(),
            "lower_body_visible": self.lower_body_visible(),
            "warnings": self.warnings(),
        }


def _as_rgb(image: np.ndarray, source: str) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"{source}: expected an RGB image [H, W, 3], got shape {img.shape}")
    img = img[..., :3]
    if img.dtype != np.uint8:
        if np.issubdtype(img.dtype, np.floating):
            img = (np.clip(img, 0.0, 1.0) * 255.0).round()
        img = img.astype(np.uint8)
    return np.ascontiguousarray(img)


def detector_regions(width: int, height: int, tiles: tuple = ()) -> List[ROI]:
    """The square regions the person detector runs on: the letterboxed whole image, then per
    tile side (a fraction of the longer side) a grid of tiles a third of a side apart, reaching
    a quarter of a side beyond the image along its longer axis (people at the edges)."""
    W, H = int(width), int(height)
    regions = [ROI((W - 1) / 2.0, (H - 1) / 2.0, float(max(W, H)), 0.0)]
    for frac in tiles:
        side = float(frac) * max(W, H)
        step = side / 3.0

        def centres(extent):
            if extent <= side:
                return [(extent - 1) / 2.0]
            reach = side / 4.0 if extent == max(W, H) else 0.0
            return list(np.arange(side / 2 - reach, extent - side / 2 + reach + 1e-6, step))

        regions += [ROI(float(cx), float(cy), side, 0.0) for cx in centres(W) for cy in centres(H)]
    return regions


def detect_candidates(image: np.ndarray, config: Optional[DetectConfig] = None):
    """The person detector alone: ``(scores [M], keypoints [M, 4, 2])`` in image pixels after
    weighted NMS, best first (keypoints: hip centre, full-body scale point, shoulder
    centre, upper-body scale point). With more than one person wanted (``max_people`` other
    than 1) the detector also runs on tiles (:func:`detector_regions`): the whole image's
    detections come first, exactly as without tiles, then the tiles' (merged by their own
    weighted NMS, in image pixels) that overlap none of them."""
    cfg = config or DetectConfig()
    H, W = image.shape[:2]
    regions = detector_regions(W, H, cfg.tiles if cfg.max_people != 1 else ())
    found = [_detect_in(image, roi, cfg) for roi in regions]
    scores, boxes, kps = weighted_nms(*found[0], cfg.min_score, cfg.nms_iou)  # the whole image: as without tiles
    if len(found) > 1:  # tiles add the people the whole image's detections do not overlap
        ts, tb, tk = weighted_nms(*(np.concatenate(x) for x in zip(*found[1:])), cfg.min_score, cfg.nms_iou)
        new = [i for i in range(len(ts)) if not len(boxes) or box_iou(tb[i], boxes).max() <= cfg.nms_iou]
        scores, kps = np.concatenate([scores, ts[new]]), np.concatenate([kps.reshape(-1, *tk.shape[1:]), tk[new]])
    return scores, kps


def _detect_in(image: np.ndarray, roi: ROI, cfg: DetectConfig):
    """The detector on one square region: ``(scores, boxes [M, 4], keypoints [M, 4, 2])`` at
    or above ``min_score``, in image pixels (before NMS)."""
    tensor = warp_to_crop(image, roi, DETECTOR_INPUT).astype(np.float32) / 127.5 - 1.0
    outputs = load_model("pose_detection")(tensor[None])
    boxes_raw, scores_raw = sorted(outputs, key=lambda t: t.shape[-1], reverse=True)
    scores, boxes, kps = decode_detections(boxes_raw, scores_raw)
    keep = scores >= cfg.min_score
    scores, boxes, kps = scores[keep], boxes[keep], kps[keep]
    return (
        scores,
        roi.crop_to_image(boxes.reshape(-1, 2)).reshape(-1, 4),  # axis-aligned regions: corners map
        roi.crop_to_image(kps.reshape(-1, 2)).reshape(kps.shape),
    )


def _person_from_detection(img: np.ndarray, score: float, kp: np.ndarray, cfg: DetectConfig) -> Optional[Person]:
    """The landmark passes on one detection; ``None`` when the landmark model sees no pose."""
    H, W = img.shape[:2]
    for scale in (ROI_SCALE,) + tuple(cfg.retry_scales):
        det_roi = roi_from_alignment_points(kp[0], kp[1], scale)
        lm = run_landmark_model(img, det_roi, refine=cfg.refine_heatmap)
        if lm.presence_score >= cfg.min_presence:
            break
    else:
        return None
    for _ in range(max(1, cfg.passes) - 1):
        again = run_landmark_model(img, roi_from_landmarks(lm), refine=cfg.refine_heatmap)
        if again.presence_score < cfg.min_presence:
            break
        lm = again
    n = NUM_LANDMARKS
    return Person(
        score=score,
        presence_score=lm.presence_score,
        detector_roi=det_roi,
        roi=lm.roi,
        xy=lm.xy[:n],
        z=lm.z[:n],
        visibility=lm.visibility[:n],
        presence=lm.presence[:n],
        world=lm.world,
        mask_prob=mask_in_image(lm, W, H),
        image_size=(W, H),
        config=cfg,
    )


def _same_person(a: Person, b: Person, min_iou: float = 0.5, max_contained: float = 1.0) -> bool:
    """``a`` is a second reading of ``b``: masks overlapping by IoU above ``min_iou``, or ``a``'s
    mask lying inside ``b``'s by more than ``max_contained`` of its area."""
    ma, mb = a.mask(), b.mask()
    union = np.logical_or(ma, mb).sum()
    inter = np.logical_and(ma, mb).sum()
    return bool(union) and (inter / union > min_iou or inter / max(ma.sum(), 1) > max_contained)


def mask_in_box(person: Person, grow: float = 0.2) -> float:
    """The share of ``person``'s mask inside the box of their landmarks (clipped to the image,
    grown by ``grow`` of its size on each side): near 1 for a real person; low for a reading
    of background clutter (a blurred crowd), whose mask spreads far from its landmarks."""
    m = person.mask()
    W, H = person.image_size
    lo, hi = person.xy.min(0), person.xy.max(0)
    pad = grow * (hi - lo)
    x0, y0 = np.clip(np.floor(lo - pad), 0, [W, H]).astype(int)
    x1, y1 = np.clip(np.ceil(hi + pad) + 1, 0, [W, H]).astype(int)
    return float(m[y0:y1, x0:x1].sum() / max(m.sum(), 1))


def _inside_union(person: Person, people: List[Person]) -> float:
    """The share of ``person``'s mask that lies inside the masks of ``people``."""
    m = person.mask()
    union = np.logical_or.reduce([p.mask() for p in people])
    return float(np.logical_and(m, union).sum() / max(m.sum(), 1))


def detect_people(image: np.ndarray, config: Optional[DetectConfig] = None, source: str = "<image>") -> List[Person]:
    """Every person found (up to ``config.max_people``), the most confident first
    (detector score times the landmark model's pose presence).

    Raises :class:`DetectionError` when nobody is found or everyone found is smaller
    than ``config.min_person_px``.
    """
    cfg = config or DetectConfig()
    img = _as_rgb(image, source)
    H, W = img.shape[:2]
    scores, kps = detect_candidates(img, cfg)
    if not len(scores):
        raise DetectionError(f"{source}: no person found (no detection scored >= {cfg.min_score})")
    # Each candidate in turn (a few more than asked for: one person can give two
    # detections, e.g. upright and upside down, that NMS keeps apart).
    candidates: List[Person] = []
    for score, kp in list(zip(scores, kps))[: 2 * max(cfg.max_people, 1) + 1 if cfg.max_people else None]:
        person = _person_from_detection(img, float(score), kp, cfg)
        if person is not None:
            candidates.append(person)
    # The same person twice (masks overlapping): keep the more confident reading.
    candidates.sort(key=lambda p: -p.score * p.presence_score)
    people: List[Person] = []
    too_small = []
    for person in candidates:
        if any(_same_person(person, p, max_contained=cfg.max_contained) for p in people):
            continue
        if people and _inside_union(person, people) > cfg.max_contained:  # a reading spanning people already kept
            continue
        if people and mask_in_box(person) < cfg.min_mask_in_box:  # a further reading whose mask is not its body's
            continue
        if person.extent_px() < cfg.min_person_px:
            too_small.append(person.extent_px())
            continue
        people.append(person)
        if cfg.max_people and len(people) >= cfg.max_people:
            break
    if not people:
        if too_small:
            raise DetectionError(
                f"{source}: person too small: the largest found spans {max(too_small):.0f} px, "
                f"need at least {cfg.min_person_px:.0f}"
            )
        raise DetectionError(
            f"{source}: no person found (the landmark model saw no pose in {len(scores)} detection(s))"
        )
    return people
