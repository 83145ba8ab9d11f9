"""A batched L-BFGS with one independent optimiser per sample.

``torch.optim.LBFGS`` over a batch shares one line search and one curvature history
between all samples, so a sample's trajectory depends on the others (and one hard
sample slows every one). Here each sample has its own history, its own step length
(backtracking Armijo line search with quadratic interpolation) and its own stopping
test; samples that have converged drop out of the batch. A batch therefore gives the
same result as fitting each sample alone, up to floating-point rounding.
"""
from __future__ import annotations

from typing import Callable, Optional

import torch

__all__ = ["batched_lbfgs"]

Energy = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def _eval(fun: Energy, x: torch.Tensor, idx: torch.Tensor):
    with torch.enable_grad():
        xr = x.detach().requires_grad_(True)
        f = fun(xr, idx)
        (g,) = torch.autograd.grad(f.sum(), xr)
    return f.detach(), g.detach()


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
        Sa, Ya, ra, va = S[a_idx], Y[a_idx], rho[a_idx], valid[a_idx].to(dt)
        # Two-loop recursion, newest to oldest.
        order = [(ptr - 1 - k) % history for k in range(history)]
        q = ga.clone()
        alphas = {}
        for k in order:
            a = ra[:, k] * (Sa[:, k] * q).sum(-1) * va[:, k]
            alphas[k] = a
            q = q - a[:, None] * Ya[:, k]
        gam = gamma[a_idx]
        fresh = ~torch.isfinite(gam)
        gam = torch.where(fresh, first_step / ga.norm(dim=-1).clamp(min=1e-12), gam)
        r = gam[:, None] * q
        for k in reversed(order):
            b = ra[:, k] * (Ya[:, k] * r).sum(-1)
            r = r + Sa[:, k] * ((alphas[k] - b) * va[:, k])[:, None]
        d = -r
        gtd = (ga * d).sum(-1)
        bad = ~(gtd < 0)
        if bad.any():  # not a descent direction: restart with steepest descent
            d[bad] = -ga[bad] * (first_step / ga[bad].norm(dim=-1).clamp(min=1e-12))[:, None]
            gtd = (ga * d).sum(-1)
            valid[a_idx[bad]] = False
        # Backtracking line search per sample.
        xa, fa = x[a_idx], f[a_idx]
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
        s = x_new - xa
        y = g_new - ga
        sy = (s * y).sum(-1)
        yy = (y * y).sum(-1)
        upd = done & (sy > 1e-10 * yy.clamp(min=1e-30).sqrt() * s.norm(dim=-1))
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
