"""``silfit demo --whole-body`` writes its close-ups and a table in which the hands and face fit."""
import json

from silfit.demo_wholebody import METHODS, SHIPPED_WHOLEBODY, run_wholebody_demo
from silfit.fitting.silhouette_stage import SilhouetteFitConfig


def test_wholebody_demo(tmp_path):
    report = run_wholebody_demo(tmp_path, SHIPPED_WHOLEBODY / "subject_000", progress=False,
                                silhouette_config=SilhouetteFitConfig(resolutions=(64,), iterations=(6,)))  # fmt: skip
    for name in ("closeups.png", "summary.png", "report.md", "report.json", "fit/params.npz"):
        assert (tmp_path / name).is_file(), name
    s = json.loads((tmp_path / "report.json").read_text())["scores"]
    # the noise-free shipped subject: hand and face keypoints make the hands and face better than at rest
    assert s[METHODS[1]]["hand_pa_mm"] < s[METHODS[0]]["hand_pa_mm"] - 3.0
    assert s[METHODS[1]]["face_pa_mm"] < s[METHODS[0]]["face_pa_mm"]
    assert "| hand error, Procrustes (mm) |" in report["table"]
