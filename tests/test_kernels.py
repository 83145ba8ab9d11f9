"""silfit.kernels: the CPU kernels asked for before torch and numpy load (README, "Same inputs, same fit")."""
import os
import platform

import pytest
import torch

from silfit.kernels import KERNEL_PINS, kernel_report, pin_kernels

AVX2 = {"avx2", "fma", "sse4_2"}


def test_pins_are_set_where_unset_on_an_avx2_cpu_before_torch_loads(monkeypatch):
    monkeypatch.setattr("platform.machine", lambda: "x86_64")
    env = {"MKL_CBWR": "AVX2"}  # an explicit choice wins
    done = pin_kernels(env, flags=AVX2, loaded=False)
    assert done == {"ATEN_CPU_CAPABILITY": "avx2", "OPENBLAS_CORETYPE": "Haswell"}
    assert env == {**KERNEL_PINS, "MKL_CBWR": "AVX2"}


def test_no_pins_when_turned_off_too_late_or_without_avx2(monkeypatch):
    monkeypatch.setattr("platform.machine", lambda: "x86_64")
    assert pin_kernels({"SILFIT_KERNELS": "native"}, flags=AVX2, loaded=False) == {}
    assert pin_kernels({}, flags=AVX2, loaded=True) == {}  # torch or numpy already read their settings
    assert pin_kernels({}, flags={"sse4_2"}, loaded=False) == {}
    monkeypatch.setattr("platform.machine", lambda: "aarch64")
    assert pin_kernels({}, flags=AVX2, loaded=False) == {}


def test_this_process_runs_on_the_kernels_its_environment_names():
    # tests/conftest.py imports silfit before torch: the pinned (or the audit's explicit) choice is in effect
    want = os.environ.get("ATEN_CPU_CAPABILITY")
    report = kernel_report()
    if want:
        assert torch.backends.cpu.get_cpu_capability().lower() == want.lower()
        assert report["environment"]["ATEN_CPU_CAPABILITY"] == want
    assert report["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()


def test_numpy_avx512_loops_are_turned_off_on_an_avx512_cpu(monkeypatch):
    from silfit.kernels import NUMPY_AVX512

    monkeypatch.setattr("platform.machine", lambda: "x86_64")
    avx512 = AVX2 | {"avx512f"}
    assert pin_kernels({}, flags=avx512, loaded=False, numpy_version="2.4.6")["NPY_DISABLE_CPU_FEATURES"] == NUMPY_AVX512
    # older numpy names its targets otherwise (AVX512F, ...); an explicit choice wins; no AVX-512, nothing to turn off
    assert "NPY_DISABLE_CPU_FEATURES" not in pin_kernels({}, flags=avx512, loaded=False, numpy_version="2.2.6")
    assert "NPY_DISABLE_CPU_FEATURES" not in pin_kernels({"NPY_DISABLE_CPU_FEATURES": ""}, flags=avx512, loaded=False,
                                                         numpy_version="2.4.6")  # fmt: skip
    assert "NPY_DISABLE_CPU_FEATURES" not in pin_kernels({}, flags=AVX2, loaded=False, numpy_version="2.4.6")
    # numpy refuses both variables at once
    assert "NPY_DISABLE_CPU_FEATURES" not in pin_kernels({"NPY_ENABLE_CPU_FEATURES": "X86_V3"}, flags=avx512, loaded=False,
                                                         numpy_version="2.4.6")  # fmt: skip


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="x86-64 dispatch targets")
def test_the_installed_numpy_takes_the_avx512_names():
    # the names must be numpy's: it would refuse unknown ones, or leave the AVX-512 loops on
    import subprocess
    import sys

    from silfit.kernels import NUMPY_AVX512

    code = ("import warnings; warnings.simplefilter('error'); import numpy; "
            "from numpy._core._multiarray_umath import __cpu_features__ as f; print(f['X86_V4'], f['AVX512_ICL'])")  # fmt: skip
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": NUMPY_AVX512, "SILFIT_KERNELS": "native"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
