"""Reading the image files silfit is given (photos, person masks).

The size is read from the header and checked against :mod:`silfit.io.limits` before
any pixel is decoded; decoding is done by Pillow, whose failures (truncated, corrupt or
unknown files) become one :class:`~silfit.errors.InputError` naming the file, with no
decoder chatter on stderr.

:func:`read_pixels` keeps the file's own layout (greyscale ``[H, W]``, grey+alpha
``[H, W, 2]``, RGB ``[H, W, 3]``, RGBA ``[H, W, 4]``; ``uint8``, or ``uint16`` for 16-bit
greyscale); palettes become RGB(A); 32-bit integer greyscale is accepted when its values
fit 16 bits. Float, CMYK and other colour spaces are refused. :func:`read_rgb` (and
:func:`to_rgb8`, for an image already open) takes the same modes to RGB ``uint8``, 16-bit
values scaled to 8 bits (``v / 257``, so 65535 is 255), not clipped.
"""

from __future__ import annotations

import os
import warnings
from typing import Union

import numpy as np
from PIL import Image

from ..errors import InputError
from .limits import check_image_size

#: the image file names silfit lists in folders (video frames, masks, a rig view's images)
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")

__all__ = ["image_file_size", "pixels_to_rgb8", "read_pixels", "read_rgb", "to_rgb8"]

_NATIVE = ("L", "LA", "RGB", "RGBA")
_SIXTEEN_BIT = ("I;16", "I;16L", "I;16B", "I;16N")


def _open(source: str, what: str):
    if not os.path.isfile(source):
        raise FileNotFoundError(f"{source}: {what} file not found")
    try:
        with warnings.catch_warnings():  # Pillow warns about odd metadata; decoding reports real problems
            warnings.simplefilter("ignore")
            return Image.open(source)
    except Image.DecompressionBombError as err:
        raise InputError(source, f"{what} is larger than silfit accepts ({err})") from None
    except Exception as err:  # noqa: BLE001 - Pillow raises many kinds for files it cannot identify
        raise InputError(source, f"cannot read the {what} as an image ({type(err).__name__}: {err})") from None


def image_file_size(path: Union[str, os.PathLike], what: str = "image") -> tuple[int, int]:
    """``(width, height)`` from the file's header (nothing decoded), within the limits."""
    source = os.fspath(path)
    with _open(source, what) as im:
        width, height = im.size
    check_image_size(width, height, source, field=f"{what} size")
    return width, height


def _decoded(path: Union[str, os.PathLike], what: str, convert=None) -> np.ndarray:
    source = os.fspath(path)
    with _open(source, what) as im:
        check_image_size(*im.size, source, field=f"{what} size")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                im.load()
                return convert(im) if convert else _native(im, source, what)
        except InputError:
            raise
        except Exception as err:  # noqa: BLE001 - truncated / corrupt data, of every format
            raise InputError(source, f"cannot decode the {what} ({type(err).__name__}: {err})") from None


def _native(im, source: str, what: str) -> np.ndarray:
    mode = im.mode
    if mode == "1":
        return np.asarray(im.convert("L"))
    if mode in ("P", "PA"):
        return np.asarray(im.convert("RGBA" if mode == "PA" or "transparency" in im.info else "RGB"))
    if mode in _NATIVE:
        return np.asarray(im)
    if mode in _SIXTEEN_BIT:
        return np.asarray(im).astype(np.uint16)
    if mode == "I":
        arr = np.asarray(im)
        if arr.size and 0 <= arr.min() and arr.max() <= 65535:
            return arr.astype(np.uint16)
        raise InputError(source, f"{what} has 32-bit integer pixels outside 0..65535 (expected 8- or 16-bit)")
    raise InputError(source, f"unsupported {what} pixel mode {mode!r} (expected 8- or 16-bit greyscale, RGB or RGBA)")


def read_pixels(path: Union[str, os.PathLike], what: str = "image") -> np.ndarray:
    """The decoded pixels in the file's own layout (see the module docstring)."""
    return _decoded(path, what)


def to_rgb8(im, source: str, what: str = "image") -> np.ndarray:
    """An open Pillow image as RGB ``uint8 [H, W, 3]``: the modes :func:`read_pixels`
    reads, 16-bit values scaled (not clipped) to 8 bits; other modes refused (naming ``source``)."""
    if im.mode == "CMYK":
        raise InputError(
            source, f"{what} is in CMYK; silfit reads greyscale, RGB and RGBA images (convert it to RGB first)"
        )
    return pixels_to_rgb8(_native(im, source, what))


def pixels_to_rgb8(arr: np.ndarray) -> np.ndarray:
    """:func:`read_pixels`' layouts as RGB ``uint8 [H, W, 3]`` (grey repeated, alpha
    dropped, 16-bit values scaled: ``v / 257``, rounded)."""
    if arr.dtype == np.uint16:
        arr = ((arr.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)  # v / 257, rounded: 65535 -> 255
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.shape[2] in (1, 2):  # grey, grey + alpha
        arr = np.repeat(arr[..., :1], 3, axis=2)
    return np.ascontiguousarray(arr[..., :3])


def read_rgb(path: Union[str, os.PathLike], what: str = "image") -> np.ndarray:
    """The decoded image as RGB ``uint8 [H, W, 3]`` (see :func:`to_rgb8`)."""
    source = os.fspath(path)
    return _decoded(path, what, convert=lambda im: to_rgb8(im, source, what))
