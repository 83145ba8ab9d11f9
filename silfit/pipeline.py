"""The whole fit of one image: keypoint stage, then silhouette stage; results in memory
(:func:`fit`) and on disk (:func:`save_fit`).

Output folder written by :func:`save_fit` (and ``silfit fit``)::

    params.npz, params.json    final SMPL parameters (betas, body_pose, global_orient, transl),
                               camera_intrinsics, image_size, vertices, joints, keypoints_2d
    mesh.obj                   the posed body in camera coordinates (OpenCV axes: x right, y down,
                               z forward, metres, the model's vertex order)
    mesh.glb, mesh.ply         with ``exports``: the body upright (x right, y up, z toward the
                               viewer), normals, the camera in the glTF (silfit.outputs.export)
    overlay.png                the final body over the image (or a grey canvas) + keypoints
    silhouette.png             final silhouette vs the mask (white: both, red: body only,
                               blue: mask only)            [with a mask]
    iou_curve.png              IoU and energy per silhouette step   [with a mask]
    metrics.json               timings per stage, reprojection error, IoU before/after, warnings
    stages/keypoints/          the keypoint stage's params.npz, params.json and overlay.png

Everything is written into a temporary folder beside the target and moved into place at
the end, so a failed run leaves nothing half-written.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import List, Optional, Sequence, Union

import numpy as np
import torch

from .camera import Camera, project_points
from .fitting.keypoint_stage import KeypointFitConfig, KeypointFitter, prepare_keypoints
from .fitting.result import KeypointFitResult
from .fitting.silhouette_stage import SilhouetteFitConfig, SilhouetteFitResult, fit_silhouettes
from .keypoints import KeypointSet, model_keypoints
from .outfolder import atomic_folder
from .plausibility import ambiguity_warnings, check_keypoints, fit_warnings, mask_warnings
from .eval.metrics import mask_iou
from .silhouette.masks import validate_mask

__all__ = ["FitResult", "fit", "refine", "refine_batch", "save_fit", "body_mask"]


@dataclass
class FitResult:
    """One image's fit: the keypoint stage's result, the silhouette stage's (if a mask was
    given), and the final parameters, mesh and metrics (numpy, no batch dimension)."""

    camera: Camera
    layout: str
    keypoint: KeypointFitResult
    silhouette: Optional[SilhouetteFitResult]
    params: dict
    vertices: np.ndarray
    joints: np.ndarray
    keypoints_2d: np.ndarray
    metrics: dict = field(default_factory=dict)
    #: rendered body masks ``[H, W]`` (bool) of the keypoint stage and of the final body,
    #: when a silhouette was fitted
    masks: dict = field(default_factory=dict)

    @property
    def final(self) -> KeypointFitResult:
        """The final parameters in the keypoint result's form (for saving and loading)."""
        arr = {k: np.asarray(v, dtype=np.float32).reshape(1, -1) for k, v in self.params.items()}  # [1, w] (one image)
        smpl = {k: v for k, v in arr.items() if k in ("betas", "body_pose", "global_orient", "transl")}
        return replace(
            self.keypoint, **smpl, extra_params={k: v for k, v in arr.items() if k not in smpl},
            vertices=self.vertices[None], joints=self.joints[None], keypoints_2d=self.keypoints_2d[None],
            reprojection_error=np.array([self.metrics.get("reprojection_error_px", np.nan)]),
        )  # fmt: skip


def body_mask(vertices: np.ndarray, faces: np.ndarray, camera: Camera) -> np.ndarray:
    """Binary mask of a camera-frame mesh (offscreen rasteriser, pixel-centre coverage)."""
    from renderers.offscreen import render_mask

    return render_mask(vertices, faces, camera)


def _pose(model, params: dict, layout: str, camera: Camera):
    t = {k: torch.as_tensor(np.asarray(v), dtype=model.dtype).reshape(1, -1) for k, v in params.items()}
    with torch.no_grad():
        out = model(**t)
        kp2d = project_points(model_keypoints(model, out, layout)[0], camera)
    return out.vertices[0].numpy(), out.joints[0].numpy(), kp2d.numpy()


def _run_record(keypoint_result: KeypointFitResult, silhouette: Optional[SilhouetteFitResult] = None) -> dict:
    """Each stage's term energies and the run's configuration, for ``metrics.json``."""
    terms = {f"keypoints.{stage}": {t: float(v[0]) for t, v in d.items()} for stage, d in keypoint_result.term_energies.items()}
    config = {"keypoint_stage": keypoint_result.config}
    if silhouette is not None:
        terms["silhouette"] = dict(silhouette.terms)
        config["silhouette_stage"] = silhouette.config
    return {"energy_terms": terms, "config": config}


def _stage_seconds(timings: dict) -> float:
    """A stage's seconds: its ``total`` where it records one, else the sum of its parts."""
    return float(timings["total"]) if "total" in timings else float(sum(timings.values()))


def _median_reprojection(kp2d: np.ndarray, keypoints: KeypointSet) -> float:
    err = np.linalg.norm(kp2d - keypoints.xy, axis=1)
    return float(np.median(err[keypoints.conf > 0]))


def refine(
    model,
    keypoint_result: KeypointFitResult,
    keypoints: KeypointSet,
    mask: np.ndarray,
    config: Optional[SilhouetteFitConfig] = None,
    pose_prior=None,
    renderer=None,
    progress: bool = True,
    mask_source: str = "mask",
) -> FitResult:
    """The silhouette stage on top of a single-sample keypoint result (see :func:`fit`)."""
    return refine_batch(model, keypoint_result, [keypoints], [mask], config, pose_prior, renderer, progress,
                        [mask_source])[0]  # fmt: skip


def refine_batch(
    model,
    keypoint_result: KeypointFitResult,
    keypoints: Sequence[KeypointSet],
    masks: Sequence[np.ndarray],
    config: Optional[SilhouetteFitConfig] = None,
    pose_prior=None,
    renderer=None,
    progress: bool = True,
    mask_sources: Optional[Sequence[str]] = None,
) -> List[FitResult]:
    """The silhouette stage on a batch of keypoint results (sample ``i`` of
    ``keypoint_result`` with ``keypoints[i]`` and ``masks[i]``), all subjects refined
    together (:func:`~silfit.fitting.silhouette_stage.fit_silhouettes`)."""
    n = len(keypoints)
    if len(keypoint_result) != n or len(masks) != n:
        raise ValueError(f"{len(keypoint_result)} keypoint results, {n} keypoint sets and {len(masks)} masks")
    mask_sources = list(mask_sources or ["mask"] * n)
    faces = model.faces.cpu().numpy()
    masks = [np.asarray(m, dtype=bool) for m in masks]
    cameras = keypoint_result.cameras
    kp_masks, ious_before = [], []
    for i in range(n):
        camera = cameras[i]
        validate_mask(masks[i], mask_sources[i], size=(camera.width, camera.height))
        kp_masks.append(body_mask(keypoint_result.vertices[i], faces, camera))
        ious_before.append(mask_iou(kp_masks[i], masks[i]))
        if ious_before[i] == 0.0:
            raise ValueError(
                f"{mask_sources[i]}: the mask does not overlap the body fitted to the keypoints at all "
                "(wrong mask, or keypoints of another image?)"
            )
    inits = [keypoint_result.params(i) for i in range(n)]
    if keypoints[0].layout == "wholebody":  # the whole-body mesh, hand and face keypoints kept
        from .fitting.problem import Problem
        from .fitting.silhouette_stage import fit_silhouette_problems
        from .fitting.wholebody import wholebody_silhouette_inputs

        cfg, body_sets, terms, weights, data = wholebody_silhouette_inputs(model, keypoints, config or SilhouetteFitConfig(), model.dtype)
        problems = [Problem.single(k, cam, m) for k, cam, m in zip(body_sets, cameras, masks)]
        sils = fit_silhouette_problems(model, problems, inits, "wholebody", cfg, pose_prior, renderer, progress,
                                       terms=terms, weights=weights, data=data)  # fmt: skip
    else:
        sils = fit_silhouettes(
            model, inits, cameras, masks, [k.as_array() for k in keypoints],
            layout=keypoints[0].layout, config=config, pose_prior=pose_prior, renderer=renderer, progress=progress,
        )  # fmt: skip
    out = []
    for i, sil in enumerate(sils):
        one = keypoint_result[i]
        params = sil.params()
        vertices, joints, kp2d = _pose(model, params, keypoints[i].layout, cameras[i])
        final_mask = body_mask(vertices, faces, cameras[i])
        iou_after = mask_iou(final_mask, masks[i])
        warnings = mask_warnings(masks[i], mask_sources[i]) + list(sil.warnings)
        if iou_after < ious_before[i] - 0.02:
            warnings.append(f"silhouette stage lowered the IoU ({ious_before[i]:.3f} -> {iou_after:.3f}); kept its result")
        metrics = {
            "stages": ["keypoints", "silhouette"],
            "timings_s": {**{f"keypoints.{k}": float(v) for k, v in one.timings.items()},
                          "keypoints": _stage_seconds(one.timings), "silhouette": sil.seconds},
            "reprojection_error_px_keypoint_stage": float(one.reprojection_error[0]),
            "reprojection_error_px": _median_reprojection(kp2d, keypoints[i]),
            "iou_keypoint_stage": ious_before[i],
            "iou": iou_after,
            "silhouette_steps": sil.steps,
            "warnings": warnings,
            **_run_record(one, sil),
        }  # fmt: skip
        out.append(FitResult(cameras[i], keypoints[i].layout, one, sil, params, vertices, joints, kp2d, metrics,
                             masks={"keypoint_stage": kp_masks[i], "final": final_mask}))  # fmt: skip
    return out


def fit(
    keypoints: Union[KeypointSet, np.ndarray],
    mask: Optional[np.ndarray] = None,
    camera: Optional[Camera] = None,
    *,
    image_size: Optional[tuple] = None,
    focal: Optional[float] = None,
    model=None,
    pose_prior=None,
    keypoint_config: Optional[KeypointFitConfig] = None,
    silhouette_config: Optional[SilhouetteFitConfig] = None,
    progress: bool = True,
) -> FitResult:
    """Fit SMPL to one image: keypoints (a :class:`KeypointSet` or ``[K, 3]`` array), then,
    if ``mask [H, W]`` (bool) is given, refine against the silhouette.

    ``camera`` or ``image_size=(W, H)`` (+ optional ``focal``) define the camera, as for
    :func:`silfit.fit_keypoints`. ``model`` defaults to the shipped open body model.
    """
    if model is None:
        from .body import load_body_model

        model = load_body_model()
    sets = prepare_keypoints(keypoints)
    if len(sets) != 1:
        raise ValueError(f"fit() takes one person's keypoints, got {len(sets)}; use fit_keypoints for batches")
    if mask is not None and camera is None and image_size is None:
        image_size = (mask.shape[1], mask.shape[0])
    # plausibility (silfit.plausibility): drop far-outside keypoints, refuse degenerate sets, warn about the result
    sets[0], plausibility_warnings = check_keypoints(sets[0], (camera.width, camera.height) if camera else image_size)
    result = _fit(sets, mask, camera, image_size, focal, model, pose_prior, keypoint_config, silhouette_config, progress)
    result.metrics["warnings"] += plausibility_warnings + fit_warnings(result.metrics, sets[0], result.vertices, result.params.get("betas")) \
        + ambiguity_warnings((result.keypoint.branch_search or [None])[0])
    if result.keypoint.branch_search:  # every hypothesis the branch search ran to its end, with its energy
        result.metrics["branch_search"] = result.keypoint.branch_search[0]
    hyps = (result.keypoint.hypotheses or [None])[0]
    if hyps is not None:  # --hypotheses K: every alternative's energy and the limbs it turns (metrics.json)
        from .plausibility import hypothesis_summary, hypothesis_warnings

        result.metrics["hypotheses"] = hypothesis_summary(hyps)
        result.metrics["warnings"] += hypothesis_warnings(hyps)
    return result


def _fit(sets, mask, camera, image_size, focal, model, pose_prior, keypoint_config, silhouette_config, progress):
    fitter = KeypointFitter(model, sets[0].layout, keypoint_config, pose_prior)
    kp_result = fitter.fit(sets, camera, image_size=image_size, focal=focal, progress=progress)
    if mask is not None:
        result = refine(model, kp_result, sets[0], np.asarray(mask, dtype=bool), silhouette_config,
                        fitter.pose_prior, progress=progress)  # fmt: skip
    else:
        vertices, joints, kp2d = _pose(model, kp_result.params(0), sets[0].layout, kp_result.camera)
        metrics = {
            "stages": ["keypoints"],
            "timings_s": {**{f"keypoints.{k}": float(v) for k, v in kp_result.timings.items()},
                          "keypoints": _stage_seconds(kp_result.timings)},
            "reprojection_error_px": _median_reprojection(kp2d, sets[0]),
            "warnings": [],
            **_run_record(kp_result),
        }  # fmt: skip
        result = FitResult(kp_result.camera, sets[0].layout, kp_result, None, kp_result.params(0), vertices, joints, kp2d,
                           metrics)  # fmt: skip
    if fitter.whole_body:  # which parts were fitted, which held at rest
        from .fitting.wholebody import wholebody_summary

        result.metrics["whole_body"], notes = wholebody_summary(sets[0])
        result.metrics["warnings"] = notes + result.metrics.get("warnings", [])
    return result


def save_fit(
    result: FitResult,
    out: Union[str, os.PathLike],
    faces: np.ndarray,
    keypoints: Optional[KeypointSet] = None,
    image: Optional[np.ndarray] = None,
    mask: Optional[np.ndarray] = None,
    extra_metrics: Optional[dict] = None,
    overwrite: bool = False,
    exports: Sequence[str] = (),
) -> Path:
    """Write the output folder described in the module docstring, atomically; ``exports``
    (``"glb"``, ``"ply"``) adds ``mesh.glb`` / ``mesh.ply`` in the upright world frame of
    :mod:`silfit.outputs.export`."""
    from . import figures
    from .meshio import write_obj

    out = Path(out)
    with atomic_folder(out, overwrite) as tmp:
        result.final.save(tmp)
        write_obj(tmp / "mesh.obj", result.vertices, faces)
        if exports:
            from .outputs.export import write_fit_exports

            write_fit_exports(tmp, result.vertices, faces, result.camera, exports)
        kp_xy = None if keypoints is None else keypoints.xy
        kp_conf = None if keypoints is None else keypoints.conf
        figures.write_png(tmp / "overlay.png", figures.fit_overlay(
            image, result.vertices, faces, result.camera, kp_xy, result.keypoints_2d, kp_conf))  # fmt: skip
        stage_dir = tmp / "stages" / "keypoints"
        result.keypoint.save(stage_dir)
        if result.silhouette is not None:
            kp_verts = result.keypoint.vertices[0]
            figures.write_png(stage_dir / "overlay.png", figures.fit_overlay(
                image, kp_verts, faces, result.camera, kp_xy, result.keypoint.keypoints_2d[0], kp_conf))  # fmt: skip
            if mask is not None:
                figures.write_png(tmp / "silhouette.png", figures.silhouette_comparison(result.masks["final"], mask))
            figures.iou_curve(result.silhouette.history, tmp / "iou_curve.png")
        for k, h in enumerate((result.keypoint.hypotheses or [[]])[0], 1):  # --hypotheses K: hypotheses/k/params.npz
            from .fitio import write_fit

            write_fit(tmp / "hypotheses" / str(k), h["params"], [result.camera], layout=result.layout,
                      model=result.keypoint.model, record={"label": h["label"], "energy": h["energy"], "differs": h["differs"]})  # fmt: skip
        metrics = dict(result.metrics)
        metrics["camera"] = result.camera.to_dict()
        metrics["layout"] = result.layout
        metrics.update(extra_metrics or {})
        (tmp / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return out

