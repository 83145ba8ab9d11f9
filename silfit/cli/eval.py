"""``silfit eval``: score fits against a dataset's ground truth (or run the fitter first)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from . import CLIError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "eval",
        help="score fits against ground truth: MPJPE, PA-MPJPE, PVE, shape, translation, 2D, IoU, time",
        description=(
            "Score existing fit outputs (FITS/<subject>/<method>/params.npz, default FITS = DATASET/fits) against "
            "every subject's gt.npz, or run the fitter first (--run, or automatically when no fit exists). Prints "
            "a Markdown table (mean and median per metric per method), writes the JSON report and a per-subject "
            "error plot. Malformed subjects are skipped and listed with their path and field. A sequence dataset "
            "(silfit synth --videos) is scored per frame and with the temporal refinement: PA-MPJPE, MPJPE, "
            "acceleration error, shape error, seconds per frame."
        ),
    )
    p.add_argument("dataset", metavar="DIR", help="dataset folder (subject folders, optionally index.json)")
    p.add_argument(
        "--report",
        dest="out",
        default="report.json",
        metavar="FILE",
        help="the JSON report's path (default report.json)",
    )
    p.add_argument("--fits", default=None, help="folder of fit outputs (default DIR/fits)")
    p.add_argument("--run", action="store_true", help="run the fitter even if fits exist (overwrites them)")
    p.add_argument(
        "--methods", default="keypoints,silhouette", help="methods to run with --run (default keypoints,silhouette)"
    )
    p.add_argument("--plot", default=None, help="per-subject error plot PNG (default: next to --report, *_errors.png)")
    p.add_argument("--no-iou", action="store_true", help="skip the silhouette IoU (no rendering)")
    p.add_argument("--model", default=None, help="body model file (default: the shipped open body model)")
    p.add_argument("--quiet", action="store_true", help="no progress bars while fitting")
    from .flags import deprecated_alias

    deprecated_alias(p, "--out", "--report")  # --out: an output folder everywhere else
    p.set_defaults(func=run)


def run_sequences(args: argparse.Namespace, model) -> int:
    """A ``silfit synth --videos`` dataset: per-frame vs temporal fits (silfit.eval.score_sequence)."""
    from ..eval.score_sequence import evaluate_sequences, sequence_table

    report = evaluate_sequences(args.dataset, fits=args.fits, model=model, run=args.run, progress=not args.quiet)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(sequence_table(report))
    for s in report["skipped"]:
        print(f"skipped {s['subject']}: {s['error']}")
    print(f"report: {out}")
    return 0 if report["results"] else 1


def run(args: argparse.Namespace) -> int:
    from ..eval.evaluate import FitterUnavailable, evaluate_dataset, markdown_table, plot_errors

    model = None
    if args.model is not None:
        from ..body import load_body_model

        model = load_body_model(args.model)
    from ..eval.score_sequence import is_sequence_dataset

    if is_sequence_dataset(args.dataset):
        return run_sequences(args, model)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    from ..eval.score_rig import evaluate_rig_dataset, is_rig_dataset

    rig = is_rig_dataset(args.dataset)  # silfit synth --cameras: world-frame metrics, IoU per view
    try:
        report = (evaluate_rig_dataset if rig else evaluate_dataset)(
            args.dataset,
            fits=args.fits,
            model=model,
            run=args.run,
            methods=methods,
            iou=not args.no_iou,
            progress=not args.quiet,
        )
    except FitterUnavailable as err:
        raise CLIError(
            f"{err}; pass --fits DIR with existing fit outputs (FITS/<subject>/<method>/params.npz)"
        ) from None
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    plot = Path(args.plot) if args.plot else out.with_name(out.stem + "_errors.png")
    if report["results"]:
        report["plot"] = str(plot_errors(report, plot))
    out.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(markdown_table(report))
    for s in report["skipped"]:
        print(f"skipped {s['subject']}{' (' + s['method'] + ')' if 'method' in s else ''}: {s['error']}")
    if report["missing_fits"]:
        print(f"no fit found for: {', '.join(report['missing_fits'])}")
    print(f"report: {out}" + (f"; plot: {report['plot']}" if "plot" in report else ""))
    return 0 if report["results"] else 1
