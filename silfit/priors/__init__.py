"""Priors for fitting SMPL: joint limits, pose priors, shape prior, interpenetration."""
from .limits import (
    BODY_JOINT_NAMES,
    JOINT_LIMITS,
    clamp_to_limits,
    limit_bounds,
    limit_centre_and_range,
    limit_violation,
    within_limits,
)

__all__ = [
    "BODY_JOINT_NAMES",
    "JOINT_LIMITS",
    "clamp_to_limits",
    "limit_bounds",
    "limit_centre_and_range",
    "limit_violation",
    "within_limits",
]
