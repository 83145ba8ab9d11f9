"""Running a dataset: pending items in batches, in this process (:func:`run_local`), in
local worker processes (:func:`run_pool`, ``--workers``) or on a Ray cluster
(:func:`silfit.runner.ray_backend.run_ray`); the driver records every finished batch
(:class:`silfit.runner.store.RunStore`) and shows a progress bar."""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Callable, Iterable, List, Optional, Sequence

from tqdm.auto import tqdm

from ..errors import interrupt_cleanup
from .items import Item
from .store import RunStore
from .worker import DatasetFitter, FitOptions, process_fitter

__all__ = [
    "available_cpus",
    "batches",
    "run_local",
    "run_pool",
    "progress_bar",
    "shared_batch_size",
    "shared_batches",
    "WorkerDied",
]


def batches(items: Sequence[Item], size: int) -> List[List[Item]]:
    size = max(1, int(size))
    return [list(items[i : i + size]) for i in range(0, len(items), size)]


def shared_batch_size(batch_size: int, pending: int, workers: int) -> int:
    """The largest batch of :func:`shared_batches` (Ray Data cuts its blocks into batches of one size)."""
    return max(1, max((len(b) for b in shared_batches(range(int(pending)), batch_size, workers)), default=1))


def available_cpus(cpu_max: str = "/sys/fs/cgroup/cpu.max") -> int:
    """The CPUs this process may run on: its affinity where the system says (else the machine's), at most
    its cgroup's CPU quota (a container's ``--cpus``; :func:`quota_cpus` of the file ``cpu_max``) where one is set."""
    try:
        cpus = max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        cpus = max(1, os.cpu_count() or 1)
    try:
        with open(cpu_max) as f:
            quota = quota_cpus(f.read())
    except OSError:
        quota = None
    return cpus if quota is None else min(cpus, quota)


def quota_cpus(cpu_max: str) -> Optional[int]:
    """The CPUs a cgroup v2 ``cpu.max`` line allows (``"<quota> <period>"``, rounded up: 150000 100000 is 2), or
    ``None`` for no limit (``"max <period>"``) or a line that cannot be read."""
    fields = cpu_max.split()
    if len(fields) < 2 or fields[0] == "max":
        return None
    try:
        quota, period = int(fields[0]), int(fields[1])
    except ValueError:
        return None
    return max(1, -(-quota // period)) if quota > 0 and period > 0 else None


def progress_bar(total: int, enabled: bool):
    """A tqdm bar in items with rate and ETA (``None`` when disabled)."""
    if not enabled:
        return None
    return tqdm(total=total, unit="item", desc="fit-dataset", dynamic_ncols=True, smoothing=0.1)


def drive(
    store: RunStore, results: Iterable[List[dict]], total: int, progress: bool, on_batch: Callable = None
) -> float:
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


def run_local(
    store: RunStore,
    pending: Sequence[Item],
    options: FitOptions,
    batch_size: int,
    progress: bool = False,
    fitter: Optional[DatasetFitter] = None,
) -> float:
    """Fit ``pending`` in this process, ``batch_size`` items per keypoint-stage call (with
    ``fitter``, already built from ``options``, when given)."""
    if not pending:
        return 0.0
    fitter = fitter or DatasetFitter(options)
    return drive(store, (fitter.run_batch(b, store.out) for b in batches(pending, batch_size)), len(pending), progress)


# ---------------------------------------------------------------------------------------------- worker processes
_PROCESS: dict = {}  # in a worker process: its fitter and the output folder, or why it could not start


def _die_with_parent(parent: int) -> None:
    """End this worker when the driver dies, even by SIGKILL, so none goes on writing into ``OUT`` while a
    restarted run fits the same items: on Linux the kernel kills it (``PR_SET_PDEATHSIG``); everywhere, a
    thread waits on the driver (multiprocessing's parent sentinel) and ends the process when it is gone."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
        except Exception:  # noqa: BLE001 - the watch below still ends it
            pass
    if os.getppid() != parent:  # the driver died before the request took hold
        os._exit(1)
    driver = multiprocessing.parent_process()

    def watch():
        if driver is not None:
            driver.join()
        else:  # not started by multiprocessing's spawn: the parent's id changes when it dies (POSIX)
            while os.getppid() == parent:
                time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="silfit-driver-watch", daemon=True).start()


def _start_process(options: dict, out: str, parent: int) -> None:
    _die_with_parent(parent)
    # Ctrl-C reaches the whole process group: the driver alone handles it (it stops the workers)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        from tqdm.std import tqdm  # the base class's lock (the module's tqdm is tqdm.auto's)

        # the stages' (disabled) progress bars would take a multiprocessing lock, a named semaphore the driver's
        # resource tracker then reports as leaked when the worker is killed; a worker's bars need a thread lock only
        tqdm.set_lock(threading.RLock())
        _PROCESS["fitter"], _PROCESS["out"] = process_fitter(options, render_threads=1), out
    except Exception as err:  # noqa: BLE001 - reported with the first batch, as the driver's own error
        _PROCESS["error"] = " ".join(f"{type(err).__name__}: {err}".split())


def _fit_in_process(items: List[dict]) -> List[dict]:
    if "error" in _PROCESS:
        raise WorkerDied(f"a fit-dataset worker process could not start: {_PROCESS['error']}")
    return _PROCESS["fitter"].run_batch([Item.from_dict(d) for d in items], _PROCESS["out"])


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored within the block (the main thread only; elsewhere nothing changes). The handler before
    it comes back, unless an interrupt ends the block whose handler set SIGINT and SIGTERM aside for the cleanup."""

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    except BaseException as err:
        if not interrupt_cleanup(err):  # (an interrupt's cleanup under way keeps both signals aside)
            signal.signal(signal.SIGINT, previous)
        raise
    signal.signal(signal.SIGINT, previous)


class WorkerDied(ChildProcessError):
    """A worker process could not start, or ended without its results (killed, out of memory). An
    ``OSError``: the command line prints it as one line and exits with status 2."""


def shared_batches(items: Sequence[Item], batch_size: int, workers: int) -> List[List[Item]]:
    """``items`` in batches of at most ``batch_size`` that ``workers`` share evenly: their count a multiple
    of ``workers`` (or one item each where there are fewer items), their sizes differing by one at most (28
    items, batches of 8, 2 workers: 4 batches of 7, not 8, 8, 8 and 4, which left one worker idle for the last
    4 items). A fit does not depend on its batch: the same bits."""
    n, workers = len(items), max(1, int(workers))
    if workers == 1 or not n:
        return batches(items, batch_size)
    count = -(-n // max(1, int(batch_size)))
    count = min(n, -(-count // workers) * workers)
    base, extra = divmod(n, count)
    cuts = [0]
    for k in range(count):
        cuts.append(cuts[-1] + base + (1 if k < extra else 0))
    return [list(items[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]


def run_pool(
    store: RunStore, pending: Sequence[Item], options: FitOptions, batch_size: int, workers: int, progress: bool = False
) -> float:
    """Fit ``pending`` in ``workers`` processes of this machine, each one CPU's worth, as Ray's one-CPU actors:
    one torch thread and one Dr.Jit thread, the fitter built once per process, at most ``batch_size`` items per
    batch (:func:`shared_batches`). Each process writes its items' folders (atomically:
    :func:`silfit.outputs.folder.atomic_folder`) and returns the records; the driver records them as batches finish
    (any order), so resuming works as for one process. The fits are the same bits as :func:`run_local`'s
    (``tests/cli/test_fit_dataset.py``). On an error or an interrupt the batches already finished are recorded
    and the workers are stopped at once (a folder being written is left as a temporary one, which the next run
    removes). Processes are started fresh (``spawn``), so a script calling this needs the usual
    ``if __name__ == "__main__":`` guard."""
    if not pending:
        return 0.0
    parts = shared_batches(pending, batch_size, min(int(workers), len(pending)))
    pool = ProcessPoolExecutor(
        max_workers=max(1, min(int(workers), len(parts))),
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_start_process,
        initargs=(options.to_dict(), os.fspath(store.out.resolve()), os.getpid()),
    )
    futures: list = []
    recorded: set = set()

    def finished():
        waiting = set(futures)
        while waiting:
            done, waiting = wait(waiting, return_when=FIRST_COMPLETED)
            failed = [f for f in done if f.exception() is not None]
            for future in done:  # the batches that did finish first, so none is fitted again
                if future.exception() is None:
                    recorded.add(future)
                    yield future.result()
            for future in failed:
                err = future.exception()
                if isinstance(err, BrokenProcessPool):
                    raise WorkerDied(
                        "a fit-dataset worker process ended without its results (killed, or out of memory?); "
                        "the items recorded so far are kept: run the same command again to fit the rest"
                    ) from None
                raise err

    clean = False
    try:  # the processes start in submit(): they begin with Ctrl-C ignored, as they keep it
        with _sigint_ignored():
            futures.extend(pool.submit(_fit_in_process, [it.to_dict() for it in part]) for part in parts)
        wall = drive(store, finished(), len(pending), progress)
        clean = True
        return wall
    finally:
        if not clean:
            for process in list((getattr(pool, "_processes", None) or {}).values()):
                process.kill()
        # waiting for killed workers is short; not waiting left the pool's thread to a closed pipe at exit. The
        # pool reads the results already sent before it finds its workers dead, so they are recorded below.
        pool.shutdown(wait=True, cancel_futures=True)
        if not clean:
            for f in futures:  # finished while the driver stopped: recorded, not fitted again
                if f not in recorded and f.done() and not f.cancelled() and f.exception() is None:
                    store.add(f.result())
