"""Benchmark of sequence fitting (issue 15, videos): per-frame fits vs the temporal refinement.

Generates ``--n`` fresh sequences (``silfit synth --videos``: walk, run, squat, wave,
turn in turn; ``--frames`` frames at 30 fps, ``--noise`` px keypoint noise, ``--drop`` of
the keypoints dropped, seed ``--seed``) and fits each

* **per-frame**: the single-image keypoint stage with its default settings, all frames of a
  sequence as one batch (``KeypointFitter.fit``; the batched single-image cost);
* **temporal**: :func:`silfit.fitting.sequence.fit_sequence` (its own per-frame
  initialisation, reported as ``per-frame init``, then the joint refinement with one shape
  and the temporal terms).

Prints PA-MPJPE, MPJPE, acceleration error (mm/frame^2), shape error (T-pose PVE) and
seconds per frame (means over sequences), and the targets: acceleration error cut >= 3x,
PA-MPJPE cut >= 20 %, per-frame cost of a sequence <= the batched single-image cost.
``--baseline K`` runs the default per-frame fits on the first K sequences only (the
comparison rows then use those K).

``--silhouette N`` runs, instead, the silhouette stage on the first ``--silhouette-frames``
frames of the first N sequences (the stage renders every frame at every step, so 600
frames do not fit a short run): the keypoint refinement, then the silhouette stage with the
temporal terms and without them (weight 0), with PA-MPJPE, acceleration error, shape
error, the mean silhouette IoU and seconds per frame.

    python benchmarks/bench_sequence.py --n 10 --frames 60 --seed 2027
    python benchmarks/bench_sequence.py --n 10 --frames 60 --seed 2027 --silhouette 2 --silhouette-frames 20
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--seed", type=int, default=2027)
    ap.add_argument("--noise", type=float, default=2.0)
    ap.add_argument("--drop", type=float, default=0.1)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument(
        "--baseline", type=int, default=None, help="default per-frame fits on the first K sequences (default all)"
    )
    ap.add_argument("--keep", help="keep the dataset here")
    ap.add_argument(
        "--from", dest="start", type=int, default=0, help="fit sequences from this index on (to split a run)"
    )
    ap.add_argument("--silhouette", type=int, default=0, help="the silhouette stage on the first N sequences instead")
    ap.add_argument("--silhouette-frames", type=int, default=20, help="frames of each (from the first)")
    ap.add_argument(
        "--silhouette-levels",
        default=None,
        metavar="R:N,...",
        help="silhouette levels as resolution:steps (default: the stage's own, 128:60,256:50)",
    )
    args = ap.parse_args(argv)

    from silfit import load_body_model
    from silfit.camera import load_camera
    from silfit.eval.score_sequence import score_sequence
    from silfit.fitting import KeypointFitter
    from silfit.fitting.keypoint_stage import _check_torso
    from silfit.fitting.sequence import fit_sequence, interpolate_frames
    from silfit.synth.motion import SequenceConfig, generate_sequence_dataset
    from silfit.io.video import read_sequence

    model = load_body_model()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_seq_"))
    t0 = time.perf_counter()
    if not (root / "index.json").is_file():
        generate_sequence_dataset(
            root,
            args.n,
            SequenceConfig(
                seed=args.seed, frames=args.frames, size=args.size, noise_px=args.noise, drop_prob=args.drop
            ),
        )
    print(
        f"dataset: {root} ({args.n} x {args.frames} frames, {time.perf_counter() - t0:.0f} s to generate)", flush=True
    )
    index = __import__("json").loads((root / "index.json").read_text())
    if args.silhouette:
        from silfit.fitting.silhouette_stage import SilhouetteFitConfig

        levels = (
            [tuple(int(x) for x in lv.split(":")) for lv in args.silhouette_levels.split(",")]
            if args.silhouette_levels
            else None
        )
        sil = SilhouetteFitConfig(
            **(
                {}
                if levels is None
                else {"resolutions": tuple(r for r, _ in levels), "iterations": tuple(n for _, n in levels)}
            )
        )
        return silhouette_benchmark(model, root, index["sequences"][: args.silhouette], args.silhouette_frames, sil)
    fitter = KeypointFitter(model)
    K = args.n if args.baseline is None else min(args.baseline, args.n)
    rows = {"per-frame": [], "per-frame init": [], "temporal": []}
    for i, rec in enumerate(index["sequences"]):
        if i < args.start:
            continue
        i -= args.start
        d = root / rec["name"]
        seq = read_sequence(d)
        cam = load_camera(d / "camera.json")
        gt = dict(np.load(d / "gt.npz"))
        F = len(seq.frames)
        if i < K:  # the single-image stage, all usable frames as one batch
            ok = []
            for f, ks in enumerate(seq.frames):
                try:
                    _check_torso(ks)
                    ok.append(f)
                except (ValueError, AttributeError):
                    pass
            t = time.perf_counter()
            res = fitter.fit([seq.frames[f] for f in ok], cam, progress=False)
            dt = time.perf_counter() - t
            per = {
                n: np.zeros((F, getattr(res, n).shape[1])) for n in ("betas", "body_pose", "global_orient", "transl")
            }
            for n in per:
                per[n][ok] = getattr(res, n)
            known = np.zeros(F, dtype=bool)
            known[ok] = True
            rows["per-frame"].append(
                {**score_sequence(model, gt, interpolate_frames(per, known)), "seconds_per_frame": dt / len(ok)}
            )
        t = time.perf_counter()
        r = fit_sequence(seq.frames, cam, model)
        dt = time.perf_counter() - t
        rows["per-frame init"].append(
            {**score_sequence(model, gt, r.per_frame), "seconds_per_frame": r.timings["per_frame_init"] / F}
        )
        rows["temporal"].append(
            {
                **score_sequence(model, gt, r.params(), r.bridged),
                "seconds_per_frame": dt / F,
                "refaced": int(r.refaced.sum()),
                "bridged": int(r.bridged.sum()),
            }
        )
        last = {m: v[-1] for m, v in rows.items() if len(v) == i + 1}
        print(
            f"{rec['name']} {rec['motion']:5s} "
            + "; ".join(
                f"{m}: PA {v['pa_mpjpe']:.1f} accel {v['accel']:.1f} shape {v['shape']:.1f} {v['seconds_per_frame']:.2f} s/f"
                for m, v in last.items()
            ),
            flush=True,
        )

    def mean(method, key, first=None):
        vals = [r[key] for r in rows[method][:first] if key in r]
        return float(np.mean(vals)) if vals else float("nan")

    load = os.getloadavg()
    print(
        f"\n{len(rows['temporal'])} sequences x {args.frames} frames, {args.noise} px noise, {args.drop:.0%} keypoints dropped, seed "
        f"{args.seed}; load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} (2-core CPU, shared)\n"
    )
    keys = (
        ("pa_mpjpe", "PA-MPJPE (mm)"),
        ("mpjpe", "MPJPE (mm)"),
        ("accel", "acceleration error (mm/frame^2)"),
        ("shape", "shape error, T-pose PVE (mm)"),
        ("seconds_per_frame", "seconds per frame"),
    )
    print(
        "| metric | per-frame (default, batched)"
        + (f" [first {K}]" if K < args.n else "")
        + " | per-frame init | temporal |"
    )
    print("|---|---:|---:|---:|")
    for k, label in keys:
        fmt = "{:.2f}" if k == "seconds_per_frame" else "{:.1f}"
        print(
            f"| {label} | {fmt.format(mean('per-frame', k))} | {fmt.format(mean('per-frame init', k))} | {fmt.format(mean('temporal', k))} |"
        )
    if K:
        acc = mean("per-frame", "accel") / mean("temporal", "accel", K)
        pa = 1 - mean("temporal", "pa_mpjpe", K) / mean("per-frame", "pa_mpjpe")
        cost = mean("temporal", "seconds_per_frame", K) / mean("per-frame", "seconds_per_frame")
        print(
            f"\nagainst the default per-frame fits (same {K} sequences): acceleration error cut {acc:.1f}x (target >= 3x), "
            f"PA-MPJPE cut {pa:.0%} (target >= 20 %), per-frame cost {cost:.2f}x the batched single-image cost (target <= 1)"
        )
    acc = mean("per-frame init", "accel") / mean("temporal", "accel")
    pa = 1 - mean("temporal", "pa_mpjpe") / mean("per-frame init", "pa_mpjpe")
    print(
        f"against its own per-frame initialisation (all {len(rows['temporal'])}): acceleration error cut {acc:.1f}x, PA-MPJPE cut {pa:.0%}"
    )


def silhouette_benchmark(model, root, records, frames, config):
    from silfit.camera import load_camera
    from silfit.eval.score_sequence import score_sequence
    from silfit.fitting.sequence import fit_sequence, refine_sequence_silhouettes
    from silfit.silhouette.masks import read_mask
    from silfit.io.video import read_sequence

    rows = {"keypoints (temporal)": [], "+ silhouette, temporal terms": [], "+ silhouette, no temporal terms": []}
    for rec in records:
        d = root / rec["name"]
        seq = read_sequence(d)
        cam = load_camera(d / "camera.json")
        gt = {k: (v[:frames] if np.ndim(v) and k not in ("betas",) else v) for k, v in np.load(d / "gt.npz").items()}
        kps = seq.frames[:frames]
        masks = [read_mask(seq.masks[n]) for n in seq.numbers[:frames]]
        t = time.perf_counter()
        r = fit_sequence(kps, cam, model)
        t_kp = time.perf_counter() - t
        rows["keypoints (temporal)"].append(
            {**score_sequence(model, gt, r.params()), "seconds_per_frame": t_kp / frames}
        )
        for label, w in (("+ silhouette, temporal terms", None), ("+ silhouette, no temporal terms", 0.0)):
            t = time.perf_counter()
            s = refine_sequence_silhouettes(
                model, r, kps, masks, config=config, **({} if w is None else {"temporal_weight": w})
            )
            dt = time.perf_counter() - t
            rows[label].append(
                {
                    **score_sequence(model, gt, s.params()),
                    "iou": float(np.nanmean(s.silhouette_iou)),
                    "iou_start": s.silhouette_iou_start,
                    "seconds_per_frame": (t_kp + dt) / frames,
                }
            )
        print(
            rec["name"],
            rec["motion"],
            {m: {k: round(v, 3) for k, v in r_[-1].items()} for m, r_ in rows.items()},
            flush=True,
        )
    load = os.getloadavg()
    print(
        f"\nsilhouette stage (levels {list(zip(config.resolutions, config.iterations))}) on the first {frames} frames "
        f"of {len(records)} sequences; load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}\n"
    )
    print(
        "| method | PA-MPJPE (mm) | acceleration error (mm/frame^2) | shape error (mm) | silhouette IoU | seconds per frame |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for m, rs in rows.items():
        mean = lambda k: float(np.mean([r[k] for r in rs])) if rs and k in rs[0] else float("nan")  # noqa: E731
        iou = f"{mean('iou_start'):.3f} -> {mean('iou'):.3f}" if "iou" in rs[0] else "-"
        print(
            f"| {m} | {mean('pa_mpjpe'):.1f} | {mean('accel'):.1f} | {mean('shape'):.1f} | {iou} | {mean('seconds_per_frame'):.2f} |"
        )


if __name__ == "__main__":
    main()
