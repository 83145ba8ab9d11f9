"""Shared fixtures. The shipped open body model is loaded once per session."""
import silfit  # noqa: F401  (first: pins the CPU kernels before torch and numpy load, silfit.kernels)

import pytest  # noqa: E402


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
