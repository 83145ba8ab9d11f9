"""Same fits, bit for bit, from two checkouts (issues 26 and 57: refactors must not change a fit): ``silfit fit``
on images (with a mask and hypotheses; keypoints only), a rig, a video, a rig video and a whole-body subject, and
``silfit fit-dataset`` on two subjects, each run by this checkout and by another (``--base``: a worktree of the
previous commit), then compared file by file.

    python benchmarks/bench_one_path.py --base /path/to/worktree-of-previous-commit [--quick]

Prints one row per case: whether every array of every ``params.npz`` is identical (``np.array_equal``; the
model's path aside, which names the checkout), whether every ``metrics.json`` is equal (timings and paths aside),
the largest absolute difference of any array where they are not, and both runs' wall seconds (one process per run,
so model loading is included in both). ``--quick`` runs few silhouette steps (the comparison is as exact).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np

HERE = Path(__file__).resolve().parents[1]
#: metrics that differ between two runs of the same code: wall times and the checkout's paths
VOLATILE = ("time", "seconds", "timings", "source", "path", "command")


def silfit(root: Path, args: list) -> float:
    env = dict(os.environ, PYTHONPATH=str(root))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "silfit", *args], cwd=root, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def stable(value):
    """``value`` (parsed JSON) without the keys that name times or paths, absolute paths blanked."""
    if isinstance(value, dict):
        return {k: stable(v) for k, v in value.items() if not any(w in k.lower() for w in VOLATILE)}
    if isinstance(value, list):
        return [stable(v) for v in value]
    if isinstance(value, str) and value.startswith("/"):
        return "<path>"  # names the checkout (the model's file)
    return value


def compare_folders(a: Path, b: Path) -> tuple:
    """``(params identical, metrics equal, largest difference, files compared)`` over every ``params.npz`` and
    ``metrics.json`` under ``a`` and their twins under ``b``."""
    same_params, same_metrics, worst, n = True, True, 0.0, 0
    for pa in sorted(a.rglob("params.npz")):
        pb = b / pa.relative_to(a)
        x, y = np.load(pa, allow_pickle=False), np.load(pb, allow_pickle=False)
        same_params &= sorted(x.files) == sorted(y.files)
        for k in x.files:
            if k == "model_source" or k not in y.files:
                continue
            n += 1
            if not np.array_equal(x[k], y[k]):
                same_params = False
                if np.issubdtype(x[k].dtype, np.number) and x[k].shape == y[k].shape:
                    d = np.abs(x[k].astype(np.float64) - y[k].astype(np.float64))
                    worst = max(worst, float(np.nanmax(d)) if d.size else 0.0)
    for ma in sorted(a.rglob("metrics.json")):
        mb = b / ma.relative_to(a)
        same_metrics &= stable(json.loads(ma.read_text())) == stable(json.loads(mb.read_text()))
        n += 1
    return same_params, same_metrics, worst, n


def inputs(tmp: Path) -> dict:
    """The cases' ``silfit`` arguments (``fit ...`` or ``fit-dataset ...``), their inputs made by this checkout."""
    data = HERE / "data" / "synthetic" / "subject_003"
    wb = HERE / "data" / "synthetic_wholebody" / "subject_000"
    rigs, seqs, rigseqs, items = tmp / "rigs", tmp / "seqs", tmp / "rigseqs", tmp / "items"
    silfit(
        HERE, ["synth", "--n", "1", "--cameras", "3", "--size", "192", "--seed", "77", "--out", str(rigs), "--quiet"]
    )
    video = ["synth", "--videos", "--motions", "walk", "--n", "1", "--size", "160", "--seed", "78", "--quiet"]
    silfit(HERE, [*video, "--frames", "6", "--out", str(seqs)])
    silfit(HERE, [*video, "--frames", "4", "--cameras", "2", "--out", str(rigseqs)])
    silfit(HERE, ["synth", "--n", "2", "--size", "160", "--seed", "79", "--out", str(items), "--quiet"])
    seq = next(p for p in seqs.iterdir() if p.is_dir())
    rigseq = next(p for p in rigseqs.iterdir() if p.is_dir())
    image = ["--keypoints", str(data / "keypoints.json"), "--camera", str(data / "camera.json")]
    return {
        "image + mask, 2 hypotheses": ["fit", *image, "--mask", str(data / "mask.png"), "--hypotheses", "2"],
        "image, keypoints only": ["fit", *image, "--image-size", "256x256", "--no-silhouette"],
        "rig (3 views) + silhouette": ["fit", "--rig", str(rigs / "subject_000")],
        "video (6 frames) + masks": ["fit", "--sequence", str(seq), "--masks", str(seq / "masks"), "--no-video"],
        "rig video (2 views, 4 frames)": ["fit", "--rig", str(rigseq), "--no-video"],
        "whole body (SMPL-X)": [
            "fit",
            "--keypoints",
            str(wb / "keypoints.json"),
            "--camera",
            str(wb / "camera.json"),
            "--mask",
            str(wb / "mask.png"),
            "--model",
            "open-smplx",
        ],
        "fit-dataset (2 subjects)": ["fit-dataset", str(items), "--no-report"],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, type=Path, help="a checkout of the previous code")
    ap.add_argument("--quick", action="store_true", help="few silhouette steps (a smoke run)")
    ap.add_argument("--only", default="", help="comma-separated case numbers (1-based) to run")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="one_path_"))
    cases = list(inputs(tmp).items())
    if a.only:
        cases = [cases[int(i) - 1] for i in a.only.split(",")]
    print("| case | params.npz arrays identical | metrics.json equal | max abs diff | files | base s | this s |")
    print("|---|---|---|---|---|---|---|")
    for i, (name, args) in enumerate(cases):
        extra = list(args[1:])
        if a.quick and (args[0] == "fit-dataset" or "--no-silhouette" not in args):
            extra += ["--silhouette-resolutions", "64", "--silhouette-iterations", "5"]
        out_a, out_b = tmp / f"base_{i}", tmp / f"this_{i}"
        ta = silfit(a.base, [args[0], *extra, "--out", str(out_a), "--quiet"])
        tb = silfit(HERE, [args[0], *extra, "--out", str(out_b), "--quiet"])
        same_p, same_m, worst, n = compare_folders(out_a, out_b)
        yes = {True: "yes", False: "**no**"}
        print(f"| {name} | {yes[same_p]} | {yes[same_m]} | {worst:.2e} | {n} | {ta:.1f} | {tb:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
