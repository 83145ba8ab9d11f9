"""The silhouette stage: refine a keypoint fit so the body's rendered silhouette matches
the person's mask.

Energy (per step, one subject)::

    E = w_sil * E_sil(S) + w_kp * E_kp + w_pose * prior(pose) + w_limits * limits(pose)
        + w_angle * angle(pose) + w_shape * |betas|^2 + w_stay * |theta - theta_kp|^2

* ``S`` is the Mitsuba silhouette (projective sampling, so the gradient includes the
  visibility-edge term) rendered in a *window* around the person (region of interest:
  the union of the mask's box and the body's projection, plus a margin) at a fixed
  number of pixels, so the cost follows the chosen resolution and not the image's.
* ``E_sil`` is the two-sided distance-transform energy of :mod:`silfit.silhouette.losses`
  in window pixels, normalised by the mask's area (an average distance in pixels).
* ``E_kp`` is the confidence-weighted Geman-McClure reprojection error of the keypoints
  in window pixels, averaged over keypoints, so the silhouette cannot drag limbs away
  from where the detector saw them.
* Priors as in the keypoint stage keep the pose plausible; ``w_stay`` (off by default:
  it cost accuracy on the synthetic set) can add a pull toward the keypoint-stage pose.

The renderer's gradients are stochastic (Monte Carlo pixels and edges), so the
optimiser is Adam with per-parameter learning rates and a cosine decay per level,
coarse to fine (``resolutions``); a level stops early on an energy plateau. Steps with
non-finite energy, or whose IoU collapses, are detected and the best parameters so far
are kept (``warnings`` in the result).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np
import torch

from ..camera import Camera, project_points
from ..keypoints import model_keypoints
from ..priors import angle_prior, limit_violation, load_pose_prior, shape_prior
from ..silhouette.losses import MaskTarget, silhouette_energy, soft_iou
from .losses import gmof
from .threads import torch_threads

__all__ = ["SilhouetteFitConfig", "SilhouetteFitResult", "choose_window", "fit_silhouette", "window_target"]

PARAMS = ("betas", "body_pose", "global_orient", "transl")


@dataclass
class SilhouetteFitConfig:
    """Settings of the silhouette stage (defaults tuned on the synthetic set)."""

    resolutions: tuple = (128, 256)  # window's longer side in pixels, per level
    iterations: tuple = (60, 50)  # Adam steps per level (upper bounds: plateaus stop earlier)
    spp: int = 4  # primal samples per pixel
    edge_spp: int = 1  # visibility-edge samples per pixel (projective integrator's sppp)
    margin: float = 0.12  # window margin, fraction of the box on each side
    lr: dict = field(
        default_factory=lambda: {"betas": 0.1, "body_pose": 0.03, "global_orient": 0.02, "transl": 0.01}
    )
    w_silhouette: float = 1.0
    w_keypoints: float = 0.02
    kp_sigma: float = 20.0  # Geman-McClure scale, window pixels
    w_pose: float = 0.002
    w_limits: float = 1.0
    w_angle: float = 0.001
    w_shape: float = 0.005
    w_stay: float = 0.0
    warmup: int = 5  # steps of linear learning-rate warm-up per level
    plateau_window: int = 12  # steps compared for the plateau test
    plateau_rtol: float = 0.003  # relative energy improvement below which a level stops
    iou_collapse: float = 0.15  # IoU drop (vs best) that counts as divergence
    optimise: tuple = PARAMS
    seed: Optional[int] = 0  # base seed of the renderer's sampling (None: fresh seeds)
    threads: Optional[int] = 1  # torch threads during the stage (see silfit.fitting.threads)


@dataclass
class SilhouetteFitResult:
    """Refined SMPL parameters (numpy, batch of one) and the stage's diagnostics."""

    betas: np.ndarray
    body_pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray
    history: dict  # per step: level, energy, silhouette, keypoints, iou (lists)
    iou_start: float  # soft IoU in the window, first step
    iou_end: float  # soft IoU in the window at the kept (lowest-energy) step
    seconds: float
    steps: int
    warnings: list

    def params(self) -> dict:
        return {name: getattr(self, name) for name in PARAMS}


def choose_window(mask: np.ndarray, uv: np.ndarray, camera: Camera, resolution: int, margin: float):
    """A :class:`renderers.silhouette.RoiWindow` covering the mask's box and the projected
    body ``uv [N, 2]`` with ``margin``, rendered with ``resolution`` pixels along its longer
    side (aspect ratio kept)."""
    from renderers.silhouette import RoiWindow

    ys, xs = np.nonzero(mask)
    lo = np.minimum([xs.min() - 0.5, ys.min() - 0.5], uv.min(0) - 0.5)
    hi = np.maximum([xs.max() + 0.5, ys.max() + 0.5], uv.max(0) + 0.5)
    lo, hi = lo - margin * (hi - lo), hi + margin * (hi - lo)
    extent = hi - lo
    scale = resolution / float(extent.max())
    width, height = (max(8, int(round(e * scale))) for e in extent)
    x0, y0 = (float(c) for c in (lo + hi) / 2 - np.array([width, height]) / scale / 2)
    return RoiWindow(x0, y0, scale, camera.crop(x0, y0, width, height, scale))


def window_target(mask: np.ndarray, window, supersample: int = 4) -> tuple[MaskTarget, np.ndarray]:
    """The mask resampled into a ``RoiWindow``: ``(MaskTarget of the binarised coverage, coverage)``.

    Coverage is the fraction of each window pixel inside the mask (supersampled, then
    area-averaged); pixels outside the image are background. Distances are in window pixels.
    """
    import cv2

    cam = window.camera
    ss = int(supersample)
    s = window.scale * ss
    # Output (supersampled) pixel centre i -> image pixel-centre coordinate x0 + (i + 0.5)/s - 0.5.
    M = np.array([[1.0 / s, 0.0, window.x0 + 0.5 / s - 0.5], [0.0, 1.0 / s, window.y0 + 0.5 / s - 0.5]])
    fine = cv2.warpAffine(
        mask.astype(np.float32), M, (cam.width * ss, cam.height * ss),
        flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0,
    )  # fmt: skip
    coverage = cv2.resize(fine, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
    binary = coverage > 0.5
    if not binary.any():
        raise ValueError("the mask vanishes at the silhouette stage's resolution; raise the resolution")
    return MaskTarget.from_mask(binary), coverage


def _learning_rate_factor(step: int, steps: int, warmup: int) -> float:
    """Linear warm-up over ``warmup`` steps (Adam's first steps are full-size sign steps),
    then a cosine decay to 10 % at the end of the level."""
    ramp = min(1.0, (step + 1) / max(warmup, 1))
    return ramp * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * step / max(steps, 1))))


class _Plateau:
    """Stops a level when the running mean energy stops improving by ``rtol``."""

    def __init__(self, window: int, rtol: float):
        self.window, self.rtol, self.values = window, rtol, []

    def update(self, value: float) -> bool:
        self.values.append(value)
        n = self.window
        if len(self.values) < 2 * n:
            return False
        before = float(np.mean(self.values[-2 * n : -n]))
        now = float(np.mean(self.values[-n:]))
        return (before - now) < self.rtol * abs(before)


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
    progress: bool = True,
    callback: Optional[Callable[[int, dict], None]] = None,
) -> SilhouetteFitResult:
    """Refine one subject's SMPL parameters against its person ``mask [H, W]`` (bool).

    ``init``: SMPL parameters (arrays ``[1, n]`` or ``[n]``) from the keypoint stage,
    in ``camera``'s frame. ``keypoints [K, 3]`` (x, y, confidence in image pixels) keep
    the keypoint term on; ``None`` fits the silhouette and priors alone. ``callback(step,
    info)`` is called every step with the level, energy and IoU.
    """
    cfg = config or SilhouetteFitConfig()
    with torch_threads(cfg.threads):
        return _fit_silhouette(model, init, camera, mask, keypoints, layout, cfg, pose_prior, renderer, progress, callback)


def _fit_silhouette(model, init, camera, mask, keypoints, layout, cfg, pose_prior, renderer, progress, callback):
    from renderers.silhouette import get_silhouette_renderer
    from tqdm.auto import tqdm

    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (camera.height, camera.width):
        raise ValueError(f"mask is {mask.shape[1]}x{mask.shape[0]} pixels, the camera {camera.width}x{camera.height}")
    dtype = model.dtype
    start = {k: torch.as_tensor(np.asarray(init[k]), dtype=dtype).reshape(1, -1) for k in PARAMS}
    params = {k: v.clone().requires_grad_(k in cfg.optimise) for k, v in start.items()}
    optimiser = torch.optim.Adam([{"params": [params[k]], "lr": cfg.lr[k]} for k in PARAMS if k in cfg.optimise])
    base_lrs = [g["lr"] for g in optimiser.param_groups]
    prior = load_pose_prior(pose_prior, dtype=dtype) if not isinstance(pose_prior, torch.nn.Module) else pose_prior
    renderer = renderer or get_silhouette_renderer(model.faces)
    use_keypoints = keypoints is not None
    if use_keypoints:
        kp = torch.as_tensor(np.asarray(keypoints, dtype=np.float64), dtype=dtype)
        kp_xy, kp_conf = kp[:, :2], kp[:, 2].clamp(min=0)
        use_keypoints = bool((kp_conf > 0).any())

    history = {k: [] for k in ("level", "energy", "silhouette", "keypoints", "iou")}
    warnings: list = []
    best = {"energy": math.inf, "iou": float("nan"), "params": {k: v.detach().clone() for k, v in params.items()}}
    best_iou_seen = -1.0
    t0 = time.perf_counter()
    step = 0
    total_steps = int(sum(cfg.iterations))
    bar = tqdm(total=total_steps, desc="silhouette", disable=not progress, leave=False)
    for level, (resolution, iters) in enumerate(zip(cfg.resolutions, cfg.iterations)):
        with torch.no_grad():
            verts = model(**params).vertices[0]
            uv = project_points(verts, camera).numpy()
        window = choose_window(mask, uv, camera, int(resolution), cfg.margin)
        target, _ = window_target(mask, window)
        to_window = window.scale
        plateau = _Plateau(cfg.plateau_window, cfg.plateau_rtol)
        best["energy"] = math.inf  # energies of different resolutions are not comparable
        for i in range(int(iters)):
            schedule = _learning_rate_factor(i, int(iters), cfg.warmup)
            for g, lr0 in zip(optimiser.param_groups, base_lrs):
                g["lr"] = lr0 * schedule
            out = model(**params)
            seed = None if cfg.seed is None else int(cfg.seed) * 100003 + step
            sil = renderer(out.vertices[0], window.camera, spp=cfg.spp, edge_spp=cfg.edge_spp, seed=seed)
            e_sil = silhouette_energy(sil, target)
            energy = cfg.w_silhouette * e_sil
            e_kp = torch.zeros((), dtype=dtype)
            if use_keypoints:  # from the same posed body as the silhouette
                residual = (project_points(model_keypoints(model, out, layout)[0], camera) - kp_xy) * to_window
                e_kp = (kp_conf * gmof(residual, cfg.kp_sigma)).sum() / kp_conf.sum()
                energy = energy + cfg.w_keypoints * e_kp
            pose = params["body_pose"]
            energy = energy + cfg.w_pose * prior(pose).sum() + cfg.w_limits * limit_violation(pose).sum()
            energy = energy + cfg.w_angle * angle_prior(pose).sum() + cfg.w_shape * shape_prior(params["betas"]).sum()
            energy = energy + cfg.w_stay * (pose - start["body_pose"]).square().sum()
            with torch.no_grad():
                iou = float(soft_iou(sil.detach(), target.mask))
            e_value = float(energy.detach())
            if not math.isfinite(e_value) or iou < best_iou_seen - cfg.iou_collapse:
                warnings.append(
                    f"step {step}: {'non-finite energy' if not math.isfinite(e_value) else f'IoU collapsed to {iou:.3f}'};"
                    " kept the best parameters so far"
                )
                break
            for key, value in (("level", level), ("energy", e_value), ("silhouette", float(e_sil.detach())),
                               ("keypoints", float(e_kp.detach())), ("iou", iou)):  # fmt: skip
                history[key].append(value)
            if e_value < best["energy"]:
                best = {"energy": e_value, "iou": iou, "params": {k: v.detach().clone() for k, v in params.items()}}
            best_iou_seen = max(best_iou_seen, iou)
            if callback is not None:
                callback(step, {"level": level, "energy": e_value, "iou": iou})
            optimiser.zero_grad(set_to_none=True)
            energy.backward()
            optimiser.step()
            step += 1
            bar.update(1)
            bar.set_postfix(iou=f"{iou:.3f}", res=resolution)
            if plateau.update(e_value):
                break
        if warnings:
            break
        # The next level restarts from the best parameters found so far.
        with torch.no_grad():
            for k in params:
                params[k].copy_(best["params"][k])
    bar.close()
    final = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in best["params"].items()}
    return SilhouetteFitResult(
        **final,
        history=history,
        iou_start=history["iou"][0] if history["iou"] else float("nan"),
        iou_end=float(best["iou"]) if history["iou"] else float("nan"),
        seconds=time.perf_counter() - t0,
        steps=step,
        warnings=warnings,
    )
