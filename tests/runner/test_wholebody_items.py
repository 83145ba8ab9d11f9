"""``silfit fit-dataset --model open-smplx`` on whole-body items: hands and face fitted, a body-only item at rest."""

import json
import shutil
from pathlib import Path

import numpy as np

from silfit.cli import main

from .helpers import FAST  # a short keypoint stage: plumbing, not accuracy

SHIPPED = Path(__file__).resolve().parents[2] / "data" / "synthetic_wholebody"


def test_fit_dataset_whole_body_items(tmp_path):
    data = tmp_path / "data"
    for name in ("subject_000", "subject_001"):
        shutil.copytree(SHIPPED / name, data / name)
    kp = json.loads((data / "subject_001" / "keypoints.json").read_text())
    for field in ("hand_left_keypoints_2d", "hand_right_keypoints_2d", "face_keypoints_2d"):
        kp["people"][0][field] = []
    (data / "subject_001" / "keypoints.json").write_text(json.dumps(kp))
    out = tmp_path / "out"
    assert (
        main(
            ["fit-dataset", str(data), "--out", str(out), "--model", "open-smplx", "--no-silhouette", "--quiet", *FAST]
        )
        == 0
    )
    full = json.loads((out / "subject_000" / "metrics.json").read_text())
    body = json.loads((out / "subject_001" / "metrics.json").read_text())
    assert full["layout"] == body["layout"] == "wholebody"
    assert full["whole_body"]["held_at_rest"] == [] and len(body["whole_body"]["held_at_rest"]) == 4
    p0, p1 = np.load(out / "subject_000" / "params.npz"), np.load(out / "subject_001" / "params.npz")
    assert np.abs(p0["left_hand_pose"]).max() > 0.05 and not p1["left_hand_pose"].any() and not p1["expression"].any()
