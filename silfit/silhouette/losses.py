"""Silhouette losses: distance transforms of the target mask (computed once, no gradient)
and a two-sided energy whose gradient flows through the rendered silhouette only.

``E(S) = [ sum(S * DT_out) + sum((1 - S) * DT_in) ] / area(mask)``

* ``DT_out``: for pixels outside the mask, Euclidean distance (pixels) to the mask;
  penalises rendered body where the person is not.
* ``DT_in``: for pixels inside the mask, distance to the background; penalises mask
  pixels the body does not cover, most strongly deep inside the person.

Both are exact Euclidean transforms from OpenCV (``DIST_MASK_PRECISE``, without IPP: the same
mask gives the same distances whatever its buffer's address); ``E = 0`` when the rendered
silhouette equals the mask.

**Truncation.** Where a target has a ``valid`` map (the pixels inside the image; a silhouette
window may reach beyond the image's border), what lies outside the image is unknown, not
background: ``DT_out`` is 0 there (a body that continues beyond the border costs nothing for
the part outside), ``DT_in`` measures the distance to the *visible* background only (the
border where the mask is cut is not the body's edge), the outline points of the cover term
leave out the cut (:func:`contour_points` with ``valid``), and the IoU counts the image's
pixels only.

**Masks are supersets of bodies** (clothing, hair, hats, held objects, segmentation leaks), so
the two sides are not symmetric. "Body outside the mask" keeps the full distance ``DT_out``;
"mask not covered" weighs each uncovered pixel by a robust, capped profile of ``DT_in``
(:class:`CoverProfile`, :func:`cover_weights`): a shallow slope ``inner`` within ``margin`` of the
mask's edge (a band as thick as loose clothing costs little, so it widens nothing by more than
the body's shape prior allows), the full slope beyond, and at most ``cap`` per pixel (a large
leak pulls no harder than a moderate one). The energy stays linear in the rendered silhouette,
so the renderer's exact-edge gradients are untouched; only the per-pixel weights change. The
contour level's cover term has the same profile on its outline points' distances
(:func:`cover_energy`); beyond the cap a point has no gradient, so an outline far from any body
part (a thin leak, an object) is ignored.

**Leaks and holes.** A mask pixel far from the body fitted to the keypoints (beyond a distance
from its silhouette: an object or background joined to the person) and a small hole in the mask
(a segmentation gap inside the person, not the real gap between limbs, which is larger or open
to the background) are *unknown*, like the pixels beyond the image (:func:`unknown_regions`,
:class:`~silfit.fitting.problem.Observation` ``known``): no pull to cover them, no cost for a body
over them.

The contour surrogate (no rendering; the silhouette stage's coarse level) compares points
instead of pixels, in the same pixel units:

* :func:`outside_distance_energy`: projected body vertices against ``DT_out`` (bilinear):
  every vertex of a body that matches the mask projects inside it;
* :func:`cover_energy`: the mask's contour points (:func:`contour_points`) against the
  nearest projected vertex: every part of the mask's outline has body next to it.

Both are means of squared pixel distances (smooth at zero, so a quasi-Newton method can
use them); neither needs the body's own outline, so no visibility is computed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree

from ..body.lbs import sqrt

__all__ = [
    "CoverProfile",
    "MaskTarget",
    "clothing_thickness",
    "trim_clothing",
    "unknown_regions",
    "concave_region",
    "contour_points",
    "cover_energy",
    "cover_weights",
    "distance_transforms",
    "outside_distance_energy",
    "silhouette_energy",
    "soft_iou",
]


def distance_transforms(mask: np.ndarray, valid=None) -> tuple[np.ndarray, np.ndarray]:
    """``(DT_out, DT_in)`` float32 ``[H, W]`` of a boolean mask (see the module docstring);
    ``valid`` (bool ``[H, W]``, default everywhere): the pixels that were seen (the image)."""
    mask = np.asarray(mask, dtype=bool)
    unseen = np.zeros_like(mask) if valid is None else ~np.asarray(valid, dtype=bool)
    # OpenCV's IPP path of the precise transform rounds by the input buffer's address (1-2 ulp:
    # the same mask gave other distances, and fits other results, from one process to the next);
    # its own implementation does not. The switch is per thread (OpenCV keeps it thread-local).
    use_ipp = cv2.ipp.useIPP()
    cv2.ipp.setUseIPP(False)
    try:
        outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        inside = cv2.distanceTransform((mask | unseen).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    finally:
        cv2.ipp.setUseIPP(use_ipp)
    outside[unseen] = 0.0  # unknown: a body there costs nothing
    inside[~mask] = 0.0
    return outside.astype(np.float32), inside.astype(np.float32)


@dataclass(frozen=True)
class CoverProfile:
    """The "mask not covered" side's robust profile, in pixels of the target's grid: an
    uncovered mask pixel at distance ``d`` from the mask's edge costs ``inner * d`` up to
    ``margin``, then ``inner * margin + (d - margin)``, at most ``cap``, all times ``weight``.
    ``CoverProfile()`` (``margin=0, inner=1, cap=inf, weight=1``) is the plain two-sided energy."""

    margin: float = 0.0
    inner: float = 1.0
    cap: float = float("inf")
    #: the whole side's weight against "body outside the mask" (issue 55: the body must lie inside the mask,
    #: strongly, but need not fill it where the mask may be clothing or hair: weakly); 1: as strong
    weight: float = 1.0

    def __post_init__(self):
        if not (self.margin >= 0 and 0 <= self.inner <= 1 and self.cap > 0 and 0 < self.weight <= 1):
            raise ValueError(f"CoverProfile: need margin >= 0, 0 <= inner <= 1, cap > 0, 0 < weight <= 1; got {self}")

    @property
    def plain(self) -> bool:
        return self.margin == 0 and self.inner == 1 and math.isinf(self.cap) and self.weight == 1

    def __call__(self, d):
        """The profile at distances ``d`` (numpy array or torch tensor, >= 0)."""
        lib = torch if isinstance(d, torch.Tensor) else np
        m, a = float(self.margin), float(self.inner)
        v = a * lib.clip(d, 0, m) + lib.clip(d - m, 0, None) if m > 0 else a * d
        v = lib.clip(v, None, float(self.cap)) if not math.isinf(self.cap) else v
        return v * float(self.weight) if self.weight != 1 else v


def cover_weights(dt_in: np.ndarray, profile: Optional[CoverProfile] = None) -> np.ndarray:
    """Per-pixel weight of an uncovered mask pixel: ``profile(DT_in)`` (``DT_in`` itself for
    ``None`` or the plain profile); 0 outside the mask."""
    if profile is None or profile.plain:
        return dt_in
    return np.where(dt_in > 0, profile(dt_in), 0.0).astype(np.float32)


@dataclass
class MaskTarget:
    """A target mask with its distance transforms, as tensors."""

    mask: torch.Tensor  # [H, W] float (0/1)
    dt_out: torch.Tensor  # [H, W]
    dt_in: torch.Tensor  # [H, W]
    area: float
    #: [H, W] float (0/1): the pixels inside the image (``None``: all of them)
    valid: Optional[torch.Tensor] = None
    #: [H, W]: the weight of an uncovered mask pixel (:func:`cover_weights`; ``None``: ``dt_in``)
    w_in: Optional[torch.Tensor] = None
    #: the robust profile of the "mask not covered" side (``None``: plain), pixels of this grid
    cover: Optional[CoverProfile] = None

    @classmethod
    def from_mask(
        cls, mask: np.ndarray, device=None, dtype=torch.float32, valid=None, cover: Optional[CoverProfile] = None
    ) -> "MaskTarget":
        """``valid``: bool ``[H, W]``, the pixels inside the image (module docstring: truncation);
        ``cover``: the robust profile of the mask-not-covered side (module docstring)."""
        dt_out, dt_in = distance_transforms(mask, valid)
        as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
        seen = None if valid is None else as_t(np.asarray(valid, dtype=np.float32))
        plain = cover is None or cover.plain
        w_in = None if plain else as_t(cover_weights(dt_in, cover))
        return cls(
            as_t(np.asarray(mask, dtype=np.float32)),
            as_t(dt_out),
            as_t(dt_in),
            float(np.count_nonzero(mask)),
            seen,
            w_in,
            None if plain else cover,
        )


def silhouette_energy(silhouette: torch.Tensor, target: MaskTarget) -> torch.Tensor:
    """Distance-transform energy of ``silhouette [..., H, W]`` in [0, 1] against ``target``:
    body outside the mask weighed by ``DT_out``, mask not covered by ``target.w_in`` (the robust
    profile of ``DT_in``, or ``DT_in`` itself), normalised by the mask's area; one value per
    leading batch element."""
    over = (silhouette * target.dt_out).sum(dim=(-2, -1))
    w_in = target.dt_in if target.w_in is None else target.w_in
    under = ((1.0 - silhouette) * w_in).sum(dim=(-2, -1))
    return (over + under) / max(target.area, 1.0)


def soft_iou(silhouette: torch.Tensor, mask: torch.Tensor, valid: Optional[torch.Tensor] = None) -> torch.Tensor:
    """IoU of a soft silhouette with a 0/1 mask: ``sum(min) / sum(max)``, over the ``valid``
    pixels only when given (the image's: what lies beyond it is unknown)."""
    if valid is not None:
        silhouette = silhouette * valid
    inter = torch.minimum(silhouette, mask).sum(dim=(-2, -1))
    union = torch.maximum(silhouette, mask).sum(dim=(-2, -1))
    return inter / union.clamp(min=1e-9)


def contour_points(mask: np.ndarray, count: int, valid=None) -> np.ndarray:
    """Up to ``count`` points ``[B, 2]`` (x, y pixel centres, float64) spread evenly along the
    outlines of a boolean mask (outer outlines and holes, OpenCV's contour order; the
    same mask gives the same points). With ``valid`` (bool ``[H, W]``: the image's pixels)
    the outline where the mask is cut by the image's border is left out: it is not the body's."""
    if int(count) <= 0:
        raise ValueError(f"contour point count must be positive, got {count}")
    m = np.asarray(mask, dtype=bool)
    seen = None if valid is None else np.asarray(valid, dtype=bool)
    if seen is not None:
        m = m | ~seen  # the unseen region joins the mask: no outline along the cut
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(np.int64)
    if seen is not None:  # keep outline points in the image whose 3x3 neighbourhood is all seen
        near = cv2.erode(seen.astype(np.uint8), np.ones((3, 3), np.uint8), borderValue=0).astype(bool)
        pts = pts[near[pts[:, 1], pts[:, 0]]]
    pts = pts.astype(np.float64)
    if len(pts) > count:
        pts = pts[np.linspace(0, len(pts) - 1, int(count)).round().astype(np.int64)]
    return pts


def _bilinear(image: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """``image [H, W]`` at points ``uv [N, 2]`` (x, y on pixel centres), bilinear; points
    outside the image take the border's value plus their distance to the image."""
    H, W = image.shape
    x = uv[:, 0].clamp(0, W - 1)
    y = uv[:, 1].clamp(0, H - 1)
    beyond = (uv[:, 0] - x).abs() + (uv[:, 1] - y).abs()
    x0 = x.detach().floor().clamp(max=W - 2).long() if W > 1 else torch.zeros_like(x, dtype=torch.long)
    y0 = y.detach().floor().clamp(max=H - 2).long() if H > 1 else torch.zeros_like(y, dtype=torch.long)
    fx, fy = x - x0.to(x.dtype), y - y0.to(y.dtype)
    x1, y1 = (x0 + 1).clamp(max=W - 1), (y0 + 1).clamp(max=H - 1)
    img = image.to(uv.dtype)
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy + beyond


def outside_distance_energy(uv: torch.Tensor, dt_out: torch.Tensor) -> torch.Tensor:
    """Mean squared distance (pixels) from the projected points ``uv [N, 2]`` to the mask
    whose outside distance transform is ``dt_out [H, W]`` (0 inside the mask)."""
    return _bilinear(dt_out, uv).square().mean()


#: the cover term's nearest points by a k-d tree in float64 (:func:`_nearest`); ``False``: the smallest
#: ``|u|^2 - 2 p.u`` from one float32 product over all pairs, as before issue 24's sampling part (kept for
#: ``benchmarks/bench_silhouette.py``'s ``dense`` method)
NEAREST_BY_TREE = True


def _nearest(u: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
    """Index ``[B]`` of the point of ``u [N, 2]`` nearest each of ``pts [B, 2]``: a k-d tree in float64
    (exact distances, so the same choice on every processor; faster than the product over all pairs at the
    contour level's sizes: docs/benchmarks/defaults.md), or, with a point of either that is not
    finite or :data:`NEAREST_BY_TREE` off, the smallest ``|u|^2 - 2 p.u`` from one product (its float32 rounding
    decides near ties)."""
    with torch.no_grad():
        if NEAREST_BY_TREE:
            u64, p64 = u.to("cpu", torch.float64).numpy(), pts.to("cpu", torch.float64).numpy()
            if np.isfinite(u64).all() and np.isfinite(p64).all():
                _, idx = cKDTree(u64, balanced_tree=False, compact_nodes=False).query(p64)
                return torch.as_tensor(np.asarray(idx, dtype=np.int64), device=u.device)
        return torch.addmm((u * u).sum(-1)[None, :], pts, u.T, alpha=-2.0).argmin(dim=1)


def cover_energy(uv: torch.Tensor, points: torch.Tensor, profile: Optional[CoverProfile] = None) -> torch.Tensor:
    """Mean over the mask's contour ``points [B, 2]`` of the squared distance (pixels) to the
    nearest projected point ``uv [N, 2]`` (the gradient reaches each point's nearest one);
    with a robust ``profile`` the square of ``profile(distance)`` (shallow within the margin,
    constant beyond the cap: no pull from an outline far from the body)."""
    if points.shape[0] == 0:
        return uv.new_zeros(())
    pts = points.to(uv.dtype)
    nearest = _nearest(uv.detach(), pts)
    diff = pts - uv[nearest]
    if profile is None or profile.plain:
        return diff.square().sum(-1).mean()
    dist = sqrt(diff.square().sum(-1) + 1e-12)
    return profile(dist).square().mean()


def clothing_thickness(mask: np.ndarray, body: np.ndarray, quantile=0.25, points: int = 600):
    """How far (pixels) a person mask reaches beyond a fitted body's mask all around: the
    ``quantile`` of the distances from the mask's outline points (those along the image's
    border left out: a cut is no edge) to the nearest ``body`` pixel. Loose clothing, hair or a
    mask grown by the segmenter widen the whole outline, so even a low quantile is large; a
    leak or a misplaced limb widens a part of it only, and a mask that matches gives about 0.
    ``quantile`` a sequence: a tuple, one thickness per quantile (one pass over the outline)."""
    many = np.ndim(quantile) > 0
    m, b = np.asarray(mask, dtype=bool), np.asarray(body, dtype=bool)
    pts = contour_points(m, points, np.ones_like(m)).astype(np.int64) if m.any() and b.any() else []
    if not len(pts):
        return tuple(0.0 for _ in quantile) if many else 0.0
    dist = cv2.distanceTransform((~b).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    at = dist[pts[:, 1], pts[:, 0]]
    if many:
        return tuple(float(np.quantile(at, float(q))) for q in quantile)
    return float(np.quantile(at, float(quantile)))


def trim_clothing(mask: np.ndarray, thickness: float) -> np.ndarray:
    """The mask eroded by ``thickness`` pixels (a disc): what lies beyond a body in loose
    clothing removed; along the image's border nothing is eroded (a cut is no edge). Parts
    thinner than twice the thickness vanish (a limb in clothing is at least that wide); a mask
    that would vanish entirely is returned unchanged."""
    m = np.asarray(mask, dtype=bool)
    r = int(round(float(thickness)))
    if r <= 0:
        return m.copy()
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    out = cv2.erode(m.astype(np.uint8), k, borderType=cv2.BORDER_REPLICATE).astype(bool)
    return out if out.any() else m.copy()


def concave_region(body: np.ndarray, radius: float) -> np.ndarray:
    """The concavities of a silhouette ``body`` (bool ``[H, W]``): its morphological closing by a
    disc of ``radius`` pixels minus the body itself -- the armpits, the gaps between the arms and
    the torso and between the thighs narrower than ``2 * radius``; empty for ``radius <= 0``.
    Loose clothing (or a grown segmentation) fills exactly these in a person mask."""
    b = np.asarray(body, dtype=bool)
    r = int(round(float(radius)))
    if r <= 0 or not b.any():
        return np.zeros_like(b)
    # padded so that the closing does not glue the body to the image's border
    pad = r + 1
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    padded = cv2.copyMakeBorder(b.astype(np.uint8), pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
    closed = cv2.morphologyEx(padded, cv2.MORPH_CLOSE, k)[pad:-pad, pad:-pad].astype(bool)
    return closed & ~b


def unknown_regions(
    mask: np.ndarray,
    body: Optional[np.ndarray],
    far: float,
    hole_fraction: float,
    concave: float = 0.0,
    hole_covered: float = 0.0,
) -> Optional[np.ndarray]:
    """``known`` (bool ``[H, W]``) of a person ``mask``, or ``None`` when all of it is: the mask's
    pixels farther than ``far`` pixels from ``body`` (the keypoint fit's silhouette; ``far <= 0`` or
    ``body None``: none), the mask's holes (background regions not touching the image's border)
    smaller than ``hole_fraction`` of the mask's area (``<= 0``: none) of which ``body`` covers at least
    ``hole_covered`` (a gap in the segmentation of the body; a hole the body leaves open, between an arm
    and the torso, is background; ``<= 0`` or ``body None``: every small hole) and the mask's pixels in the
    concavities of ``body`` (:func:`concave_region` with radius ``concave`` pixels; ``<= 0``: none:
    clothing fills them, so a mask there says nothing about the body) are unknown."""
    m = np.asarray(mask, dtype=bool)
    unknown = np.zeros_like(m)
    if body is not None and concave > 0:
        unknown |= m & concave_region(body, concave)
    if body is not None and far > 0 and np.asarray(body).any():
        dist = cv2.distanceTransform(
            (~np.asarray(body, dtype=bool)).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE
        )
        unknown |= m & (dist > float(far))
    if hole_fraction > 0 and m.any():
        count, labels, stats, _ = cv2.connectedComponentsWithStats((~m).astype(np.uint8), connectivity=4)
        H, W = m.shape
        x, y, w, h, area = stats.T
        small = (x > 0) & (y > 0) & (x + w < W) & (y + h < H) & (area < float(hole_fraction) * np.count_nonzero(m))
        small[0] = False  # label 0: the mask itself
        if body is not None and hole_covered > 0:
            covered = np.bincount(labels[np.asarray(body, dtype=bool)], minlength=count)
            small &= covered >= float(hole_covered) * area
        unknown |= small[labels]
    if not unknown.any() or not (m & ~unknown).any():  # nothing unknown, or nothing known left: all of it
        return None
    return ~unknown
