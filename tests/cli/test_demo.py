"""``silfit demo`` end to end, and the CLI's entry point."""
import json
import subprocess
import sys

import numpy as np
from PIL import Image

from silfit.cli import SUBCOMMANDS, main

DEMO_FILES = ("01_input.png", "02_mask.png", "03_keypoint_fit.png", "04_silhouette_fit.png",
              "05_silhouette_match.png", "06_iou_curve.png", "07_vertex_error.png", "summary.png",
              "report.md", "report.json", "fit/params.npz", "fit/mesh.obj", "fit/silhouette.png")  # fmt: skip


def test_help_lists_every_subcommand():
    out = subprocess.run([sys.executable, "-m", "silfit", "--help"], capture_output=True, text=True, check=True).stdout
    listed = [line.split()[0] for line in out.splitlines() if line.startswith("    ") and not line.startswith("     ")]
    assert sorted(listed) == sorted(SUBCOMMANDS), listed  # one entry per subcommand under COMMAND


def test_demo_writes_pictures_and_the_comparison_table(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "demo"), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "keypoints only" in printed and "PA-MPJPE" in printed and "silhouette IoU" in printed
    for name in DEMO_FILES:
        assert (tmp_path / "demo" / name).is_file(), name
    report = json.loads((tmp_path / "demo" / "report.json").read_text())
    before, after = report["keypoints_only"], report["keypoints_plus_silhouette"]
    assert after["iou"] > before["iou"] >= 0.5
    for name in ("01_input.png", "summary.png", "07_vertex_error.png"):
        img = np.asarray(Image.open(tmp_path / "demo" / name))
        assert img.ndim == 3 and img.std() > 5  # a real picture, not a blank canvas
