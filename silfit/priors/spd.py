"""Symmetric positive-definite matrices, BLAS-free: the same bits whatever BLAS kernel or SIMD level runs.

A prior's precisions are computed once, when it loads, and then weigh every step of every fit;
a fit's optimiser amplifies their last bits into millimetres. ``np.linalg.inv`` and
``np.linalg.cholesky`` run LAPACK in numpy's OpenBLAS, whose result follows its kernel (its core
type: ``OPENBLAS_CORETYPE=Sandybridge`` against ``Haswell`` gave other precisions for the shipped
mixture), its version (numpy's wheels bundle their own) and its thread split. Here every step is
an elementwise numpy operation (a product, a difference, a quotient, a square root: each exactly
rounded, whatever SIMD width runs it), in a fixed order, and the logarithms and sums of the
log-determinant are Python's (``math.log``, ``math.fsum``), not numpy's SIMD loops (``math.log`` is the C
library's: the same on machines with AVX2 and FMA under one glibc).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["cholesky", "inverse", "inverse_and_logdet", "logdet"]


def cholesky(a) -> np.ndarray:
    """The lower Cholesky factor ``L`` (``a = L L^T``) of each SPD matrix ``a [..., n, n]`` (float64),
    by outer-product updates; ``np.linalg.LinAlgError`` where a matrix is not positive definite."""
    a = np.array(a, dtype=np.float64, copy=True)
    if a.ndim < 2 or a.shape[-1] != a.shape[-2]:
        raise ValueError(f"cholesky: expected square matrices [..., n, n], got shape {a.shape}")
    n = a.shape[-1]
    L = np.zeros_like(a)
    for k in range(n):
        d = a[..., k, k]
        if not bool(np.all(d > 0)):  # NaN fails too
            raise np.linalg.LinAlgError("matrix is not positive definite")
        s = np.sqrt(d)
        L[..., k, k] = s
        col = a[..., k + 1 :, k] / s[..., None]
        L[..., k + 1 :, k] = col
        a[..., k + 1 :, k + 1 :] -= col[..., :, None] * col[..., None, :]
    return L


def _inverse_from_cholesky(L: np.ndarray) -> np.ndarray:
    n = L.shape[-1]
    X = np.broadcast_to(np.eye(n), L.shape).copy()  # L^-1, row by row (forward substitution)
    for k in range(n):
        X[..., k, :] = X[..., k, :] / L[..., k, k, None]
        X[..., k + 1 :, :] -= L[..., k + 1 :, k, None] * X[..., k, None, :]
    P = np.zeros_like(L)  # L^-T L^-1, one outer product per row in order: exactly symmetric
    for k in range(n):
        P += X[..., k, :, None] * X[..., k, None, :]
    return P


def logdet(L: np.ndarray) -> np.ndarray:
    """``log det(L L^T)`` per Cholesky factor ``L [..., n, n]``: ``2 sum log L_ii`` (Python's logarithm and exact sum)."""
    d = np.diagonal(L, axis1=-2, axis2=-1)
    flat = d.reshape(-1, d.shape[-1])
    out = np.array([2.0 * math.fsum(math.log(float(x)) for x in row) for row in flat])
    return out.reshape(d.shape[:-1])


def inverse_and_logdet(a) -> tuple[np.ndarray, np.ndarray]:
    """``(a^-1, log det a)`` of each SPD matrix ``a [..., n, n]`` (float64) through its Cholesky factor;
    ``np.linalg.LinAlgError`` where one is not positive definite."""
    L = cholesky(a)
    return _inverse_from_cholesky(L), logdet(L)


def inverse(a) -> np.ndarray:
    """``a^-1`` of each SPD matrix ``a [..., n, n]`` (float64)."""
    return inverse_and_logdet(a)[0]
