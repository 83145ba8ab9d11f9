"""Whole-body 2D keypoints (OpenPose's whole-body layout: BODY_25 + 2 x 21 hand + 70 face points):
reading, writing and validating OpenPose whole-body JSON, and choosing which keypoints a fit uses.
The layout's parts and their sources on an SMPL-X-layout model are in :mod:`silfit.layouts` (their
names are kept here too)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np

from ..errors import InputError
from .keypoints import KeypointSet, keypoint_triplets
from ..layouts import (  # noqa: F401  (re-exported: silfit.io.wholebody's names kept)
    BODY25_NAMES,
    FACE70_NAMES,
    FINGERS,
    HAND21_NAMES,
    PART_FIELDS,
    WHOLEBODY_NAMES,
    WHOLEBODY_PARTS,
    hand_names,
    part_slices,
    wholebody_keypoints,
    wholebody_sources,
)
from .limits import read_json

__all__ = [
    "FINGERS",
    "HAND21_NAMES",
    "FACE70_NAMES",
    "PART_FIELDS",
    "WHOLEBODY_PARTS",
    "part_slices",
    "wholebody_sources",
    "WholeBodyKeypoints",
    "hand_names",
    "wholebody_keypoints",
    "read_wholebody",
    "write_wholebody_json",
]


@dataclass
class WholeBodyKeypoints:
    """One person's whole-body detections: ``body`` (a BODY_25 :class:`KeypointSet`) and, per part,
    ``[K, 3]`` rows of x, y, confidence, or ``None`` where the file has no such part."""

    body: KeypointSet
    hand_left: Optional[np.ndarray]
    hand_right: Optional[np.ndarray]
    face: Optional[np.ndarray]
    source: str = "<array>"

    def part(self, name: str) -> Optional[np.ndarray]:
        return self.body.as_array() if name == "body" else getattr(self, name)

    def present(self) -> dict:
        """``{part: bool}``: the part is in the file with at least one confident point."""
        return {p: (a := self.part(p)) is not None and bool((a[:, 2] > 0).any()) for p in WHOLEBODY_PARTS}

    @property
    def has_parts(self) -> bool:
        """Hand or face points are present (a whole-body file, not a body-only one)."""
        pres = self.present()
        return pres["hand_left"] or pres["hand_right"] or pres["face"]

    def as_keypoint_set(self) -> KeypointSet:
        """One :class:`KeypointSet` of the ``wholebody`` layout (absent parts: confidence 0)."""
        rows = [
            self.part(p) if self.part(p) is not None else np.zeros((n, 3))
            for p, (_, n) in zip(WHOLEBODY_PARTS, PART_FIELDS.values())
        ]
        arr = np.concatenate(rows, 0)
        return KeypointSet(arr[:, :2], arr[:, 2], "wholebody", source=self.source)


def _part_array(values, count: int, source: str, field: str) -> Optional[np.ndarray]:
    if values is None:
        return None
    if isinstance(values, list) and not values:
        return None  # OpenPose writes [] for a part it was not asked to detect (anything else: keypoint_triplets checks it)
    arr = keypoint_triplets(values, source, field)
    if arr.shape[0] != count:
        raise ValueError(f"{source}: field '{field}' has {arr.shape[0]} keypoints, expected {count}")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise ValueError(
            f"{source}: field '{field}' has NaN or infinite values at point(s) {', '.join(map(str, np.flatnonzero(bad)[:5]))}"
        )
    if (arr[:, 2] < 0).any():
        raise ValueError(f"{source}: field '{field}' has negative confidences")
    return arr


def validate_wholebody(kp: WholeBodyKeypoints, require=("body",)) -> WholeBodyKeypoints:
    """Every part in ``require`` present with at least one confident point, else a clear error."""
    fields = {part: field for field, (part, _) in PART_FIELDS.items()}
    for part in require:
        arr = kp.part(part)
        if arr is None:
            raise ValueError(f"{kp.source}: field '{fields[part]}' is missing or empty")
        if not (arr[:, 2] > 0).any():
            raise ValueError(f"{kp.source}: field '{fields[part]}': all keypoint confidences are zero")
    return kp


def read_wholebody(
    path: Union[str, os.PathLike], person: Union[int, str] = "largest", require=("body",)
) -> WholeBodyKeypoints:
    """Read OpenPose whole-body JSON (``people[i]`` with ``pose_keypoints_2d`` (BODY_25),
    ``hand_left_keypoints_2d`` / ``hand_right_keypoints_2d`` (21 each) and ``face_keypoints_2d`` (70)).
    Parts that are absent or ``[]`` are ``None``; the parts in ``require`` must be present with a
    confident point. ``person``: an index or ``"largest"`` (by the body's confident extent)."""
    source = os.fspath(path)
    data = read_json(source, "keypoint")  # size limit, UTF-8, nesting depth: one line naming the file
    if not isinstance(data, dict) or not isinstance(data.get("people"), list):
        raise ValueError(f"{source}: not OpenPose JSON (no 'people' list)")
    if not data["people"]:
        raise ValueError(f"{source}: field 'people' is empty: no person detected")
    people = []
    for i, p in enumerate(data["people"]):
        if not isinstance(p, dict) or "pose_keypoints_2d" not in p:
            raise ValueError(f"{source}: field 'people[{i}].pose_keypoints_2d' is missing")
        parts = {}
        for field, (part, count) in PART_FIELDS.items():
            parts[part] = _part_array(p.get(field), count, source, f"people[{i}].{field}")
        if parts["body"] is None:
            raise ValueError(f"{source}: field 'people[{i}].pose_keypoints_2d' is empty")
        body = KeypointSet(
            parts["body"][:, :2], parts["body"][:, 2], "body25", source=f"{source} (people[{i}].pose_keypoints_2d)"
        )
        people.append(
            WholeBodyKeypoints(
                body, parts["hand_left"], parts["hand_right"], parts["face"], source=f"{source} (people[{i}])"
            )
        )
    if person == "largest":
        chosen = max(people, key=lambda k: k.body.visible_area())
    else:
        index = int(person)
        if not 0 <= index < len(people):
            raise ValueError(f"{source}: person {index} requested, the file holds {len(people)}")
        chosen = people[index]
    return validate_wholebody(chosen, require)


def write_wholebody_json(
    path: Union[str, os.PathLike], body: np.ndarray, hand_left=None, hand_right=None, face=None
) -> None:
    """Write one person's whole-body keypoints (``[K, 3]`` x, y, confidence per part; ``None`` parts
    are written as ``[]``) as OpenPose JSON. Non-finite points become zeros with zero confidence."""
    person = {"person_id": [-1]}
    for (field, (part, count)), arr in zip(PART_FIELDS.items(), (body, hand_left, hand_right, face)):
        if arr is None:
            person[field] = []
            continue
        kp = np.asarray(arr, dtype=np.float64).copy()
        if kp.shape != (count, 3):
            raise ValueError(f"{os.fspath(path)}: {part} keypoints have shape {kp.shape}, expected ({count}, 3)")
        kp[~np.isfinite(kp).all(axis=1)] = 0.0
        person[field] = [round(float(v), 4) for v in kp.reshape(-1)]
    for field in ("pose_keypoints_3d", "face_keypoints_3d", "hand_left_keypoints_3d", "hand_right_keypoints_3d"):
        person[field] = []
    tmp = Path(f"{os.fspath(path)}.tmp")
    tmp.write_text(json.dumps({"version": 1.3, "people": [person]}))
    os.replace(tmp, path)


def read_wholebody_parts(path, person: Union[int, str] = "largest") -> Optional[WholeBodyKeypoints]:
    """The file's whole-body parts when it is OpenPose JSON with ``pose_keypoints_2d`` of BODY_25
    (hand / face fields may be absent), else ``None`` (another format: read it with
    :func:`silfit.io.keypoints.read_keypoints`)."""

    try:
        data = read_json(path, "keypoint")
    except (OSError, ValueError):
        return None  # read_keypoints reports unreadable files
    people = data.get("people") if isinstance(data, dict) else None
    if not isinstance(people, list) or not people or not all(isinstance(p, dict) for p in people):
        return None
    if any(len(p.get("pose_keypoints_2d") or []) != 3 * len(BODY25_NAMES) for p in people):
        return None
    try:
        return read_wholebody(path, person)
    except ValueError as err:
        raise InputError(os.fspath(path), str(err).split(": ", 1)[-1]) from None


def choose_fit_keypoints(keypoints: KeypointSet, wholebody: Optional[WholeBodyKeypoints], model) -> tuple:
    """``(keypoints, note)`` to fit ``model`` with: the ``wholebody`` layout for an SMPL-X-layout
    model (a body-only file: hands and face at confidence 0, so they stay at rest), the body part
    for an SMPL-layout model (a note says that hands and face are not fitted)."""
    if getattr(model, "kind", "smpl") == "smplx":
        if keypoints.layout != "body25":
            raise ValueError(
                f"{keypoints.source}: an SMPL-X-layout model is fitted to OpenPose BODY_25 / whole-body "
                f"keypoints, not {keypoints.layout}"
            )
        wb = wholebody or WholeBodyKeypoints(keypoints, None, None, None, source=keypoints.source)
        return wb.as_keypoint_set(), None
    if wholebody is not None and wholebody.has_parts:
        return keypoints, f"{model.source} is an SMPL-layout model: hand and face keypoints are not fitted"
    return keypoints, None
