"""``silfit fit --rig`` and ``silfit eval`` on a rig dataset, end to end on tiny images."""
import json

import numpy as np
import pytest

from silfit.cli import main

SIL = ["--silhouette-resolutions", "32", "--silhouette-iterations", "3"]


@pytest.fixture(scope="module")
def rigs(tmp_path_factory):
    out = tmp_path_factory.mktemp("rigs") / "data"
    assert main(["synth", "--n", "1", "--views", "2", "--size", "96", "--seed", "4", "--noise-px", "0", "--out", str(out),
                 "--no-progress"]) == 0  # fmt: skip
    return out


def test_fit_rig_writes_world_outputs_and_per_view_overlays(rigs, tmp_path):
    out = tmp_path / "fit"
    assert main(["fit", "--rig", str(rigs / "subject_000"), "--out", str(out), "--quiet"] + SIL) == 0
    for f in ("params.npz", "params.json", "mesh.obj", "cameras.json", "metrics.json", "stages/keypoints/params.npz",
              "views/view_0/overlay.png", "views/view_1/overlay.png", "views/view_1/silhouette.png"):  # fmt: skip
        assert (out / f).is_file(), f
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["views"]) == {"view_0", "view_1"}
    for v in m["views"].values():
        assert v["reprojection_error_px"] < 3.0 and 0.5 < v["iou"] <= 1.0 and "iou_keypoint_stage" in v
    assert m["timings"]["silhouette"] > 0
    p = np.load(out / "params.npz")
    assert str(p["frame"]) == "world"
    gt = np.load(rigs / "subject_000" / "gt.npz")
    assert np.linalg.norm(p["joints"][0] - gt["joints"][0]) < 0.1  # the pelvis, in world coordinates
    # the rig's cameras come back out, readable as a rig manifest
    from silfit.rig import read_cameras_json

    assert [v.name for v in read_cameras_json(out / "cameras.json")] == ["view_0", "view_1"]


def test_fit_rig_keypoints_only_and_check_only(rigs, tmp_path, capsys):
    assert main(["fit", "--rig", str(rigs / "subject_000"), "--check-only", "--out", str(tmp_path / "x")]) == 0
    assert "inputs OK (2 views)" in capsys.readouterr().out and not (tmp_path / "x").exists()
    out = tmp_path / "kp"
    assert main(["fit", "--rig", str(rigs / "subject_000"), "--no-silhouette", "--out", str(out), "--quiet"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert "iou" not in m["views"]["view_0"] and m["views"]["view_0"]["iou_keypoint_stage"] > 0.5
    assert not (out / "stages").exists()
    rc = main(["fit", "--rig", str(rigs / "subject_000"), "--keypoints", "kp.json", "--out", str(tmp_path / "y")])
    assert rc == 2


def test_eval_scores_a_rig_dataset(rigs, tmp_path, capsys):
    report = tmp_path / "report.json"
    assert main(["eval", str(rigs), "--run", "--methods", "keypoints", "--out", str(report), "--quiet"]) == 0
    assert "PVE, world frame" in capsys.readouterr().out
    r = json.loads(report.read_text())
    row = r["results"][0]
    assert row["method"] == "keypoints" and len(row["iou_views"]) == 2
    assert row["pve_world"] < 60.0 and row["pa_pve"] <= row["pve_world"] + 1e-6
