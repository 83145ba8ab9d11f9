"""Body-model speed: forward and forward+backward for batch 1 and 64, float32, on the
shipped open model (or ``--model PATH``). Prints a Markdown table of median times.

    .venv/bin/python benchmarks/bench_body.py [--repeats 30] [--model PATH]

Target on a 2-core CPU: batch 1 forward+backward under 30 ms.
"""

from __future__ import annotations

import argparse
import statistics
import time

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import torch

from silfit import load_body_model


def median_ms(fn, repeats: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None)
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    model = load_body_model(args.model)
    print(
        f"model: {model.source} ({model.num_vertices} vertices), torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads\n"
    )
    print("| batch | forward (ms) | forward+backward (ms) | per sample fwd+bwd (ms) |")
    print("|---:|---:|---:|---:|")
    for batch in (1, 64):
        gen = torch.Generator().manual_seed(0)
        params = {
            "betas": torch.randn(batch, 10, generator=gen),
            "body_pose": torch.randn(batch, model.num_body_pose, generator=gen) * 0.2,
            "global_orient": torch.randn(batch, 3, generator=gen),
            "transl": torch.randn(batch, 3, generator=gen),
        }

        def forward():
            with torch.no_grad():
                model(**params)

        def forward_backward():
            leaves = {k: v.clone().requires_grad_() for k, v in params.items()}
            out = model(**leaves)
            (out.vertices.square().sum() + out.joints.sum()).backward()

        fwd = median_ms(forward, args.repeats)
        fb = median_ms(forward_backward, args.repeats)
        print(f"| {batch} | {fwd:.1f} | {fb:.1f} | {fb / batch:.2f} |")


if __name__ == "__main__":
    main()
