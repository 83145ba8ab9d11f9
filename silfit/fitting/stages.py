"""Stages as data, and the one loop that runs an L-BFGS stage on a batch of problems.

A :class:`Stage` names the free parameters, the energy terms' weights, the iteration
count and the optimiser. A fit is a list of stages (the keypoint stage's schedule is
built from :class:`~silfit.fitting.keypoint_stage.KeypointFitConfig`, the silhouette
stage's levels from :class:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig`), checked
once against the energy's terms and the model's parameters by :func:`check_stages`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Dict, Mapping, Optional, Sequence

import torch

from .optim import batched_lbfgs
from .problem import ParameterLayout
from .terms import Energy, evaluate

__all__ = ["Stage", "StageRun", "check_stages", "gated", "run_lbfgs_stage", "stage_to_dict"]

OPTIMISERS = ("lbfgs", "adam")


@dataclass(frozen=True)
class Stage:
    """One stage of a fit.

    ``options`` holds optimiser- or stage-specific settings, e.g. ``decide_after`` (the
    keypoint stage keeps each problem's best start after that many steps), or the
    silhouette stage's ``resolution`` and per-parameter ``lr``."""

    name: str
    free: tuple
    weights: Mapping[str, float]
    iterations: int
    optimiser: str = "lbfgs"
    options: Mapping[str, object] = field(default_factory=dict)


def stage_to_dict(stage: Stage) -> dict:
    return {
        "name": stage.name, "free": list(stage.free), "weights": dict(stage.weights),
        "iterations": int(stage.iterations), "optimiser": stage.optimiser, "options": dict(stage.options),
    }  # fmt: skip


def check_stages(stages: Sequence[Stage], energy: Energy, layout: ParameterLayout) -> None:
    """Refuse unknown terms, unknown parameters, optimisers and negative iteration counts."""
    seen = set()
    for s in stages:
        where = f"stage '{s.name}'"
        if s.name in seen:
            raise ValueError(f"{where}: two stages with the same name")
        seen.add(s.name)
        energy.check(s.weights, where)
        try:
            layout.check_free(s.free)
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from None
        if s.optimiser not in OPTIMISERS:
            raise ValueError(f"{where}: unknown optimiser {s.optimiser!r} (expected {', '.join(OPTIMISERS)})")
        if int(s.iterations) != s.iterations or s.iterations < 0:
            raise ValueError(f"{where}: iterations must be a non-negative integer, got {s.iterations!r}")


def gated(values: Dict[str, torch.Tensor], start: Dict[str, torch.Tensor], data: Mapping[str, torch.Tensor]) -> dict:
    """Free parameters with per-problem gates applied: where ``data`` holds ``gate_<name>`` (1 free,
    0 held; broadcastable to the parameter, e.g. ``[P, F, 1]``), a held problem's value stays at
    ``start`` exactly, so no term (a prior, the interpenetration) and no optimiser step moves a part
    that has no observations (a hand with all-zero confidences)."""
    out = dict(values)
    for n, v in values.items():
        g = data.get(f"gate_{n}")
        if g is not None:
            out[n] = start[n] + g.to(v.dtype) * (v - start[n])
    return out


@dataclass
class StageRun:
    """What a stage run leaves: final energy ``[P]``, per-term energies, seconds, steps."""

    energy: torch.Tensor
    terms: Dict[str, torch.Tensor]
    seconds: float
    iterations: torch.Tensor


def run_lbfgs_stage(
    stage: Stage,
    state: Dict[str, torch.Tensor],
    layout: ParameterLayout,
    energy: Energy,
    body,
    views: Dict[str, torch.Tensor],
    data: Dict[str, torch.Tensor],
    iterations: Optional[int] = None,
    history: int = 10,
    progress: bool = False,
) -> StageRun:
    """Minimise the stage's energy over its free parameters, one independent L-BFGS row
    per problem; updates ``state`` in place (detached) and returns the :class:`StageRun`."""
    t0 = time.perf_counter()
    free = tuple(stage.free)
    iters = int(stage.iterations if iterations is None else iterations)
    weights = dict(stage.weights)
    x0 = layout.pack(state, free)

    def params_at(x, idx):
        p = {n: v[idx] for n, v in state.items()}
        p.update(gated(layout.unpack(x, free), p, {k: v[idx] for k, v in data.items()}))
        return p

    def fun(x, idx):
        ev = evaluate(body, layout, params_at(x, idx), {k: v[idx] for k, v in views.items()},
                      {k: v[idx] for k, v in data.items()})  # fmt: skip
        return energy(ev, weights)[0]

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=iters, desc=f"keypoint fit: {stage.name}", leave=False)
    cb = (lambda it, f: bar.update(1)) if bar is not None else None
    x, f, its = batched_lbfgs(fun, x0, max_iter=iters, history=history, callback=cb)
    if bar is not None:
        bar.close()
    for n, v in gated(layout.unpack(x, free), state, data).items():
        state[n] = v.detach()
    with torch.no_grad():
        idx = torch.arange(x.shape[0])
        ev = evaluate(body, layout, params_at(x, idx), views, data)
        _, parts = energy(ev, weights)
    return StageRun(f.detach().clone(), {k: v.detach() for k, v in parts.items()}, time.perf_counter() - t0, its)
