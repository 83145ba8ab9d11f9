"""Size limits for the files and values silfit is given, checked before anything large is
allocated (every error is an :class:`~silfit.errors.InputError` naming the file or argument).

* Images, masks and cameras: at most :data:`MAX_IMAGE_SIDE` pixels per side and
  :data:`MAX_IMAGE_PIXELS` pixels in all (:mod:`silfit.io.images` reads an image's size
  from its header, before it is decoded).
* Text files (keypoint JSON, ``camera.json``, ``params.json``): at most
  :data:`MAX_JSON_BYTES`.

:func:`read_json` is the one JSON reader of silfit's input files (size-capped, every
failure an :class:`~silfit.errors.InputError` naming the file).
"""

from __future__ import annotations

import json
import os
from typing import Union

from ..errors import InputError

__all__ = [
    "MAX_IMAGE_SIDE",
    "MAX_IMAGE_PIXELS",
    "MAX_JSON_BYTES",
    "image_size_problem",
    "check_image_size",
    "check_file_size",
    "read_json",
]

#: Largest image/mask/camera side, pixels.
MAX_IMAGE_SIDE = 16384
#: Largest image/mask/camera area, pixels (64 MP: 8192 x 8192, more than a 48 MP phone photo).
MAX_IMAGE_PIXELS = 8192 * 8192
#: Largest JSON file read (keypoints, camera, fit parameters), bytes.
MAX_JSON_BYTES = 64 * 1024**2


def image_size_problem(width, height):
    """Why ``width x height`` is not an image size silfit accepts, or ``None``."""
    if width * height > MAX_IMAGE_PIXELS or max(width, height) > MAX_IMAGE_SIDE:
        return (
            f"{width}x{height} pixels is larger than silfit accepts (at most {MAX_IMAGE_SIDE} per side and "
            f"{MAX_IMAGE_PIXELS / 1e6:.0f} megapixels); downscale the image (and keypoints) first"
        )
    return None


def check_image_size(width: int, height: int, source: str, field: str = "size") -> None:
    """Raise :class:`InputError` for a size outside the limits (and for non-positive sides)."""
    if width <= 0 or height <= 0:
        raise InputError(source, f"{field} {width}x{height}: sides must be positive", field=field)
    problem = image_size_problem(width, height)
    if problem:
        raise InputError(source, f"{field} {problem}", field=field)


def check_file_size(path: Union[str, os.PathLike], limit: int = MAX_JSON_BYTES, what: str = "file") -> None:
    """Raise :class:`InputError` if ``path`` is larger than ``limit`` bytes."""
    size = os.path.getsize(path)
    if size > limit:
        raise InputError(
            path, f"{what} is {size / 1024**2:.0f} MiB, more than the {limit / 1024**2:.0f} MiB silfit reads"
        )


def read_json(path: Union[str, os.PathLike], what: str):
    """A JSON file silfit reads (at most :data:`~silfit.io.limits.MAX_JSON_BYTES`);
    ``FileNotFoundError`` or :class:`~silfit.errors.InputError` naming the file."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: {what} file not found")
    check_file_size(path, MAX_JSON_BYTES, f"the {what} file")
    try:
        with open(path, "r", encoding="utf-8") as fh:
            return json.load(fh)
    except UnicodeDecodeError:
        raise InputError(path, f"not a text (UTF-8 JSON) {what} file; is it a binary file?") from None
    except json.JSONDecodeError as err:
        raise InputError(path, f"not valid JSON ({err})") from None
    except RecursionError:
        raise InputError(path, "JSON nested too deeply") from None
    except (OSError, ValueError) as err:  # unreadable, or e.g. a number with too many digits
        raise InputError(path, f"cannot read the {what} file ({type(err).__name__}: {err})") from None
