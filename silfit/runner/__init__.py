"""Fitting whole datasets (``silfit fit-dataset``): inputs (:mod:`.items`), the output folder
and resuming (:mod:`.store`), the per-process fitter (:mod:`.worker`), local (one process or
several) and Ray execution (:mod:`.run`, :mod:`.ray_backend`) and the end-of-run summary (:mod:`.summary`).
:func:`fit_dataset` ties them together."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Optional, Union

from .items import InputError, Item, list_items
from .ray_backend import run_ray
from .run import available_cpus, run_local, run_pool
from .store import RunStore
from .summary import plot_summary, summarise, summary_table
from .worker import DatasetFitter, FitOptions, keypoint_config, silhouette_config

__all__ = ["FitOptions", "InputError", "Item", "fit_dataset", "list_items"]


def fit_dataset(
    input: Union[str, os.PathLike],
    out: Union[str, os.PathLike],
    *,
    people="largest",
    masks: Optional[str] = None,
    images: Optional[str] = None,
    camera: Optional[str] = None,
    options: Optional[FitOptions] = None,
    batch_size: int = 8,
    retry_failed: bool = False,
    workers: Union[int, str] = 1,
    ray: bool = False,
    ray_address: Optional[str] = None,
    actors: int = 2,
    num_cpus: float = 1.0,
    num_gpus: float = 0.0,
    progress: bool = False,
) -> dict:
    """Fit every (image, person) of ``input`` into ``out`` (resuming a previous run there);
    returns the summary (see :func:`silfit.runner.summary.summarise`) with ``records``.

    ``workers``: local worker processes (one CPU each; ``"auto"``: one per CPU this process may use), the
    same fits bit for bit as one (:func:`silfit.runner.run.run_pool`); 1 fits in this process. With
    ``ray``, ``actors`` plays that part."""
    if Path(out).exists() and not Path(out).is_dir():
        raise InputError(f"{out}: output path exists and is not a folder")
    if ray and workers != 1:
        raise InputError(f"workers {workers!r}: local worker processes; a Ray run has its actors (actors=)")
    if workers == "auto":
        workers = available_cpus()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise InputError(f"workers {workers!r}: expected a positive number of processes or 'auto'")
    items = list_items(input, people, masks=masks, images=images, camera=camera)
    options = options or FitOptions()
    keypoint_config(options.keypoint_options)  # bad options fail here, before any output
    silhouette_config(options)
    fitter = DatasetFitter(options)  # so do the model and the pose prior (read and checked here)
    keys = [it.key for it in items]
    store = RunStore.open(out, keys, retry_failed=retry_failed)
    pending = [it for it in items if not store.done(it.key)]
    if ray:
        wall = run_ray(store, pending, options, batch_size, ray_address, actors, num_cpus, num_gpus, progress=progress)
    elif workers > 1 and len(pending) > 1:
        del fitter  # each worker builds its own: this process need not hold one too
        wall = run_pool(store, pending, options, batch_size, workers, progress=progress)
    else:
        wall = run_local(store, pending, options, batch_size, progress=progress, fitter=fitter)
    records = store.for_keys(keys)
    summary = summarise(records, wall, len(pending))
    table = summary_table(summary)
    out = Path(out)
    (out / "summary.md").write_text(table + "\n")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    plot_summary(records, out / "summary.png")
    summary["table"] = table
    summary["records"] = records
    summary["pending"] = len(pending)
    return summary
