import pytest


@pytest.fixture(scope="session")
def toy_body():
    from silfit_toy_body import toy_model

    return toy_model()
