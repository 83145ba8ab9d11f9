"""Run the fitting and evaluation tests under several kernel and thread settings; report every
test whose outcome changes (issue 22: "same inputs, same fit" on any CPU).

CI runs on whatever processor it is given (AMD or Intel, AVX2 or AVX-512), and a test whose
outcome follows float rounding passes on one and fails on another. One machine can imitate
several: ``ATEN_CPU_CAPABILITY`` picks torch's SIMD kernels (``default``, ``avx2``, ``avx512``
where the CPU has it), ``MKL_ENABLE_INSTRUCTIONS`` caps the instruction set of MKL's BLAS
(``SSE4_2``: another GEMM blocking and rounding), ``MKL_CBWR`` asks MKL for its
conditional-reproducibility path, ``OMP_NUM_THREADS`` sets the thread pools at start-up,
``OPENBLAS_CORETYPE`` numpy's and scipy's BLAS/LAPACK kernel and ``NPY_DISABLE_CPU_FEATURES`` numpy's own
SIMD loops.
Each setting runs the tests in a fresh process; a table gives the counts per setting and then
every test that passed under one setting and not under another.

    bash tools/cpu_audit.sh                         # tests/fitting tests/eval tests/body tests/priors
    bash tools/cpu_audit.sh --jobs 2 tests/fitting  # two settings at a time, one folder
    bash tools/cpu_audit.sh --settings base,aten-default -- -k sequence

Exit status 0 when every setting passes every test, 1 otherwise.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from silfit.kernels import (
    NUMPY_AVX512,
    cpu_flags,
)  # (importing silfit pins this process's kernels: CONTROLLED are reset per setting)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TESTS = ["tests/fitting", "tests/eval", "tests/body", "tests/priors"]
#: environment variables a setting controls (unset unless the setting names them)
CONTROLLED = (
    "ATEN_CPU_CAPABILITY",
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "MKL_ENABLE_INSTRUCTIONS",
    "MKL_CBWR",
    "OPENBLAS_CORETYPE",
    "NPY_DISABLE_CPU_FEATURES",
    "NPY_ENABLE_CPU_FEATURES",
)


def all_settings() -> dict:
    """name -> environment of each setting this CPU can run."""
    flags = cpu_flags()
    s = {"base": {}, "aten-default": {"ATEN_CPU_CAPABILITY": "default"}}
    if "avx2" in flags:
        s["aten-avx2"] = {"ATEN_CPU_CAPABILITY": "avx2"}
    if "avx512f" in flags:
        s["aten-avx512"] = {"ATEN_CPU_CAPABILITY": "avx512"}
    s["omp-1"] = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    s["omp-2"] = {"OMP_NUM_THREADS": "2", "MKL_NUM_THREADS": "2"}
    s["mkl-sse4_2"] = {"MKL_ENABLE_INSTRUCTIONS": "SSE4_2"}
    s["mkl-cbwr-compatible"] = {"MKL_CBWR": "COMPATIBLE"}
    # numpy's and scipy's OpenBLAS on another kernel (AVX, no FMA), and numpy's own loops at their
    # baseline (SSE4.2) instead of AVX2: another CPU's LAPACK and numpy (silfit.kernels)
    s["openblas-sandybridge"] = {"OPENBLAS_CORETYPE": "Sandybridge"}
    if "avx2" in flags:
        s["numpy-baseline"] = {"NPY_DISABLE_CPU_FEATURES": f"X86_V3 {NUMPY_AVX512}"}
    return s


def run_setting(name: str, env: dict, tests: list, extra: list, out_dir: Path) -> dict:
    e = {k: v for k, v in os.environ.items() if k not in CONTROLLED}
    e.update(env)
    xml = out_dir / f"{name}.xml"
    log = out_dir / f"{name}.log"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={xml}", *tests, *extra]
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        rc = subprocess.run(cmd, cwd=ROOT, env=e, stdout=fh, stderr=subprocess.STDOUT).returncode
    outcomes = {}
    if xml.is_file():
        for case in ET.parse(xml).getroot().iter("testcase"):
            test = f"{case.get('classname')}::{case.get('name')}"
            kinds = {child.tag for child in case}
            outcomes[test] = "failed" if kinds & {"failure", "error"} else "skipped" if "skipped" in kinds else "passed"
    print(
        f"  {name}: exit {rc}, {len(outcomes)} tests, {time.perf_counter() - t0:.0f} s ({log})",
        file=sys.stderr,
        flush=True,
    )
    return {"rc": rc, "outcomes": outcomes, "seconds": time.perf_counter() - t0, "log": str(log)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("tests", nargs="*", help=f"test paths (default: {' '.join(DEFAULT_TESTS)})")
    ap.add_argument("--settings", help=f"comma-separated subset of: {', '.join(all_settings())}")
    ap.add_argument("--jobs", type=int, default=1, help="settings run at the same time (default 1)")
    ap.add_argument("--keep", help="folder for the logs and JUnit files (default: a temporary one)")
    a, extra = ap.parse_known_args(argv)
    extra = [x for x in extra if x != "--"]
    if a.jobs > 1 and not any(x == "-n" or x.startswith(("-n", "--numprocesses")) for x in extra):
        extra = ["-n", "0", *extra]  # settings side by side: each pytest in one process (not pyproject's -n auto)
    settings = all_settings()
    chosen = a.settings.split(",") if a.settings else list(settings)
    unknown = [s for s in chosen if s not in settings]
    if unknown:
        ap.error(f"unknown or unsupported setting(s) on this CPU: {', '.join(unknown)} (have: {', '.join(settings)})")
    tests = a.tests or DEFAULT_TESTS
    out_dir = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="cpu-audit-"))
    out_dir.mkdir(parents=True, exist_ok=True)
    import platform

    model = (
        next(
            (
                ln.split(":", 1)[1].strip()
                for ln in Path("/proc/cpuinfo").read_text().splitlines()
                if ln.startswith("model name")
            ),
            platform.processor(),
        )
        if Path("/proc/cpuinfo").is_file()
        else platform.processor()
    )
    print(
        f"cpu audit: {model}; {len(chosen)} settings; {' '.join(tests)} {' '.join(extra)}", file=sys.stderr, flush=True
    )
    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        futures = {n: pool.submit(run_setting, n, settings[n], tests, extra, out_dir) for n in chosen}
        results = {n: f.result() for n, f in futures.items()}

    print(f"\nCPU audit on {model} ({', '.join(tests)})\n")
    print("| setting | environment | passed | failed | skipped | seconds |")
    print("|---|---|---:|---:|---:|---:|")
    for n in chosen:
        r = results[n]
        count = lambda kind: sum(v == kind for v in r["outcomes"].values())  # noqa: E731
        env = " ".join(f"{k}={v}" for k, v in settings[n].items()) or "(as given)"
        print(f"| {n} | {env} | {count('passed')} | {count('failed')} | {count('skipped')} | {r['seconds']:.0f} |")
    names = sorted(set().union(*(r["outcomes"] for r in results.values())))
    changed = [t for t in names if len({results[n]["outcomes"].get(t, "missing") for n in chosen}) > 1]
    failed = [t for t in names if any(results[n]["outcomes"].get(t) == "failed" for n in chosen)]
    if changed:
        print("\nTests whose outcome changes with the setting:\n")
        print("| test | " + " | ".join(chosen) + " |\n|---|" + "---|" * len(chosen))
        for t in changed:
            print(f"| {t} | " + " | ".join(results[n]["outcomes"].get(t, "missing") for n in chosen) + " |")
    bad = [n for n in chosen if results[n]["rc"] != 0 or not results[n]["outcomes"]]
    if not changed and not failed and not bad:
        print(f"\nClean: all {len(names)} tests have the same outcome (passed or skipped) under every setting.")
        return 0
    if failed and not changed:
        print(f"\n{len(failed)} test(s) fail under every setting: {', '.join(failed[:10])}")
    if bad:
        print(f"\nSettings that did not pass: {', '.join(bad)} (logs in {out_dir})")
    return 1


if __name__ == "__main__":
    sys.exit(main())
