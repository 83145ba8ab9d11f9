"""Fitting SMPL to an image: the keypoint stage (SMPLify in torch); the silhouette
stage plugs in later as :mod:`silfit.fitting.silhouette_stage`."""

from .keypoint_stage import (
    BranchSearch,
    HandsFace,
    ImageDepthOptions,
    KeypointFitConfig,
    KeypointFitter,
    KeypointTermOptions,
    OcclusionOptions,
    Solutions,
    Starts,
    TemporalOptions,
    fit_keypoints,
    prepare_keypoints,
)
from .losses import gmof, reprojection_energy
from .optim import batched_lbfgs
from .result import KeypointFitResult

__all__ = [
    "BranchSearch",
    "HandsFace",
    "ImageDepthOptions",
    "KeypointFitConfig",
    "KeypointFitResult",
    "KeypointFitter",
    "KeypointTermOptions",
    "OcclusionOptions",
    "Solutions",
    "Starts",
    "TemporalOptions",
    "batched_lbfgs",
    "fit_keypoints",
    "gmof",
    "prepare_keypoints",
    "reprojection_energy",
]
