"""Fitting batches of dataset items in one process (:class:`DatasetFitter`): the model,
pose prior, keypoint fitter and silhouette renderer are built once; each batch is read
item by item (a bad file fails only its item), fitted by one batched keypoint-stage call
per keypoint layout, refined item by item against the masks (one call site,
:meth:`DatasetFitter.silhouette_stage`), and written with :func:`silfit.save_fit`
(atomically: a temporary folder renamed into place).

:meth:`DatasetFitter.run_batch` returns one JSON-ready record per item (``results.jsonl``'s
lines, see :mod:`silfit.runner.store`); recording them is the caller's job.
"""
from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

from ..fitting.keypoint_stage import KeypointFitConfig, KeypointFitter
from ..fitting.silhouette_stage import SilhouetteFitConfig
from ..fitting.result import KeypointFitResult
from ..pipeline import FitResult, refine, refine_batch, save_fit
from ..plausibility import ambiguity_warnings, check_keypoints, fit_warnings
from .items import Item, ItemError, LoadedItem, _reading, item_error, load_item

__all__ = ["FitOptions", "DatasetFitter", "keypoint_config", "silhouette_config"]

SILHOUETTE_FITTED = "fitted"
SILHOUETTE_NO_MASK = "keypoints only: no mask for this person"
SILHOUETTE_OFF = "keypoints only: --no-silhouette"


@dataclass
class FitOptions:
    """Everything a worker needs to build its fitter (JSON-ready, so it travels to Ray actors)."""

    model: Optional[str] = None
    gender: str = "neutral"
    pose_prior: Optional[str] = None
    silhouette: bool = True
    focal: Optional[float] = None
    keypoint_options: Dict[str, object] = field(default_factory=dict)  # KeypointFitConfig field -> value
    silhouette_resolutions: Optional[Sequence[int]] = None
    silhouette_iterations: Optional[Sequence[int]] = None
    exports: Sequence[str] = ()  # "glb", "ply": mesh.glb / mesh.ply per item (silfit.outputs.export)

    def to_dict(self) -> dict:
        return asdict(self)


def keypoint_config(options: Dict[str, object]) -> KeypointFitConfig:
    """A :class:`KeypointFitConfig` with ``options`` (field name -> value; strings are parsed
    by the type of the field's default, tuples comma-separated)."""
    base = KeypointFitConfig()
    names = {f.name for f in fields(base)}
    values = {}
    for key, value in options.items():
        if key not in names:
            raise ValueError(f"unknown keypoint-stage option {key!r} (one of {', '.join(sorted(names))})")
        default = getattr(base, key)
        if isinstance(value, str):
            try:
                if isinstance(default, bool):
                    if value.lower() not in ("true", "false", "1", "0"):
                        raise ValueError(value)
                    value = value.lower() in ("true", "1")
                elif isinstance(default, (tuple, list)):
                    kind = type(default[0]) if default else float
                    value = tuple(kind(v) for v in value.split(","))
                elif default is None:
                    value = None if value.lower() == "none" else int(value)
                else:
                    value = type(default)(value)
            except ValueError:
                raise ValueError(f"keypoint-stage option {key}={value!r}: expected a value like {default!r}") from None
        values[key] = value
    return replace(base, **values)


def silhouette_config(options: FitOptions) -> SilhouetteFitConfig:
    """The silhouette stage's settings with the options' levels (``ValueError`` if they do not pair)."""
    levels = {}
    if options.silhouette_resolutions:
        levels["resolutions"] = tuple(options.silhouette_resolutions)
    if options.silhouette_iterations:
        levels["iterations"] = tuple(options.silhouette_iterations)
    base = SilhouetteFitConfig()
    if len(levels.get("resolutions", base.resolutions)) != len(levels.get("iterations", base.iterations)):
        raise ValueError("--silhouette-resolutions and --silhouette-iterations need the same number of levels")
    return replace(base, **levels)


class DatasetFitter:
    """The per-process fitting state (see the module docstring)."""

    def __init__(self, options: Union[FitOptions, dict, None] = None):
        from ..body import load_body_model
        from ..priors import load_pose_prior

        options = FitOptions(**options) if isinstance(options, dict) else (options or FitOptions())
        self.options = options
        if options.model == "open-smplx":  # the shipped open whole-body model: whole-body OpenPose items
            self.model = load_body_model(kind="smplx")
        else:
            self.model = load_body_model(options.model, gender=options.gender) if options.model else load_body_model()
        self.faces = self.model.faces.cpu().numpy()
        self.config = keypoint_config(options.keypoint_options)
        self.pose_prior = load_pose_prior(options.pose_prior, dtype=self.model.dtype)
        self.silhouette_config = silhouette_config(options)
        self._fitters: Dict[str, KeypointFitter] = {}
        self._renderer = None

    def fitter(self, layout: str) -> KeypointFitter:
        if layout not in self._fitters:
            self._fitters[layout] = KeypointFitter(self.model, layout, self.config, self.pose_prior)
        return self._fitters[layout]

    @property
    def renderer(self):
        if self._renderer is None:
            from renderers.silhouette import get_silhouette_renderer

            self._renderer = get_silhouette_renderer(self.model.faces)
        return self._renderer

    # ------------------------------------------------------------------ one batch
    def run_batch(self, items: Sequence[Item], out: Union[str, os.PathLike]) -> List[dict]:
        """Fit ``items`` and write their folders under ``out``; one record per item, in order."""
        out = Path(out)
        records: Dict[str, dict] = {}
        loaded: List[LoadedItem] = []
        times: Dict[str, dict] = {}
        for it in items:
            t0 = time.perf_counter()
            try:
                li = load_item(it, read_masks=self.options.silhouette)
                if getattr(self.model, "kind", "smpl") == "smplx":  # hands and face from the same file
                    from ..wholebody import choose_fit_keypoints, read_wholebody_parts

                    parts = _reading("keypoints", it.keypoints, read_wholebody_parts, it.keypoints, li.person)
                    li.keypoints = _reading("keypoints", it.keypoints, choose_fit_keypoints, li.keypoints, parts, self.model)[0]
                # the checks every input gets (silfit.plausibility), as for one image
                li.keypoints, li.warnings = _reading("keypoints", it.keypoints, check_keypoints, li.keypoints, li.camera.size)
                loaded.append(li)
            except ItemError as err:
                records[it.key] = _failed(it, "load", err)
            times[it.key] = {"load": time.perf_counter() - t0}

        fitted = self.keypoint_stage(loaded, times)
        jobs = []
        for li, res in zip(loaded, fitted):
            if isinstance(res, ItemError):
                records[li.item.key] = _failed(li.item, "keypoints", res)
            else:
                jobs.append((li, res))
        for (li, _), res in zip(jobs, self.silhouette_stage(jobs, times)):
            key = li.item.key
            if isinstance(res, ItemError):
                records[key] = _failed(li.item, "silhouette", res)
                continue
            res.metrics["warnings"] = li.warnings + res.metrics.get("warnings", []) + fit_warnings(res.metrics, li.keypoints, res.vertices, res.params.get("betas")) \
                + ambiguity_warnings((res.keypoint.branch_search or [None])[0])
            t0 = time.perf_counter()
            try:
                save_fit(res, out / key, self.faces, li.keypoints, li.image, li.mask, self._extra(li, len(loaded)), overwrite=True,
                         exports=tuple(self.options.exports))
            except (OSError, ValueError) as err:
                records[key] = _failed(li.item, "save", item_error(err, os.fspath(out / key), "output"))
                continue
            times[key]["save"] = time.perf_counter() - t0
            records[key] = self._record(li, res, len(loaded))
        for it in items:
            t = times.get(it.key, {})
            t["total"] = sum(t.values())
            records[it.key]["timings_s"] = {k: round(v, 4) for k, v in t.items()}
        return [records[it.key] for it in items]

    def keypoint_stage(self, loaded: Sequence[LoadedItem], times: Dict[str, dict]) -> list:
        """Keypoint-only :class:`FitResult` (or :class:`ItemError`) per item: one batched fit
        per layout; if a batch fails, its items are fitted one by one so only the bad fail."""
        results: list = [None] * len(loaded)
        by_layout: Dict[str, List[int]] = {}
        for i, li in enumerate(loaded):
            by_layout.setdefault(li.keypoints.layout, []).append(i)
        for layout, idx in by_layout.items():
            fitter = self.fitter(layout)
            t0 = time.perf_counter()
            try:
                batch = self._fit(fitter, [loaded[i] for i in idx])
                singles = [(i, batch[j], len(idx)) for j, i in enumerate(idx)]
            except Exception:  # noqa: BLE001 - isolate the failing item(s)
                singles = []
                for i in idx:
                    try:
                        singles.append((i, self._fit(fitter, [loaded[i]])[0], 1))
                    except Exception as err:  # noqa: BLE001
                        results[i] = item_error(err, loaded[i].item.keypoints, "keypoints")
            share = (time.perf_counter() - t0) / len(idx)
            for i, kp, n in singles:
                scale = 1.0 / n
                kp = replace(kp, timings={k: v * scale for k, v in kp.timings.items()})
                results[i] = _keypoint_only(loaded[i], kp)
            for i in idx:
                times[loaded[i].item.key]["keypoints"] = share
        return results

    def _fit(self, fitter: KeypointFitter, batch: Sequence[LoadedItem]):
        return fitter.fit([li.keypoints for li in batch], [li.camera for li in batch], focal=self.options.focal, progress=False)

    def silhouette_stage(self, jobs, times: Dict[str, dict]) -> list:
        """The silhouette stage of a batch (``jobs``: ``(LoadedItem, keypoint FitResult)``):
        refined :class:`FitResult` or :class:`ItemError` per job; items without a mask (or with
        the stage off) keep their keypoint result. The items with a mask are refined together,
        one :func:`~silfit.pipeline.refine_batch` call per keypoint layout (the stage's torch work
        batched, one L-BFGS row per item); if that call fails, they are refined one by one, so
        only a bad item fails."""
        out: list = [res for _, res in jobs]
        groups: Dict[str, List[int]] = {}
        for j, (li, _) in enumerate(jobs):
            if li.mask is not None and self.options.silhouette:  # (masks are not read without the stage)
                groups.setdefault(li.keypoints.layout, []).append(j)
        for idx in groups.values():
            t0 = time.perf_counter()
            refined = None
            if len(idx) > 1:
                try:
                    refined = self._refine_together([jobs[j] for j in idx])
                except Exception:  # noqa: BLE001 - isolate the failing item(s) below
                    refined = None
            if refined is not None:
                share = (time.perf_counter() - t0) / len(idx)
                for j, res in zip(idx, refined):
                    out[j] = res
                    times[jobs[j][0].item.key]["silhouette"] = share
                continue
            for j in idx:
                li, res = jobs[j]
                t1 = time.perf_counter()
                try:
                    out[j] = refine(self.model, res.keypoint, li.keypoints, li.mask, self.silhouette_config,
                                    self.pose_prior, progress=False, mask_source=li.mask_file)  # fmt: skip
                except Exception as err:  # noqa: BLE001 - one item's failure
                    out[j] = item_error(err, li.mask_file, "mask")
                times[li.item.key]["silhouette"] = time.perf_counter() - t1
        return out

    def _refine_together(self, jobs) -> list:
        """:func:`~silfit.pipeline.refine_batch` of jobs of one layout; each result keeps its own
        keypoint-stage result (timings included)."""
        kps = [res.keypoint for _, res in jobs]
        batch = concat_keypoint_results(kps)
        refined = refine_batch(self.model, batch, [li.keypoints for li, _ in jobs], [li.mask for li, _ in jobs],
                               self.silhouette_config, self.pose_prior, progress=False,
                               mask_sources=[li.mask_file for li, _ in jobs])  # fmt: skip
        out = []
        for res, kp in zip(refined, kps):
            timings = {k: v for k, v in res.metrics["timings_s"].items() if not k.startswith("keypoints")}
            res.metrics["timings_s"] = {**{f"keypoints.{k}": float(v) for k, v in kp.timings.items()},
                                        "keypoints": float(kp.timings.get("total", sum(kp.timings.values()))), **timings}  # fmt: skip
            out.append(replace(res, keypoint=kp))
        return out

    # ------------------------------------------------------------------ records
    def _silhouette_status(self, li: LoadedItem) -> str:
        if not self.options.silhouette:
            return SILHOUETTE_OFF
        return SILHOUETTE_FITTED if li.mask is not None else SILHOUETTE_NO_MASK

    def _extra(self, li: LoadedItem, batch: int) -> dict:
        extra = {
            "item": li.item.key, "keypoints": li.item.keypoints, "person": li.person, "people_in_file": li.people,
            "mask": li.mask_file, "image": li.item.image, "camera_file": li.item.camera, "model": self.model.source,
            "silhouette_stage": self._silhouette_status(li), "keypoint_batch_size": batch,
        }  # fmt: skip
        if li.keypoints.layout == "wholebody":  # which parts were fitted, which held at rest
            from ..fitting.wholebody import wholebody_summary

            extra["whole_body"] = wholebody_summary(li.keypoints)[0]
        return extra

    def _record(self, li: LoadedItem, res: FitResult, batch: int) -> dict:
        m = res.metrics
        rec = {
            "item": li.item.key, "status": "ok", "keypoints": li.item.keypoints, "person": li.person,
            "people_in_file": li.people, "mask": li.mask_file, "silhouette_stage": self._silhouette_status(li),
            "stages": list(m["stages"]), "reprojection_error_px": _round(m["reprojection_error_px"]),
        }  # fmt: skip
        for k in ("iou_keypoint_stage", "iou"):
            if k in m:
                rec[k] = _round(m[k])
        rec["warnings"] = list(m.get("warnings", []))
        rec["keypoint_batch_size"] = batch
        return rec


def concat_keypoint_results(results: Sequence[KeypointFitResult]) -> KeypointFitResult:
    """Single-sample (or batched) keypoint results of one layout as one batched result (the
    first one's timings, configuration and model record)."""
    first = results[0]

    def cat(name):
        values = [getattr(r, name) for r in results]
        return None if any(v is None for v in values) else np.concatenate(values)

    def listed(name):
        values = [getattr(r, name) for r in results]
        return None if any(v is None for v in values) else [x for v in values for x in v]

    return KeypointFitResult(
        betas=cat("betas"), body_pose=cat("body_pose"), global_orient=cat("global_orient"), transl=cat("transl"),
        cameras=[c for r in results for c in r.cameras], vertices=cat("vertices"), joints=cat("joints"),
        keypoints_2d=cat("keypoints_2d"), layout=first.layout,
        energies={k: np.concatenate([r.energies[k] for r in results]) for k in first.energies if all(k in r.energies for r in results)},
        timings=dict(first.timings), flipped=cat("flipped"), reprojection_error=cat("reprojection_error"),
        term_energies={s: {t: np.concatenate([r.term_energies[s][t] for r in results]) for t in d}
                       for s, d in first.term_energies.items()
                       if all(s in r.term_energies and all(t in r.term_energies[s] for t in d) for r in results)},
        config=first.config, branches=listed("branches"),
        extra_params={k: np.concatenate([r.extra_params[k] for r in results]) for k in first.extra_params},
        model=first.model, branch_search=listed("branch_search"),
    )  # fmt: skip


def _round(v: float) -> float:
    return float(np.round(float(v), 6))


def _failed(item: Item, stage: str, err: ItemError) -> dict:
    return {"item": item.key, "status": "failed", "keypoints": item.keypoints, "stage": stage, "error": err.to_dict()}


def _keypoint_only(li: LoadedItem, kp) -> FitResult:
    """The one-image :class:`FitResult` of a keypoint-stage result (as :func:`silfit.fit`
    gives without a mask)."""
    metrics = {
        "stages": ["keypoints"],
        "timings_s": {**{f"keypoints.{k}": float(v) for k, v in kp.timings.items()}, "keypoints": float(kp.timings.get("total", 0.0))},
        "reprojection_error_px": float(kp.reprojection_error[0]),
        "warnings": [],
    }  # fmt: skip
    return FitResult(kp.camera, li.keypoints.layout, kp, None, kp.params(0), kp.vertices[0], kp.joints[0],
                     kp.keypoints_2d[0], metrics)  # fmt: skip
