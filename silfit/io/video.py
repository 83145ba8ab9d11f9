"""Reading a video's per-frame files: OpenPose's JSON per frame, optional masks and images.

OpenPose run on a video writes one file per frame, ``<video>_<frame, 12 digits>_keypoints.json``
(``--write_json``). :func:`read_sequence` reads such a folder (or, when the folder holds a
``keypoints/`` or ``openpose/`` sub-folder, that one; ``masks/``, ``images/`` and
``camera.json`` beside it are then picked up too, the layout ``silfit synth --videos``
writes; a ``camera.json`` among the keypoint files is picked up as well). Frames are ordered by
the number in their names; a number missing between the first and the last is a frame
with no detection, as is a file whose ``people`` list is empty (OpenPose writes those when
nobody is seen). Masks and images are matched to frames by the same number (the last run
of digits in their name).

Refused (an :class:`~silfit.errors.InputError` naming the file): a keypoint, mask or image
file with no frame number in its name; files of two videos in one folder (two name stems,
e.g. ``a_000000000000_keypoints.json`` and ``b_000000000000_keypoints.json``); more than
:data:`MAX_GAP` frame numbers missing in a row (a stray file from elsewhere would otherwise
make the sequence, and the memory it takes, as long as its number: fit the parts
separately); no mask or image matching any frame. Warned of
(:attr:`SequenceInput.warnings`): frames with a person but no mask, masks and images for
frame numbers the keypoints do not have (ignored).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

import numpy as np

from .._lazy import moved_function
from ..errors import InputError
from .images import IMAGE_EXTENSIONS
from .keypoints import KEYPOINT_FOLDERS, KeypointSet, read_keypoints
from .rig import RigView, holds_video, read_rig_views, select_views, video_folder

__all__ = [
    "RigSequence",
    "SequenceInput",
    "frame_number",
    "is_rig_video",
    "load_rig_sequence",
    "read_sequence",
    "write_overlay_video",
]

_KEYPOINTS = re.compile(r"^(?P<stem>.*?)_?(?P<num>\d+)?_keypoints\.json$")
_DIGITS = re.compile(r"(\d+)(?!.*\d)")

MAX_FRAMES = 100_000
#: Most frame numbers missing in a row (frames without detection, bridged by the fit).
MAX_GAP = 100


def frame_number(name: str) -> Optional[int]:
    """The frame number of a file name: the last run of digits before ``_keypoints.json``
    or the extension (``None`` if there is none)."""
    m = _KEYPOINTS.match(name)
    if m:
        return int(m.group("num")) if m.group("num") else None
    m = _DIGITS.search(Path(name).stem)
    return int(m.group(1)) if m else None


@dataclass
class SequenceInput:
    """Frames ``frames[i]`` (frame number ``numbers[i]``): a :class:`KeypointSet` or ``None``
    (no detection); ``masks`` / ``images``: frame number -> path; ``camera``: a
    ``camera.json`` found beside the keypoints (or ``None``)."""

    folder: Path
    numbers: List[int]
    frames: List[Optional[KeypointSet]]
    files: List[Optional[Path]]
    masks: Dict[int, Path] = field(default_factory=dict)
    images: Dict[int, Path] = field(default_factory=dict)
    camera: Optional[Path] = None
    warnings: List[str] = field(default_factory=list)

    @property
    def detected(self) -> int:
        return sum(ks is not None for ks in self.frames)


def _name_stem(name: str) -> str:
    """What a per-frame file's name holds besides its frame number (the video's name)."""
    m = _KEYPOINTS.match(name)
    if m:
        return m.group("stem")
    stem = Path(name).stem
    m = _DIGITS.search(stem)
    return stem[: m.start()].rstrip("_-. ") if m else stem


def _one_video(files: Dict[int, Path], what: str, folder: Path) -> None:
    """Refuse the per-frame files of two videos in one folder (two name stems)."""
    stems: Dict[str, List[int]] = {}
    for n, p in sorted(files.items()):
        stems.setdefault(_name_stem(p.name), []).append(n)
    if len(stems) > 1:
        (a, fa), (b, fb), *_ = sorted(stems.items(), key=lambda kv: -len(kv[1]))
        raise InputError(
            folder,
            f"{what} files of {len(stems)} videos in one folder: '{a}' (frames {fa[0]}..{fa[-1]}) and "
            f"'{b}' (frames {fb[0]}..{fb[-1]}); give each video's files their own folder",
        )


def _numbered(folder: Path, what: str) -> Dict[int, Path]:
    out: Dict[int, Path] = {}
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() not in IMAGE_EXTENSIONS or not p.is_file():
            continue
        n = frame_number(p.name)
        if n is None:
            raise InputError(p, f"{what} file name has no frame number (expected e.g. video_000000000012.png)")
        if n in out:
            raise InputError(p, f"two {what} files for frame {n}: {out[n].name} and {p.name}")
        out[n] = p
    _one_video(out, what, folder)
    return out


def _check_gaps(numbered: Dict[int, Path], folder: Path) -> None:
    """Refuse a run of more than :data:`MAX_GAP` missing frame numbers (naming the file after it)."""
    ordered = sorted(numbered)
    for before, after in zip(ordered, ordered[1:]):
        if after - before - 1 > MAX_GAP:
            raise InputError(
                numbered[after],
                f"frame {after} comes {after - before - 1} missing frames after frame {before} "
                f"(at most {MAX_GAP} are bridged); is it from another video? Fit the parts separately",
            )
    if ordered[-1] - ordered[0] + 1 > MAX_FRAMES:
        raise InputError(folder, f"frames {ordered[0]}..{ordered[-1]}: more than {MAX_FRAMES} frames")


def _match(files: Dict[int, Path], numbers: List[int], frames: list, what: str, folder: Path) -> List[str]:
    """Warnings for per-frame ``files`` (masks or images) that do not match the frames;
    an error when none does."""
    if not files:
        return []
    have = set(numbers)
    extra = sorted(set(files) - have)
    if len(extra) == len(files):
        raise InputError(
            folder,
            f"no {what} file matches a frame: {what}s for frames {extra[0]}..{extra[-1]}, keypoints "
            f"for {numbers[0]}..{numbers[-1]} (is it another video's folder?)",
        )
    out = (
        [f"{folder}: {len(extra)} {what}(s) for frames the keypoints do not have, ignored: {_listed(extra)}"]
        if extra
        else []
    )
    missing = [n for n, ks in zip(numbers, frames) if ks is not None and n not in files]
    if missing:
        effect = "no silhouette term there" if what == "mask" else "drawn without the image"
        out.append(f"{folder}: no {what} for {len(missing)} frame(s) with a person ({effect}): {_listed(missing)}")
    return out


def _listed(numbers: List[int], most: int = 10) -> str:
    return ", ".join(map(str, numbers[:most])) + (f", ... ({len(numbers) - most} more)" if len(numbers) > most else "")


def read_sequence(
    folder: Union[str, os.Union[str, os.PathLike]],
    masks: Optional[Union[str, os.Union[str, os.PathLike]]] = None,
    images: Optional[Union[str, os.Union[str, os.PathLike]]] = None,
    person: Union[int, str] = "largest",
) -> SequenceInput:
    """Read a folder of per-frame OpenPose JSON files (module docstring); ``masks`` and
    ``images`` are folders (default: ``masks/`` and ``images/`` beside a ``keypoints/``
    sub-folder, when present)."""
    root = Path(folder)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such folder")
    kp_dir = next((root / d for d in KEYPOINT_FOLDERS if (root / d).is_dir()), root)
    files = sorted(p for p in kp_dir.iterdir() if p.name.endswith("_keypoints.json") and p.is_file())
    if not files:
        raise InputError(kp_dir, "no OpenPose per-frame files (*_keypoints.json) in the folder")
    numbered = {}
    for p in files:
        n = frame_number(p.name)
        if n is None:
            raise InputError(
                p,
                "keypoint file name has no frame number (expected <video>_<frame, 12 digits>_keypoints.json, "
                "as OpenPose writes for a video)",
            )
        if n in numbered:
            raise InputError(p, f"two keypoint files for frame {n}: {numbered[n].name} and {p.name}")
        numbered[n] = p
    _one_video(numbered, "keypoint", kp_dir)
    _check_gaps(numbered, kp_dir)
    first, last = min(numbered), max(numbered)
    numbers = list(range(first, last + 1))
    frames: List[Optional[KeypointSet]] = []
    for n in numbers:
        p = numbered.get(n)
        if p is None:
            frames.append(None)
            continue
        try:
            frames.append(read_keypoints(p, person=person))
        except InputError as err:
            # OpenPose: nobody seen in this frame (no people, or a person with every confidence 0)
            if (err.field == "people" and "empty" in str(err)) or "all keypoint confidences are zero" in str(err):
                frames.append(None)
            else:
                raise
    if not any(ks is not None for ks in frames):
        raise InputError(kp_dir, f"no person detected in any of the {len(files)} frames")
    layouts = {ks.layout for ks in frames if ks is not None}
    if len(layouts) > 1:
        raise InputError(kp_dir, f"frames mix keypoint layouts ({', '.join(sorted(layouts))})")
    side = kp_dir.parent if kp_dir != root else None
    mdir = Path(masks) if masks else (side / "masks" if side and (side / "masks").is_dir() else None)
    idir = Path(images) if images else (side / "images" if side and (side / "images").is_dir() else None)
    for d, what in ((mdir, "masks"), (idir, "images")):
        if d is not None and not d.is_dir():
            raise FileNotFoundError(f"{d}: no such folder ({what})")
    cam = next((d / "camera.json" for d in (kp_dir, side) if d is not None and (d / "camera.json").is_file()), None)
    mask_files, image_files = _numbered(mdir, "mask") if mdir else {}, _numbered(idir, "image") if idir else {}
    warnings = _match(mask_files, numbers, frames, "mask", mdir) + _match(image_files, numbers, frames, "image", idir)
    return SequenceInput(
        root, numbers, frames, [numbered.get(n) for n in numbers], mask_files, image_files, cam, warnings
    )


# ----------------------------------------------------------------------------- a video's pictures
def write_overlay_video(path: Path, pictures, fps: float) -> Optional[Path]:
    """An animated GIF of ``pictures`` (with imageio when installed, else with Pillow)."""
    try:
        import imageio.v3 as iio
    except ImportError:
        from PIL import Image

        frames = [Image.fromarray(np.asarray(p, dtype=np.uint8)) for p in pictures]
        frames[0].save(
            path, format="GIF", save_all=True, append_images=frames[1:], duration=int(round(1000.0 / fps)), loop=0
        )
        return path
    iio.imwrite(path, np.stack(pictures), extension=".gif", duration=1000.0 / fps, loop=0)
    return path


# ----------------------------------------------------------------------------- rig videos
# A rig video is a video seen by a calibrated rig: the rig's cameras (silfit.io.rig's readers) and,
# per view, a video folder as read_sequence reads it.


def is_rig_video(folder: Union[str, os.PathLike]) -> bool:
    """Whether a rig folder holds a video: its views' folders hold per-frame keypoints
    (:func:`load_rig_sequence`) instead of one ``keypoints.json``."""
    views = read_rig_views(Path(folder))
    return all(v.keypoints is not None and not v.keypoints.is_file() and holds_video(video_folder(v)) for v in views)


@dataclass
class RigSequence:
    """A rig video: the rig's views (cameras; :func:`video_folder` holds each one's frames), each
    view's :class:`silfit.io.video.SequenceInput`, and the frames of all views aligned by number:
    ``numbers [F]`` (every number from the first to the last of any view), ``frames[f][c]`` a
    :class:`~silfit.io.keypoints.KeypointSet` or ``None`` (not detected in that view)."""

    folder: Path
    views: List[RigView]
    videos: list
    numbers: List[int]
    frames: List[List[object]]
    warnings: List[str] = field(default_factory=list)

    @property
    def names(self) -> List[str]:
        return [v.name for v in self.views]

    def files(self, c: int) -> List[Optional[Path]]:
        """View ``c``'s keypoint file per frame (``None``: no file)."""
        video = self.videos[c]
        by_number = dict(zip(video.numbers, video.files))
        return [by_number.get(n) for n in self.numbers]

    def select_views(self, indices: Sequence[int]) -> "RigSequence":
        """Only the views ``indices`` (in that order), e.g. after views were set aside."""
        idx = list(indices)
        return replace(
            self,
            views=[self.views[c] for c in idx],
            videos=[self.videos[c] for c in idx],
            frames=[[row[c] for c in idx] for row in self.frames],
        )

    def per_view(self, c: int, what: str) -> List[Optional[Path]]:
        """View ``c``'s ``"masks"`` or ``"images"`` file per frame (``None``: none)."""
        files = getattr(self.videos[c], what)
        return [files.get(n) for n in self.numbers]


def load_rig_sequence(folder: Union[str, os.PathLike], person: Union[int, str] = "largest", names=None) -> RigSequence:
    """A rig video (the rig folder of :func:`silfit.io.rig.load_rig`: ``cameras.json``, EasyMocap's calibration or
    sub-folders with ``camera.json``) whose views' folders are video folders as
    :func:`read_sequence` reads them (per-frame OpenPose JSON, optional ``masks/`` and
    ``images/``; the layout ``silfit synth --videos --cameras N`` writes). Frames are matched across
    views by their number; a view without a frame's number has no detection there. ``names``: only
    these views (in the rig's order; an unknown name is an :class:`~silfit.errors.InputError`)."""
    folder = Path(folder)
    views = select_views(read_rig_views(folder), names)
    videos = []
    for v in views:
        d = video_folder(v)
        if not holds_video(d):
            raise InputError(
                d,
                f"view {v.name}: no per-frame keypoints (*_keypoints.json, or keypoints/ or openpose/ "
                "with them) for a rig video",
                field="keypoints",
            )
        videos.append(read_sequence(d, person=person))
    first, last = min(s.numbers[0] for s in videos), max(s.numbers[-1] for s in videos)
    have = sorted({n for s in videos for n, ks in zip(s.numbers, s.frames)})
    for a, b in zip(have, have[1:]):
        if b - a - 1 > MAX_GAP:
            raise InputError(
                folder,
                f"the views' frames {a} and {b} are {b - a - 1} frames apart (at most {MAX_GAP} are "
                "bridged); are all views of one recording?",
            )
    numbers = list(range(first, last + 1))
    frames = []
    for n in numbers:
        row = []
        for s in videos:
            i = n - s.numbers[0]
            row.append(s.frames[i] if 0 <= i < len(s.numbers) else None)
        frames.append(row)
    warnings = [w for v, s in zip(views, videos) for w in list(v.warnings) + list(s.warnings)]
    return RigSequence(folder, views, videos, numbers, frames, warnings)


def __getattr__(name: str):
    """``save_sequence_fit`` moved to :mod:`silfit.outputs.write` (the one writer); the old name works for one release."""
    if name == "save_sequence_fit":
        return moved_function(__name__, name, "silfit.outputs.write")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
