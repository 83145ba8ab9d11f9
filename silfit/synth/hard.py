"""The "hard" synthetic set: poses from :mod:`silfit.poses.sampler` (not the pose library),
seen from the front and the back where a limb runs along the viewing ray.

A subject's pose is drawn from :class:`silfit.poses.sampler.PoseSampler` (squats,
kneeling, sitting, running, lunges, reaching, a hand at the face / head / hip). For the
deep-flexion archetypes (:data:`silfit.poses.sampler.DEEP_FLEXION`) the body yaw is,
with probability ``frontal_back_prob``, 0 or 180 degrees (even odds) plus Gaussian
jitter of ``yaw_jitter_deg``; otherwise (and for the other archetypes) it is uniform in
the configured range. Everything else (shape, camera, rendering, keypoint noise and
occlusion-aware confidences, the file format) is :mod:`silfit.synth.generate`'s.

The set itself is written by :func:`silfit.synth.generate.generate_hard_dataset`.
This set is for measuring: the shipped pose prior is fitted to the library only
(:mod:`silfit.priors.library_prior`) and must not be refitted to it.
"""

from __future__ import annotations

import functools

from typing import Tuple

import numpy as np

from ..body import load_body_model
from ..poses.sampler import DEEP_FLEXION, PoseSampler

__all__ = ["hard_pose_and_yaw", "hard_yaw", "FRONTAL_BACK_PROB", "YAW_JITTER_DEG"]

FRONTAL_BACK_PROB = 0.7
YAW_JITTER_DEG = 15.0


def hard_yaw(rng: np.random.Generator, archetype: str, yaw_range_deg: Tuple[float, float] = (-180.0, 180.0)) -> float:
    """Body yaw (degrees, in [-180, 180)) for a pose of ``archetype``: front or back views
    over-represented for the deep-flexion archetypes (see the module docstring)."""
    if archetype in DEEP_FLEXION and rng.random() < FRONTAL_BACK_PROB:
        yaw = (0.0 if rng.random() < 0.5 else 180.0) + float(rng.normal(0.0, YAW_JITTER_DEG))
        return (yaw + 180.0) % 360.0 - 180.0
    return float(rng.uniform(*yaw_range_deg))


def hard_pose_and_yaw(model, rng: np.random.Generator, yaw_range_deg: Tuple[float, float] = (-180.0, 180.0)):
    """``(SampledPose, yaw_deg)`` for one subject of the hard set."""
    ps = PoseSampler(_screening_model(model)).sample(rng)
    return ps, hard_yaw(rng, ps.archetype, yaw_range_deg)


def _screening_model(model):
    """The body the sampler screens poses on (self-contact, interpenetration): an SMPL-layout model (23 body
    joints); for a whole-body (SMPL-X) model the shipped open SMPL model, whose first 21 joints are the ones a
    SMPL-X subject takes from the pose."""
    return model if model.num_body_pose == 69 else _open_smpl()


@functools.lru_cache(maxsize=1)
def _open_smpl():
    return load_body_model()
