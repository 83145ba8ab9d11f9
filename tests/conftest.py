"""Shared fixtures. The shipped open body model is loaded once per session."""
import silfit  # noqa: F401  (first: pins the CPU kernels before torch and numpy load, silfit.kernels)

import os  # noqa: E402

import pytest  # noqa: E402

#: The most pytest-xdist workers ``-n auto`` (pyproject's addopts) starts: one per CPU this process may
#: run on, at most 4 (a worker peaks at about 1.7 GB; the fits are the same bits in any worker, each
#: test's fit runs in one process). ``-n 0`` runs the suite in this process.
MAX_WORKERS = 4


def pytest_xdist_auto_num_workers(config):
    return max(1, min(MAX_WORKERS, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


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
