"""A calibrated rig's views (one frame, or a video's frames) -> a :class:`~silfit.inputs.job.Job`,
fitted in the rig's world frame; and the rig's files read into its observations (:func:`rig_problem`,
:func:`read_rig_sequence_masks`), so the fitting core reads no file."""

from __future__ import annotations

from typing import Optional

from ..errors import InputError
from ..fitting.plausibility import check_keypoints
from ..fitting.problem import Observation, Problem
from ..io.keypoints import read_keypoints
from ..io.wholebody import choose_fit_keypoints, read_wholebody_parts
from ..silhouette.masks import read_mask
from .counts import one_per_frame, one_per_view
from .job import Job

__all__ = [
    "fit_keypoints_of",
    "has_wholebody_parts",
    "read_rig_sequence_masks",
    "rig_job",
    "rig_problem",
    "rig_video_job",
]


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
    each view's camera with its R, t: :func:`rig_problem` from
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


def fit_keypoints_of(path, model=None, person="largest"):
    """The keypoints ``model`` is fitted to from one OpenPose file: its body (BODY_25 / COCO-17) for
    an SMPL-layout model (or no model), the ``wholebody`` layout (hands and face; absent parts at
    confidence 0) for an SMPL-X-layout one (:func:`silfit.io.wholebody.choose_fit_keypoints`)."""
    ks = read_keypoints(path, person=person)
    if model is None or getattr(model, "kind", "smpl") != "smplx":
        return ks
    return choose_fit_keypoints(ks, read_wholebody_parts(path, person), model)[0]


def has_wholebody_parts(paths, person="largest") -> bool:
    """Whether any of these OpenPose files holds confident hand or face points (they pick the
    whole-body model when none is given, as for one image)."""
    for path in paths:
        try:
            parts = read_wholebody_parts(path, person)
        except InputError:  # that view's keypoints are set aside when read (e.g. no person ``person`` there)
            continue
        if parts is not None and parts.has_parts:
            return True
    return False


def rig_problem(views, person="largest", with_masks: bool = True, model=None) -> Problem:
    """A one-frame :class:`Problem` from :func:`silfit.io.rig.load_rig`'s views: each view's
    keypoints (OpenPose; checked as one image's are, :func:`silfit.fitting.plausibility.check_keypoints`,
    with the notes added to the view's warnings) and, when present and ``with_masks``, its mask
    (checked against the camera's size). With an SMPL-X-layout ``model`` the keypoints are the
    ``wholebody`` layout (:func:`fit_keypoints_of`)."""
    obs = []
    for c, v in enumerate(views):
        cam = v.view.camera
        ks, notes = check_keypoints(fit_keypoints_of(v.keypoints, model, person), cam.size)
        v.warnings.extend(n for n in notes if n not in v.warnings)
        mask = read_mask(v.mask, size=(cam.width, cam.height)) if (with_masks and v.mask is not None) else None
        obs.append(Observation(v.view, ks, mask, frame=0, view_index=c))
    return Problem(obs)


def read_rig_sequence_masks(seq) -> Optional[list]:
    """``masks[f][c]`` (bool ``[H, W]``, or ``None`` where the view has no mask for the frame; empty
    masks allowed: no silhouette term there) of a rig video, each checked against its camera's size;
    ``None`` when no view has masks."""
    if not any(v.masks for v in seq.videos):
        return None
    columns = []
    for c, view in enumerate(seq.views):
        cam = view.view.camera
        columns.append(
            [
                None if p is None else read_mask(p, size=(cam.width, cam.height), allow_empty=True)
                for p in seq.per_view(c, "masks")
            ]
        )
    return [[col[f] for col in columns] for f in range(len(seq.numbers))]
