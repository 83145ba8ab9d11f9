import pytest


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory, open_model):
    """Three 128-px subjects: subject_000 frontal and noise-free, subject_001 noise-free, subject_002 noisy."""
    from silfit.synth.generate import SynthConfig, generate_dataset

    out = tmp_path_factory.mktemp("synth") / "data"
    cfg = SynthConfig(seed=11, size=128, noise_px=3.0, clean=2, drop_prob=0.2, truncation_prob=0.0)
    index = generate_dataset(out, 3, cfg, model=open_model)
    return out, index, cfg
