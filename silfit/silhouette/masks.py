"""Reading and validating person masks.

Accepted: 8-bit or 16-bit greyscale, RGB whose channels agree (a grey image saved as
colour), and greyscale or RGB with an alpha channel whose alpha is opaque everywhere
(the colour carries the mask) or whose colour is constant (the alpha carries it).
Everything else (colour masks, palettes with several colours) is rejected with a message
naming the file. A mask is foreground where it is above half its type's range. Its size
is read from the file's header and checked against :mod:`silfit.io.limits` before the
pixels are decoded (by :mod:`silfit.io.images`).
"""

from __future__ import annotations

import os
from typing import Optional, Union

import numpy as np

from ..errors import InputError
from ..io.images import image_file_size, read_pixels

__all__ = ["read_mask", "validate_mask"]


def _binarise(channel: np.ndarray) -> np.ndarray:
    top = 65535 if channel.dtype == np.uint16 else 255 if channel.dtype == np.uint8 else 1.0
    return channel.astype(np.float64) > top / 2.0


def _to_binary(raw: np.ndarray, source: str) -> np.ndarray:
    if raw.ndim == 2:
        return _binarise(raw)
    if raw.ndim != 3 or raw.shape[2] not in (2, 3, 4):
        raise InputError(source, f"unsupported mask layout {raw.shape} (expected a greyscale image)")
    colour, alpha = (raw, None) if raw.shape[2] == 3 else (raw[..., :-1], raw[..., -1])
    grey_agrees = all(np.array_equal(colour[..., 0], colour[..., c]) for c in range(1, colour.shape[2]))
    if alpha is not None:
        top = 65535 if raw.dtype == np.uint16 else 255
        if np.all(alpha == top) and grey_agrees:
            return _binarise(colour[..., 0])
        if np.all(colour == colour.reshape(-1, colour.shape[2])[0]):
            return _binarise(alpha)
        raise InputError(
            source, "mask has an alpha channel and varying colour; save the person mask as a greyscale image"
        )
    if not grey_agrees:
        raise InputError(source, "mask is a colour image whose channels differ; expected a greyscale (binary) mask")
    return _binarise(colour[..., 0])


def _check_size(width: int, height: int, source: str, size: Optional[tuple[int, int]]) -> None:
    if size is not None and (width, height) != tuple(size):
        raise InputError(source, f"mask is {width}x{height} pixels but the image/camera is {size[0]}x{size[1]}")


def validate_mask(
    mask: np.ndarray, source: str, size: Optional[tuple[int, int]] = None, allow_empty: bool = False
) -> np.ndarray:
    """Check a boolean mask ``[H, W]``: not empty (unless ``allow_empty``), not all foreground,
    of ``size = (W, H)``."""
    _check_size(mask.shape[1], mask.shape[0], source, size)
    if not mask.any() and not allow_empty:
        raise InputError(source, "mask is empty (no foreground pixel)")
    if mask.all():
        raise InputError(source, "mask is foreground everywhere (all white); expected the person's silhouette")
    return mask


def read_mask(
    path: Union[str, os.PathLike], size: Optional[tuple[int, int]] = None, allow_empty: bool = False
) -> np.ndarray:
    """Read a person mask as a boolean array ``[H, W]`` (see the module docstring); ``allow_empty``
    accepts a mask without foreground (a video frame where the person was not segmented)."""
    source = os.fspath(path)
    if not os.path.isfile(source):
        raise FileNotFoundError(f"{source}: mask file not found")
    _check_size(*image_file_size(source, "mask"), source, size)
    raw = read_pixels(source, "mask")
    return validate_mask(_to_binary(raw, source), source, size, allow_empty)
