"""The one silhouette driver (:func:`silfit.fitting.refine.refine_silhouettes`): the order in which it asks its
hooks, the problems and starts it hands the stage, and a second pass replacing the first's results."""

from __future__ import annotations

import numpy as np

import silfit.fitting.silhouette_stage as stage
from silfit.fitting.refine import SilhouetteHooks, StageInputs, refine_silhouettes
from silfit.fitting.silhouette_stage import SilhouetteFitConfig, SilhouetteFitResult
from silfit.fitting.silhouette_stage import Rendering


class _Hooks(SilhouetteHooks):
    """Three problems (``x`` = 0, 1, 2); with ``again``, problems 0 and 2 fitted a second time."""

    def __init__(self, again: bool):
        self.again, self.calls = again, []

    def prepare(self, model, config):
        self.calls.append("prepare")
        return config

    def starts(self, config):
        self.calls.append("starts")
        return [{"x": np.array([float(k)])} for k in range(3)]

    def inputs(self, model, problems, config):
        self.calls.append(("inputs", list(problems), config.render.spp))
        return StageInputs([f"problem {k}" for k in problems], "body25", config)

    def first_pass(self, config):
        return SilhouetteFitConfig(render=Rendering(spp=config.render.spp + 1))

    def refit(self, model, sils, config):
        self.calls.append("refit")
        return [0, 2] if self.again else []

    def refitted(self, problems, first):
        self.calls.append(("refitted", list(problems), [s.steps for s in first]))

    def read_back(self, model, sils, config, seconds):
        self.calls.append("read_back")
        return [(s.parameters["x"][0], s.steps) for s in sils]


def _stub(monkeypatch):
    """The stage stubbed: each problem's result holds its start and, in ``steps``, the settings' ``spp``."""
    seen = []

    def stub(model, problems, inits, layout, config, *args, **kwargs):
        seen.append((list(problems), layout))
        return [SilhouetteFitResult(dict(init), {}, 0.0, 0.0, 0.0, config.render.spp, []) for init in inits]

    monkeypatch.setattr(stage, "fit_silhouette_problems", stub)
    return seen


def test_one_pass_asks_the_hooks_in_order(monkeypatch):
    seen = _stub(monkeypatch)
    hooks = _Hooks(again=False)
    out = refine_silhouettes(None, hooks, SilhouetteFitConfig(render=Rendering(spp=4)))
    assert hooks.calls == ["prepare", "starts", ("inputs", [0, 1, 2], 5), "refit", "read_back"]
    assert seen == [(["problem 0", "problem 1", "problem 2"], "body25")]
    assert out == [(0.0, 5), (1.0, 5), (2.0, 5)]  # the first pass's settings (spp 5)


def test_a_second_pass_replaces_the_problems_it_refits(monkeypatch):
    seen = _stub(monkeypatch)
    hooks = _Hooks(again=True)
    out = refine_silhouettes(None, hooks, SilhouetteFitConfig(render=Rendering(spp=4)))
    assert hooks.calls[3:] == ["refit", ("inputs", [0, 2], 4), ("refitted", [0, 2], [5, 5]), "read_back"]
    assert seen[1] == (["problem 0", "problem 2"], "body25")
    assert out == [(0.0, 4), (1.0, 5), (2.0, 4)]  # problems 0 and 2 from the second pass, with the given settings
