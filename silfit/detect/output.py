"""A photo in, people out: :func:`detect_photo`, and the folder ``silfit detect`` writes
(:func:`save_detection`)::

    keypoints.json    OpenPose JSON, one entry in ``people`` per person (largest first),
                      ``pose_keypoints_2d`` in BODY_25 (or layout="coco17" / "blazepose33")
    mask.png          the first (largest) person's mask, 8-bit grey 0/255
    mask_<i>.png      the masks of people 1, 2, ... (with several people)
    detection.json    per person: detector score, regions, the 33 BlazePose landmarks with
                      visibility / presence / confidence, what is not visible, warnings;
                      plus the image size, the EXIF focal length (if any, within the
                      camera file's bounds) and the photo's warnings (an EXIF focal
                      length out of bounds or malformed EXIF data, ignored)
    detection.png     the image with masks, regions and skeletons drawn

Written into a temporary folder beside the target and moved into place at the end, so
a failed run leaves nothing half-written.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import List, Optional, Tuple

import numpy as np

from ..io.keypoints import write_openpose_json
from ..io.subjects import write_png
from ..outputs.folder import atomic_folder
from .draw import detection_overlay
from .person import DetectConfig, Person, detect_people
from .photo import Photo, read_photo

__all__ = ["detect_photo", "save_detection"]


def detect_photo(path: os.PathLike, config: Optional[DetectConfig] = None) -> Tuple[Photo, List[Person]]:
    """Read ``path`` and detect its people, ordered largest first (the extent of their
    confident keypoints, as ``read_keypoints(person="largest")`` ranks them)."""
    photo = read_photo(path)
    people = detect_people(photo.image, config, source=photo.path)
    people.sort(key=lambda p: -p.keypoint_set().visible_area())
    return photo, people


def save_detection(
    out: os.PathLike, photo: Photo, people: List[Person], layout: str = "body25", overwrite: bool = False
) -> Path:
    out = Path(out)
    with atomic_folder(out, overwrite) as tmp:
        write_openpose_json(tmp / "keypoints.json", np.stack([p.keypoints(layout) for p in people]))
        for i, p in enumerate(people):
            write_png(tmp / ("mask.png" if i == 0 else f"mask_{i}.png"), p.mask())
        write_png(tmp / "detection.png", detection_overlay(photo.image, people))
        focal, focal_source = photo.focal()
        report = {
            "image": photo.path,
            "width": photo.size[0],
            "height": photo.size[1],
            "layout": layout,
            "focal_px": focal,
            "focal_source": focal_source,
            "warnings": photo.warnings(),
            "models": "MediaPipe BlazePose GHUM pose_detection + pose_landmark_full (mediapipe 0.10.21)",
            "people": [p.to_dict() for p in people],
        }
        (tmp / "detection.json").write_text(json.dumps(report, indent=2))
    return out
