"""`silfit fit` overhead outside the fit: imports, loading, the fit, writing the folder.

Runs the phases of ``silfit fit`` in a fresh process (as ``silfit/cli/fit.py`` does) and
prints wall and CPU seconds per phase, for one subject, with and without the silhouette
stage; then the wall time of the real command (``python -m silfit fit``, median of
``--repeats``).  The subject is written with ``silfit synth`` (512x512) unless given.

    .venv/bin/python benchmarks/bench_cli.py [--subject DIR] [--repeats 3]

Target on the 2-core CPU (issue 10): ``silfit fit`` with silhouettes at most 5 s wall for
one 512x512 image.  Timings on a shared machine are noisy: the CPU column is the steadier.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: pins the CPU kernels in os.environ, so the children measured run the command line's)

ROOT = Path(__file__).resolve().parents[1]

PHASES = r"""
import json, os, sys, time
t0 = time.perf_counter(); c0 = time.process_time()
marks = []
def mark(name):
    marks.append((name, time.perf_counter(), time.process_time()))
import torch
mark("import torch")
from silfit import load_body_model
from silfit.camera import load_camera
from silfit.fitting.silhouette_stage import SilhouetteFitConfig
from silfit.io.keypoints import read_keypoints
from silfit.outputs.write import save_fit
from silfit.run import fit
from silfit.silhouette.masks import read_mask
mark("import silfit (fitting, pipeline)")
subject, sil, out = sys.argv[1], sys.argv[2] == "1", sys.argv[3]
import cv2
kp = read_keypoints(os.path.join(subject, "keypoints.json"))
camera = load_camera(os.path.join(subject, "camera.json"))
image = cv2.cvtColor(cv2.imread(os.path.join(subject, "image.png")), cv2.COLOR_BGR2RGB)
mask = read_mask(os.path.join(subject, "mask.png"), size=(camera.width, camera.height)) if sil else None
model = load_body_model()
mark("read inputs, load model")
result = fit(kp, mask, camera, model=model, silhouette_config=SilhouetteFitConfig(), progress=False)
mark("fit (keypoint stage" + (" + silhouette stage)" if sil else ")"))
save_fit(result, out, model.faces.cpu().numpy(), kp, image, mask, {}, overwrite=True)
mark("save_fit (params, mesh, overlays, curves)")
prev = (t0, c0)
rows = []
for name, t, c in marks:
    rows.append((name, t - prev[0], c - prev[1]))
    prev = (t, c)
print(json.dumps(rows))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subject", help="a subject folder (keypoints.json, camera.json, image.png, mask.png)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with tempfile.TemporaryDirectory() as tmp:
        subject = args.subject
        if subject is None:
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "silfit",
                    "synth",
                    "--n",
                    "1",
                    "--seed",
                    "3",
                    "--size",
                    "512",
                    "--out",
                    f"{tmp}/data",
                    "--quiet",
                ],
                check=True,
                env=env,
                capture_output=True,
            )
            subject = f"{tmp}/data/subject_000"
        print(f"Subject {subject}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs.\n")
        for sil in (False, True):
            out = subprocess.run(
                [sys.executable, "-c", PHASES, subject, str(int(sil)), f"{tmp}/o"],
                check=True,
                env=env,
                capture_output=True,
                text=True,
            )
            rows = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"### Phases of one `silfit fit` ({'with' if sil else 'without'} the silhouette stage)\n")
            print("| phase | wall (s) | CPU (s) |\n|---|---:|---:|")
            for name, wall, cpu in rows:
                print(f"| {name} | {wall:.2f} | {cpu:.2f} |")
            print(f"| **total** | {sum(r[1] for r in rows):.2f} | {sum(r[2] for r in rows):.2f} |\n")
        print("### `python -m silfit fit` wall time (median of %d)\n" % args.repeats)
        print("| command | wall (s) | CPU (s) |\n|---|---:|---:|")
        for label, extra in (
            ("--no-silhouette", ["--no-silhouette"]),
            ("with --mask", ["--mask", f"{subject}/mask.png"]),
        ):
            walls, cpus = [], []
            for _ in range(args.repeats):
                cmd = [
                    sys.executable,
                    "-m",
                    "silfit",
                    "fit",
                    "--keypoints",
                    f"{subject}/keypoints.json",
                    "--camera",
                    f"{subject}/camera.json",
                    "--image",
                    f"{subject}/image.png",
                    "--out",
                    f"{tmp}/cli",
                    "--overwrite",
                    "--quiet",
                    *extra,
                ]
                t = time.perf_counter()
                before = os.times()
                subprocess.run(cmd, check=True, env=env, capture_output=True)
                after = os.times()
                walls.append(time.perf_counter() - t)
                cpus.append(after.children_user - before.children_user + after.children_system - before.children_system)
            print(f"| silfit fit {label} | {statistics.median(walls):.2f} | {statistics.median(cpus):.2f} |")
        print("\ntarget: silfit fit with silhouettes <= 5 s wall")
    return 0


if __name__ == "__main__":
    sys.exit(main())
