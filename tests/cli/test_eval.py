"""``silfit eval`` from the command line."""

import json

import numpy as np
import pytest

from silfit.cli import main


@pytest.fixture
def small(tmp_path, open_model):
    from silfit.synth.generate import SynthConfig, generate_dataset

    data = tmp_path / "data"
    generate_dataset(data, 2, SynthConfig(seed=8, size=96, noise_px=0.0), model=open_model)
    for name in ("subject_000", "subject_001"):
        with np.load(data / name / "gt.npz") as gt:
            params = {k: gt[k] for k in ("betas", "body_pose", "global_orient", "transl")}
        d = data / "fits" / name / "keypoints"
        d.mkdir(parents=True)
        np.savez(d / "params.npz", **params)
    return data


def test_eval_scores_existing_fits(small, tmp_path, capsys):
    report_path = tmp_path / "out" / "report.json"
    assert main(["eval", str(small), "--report", str(report_path)]) == 0
    out = capsys.readouterr().out
    assert "| MPJPE (mm) |" in out and "keypoints mean" in out
    report = json.loads(report_path.read_text())
    assert report["num_scored"] == 2 and report["skipped"] == []
    assert (tmp_path / "out" / "report_errors.png").is_file()


def test_eval_reports_a_broken_subject_and_scores_the_rest(small, tmp_path, capsys):
    (small / "subject_001" / "camera.json").write_text('{"fx": 100, "fy": 100, "cx": 47.5, "cy": 47.5, "width": 96}')
    report_path = tmp_path / "report.json"
    assert main(["eval", str(small), "--report", str(report_path), "--no-iou"]) == 0
    out = capsys.readouterr().out
    assert "skipped subject_001" in out and "subject_001/camera.json" in out and "height" in out
    report = json.loads(report_path.read_text())
    assert [r["subject"] for r in report["results"]] == ["subject_000"]
    assert report["skipped"][0]["subject"] == "subject_001"


def test_eval_of_a_missing_folder_is_a_one_line_error(tmp_path, capsys):
    assert main(["eval", str(tmp_path / "nope"), "--report", str(tmp_path / "r.json")]) == 2
    assert "dataset folder not found" in capsys.readouterr().err
