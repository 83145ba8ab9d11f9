import pickle

import numpy as np
import pytest
import torch

from silfit.priors import LimitsPrior, MaxMixturePrior, angle_prior, load_pose_prior, shape_prior


def write_gmm(path, K=4, D=69, seed=0):
    rng = np.random.default_rng(seed)
    means = rng.normal(0, 0.3, (K, D))
    covars = []
    for _ in range(K):
        A = rng.normal(0, 0.1, (D, D))
        covars.append(A @ A.T + 0.02 * np.eye(D))
    weights = rng.uniform(0.5, 1.5, K)
    weights /= weights.sum()
    with open(path, "wb") as fh:  # SMPLify's gmm_08.pkl layout (a plain dict, read with latin1)
        pickle.dump({"means": means, "covars": np.stack(covars), "weights": weights}, fh, protocol=2)
    return means, np.stack(covars), weights


def test_gmm_reads_file_and_matches_the_best_component_nll(tmp_path):
    means, covars, weights = write_gmm(tmp_path / "gmm_08.pkl")
    prior = load_pose_prior(tmp_path / "gmm_08.pkl", dtype=torch.float64)
    assert isinstance(prior, MaxMixturePrior) and prior.num_components == 4
    x = torch.as_tensor(means[2] + 0.05, dtype=torch.float64)[None]
    # Reference with numpy: min_k of the Gaussian NLL (up to a common constant).
    nll = []
    for k in range(4):
        d = x[0].numpy() - means[k]
        nll.append(0.5 * d @ np.linalg.solve(covars[k], d) + 0.5 * np.linalg.slogdet(covars[k])[1] - np.log(weights[k]))
    const = [0.5 * np.linalg.slogdet(covars[k])[1] - np.log(weights[k]) for k in range(4)]
    assert float(prior(x)) == pytest.approx(min(nll) - min(const), rel=1e-6)


def test_gmm_energy_is_lowest_at_a_component_mean(tmp_path):
    means, _, _ = write_gmm(tmp_path / "gmm_08.pkl")
    prior = MaxMixturePrior.from_pickle(tmp_path / "gmm_08.pkl", dtype=torch.float64)
    rng = np.random.default_rng(1)
    for k in range(4):
        mu = torch.as_tensor(means[k])[None]
        e_mu = prior.component_energies(mu)[0, k]
        around = mu + torch.as_tensor(rng.normal(0, 0.05, (32, 69)))
        assert (prior.component_energies(around)[:, k] > e_mu).all()
    # Gradient at a mean of the best component is zero; the energy is never negative.
    best = int(torch.argmin(prior.constants))
    x = torch.as_tensor(means[best])[None].requires_grad_(True)
    e = prior(x)
    (g,) = torch.autograd.grad(e.sum(), x)
    assert float(e.detach()) == pytest.approx(0.0, abs=1e-9) and float(g.abs().max()) < 1e-9
    assert (prior(torch.as_tensor(rng.normal(0, 0.5, (16, 69)))) >= 0).all()


def test_gmm_file_errors_name_the_file_and_field(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.pkl"):
        MaxMixturePrior.from_pickle(tmp_path / "missing.pkl")
    p = tmp_path / "bad.pkl"
    with open(p, "wb") as fh:
        pickle.dump({"means": np.zeros((2, 69)), "weights": np.ones(2)}, fh)
    with pytest.raises(ValueError, match="bad.pkl.*covars"):
        MaxMixturePrior.from_pickle(p)
    with open(p, "wb") as fh:
        pickle.dump({"means": np.zeros((2, 69)), "covars": np.zeros((2, 69, 69)), "weights": np.ones(2)}, fh)
    with pytest.raises(ValueError, match="positive definite"):
        MaxMixturePrior.from_pickle(p)
    lopsided = np.tile(np.eye(69), (2, 1, 1))
    lopsided[1, 0, 1] = 0.5  # an upper triangle that is not the lower one's mirror
    with open(p, "wb") as fh:
        pickle.dump({"means": np.zeros((2, 69)), "covars": lopsided, "weights": np.ones(2)}, fh)
    with pytest.raises(ValueError, match="bad.pkl.*'covars' is not symmetric"):
        MaxMixturePrior.from_pickle(p)
    (tmp_path / "junk.pkl").write_bytes(b"not a pickle")
    with pytest.raises(ValueError, match="junk.pkl"):
        MaxMixturePrior.from_pickle(tmp_path / "junk.pkl")


def test_limits_prior_shape():
    prior = load_pose_prior("limits")
    assert isinstance(prior, LimitsPrior)
    z = torch.zeros(2, 69)
    assert prior(z).tolist() == [0.0, 0.0]
    bend, hyper = torch.zeros(1, 69), torch.zeros(1, 69)
    bend[0, 9], hyper[0, 9] = 0.3, -0.3  # left knee flexion vs hyperextension
    assert 0 < float(prior(bend)) < 0.1 * float(prior(hyper))
    # Left/right symmetric: right elbow flexion (+y) costs what left elbow flexion (-y) does.
    le, re = torch.zeros(1, 69), torch.zeros(1, 69)
    le[0, 52], re[0, 55] = -1.0, 1.0
    assert float(prior(le)) == pytest.approx(float(prior(re)))


def test_angle_and_shape_priors():
    p = torch.zeros(4, 69)
    p[1, 52] = 0.5  # left elbow hyperextended
    p[2, 52] = -0.5  # left elbow flexed
    p[3, 12] = -0.5  # right knee hyperextended
    a = angle_prior(p)
    assert a[0] == pytest.approx(4.0) and a[1] > a[0] > a[2] and a[3] > a[0]
    assert shape_prior(torch.tensor([[3.0, 4.0]])).item() == pytest.approx(25.0)
