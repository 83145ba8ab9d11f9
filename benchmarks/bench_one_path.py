"""Same fits through the one path (issue 26): ``silfit fit`` on an image, a rig and a video, run by
this checkout and by another (``--base``: a worktree of the previous commit), compared parameter by
parameter, with the wall time of each run.

    python benchmarks/bench_one_path.py --base /path/to/worktree-of-previous-commit [--quick]

Prints one row per case: the largest absolute difference of any parameter, of the vertices, and
both runs' wall seconds (one process per run, so model loading is included in both).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np

HERE = Path(__file__).resolve().parents[1]


def silfit(root: Path, args: list, env_extra: dict | None = None) -> float:
    env = dict(os.environ, PYTHONPATH=str(root), **(env_extra or {}))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "silfit", *args], cwd=root, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def compare(a: Path, b: Path) -> tuple:
    pa, pb = np.load(a / "params.npz"), np.load(b / "params.npz")
    names = [n for n in ("betas", "body_pose", "global_orient", "transl") if n in pa.files]
    dp = max(float(np.abs(pa[n].astype(np.float64) - pb[n].astype(np.float64)).max()) for n in names)
    dv = (
        float(np.abs(pa["vertices"].astype(np.float64) - pb["vertices"].astype(np.float64)).max())
        if "vertices" in pa.files
        else float("nan")
    )
    return dp, dv


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, type=Path, help="a checkout of the previous code")
    ap.add_argument("--quick", action="store_true", help="few silhouette steps (a smoke run)")
    a = ap.parse_args()
    sil = ["--silhouette-resolutions", "64", "--silhouette-iterations", "5"] if a.quick else []
    tmp = Path(tempfile.mkdtemp(prefix="one_path_"))
    data = HERE / "data" / "synthetic" / "subject_003"
    rigs, seqs = tmp / "rigs", tmp / "seqs"
    silfit(
        HERE, ["synth", "--n", "1", "--cameras", "3", "--size", "256", "--seed", "77", "--out", str(rigs), "--quiet"]
    )
    silfit(
        HERE,
        [
            "synth",
            "--videos",
            "--motions",
            "walk",
            "--frames",
            "8",
            "--n",
            "1",
            "--size",
            "256",
            "--seed",
            "78",
            "--out",
            str(seqs),
            "--quiet",
        ],
    )
    seq = next(p for p in seqs.iterdir() if p.is_dir())
    cases = {
        "image, keypoints only": [
            "--keypoints",
            str(data / "keypoints.json"),
            "--camera",
            str(data / "camera.json"),
            "--image-size",
            "256x256",
            "--no-silhouette",
        ],
        "image + silhouette": [
            "--keypoints",
            str(data / "keypoints.json"),
            "--camera",
            str(data / "camera.json"),
            "--mask",
            str(data / "mask.png"),
        ]
        + sil,
        "rig (3 views) + silhouette": ["--rig", str(rigs / "subject_000")] + sil,
        "video (8 frames)": ["--sequence", str(seq), "--no-silhouette", "--no-video"],
    }
    print("| case | max abs diff, parameters | max abs diff, vertices (m) | base wall s | this wall s |")
    print("|---|---|---|---|---|")
    for name, args in cases.items():
        out_a, out_b = tmp / f"base_{len(name)}_{hash(name) & 0xFFFF}", tmp / f"this_{len(name)}_{hash(name) & 0xFFFF}"
        ta = silfit(a.base, ["fit", *args, "--out", str(out_a), "--quiet"])
        tb = silfit(HERE, ["fit", *args, "--out", str(out_b), "--quiet"])
        dp, dv = compare(out_a, out_b)
        print(f"| {name} | {dp:.2e} | {dv:.2e} | {ta:.1f} | {tb:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
