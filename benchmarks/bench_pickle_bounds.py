"""What the restricted unpickler's bound costs: the opcode pre-pass (``_check_bounds``, run
before anything is unpickled) against the opcode scan it replaced (``pickletools.genops``
alone, the malformed-file check before issue 28) and the unpickling itself, on SMPL-sized model pickles
(numpy arrays as protocol 2 writes them, and chumpy-style stand-ins) and on a pickle of
plain lists (one opcode per number, the pre-pass's worst case). Prints a Markdown table
of median seconds.

    .venv/bin/python benchmarks/bench_pickle_bounds.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import io
import pickle
import pickletools
import statistics
import time

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np

from silfit.io.safe_pickle import RestrictedUnpickler, _check_bounds


def smpl_sized(seed: int = 0) -> dict:
    """Arrays of the official SMPL file's shapes (6890 vertices, 24 joints, 300 shape components)."""
    rng = np.random.default_rng(seed)
    V, J = 6890, 24
    return {
        "v_template": rng.normal(size=(V, 3)),
        "f": rng.integers(0, V, (13776, 3)).astype(np.uint32),
        "shapedirs": rng.normal(size=(V, 3, 300)),
        "posedirs": rng.normal(size=(V, 3, 207)),
        "J_regressor": rng.random((J, V)),
        "weights": rng.random((V, J)),
        "kintree_table": np.stack([np.arange(J) - 1, np.arange(J)]),
        "bs_style": "lbs",
        "bs_type": "lrotmin",
    }


def median_s(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    cases = {
        "SMPL-sized arrays, protocol 2": pickle.dumps(smpl_sized(), protocol=2),
        "SMPL-sized arrays, protocol 5": pickle.dumps(smpl_sized(), protocol=5),
        "1M floats as nested lists, protocol 2": pickle.dumps(
            {"v_template": rng.normal(size=(200_000, 5)).tolist()}, protocol=2
        ),
    }
    print(
        "| pickle | size (MB) | opcode scan alone (s) | pre-pass with the bound (s) | unpickling (s) | pre-pass / unpickling |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for name, data in cases.items():
        scan = median_s(lambda: sum(1 for _ in pickletools.genops(data)), args.repeats)
        check = median_s(lambda: _check_bounds(data, "bench", "a model"), args.repeats)
        load = median_s(lambda: RestrictedUnpickler(io.BytesIO(data), "bench").load(), args.repeats)
        print(f"| {name} | {len(data) / 1e6:.1f} | {scan:.3f} | {check:.3f} | {load:.3f} | {check / load:.2f} |")


if __name__ == "__main__":
    main()
