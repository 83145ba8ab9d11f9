"""Synthetic rigs: per-view data with one world-frame truth."""

import json

import numpy as np

from silfit.cli import main
from silfit.io.rig import load_rig, project_world


def test_synth_views_writes_consistent_per_view_data(tmp_path):
    out = tmp_path / "rigs"
    assert (
        main(
            [
                "synth",
                "--n",
                "2",
                "--cameras",
                "3",
                "--size",
                "64",
                "--seed",
                "3",
                "--noise-px",
                "0",
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    index = json.loads((out / "index.json").read_text())
    assert index["rig"] == 3 and len(index["subjects"]) == 2
    sub = out / "subject_000"
    views = load_rig(sub)
    gt = np.load(sub / "gt.npz")
    assert [v.name for v in views] == ["view_0", "view_1", "view_2"]
    assert all(v.mask is not None and v.image is not None for v in views)
    centres = []
    for c, v in enumerate(views):
        # the truth's world keypoints projected by each view's camera are that view's clean keypoints
        assert np.allclose(project_world(gt["keypoints_3d"], v.view), gt["keypoints_2d_clean"][c], atol=1e-3)
        kp = json.loads(v.keypoints.read_text())["people"][0]["pose_keypoints_2d"]
        xy = np.asarray(kp).reshape(25, 3)
        seen = gt["keypoints_visibility"][c] > 0
        assert np.allclose(xy[seen, :2], gt["keypoints_2d_clean"][c][seen], atol=1e-3)
        R, t = v.view.extrinsics()
        centres.append(-R.T @ t)
    centres = np.asarray(centres)
    assert np.linalg.norm(centres[:, [0, 2]], axis=1).min() > 1.0  # around the body, not at it
    assert np.ptp(centres[:, 1]) > 0.05  # at varied heights
    # the same cameras again from a layout file: same cameras, another body
    out2 = tmp_path / "fixed"
    assert (
        main(
            [
                "synth",
                "--n",
                "1",
                "--cameras-file",
                str(sub / "cameras.json"),
                "--seed",
                "9",
                "--out",
                str(out2),
                "--quiet",
            ]
        )
        == 0
    )
    again = load_rig(out2 / "subject_000")
    assert np.allclose(again[2].view.extrinsics()[0], views[2].view.extrinsics()[0])
    assert not np.allclose(np.load(out2 / "subject_000" / "gt.npz")["betas"], gt["betas"])
