"""The :class:`Job`: what every input builder (:mod:`silfit.inputs`) makes and :func:`silfit.run.run` fits."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from ..fitting.problem import Problem

__all__ = ["Job"]


@dataclass
class Job:
    """What to fit: ``problem`` (observations over frames x views of one person; a frame's
    keypoints may be ``None``: no detection there), the body ``model`` and the settings.

    ``silhouette_config`` ``None``: the defaults; ``silhouette=False``: no silhouette stage
    even where masks exist. ``view_names`` name the views (warnings, output folders);
    ``frame_numbers`` the frames (a video's file numbers). ``warnings`` are the input readers'
    findings, carried into the result; ``record`` is copied into ``metrics.json`` (the input
    files, the camera's source, the model); ``images`` maps ``(frame, view)`` to an RGB image
    for the pictures; ``inputs`` is the reader's own object where a writer needs more (a
    video's :class:`~silfit.io.video.SequenceInput`); ``rig`` marks views of a calibrated rig
    (world coordinates; with one view too)."""

    problem: Problem
    model: Any = None
    view_names: Sequence[str] = ("camera",)
    pose_prior: Any = None
    keypoint_config: Any = None
    silhouette_config: Any = None
    sequence_config: Any = None
    silhouette: bool = True
    progress: bool = False
    frame_numbers: Optional[Sequence[int]] = None
    warnings: List[str] = field(default_factory=list)
    record: Dict[str, Any] = field(default_factory=dict)
    images: Dict[tuple, np.ndarray] = field(default_factory=dict)
    mask_sources: Dict[tuple, str] = field(default_factory=dict)
    inputs: Any = None
    #: the views are a calibrated rig (fitted in its world frame), even when only one is left
    rig: bool = False
    #: the frames are a video's (the sequence fit and the video's outputs), even when it has one frame
    video: bool = False
    #: ``(frame, view)`` -> the detected :class:`~silfit.detect.Person` the keypoints came from (its 3D landmarks
    #: give the image depth cue without running the landmark model again; absent: run on ``images``)
    people: Dict[tuple, Any] = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        return self.problem.num_frames

    @property
    def num_views(self) -> int:
        return self.problem.num_views

    @property
    def layout(self) -> str:
        return next(o.keypoints.layout for o in self.problem.observations if o.keypoints is not None)

    @property
    def has_masks(self) -> bool:
        return any(o.mask is not None for o in self.problem.observations)

    @property
    def mode(self) -> str:
        """``"image"``, ``"rig"`` or ``"video"`` (what the frames x views shape is called)."""
        return (
            "video" if (self.video or self.num_frames > 1) else "rig" if (self.rig or self.num_views > 1) else "image"
        )
