"""A calibrated rig's views (one frame, or a video's frames) -> a :class:`~silfit.inputs.job.Job`,
fitted in the rig's world frame."""

from __future__ import annotations

from ..fitting.problem import Observation, Problem
from .counts import one_per_frame, one_per_view
from .job import Job

__all__ = ["rig_job", "rig_video_job"]


def rig_job(
    problem: Problem,
    view_names,
    model=None,
    *,
    pose_prior=None,
    keypoint_config=None,
    silhouette_config=None,
    silhouette: bool = True,
    progress: bool = False,
    warnings=(),
    record=None,
    images=None,
) -> Job:
    """A job for one frame seen by a calibrated rig: ``problem`` the views' observations (one frame;
    each view's camera with its R, t: :func:`silfit.fitting.rig_fit.rig_problem` from
    :func:`silfit.io.rig.load_rig`'s views), ``view_names`` one name per view; ``images`` maps
    ``(0, view)`` to the RGB image for the pictures. Refuses (``ValueError``) a problem of more than
    one frame (a rig video: :func:`rig_video_job`) and names that are not one per view."""
    if problem.num_frames != 1:
        raise ValueError(f"a rig job is one frame, the problem has {problem.num_frames}; use rig_video_job")
    names = list(view_names)
    one_per_view(problem.num_views, view_names=names)
    return Job(
        problem,
        model,
        names,
        pose_prior=pose_prior,
        keypoint_config=keypoint_config,
        silhouette_config=silhouette_config,
        silhouette=silhouette,
        progress=progress,
        warnings=list(warnings),
        record=dict(record or {}),
        images=dict(images or {}),
        rig=True,
    )


def rig_video_job(
    frames,
    views,
    view_names,
    model=None,
    *,
    masks=None,
    config=None,
    silhouette_config=None,
    pose_prior=None,
    silhouette: bool = True,
    progress: bool = False,
    numbers=None,
    inputs=None,
    warnings=(),
    record=None,
) -> Job:
    """A job for a rig's video: ``frames[f][c]`` the keypoints (or ``None``) of frame ``f`` in view
    ``c``, ``views`` one :class:`~silfit.fitting.problem.View` per camera (intrinsics, R, t),
    ``view_names`` their names, ``masks[f][c]`` (or ``None``: no masks) the masks; ``config``,
    ``numbers``, ``inputs`` (the reader's :class:`~silfit.io.video.RigSequence`) as for
    :func:`silfit.inputs.video.video_job`. Refuses (``ValueError``) a video without frames, a frame
    that is not one entry per view, names that are not one per view and masks or numbers that are
    not one per frame."""
    frames, views, names = [list(row) for row in frames], list(views), list(view_names)
    if not frames:
        raise ValueError("a video without frames")
    one_per_view(len(views), view_names=names)
    one_per_frame(len(frames), masks=masks, numbers=numbers)
    for f, row in enumerate(frames):  # every frame one entry per view
        one_per_view(len(views), **{f"keypoint sets in frame {f}": row})
        if masks is not None:
            one_per_view(len(views), **{f"masks in frame {f}": masks[f]})
    obs = [
        Observation(v, frames[f][c], None if masks is None else masks[f][c], f, c)
        for f in range(len(frames))
        for c, v in enumerate(views)
    ]
    return Job(
        Problem(obs),
        model,
        names,
        pose_prior=pose_prior,
        silhouette_config=silhouette_config,
        sequence_config=config,
        silhouette=silhouette,
        progress=progress,
        frame_numbers=None if numbers is None else list(numbers),
        warnings=list(warnings),
        inputs=inputs,
        rig=True,
        video=True,
        record=dict(record or {}),
    )
