"""silfit.kernels: the CPU kernels asked for before torch and numpy load (README, "Same inputs, same fit")."""
import os

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
