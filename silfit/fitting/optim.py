"""Batched optimisers with one independent optimiser per sample (row): L-BFGS and Adam.

``torch.optim.LBFGS`` over a batch shares one line search and one curvature history
between all samples, so a sample's trajectory depends on the others (and one hard
sample slows every one). Here each sample has its own history, its own step length
(backtracking Armijo line search with quadratic interpolation) and its own stopping
test; samples that have converged drop out of the batch. A batch therefore gives the
same result as fitting each sample alone, up to floating-point rounding.
"""

from __future__ import annotations

import math
from typing import Callable, Mapping, Optional

import numpy as np
import torch

from ..body.lbs import sqrt

__all__ = ["BatchedAdam", "Plateau", "batched_lbfgs", "learning_rate_factor"]

Energy = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def _eval(fun: Energy, x: torch.Tensor, idx: torch.Tensor):
    with torch.enable_grad():
        xr = x.detach().requires_grad_(True)
        f = fun(xr, idx)
        (g,) = torch.autograd.grad(f.sum(), xr)
    return f.detach(), g.detach()


def _two_loop_direction(ga, Sa, Ya, ra, va, gam, order, first_step: float) -> torch.Tensor:
    """L-BFGS's search direction ``-H g`` per row by the two-loop recursion over the stored pairs (``order``: slots
    newest to oldest, ``va`` 1 for a valid pair); the initial scale ``gam`` (NaN: none yet, then a steepest-descent
    step of length ``first_step``)."""
    q = ga.clone()
    alphas = {}
    for k in order:
        a = ra[:, k] * (Sa[:, k] * q).sum(-1) * va[:, k]
        alphas[k] = a
        q = q - a[:, None] * Ya[:, k]
    fresh = ~torch.isfinite(gam)
    gam = torch.where(fresh, first_step / ga.norm(dim=-1).clamp(min=1e-12), gam)
    r = gam[:, None] * q
    for k in reversed(order):
        b = ra[:, k] * (Ya[:, k] * r).sum(-1)
        r = r + Sa[:, k] * ((alphas[k] - b) * va[:, k])[:, None]
    return -r


def _backtrack(fun: Energy, xa, fa, ga, d, gtd, a_idx, max_ls: int, c1: float):
    """A backtracking line search per row along ``d`` from ``xa`` (Armijo's condition with ``c1``; a rejected step
    shrinks to the minimum of the quadratic through ``fa``, ``gtd`` and the trial, within [0.1, 0.5] of it).
    Returns ``(x, f, g, accepted)``: a row not accepted within ``max_ls`` trials keeps its start."""
    dt, dev = xa.dtype, xa.device
    t = torch.ones(len(a_idx), dtype=dt, device=dev)
    done = torch.zeros(len(a_idx), dtype=torch.bool, device=dev)
    x_new, f_new, g_new = xa.clone(), fa.clone(), ga.clone()
    for _ in range(max_ls):
        todo = (~done).nonzero().squeeze(1)
        xt = xa[todo] + t[todo, None] * d[todo]
        ft, gt = _eval(fun, xt, a_idx[todo])
        ok = torch.isfinite(ft) & (ft <= fa[todo] + c1 * t[todo] * gtd[todo])
        acc = todo[ok]
        x_new[acc], f_new[acc], g_new[acc] = xt[ok], ft[ok], gt[ok]
        done[acc] = True
        if bool(done.all()):
            break
        rej = todo[~ok]
        tr, fr = t[rej], ft[~ok]
        denom = 2.0 * (fr - fa[rej] - gtd[rej] * tr)
        tq = -gtd[rej] * tr * tr / denom
        tq = torch.where(torch.isfinite(tq) & (denom > 0), tq, 0.5 * tr)
        t[rej] = torch.minimum(torch.maximum(tq, 0.1 * tr), 0.5 * tr)
    return x_new, f_new, g_new, done


def batched_lbfgs(
    fun: Energy,
    x0: torch.Tensor,
    max_iter: int = 50,
    history: int = 10,
    first_step: float = 0.1,
    tol_grad: float = 1e-6,
    tol_change: float = 1e-8,
    max_ls: int = 12,
    c1: float = 1e-4,
    callback: Optional[Callable[[int, torch.Tensor], None]] = None,
):
    """Minimise ``fun(x[idx], idx) -> energies [len(idx)]`` independently per row of ``x0 [B, D]``.

    ``first_step`` is the length of the first (steepest-descent) step. Returns
    ``(x [B, D], energies [B], iterations [B])``.
    """
    x = x0.detach().clone()
    B, D = x.shape
    dev, dt = x.device, x.dtype
    all_idx = torch.arange(B, device=dev)
    f, g = _eval(fun, x, all_idx)
    S = torch.zeros(B, history, D, dtype=dt, device=dev)
    Y = torch.zeros_like(S)
    rho = torch.zeros(B, history, dtype=dt, device=dev)
    valid = torch.zeros(B, history, dtype=torch.bool, device=dev)
    gamma = torch.full((B,), float("nan"), dtype=dt, device=dev)
    ptr = 0
    iters = torch.zeros(B, dtype=torch.long, device=dev)
    active = torch.isfinite(f) & (g.abs().amax(-1) > tol_grad)

    for it in range(max_iter):
        a_idx = active.nonzero().squeeze(1)
        if a_idx.numel() == 0:
            break
        ga = g[a_idx]
        order = [(ptr - 1 - k) % history for k in range(history)]  # newest to oldest
        d = _two_loop_direction(
            ga, S[a_idx], Y[a_idx], rho[a_idx], valid[a_idx].to(dt), gamma[a_idx], order, first_step
        )
        gtd = (ga * d).sum(-1)
        bad = ~(gtd < 0)
        if bad.any():  # not a descent direction: restart with steepest descent
            d[bad] = -ga[bad] * (first_step / ga[bad].norm(dim=-1).clamp(min=1e-12))[:, None]
            gtd = (ga * d).sum(-1)
            valid[a_idx[bad]] = False
        # Backtracking line search per sample.
        xa, fa = x[a_idx], f[a_idx]
        x_new, f_new, g_new, done = _backtrack(fun, xa, fa, ga, d, gtd, a_idx, max_ls, c1)
        s = x_new - xa
        y = g_new - ga
        sy = (s * y).sum(-1)
        yy = (y * y).sum(-1)
        upd = done & (sy > 1e-10 * sqrt(yy.clamp(min=1e-30)) * s.norm(dim=-1))
        u_idx = a_idx[upd]
        S[u_idx, ptr] = s[upd]
        Y[u_idx, ptr] = y[upd]
        rho[u_idx, ptr] = 1.0 / sy[upd]
        valid[a_idx, ptr] = upd
        gamma[u_idx] = sy[upd] / yy[upd]
        ptr = (ptr + 1) % history
        change = (fa - f_new).abs() / torch.maximum(torch.maximum(fa.abs(), f_new.abs()), torch.ones_like(fa))
        x[a_idx], f[a_idx], g[a_idx] = x_new, f_new, g_new
        iters[a_idx] += 1
        still = done & (g_new.abs().amax(-1) > tol_grad) & (change > tol_change)
        active[a_idx] = still
        if callback is not None:
            callback(it, f)
    return x, f, iters


class BatchedAdam:
    """Adam with per-row step counts and moments over parameter groups ``params``
    (``{name: [B, ...]}``, each with its own learning rate): :meth:`step` updates only the
    rows it is told to, so a row that stopped is left exactly as it is, and a batch equals
    single runs. The state lives as long as the object (a schedule's Adam stages can share it)."""

    def __init__(self, params: dict, lr: Mapping[str, float], betas=(0.9, 0.999), eps: float = 1e-8):
        self.params, self.lr, self.b1, self.b2, self.eps = params, dict(lr), betas[0], betas[1], eps
        B = next(iter(params.values())).shape[0]
        self.t = torch.zeros(B, dtype=torch.long)
        self.m = {k: torch.zeros_like(v) for k, v in params.items()}
        self.v = {k: torch.zeros_like(v) for k, v in params.items()}

    def step(self, rows: torch.Tensor, factor: float = 1.0, lr: Optional[Mapping[str, float]] = None) -> None:
        """One step of rows ``rows`` from the parameters' ``.grad``; learning rates ``lr`` (default:
        the constructor's) times ``factor`` (a schedule's warm-up or decay)."""
        lr = self.lr if lr is None else lr
        self.t[rows] += 1
        t = self.t[rows].to(torch.float64)
        with torch.no_grad():
            for k, p in self.params.items():
                g = p.grad[rows]
                m = self.m[k][rows].mul_(self.b1).add_(g, alpha=1 - self.b1)
                v = self.v[k][rows].mul_(self.b2).addcmul_(g, g, value=1 - self.b2)
                self.m[k][rows], self.v[k][rows] = m, v
                shape = (-1,) + (1,) * (p.dim() - 1)
                bc1 = (1 - self.b1**t).to(p.dtype).reshape(shape)
                bc2 = sqrt(1 - self.b2**t).to(p.dtype).reshape(shape)
                p[rows] -= (lr[k] * factor / bc1) * m / (sqrt(v) / bc2 + self.eps)


def learning_rate_factor(step: int, steps: int, warmup: int) -> float:
    """Linear warm-up over ``warmup`` steps (Adam's first steps are full-size sign steps),
    then a cosine decay to 10 % at the end of ``steps``."""
    ramp = min(1.0, (step + 1) / max(warmup, 1))
    return ramp * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * step / max(steps, 1))))


class Plateau:
    """Stops a row when the running mean of its energy stops improving: the mean of the last
    ``window`` values against the ``window`` before them, by less than ``rtol`` (relative)."""

    def __init__(self, window: int, rtol: float):
        self.window, self.rtol, self.values = window, rtol, []

    def update(self, value: float) -> bool:
        self.values.append(value)
        n = self.window
        if len(self.values) < 2 * n:
            return False
        before = float(np.mean(self.values[-2 * n : -n]))
        now = float(np.mean(self.values[-n:]))
        return (before - now) < self.rtol * abs(before)
