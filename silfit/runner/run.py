"""Running a dataset: pending items in batches, in this process (:func:`run_local`) or on
a Ray cluster (:func:`silfit.runner.ray_backend.run_ray`); the driver records every
finished batch (:class:`silfit.runner.store.RunStore`) and shows a progress bar."""
from __future__ import annotations

import time
from typing import Callable, Iterable, List, Optional, Sequence

from .items import Item
from .store import RunStore
from .worker import DatasetFitter, FitOptions

__all__ = ["batches", "run_local", "progress_bar"]


def batches(items: Sequence[Item], size: int) -> List[List[Item]]:
    size = max(1, int(size))
    return [list(items[i : i + size]) for i in range(0, len(items), size)]


def progress_bar(total: int, enabled: bool):
    """A tqdm bar in items with rate and ETA (``None`` when disabled)."""
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="item", desc="fit-dataset", dynamic_ncols=True, smoothing=0.1)


def drive(store: RunStore, results: Iterable[List[dict]], total: int, progress: bool, on_batch: Callable = None) -> float:
    """Record each batch of records as it arrives; the wall time in seconds."""
    t0 = time.perf_counter()
    bar = progress_bar(total, progress)
    try:
        for records in results:
            store.add(records)
            if bar is not None:
                failed = sum(1 for r in store.records.values() if r["status"] == "failed")
                bar.set_postfix(failed=failed, refresh=False)
                bar.update(len(records))
            if on_batch is not None:
                on_batch(records)
    finally:
        if bar is not None:
            bar.close()
    return time.perf_counter() - t0


def run_local(store: RunStore, pending: Sequence[Item], options: FitOptions, batch_size: int, progress: bool = True,
              fitter: Optional[DatasetFitter] = None) -> float:  # fmt: skip
    """Fit ``pending`` in this process, ``batch_size`` items per keypoint-stage call (with
    ``fitter``, already built from ``options``, when given)."""
    if not pending:
        return 0.0
    fitter = fitter or DatasetFitter(options)
    return drive(store, (fitter.run_batch(b, store.out) for b in batches(pending, batch_size)), len(pending), progress)
