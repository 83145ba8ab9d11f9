"""The shipped default pose prior: a mixture fitted to silfit's own pose library."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from silfit.priors import (
    DEFAULT_MIXTURE_PATH,
    LibraryMixturePrior,
    LimitsPrior,
    clamp_to_limits,
    default_pose_prior,
    limit_bounds,
    load_pose_prior,
)
from silfit.priors.library_prior import BUILD_DEFAULTS, build_library_mixture, sample_library_poses, split_library
from silfit.synth.poses import POSE_LIBRARY, arm, elbow, mirror_pose

ROOT = Path(__file__).resolve().parents[2]


def library():
    return torch.as_tensor(np.stack([p.body_pose for p in POSE_LIBRARY.values()]))


def test_default_is_the_shipped_library_mixture():
    prior = load_pose_prior()
    assert isinstance(prior, LibraryMixturePrior)
    assert isinstance(default_pose_prior(), LibraryMixturePrior)
    assert isinstance(load_pose_prior("default"), LibraryMixturePrior)
    assert isinstance(load_pose_prior("limits"), LimitsPrior)
    assert prior.dim == 69 and 2 <= prior.num_components <= 64
    assert set(prior.pose_names) == set(POSE_LIBRARY)
    assert prior.settings == pytest.approx({k: float(v) for k, v in BUILD_DEFAULTS.items()})
    assert load_pose_prior(DEFAULT_MIXTURE_PATH).num_components == prior.num_components


def test_shipped_file_layout():
    path = Path(DEFAULT_MIXTURE_PATH)
    assert path.is_file() and path.parent.name == "data" and path.stat().st_size < 2_000_000
    with np.load(path, allow_pickle=False) as z:  # plain arrays, no pickles
        K = z["means"].shape[0]
        assert z["means"].shape == (K, 69) and z["covars"].shape == (K, 69, 69) and z["weights"].shape == (K,)
        assert np.isfinite(z["covars"]).all() and z["weights"].sum() == pytest.approx(1.0, abs=1e-5)
        assert np.allclose(z["covars"], np.transpose(z["covars"], (0, 2, 1)))
        assert (np.linalg.eigvalsh(z["covars"].astype(np.float64)).min(-1) > 0).all()


def test_library_poses_cost_less_than_implausible_ones():
    prior = load_pose_prior(dtype=torch.float64)
    lib = prior(library())
    assert (lib >= 0).all()
    rng = np.random.default_rng(0)
    lo, hi = limit_bounds(torch.float64)
    # Poses uniform over the joint-limit box (inside the limits, but mostly unnatural).
    box = lo + (hi - lo) * torch.as_tensor(rng.random((64, 69)))
    assert float(prior(box).min()) > float(lib.max())
    # Hyperextended elbows and knees, knees bent sideways.
    bad = torch.zeros(3, 69)
    bad[0, 52], bad[0, 55] = 0.6, -0.6  # both elbows bent backwards
    bad[1, 9], bad[1, 12] = -0.6, -0.6  # both knees hyperextended
    bad[2, 11], bad[2, 14] = 0.8, -0.8  # knees bent sideways
    assert float(prior(bad.double()).min()) > float(lib.median())


def test_prefers_arms_in_front_to_arms_behind():
    # The 2D depth ambiguity the prior is meant to resolve: a bent arm reaching forward
    # and its mirror image through the frontal plane project to similar 2D points.
    base = POSE_LIBRARY["stand_relaxed"].body_pose.copy()
    fwd, back = base.copy(), base.copy()
    fwd[45:48], fwd[51:54] = arm("L", (0.3, -0.6, 0.7)), elbow("L", 70)
    back[45:48], back[51:54] = arm("L", (0.3, -0.6, -0.7)), elbow("L", 70)
    x = clamp_to_limits(torch.as_tensor(np.stack([fwd, back, mirror_pose(fwd), mirror_pose(back)])))
    e = load_pose_prior(dtype=torch.float64)(x)
    assert e[0] < e[1] and e[2] < e[3]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_gradient_is_finite(dtype):
    prior = load_pose_prior(dtype=dtype)
    x = torch.cat([library().to(dtype), torch.zeros(1, 69, dtype=dtype), 3 * torch.randn(8, 69, dtype=dtype)])
    x.requires_grad_(True)
    e = prior(x)
    (g,) = torch.autograd.grad(e.sum(), x)
    assert e.dtype == dtype and torch.isfinite(e).all() and torch.isfinite(g).all()
    assert g.abs().sum() > 0


def test_builder_is_deterministic_and_respects_the_name_list(tmp_path):
    a, b = split_library(0)
    assert set(a).isdisjoint(b) and set(a) | set(b) == set(POSE_LIBRARY)
    small = dict(n_samples=400, components=3, em_iters=5)
    g1 = build_library_mixture(a, **small)
    g2 = build_library_mixture(a, **small)
    for k in ("means", "covars", "weights"):
        np.testing.assert_array_equal(g1[k], g2[k])
    assert list(g1["pose_names"]) == a
    # Samples around a single pose stay near it (and its mirror image).
    X = sample_library_poses(200, 0, ["wave_right"], perturb_deg=5.0, mirror_prob=0.0)
    assert np.abs(X.mean(0) - POSE_LIBRARY["wave_right"].body_pose).max() < 0.1
    with pytest.raises(ValueError, match="unknown"):
        sample_library_poses(10, 0, ["no_such_pose"])


def test_build_script_writes_a_loadable_file(tmp_path):
    out = tmp_path / "mix.npz"
    subprocess.run(
        [
            sys.executable,
            str(ROOT / "tools" / "build_pose_prior.py"),
            "--out",
            str(out),
            "--n-samples",
            "300",
            "--components",
            "2",
            "--em-iters",
            "3",
            "--names",
            "t_pose",
            "a_pose",
            "stand_relaxed",
        ],
        check=True,
        capture_output=True,
    )
    prior = load_pose_prior(out)
    assert isinstance(prior, LibraryMixturePrior) and prior.num_components == 2
    assert prior.pose_names == ["t_pose", "a_pose", "stand_relaxed"] and prior.settings["components"] == 2


def test_mixture_file_errors_name_the_file_and_field(tmp_path):
    p = tmp_path / "bad.npz"
    np.savez(p, means=np.zeros((2, 69)), weights=np.ones(2))
    with pytest.raises(ValueError, match="bad.npz.*covars"):
        load_pose_prior(p)
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        load_pose_prior(tmp_path / "missing.npz")
