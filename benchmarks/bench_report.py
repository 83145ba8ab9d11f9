"""`silfit report` on a 100-item `fit-dataset` output, opened in headless Chromium.

Writes N synthetic subjects (``silfit synth``, small images, noisy and dropped keypoints so the
fits differ), fits them keypoint-only with ``silfit fit-dataset`` (which writes the report at the
end), times ``silfit report`` on the output again, then opens ``report/index.html`` in Debian's
``chromium`` (headless): ``--dump-dom`` checks that the page's script sorted all N cards worst
first, ``--screenshot`` writes the picture (``docs/report_100.png`` by default). Prints a table.

    .venv/bin/python benchmarks/bench_report.py [--n 100] [--seed 5] [--size 160] [--screenshot docs/report_100.png]
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FAST = [
    "--keypoint-option",
    "starts.poses=1",
    "--keypoint-option",
    "camera_iters=20",
    "--keypoint-option",
    "pose_iters=20,20,20",
    "--keypoint-option",
    "shape_iters=10",
    "--keypoint-option",
    "final_iters=20",
]


def chromium(*args) -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        sys.exit("bench_report: Debian's chromium is not installed (tools/setup.sh installs it)")
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=True).stdout


def main() -> int:
    from silfit.cli import main as silfit
    from silfit.runner.store import read_jsonl

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--size", type=int, default=160)
    ap.add_argument("--work", help="working folder (default: a temporary one, removed)")
    ap.add_argument("--screenshot", default=str(ROOT / "docs" / "report_100.png"))
    ap.add_argument("--window", default="1400,1000")
    args = ap.parse_args()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="bench_report."))
    rows = []
    try:
        t = time.perf_counter()
        assert (
            silfit(
                [
                    "synth",
                    "--n",
                    str(args.n),
                    "--seed",
                    str(args.seed),
                    "--size",
                    str(args.size),
                    "--noise-px",
                    "3",
                    "--drop",
                    "0.08",
                    "--truncation",
                    "0.1",
                    "--out",
                    str(work / "data"),
                    "--quiet",
                ]
            )
            == 0
        )
        rows.append(("silfit synth", f"{time.perf_counter() - t:.1f} s"))
        t = time.perf_counter()
        rc = silfit(
            [
                "fit-dataset",
                str(work / "data"),
                "--out",
                str(work / "fits"),
                "--no-silhouette",
                "--batch-size",
                "16",
                "--quiet",
                *FAST,
            ]
        )
        rows.append(
            (f"silfit fit-dataset (keypoints only, exit {rc}), report included", f"{time.perf_counter() - t:.1f} s")
        )
        t = time.perf_counter()
        assert silfit(["report", str(work / "fits")]) == 0
        rows.append(("silfit report (side views included)", f"{time.perf_counter() - t:.1f} s"))
        t = time.perf_counter()
        assert silfit(["report", str(work / "fits"), "--out", str(work / "plain"), "--no-side-views"]) == 0
        rows.append(("silfit report --no-side-views", f"{time.perf_counter() - t:.1f} s"))
        index = work / "fits" / "report" / "index.html"
        records = [r for r in read_jsonl(work / "fits" / "results.jsonl")]
        failed = [r["item"] for r in records if r["status"] != "ok"]
        ok = sorted((r for r in records if r["status"] == "ok"), key=lambda r: -r["reprojection_error_px"])
        t = time.perf_counter()
        dom = chromium("--dump-dom", index.as_uri())
        rows.append(("chromium --dump-dom", f"{time.perf_counter() - t:.1f} s"))
        order = re.findall(r'<div class="card[^"]*" id="card-\d+" data-item="([^"]*)"', dom)
        expected = [r["item"] for r in ok]
        sorted_ok = (
            len(order) == len(records) and set(order[: len(failed)]) == set(failed) and order[len(failed) :] == expected
        )
        rows.append(("cards in the page / sorted worst first by the page's script", f"{len(order)} / {sorted_ok}"))
        shot = Path(args.screenshot)
        shot.parent.mkdir(parents=True, exist_ok=True)
        t = time.perf_counter()
        chromium(f"--screenshot={shot.resolve()}", f"--window-size={args.window}", index.as_uri())
        rows.append((f"chromium --screenshot ({args.window} px) -> {shot}", f"{time.perf_counter() - t:.1f} s"))
        size = sum(p.stat().st_size for p in (work / "fits" / "report").rglob("*") if p.is_file())
        rows.append(("report size (index.html + side views)", f"{size / 1024:.0f} KiB"))
        rows.append(("items / fitted / failed", f"{len(records)} / {len(ok)} / {len(failed)}"))
        print(f"\n`benchmarks/bench_report.py --n {args.n} --seed {args.seed} --size {args.size}`\n")
        print("| step | result |\n|---|---:|")
        for name, value in rows:
            print(f"| {name} | {value} |")
        print(json.dumps({"sorted": sorted_ok}))
        return 0 if sorted_ok else 1
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
