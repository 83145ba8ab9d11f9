"""How reproducible is a silhouette fit? The same short fit (fixed seed) of a shipped
noise-free subject, run ``--runs`` times from one keypoint-stage result; prints the
spread (max - min) of PA-MPJPE, the translation and the pose.

    python tools/repro_silhouette.py                 # Dr.Jit one thread (the renderer's default)
    python tools/repro_silhouette.py --threads none  # Dr.Jit's own pool size (the old behaviour)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subject", default=str(ROOT / "data" / "synthetic" / "subject_000"))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--resolution", type=int, default=96)
    ap.add_argument("--threads", default="1", help="Dr.Jit threads for the renderer, or 'none'")
    args = ap.parse_args(argv)

    from silfit.render.silhouette import SilhouetteRenderer
    from silfit import load_body_model
    from silfit.io.subjects import load_subject
    from silfit.eval.metrics import pa_mpjpe
    from silfit.fitting import KeypointFitConfig, fit_keypoints
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig, fit_silhouette

    model = load_body_model()
    s = load_subject(Path(args.subject))
    kcfg = KeypointFitConfig(camera_iters=20, pose_iters=(20, 20, 30), shape_iters=10, final_iters=20)
    kr = fit_keypoints(s.keypoints, s.camera, model, config=kcfg, progress=False)
    threads = None if args.threads == "none" else int(args.threads)
    renderer = SilhouetteRenderer(model.faces, threads=threads)
    cfg = SilhouetteFitConfig(resolutions=(args.resolution,), iterations=(args.steps,))
    pa, transl, pose = [], [], []
    print("| run | seconds | PA-MPJPE mm | transl (m) |\n|---|---|---|---|")
    for r in range(args.runs):
        t0 = time.perf_counter()
        sr = fit_silhouette(
            model, kr.params(0), s.camera, s.mask, s.keypoints.as_array(), config=cfg, renderer=renderer, progress=False
        )
        with torch.no_grad():
            joints = model(**{k: torch.as_tensor(v) for k, v in sr.params().items()}).joints[0].numpy()
        pa.append(1000 * pa_mpjpe(joints, s.gt.joints))
        transl.append(sr.transl[0].astype(np.float64))
        pose.append(sr.body_pose[0].astype(np.float64))
        print(
            f"| {r} | {time.perf_counter() - t0:.1f} | {pa[-1]:.3f} | {np.round(transl[-1], 5).tolist()} |", flush=True
        )
    spread_t = 1000 * np.ptp(np.stack(transl), 0)
    print(
        f"\nDr.Jit threads {args.threads}, {args.steps} steps at {args.resolution} px, {args.runs} runs: spread "
        f"PA-MPJPE {np.ptp(pa):.3f} mm, translation x/y/z {spread_t[0]:.3f}/{spread_t[1]:.3f}/{spread_t[2]:.3f} mm, "
        f"body_pose max {np.ptp(np.stack(pose), 0).max():.2e} rad"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
