"""Dataset-run throughput of ``silfit fit-dataset``: a generated synthetic set (``--n``
subjects, default 100, 256 px) where every fifth subject's keypoint file gets a second,
keypoint-only person and three files are corrupted (a keypoint file, a camera, a mask),
fitted with ``--people all``:

* keypoints only: locally with batch sizes 1, 8 and 32, and through a local Ray (2 actors,
  1 CPU each, batch 8);
* with the silhouette stage (default settings) on the first ``--sil-subset`` subjects
  (default 10: the stage costs seconds per item on this CPU), locally (batch 8) and via Ray.

Prints a Markdown table: images and items (image, person) per hour, failures, the keypoint
and silhouette stages' seconds per fitted item (mean of the records' ``timings_s``), and the time
per item spent outside the fit (reading inputs, writing the output folder, and the rest:
model building, Ray start-up and scheduling, recording). Timings on a shared 2-core
machine are noisy.

    .venv/bin/python benchmarks/bench_dataset.py [--n 100] [--sil-subset 10] [--work DIR]
    .venv/bin/python benchmarks/bench_dataset.py --n 12 --sil-subset 12 --silhouette-only --no-ray --main
    .venv/bin/python benchmarks/bench_dataset.py --n 24 --sil-subset 24 --silhouette-only --no-ray --close

``--close``: also the local silhouette run before issue 25's close-alternatives part (``alternatives_margin=0``: the
keypoint stage's branch only is refined against the mask).

``--workers 2``: also the local runs in 2 worker processes (``silfit fit-dataset --workers 2``, one CPU each; the
one-process rows are the code before); ``--uneven``: also with the batches cut as before they were shared evenly
(at most ``batch`` items, as many as fill it: 28 items for 2 workers in batches of 8, 8, 8 and 4). ``--twice``: every local row of the silhouette subset twice, in turn (the
machine is noisy; ratios within one pass).

    .venv/bin/python benchmarks/bench_dataset.py --n 24 --sil-subset 24 --silhouette-only --no-ray --workers 2 --twice
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np

from silfit.fitting.silhouette_stage import BEFORE_SAMPLING_PART
from silfit.runner import FitOptions, fit_dataset
from silfit.synth.generate import SynthConfig, generate_dataset
from silfit.synth.people import bystander

#: subject index -> corrupted file (the mask one only matters when masks are read)
CORRUPT = {3: "mask.png", 10: "keypoints.json", 21: "camera.json"}


def build_dataset(root: Path, n: int, size: int) -> Path:
    data = root / f"data_{n}_{size}"
    if (data / "index.json").is_file():
        return data
    tmp = root / f".data_{n}_{size}"
    shutil.rmtree(tmp, ignore_errors=True)
    generate_dataset(tmp, n, SynthConfig(seed=11, size=size), progress=True)
    for i in range(n):
        s = tmp / f"subject_{i:03d}"
        if i % 5 == 4:
            kp = json.loads((s / "keypoints.json").read_text())
            kp["people"].append(bystander(kp["people"][0]))
            (s / "keypoints.json").write_text(json.dumps(kp))
        bad = CORRUPT.get(i)
        if bad == "keypoints.json":
            (s / bad).write_text('{"people": [{"pose_keypoints_2d": [1, 2, 3')
        elif bad == "camera.json":
            (s / bad).write_text('{"fx": 200, "cx": 128, "cy": 128, "width": 256, "height": 256}')
        elif bad == "mask.png":
            from PIL import Image

            Image.fromarray(np.zeros((size // 2, size), np.uint8)).save(s / bad)  # wrong size
    os.replace(tmp, data)
    return data


def subset(data: Path, root: Path, k: int) -> Path:
    sub = root / f"subset_{data.name}_{k}"
    if not sub.is_dir():
        sub.mkdir()
        for i in range(k):
            os.symlink(data / f"subject_{i:03d}", sub / f"subject_{i:03d}")
    return sub


@contextlib.contextmanager
def uneven_batches():
    """The pool's batches cut as before :func:`silfit.runner.run.shared_batches` shared them evenly."""
    from silfit.runner import run as runmod

    original = runmod.shared_batches
    runmod.shared_batches = lambda items, batch, workers: runmod.batches(
        items, max(1, min(int(batch), -(-len(items) // max(1, int(workers)))))
    )
    try:
        yield
    finally:
        runmod.shared_batches = original


@contextlib.contextmanager
def stage_changes(changes: dict):
    """The silhouette stage's settings with ``changes`` (field -> value, a group's field as ``group.field``) in this
    process (local runs only: Ray actors build their own)."""
    from silfit.runner import worker

    original = worker.silhouette_config

    def changed(options):
        config = original(options)
        return replace(config, **worker.grouped_values(changes, config))

    worker.silhouette_config = changed
    try:
        yield
    finally:
        worker.silhouette_config = original


def run(data: Path, out: Path, silhouette: bool, batch: int, ray: bool, label: str = "", workers: int = 1) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    s = fit_dataset(
        data,
        out,
        people="all",
        options=FitOptions(silhouette=silhouette),
        batch_size=batch,
        ray=ray,
        actors=2,
        num_cpus=1,
        workers=workers,
        progress=False,
    )
    wall = time.perf_counter() - t0
    ok = [r for r in s["records"] if r["status"] == "ok"]
    images = len({r["keypoints"] for r in s["records"]})
    workers = 2 if ray else workers
    t = lambda key: np.array([r["timings_s"].get(key, 0.0) for r in ok])  # noqa: E731
    fit = t("keypoints") + t("silhouette")
    io = t("load") + t("save")
    n = len(s["records"])
    other = (workers * wall - t("total").sum()) / n
    return {
        "mode": ("Ray, 2 actors" if ray else f"local, {workers} process{'es' if workers > 1 else ''}") + label,
        "batch": batch,
        "silhouette": silhouette,
        "items": n,
        "images": images,
        "ok": len(ok),
        "failed": s["failed"],
        "wall": wall,
        "images_h": 3600 * images / wall,
        "items_h": 3600 * n / wall,
        "fit": float(np.median(fit)),
        "io": float(np.median(io)),
        "other": other,
        "kp_stage": float(t("keypoints").mean()) if ok else float("nan"),
        "sil_stage": float(t("silhouette").mean()) if ok else float("nan"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--sil-subset", type=int, default=10)
    parser.add_argument("--batches", default="1,8,32")
    parser.add_argument("--work", help="folder for the generated data and outputs (default: a temporary one)")
    parser.add_argument("--no-ray", action="store_true", help="skip the Ray runs")
    parser.add_argument("--silhouette-only", action="store_true", help="only the runs with the silhouette stage")
    parser.add_argument(
        "--main",
        action="store_true",
        help="also the local silhouette run with edge_density=None (the stage before issue 24's speed part)",
    )
    parser.add_argument(
        "--close",
        action="store_true",
        help="also the local silhouette run with alternatives_margin=0 (before issue 25's close alternatives)",
    )
    parser.add_argument("--workers", type=int, default=1, help="also the local runs in this many worker processes")
    parser.add_argument("--twice", action="store_true", help="the silhouette subset's local rows twice, in turn")
    parser.add_argument("--uneven", action="store_true", help="with --workers: also the batches cut as before")
    args = parser.parse_args()
    root = Path(args.work or tempfile.mkdtemp(prefix="bench_dataset_"))
    root.mkdir(parents=True, exist_ok=True)
    data = build_dataset(root, args.n, args.size)
    rows = []
    if not args.silhouette_only:
        for b in (int(v) for v in args.batches.split(",")):
            rows.append(run(data, root / f"out_kp_b{b}", False, b, False))
            print(rows[-1], flush=True)
            if args.workers > 1 and b == 8:
                rows.append(run(data, root / f"out_kp_b{b}_w{args.workers}", False, b, False, workers=args.workers))
                print(rows[-1], flush=True)
        if not args.no_ray:
            rows.append(run(data, root / "out_kp_ray", False, 8, True))
            print(rows[-1], flush=True)
    if args.sil_subset:
        sub = subset(data, root, args.sil_subset)
        if args.main or args.close:  # a warm-up first (model, priors, proxies, silfit.render), so neither run pays it
            run(subset(data, root, 2), root / "out_warmup", True, 8, False)
        if args.close:
            with stage_changes({"alternatives_margin": 0.0}):
                rows.append(run(sub, root / "out_sil_b8_close", True, 8, False, " (alternatives_margin=0)"))
            print(rows[-1], flush=True)
        if args.main:
            before = {f"render.{k}": v for k, v in BEFORE_SAMPLING_PART.items()}
            with stage_changes({**before, "render.edge_density": None, "alternatives_margin": 0.0}):
                rows.append(
                    run(
                        sub,
                        root / "out_sil_b8_main",
                        True,
                        8,
                        False,
                        " (main: edge_density=None, spp=4, alternatives_margin=0)",
                    )
                )
            print(rows[-1], flush=True)
        for _ in range(2 if args.twice else 1):
            rows.append(run(sub, root / "out_sil_b8", True, 8, False))
            print(rows[-1], flush=True)
            if args.workers > 1 and args.uneven:
                with uneven_batches():
                    rows.append(
                        run(
                            sub,
                            root / f"out_sil_b8_w{args.workers}_uneven",
                            True,
                            8,
                            False,
                            " (batches as before)",
                            workers=args.workers,
                        )
                    )
                print(rows[-1], flush=True)
            if args.workers > 1:
                rows.append(run(sub, root / f"out_sil_b8_w{args.workers}", True, 8, False, workers=args.workers))
                print(rows[-1], flush=True)
        if not args.no_ray:
            rows.append(run(sub, root / "out_sil_ray", True, 8, True))
            print(rows[-1], flush=True)
    print(
        f"\n{args.n} generated subjects ({args.size} px), every fifth with a second keypoint-only person, "
        f"3 corrupted files (keypoints of subject 10, camera of 21, mask of 3); --people all. Work: {root}\n"
    )
    print(
        "| run | batch | silhouette | images | items | failed | wall (s) | images/h | items/h "
        "| fit s/item (median) | keypoint stage s/item (mean) | silhouette stage s/item (mean) "
        "| read+write s/item (median) | other s/item |"
    )
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['mode']} | {r['batch']} | {'yes' if r['silhouette'] else 'no'} | {r['images']} | {r['items']} "
            f"| {r['failed']} | {r['wall']:.0f} | {r['images_h']:.0f} | {r['items_h']:.0f} | {r['fit']:.2f} "
            f"| {r['kp_stage']:.2f} | {r['sil_stage']:.2f} | {r['io']:.2f} | {r['other']:.2f} |"
        )


if __name__ == "__main__":
    main()
