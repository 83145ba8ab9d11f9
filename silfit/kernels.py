"""The CPU kernels silfit's arithmetic runs on, chosen before torch and numpy load theirs.

A fit's optimiser amplifies differences in the last bits of its arithmetic into millimetres
(README, "Same inputs, same fit"; the measurement: docs/benchmarks/defaults.md). The libraries
under silfit pick their kernels by the processor: torch's SIMD level
(AVX2 or AVX-512: 4 or 8 lanes, so another order of partial sums), MKL's branch (its GEMMs, and the
vector maths torch hands it: ``sin``, ``cos``, ``exp``, ``log``, ``sqrt``, ``tanh`` of a float tensor
go to MKL's VML), OpenBLAS's core type (Haswell, Zen, SkylakeX). So on an x86-64 processor with AVX2
silfit asks each for kernels every such processor (AMD or Intel, with or without AVX-512) runs the
same way:

* ``ATEN_CPU_CAPABILITY=avx2`` (torch's vectorised kernels),
* ``MKL_CBWR=COMPATIBLE`` (MKL's conditional numerical reproducibility on the code path it runs on
  every Intel and compatible processor; before 2026-12-03 ``AVX2``, MKL's AVX2 branch,
  which it need not take on another maker's processor; on an Intel Xeon with AVX-512 the keypoint
  stage's fits are the same bits with either, and differ with ``AVX512``),
* ``OPENBLAS_CORETYPE=Haswell`` (numpy's and scipy's OpenBLAS),
* on a CPU with AVX-512 and numpy 2.4 or newer from a pip/uv wheel, ``NPY_DISABLE_CPU_FEATURES`` naming
  numpy's AVX-512 dispatch targets (:data:`NUMPY_AVX512`; not where ``NPY_ENABLE_CPU_FEATURES`` is set):
  numpy's own loops for float64 ``exp`` and ``log`` (its AVX512F code) and ``sin``, ``cos``, ``tan``,
  ``log10``, ``expm1``, ``power`` and more (SVML) round otherwise than the scalar ones AVX2 machines run,
  so every processor runs its AVX2-level loops (added 2026-12-04, on an AMD EPYC; from numpy's sources,
  not measured: that machine has no AVX-512).

The pose prior's precisions, computed once when it loads, are BLAS-free (:mod:`silfit.priors.spd`):
LAPACK's inverse followed OpenBLAS's kernel (``Sandybridge`` against ``Haswell``: other bits, other fits).

The body model and the keypoint stage use no BLAS (:mod:`silfit.body.lbs`, "No BLAS"): MKL's GEMMs
changed with its thread count on an Intel Xeon, and so did a float64 keypoint fit; the collision spheres are
posed without BLAS too. Nor ``torch.sqrt``, which MKL's vector maths rounds otherwise on an Intel Xeon with
AVX-512 than on an AMD EPYC, whatever the pins (:func:`silfit.body.lbs.sqrt`, "No VML square root").

Each is set only where the environment does not set it already (an explicit choice wins), and
only when neither torch nor numpy has been imported yet: they read these variables once, when
they load. ``import silfit`` does this first thing, so the command line, Ray workers (which
inherit the driver's environment) and scripts that import silfit before torch all get it.
``SILFIT_KERNELS=native`` turns it off. :func:`kernel_report` says what a process runs on.
"""

from __future__ import annotations

import os
import platform
import sys
from typing import Dict, MutableMapping, Optional

__all__ = ["KERNEL_PINS", "NUMPY_AVX512", "cpu_flags", "kernel_report", "late_import_message", "pin_kernels"]

#: environment variable -> value asked for on an x86-64 CPU with AVX2 and FMA
KERNEL_PINS: Dict[str, str] = {"ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "COMPATIBLE", "OPENBLAS_CORETYPE": "Haswell"}

#: numpy's dispatch targets above AVX2 (numpy 2.4's names), turned off on a CPU with AVX-512
NUMPY_AVX512 = "X86_V4 AVX512_ICL AVX512_SPR"

#: what :func:`pin_kernels` did in this process (``None``: not run yet)
PINNED: Optional[Dict[str, str]] = None
#: the libraries (``numpy``, ``torch``) loaded before silfit where that kept :func:`pin_kernels` from pinning
#: kernels the environment does not name (empty: none; ``import silfit`` warns, :func:`late_import_message`)
LOADED_FIRST: tuple = ()


def cpu_flags() -> set:
    """The CPU's feature flags (``/proc/cpuinfo``; empty where it cannot be read)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def _numpy_names_targets(version: Optional[str]) -> bool:
    """Whether numpy ``version`` (default: the installed one, read without importing it) names its
    dispatch targets as :data:`NUMPY_AVX512` does (2.4 and newer; older ones call them AVX512F, ...)
    and, for the installed one, came from a wheel installed by pip or uv: those are built with the
    X86_V2 baseline, so the AVX-512 targets are dispatched, not built in (numpy refuses to turn off a
    baseline feature, as a conda build for a newer baseline could have)."""
    if version is None:
        try:
            from importlib.metadata import distribution

            dist = distribution("numpy")
            version = dist.version
            if (dist.read_text("INSTALLER") or "").strip().lower() not in ("pip", "uv"):
                return False
        except Exception:  # noqa: BLE001 - no numpy metadata: leave numpy alone
            return False
    try:
        major, minor = (int(x) for x in version.split(".")[:2])
    except ValueError:
        return False
    return (major, minor) >= (2, 4)


def pin_kernels(
    environ: Optional[MutableMapping[str, str]] = None,
    flags: Optional[set] = None,
    loaded: Optional[bool] = None,
    numpy_version: Optional[str] = None,
) -> Dict[str, str]:
    """Set the :data:`KERNEL_PINS` that ``environ`` (default ``os.environ``) does not set yet, where
    the CPU has AVX2 and FMA, ``SILFIT_KERNELS`` is not ``native`` and torch and numpy are not loaded
    (``loaded``: override that check); with AVX-512, also numpy's dispatch (``numpy_version``: default the
    installed one's). Returns the variables it set."""
    global PINNED, LOADED_FIRST
    env = os.environ if environ is None else environ
    flags = cpu_flags() if flags is None else flags
    first = tuple(m for m in ("numpy", "torch") if m in sys.modules)
    if loaded is None:
        loaded = bool(first)
    done: Dict[str, str] = {}
    x86 = platform.machine().lower() in ("x86_64", "amd64")
    eligible = env.get("SILFIT_KERNELS", "").lower() != "native" and x86 and {"avx2", "fma"} <= flags
    # numpy refuses both NPY_ENABLE_ and NPY_DISABLE_CPU_FEATURES: a user's choice of either wins
    npy_free = "NPY_DISABLE_CPU_FEATURES" not in env and "NPY_ENABLE_CPU_FEATURES" not in env
    numpy_pin = eligible and "avx512f" in flags and npy_free and _numpy_names_targets(numpy_version)
    if environ is None:  # numpy or torch came first and some pin is unset: import silfit warns
        unset = numpy_pin or any(k not in env for k in KERNEL_PINS)
        LOADED_FIRST = first if loaded and eligible and unset else ()
    if eligible and not loaded:
        for k, v in KERNEL_PINS.items():
            if k not in env:
                env[k] = v
                done[k] = v
        if numpy_pin:
            env["NPY_DISABLE_CPU_FEATURES"] = done["NPY_DISABLE_CPU_FEATURES"] = NUMPY_AVX512
    if environ is None:
        PINNED = done
    return done


def late_import_message() -> Optional[str]:
    """What ``import silfit`` warns when numpy or torch loaded before it kept the kernels unpinned
    (:data:`LOADED_FIRST`), or ``None``."""
    if not LOADED_FIRST:
        return None
    return (
        f"{' and '.join(LOADED_FIRST)} loaded before silfit, so silfit could not pin the CPU kernels its fits are "
        "reproduced with (silfit.kernels): fits may differ in their last bits, and by millimetres, from the "
        "command line's; import silfit first, or set SILFIT_KERNELS=native to choose the native kernels"
    )


def kernel_report() -> Dict[str, object]:
    """What this process computes with: torch's SIMD level, the pins silfit set, the variables as
    they stand (for ``metrics.json`` and bug reports)."""
    out: Dict[str, object] = {"machine": platform.machine(), "pinned_by_silfit": dict(PINNED or {})}
    out["environment"] = {
        k: os.environ.get(k)
        for k in (*KERNEL_PINS, "NPY_DISABLE_CPU_FEATURES", "OMP_NUM_THREADS", "MKL_ENABLE_INSTRUCTIONS")
    }
    if "torch" in sys.modules:
        import torch

        out["torch_cpu_capability"] = torch.backends.cpu.get_cpu_capability()
    return out
