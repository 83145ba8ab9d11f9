"""The end-of-run summary of a dataset run: a Markdown table (``OUT/summary.md``) and a plot
(``OUT/summary.png``) from the result records."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

__all__ = ["summarise", "summary_table", "plot_summary"]


def _stats(values) -> Optional[dict]:
    v = np.array([x for x in values if x is not None and np.isfinite(x)], dtype=np.float64)
    if not len(v):
        return None
    return {
        "n": int(len(v)),
        "mean": float(v.mean()),
        "median": float(np.median(v)),
        "p90": float(np.percentile(v, 90)),
    }


def summarise(records: Sequence[dict], wall_s: Optional[float] = None, fitted_now: int = 0) -> dict:
    ok = [r for r in records if r.get("status") == "ok"]
    failed = [r for r in records if r.get("status") == "failed"]
    timing_keys = sorted({k for r in ok for k in r.get("timings_s", {})})
    out = {
        "items": len(records),
        "ok": len(ok),
        "failed": len(failed),
        "with_silhouette": sum(1 for r in ok if "silhouette" in r.get("stages", [])),
        "failed_by_stage": dict(Counter(r.get("stage", "?") for r in failed)),
        "reprojection_error_px": _stats(r.get("reprojection_error_px") for r in ok),
        "iou_keypoint_stage": _stats(r.get("iou_keypoint_stage") for r in ok),
        "iou": _stats(r.get("iou") for r in ok),
        "timings_s": {k: _stats(r.get("timings_s", {}).get(k) for r in ok) for k in timing_keys},
        "warnings": sum(len(r.get("warnings", [])) for r in ok),
    }
    if wall_s and fitted_now:
        out["this_run"] = {"items": fitted_now, "wall_s": wall_s, "items_per_hour": 3600.0 * fitted_now / wall_s}
    return out


def summary_table(s: dict) -> str:
    lines = ["| quantity | n | mean | median | p90 |", "|---|---:|---:|---:|---:|"]

    def row(label, st, fmt):
        if st:
            lines.append(
                f"| {label} | {st['n']} | {fmt.format(st['mean'])} | {fmt.format(st['median'])} | {fmt.format(st['p90'])} |"
            )

    row("reprojection error (px)", s["reprojection_error_px"], "{:.2f}")
    row("IoU after keypoint stage", s["iou_keypoint_stage"], "{:.3f}")
    row("IoU final", s["iou"], "{:.3f}")
    for k, st in s["timings_s"].items():
        row(f"time: {k} (s)", st, "{:.2f}")
    by_stage = ", ".join(f"{k}: {v}" for k, v in sorted(s["failed_by_stage"].items())) or "none"
    lines += [
        "",
        f"Items: {s['items']}, fitted: {s['ok']} ({s['with_silhouette']} with the silhouette stage), "
        f"failed: {s['failed']} (by stage: {by_stage}), warnings: {s['warnings']}.",
    ]
    if "this_run" in s:
        t = s["this_run"]
        lines.append(f"This run: {t['items']} items in {t['wall_s']:.1f} s ({t['items_per_hour']:.0f} items/hour).")
    return "\n".join(lines)


def plot_summary(records: Sequence[dict], path: os.PathLike) -> Path:
    """Histograms of the reprojection error, final IoU and time per item."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in records if r.get("status") == "ok"]
    panels = [
        ("reprojection error (px)", [r.get("reprojection_error_px") for r in ok]),
        ("final IoU (items with a mask)", [r.get("iou") for r in ok if "iou" in r]),
        ("time per item (s)", [r.get("timings_s", {}).get("total") for r in ok]),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(11, 3))
    for ax, (label, values) in zip(axes, panels):
        v = [x for x in values if x is not None and np.isfinite(x)]
        if v:
            ax.hist(v, bins=min(30, max(5, len(v) // 3)), color="tab:blue", alpha=0.8)
        else:
            ax.text(0.5, 0.5, "none", ha="center", va="center", transform=ax.transAxes)
        ax.set_xlabel(label, fontsize=8)
        ax.grid(alpha=0.3)
    failed = sum(1 for r in records if r.get("status") == "failed")
    fig.suptitle(f"{len(ok)} fitted, {failed} failed", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)
    return path
