"""Benchmark of rig videos (issue 26): per-frame rig fits vs the temporal refinement over frames x views.

Generates ``--n`` fresh rig sequences (``silfit synth --videos --cameras V``: walk, run, squat, wave,
turn in turn; ``--frames`` frames, ``--noise`` px keypoint noise, ``--drop`` of the keypoints dropped,
seed ``--seed``) and fits each with :func:`silfit.fitting.sequence.fit_sequence` given the rig's views:
its per-frame initialisation (every frame the rig's keypoint stage, one batch: ``per-frame rig fits``)
and the joint refinement with one shape and the temporal terms (``temporal``). Prints, as means over
sequences, MPJPE in the world frame with no alignment at all, PA-MPJPE, acceleration error
(mm/frame^2), shape error (T-pose PVE) and seconds per frame.

    python benchmarks/bench_rig_sequence.py --n 3 --frames 20 --views 4 --seed 2026
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--noise", type=float, default=2.0)
    ap.add_argument("--drop", type=float, default=0.1)
    ap.add_argument("--size", type=int, default=256)
    args = ap.parse_args(argv)

    import torch

    from silfit import load_body_model
    from silfit.eval.score_sequence import score_sequence
    from silfit.fitting.sequence import fit_sequence
    from silfit.io.video import load_rig_sequence
    from silfit.synth.motion import SequenceConfig, generate_sequence_dataset

    model = load_body_model()
    rows = {"per-frame rig fits": [], "temporal": []}
    with tempfile.TemporaryDirectory() as tmp:
        cfg = SequenceConfig(
            seed=args.seed, frames=args.frames, size=args.size, noise_px=args.noise, drop_prob=args.drop
        )
        index = generate_sequence_dataset(tmp, args.n, cfg, model=model, views=args.views)
        for rec in index["sequences"]:
            d = Path(tmp) / rec["name"]
            seq = load_rig_sequence(d)
            gt = {k: v for k, v in np.load(d / "gt.npz").items()}
            t0 = time.perf_counter()
            r = fit_sequence(seq.frames, [v.view for v in seq.views], model)
            seconds = time.perf_counter() - t0
            init_s = r.timings["per_frame_init"]
            for name, params, s in (("per-frame rig fits", r.per_frame, init_s), ("temporal", r.params(), seconds)):
                row = score_sequence(model, gt, params)
                T = lambda a: torch.as_tensor(np.asarray(a), dtype=model.dtype)  # noqa: E731
                F = args.frames
                with torch.no_grad():
                    j = model(
                        **{
                            k: T(np.repeat(np.asarray(v)[None], F, 0) if np.asarray(v).ndim == 1 else v)
                            for k, v in params.items()
                        }
                    ).joints.numpy()
                row["mpjpe_world"] = float(np.linalg.norm(j[:, :24] - gt["joints"], axis=-1).mean() * 1000)
                row["s_per_frame"] = s / F
                rows[name].append(row)
            print(
                f"{rec['name']} {rec['motion']}: world MPJPE {rows['per-frame rig fits'][-1]['mpjpe_world']:.1f} -> "
                f"{rows['temporal'][-1]['mpjpe_world']:.1f} mm, {seconds:.0f} s",
                flush=True,
            )
    print(
        f"\n{args.n} rig sequences x {args.frames} frames x {args.views} views, {args.size} px, noise {args.noise} px, "
        f"drop {args.drop}, seed {args.seed} (means)\n"
    )
    print("| metric | per-frame rig fits | temporal |\n|---|---:|---:|")
    for key, label in (
        ("mpjpe_world", "MPJPE, world frame, no alignment (mm)"),
        ("pa_mpjpe", "PA-MPJPE (mm)"),
        ("mpjpe", "MPJPE, pelvis-aligned (mm)"),
        ("accel", "acceleration error (mm/frame²)"),
        ("shape", "shape error, T-pose PVE (mm)"),
        ("s_per_frame", "seconds per frame"),
    ):
        a, b = (np.mean([r[key] for r in rows[n]]) for n in rows)
        print(f"| {label} | {a:.1f} | {b:.1f} |" if key != "s_per_frame" else f"| {label} | {a:.2f} | {b:.2f} |")


if __name__ == "__main__":
    main()
