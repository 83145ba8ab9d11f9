"""silfit.kernels: the CPU kernels asked for before torch and numpy load (README, "Same inputs, same fit")."""

import os
import platform

import pytest
import torch

from silfit.kernels import KERNEL_PINS, NUMPY_AVX512, cpu_flags, kernel_report, pin_kernels

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
    assert (
        pin_kernels({}, flags=avx512, loaded=False, numpy_version="2.4.6")["NPY_DISABLE_CPU_FEATURES"] == NUMPY_AVX512
    )
    # older numpy names its targets otherwise (AVX512F, ...); an explicit choice wins; no AVX-512, nothing to turn off
    assert "NPY_DISABLE_CPU_FEATURES" not in pin_kernels({}, flags=avx512, loaded=False, numpy_version="2.2.6")
    assert "NPY_DISABLE_CPU_FEATURES" not in pin_kernels(
        {"NPY_DISABLE_CPU_FEATURES": ""}, flags=avx512, loaded=False, numpy_version="2.4.6"
    )
    assert "NPY_DISABLE_CPU_FEATURES" not in pin_kernels({}, flags=AVX2, loaded=False, numpy_version="2.4.6")
    # numpy refuses both variables at once
    assert "NPY_DISABLE_CPU_FEATURES" not in pin_kernels(
        {"NPY_ENABLE_CPU_FEATURES": "X86_V3"}, flags=avx512, loaded=False, numpy_version="2.4.6"
    )


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="x86-64 dispatch targets")
def test_the_installed_numpy_takes_the_avx512_names():
    # the names must be numpy's: it would refuse unknown ones, or leave the AVX-512 loops on
    import subprocess
    import sys

    from silfit.kernels import NUMPY_AVX512

    code = (
        "import warnings; warnings.simplefilter('error'); import numpy; "
        "from numpy._core._multiarray_umath import __cpu_features__ as f; print(f['X86_V4'], f['AVX512_ICL'])"
    )
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": NUMPY_AVX512, "SILFIT_KERNELS": "native"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def _first_import_of_a_library(path):
    """``(module, line, root inserted after it)``: the first top-level import in ``path`` of something outside the
    standard library (the first named, in source order), and whether a top-level ``sys.path.insert`` of the
    checkout's root comes after it (the script's own silfit must be found first); ``None``: no such import."""
    import ast
    import sys

    body = ast.parse(path.read_text(encoding="utf-8")).body
    for at, node in enumerate(body):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            tops = [
                n.split(".")[0] for n in names if n.split(".")[0] not in sys.stdlib_module_names and n != "__future__"
            ]
            if tops:
                later = any(
                    "sys.path.insert" in (src := ast.unparse(n)) and ("parents[1]" in src or "ROOT" in src)
                    for n in body[at + 1 :]
                    if isinstance(n, ast.Expr)
                )  # the checkout's root (the scripts' idioms)
                return tops[0], node.lineno, later
    return None


@pytest.mark.parametrize("folder", ["benchmarks", "tools"])
def test_scripts_import_silfit_before_numpy_and_torch(folder):
    # a benchmark that loads numpy or torch first measures unpinned kernels: other fits than the command line's
    from pathlib import Path

    scripts = sorted((Path(__file__).resolve().parents[1] / folder).glob("*.py"))
    assert scripts
    firsts = {p.name: _first_import_of_a_library(p) for p in scripts}
    late = [f"{name}:{first[1]} ({first[0]})" for name, first in firsts.items() if first and first[0] != "silfit"]
    assert not late, f"import silfit before these: {late}"
    path_after = [name for name, first in firsts.items() if first and first[0] == "silfit" and first[2]]
    assert not path_after, (
        f"these change sys.path after importing silfit (another installed silfit would win): {path_after}"
    )


@pytest.mark.skipif(
    platform.machine().lower() not in ("x86_64", "amd64") or not {"avx2", "fma"} <= cpu_flags(),
    reason="kernels are pinned on x86-64 with AVX2 and FMA only",
)
def test_importing_silfit_after_numpy_warns_once_unless_told_native():
    import subprocess
    import sys

    env = {
        k: v for k, v in os.environ.items() if k not in KERNEL_PINS and k not in ("SILFIT_KERNELS", "PYTHONWARNINGS")
    }

    def stderr(code, **extra):
        return subprocess.run(
            [sys.executable, "-c", code], env={**env, **extra}, capture_output=True, text=True, check=True
        ).stderr

    late = stderr("import numpy, torch; import silfit; import silfit.kernels as k; print(k.LOADED_FIRST)")
    assert late.count("RuntimeWarning: numpy and torch loaded before silfit") == 1, late
    assert "import silfit first" in late
    assert "silfit" not in stderr("import silfit, numpy, torch")
    assert "silfit" not in stderr("import numpy; import silfit", SILFIT_KERNELS="native")
    pins = {**KERNEL_PINS, "NPY_DISABLE_CPU_FEATURES": NUMPY_AVX512} if "avx512f" in cpu_flags() else KERNEL_PINS
    assert "silfit" not in stderr("import numpy; import silfit", **pins)  # the environment names the kernels already
