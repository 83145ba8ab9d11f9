"""Soak test: many renders and fits in one process, printing resident memory (RSS).

1. ``--renders`` (default 1,000) differentiable Mitsuba silhouettes of the open body
   model (13,348 vertices) in a fresh random pose each time, rendered in a window around
   the person (``--size`` px, 4 spp) and back-propagated to the pose and shape through
   the body model (a squared-error loss against a fixed target).
2. ``--subjects`` (default 200) subjects fitted one after another the way a dataset
   run does: ``silfit.fit`` (the keypoint stage, BODY_25 keypoints of a random posed
   body with 2 px noise, 512x512 default camera) and ``silfit.save_fit`` (params,
   mesh, overlay with pyrender, metrics) into a temporary folder that is then deleted.
   ``--iters-scale`` shrinks the keypoint stage's iteration counts (default 1: the real
   stage); ``--no-save`` leaves ``save_fit`` out.

RSS (``/proc/self/status`` VmRSS) is printed every ``--every`` renders / ``--every-fit``
fits. The target is flat after warm-up: the drift from the end of warm-up (the first
10 % of each phase) to the end under 50 MB.

    python benchmarks/soak.py [--renders 1000] [--subjects 200] [--iters-scale 1]
"""

from __future__ import annotations

import argparse
import gc
import math
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import silfit  # noqa: E402, F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import torch  # noqa: E402

TARGET_DRIFT_MB = 50.0


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status (Linux only)")


def soak_renders(model, n: int, size: int, every: int, rows: list) -> None:
    from silfit.render import SilhouetteRenderer
    from silfit.camera import Camera

    renderer = SilhouetteRenderer(model.faces, spp=4, edge_spp=1)
    camera = Camera.from_image_size(512, 512)
    g = torch.Generator().manual_seed(0)
    orient, transl = torch.tensor([[math.pi, 0.0, 0.0]]), torch.tensor([[0.0, 0.2, 3.0]])
    with torch.no_grad():
        target_verts = model(global_orient=orient, transl=transl).vertices[0]
        target, window = renderer.render_roi(target_verts, camera, size=size, seed=0)
        target = (target > 0.5).float()
    t0 = time.perf_counter()
    for i in range(1, n + 1):
        pose = (torch.randn(1, model.num_body_pose, generator=g) * 0.15).requires_grad_()
        betas = (torch.randn(1, 10, generator=g) * 0.5).requires_grad_()
        verts = model(betas=betas, body_pose=pose, global_orient=orient, transl=transl).vertices[0]
        sil, _ = renderer.render_roi(verts, camera, window=window)
        loss = ((sil - target) ** 2).sum()
        loss.backward()
        assert torch.isfinite(pose.grad).all() and pose.grad.abs().sum() > 0
        if i % every == 0 or i == 1:
            rows.append(("render", i, time.perf_counter() - t0, rss_mb()))
            print(f"  render {i:5d}  {rows[-1][2]:7.1f} s  RSS {rows[-1][3]:8.1f} MB", file=sys.stderr, flush=True)


def soak_fits(model, n: int, iters_scale: float, every: int, rows: list, save: bool = True) -> None:
    from bench_fit import generate

    import silfit
    from silfit.fitting import KeypointFitConfig
    from silfit.io.keypoints import KeypointSet

    cfg = KeypointFitConfig()
    if iters_scale != 1:
        s = lambda v: max(1, int(round(v * iters_scale)))  # noqa: E731
        cfg = replace(
            cfg,
            decision_iters=s(cfg.decision_iters),
            camera_iters=s(cfg.camera_iters),
            pose_iters=tuple(s(v) for v in cfg.pose_iters),
            shape_iters=s(cfg.shape_iters),
            final_iters=s(cfg.final_iters),
        )
    subjects = generate(model, n, seed=1)
    faces = model.faces.numpy()
    work = Path(tempfile.mkdtemp(prefix="silfit-soak-"))
    t0 = time.perf_counter()
    warnings = 0
    try:
        for i in range(1, n + 1):
            arr = subjects["keypoints"][i - 1]
            kp = KeypointSet(arr[:, :2], arr[:, 2], "body25", source=f"subject {i}")
            result = silfit.fit(kp, camera=subjects["cameras"][i - 1], model=model, keypoint_config=cfg, progress=False)
            warnings += len(result.metrics["warnings"])
            if save:
                shutil.rmtree(silfit.save_fit(result, work / "fit", faces, kp))
            del result
            if i % every == 0 or i == 1:
                rows.append(("fit", i, time.perf_counter() - t0, rss_mb()))
                print(f"  fit    {i:5d}  {rows[-1][2]:7.1f} s  RSS {rows[-1][3]:8.1f} MB", file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"  {warnings} plausibility warnings over {n} fits", file=sys.stderr)


def drift(rows: list, phase: str, warmup_fraction: float = 0.1):
    pts = [(i, mb) for p, i, _, mb in rows if p == phase]
    if len(pts) < 2:
        return None
    last = pts[-1][0]
    after = [mb for i, mb in pts if i >= warmup_fraction * last]
    return after[0], pts[-1][1], pts[-1][1] - after[0], max(after) - after[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--renders", type=int, default=1000)
    ap.add_argument("--subjects", type=int, default=200)
    ap.add_argument("--size", type=int, default=256, help="silhouette window size (default 256)")
    ap.add_argument("--iters-scale", type=float, default=1.0, help="scale the keypoint stage's iteration counts")
    ap.add_argument("--every", type=int, default=100, help="RSS every N renders (default 100)")
    ap.add_argument("--every-fit", type=int, default=20, help="RSS every N fits (default 20)")
    ap.add_argument(
        "--no-save", action="store_true", help="fit only, no save_fit (to tell the fit's memory from the output's)"
    )
    args = ap.parse_args(argv)

    import silfit

    rows = [("start", 0, 0.0, rss_mb())]
    model = silfit.load_body_model()
    rows.append(("model loaded", 0, 0.0, rss_mb()))
    if args.renders:
        soak_renders(model, args.renders, args.size, args.every, rows)
    gc.collect()
    if args.subjects:
        soak_fits(model, args.subjects, args.iters_scale, args.every_fit, rows, save=not args.no_save)
    print(
        f"Soak: {args.renders} silhouettes ({args.size}x{args.size} window, 4 spp, forward+backward) and "
        f"{args.subjects} fits (keypoint stage, iterations x{args.iters_scale:g}{'' if args.no_save else ', + save_fit'}) in one process; "
        f"torch threads {torch.get_num_threads()}.\n"
    )
    print("| phase | step | elapsed (s) | RSS (MB) |\n|---|---:|---:|---:|")
    for phase, i, t, mb in rows:
        print(f"| {phase} | {i} | {t:.1f} | {mb:.1f} |")
    ok = True
    print("\n| phase | RSS after warm-up (MB) | RSS at end (MB) | drift (MB) | peak above warm-up (MB) | target |")
    print("|---|---:|---:|---:|---:|---|")
    for phase in ("render", "fit"):
        d = drift(rows, phase)
        if d is None:
            continue
        met = d[2] < TARGET_DRIFT_MB
        ok &= met
        print(
            f"| {phase} | {d[0]:.1f} | {d[1]:.1f} | {d[2]:+.1f} | {d[3]:.1f} | < {TARGET_DRIFT_MB:.0f} MB: "
            f"{'met' if met else 'MISSED'} |"
        )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
