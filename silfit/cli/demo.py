"""``silfit demo``: fit a shipped synthetic subject end to end (see :mod:`silfit.demos.body`)."""

from __future__ import annotations

import time
from pathlib import Path

from . import warn


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo", help="fit a shipped synthetic subject (keypoints, then silhouette) and write pictures and a table"
    )
    p.add_argument("--out", default="silfit-demo", help="output folder (default: ./silfit-demo)")
    p.add_argument("--subject", help="a subject folder in the synthetic format (default: the shipped subject_000)")
    p.add_argument(
        "--photo",
        nargs="?",
        const="",
        metavar="PATH",
        help="fit a photograph instead: detect the person, fit, draw (default: the shipped sample photo)",
    )
    p.add_argument(
        "--whole-body",
        action="store_true",
        help="a shipped whole-body subject: hands and face close up, body-only vs whole-body fit "
        "(--subject: a whole-body subject folder)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..demos.body import run_demo

    t0 = time.perf_counter()
    out = Path(args.out)
    if args.photo is not None:
        return _run_photo(args, out, t0)
    if args.whole_body:
        from ..demos.wholebody import run_wholebody_demo

        demo, label, first = run_wholebody_demo, "silfit demo --whole-body", "closeups.png"
    else:
        demo, label, first = run_demo, "silfit demo", "summary.png"
    report = demo(out, Path(args.subject) if args.subject else None, progress=not args.quiet)
    print(f"{label}: {report['subject']}\n")
    print(report["table"])
    for warning in report["warnings"]:
        warn(warning)
    print(f"\npictures and report in {out}/ (open {first} first); took {time.perf_counter() - t0:.0f} s")
    return 0


def _run_photo(args, out: Path, t0: float) -> int:
    from ..detect.demo import run_photo_demo

    report = run_photo_demo(out, Path(args.photo) if args.photo else None, progress=not args.quiet)
    print(f"silfit demo --photo: {report['photo']}\n")
    print(report["table"])
    for warning in report["warnings"]:
        warn(warning)
    print(f"\npictures and report in {out}/ (open summary.png first); took {time.perf_counter() - t0:.0f} s")
    return 0
