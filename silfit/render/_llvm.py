"""Dr.Jit / Mitsuba bootstrap: pick a working libLLVM and a Mitsuba variant.

Dr.Jit's LLVM backend loads ``libLLVM`` at import time.  On Debian several versions can
be installed side by side (Mesa pulls in libllvm15), and only a recent one works here:
libLLVM 14 is rejected by Dr.Jit and 15/16 crash the process on the first real render
("LLVM ERROR: Cannot select: f32 = fminimum").  :func:`configure_libllvm` therefore sets
``DRJIT_LIBLLVM_PATH`` *before* ``drjit`` is imported:

* a user-set ``DRJIT_LIBLLVM_PATH`` is kept if it names an existing libLLVM >= 17;
* otherwise the Debian/Ubuntu locations are searched, libLLVM 19 first;
* if nothing usable is found, :class:`LibLLVMNotFoundError` says to
  ``apt-get install libllvm19``.

:func:`import_mitsuba` returns ``(mitsuba, drjit)`` with the variant set: ``cuda_ad_mono``
when the wheel has it and a CUDA device is actually usable, ``llvm_ad_mono`` otherwise.
Override with the ``variant`` argument or the ``SILFIT_MITSUBA_VARIANT`` environment
variable.
"""

from __future__ import annotations

import ctypes
import glob
import os
import re
import sys
import warnings
from typing import Optional

from silfit.errors import SystemLibraryError

__all__ = [
    "LibLLVMNotFoundError",
    "MIN_LLVM_MAJOR",
    "PREFERRED_LLVM_MAJOR",
    "llvm_major_version",
    "find_libllvm",
    "configure_libllvm",
    "select_variant",
    "import_mitsuba",
]

#: Oldest libLLVM major version accepted (14 is rejected by Dr.Jit, 15/16 crash).
MIN_LLVM_MAJOR = 17
#: The version measured to work with drjit 1.5 (Debian package ``libllvm19``).
PREFERRED_LLVM_MAJOR = 19
ENV_LIBLLVM = "DRJIT_LIBLLVM_PATH"
ENV_VARIANT = "SILFIT_MITSUBA_VARIANT"

_SEARCH_GLOBS = (
    "/usr/lib/*-linux-gnu/libLLVM.so.*",
    "/usr/lib/*-linux-gnu/libLLVM-*.so*",
    "/usr/lib/llvm-*/lib/libLLVM.so.*",
    "/usr/lib/llvm-*/lib/libLLVM-*.so*",
    "/usr/lib/llvm-*/lib/libLLVM.so",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
)


class LibLLVMNotFoundError(SystemLibraryError):
    """No libLLVM that Dr.Jit's LLVM backend can use was found."""


def _version_from_name(path: str) -> Optional[int]:
    name = os.path.basename(path)
    m = re.match(r"libLLVM(?:-|\.so\.)(\d+)", name)
    if m:
        return int(m.group(1))
    m = re.search(r"/llvm-(\d+)/", path)
    return int(m.group(1)) if m else None


def llvm_major_version(path: str) -> Optional[int]:
    """Major version of the libLLVM at ``path`` (from its name, else ``LLVMGetVersion``);
    ``None`` when the file is missing or not a loadable libLLVM."""
    if not os.path.isfile(path):
        return None
    version = _version_from_name(path)
    if version is not None:
        return version
    try:
        lib = ctypes.CDLL(path)
        get_version = lib.LLVMGetVersion  # LLVM >= 16 C API
    except (OSError, AttributeError):
        return None
    major, minor, patch = ctypes.c_uint(), ctypes.c_uint(), ctypes.c_uint()
    get_version(ctypes.byref(major), ctypes.byref(minor), ctypes.byref(patch))
    return int(major.value)


def _candidates() -> list[tuple[int, str]]:
    found: dict[str, int] = {}
    seen: set[str] = set()
    for pattern in _SEARCH_GLOBS:
        for path in sorted(glob.glob(pattern), key=len):
            real = os.path.realpath(path)
            if real in seen or not os.path.isfile(real):
                continue
            version = _version_from_name(path)
            if version is not None and version >= MIN_LLVM_MAJOR:
                seen.add(real)
                found[path] = version
    # Preferred version first, then newest; within a version, the shortest (canonical) name.
    ranked = sorted(found.items(), key=lambda kv: (kv[1] != PREFERRED_LLVM_MAJOR, -kv[1], len(kv[0]), kv[0]))
    return [(v, p) for p, v in ranked]


def find_libllvm() -> str:
    """Path of a usable libLLVM (>= 17, preferably 19); raises :class:`LibLLVMNotFoundError`."""
    candidates = _candidates()
    if not candidates:
        raise LibLLVMNotFoundError(
            f"no usable libLLVM (>= {MIN_LLVM_MAJOR}) found for Mitsuba/Dr.Jit's LLVM backend; "
            f"install it with `apt-get install libllvm{PREFERRED_LLVM_MAJOR}` "
            f"(or set {ENV_LIBLLVM} to a libLLVM {PREFERRED_LLVM_MAJOR} shared library)"
        )
    return candidates[0][1]


def configure_libllvm(required: bool = True) -> Optional[str]:
    """Set ``DRJIT_LIBLLVM_PATH`` (keeping a valid user value) and return it.

    Must run before ``drjit`` is imported; afterwards it only reports.  With
    ``required=False`` a missing libLLVM returns ``None`` instead of raising (CUDA-only use).
    """
    user = os.environ.get(ENV_LIBLLVM)
    if user:
        version = llvm_major_version(user)
        if version is not None and version >= MIN_LLVM_MAJOR:
            return user
        warnings.warn(
            f"{ENV_LIBLLVM}={user!r} is not a libLLVM >= {MIN_LLVM_MAJOR} "
            f"(found version {version}); searching the system instead",
            RuntimeWarning,
            stacklevel=2,
        )
    if "drjit" in sys.modules:
        return os.environ.get(ENV_LIBLLVM)
    try:
        path = find_libllvm()
    except LibLLVMNotFoundError:
        if required:
            raise
        return None
    os.environ[ENV_LIBLLVM] = path
    return path


def select_variant(preferred: Optional[str] = None) -> str:
    """The Mitsuba variant to use: ``preferred``, else ``$SILFIT_MITSUBA_VARIANT``, else
    ``cuda_ad_mono`` if available and a CUDA device is usable, else ``llvm_ad_mono``."""
    import drjit as dr
    import mitsuba as mi

    requested = preferred or os.environ.get(ENV_VARIANT)
    available = mi.variants()
    if requested:
        if requested not in available:
            raise ValueError(f"Mitsuba variant {requested!r} is not available; choose one of {', '.join(available)}")
        return requested
    if "cuda_ad_mono" in available and _cuda_usable(dr):
        return "cuda_ad_mono"
    if "llvm_ad_mono" not in available:
        raise RuntimeError("the installed Mitsuba has neither 'cuda_ad_mono' nor 'llvm_ad_mono'")
    return "llvm_ad_mono"


def _cuda_usable(dr) -> bool:
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # noqa: BLE001 - any driver problem means "no GPU"
        return False


def import_mitsuba(variant: Optional[str] = None):
    """Import Mitsuba and Dr.Jit with a working libLLVM and the variant set; returns ``(mi, dr)``.

    Calling it again with a different variant switches Mitsuba's global variant."""
    wants_cuda = (variant or os.environ.get(ENV_VARIANT) or "").startswith("cuda")
    configure_libllvm(required=not wants_cuda and not _maybe_gpu())
    import drjit as dr
    import mitsuba as mi

    chosen = select_variant(variant)
    if chosen.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
        raise LibLLVMNotFoundError(
            f"Dr.Jit could not initialise its LLVM backend with {ENV_LIBLLVM}="
            f"{os.environ.get(ENV_LIBLLVM)!r}; install `apt-get install libllvm{PREFERRED_LLVM_MAJOR}`"
        )
    if mi.variant() != chosen:
        mi.set_variant(chosen)
    return mi, dr


def _maybe_gpu() -> bool:
    """Cheap pre-import hint that a CUDA driver exists (then a missing libLLVM is not fatal)."""
    return bool(glob.glob("/dev/nvidia[0-9]*")) or os.path.exists("/proc/driver/nvidia/version")
