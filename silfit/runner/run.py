"""Running a dataset: pending items in batches, in this process (:func:`run_local`), in
local worker processes (:func:`run_pool`, ``--workers``) or on a Ray cluster
(:func:`silfit.runner.ray_backend.run_ray`); the driver records every finished batch
(:class:`silfit.runner.store.RunStore`) and shows a progress bar."""
from __future__ import annotations

import os
import time
from typing import Callable, Iterable, List, Optional, Sequence

from .items import Item
from .store import RunStore
from .worker import DatasetFitter, FitOptions

__all__ = ["available_cpus", "batches", "run_local", "run_pool", "progress_bar", "shared_batch_size"]


def batches(items: Sequence[Item], size: int) -> List[List[Item]]:
    size = max(1, int(size))
    return [list(items[i : i + size]) for i in range(0, len(items), size)]


def shared_batch_size(batch_size: int, pending: int, workers: int) -> int:
    """``batch_size``, cut so that every one of ``workers`` gets work when there are fewer than
    ``workers x batch_size`` pending items (a fit does not depend on its batch: the same bits)."""
    return max(1, min(int(batch_size), -(-int(pending) // max(1, int(workers)))))


def available_cpus() -> int:
    """The CPUs this process may run on (its affinity where the system says, else the machine's)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


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


# ---------------------------------------------------------------------------------------------- worker processes
_PROCESS: dict = {}  # in a worker process: its fitter and the output folder


def _die_with_parent(parent: int) -> None:
    """Ask Linux to kill this worker when the driver dies (even by SIGKILL), so no orphan writes into ``OUT``
    while a restarted run fits the same items; where that cannot be asked, a worker finds its driver gone at
    its next batch (the pool's queue closes)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except (AttributeError, OSError):
        return
    if os.getppid() != parent:  # the driver died before the request took hold
        os._exit(1)


def _start_process(options: dict, out: str, parent: int) -> None:
    _die_with_parent(parent)
    from .worker import process_fitter

    _PROCESS["fitter"], _PROCESS["out"] = process_fitter(options, render_threads=1), out


def _fit_in_process(items: List[dict]) -> List[dict]:
    return _PROCESS["fitter"].run_batch([Item.from_dict(d) for d in items], _PROCESS["out"])


class WorkerDied(RuntimeError):
    """A worker process ended without its results (killed, out of memory)."""


def run_pool(store: RunStore, pending: Sequence[Item], options: FitOptions, batch_size: int, workers: int,
             progress: bool = True) -> float:  # fmt: skip
    """Fit ``pending`` in ``workers`` processes of this machine, each one CPU's worth, as Ray's one-CPU actors:
    one torch thread and one Dr.Jit thread, the fitter built once per process, ``batch_size`` items per
    batch (fewer so every process gets work: :func:`shared_batch_size`). Each process writes its items'
    folders (atomically: :func:`silfit.outfolder.atomic_folder`) and returns the records; the driver records them as
    batches finish (any order), so resuming works as for one process. The fits are the same bits as
    :func:`run_local`'s (``tests/cli/test_fit_dataset.py``). Processes are started fresh (``spawn``), so a
    script calling this needs the usual ``if __name__ == "__main__":`` guard."""
    if not pending:
        return 0.0
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    workers = max(1, min(int(workers), len(pending)))
    size = shared_batch_size(batch_size, len(pending), workers)
    parts = batches(pending, size)
    pool = ProcessPoolExecutor(max_workers=min(workers, len(parts)), mp_context=multiprocessing.get_context("spawn"),
                               initializer=_start_process, initargs=(options.to_dict(), os.fspath(store.out.resolve()), os.getpid()))  # fmt: skip

    def finished():
        waiting = {pool.submit(_fit_in_process, [it.to_dict() for it in part]) for part in parts}
        while waiting:
            done, waiting = wait(waiting, return_when=FIRST_COMPLETED)
            for future in done:
                try:
                    yield future.result()
                except BrokenProcessPool:
                    raise WorkerDied("a fit-dataset worker process ended without its results (killed, or out of memory?); "
                                     "the items recorded so far are kept: run the same command again to fit the rest") from None  # fmt: skip

    try:
        return drive(store, finished(), len(pending), progress)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
