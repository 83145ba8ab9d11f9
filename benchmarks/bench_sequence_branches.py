"""Benchmark of the branch choice over time in sequence fits (issue 25, videos).

Generates fresh sequences of ``--motions`` (``silfit synth --videos``; ``--frames`` frames at
30 fps, ``--noise`` px keypoint noise, ``--drop`` of the keypoints dropped, seed ``--seed``) and fits
each with :func:`silfit.fitting.sequence.fit_sequence` once per ``--methods`` entry:

* ``before`` / ``after``: the defaults without / with the offsets round (``branch_choice.offsets=()`` / the
  default ``(1, 2, 4)``: each frame refitted from the picks of the frames 1, 2 and 4 away);
* ``off`` / ``on``: ``branch_choice.dp`` off (one per-frame answer refined) / on (a dynamic programme over each
  frame's hypotheses picks the branch sequence before the refinement), both without the offsets round;
* ``kp:NAME=VALUE+NAME=VALUE``: the defaults with the per-frame keypoint stage's options changed (as ``silfit fit
  --keypoint-option``), e.g. ``kp:starts.poses=2``: the per-frame start before issue 25's squat change (options
  whose values are lists cannot be given: ``--methods`` is split at commas).

Prints per sequence the PA-MPJPE median and worst frame, the frames above 2x the sequence's median, the
frames the programme changed, the CPU seconds of each fit, and the last method's CPU time over the first's.

    python benchmarks/bench_sequence_branches.py --motions squat,walk,run --seed 2031 --methods before,after
    python benchmarks/bench_sequence_branches.py --motions squat,walk,run --seed 2101 --methods kp:starts.poses=2,after
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np


def frame_errors(model, gt, params) -> np.ndarray:
    """PA-MPJPE per frame (mm)."""
    from silfit.eval.metrics import pa_mpjpe
    from silfit.eval.score_sequence import _joints

    F = int(np.asarray(gt["body_pose"]).shape[0])
    return np.asarray(pa_mpjpe(_joints(model, params, F), np.asarray(gt["joints"], dtype=np.float64))) * 1000


def method_config(m: str):
    """The :class:`SequenceFitConfig` of method ``m`` (module docstring); ``SystemExit`` with one line if unknown."""
    from silfit.fitting.sequence import SequenceFitConfig
    from silfit.runner.worker import keypoint_config

    cfg = SequenceFitConfig()
    if m in ("off", "on"):
        return replace(cfg, branch_choice=replace(cfg.branch_choice, dp=(m == "on"), offsets=()))
    if m == "before":
        return replace(cfg, branch_choice=replace(cfg.branch_choice, offsets=()))
    if m.startswith("kp:"):  # the defaults with per-frame keypoint-stage options, as --keypoint-option
        parts = m[3:].split("+")
        if not all("=" in p and p.split("=", 1)[0] for p in parts):
            raise SystemExit(f"method {m!r}: expected kp:NAME=VALUE+NAME=VALUE")
        try:
            return replace(cfg, keypoint=keypoint_config(dict(p.split("=", 1) for p in parts), cfg.keypoint))
        except ValueError as e:
            raise SystemExit(f"method {m!r}: {e}") from None
    if m != "after":
        raise SystemExit(f"unknown method {m!r} (before, after, off, on, kp:NAME=VALUE+NAME=VALUE)")
    return cfg


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--motions", default="squat,walk,run")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--seed", type=int, default=2031)
    ap.add_argument("--noise", type=float, default=2.0)
    ap.add_argument("--drop", type=float, default=0.1)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--keep", help="keep the dataset here")
    ap.add_argument(
        "--methods", default="before,after", help="settings to run (before, after, off, on, kp:NAME=VALUE+NAME=VALUE)"
    )
    ap.add_argument("--per-frame", action="store_true", help="print each frame's PA-MPJPE")
    ap.add_argument("--only", help="fit only these sequences (comma-separated names)")
    args = ap.parse_args(argv)

    from silfit import load_body_model
    from silfit.camera import load_camera
    from silfit.fitting.sequence import fit_sequence
    from silfit.synth.motion import SequenceConfig, generate_sequence_dataset
    from silfit.io.video import read_sequence

    model = load_body_model()
    motions = tuple(args.motions.split(","))
    methods = args.methods.split(",")
    configs = {m: method_config(m) for m in methods}  # a bad method fails before any data or fit
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_seqdp_"))
    if not (root / "index.json").is_file():
        generate_sequence_dataset(
            root,
            len(motions),
            SequenceConfig(
                seed=args.seed,
                frames=args.frames,
                size=args.size,
                noise_px=args.noise,
                drop_prob=args.drop,
                motions=motions,
            ),
        )
    index = json.loads((root / "index.json").read_text())
    table = []
    for rec in index["sequences"]:
        if args.only and rec["name"] not in args.only.split(","):
            continue
        d = root / rec["name"]
        seq = read_sequence(d)
        cam = load_camera(d / "camera.json")
        gt = dict(np.load(d / "gt.npz"))
        row = {"name": rec["name"], "motion": rec["motion"]}
        for m in methods:
            cfg = configs[m]
            t, c = time.perf_counter(), time.process_time()
            r = fit_sequence(seq.frames, cam, model, config=cfg)
            dt, cpu = time.perf_counter() - t, time.process_time() - c
            e = frame_errors(model, gt, r.params())
            e0 = frame_errors(model, gt, r.per_frame)
            med = float(np.median(e))
            changed = getattr(r, "rebranched", None)
            row[m] = {
                "median": med,
                "max": float(e.max()),
                "argmax": int(e.argmax()),
                "above": int((e > 2 * med).sum()),
                "seconds": dt,
                "cpu": cpu,
                "changed": int(np.sum(changed)) if changed is not None else 0,
                "init_median": float(np.median(e0)),
                "init_max": float(e0.max()),
            }
            if args.per_frame:
                print(f"{rec['name']} {rec['motion']} {m} final:", " ".join(f"{x:.0f}" for x in e))
                print(f"{rec['name']} {rec['motion']} {m} init: ", " ".join(f"{x:.0f}" for x in e0))
                if changed is not None:
                    print(f"{rec['name']} {rec['motion']} {m} changed:", np.flatnonzero(changed).tolist())
            print(rec["name"], rec["motion"], m, {k: round(v, 1) for k, v in row[m].items()}, flush=True)
        table.append(row)
    load = os.getloadavg()
    print(
        f"\n{len(table)} sequences x {args.frames} frames, {args.noise} px noise, {args.drop:.0%} keypoints dropped, "
        f"seed {args.seed}; load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} (shared CPU)\n"
    )
    head = " | ".join(f"{m}: median / max (frame) / above 2x median / changed / CPU s" for m in methods)
    print(f"| sequence | {head} | CPU time ratio |")
    print("|---|" + "---|" * len(methods) + "---:|")
    for row in table:
        cells = " | ".join(
            f"{row[m]['median']:.1f} / {row[m]['max']:.1f} ({row[m]['argmax']}) / {row[m]['above']} / "
            f"{row[m]['changed']} / {row[m]['cpu']:.0f}"
            for m in methods
        )
        ratio = row[methods[-1]]["cpu"] / row[methods[0]]["cpu"] if len(methods) > 1 else 1.0
        print(f"| {row['name']} {row['motion']} | {cells} | {ratio:.2f} |")


if __name__ == "__main__":
    main()
