"""A dataset item (``silfit fit-dataset``, :mod:`silfit.runner`) -> a :class:`~silfit.inputs.job.Job`."""

from __future__ import annotations

from .image import image_job
from .job import Job

__all__ = ["item_job"]


def item_job(
    item, model, *, focal=None, pose_prior=None, keypoint_config=None, silhouette_config=None, silhouette: bool = True
) -> Job:
    """The job of a loaded dataset item (a :class:`~silfit.runner.items.LoadedItem`: one image's
    keypoints, camera, optional mask and image, the reader's warnings): :func:`~silfit.inputs.image.image_job`
    with ``focal`` (``fit-dataset --focal``) over the item's camera and the mask's file named in its errors."""
    return image_job(
        item.keypoints,
        item.mask,
        item.camera,
        focal=focal,
        model=model,
        pose_prior=pose_prior,
        keypoint_config=keypoint_config,
        silhouette_config=silhouette_config,
        progress=False,
        image=item.image,
        silhouette=silhouette,
        warnings=item.warnings,
        mask_source=item.mask_file or "mask",
    )
