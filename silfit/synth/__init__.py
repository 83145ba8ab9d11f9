"""Synthetic subjects with known ground truth: a hand-authored pose library, pose / shape /
camera samplers and the dataset generator behind ``silfit synth``.

The rendering pieces (pyrender) are imported only when a subject is generated.
"""

from ..poses.library import FRONTAL_POSES, POSE_LIBRARY, LibraryPose, get_pose, mirror_pose, pose_names
from .sampler import Placement, PoseSample, global_orientation, place_body, sample_betas, sample_intrinsics, sample_pose

__all__ = [
    "FRONTAL_POSES",
    "POSE_LIBRARY",
    "LibraryPose",
    "Placement",
    "PoseSample",
    "SynthConfig",
    "dataset_summary",
    "generate_dataset",
    "generate_hard_dataset",
    "generate_subject",
    "get_pose",
    "global_orientation",
    "mirror_pose",
    "place_body",
    "pose_names",
    "sample_betas",
    "sample_intrinsics",
    "sample_pose",
]


def __getattr__(name):
    if name in ("SynthConfig", "generate_dataset", "generate_subject", "dataset_summary"):
        from . import generate

        return getattr(generate, name)
    if name == "generate_hard_dataset":
        from .generate import generate_hard_dataset

        return generate_hard_dataset
    raise AttributeError(f"module 'silfit.synth' has no attribute {name!r}")
