import pytest


@pytest.fixture(scope="session")
def body_model():
    """The shipped open body model, or skip while it has not landed yet."""
    from silfit import load_body_model

    try:
        return load_body_model()
    except FileNotFoundError as err:
        pytest.skip(f"shipped body model missing: {err}")
