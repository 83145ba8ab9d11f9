"""silfit.priors.spd: BLAS-free Cholesky and inverse of SPD matrices, the same bits under any OpenBLAS kernel."""

import os
import subprocess
import sys

import numpy as np
import pytest

from silfit.priors import spd


def _spd(n=12, k=3, seed=0):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(k, n, n))
    return a @ np.transpose(a, (0, 2, 1)) / n + 0.05 * np.eye(n)


def test_cholesky_inverse_and_logdet_agree_with_lapack():
    c = _spd()
    L = spd.cholesky(c)
    assert np.allclose(L, np.linalg.cholesky(c), rtol=0, atol=1e-12)
    P, logdet = spd.inverse_and_logdet(c)
    assert np.abs(P - np.linalg.inv(c)).max() <= 1e-10 * np.abs(P).max()
    assert np.array_equal(P, np.transpose(P, (0, 2, 1)))  # exactly symmetric
    assert np.allclose(logdet, np.linalg.slogdet(c)[1], rtol=0, atol=1e-11)
    assert np.allclose(spd.inverse(c[0]), np.linalg.inv(c[0]), rtol=0, atol=1e-9)  # one matrix, no batch axis


def test_not_positive_definite_is_refused():
    c = _spd()
    c[1, 3, 3] = -1.0
    with pytest.raises(np.linalg.LinAlgError):
        spd.cholesky(c)
    with pytest.raises(np.linalg.LinAlgError):
        spd.cholesky(np.full((2, 2), np.nan))


_HASH = (
    "import silfit, hashlib, torch; from silfit.priors import load_pose_prior; "
    "p = load_pose_prior(None, dtype=torch.float64); "
    "print(hashlib.sha256(p.precisions.numpy().tobytes() + p.constants.numpy().tobytes()).hexdigest())"
)


@pytest.mark.skipif(
    not {"avx2", "fma"} <= __import__("silfit.kernels").kernels.cpu_flags(), reason="needs an x86-64 CPU with AVX2"
)
def test_the_shipped_prior_has_the_same_precisions_under_another_openblas_kernel():
    # LAPACK's inverse gave other bits with OpenBLAS's Sandybridge kernel than with Haswell (then other fits)
    out = []
    for core in ("Haswell", "Sandybridge"):
        env = {**os.environ, "OPENBLAS_CORETYPE": core}
        out.append(
            subprocess.run([sys.executable, "-c", _HASH], env=env, capture_output=True, text=True, check=True).stdout
        )
    assert out[0] == out[1] and len(out[0]) > 60
