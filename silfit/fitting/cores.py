"""The steps every fit goes through, for any frames x views (:func:`run_steps`), around a core per mode
(:class:`Core`): an image batch (:class:`silfit.fitting.image_fit.ImageCore`), a rig batch
(:class:`silfit.fitting.rig_pipeline.RigCore`), a video of one camera or of a rig
(:class:`silfit.fitting.sequence.VideoCore`); :func:`silfit.run.run_batch` chooses the core by frames x views::

    kp      = core.keypoint_stage(rows)              per row its keypoint fit (multi-start and branch search,
                                                     triangulation, bridging and the temporal terms: the core's)
    rows    = core.silhouette_rows(rows, kp)         the rows with masks (and the stage on)
    refined = refine_silhouettes(model, hooks, ...)  the one silhouette driver, on each hooks object the core gives
    return core.results(kp, refined)                 per row the core's result, or the failure in its place

With ``isolate``, a stage that fails on a batch of rows runs again row by row (:func:`each`), and a row that
still fails gets a :class:`StageFailure` in its place; without, the first error raises.
"""

from __future__ import annotations

from typing import Iterator, List, Tuple

from ..errors import interruption
from .refine import SilhouetteHooks, refine_silhouettes

__all__ = ["Core", "StageFailure", "each", "run_steps"]


class StageFailure(Exception):
    """One image of a batch failed in ``stage`` (``"keypoints"`` or ``"silhouette"``): the
    original error is ``error``; after a failed silhouette stage, ``partial`` holds the keypoint
    stage's :class:`FitResult`."""

    def __init__(self, stage: str, error: Exception, partial=None):
        super().__init__(str(error))
        self.stage, self.error, self.partial = stage, error, partial


class Core:
    """What differs by mode around :func:`run_steps`: ``size`` rows (images, rigs or one video), the settings the
    silhouette driver gets (``model``, ``silhouette_config``, ``pose_prior``, ``progress``) and the steps' methods.
    ``isolates_stages``: with ``isolate``, a failing stage is fitted again row by row (images); otherwise the caller
    fits failing jobs again one by one (:func:`silfit.run.run_batch`)."""

    isolates_stages = False
    size: int
    model: object
    silhouette_config: object = None
    pose_prior: object = None
    progress: bool = False

    def keypoint_stage(self, rows: List[int]) -> list:
        """Per row of ``rows`` its keypoint fit."""
        raise NotImplementedError

    def silhouette_rows(self, rows: List[int], kp: dict) -> List[int]:
        """The rows of ``rows`` (keypoint stage done: ``kp``) whose silhouette stage runs."""
        return []

    def silhouette_hooks(self, rows: List[int], kp: dict) -> Iterator[Tuple[List[int], SilhouetteHooks]]:
        """``(rows, hooks)`` per call of the driver: the rows (of ``rows``) refined together and their hooks."""
        raise NotImplementedError

    def results(self, kp: dict, refined: dict) -> list:
        """Per row its result, from its keypoint fit (``kp``) and, where it ran, its silhouette stage's
        (``refined``); a failure in its place."""
        raise NotImplementedError


def each(rows: list, call, stage: str, isolate: bool) -> list:
    """``call(rows)`` -> one result per row; ``isolate``: again row by row where the batch fails (a row that still
    fails gets a :class:`StageFailure` of ``stage``)."""
    try:
        return list(zip(rows, call(rows)))
    except Exception as err:  # noqa: BLE001 - which row failed is found by fitting them alone
        if not isolate or interruption(err) is not None:  # (an error on an interrupt's way out is the interrupt)
            raise
        if len(rows) == 1:
            return [(rows[0], StageFailure(stage, err))]
        return [pair for r in rows for pair in each([r], call, stage, isolate)]


def run_steps(core: Core, isolate: bool = False) -> list:
    """The keypoint stage, the silhouette stage where the core has masks (the one driver,
    :func:`~silfit.fitting.refine.refine_silhouettes`), the results: per row of ``core`` its result (module
    docstring)."""
    kp = dict(each(list(range(core.size)), core.keypoint_stage, "keypoints", isolate))
    rows = core.silhouette_rows([i for i in range(core.size) if not isinstance(kp[i], StageFailure)], kp)
    refined = dict(each(rows, lambda chosen: silhouette_stage(core, chosen, kp), "silhouette", isolate)) if rows else {}
    return core.results(kp, refined)


def silhouette_stage(core: Core, rows: List[int], kp: dict) -> list:
    """Per row of ``rows`` its refined result: the one silhouette driver on each hooks object of the core."""
    done = {}
    for group, hooks in core.silhouette_hooks(rows, kp):
        fitted = refine_silhouettes(
            core.model, hooks, core.silhouette_config, core.pose_prior, progress=core.progress
        )  # (looked up here: tests count its calls)
        done.update(zip(group, fitted))
    return [done[i] for i in rows]
