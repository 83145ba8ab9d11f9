"""Shared fixtures. The shipped open body model is loaded once per session."""
import pytest


@pytest.fixture(scope="session")
def open_model():
    from silfit import load_body_model

    return load_body_model()


@pytest.fixture(scope="session")
def open_model64():
    import torch

    from silfit import load_body_model

    return load_body_model(dtype=torch.float64)
