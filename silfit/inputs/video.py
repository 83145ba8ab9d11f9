"""A video of one camera -> a :class:`~silfit.inputs.job.Job` (a rig's video:
:func:`silfit.inputs.rig.rig_video_job`)."""

from __future__ import annotations

from ..fitting.problem import Observation, Problem, View
from .counts import one_per_frame
from .job import Job

__all__ = ["video_job"]


def video_job(
    frames,
    camera,
    model=None,
    *,
    masks=None,
    config=None,
    silhouette_config=None,
    pose_prior=None,
    progress: bool = False,
    numbers=None,
    inputs=None,
    warnings=(),
    record=None,
    silhouette: bool = True,
) -> Job:
    """A job for one camera's video: ``frames`` one :class:`~silfit.io.keypoints.KeypointSet` (or
    ``None``: no detection) per frame, ``masks`` one mask or ``None`` per frame, ``config`` a
    :class:`~silfit.fitting.sequence.SequenceFitConfig`; ``numbers`` the frame numbers and
    ``inputs`` the reader's :class:`~silfit.io.video.SequenceInput` (for the writer's pictures);
    ``silhouette=False``: no silhouette stage even where masks exist. Refuses (``ValueError``) a
    video without frames and masks or numbers that are not one per frame."""
    frames = list(frames)
    if not frames:
        raise ValueError("a video without frames")
    masks = list(masks) if masks is not None else [None] * len(frames)
    one_per_frame(len(frames), masks=masks, numbers=numbers)
    view = View(camera)
    return Job(
        Problem([Observation(view, ks, m, f) for f, (ks, m) in enumerate(zip(frames, masks))]),
        model,
        pose_prior=pose_prior,
        silhouette_config=silhouette_config,
        sequence_config=config,
        silhouette=silhouette,
        progress=progress,
        frame_numbers=None if numbers is None else list(numbers),
        warnings=list(warnings),
        inputs=inputs,
        record=dict(record or {}),
        video=True,
    )
