"""``silfit report DIR``: a static HTML gallery of the fits in DIR (see :mod:`silfit.outputs.report`)."""

from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "report",
        help="a static HTML gallery of many fits (DIR/report/index.html; opens from disk, sortable)",
        description="DIR: a `silfit fit-dataset` output, a folder of `silfit fit` outputs, or one fit. Writes "
        "index.html (one card per fit: overlay, side view, IoU, reprojection error, warnings; failed "
        "items too), sortable by any metric in the page, worst first; no server, nothing fetched.",
    )
    p.add_argument("dir", help="the fits' folder")
    p.add_argument("--out", help="report folder (default DIR/report)")
    p.add_argument("--no-side-views", action="store_true", help="skip the side views (faster for thousands of fits)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..outputs.report import write_report

    index = write_report(args.dir, args.out, side_views=not args.no_side_views)
    print(f"wrote {index} (open it in a browser)")
    return 0
