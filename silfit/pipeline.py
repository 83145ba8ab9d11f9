"""The names ``silfit.pipeline`` had before the one path (issue 26), kept for callers: one image's
core is :mod:`silfit.fitting.image_fit`, the fit of anything is :func:`silfit.run.run`, and
:func:`silfit.fit` (``silfit.pipeline.fit``) is :func:`silfit.run.fit`. Nothing inside silfit
imports this module."""

from .fitting.image_fit import (  # noqa: F401
    FitResult,
    StageFailure,
    body_mask,
    fit_problem,
    fit_problems,
    refine,
    refine_batch,
)
from .outputs.write import save_fit  # noqa: F401
from .run import fit  # noqa: F401

__all__ = [
    "FitResult",
    "StageFailure",
    "body_mask",
    "fit",
    "fit_problem",
    "fit_problems",
    "refine",
    "refine_batch",
    "save_fit",
]
