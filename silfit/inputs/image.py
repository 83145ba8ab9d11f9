"""One image (or photo) -> a :class:`~silfit.inputs.job.Job`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..camera import Camera
from ..fitting.keypoint_stage import prepare_keypoints
from ..fitting.problem import Problem
from .job import Job

__all__ = ["image_job"]


def image_job(
    keypoints,
    mask=None,
    camera=None,
    *,
    image_size=None,
    focal=None,
    model=None,
    pose_prior=None,
    keypoint_config=None,
    silhouette_config=None,
    progress: bool = False,
    image=None,
    known=None,
    silhouette: bool = True,
    warnings=(),
    record=None,
    mask_source=None,
    detected_person=None,
) -> Job:
    """A job for one image: keypoints (a :class:`~silfit.io.keypoints.KeypointSet` or ``[K, 3]``
    array), an optional ``mask [H, W]``, and ``camera`` or ``image_size=(W, H)`` (+ ``focal``)
    for the default camera.

    ``known`` (bool ``[H, W]``): the mask's trusted pixels (a photo's, where other people were
    detected); ``silhouette=False``: no silhouette stage; ``warnings``: the reader's findings;
    ``record``: fields for ``metrics.json``; ``mask_source``: the mask's file (named in its
    errors); ``detected_person``: the :class:`~silfit.detect.Person` the keypoints came from.
    Refuses (``ValueError``) keypoints of more than one person and a job without a camera or a
    size to derive it from."""
    sets = prepare_keypoints(keypoints)
    if len(sets) != 1:
        raise ValueError(f"one person's keypoints, got {len(sets)}; use fit_keypoints for batches")
    if camera is None:
        if image_size is None and mask is not None:
            image_size = (mask.shape[1], mask.shape[0])
        if image_size is None:
            raise ValueError("no camera: give a camera (intrinsics) or the image size to derive the default one")
        camera = Camera.from_image_size(int(image_size[0]), int(image_size[1]), focal)
    elif focal is not None:
        camera = replace(camera, fx=float(focal), fy=float(focal))
    mask = None if mask is None else np.asarray(mask, dtype=bool)
    return Job(
        Problem.single(sets[0], camera, mask, known),
        model,
        pose_prior=pose_prior,
        keypoint_config=keypoint_config,
        silhouette_config=silhouette_config,
        silhouette=silhouette,
        progress=progress,
        warnings=list(warnings),
        record=dict(record or {}),
        images={} if image is None else {(0, 0): image},
        mask_sources={} if mask_source is None else {(0, 0): mask_source},
        people={} if detected_person is None else {(0, 0): detected_person},
    )
