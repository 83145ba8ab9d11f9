"""``silfit demo --whole-body`` writes its close-ups and a table in which the hands and face fit."""

import json

from silfit.demos.wholebody import METHODS, SHIPPED_WHOLEBODY, run_wholebody_demo
from silfit.fitting.silhouette_stage import SilhouetteFitConfig


def test_wholebody_demo(tmp_path):
    report = run_wholebody_demo(
        tmp_path,
        SHIPPED_WHOLEBODY / "subject_000",
        progress=False,
        silhouette_config=SilhouetteFitConfig(resolutions=(64,), iterations=(6,)),
    )
    for name in ("closeups.png", "summary.png", "report.md", "report.json", "fit/params.npz"):
        assert (tmp_path / name).is_file(), name
    s = json.loads((tmp_path / "report.json").read_text())["scores"]
    # the noise-free shipped subject: hand and face keypoints make the hands and face better than at rest
    assert s[METHODS[1]]["hand_pa_mm"] < s[METHODS[0]]["hand_pa_mm"] - 3.0
    assert s[METHODS[1]]["face_pa_mm"] < s[METHODS[0]]["face_pa_mm"]
    assert "| hand error, Procrustes (mm) |" in report["table"]


def test_summary_panels_keep_each_title_over_its_picture():
    import numpy as np

    from silfit.demos.wholebody import WHOLE_TITLES, summary_panels

    whole = [np.full((4, 4, 3), k, np.uint8) for k in range(3)]
    closeups = [np.full((4, 4, 3), 10 + k, np.uint8) for k in range(8)]
    titles = [f"close-up {k}" for k in range(8)]
    panels, names = summary_panels(whole, closeups, titles, columns=4)
    assert len(panels) == len(names) == 12
    assert names[:3] == list(WHOLE_TITLES) and panels[3] is None and names[3] == ""
    for picture, name in zip(panels[4:], names[4:]):  # the fourth panel on: each close-up under its own title
        assert name == f"close-up {int(picture[0, 0, 0]) - 10}"
