"""The one silhouette driver: the silhouette stage
(:func:`~silfit.fitting.silhouette_stage.fit_silhouette_problems`, problems over frames x views) driven the same
way for one image, a rig and a video (:func:`refine_silhouettes`). What differs by mode is a small hooks object
(:class:`SilhouetteHooks`): how the masks are prepared and checked, the problems' starts (an image's keypoint-stage
alternatives as more problems), the stage's problems and extra terms (a video's temporal terms), a second pass
(an image's two-pass refit) and how the results are read back (an image's hypothesis choice and guard, a rig's
before/after, a video's re-posing and guard)::

    config = hooks.prepare(model, config)       masks checked and prepared; the stage's settings
    starts = hooks.starts(config)               one start per problem (the keypoint fits, alternatives after)
    sils   = the stage on hooks.inputs(...)     from hooks.first_pass(config)
    again  = hooks.refit(model, sils, config)   problems fitted again with ``config`` (none by default)
    return hooks.read_back(model, sils, config, seconds)

The hooks of each mode live with its results: :class:`silfit.fitting.image_fit.ImageRefinement`,
:class:`silfit.fitting.rig_pipeline.RigRefinement`, :class:`silfit.fitting.sequence.SequenceRefinement`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import List, Optional, Sequence

from . import silhouette_stage
from .silhouette_stage import SilhouetteFitConfig, SilhouetteFitResult

__all__ = ["SilhouetteHooks", "StageInputs", "refine_silhouettes"]


@dataclass
class StageInputs:
    """One call of the silhouette stage: its problems (frames x views, one per start), the keypoint layout, the
    settings and the extra energy terms with their weights and data
    (:func:`~silfit.fitting.silhouette_stage.fit_silhouette_problems`' ``terms``, ``weights``, ``data``)."""

    problems: list
    layout: str
    config: Optional[SilhouetteFitConfig]
    terms: Sequence = ()
    weights: Optional[dict] = None
    data: Optional[dict] = None


class SilhouetteHooks:
    """What differs by mode around :func:`refine_silhouettes`; the defaults: the settings as given, one pass."""

    def prepare(self, model, config: SilhouetteFitConfig) -> SilhouetteFitConfig:
        """The masks checked and prepared; returns the stage's settings."""
        return config

    def starts(self, config: SilhouetteFitConfig) -> list:
        """One start (parameters by name) per problem of the stage."""
        raise NotImplementedError

    def inputs(self, model, problems: List[int], config: SilhouetteFitConfig) -> StageInputs:
        """The stage's inputs for the problems numbered ``problems`` (indices into :meth:`starts`)."""
        raise NotImplementedError

    def first_pass(self, config: SilhouetteFitConfig) -> SilhouetteFitConfig:
        """The settings of the first pass over every problem."""
        return config

    def refit(self, model, sils: list, config: SilhouetteFitConfig) -> List[int]:
        """The problems to fit again with ``config`` after the first pass (``sils``); none by default."""
        return []

    def refitted(self, problems: List[int], first: list) -> None:
        """Told which problems were fitted again, with their first pass's results ``first``."""

    def read_back(self, model, sils: list, config: SilhouetteFitConfig, seconds: float) -> list:
        """The mode's results from the stage's (one per problem; ``seconds``: the stage's wall time)."""
        raise NotImplementedError


def refine_silhouettes(
    model,
    hooks: SilhouetteHooks,
    config: Optional[SilhouetteFitConfig] = None,
    pose_prior=None,
    renderer=None,
    progress: bool = False,
) -> list:
    """The silhouette stage of any mode (module docstring): the problems over frames x views that ``hooks`` makes,
    from the starts it gives, in one pass or two, read back by ``hooks``. Returns what :meth:`SilhouetteHooks.read_back`
    returns."""
    config = hooks.prepare(model, config or SilhouetteFitConfig())
    starts = hooks.starts(config)
    run = (pose_prior, renderer, progress)
    sils, seconds = _stage(model, hooks, list(range(len(starts))), starts, hooks.first_pass(config), run)
    again = hooks.refit(model, sils, config)
    if again:
        refitted, more = _stage(model, hooks, again, starts, config, run)
        hooks.refitted(again, [sils[k] for k in again])
        for k, sil in zip(again, refitted):
            sils[k] = sil
        seconds += more
    return hooks.read_back(model, sils, config, seconds)


def _stage(model, hooks: SilhouetteHooks, problems: List[int], starts: list, config, run: tuple) -> tuple:
    """``(results, seconds)``: the silhouette stage on the problems numbered ``problems`` from their ``starts``
    (``run``: ``(pose_prior, renderer, progress)``)."""
    pose_prior, renderer, progress = run
    s = hooks.inputs(model, problems, config)
    t0 = time.perf_counter()
    sils: List[SilhouetteFitResult] = silhouette_stage.fit_silhouette_problems(  # (looked up here: tests stub it)
        model,
        s.problems,
        [starts[k] for k in problems],
        s.layout,
        s.config,
        pose_prior,
        renderer,
        progress,
        terms=s.terms,
        weights=s.weights,
        data=s.data,
    )
    return sils, time.perf_counter() - t0
