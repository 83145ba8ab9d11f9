"""``silfit fit-dataset --ray``: the same job on a Ray cluster with Ray Data.

The pending items become a dataset (one JSON row each); ``map_batches`` sends batches of at
most ``batch_size`` items (the largest size of the batches the actors would share evenly,
:func:`silfit.runner.run.shared_batch_size`; Ray Data cuts its blocks to one size) to a fixed pool of actors (:class:`FitActor`), each holding a
:class:`~silfit.runner.worker.DatasetFitter` (model, prior, keypoint fitter, renderer built
once per actor) with ``num_cpus`` / ``num_gpus`` reserved per actor. Each actor writes its
items' folders under ``OUT`` itself (atomically, so ``OUT`` must be a path every node sees
at the same place) and returns the records; the driver streams them into
``results.jsonl`` as batches finish, so a killed run resumes like a local one.

Without an address a local Ray is started (``ray.init(num_cpus=..., include_dashboard=False)``);
with one (``auto``, ``ray://host:10001`` or ``host:6379``) the job joins that cluster.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Optional, Sequence

import numpy as np

from ..errors import interrupt_cleanup
from ..kernels import KERNEL_PINS
from .items import Item
from .run import drive, shared_batch_size
from .store import RunStore
from .worker import FitOptions, process_fitter

__all__ = ["FitActor", "run_ray"]


class FitActor:
    """A Ray Data actor: builds the fitter once, then fits the batches it is given."""

    def __init__(self, options: dict, out: str, render_threads: int = 1):
        self.fitter = process_fitter(options, render_threads)  # Dr.Jit's pool as large as the CPUs reserved
        self.out = out

    def __call__(self, batch: dict) -> dict:
        items = [Item.from_dict(json.loads(s)) for s in batch["item"]]
        records = self.fitter.run_batch(items, self.out)
        return {"record": np.array([json.dumps(r) for r in records], dtype=object)}


def _init(address: Optional[str], local_cpus: int):
    import ray

    if ray.is_initialized():
        return False
    # the pinned CPU kernels too (silfit.kernels): a cluster's raylet was not started by this process
    passed = (
        "PYTHONPATH",
        "DRJIT_LIBLLVM_PATH",
        "PYOPENGL_PLATFORM",
        *KERNEL_PINS,
        "NPY_DISABLE_CPU_FEATURES",
        "SILFIT_KERNELS",
    )
    env = {"env_vars": {k: os.environ[k] for k in passed if k in os.environ}}
    with _signal_handlers_kept():
        if address:
            ray.init(address=address, runtime_env=env, log_to_driver=False, logging_level=logging.WARNING)
        else:
            ray.init(
                num_cpus=local_cpus,
                include_dashboard=False,
                runtime_env=env,
                log_to_driver=False,
                logging_level=logging.WARNING,
            )
    _auto_connect_off()  # now, not at the shutdown: Ray's check of the switch does not lock
    return True


def _auto_connect_off() -> None:
    """No Ray started by a bare ``ray.get`` (Ray's auto-connect) in this process from now on: after the run's
    ``ray.shutdown()`` a Ray Data thread still finishing would start a new local Ray from that thread, and a
    ``fit-dataset --ray`` stopped by SIGTERM once printed its line and then waited at exit, its log showing a
    ``ray.init`` from a thread other than the main one (CI). While the run's Ray is up the switch changes nothing."""
    hook = sys.modules.get("ray._private.auto_init_hook")
    if hook is not None and hasattr(hook, "enable_auto_connect"):
        hook.enable_auto_connect = False


@contextmanager
def _signal_handlers_kept():
    """The command line's SIGINT and SIGTERM handlers (Python functions) back after the block: ``ray.init``
    installs its own SIGTERM handler in the driver, which exits with status 15 (``SystemExit``), before the
    command line's cleanup and its one line. So ``silfit fit-dataset --ray`` stopped by SIGTERM exits 143 like a
    local run, also while Ray starts (its exit is handed to the command line's handler). Handlers that are not
    Python functions (the defaults, a library caller's run) stay as Ray leaves them (a library caller's own
    Python handler is called, with no frame, for a SIGTERM while Ray starts); an interrupt whose handler set both
    signals aside for the cleanup (:mod:`silfit.cli.interrupts`) leaves them aside."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    kept = {s: h for s in (signal.SIGTERM, signal.SIGINT) if callable(h := signal.getsignal(s))}  # SIGTERM's first back
    try:
        yield
    except BaseException as err:
        if isinstance(err, SystemExit) and err.code == signal.SIGTERM and signal.SIGTERM in kept:
            kept[signal.SIGTERM](signal.SIGTERM, None)  # Ray's exit while it started: the command line's interrupt
        if not interrupt_cleanup(err):  # (an interrupt's cleanup under way keeps both signals aside)
            _restore(kept)
        raise
    _restore(kept)


def _restore(handlers: dict) -> None:
    for s, handler in handlers.items():
        signal.signal(s, handler)


def run_ray(
    store: RunStore,
    pending: Sequence[Item],
    options: FitOptions,
    batch_size: int,
    address: Optional[str] = None,
    actors: int = 2,
    num_cpus: float = 1.0,
    num_gpus: float = 0.0,
    local_cpus: int = 2,
    progress: bool = False,
) -> float:
    """Fit ``pending`` on Ray (see the module docstring); the wall time in seconds. Where it starts Ray itself,
    it shuts it down at the end and leaves Ray's auto-connect off in this process (:func:`_auto_connect_off`): a
    caller that wants Ray again calls ``ray.init``."""
    if not pending:
        return 0.0
    import ray
    import ray.data

    started = _init(address, local_cpus)
    try:
        ctx = ray.data.DataContext.get_current()
        ctx.enable_progress_bars = False
        ctx.print_on_execution_start = False
        batch_size = shared_batch_size(batch_size, len(pending), actors)
        rows = [{"item": json.dumps(it.to_dict())} for it in pending]
        ds = ray.data.from_items(rows, override_num_blocks=max(1, -(-len(rows) // batch_size)))
        fitted = ds.map_batches(
            FitActor,
            fn_constructor_kwargs={
                "options": options.to_dict(),
                "out": os.fspath(store.out.resolve()),
                "render_threads": max(1, int(num_cpus)),
            },
            batch_size=batch_size,
            compute=ray.data.ActorPoolStrategy(size=max(1, actors)),
            num_cpus=num_cpus,
            num_gpus=num_gpus or None,
            batch_format="numpy",
        )

        def stream():
            batches = iter(fitted.iter_batches(batch_size=None, batch_format="numpy"))
            try:
                for batch in batches:
                    yield [json.loads(s) for s in batch["record"]]
            finally:
                getattr(batches, "close", lambda: None)()  # Ray Data shuts its executor down here

        records = stream()
        clean = False
        try:
            wall = drive(store, records, len(pending), progress)
            clean = True
            return wall
        finally:  # Ray Data's execution stopped before Ray is, on an interrupt or an error too
            try:
                records.close()
            except Exception:
                if clean:
                    raise
                logging.getLogger(__name__).debug(
                    "stopping Ray Data's execution", exc_info=True
                )  # the first error stands
    finally:
        if started:
            ray.shutdown()
