"""Same inputs, same fit: how much a keypoint fit depends on how it was run; prints Markdown tables.

The parent process generates ``--subjects`` fresh subjects (random poses inside the joint
limits, all yaws, 2 px keypoint noise; ``benchmarks/bench_fit.py``'s generator, seed
``--seed``) and writes their keypoints to one file, so every run reads the same bytes. Each
run is a child process with its own environment, since ``OMP_NUM_THREADS`` and
``ATEN_CPU_CAPABILITY`` act at process start:

* batch sizes 1, 8 and 32 (the default kernels and threads),
* ``OMP_NUM_THREADS`` 1 and 2 (batch 8),
* ``ATEN_CPU_CAPABILITY=default`` and ``=avx2`` (batch 8; ``avx512`` too where the CPU has it),

each in the keypoint stage's float64 (the default) and in float32 (the old default, for the
comparison); ``--before REF`` runs the same settings on the code of git revision ``REF`` too (a
temporary worktree; its own defaults), the spread and speed before this work. Against the first run of its dtype (batch 1), each run's largest difference of any
parameter (radians / shape units / metres) and of any vertex (mm) over all subjects is shown,
with the number of subjects whose vertices moved by more than 0.1 mm, and the seconds per image.

    python benchmarks/bench_reproducible.py --subjects 30 --seed 2207 --before 4f1b8e7
    python benchmarks/bench_reproducible.py --subjects 6 --quick      # batch 1 and 4, two settings
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

import silfit  # noqa: F401  (first: the CPU kernels are chosen before numpy and torch load, silfit.kernels)

import numpy as np  # noqa: E402

from silfit.kernels import cpu_flags  # noqa: E402

HERE = Path(__file__).resolve().parent
PARAMS = ("betas", "global_orient", "body_pose", "transl")


def settings(quick: bool) -> list:
    """``(label, batch, env)`` of each run; the first is the reference."""
    if quick:
        return [
            ("batch 1", 1, {}),
            ("batch 4", 4, {}),
            ("batch 4, OMP 1", 4, {"OMP_NUM_THREADS": "1"}),
            ("batch 4, ATEN default", 4, {"ATEN_CPU_CAPABILITY": "default"}),
        ]
    runs = [
        ("batch 1", 1, {}),
        ("batch 8", 8, {}),
        ("batch 32", 32, {}),
        ("batch 8, OMP 1", 8, {"OMP_NUM_THREADS": "1"}),
        ("batch 8, OMP 2", 8, {"OMP_NUM_THREADS": "2"}),
        ("batch 8, ATEN default", 8, {"ATEN_CPU_CAPABILITY": "default"}),
        ("batch 8, ATEN avx2", 8, {"ATEN_CPU_CAPABILITY": "avx2"}),
    ]
    if "avx512f" in cpu_flags():
        runs.append(("batch 8, ATEN avx512", 8, {"ATEN_CPU_CAPABILITY": "avx512"}))
    return runs


def generate_inputs(path: Path, n: int, seed: int) -> None:
    sys.path.insert(0, str(HERE))
    from bench_fit import generate

    from silfit import load_body_model

    data = generate(load_body_model(), n, seed=seed)
    cam = data["cameras"][0]
    np.savez(
        path, keypoints=np.stack(data["keypoints"]), camera=[cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy]
    )


def worker(inputs: str, out: str, batch: int, dtype: str) -> None:
    """Fit the subjects of ``inputs`` in batches of ``batch``; write parameters, vertices and seconds."""
    import torch

    from silfit import load_body_model
    from silfit.camera import Camera
    from silfit.fitting import KeypointFitConfig, KeypointFitter

    d = np.load(inputs)
    w, h, fx, fy, cx, cy = d["camera"].tolist()
    cam = Camera(width=int(w), height=int(h), fx=fx, fy=fy, cx=cx, cy=cy)
    kps = d["keypoints"]
    fitter = KeypointFitter(
        load_body_model(), config=KeypointFitConfig() if dtype == "before" else KeypointFitConfig(dtype=dtype)
    )
    res = {k: [] for k in PARAMS + ("vertices",)}
    t0, c0 = time.perf_counter(), time.process_time()
    for s in range(0, len(kps), batch):
        r = fitter.fit(kps[s : s + batch], [cam] * len(kps[s : s + batch]), progress=False)
        for k in PARAMS + ("vertices",):
            res[k].append(getattr(r, k))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    np.savez(
        out,
        **{k: np.concatenate(v) for k, v in res.items()},
        wall=wall / len(kps),
        cpu=cpu / len(kps),
        threads=torch.get_num_threads(),
        code=str(Path(silfit.__file__).resolve().parent),
    )


def run_child(inputs: Path, out: Path, batch: int, dtype: str, env: dict, code: Path = None) -> None:
    e = dict(os.environ)
    for k in ("OMP_NUM_THREADS", "ATEN_CPU_CAPABILITY"):
        if k not in env:
            e.pop(k, None)
    e.update(env)
    if code is not None:  # another revision's silfit first on the path
        e["PYTHONPATH"] = os.pathsep.join([str(code), e.get("PYTHONPATH", "")])
    cmd = [sys.executable, __file__, "--worker", str(inputs), str(out), str(batch), dtype]
    subprocess.run(cmd, env=e, check=True)


def compare(ref: dict, run: dict) -> dict:
    param = max(float(np.abs(run[k].astype(np.float64) - ref[k]).max()) for k in PARAMS)
    dv = np.linalg.norm(run["vertices"].astype(np.float64) - ref["vertices"], axis=-1).max(-1) * 1000  # mm per subject
    return {"param": param, "vertex": float(dv.max()), "moved": int((dv > 0.1).sum())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--subjects", type=int, default=30)
    ap.add_argument("--seed", type=int, default=2207)
    ap.add_argument("--dtypes", default="float64,float32")
    ap.add_argument("--quick", action="store_true", help="batch 1 and 4, OMP 1, ATEN default only")
    ap.add_argument("--before", metavar="REF", help="also run the settings on git revision REF's code (its defaults)")
    ap.add_argument("--worker", nargs=4, metavar=("INPUTS", "OUT", "BATCH", "DTYPE"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        worker(a.worker[0], a.worker[1], int(a.worker[2]), a.worker[3])
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        inputs = tmp / "inputs.npz"
        generate_inputs(inputs, a.subjects, a.seed)
        rows, speed = [], {}
        kinds = a.dtypes.split(",")
        code = None
        if a.before:
            code = tmp / "before"
            subprocess.run(
                ["git", "-C", str(HERE.parent), "worktree", "add", "--detach", str(code), a.before],
                check=True,
                capture_output=True,
            )
            kinds = ["before"] + kinds
        for dtype in kinds:
            ref = None
            for i, (label, batch, env) in enumerate(settings(a.quick)):
                out = tmp / f"{dtype}_{i}.npz"
                t0 = time.perf_counter()
                run_child(inputs, out, batch, dtype, env, code if dtype == "before" else None)
                r = dict(np.load(out))
                used = str(r.pop("code"))
                if (dtype == "before") != used.startswith(str(tmp)):
                    raise SystemExit(f"the {dtype} run imported silfit from {used}")
                print(
                    f"  {dtype:8s} {label:24s} {r['wall']:.2f} s/image ({time.perf_counter() - t0:.0f} s with start-up)",
                    file=sys.stderr,
                    flush=True,
                )
                if ref is None:
                    ref = {k: v.astype(np.float64) for k, v in r.items()}
                rows.append((dtype, label, compare(ref, r), float(r["wall"]), float(r["cpu"])))
                speed.setdefault(dtype, {})[label] = float(r["wall"])
        if code is not None:
            subprocess.run(["git", "-C", str(HERE.parent), "worktree", "remove", "--force", str(code)], check=False)
    print(
        f"\n{a.subjects} fresh subjects (seed {a.seed}), keypoint stage, differences against batch 1 of the same code "
        f"and dtype{f'; before: {a.before}, its float32 default' if a.before else ''}\n"
    )
    print(
        "| dtype | run | max parameter diff | max vertex diff (mm) | subjects moved > 0.1 mm | s/image (wall) | s/image (CPU) |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for dtype, label, c, wall, cpu in rows:
        print(
            f"| {dtype} | {label} | {c['param']:.2e} | {c['vertex']:.4f} | {c['moved']} / {a.subjects} | {wall:.2f} | {cpu:.2f} |"
        )
    if "float64" in speed and len(speed) > 1:
        others = [k for k in speed if k != "float64"]
        print(
            "\n| run | "
            + " | ".join(f"float64 / {k} time (wall)" for k in others)
            + " |\n|---|"
            + "---:|" * len(others)
        )
        for label in speed["float64"]:
            print(
                f"| {label} | "
                + " | ".join(
                    f"{speed['float64'][label] / speed[k][label]:.2f}x" if label in speed[k] else "-" for k in others
                )
                + " |"
            )
    print(json.dumps({"subjects": a.subjects, "seed": a.seed}), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
