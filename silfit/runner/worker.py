"""Fitting batches of dataset items in one process (:class:`DatasetFitter`): the model and
pose prior are built once; each batch is read item by item (a bad file fails only its item),
each item made a :class:`silfit.inputs.Job` (:func:`silfit.inputs.item_job`), the batch fitted by :func:`silfit.run.run_batch`
(the path every mode takes: the checks, one batched keypoint stage per layout, the silhouette
stage batched over the items with masks, the warnings; a failing item fails alone), and
written with :func:`silfit.run.write` (atomically: a temporary folder renamed into place).

:meth:`DatasetFitter.run_batch` returns one JSON-ready record per item (``results.jsonl``'s
lines, see :mod:`silfit.runner.store`); recording them is the caller's job.
"""

from __future__ import annotations

import collections.abc
import difflib
import functools
import os
import time
import typing
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

import silfit.render.silhouette

from ..body import load_body_model
from ..errors import interruption
from ..fitting.keypoint_stage import KeypointFitConfig
from ..fitting.silhouette_stage import SilhouetteFitConfig
from ..fitting.threads import torch_threads
from ..inputs import item_job
from ..io.wholebody import choose_fit_keypoints, read_wholebody_parts
from ..priors import load_pose_prior
from ..run import Fit, StageFailure, run_batch, write
from .items import Item, ItemError, LoadedItem, read_component, item_error, load_item

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
    silhouette_options: Dict[str, object] = field(default_factory=dict)  # SilhouetteFitConfig field -> value
    exports: Sequence[str] = ()  # "glb", "ply": mesh.glb / mesh.ply per item (silfit.outputs.export)

    def to_dict(self) -> dict:
        return asdict(self)


def _declared_kind(hint, key: str, stage: str = "keypoint") -> tuple:
    """``(kind, many, expected)`` of an Optional field's declared type: ``Optional[Sequence[float]]`` ->
    ``(float, True, "comma-separated numbers ...")``; a type a command line cannot spell is a ``ValueError``."""
    args = [a for a in typing.get_args(hint) if a is not type(None)] or [hint]
    kind, many = args[0], False
    if typing.get_origin(kind) in (list, tuple, collections.abc.Sequence):
        kind, many = (typing.get_args(kind) or (float,))[0], True
    if kind not in (int, float, str):
        raise ValueError(f"{stage}-stage option {key} cannot be given on the command line")
    word = {int: "integers", float: "numbers", str: "words"}[kind]
    return kind, many, (f"comma-separated {word} (e.g. 0,0.5,1) or none" if many else f"{word[:-1]} or none")


def keypoint_config(options: Dict[str, object], base: Optional[KeypointFitConfig] = None) -> KeypointFitConfig:
    """``base`` (default :class:`KeypointFitConfig()`) with ``options`` (:func:`config_with`)."""
    return config_with(KeypointFitConfig, options, base, "keypoint")


def config_with(cls, options: Dict[str, object], base=None, stage: str = "keypoint"):
    """``base`` (default ``cls()``: :class:`KeypointFitConfig` or :class:`SilhouetteFitConfig`; ``stage`` names it
    in errors) with ``options`` (field name -> value; strings are parsed by the type of the field's default in
    ``cls()``, whatever ``base`` holds (a video's ``final_tol_change`` is ``None`` there, still a float), or by the
    field's declared type where that default is ``None`` (``hand_weights``: comma-separated numbers); tuples
    comma-separated; ``none`` for an optional field; a mapping (``lr``) cannot be given as text; a group's field as
    ``group.field``, e.g. ``image_depth.weight``)."""
    plain = cls()
    base = plain if base is None else base
    hints = _config_hints(cls)
    names = {f.name for f in fields(plain)} | set(getattr(cls, "renamed_fields", {})) | set(hints)  # old names too
    values = {}
    optional = {n for n, h in hints.items() if type(None) in typing.get_args(h)}  # these also take "none"
    for key, value in options.items():
        if key not in names:
            close = difflib.get_close_matches(key, sorted(names), n=3, cutoff=0.6)
            hint = f"did you mean {' or '.join(close)}? " if close else ""
            raise ValueError(f"unknown {stage}-stage option {key!r}: {hint}(one of {', '.join(sorted(names))})")
        default = functools.reduce(getattr, key.split("."), plain)
        if is_dataclass(default) and isinstance(value, str):
            raise ValueError(f"{stage}-stage option {key} is a group: give its fields ({key}.<field>)")
        if isinstance(value, str) and key in optional and value.lower() == "none":
            value = None
        elif isinstance(value, str):
            if isinstance(default, dict):
                raise ValueError(f"{stage}-stage option {key} cannot be given on the command line (a mapping)")
            declared = (
                _declared_kind(hints.get(key), key, stage) if default is None else None
            )  # e.g. Optional[Sequence[float]]
            expected = declared[2] if declared else f"a value like {default!r}"
            try:
                if isinstance(default, bool):
                    if value.lower() not in ("true", "false", "1", "0"):
                        raise ValueError(value)
                    value = value.lower() in ("true", "1")
                elif isinstance(default, (tuple, list)):
                    kind = type(default[0]) if default else float
                    value = tuple(kind(v) for v in value.split(","))
                elif declared:
                    kind, many, _ = declared
                    value = tuple(kind(v) for v in value.split(",")) if many else kind(value)
                else:
                    value = type(default)(value)
            except ValueError:
                raise ValueError(f"{stage}-stage option {key}={value!r}: expected {expected}") from None
        values[key] = value
    return replace(base, **grouped_values(values, base))


def grouped_values(values: dict, base) -> dict:
    """``values`` by field of ``base``: each ``group.field`` value set in (a copy of) its group."""
    out = {k: v for k, v in values.items() if "." not in k}
    for key, value in values.items():
        if "." in key:
            group, name = key.split(".", 1)
            out[group] = replace(out.get(group, getattr(base, group)), **{name: value})
    return out


@functools.lru_cache(maxsize=4)
def _config_hints(cls) -> dict:
    """A settings class's declared field types (read once), its groups' fields' (``group.field``) and the old flat
    names' of those (:func:`~silfit.fitting.aliases.grouped`)."""
    hints, plain = dict(typing.get_type_hints(cls)), cls()
    for f in fields(plain):
        group = getattr(plain, f.name)
        if is_dataclass(group):
            hints.update({f"{f.name}.{k}": h for k, h in typing.get_type_hints(type(group)).items()})
    for old, a in getattr(cls, "renamed_fields", {}).items():
        if a.sub is not None:
            hints[old] = hints[f"{a.field}.{a.sub}"]
    return hints


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
    return config_with(
        SilhouetteFitConfig, dict(options.silhouette_options or {}), replace(base, **levels), "silhouette"
    )


class DatasetFitter:
    """The per-process fitting state (see the module docstring)."""

    def __init__(self, options: Union[FitOptions, dict, None] = None):
        options = FitOptions(**options) if isinstance(options, dict) else (options or FitOptions())
        self.options = options
        if options.model == "open-smplx":  # the shipped open whole-body model: whole-body OpenPose items
            self.model = load_body_model(kind="smplx")
        else:
            self.model = load_body_model(options.model, gender=options.gender) if options.model else load_body_model()
        self.config = keypoint_config(options.keypoint_options)
        self.pose_prior = load_pose_prior(options.pose_prior, dtype=self.model.dtype)
        self.silhouette_config = silhouette_config(options)

    # ------------------------------------------------------------------ one batch
    def job(self, li: LoadedItem):
        """The :class:`silfit.inputs.Job` of a loaded item (:func:`silfit.inputs.item_job`: one image; ``--focal``
        applied)."""
        return item_job(
            li,
            self.model,
            focal=self.options.focal,
            pose_prior=self.pose_prior,
            keypoint_config=self.config,
            silhouette_config=self.silhouette_config,
            silhouette=self.options.silhouette,
        )

    def run_batch(self, items: Sequence[Item], out: Union[str, os.PathLike]) -> List[dict]:
        """Fit ``items`` (:func:`silfit.run.run_batch`: the checks, one batched keypoint stage per
        layout, the silhouette stage batched over the items with masks, the warnings) and write
        their folders under ``out``; one record per item, in order. With one torch thread, as the
        stages and Ray's one-CPU actors run (the same bits: ``tests/cli/test_fit_dataset.py``): the
        small work between the stages (posing, masks, writing) gains nothing from a second thread,
        and on a loaded CPU the pool's waiting made it much slower (docs/benchmarks/defaults.md)."""
        with torch_threads(1):
            return self._run_batch(items, out)

    def _run_batch(self, items: Sequence[Item], out: Union[str, os.PathLike]) -> List[dict]:
        out = Path(out)
        records: Dict[str, dict] = {}
        loaded: List[LoadedItem] = []
        times: Dict[str, dict] = {}
        for it in items:
            t0 = time.perf_counter()
            try:
                li = load_item(it, read_masks=self.options.silhouette)
                if getattr(self.model, "kind", "smpl") == "smplx":  # hands and face from the same file
                    parts = read_component("keypoints", it.keypoints, read_wholebody_parts, it.keypoints, li.person)
                    li.keypoints = read_component(
                        "keypoints", it.keypoints, choose_fit_keypoints, li.keypoints, parts, self.model
                    )[0]
                loaded.append(li)
            except ItemError as err:
                records[it.key] = _failed(it, "load", err)
            times[it.key] = {"load": time.perf_counter() - t0}
        fits = run_batch([self.job(li) for li in loaded], isolate=True)
        for li, fit in zip(loaded, fits):
            key = li.item.key
            if isinstance(fit, Exception):  # the checks (as reading), or a stage
                stage = fit.stage if isinstance(fit, StageFailure) else "load"
                err = fit.error if isinstance(fit, StageFailure) else fit
                source, component = (
                    (li.mask_file, "mask") if stage == "silhouette" else (li.item.keypoints, "keypoints")
                )
                records[key] = _failed(li.item, stage, item_error(err, source, component))
                continue
            times[key].update(fit.seconds)
            t0 = time.perf_counter()
            try:
                write(
                    fit,
                    out / key,
                    overwrite=True,
                    exports=tuple(self.options.exports),
                    extra=self._extra(li, len(loaded)),
                )
            except (OSError, ValueError) as err:
                if interruption(err) is not None:  # the run was stopped while writing: not this item's failure
                    raise
                records[key] = _failed(li.item, "save", item_error(err, os.fspath(out / key), "output"))
                continue
            times[key]["save"] = time.perf_counter() - t0
            records[key] = self._record(li, fit, len(loaded))
        for it in items:
            t = times.get(it.key, {})
            t["total"] = sum(t.values())
            records[it.key]["timings_s"] = {k: round(v, 4) for k, v in t.items()}
        return [records[it.key] for it in items]

    # ------------------------------------------------------------------ records
    def _silhouette_status(self, li: LoadedItem) -> str:
        if not self.options.silhouette:
            return SILHOUETTE_OFF
        return SILHOUETTE_FITTED if li.mask is not None else SILHOUETTE_NO_MASK

    def _extra(self, li: LoadedItem, batch: int) -> dict:
        extra = {
            "item": li.item.key,
            "keypoints": li.item.keypoints,
            "person": li.person,
            "people_in_file": li.people,
            "mask": li.mask_file,
            "image": li.item.image,
            "camera_file": li.item.camera,
            "model": self.model.source,
            "silhouette_stage": self._silhouette_status(li),
            "keypoint_batch_size": batch,
        }
        return extra

    def _record(self, li: LoadedItem, fit: Fit, batch: int) -> dict:
        m = fit.metrics
        rec = {
            "item": li.item.key,
            "status": "ok",
            "keypoints": li.item.keypoints,
            "person": li.person,
            "people_in_file": li.people,
            "mask": li.mask_file,
            "silhouette_stage": self._silhouette_status(li),
            "stages": list(m["stages"]),
            "reprojection_error_px": _round(m["reprojection_error_px"]),
        }
        for k in ("iou_keypoint_stage", "iou"):
            if k in m:
                rec[k] = _round(m[k])
        rec["warnings"] = list(m.get("warnings", []))
        rec["keypoint_batch_size"] = batch
        return rec


def process_fitter(options: dict, render_threads: int = 1) -> DatasetFitter:
    """The fitter of one worker process (a Ray actor, a local ``--workers`` process): Dr.Jit's pool as large as
    the CPUs the worker has (``render_threads``), not every core of the machine (the fits are the same bits for any
    count: :class:`silfit.render.silhouette.SilhouetteRenderer`), then :class:`DatasetFitter` from ``options``
    (:meth:`FitOptions.to_dict`)."""
    silfit.render.silhouette.AUTO_THREADS = max(1, int(render_threads))
    return DatasetFitter(FitOptions(**options))


def _round(v: float) -> float:
    return float(np.round(float(v), 6))


def _failed(item: Item, stage: str, err: ItemError) -> dict:
    return {"item": item.key, "status": "failed", "keypoints": item.keypoints, "stage": stage, "error": err.to_dict()}
