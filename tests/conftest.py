"""Shared fixtures. The shipped open body model is loaded once per session."""

import silfit  # noqa: F401  (first: pins the CPU kernels before torch and numpy load, silfit.kernels)

import os  # noqa: E402

import pytest  # noqa: E402


def pytest_configure(config):
    """In a pytest-xdist worker, torch's pool shares the CPUs with the other workers: a thread each per
    CPU (the fits are the same bits with any thread count, tests/fitting/test_determinism.py), and
    the processes the tests start (``silfit`` on the command line) read the same from OMP_NUM_THREADS.
    An OMP_NUM_THREADS already set is kept (``tools/cpu_audit.py``'s thread settings)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0") or 0)
    if workers > 1 and "OMP_NUM_THREADS" not in os.environ:
        import torch

        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        threads = max(1, cpus // workers)
        torch.set_num_threads(threads)
        os.environ["OMP_NUM_THREADS"] = str(threads)


@pytest.fixture(autouse=True)
def _seeded_global_generators():
    """Each test starts from the same global torch and numpy random state, whichever worker runs it
    and whatever ran before (pytest-xdist's ``worksteal`` deals tests to workers as they free up)."""
    import numpy as np
    import torch

    torch.manual_seed(0)
    np.random.seed(0)


@pytest.fixture(scope="session")
def open_model():
    from silfit import load_body_model

    return load_body_model()


@pytest.fixture(scope="session")
def open_model64():
    import torch

    from silfit import load_body_model

    return load_body_model(dtype=torch.float64)


@pytest.fixture(scope="session")
def body_model(open_model):
    """The shipped open body model (the name the fitting and prior tests use)."""
    return open_model


@pytest.fixture(scope="session", autouse=True)
def _silfit_cache(tmp_path_factory):
    """Caches (the render proxy) go to a temporary folder, not the home directory."""
    mp = pytest.MonkeyPatch()
    mp.setenv("SILFIT_CACHE_DIR", str(tmp_path_factory.mktemp("silfit-cache")))
    yield
    mp.undo()
