"""Output folders written atomically: everything goes into a temporary folder beside the
target, which replaces the target only once it is complete. An earlier output is set
aside before the swap and removed after it, so a crash at any point leaves either the old
folder or the new one, never neither and never a half-written one."""

from __future__ import annotations

import os
import secrets
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Union

__all__ = ["atomic_folder"]


@contextmanager
def atomic_folder(out: Union[str, os.PathLike], overwrite: bool = False) -> Iterator[Path]:
    """``with atomic_folder(out) as tmp:`` write into ``tmp``; on a clean exit ``tmp``
    becomes ``out``, on an error or interrupt it is removed. ``out`` that exists and is not
    an empty folder is refused unless ``overwrite``."""
    out = Path(out)
    if out.exists() and not overwrite and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"{out}: output folder exists and is not empty (use --overwrite)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = old = None  # named before they exist, so an interrupt at any point knows what to remove
    try:
        while tmp is None:
            tmp = out.parent / f".{out.name}.{secrets.token_hex(6)}"
            try:
                os.mkdir(tmp, 0o700)
            except FileExistsError:  # another's folder: never removed
                tmp = None
        yield tmp
        if out.exists():  # set the old output aside first, so a crash here never loses both
            while old is None:
                old = out.parent / f".{out.name}.old.{secrets.token_hex(6)}"
                try:
                    os.mkdir(old, 0o700)
                except FileExistsError:
                    old = None
            try:
                os.replace(out, old / out.name)
            except OSError as err:  # e.g. a read-only folder (moving a folder writes its '..')
                raise OSError(
                    err.errno, f"{err.strerror}: cannot replace the existing output folder (read-only?)", str(out)
                ) from None
        os.replace(tmp, out)
        if old is not None:  # within the try: an interrupt while the earlier output is deleted still removes it
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        if old is not None and (old / out.name).exists() and not out.exists():  # put the earlier output back
            os.replace(old / out.name, out)
        for folder in (tmp, old):
            if folder is not None:
                shutil.rmtree(folder, ignore_errors=True)
        raise
