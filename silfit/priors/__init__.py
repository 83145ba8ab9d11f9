"""Priors for fitting SMPL: joint limits, pose priors (SMPLify's GMM file format and
the shipped default), knee/elbow angle prior, shape prior and interpenetration."""

from .interpenetration import SphereCollisionModel
from .limits import (
    BODY_JOINT_NAMES,
    JOINT_LIMITS,
    clamp_to_limits,
    limit_bounds,
    limit_centre_and_range,
    limit_violation,
    within_limits,
)
from .pose import (
    DEFAULT_MIXTURE_PATH,
    LibraryMixturePrior,
    LimitsPrior,
    MaxMixturePrior,
    default_pose_prior,
    load_pose_prior,
)
from .simple import angle_prior, shape_prior

__all__ = [
    "BODY_JOINT_NAMES",
    "JOINT_LIMITS",
    "DEFAULT_MIXTURE_PATH",
    "LibraryMixturePrior",
    "LimitsPrior",
    "MaxMixturePrior",
    "SphereCollisionModel",
    "angle_prior",
    "clamp_to_limits",
    "default_pose_prior",
    "limit_bounds",
    "limit_centre_and_range",
    "limit_violation",
    "load_pose_prior",
    "shape_prior",
    "within_limits",
]
