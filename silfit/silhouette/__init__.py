"""Silhouette side of the fit: reading person masks and the distance-transform losses."""
from .losses import MaskTarget, distance_transforms, silhouette_energy, soft_iou
from .masks import read_mask, validate_mask

__all__ = ["MaskTarget", "distance_transforms", "read_mask", "silhouette_energy", "soft_iou", "validate_mask"]
