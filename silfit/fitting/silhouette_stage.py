"""The silhouette stage: refine keypoint fits so each body's rendered silhouette matches
its person's mask. A batch of subjects (problems) runs together, each with its own
window, target, learning-rate schedule, plateau stop and divergence handling, and no
cross-talk: a batch gives what the subjects give one at a time.

Energy (per subject, the named terms of :mod:`silfit.fitting.terms` plus the silhouette)::

    E = w_silhouette * E_sil(S) + w_keypoints * E_kp + pose_weight * prior(pose)
        + limit_weight * limits(pose) + angle_weight * angle(pose) + shape_weight * |betas|^2
        + w_stay * |theta - theta_kp|^2

* ``S`` is the Mitsuba silhouette (projective sampling, so the gradient includes the
  visibility-edge term) rendered in a *window* around the person (region of interest:
  the union of the mask's box and the body's projection, plus a margin) at a fixed
  number of pixels, so the cost follows the chosen resolution and not the image's.
* ``E_sil`` is the distance-transform energy of :mod:`silfit.silhouette.losses` in window
  pixels, normalised by the mask's area (an average distance in pixels); its mask-not-covered
  side has a robust, capped profile (``robust_cover``: masks are supersets of bodies).
* ``E_kp`` is the keypoint stage's robust reprojection term (:class:`KeypointTerm`) with
  this stage's data: residuals in window pixels, weights the confidences normalised to
  sum 1, Geman-McClure scale ``kp_sigma``; so the silhouette cannot drag limbs away from
  where the detector saw them.
* Priors as in the keypoint stage keep the pose plausible; ``w_stay`` (off by default:
  it cost accuracy on the synthetic set) can add a pull toward the keypoint-stage pose.

The contour level (issue 24) comes first when ``contour_iterations`` > 0: no rendering;
``E_sil`` is replaced by two named terms on projected points (:class:`ContourInsideTerm`:
vertices against the mask's outside distance transform; :class:`ContourCoverTerm`: the
mask's outline points against the nearest projected vertex), the body posed only at about
``contour_vertices`` surface vertices (:class:`ContourBody`), minimised by the project's
batched L-BFGS (:func:`~silfit.fitting.stages.run_stage`, one deterministic row per
subject). It does the coarse moves in a fraction of a rendered step's time each; the
rendered levels then finish, so the final IoU is the renderer's.

Rendered levels are stages (:meth:`SilhouetteFitConfig.stages`): coarse to fine window
resolutions, each run with Adam (the renderer's gradients are stochastic; per-subject
moments and step counts), linear warm-up and cosine decay; a level stops early for a
subject on an energy plateau. All levels run in the project's one schedule runner
(:func:`~silfit.fitting.stages.run_schedule`), this module's hooks preparing each level's
windows and recording each step. Steps with non-finite energy, or whose IoU collapses, stop
that subject and keep its best parameters so far (``warnings`` in its result).
"""

from __future__ import annotations

import math
import threading
import time
import weakref
from dataclasses import dataclass, field, replace
from typing import Callable, List, Optional, Sequence

import cv2
import numpy as np
import torch
from tqdm.auto import tqdm

from silfit.render.batch import get_batch_renderer
from silfit.render.proxy import get_proxy
from silfit.render.silhouette import RoiWindow, get_silhouette_renderer

from ..camera import Camera, project_points
from ..priors import angle_prior, limit_violation, load_pose_prior, shape_prior
from ..silhouette.losses import (
    CoverProfile,
    MaskTarget,
    contour_points,
    cover_energy,
    outside_distance_energy,
    silhouette_energy,
    soft_iou,
)
from ..body.lbs import axis_angle_to_matrix, blend_shapes, pose_correctives, skin_vertices
from ..priors.smplx_priors import body_prior_for
from .body import BodyState, KeypointBody, MeshBody, pose_parameter_names
from .problem import ParameterLayout, Problem, stack_views, world_to_camera
from .aliases import Alias, flat_dict, grouped, renamed_fields
from .schedule_edits import silhouette_defaults, silhouette_stages
from .stages import PerRow, Stage, check_stages, run_schedule, stage_to_dict
from .terms import Energy, Evaluation, KeypointTerm, PriorTerm, StayTerm, Term, evaluate
from .threads import torch_threads

__all__ = [
    "ContourCoverTerm",
    "ContourInsideTerm",
    "MaskHandling",
    "SilhouetteFitConfig",
    "SilhouetteFitResult",
    "Rendering",
    "SilhouetteTerm",
    "TrustRegion",
    "choose_window",
    "fit_silhouette",
    "fit_silhouette_problems",
    "fit_silhouettes",
    "window_target",
]

_CONTOUR_LOCK = threading.Lock()

#: the rendered levels' samples before issue 24's sampling part (4 rays per edge pixel, 4 visibility-edge points
#: per pixel of contour-candidate length): the benchmark's ``dense`` method
BEFORE_SAMPLING_PART = {"spp": 4, "edge_density": 4.0}
#: the rendered levels' settings before issue 24's fourth part (one proxy for every level, a shorter warm-up,
#: body_pose's learning rate twice today's, edge_spp edge points per window pixel): :meth:`SilhouetteFitConfig.legacy`
#: and the benchmark's older methods
BEFORE_FOURTH_PART = {
    "level_proxy_faces": {},
    "warmup": 5,
    "edge_density": None,
    "spp": BEFORE_SAMPLING_PART["spp"],
    "lr": {"betas": 0.1, "body_pose": 0.03, "global_orient": 0.02, "transl": 0.01},
}


#: :class:`Rendering`'s fields (once :class:`SilhouetteFitConfig`'s, by these names)
RENDER_SETTINGS = ("spp", "edge_spp", "edge_density", "seed", "proxy_body", "batch_render")
#: where ``to_dict`` records the group fields that stood apart from their group's first (field: those after it)
RECORDED_LATER = {"optimise": ("seed",), "level_proxy_faces": ("proxy_body", "batch_render")}
#: the trust region of the two-pass refit's first pass (``SilhouetteFitConfig.trust.free_ratio``): the one before
#: issue 55, a radius of this share of the window's longer side around the detections
FREE_TRUST_FRACTION = 0.06
#: the defaults of :class:`SilhouetteFitConfig`'s stage fields: the cells of the literal table
#: (:data:`~silfit.fitting.schedules.SILHOUETTE_SCHEDULE`)
STAGE_DEFAULTS = silhouette_defaults()


@dataclass(frozen=True)
class MaskHandling:
    """What the silhouette stage makes of a mask (:mod:`silfit.silhouette.losses`): the pixels it leaves unknown
    (beyond the image, leaks, holes, the keypoint fit's concavities), the clothing it trims and the robust profile of
    the mask-not-covered side. Each field was :class:`SilhouetteFitConfig`'s own, by the same name, which still
    works."""

    #: what lies outside the image is unknown, not background (:mod:`silfit.silhouette.losses`:
    #: truncation); ``False``: the border is background, as before issue 23
    truncation_aware: bool = True
    #: the "mask not covered" side's robust profile (:class:`~silfit.silhouette.losses.CoverProfile`:
    #: masks are supersets of bodies: clothing, hair, leaks): slope ``cover_inner`` within
    #: ``cover_margin`` of the mask's edge, full slope beyond, at most ``cover_cap`` per pixel; margin
    #: and cap as fractions of the window's longer side; ``robust_cover=False``: the plain
    #: two-sided energy (before issue 23's second part)
    robust_cover: bool = True
    cover_margin: float = 0.03
    cover_inner: float = 0.25
    cover_cap: float = 0.06
    #: the mask-not-covered side's weight against body-outside-the-mask's (``CoverProfile.weight``, issue 55:
    #: a body inside its mask strongly, filling it weakly: the mask may be clothing or hair); 1: as strong
    cover_weight: float = 1.0
    #: a mask that reaches beyond the keypoint fit's body all around (loose clothing, hair, a grown
    #: segmentation: :func:`~silfit.silhouette.losses.clothing_thickness` above ``trim_min`` of the
    #: mask's extent) is eroded by that thickness (at most ``trim_max``) before the stage
    #: (:func:`~silfit.silhouette.losses.trim_clothing`; image path: image_fit.ImageRefinement)
    trim_clothing: bool = True
    trim_min: float = 0.015
    trim_max: float = 0.08
    #: the quantile of the mask outline's distances to the keypoint fit's body taken as the clothing's thickness
    #: (:func:`~silfit.silhouette.losses.clothing_thickness`); 0.25 before the two-pass refit (why this default:
    #: docs/benchmarks/defaults.md)
    trim_quantile: float = 0.25
    #: the trim's depth: the outline distances' ``trim_upper`` quantile where it lies at most ``trim_upper_max`` of
    #: the mask's extent beyond the ``trim_quantile`` one (a layer about even all around: a grown mask, tight
    #: clothing, whose quartile the keypoint fit's own misplacement biases low, about 1 px on a 256 px render grown
    #: by 6), else the ``trim_quantile`` one (uneven clothing, a suit: its thinner quarter; the head and hands
    #: have none); ``None``: the ``trim_quantile`` one always (before issue 55's deeper trim:
    #: docs/benchmarks/real-photos.md)
    trim_upper: Optional[float] = 0.5
    #: how close (a share of the mask's extent) the two quantiles must lie for the layer to count as even
    trim_upper_max: float = 0.01
    #: mask pixels farther than ``leak_distance`` of the mask's extent from the keypoint fit's
    #: silhouette (a leak into an object or the background) and the mask's holes smaller than
    #: ``hole_fraction`` of its area (segmentation gaps) are unknown, like the pixels beyond the
    #: image (:func:`~silfit.silhouette.losses.unknown_regions`; image path:
    #: image_fit.ImageRefinement); 0: off
    leak_distance: float = 0.03
    hole_fraction: float = 0.02
    #: a small hole is unknown only where the keypoint fit's body covers at least this share of it (a gap in the
    #: segmentation of the body); a hole the body leaves open (between an arm and the torso of a clean mask) is
    #: background; 0: every small hole (before the demo's IoU change, issue 55: docs/benchmarks/real-photos.md)
    hole_covered: float = 0.5
    #: mask pixels in the concavities of the keypoint fit's silhouette (its closing by a disc of
    #: ``concave_radius`` of the mask's extent, minus itself: armpits, between the arms and the torso,
    #: between the thighs) are unknown (:func:`~silfit.silhouette.losses.concave_region`): loose
    #: clothing fills them, and a stage that covers them turns many joints a little; 0: off (before
    #: issue 23's concavity change; why this default: docs/benchmarks/defaults.md)
    concave_radius: float = 0.07
    #: the concavities unknown only in a mask trimmed as clothing (``trim_clothing``): a mask that
    #: matches the body has no filled concavities, and there they are the only sign of a misplaced limb
    concave_trimmed_only: bool = True
    #: ``cover_inner`` for a mask the clothing trim (``trim_clothing``) left whole and the keypoint fit's body already
    #: matches (IoU at least ``whole_iou``): the body's own silhouette, no clothing near its edge to forgive, so the
    #: mask not covered there costs as much as the body outside it; ``None``, or the trim off: ``cover_inner`` for
    #: every mask (before the demo's IoU change, issue 55: docs/benchmarks/real-photos.md; a photo's masks, IoU
    #: 0.48-0.84 with the keypoint fit, fitted this way raised the reprojection error). Image path only
    #: (image_fit.ImageRefinement: :attr:`~silfit.fitting.problem.Observation.cover_inner`)
    untrimmed_inner: Optional[float] = 1.0
    whole_iou: float = 0.9


@dataclass(frozen=True)
class Rendering:
    """How the silhouette stage's rendered levels render (:mod:`silfit.render`): the samples, their seed, the posed
    render proxy and the batch's tiles. The proxy's faces (``SilhouetteFitConfig.proxy_faces``,
    ``level_proxy_faces``) are the levels' table cells and stay the config's. Each field was
    :class:`SilhouetteFitConfig`'s own, by the same name, which still works."""

    #: primal samples per edge pixel with the ray-cast renderer (which traces one ray per constant region elsewhere;
    #: per pixel with the projective one); 4 before issue 24's sampling part (why this default, and
    #: ``edge_density``'s: docs/benchmarks/defaults.md)
    spp: int = 2
    edge_spp: int = 1  # visibility-edge samples per pixel (projective integrator's sppp)
    #: the ray-cast renderer's visibility-edge points per pixel of contour-candidate length instead of
    #: ``edge_spp`` per window pixel (at most that many; silfit.render.raycast: same expected gradient, fewer rays);
    #: ``None``: ``edge_spp`` per pixel (before issue 24's speed part)
    edge_density: Optional[float] = 3.0  # 4.0 before issue 24's sampling part
    seed: Optional[int] = 0  # base seed of the renderer's sampling (None: fresh seeds)
    #: pose the render proxy's vertices directly (:class:`ContourBody` of the proxy: its rest-pose mix
    #: of the model, no full mesh per step) in the rendered levels of an SMPL-layout model; ``False``:
    #: pose the full mesh, then map it to the proxy (before issue 24's third part)
    proxy_body: bool = True
    #: a batch's subjects rendered together in tiles of one film (:mod:`silfit.render.batch`);
    #: off by default (why: docs/benchmarks/defaults.md)
    batch_render: bool = False


@dataclass(frozen=True)
class TrustRegion:
    """The keypoint trust region of the silhouette stage (:class:`KeypointTrustTerm`, weighed by
    ``SilhouetteFitConfig.w_trust``): a keypoint's projection may move up to a radius from its detection at no cost,
    beyond it quadratically, weighed by its confidence (issue 55: keypoints as a constraint, not a competitor). With
    ``from_start`` (issue 55) the radius is each keypoint's own reprojection error after the keypoint stage times
    ``ratio``, plus ``median`` times the median of those errors (the median error can rise by about that share), plus
    ``fraction`` of the window's longer side; the excess counts in units of the median error plus a pixel
    (:func:`trust_data`: the same on a photo of 4,000 pixels as on one of 256) and each keypoint weighs its confidence
    over the observation's largest. Before issue 55 (``from_start=False, fraction=0.06``): a radius of 6 % of the
    window around the detections, confidences normalised to sum 1 (docs/benchmarks/real-photos.md; why these
    defaults: docs/benchmarks/defaults.md). Each field was :class:`SilhouetteFitConfig`'s ``trust_<name>``, which
    still works."""

    fraction: float = 0.0
    from_start: bool = True
    ratio: float = 1.0
    median: float = 0.15
    #: the share of the median error in the trust region's unit (``unit = unit_median * median + 1 px``;
    #: why this default: docs/benchmarks/defaults.md)
    unit_median: float = 1.0
    #: two passes in the image path (image_fit.ImageRefinement): the stage runs first with the trust region
    #: before issue 55 (a radius of ``FREE_TRUST_FRACTION`` of the window around the detections: the silhouette free
    #: to move the keypoints a little), then every image whose kept result's median reprojection error exceeds
    #: ``free_ratio`` times the keypoint stage's has all its branches refitted with the trust region above
    #: (``from_start``), and keeps that. ``None``: one pass with the trust region above (why this default:
    #: docs/benchmarks/defaults.md)
    free_ratio: Optional[float] = None


@renamed_fields(
    w_pose=Alias("pose_weight"),
    w_limits=Alias("limit_weight"),
    w_angle=Alias("angle_weight"),
    w_shape=Alias("shape_weight"),
    **grouped(
        "mask",
        truncation_aware="truncation_aware",
        robust_cover="robust_cover",
        cover_margin="cover_margin",
        cover_inner="cover_inner",
        cover_cap="cover_cap",
        cover_weight="cover_weight",
        trim_clothing="trim_clothing",
        trim_min="trim_min",
        trim_max="trim_max",
        trim_quantile="trim_quantile",
        leak_distance="leak_distance",
        hole_fraction="hole_fraction",
        concave_radius="concave_radius",
        concave_trimmed_only="concave_trimmed_only",
    ),
    **grouped(
        "render",
        spp="spp",
        edge_spp="edge_spp",
        edge_density="edge_density",
        seed="seed",
        proxy_body="proxy_body",
        batch_render="batch_render",
    ),
    **grouped(
        "trust",
        trust_fraction="fraction",
        trust_from_start="from_start",
        trust_ratio="ratio",
        trust_median="median",
        trust_unit_median="unit_median",
        trust_free_ratio="free_ratio",
    ),
)
@dataclass
class SilhouetteFitConfig:
    """Settings of the silhouette stage (defaults tuned on the synthetic set)."""

    #: window's longer side in pixels, per rendered level
    resolutions: tuple = STAGE_DEFAULTS["resolutions"]
    #: Adam steps per rendered level (upper bounds: plateaus stop earlier)
    iterations: tuple = STAGE_DEFAULTS["iterations"]
    #: L-BFGS iterations of the contour level (no rendering: :class:`ContourInsideTerm` and
    #: :class:`ContourCoverTerm`) run before the rendered levels; 0: none (:meth:`legacy`)
    contour_iterations: int = STAGE_DEFAULTS["contour_iterations"]
    #: the contour level's window (its distance transform's pixels)
    contour_resolution: int = STAGE_DEFAULTS["contour_resolution"]
    contour_points: int = 256  # mask outline points per observation in the contour level
    #: surface points the contour level poses and projects (model vertices spread over the
    #: surface, :func:`contour_vertex_index`); ``None``: all (the render proxy's, if any)
    contour_vertices: Optional[int] = 2000
    w_contour_inside: float = STAGE_DEFAULTS["w_contour_inside"]
    w_contour_cover: float = STAGE_DEFAULTS["w_contour_cover"]
    #: how the rendered levels render (:class:`Rendering`: samples, seed, the posed proxy, tiles; its fields were the
    #: config's, names that still work)
    render: Rendering = field(default_factory=Rendering)
    margin: float = 0.12  # window margin, fraction of the box on each side
    #: window sides rounded up to a multiple of this many pixels: few distinct window sizes,
    #: so few compiled render kernels (a new size costs Dr.Jit a trace and, the first time on
    #: a machine, an LLVM compile of seconds)
    window_multiple: int = 16
    #: what the stage makes of the masks (:class:`MaskHandling`; its fields were the config's, names that still work)
    mask: MaskHandling = field(default_factory=MaskHandling)
    #: after the stage, a fit less plausible than the keypoint fit (silfit.fitting.plausibility.silhouette_guard)
    #: is replaced by the keypoint fit, with a warning (image path: image_fit.ImageRefinement)
    plausibility_guard: bool = True
    #: the keypoint stage's other distinct branches refined to the end (``KeypointFitResult.alternatives``) whose
    #: final energy lies within this relative margin of the fit's (the same 10 % as the depth warning's
    #: ``silfit.fitting.plausibility.HYPOTHESIS_MARGIN``, which also asks that they move a joint 400 mm) are refined against
    #: the mask too, as more problems of the batch, and the lowest final energy of the stage is kept, beyond
    #: ``choice_margin`` (image path: image_fit.ImageRefinement; ``--hypotheses K`` refines its K hypotheses instead,
    #: whatever this is); 0: off, the keypoint stage's branch only (before issue 25's close-alternatives part; README
    #: "By default, the close alternatives too")
    alternatives_margin: float = 0.1
    #: at most this many close alternatives per image, the closest in energy first (each costs one more problem)
    alternatives_max: int = 2
    #: an alternative (or ``--hypotheses K``'s hypothesis) replaces the keypoint stage's fit only where its final
    #: energy is lower than the fit's by more than this share of it: a mask hardly sees a limb mirrored in depth, and
    #: the render seed alone moves the gap between two refined branches by 2.1 % (standard deviation), so a smaller
    #: gap is a coin toss; 0.04 is about twice that (image path: image_fit._choose_hypothesis; 0: the lowest energy,
    #: before issue 55's depth-branch part; the measurements: docs/benchmarks/real-photos.md)
    choice_margin: float = 0.04
    #: Adam's learning rates (body_pose 0.03 before issue 24's fourth part: the first steps of a rendered level
    #: knocked the contour level's IoU down)
    lr: dict = field(default_factory=lambda: dict(sorted(STAGE_DEFAULTS["lr"].items())))  # by name
    w_silhouette: float = STAGE_DEFAULTS["w_silhouette"]
    w_keypoints: float = STAGE_DEFAULTS["w_keypoints"]
    kp_sigma: float = 20.0  # Geman-McClure scale, window pixels
    #: the pose prior's (one name in every config, issue 26; old name ``w_pose``); it holds the arms a
    #: detector's keypoints barely hold (why this default: docs/benchmarks/defaults.md)
    pose_weight: float = STAGE_DEFAULTS["pose_weight"]
    #: the joint limits', the angle prior's and the shape prior's (one name in every config, issue 57; old names
    #: ``w_limits``, ``w_angle``, ``w_shape``)
    limit_weight: float = STAGE_DEFAULTS["limit_weight"]
    angle_weight: float = STAGE_DEFAULTS["angle_weight"]
    shape_weight: float = STAGE_DEFAULTS["shape_weight"]
    w_stay: float = STAGE_DEFAULTS["w_stay"]
    #: trust region on the keypoints (:class:`KeypointTrustTerm`, its radius and unit: :class:`TrustRegion`):
    #: the weight; too strong, it holds a noise-free subject's keypoints so hard that the stage turns limbs in depth
    #: instead; 0: off (before issue 23; why these defaults: docs/benchmarks/defaults.md)
    w_trust: float = STAGE_DEFAULTS["w_trust"]
    #: the trust region's radius, unit and passes (:class:`TrustRegion`; its fields were the config's ``trust_<name>``,
    #: names that still work)
    trust: TrustRegion = field(default_factory=TrustRegion)
    #: shape held in the plausible range: ``(|beta| - max_abs_beta)^2`` beyond it (:func:`beta_bound`)
    w_beta_bound: float = STAGE_DEFAULTS["w_beta_bound"]
    max_abs_beta: float = 2.5
    #: steps of linear learning-rate warm-up per level (5 before issue 24's fourth part)
    warmup: int = STAGE_DEFAULTS["warmup"]
    #: steps compared for the plateau test
    plateau_window: int = STAGE_DEFAULTS["plateau_window"]
    #: relative energy improvement below which a level stops
    plateau_rtol: float = STAGE_DEFAULTS["plateau_rtol"]
    iou_collapse: float = 0.15  # IoU drop (vs best) that counts as divergence
    optimise: tuple = STAGE_DEFAULTS["optimise"]
    #: render a coarser proxy mesh with this many faces (vertices a fixed linear map of the
    #: model's, :mod:`silfit.render.proxy`; IoU >= 0.995 against the full mesh at 10,000 faces);
    #: ``None`` renders the full mesh
    proxy_faces: Optional[int] = 10000
    #: the render proxy's faces by rendered level resolution (window pixels -> faces, at most
    #: ``proxy_faces``; a level not listed renders ``proxy_faces``; ignored with ``proxy_faces=None`` or a
    #: caller's renderer): a window pixel spans 2-4 image pixels, so a coarser proxy does at a smaller
    #: acceleration-structure build, ray plan and trace per step (issue 24's fourth part; ``{}``: before it)
    level_proxy_faces: dict = field(default_factory=lambda: dict(STAGE_DEFAULTS["level_proxy_faces"]))
    threads: Optional[int] = 1  # torch threads during the stage (see silfit.fitting.threads)

    def __post_init__(self):
        if len(self.resolutions) != len(self.iterations) or not self.resolutions:
            raise ValueError(
                f"SilhouetteFitConfig: resolutions ({len(self.resolutions)}) and iterations ({len(self.iterations)}) "
                "must have the same non-zero length"
            )
        if int(self.contour_iterations) != self.contour_iterations or self.contour_iterations < 0:
            raise ValueError(
                f"SilhouetteFitConfig: contour_iterations must be a non-negative integer, got {self.contour_iterations!r}"
            )
        missing = [n for n in self.optimise if n not in self.lr]
        if missing:
            raise ValueError(
                f"SilhouetteFitConfig: no learning rate (lr) for optimised parameter(s) {', '.join(missing)}"
            )
        t = self.trust
        values = {"w_trust": self.w_trust, "trust.fraction": t.fraction, "trust.ratio": t.ratio}
        values.update({"trust.median": t.median, "trust.unit_median": t.unit_median})
        negative = [n for n, v in values.items() if not float(v) >= 0]
        if negative:
            raise ValueError(
                f"SilhouetteFitConfig: {', '.join(negative)} must be 0 or more (the keypoint trust region)"
            )
        if t.free_ratio is not None and not float(t.free_ratio) > 0:
            raise ValueError(f"SilhouetteFitConfig: trust.free_ratio must be above 0 or None, got {t.free_ratio!r}")
        bad = [n for n in ("alternatives_margin", "choice_margin") if not float(getattr(self, n)) >= 0]  # NaN too
        if bad:
            raise ValueError(f"SilhouetteFitConfig: {', '.join(bad)} must be 0 or more")
        if not 0.0 <= float(self.mask.trim_quantile) <= 1.0:
            raise ValueError(
                f"SilhouetteFitConfig: mask.trim_quantile must lie in [0, 1], got {self.mask.trim_quantile!r}"
            )
        upper = self.mask.trim_upper
        if (upper is not None and not 0.0 <= float(upper) <= 1.0) or not float(self.mask.trim_upper_max) >= 0:
            raise ValueError(
                "SilhouetteFitConfig: mask.trim_upper must lie in [0, 1] (or be None) and mask.trim_upper_max be 0 "
                f"or more, got {upper!r} and {self.mask.trim_upper_max!r}"
            )

    @classmethod
    def legacy(cls, **changes) -> "SilhouetteFitConfig":
        """The schedule before the contour level (issue 24): rendered Adam levels only, 60
        steps at 128 px and 50 at 256 px, the rendered levels' settings before its fourth part
        (:data:`BEFORE_FOURTH_PART`; the benchmark's "before")."""
        before = {k: (dict(v) if isinstance(v, dict) else v) for k, v in BEFORE_FOURTH_PART.items()}
        render = Rendering(**{k: before.pop(k) for k in RENDER_SETTINGS if k in before})
        return cls(
            **{
                "resolutions": (128, 256),
                "iterations": (60, 50),
                "contour_iterations": 0,
                "window_multiple": 1,
                **before,
                "render": render,
                **changes,
            }
        )

    def free_pass(self) -> "SilhouetteFitConfig":
        """The two-pass refit's first pass (``trust.free_ratio``): these settings with the trust region before issue
        55 (a radius of :data:`FREE_TRUST_FRACTION` of the window around the detections)."""
        return replace(self, trust=replace(self.trust, from_start=False, fraction=FREE_TRUST_FRACTION))

    def cover_profile(self, resolution: int, inner: Optional[float] = None) -> Optional[CoverProfile]:
        """The mask-not-covered profile in pixels of a window ``resolution`` pixels long
        (``None``: plain, ``robust_cover=False``); ``inner``: its slope within the margin in place of
        ``mask.cover_inner`` (an observation's own, :attr:`~silfit.fitting.problem.Observation.cover_inner`)."""
        m = self.mask
        if not m.robust_cover:
            return None
        r = float(resolution)
        inner = float(m.cover_inner) if inner is None else float(inner)
        return CoverProfile(float(m.cover_margin) * r, inner, float(m.cover_cap) * r, float(m.cover_weight))

    def weights(self) -> dict:
        """The rendered levels' weights."""
        return {
            "silhouette": self.w_silhouette,
            "keypoints": self.w_keypoints,
            "pose": self.pose_weight,
            "limits": self.limit_weight,
            "angle": self.angle_weight,
            "shape": self.shape_weight,
            "stay": self.w_stay,
            "keypoint_trust": self.w_trust,
            "beta_bound": self.w_beta_bound,
        }

    def stages(self) -> tuple:
        """The contour level (L-BFGS, when ``contour_iterations``), then one Adam stage per rendered window
        resolution (coarse to fine): the literal table :data:`~silfit.fitting.schedules.SILHOUETTE_SCHEDULE`, edited by
        the fields that differ from their defaults (:func:`~silfit.fitting.schedule_edits.silhouette_stages`)."""
        return silhouette_stages(self)

    def level_faces(self, resolution: int) -> Optional[int]:
        """The render proxy's faces of a rendered level at ``resolution`` when it is not ``proxy_faces``
        (``level_proxy_faces``), else ``None``."""
        faces = {int(k): v for k, v in (self.level_proxy_faces or {}).items()}.get(int(resolution))  # JSON: str keys
        if not self.proxy_faces or faces is None or int(faces) >= int(self.proxy_faces):
            return None
        return int(faces)

    def to_dict(self) -> dict:
        d = flat_dict(self, later=RECORDED_LATER)  # the groups' fields by their flat names, where they stood
        d["stages"] = [stage_to_dict(s) for s in self.stages()]
        return d


@dataclass
class SilhouetteFitResult:
    """Refined parameters of one problem (numpy) and the stage's diagnostics.

    ``parameters``: the model's parameters by name, per-frame ones ``[F, w]`` and shared
    ones (``betas``) ``[1, w]``; one image is ``F = 1``, so every array is ``[1, w]``.
    The parameter names are also attributes (``result.betas``, ``result.body_pose``...)."""

    parameters: dict
    history: dict  # per step: level, energy, silhouette, keypoints, iou (lists)
    iou_start: float  # soft IoU in the windows (mean over masked observations), first step
    iou_end: float  # the same at the kept (lowest-energy) step
    seconds: float
    steps: int
    warnings: list
    #: each term's unweighted value at the kept step of the last level
    terms: dict = field(default_factory=dict)
    config: dict = field(default_factory=dict)
    #: soft IoU per observation ``[F][C]`` at the kept step of the last level (NaN: no mask)
    ious: list = field(default_factory=list)
    #: L-BFGS iterations of the contour level (``steps`` counts the rendered levels' steps)
    contour_iterations: int = 0
    #: the stage stopped this problem early (a non-finite energy or a collapsed IoU; see ``warnings``)
    failed: bool = False

    def params(self) -> dict:
        return dict(self.parameters)

    @property
    def final_energy(self) -> float:
        """The stage's energy at the kept (lowest-energy) step of its last level: silhouette, keypoints and
        priors at that level's weights (what :class:`image_fit.ImageRefinement` compares hypotheses by)."""
        level = self.final_level
        last = [e for lv, e in zip(self.history.get("level") or [], self.history.get("energy") or []) if lv == level]
        return float(min(last)) if last else float("nan")

    @property
    def final_level(self):
        """The level of the last recorded step (``None``: none): energies compare only within one level."""
        levels = self.history.get("level") or []
        return levels[-1] if levels else None

    def __getattr__(self, name):
        parameters = self.__dict__.get("parameters")
        if parameters is not None and name in parameters:
            return parameters[name]
        raise AttributeError(name)


def choose_window(mask: np.ndarray, uv: np.ndarray, camera: Camera, resolution: int, margin: float, multiple: int = 1):
    """A :class:`silfit.render.silhouette.RoiWindow` covering the mask's box and the projected
    body ``uv [N, 2]`` with ``margin``, rendered with ``resolution`` pixels along its longer
    side (aspect ratio kept); the shorter side is rounded up to a ``multiple`` of pixels (more
    margin), so windows come in a few sizes and the renderer reuses its compiled kernels."""
    ys, xs = np.nonzero(mask)
    lo = np.minimum([xs.min() - 0.5, ys.min() - 0.5], uv.min(0) - 0.5)
    hi = np.maximum([xs.max() + 0.5, ys.max() + 0.5], uv.max(0) + 0.5)
    lo, hi = lo - margin * (hi - lo), hi + margin * (hi - lo)
    extent = hi - lo
    scale = resolution / float(extent.max())
    width, height = (max(8, int(round(e * scale))) for e in extent)
    m = max(1, int(multiple))
    width, height = (max(v, min(-(-v // m) * m, int(resolution))) for v in (width, height))
    x0, y0 = (float(c) for c in (lo + hi) / 2 - np.array([width, height]) / scale / 2)
    return RoiWindow(x0, y0, scale, camera.crop(x0, y0, width, height, scale))


def window_target(
    mask: np.ndarray,
    window,
    supersample: int = 4,
    truncation_aware: bool = True,
    cover: Optional[CoverProfile] = None,
    known: Optional[np.ndarray] = None,
) -> tuple[MaskTarget, np.ndarray]:
    """The mask resampled into a ``RoiWindow``: ``(MaskTarget of the binarised coverage, coverage)``.

    Coverage is the fraction of each window pixel inside the mask (supersampled, then
    area-averaged). Pixels outside the image are unknown, not background: the target's
    ``valid`` map marks the image's pixels (:mod:`silfit.silhouette.losses`: truncation).
    Distances are in window pixels; ``cover`` (window pixels) is the mask-not-covered side's
    robust profile (``None``: plain). ``known`` (bool, the image's ``[H, W]``; ``None``: all): the
    image pixels whose mask value is trusted; the others (leaks, small holes:
    :func:`~silfit.silhouette.losses.unknown_regions`) are unknown like those beyond the image,
    whatever ``truncation_aware``.
    """
    cam = window.camera
    ss = int(supersample)
    s = window.scale * ss
    # Output (supersampled) pixel centre i -> image pixel-centre coordinate x0 + (i + 0.5)/s - 0.5.
    M = np.array([[1.0 / s, 0.0, window.x0 + 0.5 / s - 0.5], [0.0, 1.0 / s, window.y0 + 0.5 / s - 0.5]])

    def warp(img):
        return cv2.resize(
            cv2.warpAffine(
                img,
                M,
                (cam.width * ss, cam.height * ss),
                flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=0.0,
            ),
            (cam.width, cam.height),
            interpolation=cv2.INTER_AREA,
        )

    if known is not None:
        known = np.asarray(known, dtype=bool)
        mask = np.asarray(mask, dtype=bool) & known
    coverage = warp(mask.astype(np.float32))
    binary = coverage > 0.5
    if not binary.any():
        raise ValueError("the mask vanishes at the silhouette stage's resolution; raise the resolution")
    seen = warp(np.ones(mask.shape, np.float32)) > 0.5  # the window's pixels inside the image
    valid = None if seen.all() or not truncation_aware else seen
    if known is not None:  # the window's pixels whose mask value is known (inside the image, if truncation-aware)
        trusted = (warp(known.astype(np.float32)) > 0.5) | ~seen  # beyond the image: truncation_aware decides
        valid = trusted if valid is None else valid & trusted
        valid = None if valid.all() else valid
    return MaskTarget.from_mask(binary, valid=valid, cover=cover), coverage


class SilhouetteTerm(Term):
    """Two-sided distance-transform energy of each observation's rendered silhouette,
    summed over observations (those with a window; observations without a mask have
    none); leaves the soft IoU per problem (mean over its masks) in ``ev.extras['iou']``
    and per observation in ``ev.extras['iou_observations']``.

    ``proxy`` (a :class:`silfit.render.proxy.RenderProxy`) maps the body's vertices to the
    render proxy first; ``batch_renderer`` renders several observations in one call.
    Reads ``ev.data``: ``windows`` and ``targets`` (per problem, lists over its
    observations of :class:`silfit.render.silhouette.RoiWindow` and :class:`MaskTarget`) and
    ``seeds`` (per problem, the renderer seed of this step or ``None``)."""

    name = "silhouette"

    def __init__(self, renderer, spp: int, edge_spp: int, proxy=None, batch_renderer=None, edge_density=None):
        self.renderer, self.spp, self.edge_spp = renderer, int(spp), int(edge_spp)
        self.proxy, self.batch_renderer = proxy, batch_renderer
        self.edge_density = None if edge_density is None else float(edge_density)

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        V = ev.body.vertices
        if self.proxy is not None:
            V = self.proxy(V)
        verts = V.reshape(ev.P, ev.F, 1, *V.shape[1:]).expand(ev.P, ev.F, ev.C, *V.shape[1:])
        cams = world_to_camera(verts, ev.data["R"].to(V.dtype), ev.data["t"].to(V.dtype))
        windows = ev.data["windows"]
        jobs = [(p, o) for p in range(ev.P) for o, w in enumerate(windows[p]) if w is not None]
        seeds = [None if ev.data["seeds"][p] is None else int(ev.data["seeds"][p]) + 7919 * o for p, o in jobs]
        # edge_density only when set: a caller's renderer without the option still works with None
        dens = {} if self.edge_density is None else {"edge_density": self.edge_density}
        if self.batch_renderer is not None and len(jobs) > 1:
            sils = self.batch_renderer(
                [cams[p, o // ev.C, o % ev.C] for p, o in jobs],
                [windows[p][o].camera for p, o in jobs],
                spp=self.spp,
                edge_spp=self.edge_spp,
                seed=seeds[0],
                **dens,
            )
        elif hasattr(self.renderer, "render_views"):  # a body's views in one call (one BVH build per body)
            Vb, R, t = V.reshape(ev.P, ev.F, *V.shape[1:]), ev.data["R"], ev.data["t"]
            sils = [None] * len(jobs)
            for key in dict.fromkeys((p, o // ev.C) for p, o in jobs):
                js = [j for j, (p, o) in enumerate(jobs) if (p, o // ev.C) == key]
                cs = [jobs[j][1] % ev.C for j in js]
                imgs = self.renderer.render_views(
                    Vb[key],
                    [windows[key[0]][jobs[j][1]].camera for j in js],
                    [R[key][c] for c in cs],
                    [t[key][c] for c in cs],
                    spp=self.spp,
                    edge_spp=self.edge_spp,
                    seeds=[seeds[j] for j in js],
                    **dens,
                )
                for j, img in zip(js, imgs):
                    sils[j] = img
        else:
            sils = [
                self.renderer(
                    cams[p, o // ev.C, o % ev.C],
                    windows[p][o].camera,
                    spp=self.spp,
                    edge_spp=self.edge_spp,
                    seed=seed,
                    **dens,
                )
                for (p, o), seed in zip(jobs, seeds)
            ]
        energies = [torch.zeros((), dtype=V.dtype) for _ in range(ev.P)]
        ious = [[float("nan")] * len(windows[p]) for p in range(ev.P)]
        for (p, o), sil in zip(jobs, sils):
            target = ev.data["targets"][p][o]
            energies[p] = energies[p] + silhouette_energy(sil, target)
            with torch.no_grad():
                ious[p][o] = float(soft_iou(sil.detach(), target.mask, target.valid))
        ev.extras["iou_observations"] = ious
        ev.extras["iou"] = [float(np.nanmean(i)) if any(x == x for x in i) else float("nan") for i in ious]
        return torch.stack(energies)


def trust_excess(dist: torch.Tensor, radius: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """The trust region's penalty per observation: ``sum_k w_k relu(dist_k - radius_k)^2`` over the last axis
    (distances and radii in one unit: nothing inside a keypoint's radius, quadratic beyond it)."""
    return (weights * torch.relu(dist - radius).square()).sum(-1)


def trust_data(
    target: torch.Tensor,
    weights: torch.Tensor,
    start_2d: torch.Tensor,
    ratio: float = 1.0,
    median_share: float = 0.0,
    floor_px: float = 1.0,
    unit_share: float = 1.0,
) -> dict:
    """The data of :class:`KeypointTrustTerm` around the keypoint stage's fit (issue 55), from the detections
    ``target [..., K, 2]``, their ``weights [..., K]`` (confidences) and the fit's projections ``start_2d``, all in
    image pixels: ``trust_radius [..., K]``, each keypoint's free radius, ``ratio`` times its reprojection error
    ``r_k`` plus ``median_share`` times the median ``r`` of its observation's keypoints (so the median error rises
    by at most that share); ``trust_unit [...]``, the pixels one unit of excess costs (that median plus
    ``floor_px``: the penalty is scale-free, the same for a photo of 4,000 pixels as of 256); ``trust_weights``,
    each keypoint's confidence over its observation's largest (a keypoint of confidence 0 weighs 0)."""
    seen = weights > 0
    start = (start_2d.to(target.dtype) - target).norm(dim=-1) * seen
    flat, fseen = start.reshape(-1, start.shape[-1]), seen.reshape(-1, start.shape[-1])
    med = torch.stack([r[m].median() if bool(m.any()) else r.new_zeros(()) for r, m in zip(flat, fseen)])
    med = med.reshape(start.shape[:-1])
    top = weights.amax(dim=-1, keepdim=True).clamp(min=1e-12)
    return {
        "trust_radius": float(ratio) * start + float(median_share) * med[..., None],
        "trust_unit": float(unit_share) * med + float(floor_px),
        "trust_weights": weights / top,
    }


class KeypointTrustTerm(Term):
    """A trust region on the keypoints: per observation, :func:`trust_excess` of each keypoint's distance from
    its detection beyond its radius, weighed by its confidence, summed per problem. The robust keypoint term
    saturates, so alone it lets the silhouette stage trade keypoints for mask (clothing, leaks, cut-off people);
    this one does not saturate beyond the radius.

    Around the keypoint stage's fit (issue 55; ``ev.data`` holds :func:`trust_data`'s ``trust_radius``,
    ``trust_unit`` and ``trust_weights``): distances and radii in image pixels (plus ``trust_px`` window pixels),
    the excess in units of ``trust_unit``. Before issue 55 (without them): a radius of ``trust_px`` window pixels
    around the detections, distances in window pixels, the confidences ``weights`` normalised to sum 1. Reads
    ``target``, ``weights``, ``scale`` (image to window pixels) and ``trust_px`` too."""

    name = "keypoint_trust"

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        d = ev.data
        K = ev.keypoints_2d.shape[-2]
        scale = d["scale"].reshape(-1, 1).to(ev.keypoints_2d.dtype)
        dist = (ev.keypoints_2d.reshape(-1, K, 2) - d["target"].reshape(-1, K, 2)).norm(dim=-1)  # image pixels
        tau = d["trust_px"].to(dist.dtype).repeat_interleave(ev.F * ev.C)[:, None]  # [P] -> per observation
        if "trust_radius" not in d:  # before issue 55
            w = d["weights"].reshape(-1, K).to(dist.dtype)
            return ev.per_problem(trust_excess(dist * scale, tau, w / w.sum(-1, keepdim=True).clamp(min=1e-9)))
        unit = d["trust_unit"].reshape(-1, 1).to(dist.dtype)
        radius = d["trust_radius"].reshape(-1, K).to(dist.dtype) + tau / scale
        return ev.per_problem(
            trust_excess(dist / unit, radius / unit, d["trust_weights"].reshape(-1, K).to(dist.dtype))
        )


def beta_bound(betas: torch.Tensor, limit: float) -> torch.Tensor:
    """``sum relu(|beta| - limit)^2`` per row: nothing inside the shape space's plausible range."""
    return torch.relu(betas.abs() - float(limit)).square().sum(-1)


def contour_vertex_index(model, count: int) -> np.ndarray:
    """About ``count`` model vertices spread evenly over the surface (sorted indices): each
    vertex of a render proxy of ``2 * count`` faces (:func:`silfit.render.proxy.get_proxy`)
    replaced by the model vertex that weighs most in it; every vertex of a model with no more
    than ``2 * count`` faces (nothing to reduce)."""
    if 2 * int(count) >= int(model.faces.shape[0]):
        return np.arange(int(model.v_template.shape[0]))
    proxy = get_proxy(model.v_template, model.faces, 2 * int(count))
    dominant = proxy.indices[np.arange(len(proxy.indices)), np.argmax(proxy.weights, axis=1)]
    return np.unique(dominant)


class ContourBody(torch.nn.Module):
    """A reduced body evaluator: the keypoint stage's reduced forward
    (:class:`~silfit.fitting.body.KeypointBody`: keypoints, joints, skinning transforms)
    plus linear blend skinning of a few points only (``vertices [R, n, 3]``). For
    SMPL-layout models (pose parameters are axis-angle rotations).

    ``vertex_index``: model vertex indices ``[n]`` (the contour level: each point is a
    model vertex, the same function of the parameters as the full mesh's vertices), or a
    render proxy (:class:`silfit.render.proxy.RenderProxy`, the rendered levels): each point is
    the proxy's fixed mix of model vertices taken in the rest pose (template, shape and pose
    correctives mixed exactly, skinning weights mixed too), so the proxy's vertices are
    posed directly, without the full mesh (its neighbours' transforms differ little: the
    posed proxy moves well under a millimetre from the proxy of the posed mesh)."""

    def __init__(self, model, layout: str, vertex_index):
        super().__init__()
        self.keypoint_body = KeypointBody(model, layout)
        self.pose_names = pose_parameter_names(model)
        if hasattr(vertex_index, "indices") and hasattr(vertex_index, "weights"):
            idx = torch.as_tensor(np.asarray(vertex_index.indices), dtype=torch.long)  # [n, K]
            w = torch.as_tensor(np.asarray(vertex_index.weights), dtype=torch.float64)
        else:
            idx = torch.as_tensor(np.asarray(vertex_index), dtype=torch.long)[:, None]
            w = torch.ones(idx.shape, dtype=torch.float64)
        dt = model.v_template.dtype

        def mix(a: torch.Tensor) -> torch.Tensor:  # [V, ...] -> [n, ...]: sum_k w_k a[idx_k]
            g = a.double()[idx.reshape(-1)].reshape(*idx.shape, *a.shape[1:])
            return (g * w.reshape(*w.shape, *([1] * (a.ndim - 1)))).sum(1).to(dt)

        self.register_buffer("v_template", mix(model.v_template))
        self.register_buffer("shapedirs", mix(model.shapedirs))
        self.register_buffer("lbs_weights", mix(model.lbs_weights))
        posedirs = getattr(model, "posedirs", None)
        if posedirs is not None:  # [P, V*3] -> [P, n*3]
            pd = posedirs.reshape(posedirs.shape[0], -1, 3).transpose(0, 1)  # [V, P, 3]
            posedirs = mix(pd).transpose(0, 1).reshape(posedirs.shape[0], -1).contiguous()
        self.register_buffer("posedirs", posedirs)

    def forward(self, **params) -> BodyState:
        state = self.keypoint_body(**params)
        betas = params["betas"]
        v = self.v_template + blend_shapes(betas, self.shapedirs)
        if self.posedirs is not None:
            full = torch.cat([params[n] for n in self.pose_names], dim=1).reshape(betas.shape[0], -1, 3)
            v = v + pose_correctives(axis_angle_to_matrix(full), self.posedirs)
        verts = skin_vertices(v, state.transforms, self.lbs_weights) + params["transl"][:, None]
        return BodyState(state.keypoints, state.joints, state.transforms, verts)


#: model -> {(layout, what, model's dtype): (the model's arrays it mixes, their versions, ContourBody)}: the reduced
#: bodies of the stage (the contour level's points, each rendered level's proxy) kept from call to call (building
#: one poses the landmarks' reduction and mixes the model's arrays, a cost paid per call before issue 24's speed
#: part: docs/benchmarks/defaults.md); rebuilt when one of those arrays is another tensor or was written in place
#: (its ``_version``)
_CONTOUR_BODIES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _mixed_arrays(model) -> tuple:
    names = ("v_template", "shapedirs", "posedirs", "lbs_weights", "J_regressor", "landmark_regressor")
    return tuple(a for a in (getattr(model, n, None) for n in names) if isinstance(a, torch.Tensor))


def cached_contour_body(model, layout: str, what: tuple, vertex_index: Callable) -> "ContourBody":
    """The :class:`ContourBody` of ``model`` and ``layout`` at the points ``vertex_index()`` names
    (``what``: their key, e.g. ``("proxy", faces)``), built once per model and kept while it lives."""
    key = (layout, what, str(model.dtype))
    arrays = _mixed_arrays(model)
    versions = tuple(None if a.is_inference() else a._version for a in arrays)  # inference tensors: no counter
    with _CONTOUR_LOCK:
        bodies = _CONTOUR_BODIES.setdefault(model, {})
        kept = bodies.get(key)
        if (
            kept is not None
            and len(kept[0]) == len(arrays)
            and all(a is b for a, b in zip(kept[0], arrays))
            and kept[1] == versions
        ):
            return kept[2]
        body = ContourBody(model, layout, vertex_index())
        bodies[key] = (arrays, versions, body)
        return body


def _window_points(ev: Evaluation, proxy) -> dict:
    """``{(problem, observation): uv [V, 2]}``: the (proxy's) vertices projected into each
    observation's window (window pixels), for the observations with a window; computed
    once per evaluation and shared by the contour terms."""
    cached = ev.extras.get("window_points")
    if cached is not None:
        return cached
    V = ev.body.vertices
    if proxy is not None:
        V = proxy(V)
    V = V.reshape(ev.P, ev.F, *V.shape[1:])
    R, t = ev.data["R"].to(V.dtype), ev.data["t"].to(V.dtype)
    out = {}
    for p, windows in enumerate(ev.data["windows"]):
        for o, w in enumerate(windows):
            if w is None:
                continue
            f, c = divmod(o, ev.C)
            out[(p, o)] = project_points(world_to_camera(V[p, f], R[p, f, c], t[p, f, c]), w.camera)
    ev.extras["window_points"] = out
    return out


class _ContourTerm(Term):
    """A contour-level term: ``observation_energy`` of each observation with a window, from
    the (proxy's) vertices projected into it (window pixels), summed per problem."""

    def __init__(self, proxy=None):
        self.proxy = proxy

    def observation_energy(self, uv: torch.Tensor, ev: Evaluation, p: int, o: int) -> torch.Tensor:  # pragma: no cover
        raise NotImplementedError

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        energies = [torch.zeros((), dtype=ev.keypoints_2d.dtype) for _ in range(ev.P)]
        for (p, o), uv in _window_points(ev, self.proxy).items():
            energies[p] = energies[p] + self.observation_energy(uv, ev, p, o)
        return torch.stack(energies)


class ContourInsideTerm(_ContourTerm):
    """The contour level's "body outside the mask" term: per observation with a window, the
    mean squared distance (window pixels) from the projected vertices to the mask
    (:func:`~silfit.silhouette.losses.outside_distance_energy`), summed per problem. Reads
    ``ev.data['windows']`` and ``ev.data['targets']`` (as :class:`SilhouetteTerm`)."""

    name = "contour_inside"

    def observation_energy(self, uv, ev, p, o):
        return outside_distance_energy(uv, ev.data["targets"][p][o].dt_out)


class ContourCoverTerm(_ContourTerm):
    """The contour level's "mask not covered" term: per observation with a window, the mean
    over the mask's outline points of the squared distance (window pixels) to the nearest
    projected vertex (:func:`~silfit.silhouette.losses.cover_energy`, with the target's robust
    profile ``MaskTarget.cover`` when it has one), summed per problem.
    Reads ``ev.data['windows']`` and ``ev.data['contours']`` (per problem, lists over its
    observations of outline points ``[B, 2]`` in window pixels, or ``None``)."""

    name = "contour_cover"

    def observation_energy(self, uv, ev, p, o):
        return cover_energy(uv, ev.data["contours"][p][o], ev.data["targets"][p][o].cover)


def fit_silhouette(
    model,
    init: dict,
    camera: Camera,
    mask: np.ndarray,
    keypoints: Optional[np.ndarray] = None,
    layout: str = "body25",
    config: Optional[SilhouetteFitConfig] = None,
    pose_prior=None,
    renderer=None,
    progress: bool = False,
    callback: Optional[Callable[[int, dict], None]] = None,
) -> SilhouetteFitResult:
    """Refine one subject's parameters against its person ``mask [H, W]`` (bool).

    ``init``: parameters (arrays ``[1, n]`` or ``[n]``) from the keypoint stage, in
    ``camera``'s frame. ``keypoints [K, 3]`` (x, y, confidence in image pixels) keep the
    keypoint term on; ``None`` fits the silhouette and priors alone. ``callback(step,
    info)`` is called every step with the level, energy and IoU.
    """
    return fit_silhouettes(
        model, [init], [camera], [mask], [keypoints], layout, config, pose_prior, renderer, progress, callback
    )[0]


def fit_silhouettes(
    model,
    inits: Sequence[dict],
    cameras: Sequence[Camera],
    masks: Sequence[np.ndarray],
    keypoints: Optional[Sequence[Optional[np.ndarray]]] = None,
    layout: str = "body25",
    config: Optional[SilhouetteFitConfig] = None,
    pose_prior=None,
    renderer=None,
    progress: bool = False,
    callback: Optional[Callable[[int, dict], None]] = None,
) -> List[SilhouetteFitResult]:
    """The silhouette stage for a batch of single images (one camera and mask each), as
    :func:`fit_silhouette` per subject; ``callback(step, info)`` gets ``info['subject']``."""
    keypoints = list(keypoints) if keypoints is not None else [None] * len(inits)
    if not (len(inits) == len(cameras) == len(masks) == len(keypoints)):
        raise ValueError(
            f"{len(inits)} starts, {len(cameras)} cameras, {len(masks)} masks, {len(keypoints)} keypoint sets"
        )
    problems = [Problem.single(kp, cam, mask) for kp, cam, mask in zip(keypoints, cameras, masks)]
    return fit_silhouette_problems(model, problems, inits, layout, config, pose_prior, renderer, progress, callback)


def fit_silhouette_problems(
    model,
    problems: Sequence[Problem],
    inits: Sequence[dict],
    layout: str = "body25",
    config: Optional[SilhouetteFitConfig] = None,
    pose_prior=None,
    renderer=None,
    progress: bool = False,
    callback: Optional[Callable[[int, dict], None]] = None,
    terms: Sequence[Term] = (),
    weights: Optional[dict] = None,
    data: Optional[dict] = None,
) -> List[SilhouetteFitResult]:
    """The silhouette stage on problems: bodies seen in ``F`` frames by ``C`` views
    (:class:`~silfit.fitting.problem.Problem`; every problem of a batch has the same
    ``F`` and ``C``). Each observation's ``mask [H, W]`` (bool, or ``None``: no silhouette
    term for it) is matched in its camera (extrinsics ``R, t`` from its view), its
    ``keypoints`` (a :class:`~silfit.io.keypoints.KeypointSet`, an array ``[K, 3]`` or
    ``None``) keep the keypoint term; all observations' terms are summed per problem.

    ``inits``: one dict per problem of the model's parameters by name, per-frame ones
    ``[F, w]`` (``[w]`` when ``F = 1``) and shared ones (``problem.shared``, e.g.
    ``betas``) ``[w]``; absent names start at zero (rest). ``terms``/``weights`` add
    named energy terms (e.g. temporal ones) with their weight in every level; ``data``
    (tensors with a leading problem axis ``[P, ...]``) is what they read from
    ``Evaluation.data``.

    Returns one :class:`SilhouetteFitResult` per problem (per-frame arrays ``[F, w]``)."""
    cfg = config or SilhouetteFitConfig()
    problems = list(problems)
    if len(inits) != len(problems):
        raise ValueError(f"{len(inits)} starts for {len(problems)} problems")
    if not problems:
        return []
    shapes = {(p.num_frames, p.num_views) for p in problems}
    if len(shapes) != 1:
        raise ValueError(f"problems of one batch must have the same frames and views, got {sorted(shapes)}")
    if len({tuple(p.shared) for p in problems}) != 1:
        raise ValueError("problems of one batch must share the same parameters across frames")
    if pose_prior is not None:  # an SMPL-X-layout model: the prior's marginal over its body joints
        pose_prior = body_prior_for(model, pose_prior)
    with torch_threads(cfg.threads):
        return _fit_problems(
            model,
            problems,
            list(inits),
            layout,
            cfg,
            pose_prior,
            renderer,
            progress,
            callback,
            tuple(terms),
            dict(weights or {}),
            dict(data or {}),
        )


def _keypoint_array(keypoints) -> Optional[np.ndarray]:
    """``[K, 3]`` (x, y, confidence) of an observation's keypoints, or ``None``."""
    if keypoints is None:
        return None
    if hasattr(keypoints, "xy") and hasattr(keypoints, "conf"):
        return np.concatenate([np.asarray(keypoints.xy, dtype=np.float64), np.asarray(keypoints.conf)[:, None]], 1)
    arr = np.asarray(keypoints, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"keypoints of an observation have shape {arr.shape}, expected [K, 3]")
    return arr


def _keypoint_data(grids, dtype) -> tuple:
    """``target [P, F, C, K, 2]`` and ``weights [P, F, C, K]`` (each observation's
    confidences normalised to sum 1; zero where it has none) of the problems' grids."""
    arrays = [[[_keypoint_array(o.keypoints) for o in row] for row in grid] for grid in grids]
    counts = {a.shape[0] for g in arrays for row in g for a in row if a is not None}
    if len(counts) > 1:
        raise ValueError(f"observations of one batch have different keypoint counts {sorted(counts)}")
    K = counts.pop() if counts else 1
    target = torch.zeros((len(grids), len(grids[0]), len(grids[0][0]), K, 2), dtype=dtype)
    weights = torch.zeros(target.shape[:-1], dtype=dtype)
    for p, g in enumerate(arrays):
        for f, row in enumerate(g):
            for c, a in enumerate(row):
                if a is None:
                    continue
                a = torch.as_tensor(a, dtype=dtype)
                conf = a[:, 2].clamp(min=0)  # normalised in the model's dtype
                target[p, f, c] = a[:, :2]
                if bool((conf > 0).any()):
                    weights[p, f, c] = conf / conf.sum()
    return target, weights, any(a is not None for g in arrays for row in g for a in row)


def _observation_window(
    mask,
    uv: np.ndarray,
    camera: Camera,
    resolution: int,
    margin: float,
    multiple: int = 1,
    truncation_aware: bool = True,
    cover: Optional[CoverProfile] = None,
    known=None,
):
    """``(window, target)`` of an observation with a mask, or ``(None, scale)`` without one
    (the pixels-to-window scale a window around the projected body would have)."""
    if mask is not None:
        window = choose_window(mask if known is None else mask & known, uv, camera, resolution, margin, multiple)
        return window, window_target(mask, window, truncation_aware=truncation_aware, cover=cover, known=known)[0]
    extent = float((uv.max(0) - uv.min(0)).max()) * (1 + 2 * margin) + 1.0
    return None, resolution / extent


def _checked_masks(grids) -> tuple:
    """``(masks, known)``: per problem, frame and view, the observation's mask (bool ``[H, W]`` or ``None``) and
    its known pixels (or ``None``); a mask not of its camera's size, an empty one, known pixels not of the mask's
    size, or no mask at all raise ``ValueError``."""
    masks = [[[None if o.mask is None else np.asarray(o.mask, dtype=bool) for o in row] for row in g] for g in grids]
    known = [
        [
            [
                None if o.mask is None or getattr(o, "known", None) is None else np.asarray(o.known, dtype=bool)
                for o in row
            ]
            for row in g
        ]
        for g in grids
    ]
    for p, g in enumerate(grids):
        for f, row in enumerate(g):
            for c, o in enumerate(row):
                m, cam = masks[p][f][c], o.view.camera
                if m is None:
                    continue
                if m.shape != (cam.height, cam.width):
                    raise ValueError(f"mask is {m.shape[1]}x{m.shape[0]} pixels, the camera {cam.width}x{cam.height}")
                if not m.any():
                    raise ValueError(f"problem {p}, frame {f}, view {c}: the mask is empty")
                if known[p][f][c] is not None and known[p][f][c].shape != m.shape:
                    raise ValueError(
                        f"problem {p}, frame {f}, view {c}: known is {known[p][f][c].shape[1]}x"
                        f"{known[p][f][c].shape[0]} pixels, the mask {m.shape[1]}x{m.shape[0]}"
                    )
    if not any(m is not None for g in masks for row in g for m in row):
        raise ValueError("the silhouette stage needs at least one mask")
    return masks, known


def _start_state(inits, params_layout: ParameterLayout, frames: int, dtype) -> dict:
    """The problems' starting parameters: shared ``[P, w]``, per-frame ``[P, F, w]`` (absent names: zero)."""
    start = {}
    for n, w in params_layout.sizes.items():
        rows = []
        for init in inits:
            v = init.get(n)
            v = (
                np.zeros(w if params_layout.is_shared(n) else (frames, w))
                if v is None
                else np.asarray(v, dtype=np.float64)
            )
            rows.append(
                torch.as_tensor(v, dtype=dtype).reshape(w)
                if params_layout.is_shared(n)
                else torch.as_tensor(v, dtype=dtype).reshape(frames, w)
            )
        start[n] = torch.stack(rows)
    return start


class _LevelRenders:
    """Each rendered level's ``(renderer, proxy map, batch renderer, body)`` by its proxy's face count (``None``:
    ``proxy_faces``), built on first use; a caller's ``renderer`` renders the body's own vertices at every level."""

    def __init__(self, model, layout: str, cfg: SilhouetteFitConfig, body, renderer, smpl_layout: bool):
        self.model, self.layout, self.cfg, self.body, self.smpl_layout = model, layout, cfg, body, smpl_layout
        self.built = {} if renderer is None else {"caller": (renderer, None, None, body)}

    def __call__(self, n_faces):
        """The level's ``(renderer, proxy map, batch renderer, body)``."""
        cfg, model = self.cfg, self.model
        if self.built.get("caller"):
            return self.built["caller"]
        if n_faces is None or not cfg.proxy_faces:
            n_faces = cfg.proxy_faces
        if n_faces not in self.built:
            level_proxy, faces, level_body = None, model.faces, self.body
            if n_faces:
                level_proxy = get_proxy(model.v_template, model.faces, int(n_faces))
                faces = level_proxy.faces
            level_batch = None
            if cfg.render.batch_render:
                level_batch = get_batch_renderer(faces)
            if level_proxy is not None and cfg.render.proxy_body and self.smpl_layout:
                level_body = cached_contour_body(model, self.layout, ("proxy", int(n_faces)), lambda: level_proxy)
                level_proxy = None
            self.built[n_faces] = (get_silhouette_renderer(faces), level_proxy, level_batch, level_body)
        return self.built[n_faces]


class _SilhouetteRun:
    """One :func:`_fit_problems` run's hooks and records: per level (:meth:`prepare_level`) each problem's windows,
    targets and contour points around the body as it is, the rendered levels' renderer; per rendered step each
    problem's history, divergence check and best parameters so far (the lowest energy of the level: levels of
    other resolutions do not compare); :meth:`finish_level` takes the contour level's end as the best so far and
    restarts the next level from a rendered level's best; :meth:`results` ends it."""

    def __init__(
        self,
        model,
        cfg: SilhouetteFitConfig,
        grids,
        masks,
        known,
        params: dict,
        params_layout,
        views: dict,
        data: dict,
        silhouette: SilhouetteTerm,
        level_render: _LevelRenders,
        contour_body,
        callback,
        bar,
    ):
        self.model, self.cfg, self.grids, self.masks, self.known = model, cfg, grids, masks, known
        self.params, self.params_layout, self.views, self.data = params, params_layout, views, data
        self.silhouette, self.level_render, self.contour_body = silhouette, level_render, contour_body
        self.callback, self.bar = callback, bar
        P = self.P = len(grids)
        self.F, self.C = len(grids[0]), len(grids[0][0])  # frames and views (every problem's)
        self.history = [{k: [] for k in ("level", "energy", "silhouette", "keypoints", "iou")} for _ in range(P)]
        self.warnings: list = [[] for _ in range(P)]
        self.best_params = [{k: v[p].detach().clone() for k, v in params.items()} for p in range(P)]
        self.best_iou = [float("nan")] * P
        self.best_obs_iou: list = [[] for _ in range(P)]
        self.best_terms: list = [{} for _ in range(P)]
        self.best_iou_seen = [-1.0] * P
        self.best_energy = [math.inf] * P
        self.steps = [0] * P
        self.contour_steps = [0] * P
        self.failed = [False] * P
        self.level, self.resolution, self.stepped_ious = None, None, {}

    def prepare_level(self, level, stage):
        """Each problem's windows and targets at the level's resolution (around the body as it
        is now); the rows that run (those that have not failed) and the level's hooks."""
        cfg, data, dtype, P, F, C = self.cfg, self.data, self.model.dtype, self.P, self.F, self.C
        resolution = int(stage.options["resolution"])
        with torch.no_grad():
            verts = self.model(**self.params_layout.rows({k: v.detach() for k, v in self.params.items()})).vertices
            verts = verts.reshape(P, F, *verts.shape[1:])
        scale = torch.ones(P, F, C, dtype=dtype)
        for p in range(P):
            if self.failed[p]:
                continue
            windows, targets, contours = [], [], []
            for f in range(F):
                for c in range(C):
                    R, t = self.views["R"][p, f, c].to(verts.dtype), self.views["t"][p, f, c].to(verts.dtype)
                    cam_pts = world_to_camera(verts[p, f], R, t)
                    cam = self.grids[p][f][c].view.camera
                    window, target = _observation_window(
                        self.masks[p][f][c],
                        project_points(cam_pts, cam).numpy(),
                        cam,
                        resolution,
                        cfg.margin,
                        cfg.window_multiple,
                        cfg.mask.truncation_aware,
                        cfg.cover_profile(resolution, getattr(self.grids[p][f][c], "cover_inner", None)),
                        self.known[p][f][c],
                    )
                    windows.append(window)
                    targets.append(target if window is not None else None)
                    scale[p, f, c] = window.scale if window is not None else target
                    if window is not None and stage.optimiser == "lbfgs":
                        seen = None if target.valid is None else target.valid.numpy() > 0.5
                        pts = contour_points(target.mask.numpy() > 0.5, cfg.contour_points, seen)
                        contours.append(torch.as_tensor(pts, dtype=dtype))
                    else:
                        contours.append(None)
            data["windows"][p], data["targets"][p], data["contours"][p] = windows, targets, contours
        data["scale"] = scale
        data["trust_px"] = torch.full((P,), float(cfg.trust.fraction) * resolution, dtype=dtype)
        rows = torch.as_tensor([p for p in range(P) if not self.failed[p]], dtype=torch.long)
        if stage.optimiser == "lbfgs":  # the contour level: deterministic, no rendering
            return {"rows": rows, "body": self.contour_body}
        sil = self.silhouette
        sil.renderer, sil.proxy, sil.batch_renderer, level_body = self.level_render(stage.options.get("proxy_faces"))
        self.best_energy[:] = [math.inf] * P  # energies of different resolutions are not comparable
        self.level, self.resolution, self.stepped_ious = level, resolution, {}
        return {
            "rows": rows,
            "body": level_body,
            "before_step": self.before_step,
            "on_step": self.on_step,
            "after_step": self.after_step,
        }

    def before_step(self, i, rows):
        """Each problem's renderer seed of this step (its own step count)."""
        seed = self.cfg.render.seed
        self.data["seeds"] = [None if seed is None else int(seed) * 100003 + self.steps[p] for p in range(self.P)]

    def on_step(self, i, rows, total, parts, ev):
        """Per row: stop on divergence (keeping the best so far), else record the step."""
        ious, obs_ious = ev.extras["iou"], ev.extras["iou_observations"]
        go = []
        for j, p in enumerate(rows.tolist()):
            e_value, iou = float(total[j].detach()), ious[j]
            if not math.isfinite(e_value) or iou < self.best_iou_seen[p] - self.cfg.iou_collapse:
                why = "non-finite energy" if not math.isfinite(e_value) else f"IoU collapsed to {iou:.3f}"
                self.warnings[p].append(f"step {self.steps[p]}: {why}; kept the best parameters so far")
                self.failed[p] = True
                go.append(False)
                continue
            h = self.history[p]
            term_values = {k: float(v[j].detach()) for k, v in parts.items()}
            for key, value in (
                ("level", self.level),
                ("energy", e_value),
                ("silhouette", term_values.get("silhouette", 0.0)),
                ("keypoints", term_values.get("keypoints", 0.0)),
                ("iou", iou),
            ):
                h[key].append(value)
            if e_value < self.best_energy[p]:
                self.best_energy[p], self.best_iou[p], self.best_terms[p] = e_value, iou, term_values
                self.best_obs_iou[p] = obs_ious[j]
                self.best_params[p] = {k: v[p].detach().clone() for k, v in self.params.items()}
            self.best_iou_seen[p] = max(self.best_iou_seen[p], iou)
            if self.callback is not None:
                self.callback(self.steps[p], {"level": self.level, "energy": e_value, "iou": iou, "subject": p})
            self.stepped_ious[p] = iou
            go.append(True)
        return go

    def after_step(self, i, stepped, totals):
        """Count the step of the rows that took it (the progress bar too)."""
        for p in stepped.tolist():
            self.steps[p] += 1
            self.bar.update(1)
        self.bar.set_postfix(
            iou=f"{np.mean([self.stepped_ious[p] for p in stepped.tolist()]):.3f}", res=self.resolution
        )
        self.stepped_ious.clear()

    def finish_level(self, level, stage, run):
        """After the contour level its end is each problem's best so far; after a rendered level the next level
        restarts from the best parameters found so far."""
        if stage.optimiser == "lbfgs":
            for p in range(self.P):
                self.contour_steps[p] += int(run.iterations[p])
                if not self.failed[p]:
                    self.best_params[p] = {k: v[p].detach().clone() for k, v in self.params.items()}
            return
        # The next level restarts from the best parameters found so far.
        with torch.no_grad():
            for p in range(self.P):
                for k in self.params:
                    self.params[k][p].copy_(self.best_params[p][k])

    def results(self, seconds: float) -> List[SilhouetteFitResult]:
        """One :class:`SilhouetteFitResult` per problem: its best parameters (per-frame ``[F, w]``, shared ``[1, w]``)."""
        config, sizes, layout = self.cfg.to_dict(), self.params_layout.sizes, self.params_layout
        F, C = self.F, self.C
        results = []
        for p in range(self.P):
            final = {}
            for k, v in self.best_params[p].items():
                final[k] = (
                    v.detach().cpu().numpy().astype(np.float32).reshape(-1 if layout.is_shared(k) else F, sizes[k])
                )
                if layout.is_shared(k):
                    final[k] = final[k].reshape(1, -1)
            h = self.history[p]
            obs = self.best_obs_iou[p] or [float("nan")] * (F * C)
            results.append(
                SilhouetteFitResult(
                    parameters=final,
                    history=h,
                    iou_start=h["iou"][0] if h["iou"] else float("nan"),
                    iou_end=float(self.best_iou[p]) if h["iou"] else float("nan"),
                    seconds=seconds,
                    steps=self.steps[p],
                    warnings=self.warnings[p],
                    terms=self.best_terms[p],
                    config=config,
                    contour_iterations=self.contour_steps[p],
                    ious=[list(obs[f * C : (f + 1) * C]) for f in range(F)],
                    failed=bool(self.failed[p]),
                )
            )
        return results


def _fit_problems(
    model,
    problems,
    inits,
    layout,
    cfg,
    pose_prior,
    renderer,
    progress,
    callback,
    extra_terms,
    extra_weights,
    extra_data,
):
    dtype = model.dtype
    P, F = len(problems), problems[0].num_frames
    grids = [p.grid() for p in problems]
    masks, known = _checked_masks(grids)
    params_layout = ParameterLayout.of(model, problems[0].shared, F)
    # State: shared [P, w], per-frame [P, F, w].
    start = _start_state(inits, params_layout, F, dtype)
    free_names = tuple(n for n in cfg.optimise if n in params_layout.sizes)
    params = {k: v.clone().requires_grad_(k in free_names) for k, v in start.items()}
    prior = load_pose_prior(pose_prior, dtype=dtype) if not isinstance(pose_prior, torch.nn.Module) else pose_prior
    body = MeshBody(model, layout)
    smpl_layout = getattr(model, "kind", "smpl") == "smpl"
    contour_body, contour_points_map = _contour_evaluators(model, layout, cfg, body, smpl_layout)
    silhouette = SilhouetteTerm(
        None, cfg.render.spp, cfg.render.edge_spp, edge_density=cfg.render.edge_density
    )  # each rendered level sets its renderer (_LevelRenders)
    energy = _silhouette_energy(silhouette, prior, cfg, contour_points_map, extra_terms)
    target_xy, target_w, any_keypoints = _keypoint_data(grids, dtype)
    stages = _weighted_stages(cfg, free_names, extra_weights, any_keypoints)
    check_stages(stages, energy, params_layout)
    views = stack_views(problems, dtype)
    data = _stage_data(
        problems, extra_data, (target_xy, target_w, any_keypoints), start, views, cfg, body, params_layout
    )
    t0 = time.perf_counter()
    bar = tqdm(total=int(sum(cfg.iterations)) * P, desc="silhouette", disable=not progress, leave=False)
    hooks = _SilhouetteRun(
        model,
        cfg,
        grids,
        masks,
        known,
        params,
        params_layout,
        views,
        data,
        silhouette,
        _LevelRenders(model, layout, cfg, body, renderer, smpl_layout),
        contour_body,
        callback,
        bar,
    )
    run_schedule(
        stages,
        params,
        params_layout,
        energy,
        body,
        views,
        data,
        before_stage=hooks.prepare_level,
        after_stage=hooks.finish_level,
    )
    bar.close()
    return hooks.results((time.perf_counter() - t0) / max(P, 1))


def _contour_evaluators(model, layout, cfg, body, smpl_layout: bool) -> tuple:
    """``(contour_body, contour_points_map)``: the contour level's evaluator (``body``, or one of the model's contour
    vertices only) and its vertices' map (the proxy's vertices where the full body is read at them, else ``None``)."""
    contour_body, contour_points_map = body, None  # the contour level's evaluator and its vertices' map
    if cfg.contour_iterations and cfg.contour_vertices and smpl_layout:
        contour_body = cached_contour_body(
            model,
            layout,
            ("vertices", int(cfg.contour_vertices)),
            lambda: contour_vertex_index(model, cfg.contour_vertices),
        )
    elif cfg.proxy_faces:  # the full body, its points read at the proxy's vertices
        contour_points_map = get_proxy(model.v_template, model.faces, int(cfg.proxy_faces))
    return contour_body, contour_points_map


def _silhouette_energy(silhouette, prior, cfg, contour_points_map, extra_terms) -> Energy:
    """The silhouette stage's energy: the ``silhouette`` term, the keypoints, the priors, the contour terms (read at
    ``contour_points_map``), the trust region, the shape's bound and the caller's ``extra_terms``."""
    return Energy(
        [
            silhouette,
            KeypointTerm("keypoints", cfg.kp_sigma),
            PriorTerm("pose", prior, "body_pose"),
            PriorTerm("limits", limit_violation, "body_pose"),
            PriorTerm("angle", angle_prior, "body_pose"),
            PriorTerm("shape", shape_prior, "betas"),
            StayTerm("body_pose"),
            ContourInsideTerm(contour_points_map),
            ContourCoverTerm(contour_points_map),
            KeypointTrustTerm(),
            PriorTerm("beta_bound", lambda b: beta_bound(b, cfg.max_abs_beta), "betas"),
            *extra_terms,
        ]
    )


def _weighted_stages(cfg, free_names: tuple, extra_weights: dict, any_keypoints: bool) -> tuple:
    """``cfg``'s stages freeing ``free_names``, with the caller's ``extra_weights`` (and no keypoint terms where no
    problem has keypoints)."""
    return tuple(
        Stage(
            s.name,
            free_names,
            {**s.weights, **extra_weights, **({} if any_keypoints else {"keypoints": 0.0, "keypoint_trust": 0.0})},
            s.iterations,
            s.optimiser,
            s.options,
        )
        for s in cfg.stages()
    )


def _stage_data(
    problems, extra_data: dict, keypoints: tuple, start: dict, views: dict, cfg, body, params_layout
) -> dict:
    """The silhouette stage's data: the caller's ``extra_data`` (checked: a leading problem axis), the ``keypoints``
    (:func:`_keypoint_data`'s ``(target, weights, any)``), the start's body pose, the views' extrinsics, the per-row
    slots the levels fill, and the trust region around the start's keypoints (``trust.from_start``)."""
    P, F, dtype = len(problems), problems[0].num_frames, start["body_pose"].dtype
    target_xy, target_w, any_keypoints = keypoints
    for k, v in extra_data.items():
        if isinstance(v, torch.Tensor) and v.shape[:1] != (P,):
            raise ValueError(f"data[{k!r}] has shape {tuple(v.shape)}; expected a leading problem axis of {P}")
    data = {
        **extra_data,
        "target": target_xy,
        "weights": target_w,
        "scale": torch.ones(P, F, problems[0].num_views, dtype=dtype),
        "start_body_pose": start["body_pose"],
        "R": views["R"],
        "t": views["t"],
        "windows": PerRow([None] * P),
        "targets": PerRow([None] * P),
        "seeds": PerRow([None] * P),
        "contours": PerRow([None] * P),
        "trust_px": torch.zeros(P, dtype=dtype),
    }
    if cfg.trust.from_start and any_keypoints:  # the trust region around the keypoint stage's fit (issue 55)
        with torch.no_grad():
            start_2d = evaluate(body, params_layout, start, views, data).keypoints_2d
        data.update(
            trust_data(
                target_xy, target_w, start_2d, cfg.trust.ratio, cfg.trust.median, unit_share=cfg.trust.unit_median
            )
        )
    return data
