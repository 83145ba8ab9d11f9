"""Stages as data, and the one schedule runner.

A :class:`Stage` names the free parameters, the energy terms' weights, the iteration
count and the optimiser. A fit is a list of stages (the keypoint stage's schedule is
built from :class:`~silfit.fitting.keypoint_stage.KeypointFitConfig`, the silhouette
stage's levels from :class:`~silfit.fitting.silhouette_stage.SilhouetteFitConfig`), checked
once against the energy's terms and the model's parameters by :func:`check_stages`.

:func:`run_stage` runs one stage on a batch of problems, dispatching on ``Stage.optimiser``;
:func:`run_schedule` runs a list of them. Both optimisers are batched per row (one problem
per row, its own optimiser state and stopping; a batch gives what its rows give alone):

* ``"lbfgs"``: :func:`~silfit.fitting.optim.batched_lbfgs` (rows stop on convergence);
* ``"adam"``: :class:`~silfit.fitting.optim.BatchedAdam` with the stage's
  :class:`AdamSettings` (learning rate per parameter, warm-up and cosine decay, plateau
  stop per row); hooks let a caller refresh data before each step (``before_step``: e.g.
  renderer seeds), look at each step's rows (``on_step``: history, best parameters,
  divergence; it says which rows take the step) and follow the steps taken (``after_step``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Mapping, Optional, Sequence

import torch
from tqdm.auto import tqdm

from .optim import BatchedAdam, Plateau, batched_lbfgs, learning_rate_factor
from .problem import ParameterLayout
from .terms import Energy, evaluate

__all__ = [
    "AdamSettings",
    "PerRow",
    "Stage",
    "StageRun",
    "check_stages",
    "gated",
    "run_adam_stage",
    "run_lbfgs_stage",
    "run_schedule",
    "run_stage",
    "stage_to_dict",
]

OPTIMISERS = ("lbfgs", "adam")


@dataclass(frozen=True)
class Stage:
    """One stage of a fit.

    ``options`` holds optimiser- or stage-specific settings, e.g. ``decide_after`` (the
    keypoint stage keeps each problem's best start after that many steps), an L-BFGS stage's
    ``tol_change`` (a row stops once a step lowers its energy by less than this, relative), the silhouette
    stage's ``resolution``, or an Adam stage's :class:`AdamSettings` (``lr`` per parameter,
    ``warmup``, ``plateau_window``, ``plateau_rtol``)."""

    name: str
    free: tuple
    weights: Mapping[str, float]
    iterations: int
    optimiser: str = "lbfgs"
    options: Mapping[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class AdamSettings:
    """An Adam stage's settings, read from its ``options`` (:meth:`of`): a learning rate per
    free parameter (``lr``), ``warmup`` steps of linear warm-up then a cosine decay to 10 %
    over the stage (:func:`~silfit.fitting.optim.learning_rate_factor`), and a row's plateau
    stop (:class:`~silfit.fitting.optim.Plateau`; ``plateau_window`` 0: none)."""

    lr: Mapping[str, float]
    warmup: int = 0
    plateau_window: int = 0
    plateau_rtol: float = 0.0

    @classmethod
    def of(cls, stage: "Stage") -> "AdamSettings":
        o = stage.options
        missing = [n for n in stage.free if n not in o.get("lr", {})]
        if missing:
            raise ValueError(f"stage '{stage.name}': no learning rate (options['lr']) for {', '.join(missing)}")
        return cls(
            dict(o["lr"]), int(o.get("warmup", 0)), int(o.get("plateau_window", 0)), float(o.get("plateau_rtol", 0.0))
        )

    def options(self) -> dict:
        """The stage options that give these settings."""
        return {
            "lr": dict(self.lr),
            "warmup": self.warmup,
            "plateau_window": self.plateau_window,
            "plateau_rtol": self.plateau_rtol,
        }


def stage_to_dict(stage: Stage) -> dict:
    return {
        "name": stage.name,
        "free": list(stage.free),
        "weights": dict(stage.weights),
        "iterations": int(stage.iterations),
        "optimiser": stage.optimiser,
        "options": dict(stage.options),
    }


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
        if s.optimiser == "adam":
            AdamSettings.of(s)
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


class PerRow(list):
    """A list with one entry per problem (row) that a tensor of row indices selects from
    (``rows[idx]``), as tensors with a leading problem axis are: non-tensor data of a stage
    (e.g. the silhouette stage's windows and targets)."""

    def __getitem__(self, index):
        if isinstance(index, torch.Tensor):
            return PerRow(list.__getitem__(self, int(i)) for i in index.reshape(-1).tolist())
        return list.__getitem__(self, index)


@dataclass
class StageRun:
    """What a stage run leaves: final energy ``[P]``, per-term energies, seconds, steps
    ``[P]`` (rows not run: energy NaN, 0 steps); an Adam run also its optimiser (``adam``,
    whose moments a following Adam stage may continue)."""

    energy: torch.Tensor
    terms: Dict[str, torch.Tensor]
    seconds: float
    iterations: torch.Tensor
    adam: Optional[BatchedAdam] = None


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
        ev = evaluate(
            body, layout, params_at(x, idx), {k: v[idx] for k, v in views.items()}, {k: v[idx] for k, v in data.items()}
        )
        return energy(ev, weights)[0]

    bar = None
    if progress:
        bar = tqdm(total=iters, desc=f"keypoint fit: {stage.name}", leave=False)
    cb = (lambda it, f: bar.update(1)) if bar is not None else None
    tol = {"tol_change": float(stage.options["tol_change"])} if "tol_change" in stage.options else {}
    x, f, its = batched_lbfgs(fun, x0, max_iter=iters, history=history, callback=cb, **tol)
    if bar is not None:
        bar.close()
    for n, v in gated(layout.unpack(x, free), state, data).items():
        state[n] = v.detach()
    with torch.no_grad():
        idx = torch.arange(x.shape[0])
        ev = evaluate(body, layout, params_at(x, idx), views, data)
        _, parts = energy(ev, weights)
    return StageRun(f.detach().clone(), {k: v.detach() for k, v in parts.items()}, time.perf_counter() - t0, its)


def _select(data: Mapping[str, object], rows: torch.Tensor) -> dict:
    """Rows ``rows`` of a stage's data: tensors and :class:`PerRow` lists indexed, other values as they are."""
    return {k: (v[rows] if isinstance(v, (torch.Tensor, PerRow)) else v) for k, v in data.items()}


def _lbfgs_rows(stage, state, layout, energy, body, views, data, rows, iterations, history, progress) -> StageRun:
    """:func:`run_lbfgs_stage` on rows ``rows`` of the batch only; the others are left as they are."""
    P = next(iter(state.values())).shape[0]
    if rows.numel() == 0:
        return StageRun(torch.full((P,), float("nan")), {}, 0.0, torch.zeros(P, dtype=torch.long))
    sub = {k: v.detach()[rows].clone() for k, v in state.items()}
    run = run_lbfgs_stage(
        stage,
        sub,
        layout,
        energy,
        body,
        {k: v[rows] for k, v in views.items()},
        _select(data, rows),
        iterations,
        history,
        progress,
    )
    with torch.no_grad():
        for k in stage.free:
            state[k][rows] = sub[k].to(state[k].dtype)
    energy_all = torch.full((P,), float("nan"), dtype=run.energy.dtype)
    energy_all[rows] = run.energy
    terms = {}
    for k, v in run.terms.items():
        terms[k] = torch.full((P,), float("nan"), dtype=v.dtype)
        terms[k][rows] = v
    its = torch.zeros(P, dtype=torch.long)
    its[rows] = run.iterations
    return StageRun(energy_all, terms, run.seconds, its)


def _select_rows(d: Dict[str, object], rows: torch.Tensor) -> Dict[str, object]:
    """``d``'s entries at ``rows``: tensors indexed, anything else read as one entry per row (unlike :func:`_select`)."""
    return {k: (v[rows] if isinstance(v, torch.Tensor) else [v[i] for i in rows.tolist()]) for k, v in d.items()}


def _evaluate_rows(
    stage: Stage, state, layout, energy: Energy, body, views, data, rows: torch.Tensor, weights
) -> tuple:
    """``(total [R], parts, evaluation)``: the stage's energy at the problems ``rows`` (their free parameters gated as
    the stage's data says)."""
    sub = {k: v[rows] for k, v in state.items()}
    data_rows = _select_rows(data, rows)
    sub.update(gated({k: sub[k] for k in stage.free}, sub, data_rows))
    ev = evaluate(body, layout, sub, {k: v[rows] for k, v in views.items()}, data_rows)
    total, parts = energy(ev, weights)
    return total, parts, ev


def _record_energies(last: torch.Tensor, last_terms: Dict[str, torch.Tensor], rows, total, parts) -> None:
    """The rows' latest total and per-term energies into ``last`` and ``last_terms`` (float64, NaN where never set)."""
    with torch.no_grad():
        last[rows] = total.detach().to(last.dtype)
        for k, v in parts.items():
            last_terms.setdefault(k, torch.full(last.shape, float("nan"), dtype=torch.float64))[rows] = v.detach().to(
                torch.float64
            )


def run_adam_stage(
    stage: Stage,
    state: Dict[str, torch.Tensor],
    layout: ParameterLayout,
    energy: Energy,
    body,
    views: Dict[str, torch.Tensor],
    data: Dict[str, object],
    rows: Optional[torch.Tensor] = None,
    iterations: Optional[int] = None,
    adam: Optional[BatchedAdam] = None,
    before_step: Optional[Callable[[int, torch.Tensor], None]] = None,
    on_step: Optional[Callable] = None,
    after_step: Optional[Callable[[int, torch.Tensor, torch.Tensor], None]] = None,
) -> StageRun:
    """Adam over the stage's free parameters, one independent row per problem, in place on
    ``state`` (the free parameters must be leaf tensors with ``requires_grad``).

    Each step evaluates the active rows (``rows``, default all) at once; ``before_step(i,
    active_rows)`` may first refresh ``data``; ``on_step(i, active_rows, total, parts, ev)``
    returns per active row whether it takes the step (default: a finite energy); a row that
    does not stops for the rest of the stage. The rows that take it step with their own
    moments (``adam``: continued, or a fresh :class:`BatchedAdam`), learning rate ``lr *
    learning_rate_factor(i, iterations, warmup)``; then a row whose energies plateau stops,
    and ``after_step(i, stepped_rows, their_energies)`` is called."""
    t0 = time.perf_counter()
    settings = AdamSettings.of(stage)
    iters = int(stage.iterations if iterations is None else iterations)
    free = {k: state[k] for k in stage.free}
    P = next(iter(state.values())).shape[0]
    if adam is None:
        adam = BatchedAdam(free, {k: settings.lr[k] for k in stage.free})
    weights = dict(stage.weights)
    rows = torch.arange(P) if rows is None else torch.as_tensor(rows, dtype=torch.long)
    active = torch.zeros(P, dtype=torch.bool)
    active[rows] = True
    plateaus = [Plateau(settings.plateau_window, settings.plateau_rtol) for _ in range(P)]
    its = torch.zeros(P, dtype=torch.long)
    last = torch.full((P,), float("nan"), dtype=torch.float64)
    last_terms: Dict[str, torch.Tensor] = {}
    for i in range(iters):
        rows = active.nonzero().squeeze(1)
        if rows.numel() == 0:
            break
        factor = learning_rate_factor(i, iters, settings.warmup)
        if before_step is not None:
            before_step(i, rows)
        total, parts, ev = _evaluate_rows(stage, state, layout, energy, body, views, data, rows, weights)
        if on_step is not None:
            go = [bool(g) for g in on_step(i, rows, total, parts, ev)]
        else:
            go = [math.isfinite(float(e)) for e in total.detach()]
        _record_energies(last, last_terms, rows, total, parts)
        keep = [j for j, g in enumerate(go) if g]
        active[rows[[j for j, g in enumerate(go) if not g]]] = False
        if not keep:
            continue
        keep_t = torch.as_tensor(keep, dtype=torch.long)
        for v in free.values():
            v.grad = None
        total[keep_t].sum().backward()
        adam.step(rows[keep_t], factor, {k: settings.lr[k] for k in stage.free})
        stepped = rows[keep_t]
        its[stepped] += 1
        if settings.plateau_window > 0:
            for j in keep:
                p = int(rows[j])
                if plateaus[p].update(float(total[j].detach())):
                    active[p] = False
        if after_step is not None:
            after_step(i, stepped, total[keep_t].detach())
    for v in free.values():
        v.grad = None
    return StageRun(last, last_terms, time.perf_counter() - t0, its, adam)


def run_stage(
    stage: Stage,
    state: Dict[str, torch.Tensor],
    layout: ParameterLayout,
    energy: Energy,
    body,
    views: Dict[str, torch.Tensor],
    data: Dict[str, object],
    *,
    rows: Optional[torch.Tensor] = None,
    iterations: Optional[int] = None,
    history: int = 10,
    progress: bool = False,
    adam: Optional[BatchedAdam] = None,
    before_step: Optional[Callable] = None,
    on_step: Optional[Callable] = None,
    after_step: Optional[Callable] = None,
) -> StageRun:
    """Run one stage on a batch of problems (``state``: shared ``[P, w]`` and per-frame ``[P,
    F, w]`` parameters, updated in place), dispatching on ``stage.optimiser``: ``"lbfgs"``
    (:func:`run_lbfgs_stage`; ``history`` and ``progress`` are its) or ``"adam"``
    (:func:`run_adam_stage`; ``adam``, ``before_step``, ``on_step``, ``after_step`` are its).
    ``rows`` (row indices, default all) are the problems that run; the others are left as
    they are. ``iterations`` overrides the stage's count."""
    if stage.optimiser == "lbfgs":
        if rows is None and any(v.requires_grad for v in state.values()):  # leaves that other stages hold: in place
            rows = torch.arange(next(iter(state.values())).shape[0])
        if rows is None:
            return run_lbfgs_stage(stage, state, layout, energy, body, views, data, iterations, history, progress)
        return _lbfgs_rows(
            stage,
            state,
            layout,
            energy,
            body,
            views,
            data,
            torch.as_tensor(rows, dtype=torch.long),
            iterations,
            history,
            progress,
        )
    if stage.optimiser == "adam":
        return run_adam_stage(
            stage, state, layout, energy, body, views, data, rows, iterations, adam, before_step, on_step, after_step
        )
    raise ValueError(f"stage '{stage.name}': unknown optimiser {stage.optimiser!r} (expected {', '.join(OPTIMISERS)})")


def run_schedule(
    stages: Sequence[Stage],
    state: Dict[str, torch.Tensor],
    layout: ParameterLayout,
    energy: Energy,
    body,
    views: Dict[str, torch.Tensor],
    data: Dict[str, object],
    *,
    before_stage: Optional[Callable[[int, Stage], Optional[dict]]] = None,
    after_stage: Optional[Callable[[int, Stage, StageRun], None]] = None,
    **options,
) -> List[StageRun]:
    """Run ``stages`` in order with :func:`run_stage` (``options`` are its keywords). The Adam
    stages of one schedule continue one :class:`BatchedAdam` (per-row moments and step counts
    carry over). ``before_stage(index, stage)`` may prepare the stage's data and return
    keywords of :func:`run_stage` for it (e.g. ``rows``, ``body``, ``on_step``);
    ``after_stage(index, stage, run)`` sees what it left."""
    runs: List[StageRun] = []
    adam = options.pop("adam", None)
    for i, stage in enumerate(stages):
        kw = dict(options)
        kw.update((before_stage(i, stage) if before_stage is not None else None) or {})
        run_body = kw.pop("body", body)
        if stage.optimiser == "adam":
            kw["adam"] = adam
        run = run_stage(stage, state, layout, energy, run_body, views, data, **kw)
        if run.adam is not None:
            adam = run.adam
        runs.append(run)
        if after_stage is not None:
            after_stage(i, stage, run)
    return runs
