"""2D keypoints of one person (:class:`KeypointSet`) and the body keypoint files silfit reads and
writes (OpenPose BODY_25 / COCO-17 JSON). The layouts and their sources on a body model are in
:mod:`silfit.layouts` (their names are kept here too)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Optional, Union

import numpy as np

from ..errors import InputError, quoted
from ..layouts import (  # noqa: F401  (re-exported: silfit.io.keypoints's names kept)
    BLAZEPOSE33_NAMES,
    BODY25_NAMES,
    COCO17_NAMES,
    LAYOUTS,
    WHOLEBODY_NAMES,
    layout_names,
    keypoint_sources,
    model_keypoints,
)
from .limits import read_json

#: Sub-folders of a video folder (or a rig video's view) that hold per-frame OpenPose files, in order of preference.
KEYPOINT_FOLDERS = ("keypoints", "openpose")

__all__ = [
    "BLAZEPOSE33_NAMES",
    "BODY25_NAMES",
    "COCO17_NAMES",
    "LAYOUTS",
    "WHOLEBODY_NAMES",
    "KeypointSet",
    "keypoint_sources",
    "model_keypoints",
    "read_keypoints",
    "write_openpose_json",
]


class KeypointSet:
    """Detected 2D keypoints of one person: ``xy [K, 2]`` pixels, ``conf [K]`` in [0, 1]."""

    def __init__(self, xy, conf, layout: str, source: str = "<array>"):
        names = layout_names(layout)
        xy = np.asarray(xy, dtype=np.float64)
        conf = np.asarray(conf, dtype=np.float64)
        if xy.shape != (len(names), 2) or conf.shape != (len(names),):
            raise InputError(
                source,
                f"keypoints have shape {xy.shape} with {conf.shape} confidences, expected "
                f"{len(names)} points of [x, y, confidence] for layout {layout}",
            )
        bad = ~np.isfinite(xy).all(axis=1) | ~np.isfinite(conf)
        if bad.any():
            raise InputError(
                source, f"keypoint(s) {', '.join(names[i] for i in np.flatnonzero(bad))} are NaN or infinite"
            )
        if (conf < 0).any():
            raise InputError(source, f"negative confidence for {', '.join(names[i] for i in np.flatnonzero(conf < 0))}")
        if not (conf > 0).any():
            raise InputError(source, "all keypoint confidences are zero: no person to fit")
        self.xy, self.conf, self.layout, self.source = xy, conf, layout.lower(), source

    @property
    def names(self) -> tuple:
        return LAYOUTS[self.layout]

    def __len__(self) -> int:
        return len(self.names)

    def as_array(self) -> np.ndarray:
        """``[K, 3]`` rows of ``x, y, confidence``."""
        return np.concatenate([self.xy, self.conf[:, None]], axis=1)

    def visible_area(self) -> float:
        vis = self.xy[self.conf > 0]
        return float(np.prod(vis.max(0) - vis.min(0) + 1.0)) if len(vis) else 0.0


def _number(value) -> bool:
    """A JSON number, or null (read as NaN, which :class:`KeypointSet` then reports by name)."""
    return value is None or (isinstance(value, (int, float)) and not isinstance(value, bool))


def keypoint_triplets(values, source: str, field: str) -> np.ndarray:
    """``[K, 3]`` from a flat list of numbers or a list of ``[x, y, confidence]`` lists;
    anything else (strings, booleans, nesting, ragged rows) is refused naming the field."""
    if not isinstance(values, list):
        raise InputError(source, f"field '{field}' must be a list of numbers, got {type(values).__name__}", field=field)
    if values and all(isinstance(v, list) for v in values):
        for i, row in enumerate(values):
            if len(row) != 3:
                raise InputError(
                    source, f"field '{field}[{i}]' has {len(row)} values, expected [x, y, confidence]", field
                )
        flat = [v for row in values for v in row]
    else:
        flat = values
    for i, v in enumerate(flat):
        if not _number(v):
            shown = quoted(v) if not isinstance(v, (list, dict)) else type(v).__name__
            raise InputError(source, f"field '{field}' value {i} is {shown}, expected a number", field=field)
    if len(flat) % 3:
        raise InputError(
            source, f"field '{field}' holds {len(flat)} numbers, not a multiple of 3 (x, y, confidence)", field
        )
    try:
        return np.asarray([np.nan if v is None else v for v in flat], dtype=np.float64).reshape(-1, 3)
    except OverflowError:  # an integer beyond float range
        raise InputError(
            source, f"field '{field}' holds a number too large for a pixel coordinate", field=field
        ) from None


def _layout_for_count(count: int, source: str, field: str) -> str:
    for name, names in LAYOUTS.items():
        if len(names) == count:
            return name
    raise InputError(
        source,
        f"field '{field}' has {count} keypoints; expected 25 (OpenPose BODY_25), 17 (COCO-17) or 33 (BlazePose)",
        field,
    )


def read_keypoints(path: Union[str, os.PathLike], person: Union[int, str] = "largest") -> KeypointSet:
    """Read a keypoint file: OpenPose JSON (``people[i].pose_keypoints_2d``, 25 or 17 points), a COCO annotation (``keypoints`` flat list of 17 x 3,
    or a list of such annotations), or a plain JSON list of 25/17 ``[x, y, score]``.

    ``person`` picks one of several people: an index or ``"largest"`` (largest extent
    of its confident keypoints).
    """
    source = os.fspath(path)
    data = read_json(source, "keypoint")

    candidates: list[tuple[str, np.ndarray]] = []
    if isinstance(data, dict) and "people" in data:
        people = data["people"]
        if not isinstance(people, list) or not people:
            raise InputError(source, "field 'people' is empty: no person detected", field="people")
        for i, p in enumerate(people):
            field = f"people[{i}].pose_keypoints_2d"
            if not isinstance(p, dict) or "pose_keypoints_2d" not in p:
                raise InputError(source, f"field '{field}' is missing", field=field)
            candidates.append((field, keypoint_triplets(p["pose_keypoints_2d"], source, field)))
    elif isinstance(data, dict) and "keypoints" in data:
        candidates.append(("keypoints", keypoint_triplets(data["keypoints"], source, "keypoints")))
    elif isinstance(data, list) and data and isinstance(data[0], dict):
        for i, ann in enumerate(data):
            if not isinstance(ann, dict) or "keypoints" not in ann:
                raise InputError(source, f"field '[{i}].keypoints' is missing", field=f"[{i}].keypoints")
            candidates.append((f"[{i}].keypoints", keypoint_triplets(ann["keypoints"], source, f"[{i}].keypoints")))
    elif isinstance(data, list):
        candidates.append(("<list>", keypoint_triplets(data, source, "<top-level list>")))
    else:
        raise InputError(source, "no keypoints found (expected OpenPose 'people', COCO 'keypoints' or a list)")

    sets = []
    for field, arr in candidates:
        layout = _layout_for_count(arr.shape[0], source, field)
        sets.append(KeypointSet(arr[:, :2], arr[:, 2], layout, source=f"{source} ({field})"))
    if person == "largest":
        return max(sets, key=lambda s: s.visible_area())
    index = int(person)
    if not 0 <= index < len(sets):
        raise InputError(source, f"person {index} requested, the file holds {len(sets)}", field="people")
    return sets[index]


def write_openpose_json(path: Union[str, os.PathLike], keypoints: np.ndarray, extra: Optional[dict] = None) -> None:
    """Write ``[K, 3]`` keypoints (x, y, confidence) as OpenPose JSON with one person, or
    ``[P, K, 3]`` with P people (``extra`` is added to each person's entry).
    Non-finite coordinates are written as zeros with zero confidence, as OpenPose does."""
    kp = np.asarray(keypoints, dtype=np.float64).copy()
    kp = kp[None] if kp.ndim == 2 else kp
    missing = ~np.isfinite(kp).all(axis=2)
    kp[missing] = 0.0
    people = [
        {"person_id": [-1], "pose_keypoints_2d": [round(float(v), 4) for v in k.reshape(-1)], **(extra or {})}
        for k in kp
    ]
    payload = {"version": 1.3, "people": people}
    tmp = Path(f"{os.fspath(path)}.tmp")
    tmp.write_text(json.dumps(payload))
    os.replace(tmp, path)
