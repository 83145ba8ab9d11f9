"""Evaluation: error metrics (:mod:`.metrics`) and dataset scoring (:mod:`.evaluate`)."""

from .metrics import mask_iou, mpjpe, pa_mpjpe, procrustes_align, pve, reprojection_error, shape_pve, translation_error

__all__ = [
    "evaluate_dataset",
    "markdown_table",
    "mask_iou",
    "mpjpe",
    "pa_mpjpe",
    "plot_errors",
    "procrustes_align",
    "pve",
    "read_fit",
    "reprojection_error",
    "score_fit",
    "shape_pve",
    "translation_error",
]


def __getattr__(name):
    if name in (
        "evaluate_dataset",
        "markdown_table",
        "plot_errors",
        "read_fit",
        "score_fit",
        "find_fits",
        "run_fitter",
    ):
        from . import evaluate

        return getattr(evaluate, name)
    raise AttributeError(f"module 'silfit.eval' has no attribute {name!r}")
