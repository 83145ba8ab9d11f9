import shutil

import numpy as np
import pytest


@pytest.fixture(scope="session")
def eval_dataset(tmp_path_factory, open_model):
    """Two noise-free 128-px subjects, generated once."""
    from silfit.synth.generate import SynthConfig, generate_dataset

    out = tmp_path_factory.mktemp("evaldata") / "data"
    generate_dataset(out, 2, SynthConfig(seed=21, size=128, noise_px=0.0), model=open_model)
    return out


@pytest.fixture
def dataset_with_fits(eval_dataset, tmp_path):
    """A copy of the dataset with fits: ``keypoints`` = the ground truth exactly, ``silhouette`` =
    the ground truth moved 10 cm away from the camera."""
    data = tmp_path / "data"
    shutil.copytree(eval_dataset, data)
    fits = tmp_path / "fits"
    for sub in sorted(p for p in data.iterdir() if p.is_dir()):
        with np.load(sub / "gt.npz") as gt:
            params = {k: gt[k] for k in ("betas", "body_pose", "global_orient", "transl")}
        for method, shift in (("keypoints", 0.0), ("silhouette", 0.1)):
            d = fits / sub.name / method
            d.mkdir(parents=True)
            p = dict(params, transl=params["transl"] + np.array([0, 0, shift], np.float32))
            np.savez(d / "params.npz", **p)
            (d / "metrics.json").write_text('{"timings": {"camera": 0.5, "pose": 1.5}}')
    return data, fits
