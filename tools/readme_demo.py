"""Write the README's demo table from what ``silfit demo`` prints, so the numbers cannot go stale.

    python tools/readme_demo.py                    # run the demo (the shipped subject_000, ~20 s), rewrite README.md
    python tools/readme_demo.py --from silfit-demo # take an existing demo folder's report.json instead
    python tools/readme_demo.py --check            # exit 1 when the README's table is not the demo's

The table sits between the ``<!-- silfit-demo-table: begin ...-->`` and ``<!-- silfit-demo-table: end -->``
lines of README.md; ``tests/cli/test_demo.py`` compares it with the demo's own output in the suite.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's silfit, not another installed one

import silfit  # noqa: E402,F401  (before numpy and torch: the kernel pins, as on the command line)

BEGIN, END = "<!-- silfit-demo-table: begin", "<!-- silfit-demo-table: end -->"


def readme_block(text: str) -> str:
    """The table lines between the markers (the begin comment may span lines, ending with ``-->``)."""
    start = text.index(BEGIN)
    start = text.index("-->", start) + len("-->")
    return text[start : text.index(END, start)].strip()


def rewrite(text: str, table: str) -> str:
    start = text.index(BEGIN)
    start = text.index("-->", start) + len("-->")
    return text[:start] + "\n" + table.strip() + "\n" + text[text.index(END, start) :]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--from", dest="source", help="a `silfit demo` output folder (default: run the demo now)")
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 when they differ")
    parser.add_argument("--readme", default=str(ROOT / "README.md"))
    args = parser.parse_args(argv)
    from silfit.demos.body import report_table, run_demo

    if args.source:
        report = json.loads((Path(args.source) / "report.json").read_text())
    else:
        with tempfile.TemporaryDirectory() as tmp:
            report = run_demo(Path(tmp), progress=False)
    table = report_table(report)
    readme = Path(args.readme)
    text = readme.read_text()
    if args.check:
        strip_time = lambda t: "\n".join(l for l in t.splitlines() if not l.startswith("| time"))  # noqa: E731,E741
        same = strip_time(readme_block(text)) == strip_time(table)
        print("README demo table: " + ("the demo's" if same else "differs from the demo's:\n" + table))
        return 0 if same else 1
    readme.write_text(rewrite(text, table))
    print(f"{readme}: demo table written\n{table}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
