"""Silhouette side of the fit: reading person masks and the distance-transform losses."""

from .losses import (
    CoverProfile,
    MaskTarget,
    clothing_thickness,
    contour_points,
    cover_energy,
    cover_weights,
    distance_transforms,
    outside_distance_energy,
    silhouette_energy,
    soft_iou,
    trim_clothing,
)
from .masks import read_mask, validate_mask

__all__ = [
    "CoverProfile",
    "MaskTarget",
    "clothing_thickness",
    "contour_points",
    "cover_energy",
    "cover_weights",
    "distance_transforms",
    "outside_distance_energy",
    "read_mask",
    "silhouette_energy",
    "soft_iou",
    "trim_clothing",
    "validate_mask",
]
