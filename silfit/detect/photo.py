"""Photos: the pixels (upright, per the EXIF orientation) and the focal length the EXIF
data gives, in pixels.

Focal length, in order of preference:

1. ``FocalLengthIn35mmFilm``: the 35 mm equivalent, converted through the diagonal
   (a 36 x 24 mm frame's diagonal is 43.27 mm, so ``f_px = f35 * diagonal_px / 43.27``),
   which is how the equivalent focal length is defined (equal diagonal angle of view);
2. ``FocalLength`` (mm) with ``FocalPlaneXResolution`` / ``FocalPlaneResolutionUnit``
   (sensor pixels per unit), rescaled when the image is smaller than ``PixelXDimension``;
3. none: the caller's default (silfit's ``max(W, H)``).

A focal length outside the bounds a camera file's must meet
(:data:`silfit.camera.FOCAL_RANGE` times the image's longer side) is ignored: the default
is used and :meth:`Photo.warnings` says why. So is an EXIF block Pillow cannot parse.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from ..camera import FOCAL_RANGE
from ..errors import InputError
from ..io.images import image_file_size, to_rgb8

__all__ = ["Photo", "read_photo", "focal_from_exif", "FULL_FRAME_DIAGONAL_MM"]

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
_EXIF_IFD = 0x8769
_TAGS = {
    "FocalLength": 0x920A,
    "FocalLengthIn35mmFilm": 0xA405,
    "FocalPlaneXResolution": 0xA20E,
    "FocalPlaneResolutionUnit": 0xA210,
    "PixelXDimension": 0xA002,
}
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}  # inch, cm, mm, micrometre


@dataclass
class Photo:
    image: np.ndarray  # uint8 [H, W, 3] RGB, upright
    path: str
    exif: dict = field(default_factory=dict)  # the focal-related tags found (name -> float)
    stored_width: int = 0  # width as stored in the file (before the EXIF rotation)
    notes: List[str] = field(default_factory=list)  # problems met while reading (malformed EXIF)

    @property
    def size(self) -> Tuple[int, int]:
        return self.image.shape[1], self.image.shape[0]

    def focal(self) -> Tuple[Optional[float], str]:
        """``(focal_px or None, how it was found)``."""
        return focal_from_exif(self.exif, self.size, self.stored_width)

    def warnings(self) -> List[str]:
        """What was ignored in the file: a malformed EXIF block, an implausible focal length."""
        focal, source = self.focal()
        ignored = focal is None and _exif_focal(self.exif, self.size, self.stored_width)[0] is not None
        return self.notes + ([f"{self.path}: {source}"] if ignored else [])


def _number(value) -> Optional[float]:
    try:
        v = float(value[0]) / float(value[1]) if isinstance(value, tuple) else float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def read_photo(path: os.PathLike) -> Photo:
    """Read a photo (any format Pillow reads) as upright RGB, with its focal-length EXIF tags.
    Errors name the file: not found, not a readable image, no pixels."""

    source = os.fspath(path)
    if not os.path.isfile(source):
        raise FileNotFoundError(f"{source}: image not found")
    image_file_size(source, "image")  # the size limits, from the header, before any pixel is decoded
    problems: list = []
    try:
        with warnings.catch_warnings(record=True) as caught:  # Pillow's warnings of malformed EXIF: one note below
            warnings.simplefilter("always")
            with Image.open(source) as im:
                im.load()
                stored_width = im.size[0]
                exif = _focal_tags(im, problems)
                try:
                    upright = ImageOps.exif_transpose(im)
                except Exception as err:  # noqa: BLE001 - an orientation tag Pillow cannot apply
                    upright = im
                    problems.append(err)
                arr = to_rgb8(upright, source, "image")
    except InputError:
        raise
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as err:
        raise ValueError(f"{source}: not a readable image ({err})") from None
    problems = [str(w.message) for w in caught] + [str(e) for e in problems]
    notes = [f"{source}: malformed EXIF data ignored ({' '.join(problems[0].split())[:80]})"] if problems else []
    if arr.ndim != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{source}: the image is empty ({arr.shape[1] if arr.ndim > 1 else 0}x{arr.shape[0]} pixels)")
    return Photo(image=np.ascontiguousarray(arr), path=source, exif=exif, stored_width=stored_width, notes=notes)


def _focal_tags(im, problems: list) -> dict:
    """The focal-related EXIF tags of an open image (name -> positive float); a malformed
    EXIF block gives none (its error appended to ``problems``), not an unreadable image."""
    exif = {}
    try:
        raw = im.getexif()
        ifd = raw.get_ifd(_EXIF_IFD)
        for name, tag in _TAGS.items():
            v = _number(ifd.get(tag, raw.get(tag)))
            if v is not None:
                exif[name] = v
    except Exception as err:  # noqa: BLE001 - Pillow raises many kinds for malformed EXIF
        problems.append(err)
        return {}
    return exif


def focal_from_exif(exif: dict, size: Tuple[int, int], stored_width: int = 0) -> Tuple[Optional[float], str]:
    """The focal length in pixels from EXIF tags (see the module docstring) for an image of
    ``size = (W, H)``; ``(None, reason)`` when the tags do not give one or it lies outside
    :data:`silfit.camera.FOCAL_RANGE` times the longer side."""
    focal, source = _exif_focal(exif, size, stored_width)
    side = max(size)
    if focal is not None and not FOCAL_RANGE[0] * side <= focal <= FOCAL_RANGE[1] * side:
        return None, (
            f"{source} gives {focal:.4g} px, {focal / side:.3g} times the image's longer side (expected "
            f"{FOCAL_RANGE[0]:g} to {FOCAL_RANGE[1]:g} times, as for a camera file): ignored, the default focal length max(W, H) used"
        )
    return focal, source


def _exif_focal(exif: dict, size: Tuple[int, int], stored_width: int) -> Tuple[Optional[float], str]:
    W, H = size
    f35 = exif.get("FocalLengthIn35mmFilm")
    if f35:
        return f35 * math.hypot(W, H) / FULL_FRAME_DIAGONAL_MM, f"EXIF FocalLengthIn35mmFilm ({f35:g} mm)"
    f_mm, xres, unit = (
        exif.get("FocalLength"),
        exif.get("FocalPlaneXResolution"),
        exif.get("FocalPlaneResolutionUnit", 2),
    )
    if f_mm and xres and int(unit) in _UNIT_MM:
        px_per_mm = xres / _UNIT_MM[int(unit)]
        stored = stored_width or W
        scale = stored / exif["PixelXDimension"] if exif.get("PixelXDimension") else 1.0
        return f_mm * px_per_mm * scale, f"EXIF FocalLength ({f_mm:g} mm) and FocalPlaneXResolution"
    if f_mm:
        return None, f"EXIF FocalLength ({f_mm:g} mm) without the sensor size"
    return None, "no focal length in EXIF"
