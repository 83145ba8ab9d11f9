"""Scoring fits over a dataset."""

import numpy as np
import pytest

from silfit.eval.evaluate import evaluate_dataset, markdown_table, plot_errors, read_fit
from silfit.io.subjects import SubjectError


def test_perfect_and_shifted_fits(dataset_with_fits, open_model):
    data, fits = dataset_with_fits
    report = evaluate_dataset(data, fits, model=open_model)
    assert report["methods"] == ["keypoints", "silhouette"] and not report["skipped"]
    rows = {(r["subject"], r["method"]): r for r in report["results"]}
    assert len(rows) == 4
    for (subject, method), r in rows.items():
        for k in ("mpjpe", "pa_mpjpe", "pve", "shape_pve"):
            assert r[k] < 1e-2, (subject, method, k)  # mm
        assert r["time_s"] == pytest.approx(2.0) and r["time_pose"] == pytest.approx(1.5)
        if method == "keypoints":
            assert r["transl_err"] < 1e-2 and r["reproj_px"] < 1e-2 and r["iou"] == pytest.approx(1.0)
        else:
            assert r["transl_err"] == pytest.approx(100.0, abs=1e-2)  # 10 cm
            assert r["reproj_px"] > 0.5 and 0.5 < r["iou"] < 1.0
    s = report["summary"]["silhouette"]["transl_err"]
    assert s["mean"] == pytest.approx(100.0, abs=1e-2) and s["n"] == 2
    table = markdown_table(report)
    assert "| MPJPE (mm) |" in table and "keypoints mean" in table and "silhouette median" in table
    png = plot_errors(report, data.parent / "plot.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_malformed_subject_is_skipped_and_named(dataset_with_fits, open_model):
    data, fits = dataset_with_fits
    with np.load(data / "subject_001" / "gt.npz") as gt:
        broken = {k: gt[k] for k in gt.files if k != "body_pose"}
    np.savez(data / "subject_001" / "gt.npz", **broken)
    (fits / "subject_000" / "silhouette" / "params.npz").write_bytes(b"junk")
    report = evaluate_dataset(data, fits, model=open_model, iou=False)
    assert {(r["subject"], r["method"]) for r in report["results"]} == {("subject_000", "keypoints")}
    by = {(s["subject"], s.get("method")): s for s in report["skipped"]}
    gt_err = by[("subject_001", None)]
    assert gt_err["field"] == "body_pose" and gt_err["file"].endswith("subject_001/gt.npz")
    assert "subject_001/gt.npz" in gt_err["error"] and "body_pose" in gt_err["error"]
    fit_err = by[("subject_000", "silhouette")]
    assert fit_err["file"].endswith("silhouette/params.npz")


def test_missing_fits_are_listed(dataset_with_fits, open_model):
    data, fits = dataset_with_fits
    import shutil

    shutil.rmtree(fits / "subject_001")
    report = evaluate_dataset(data, fits, model=open_model, iou=False)
    assert report["missing_fits"] == ["subject_001"]
    assert report["num_scored"] == 1


def test_read_fit_validates_fields(tmp_path):
    np.savez(
        tmp_path / "params.npz",
        betas=np.zeros(10),
        body_pose=np.zeros(72),
        global_orient=np.zeros(3),
        transl=np.zeros(3),
    )
    with pytest.raises(SubjectError) as info:
        read_fit(tmp_path)
    assert info.value.field == "body_pose" and "params.npz" in str(info.value)
    np.savez(
        tmp_path / "params.npz",
        betas=np.zeros((1, 10)),
        body_pose=np.zeros((1, 69)),
        global_orient=np.zeros(3),
        transl=np.zeros(3),
        camera_intrinsics=np.array([100.0, 100, 50, 50]),
        image_size=np.array([101, 101]),
    )
    fit = read_fit(tmp_path)
    assert fit.betas.shape == (10,) and fit.camera.width == 101 and fit.timings == {}


def test_read_fit_takes_silfit_fits_stage_seconds(tmp_path):
    """``silfit fit`` records its stages in metrics.json's ``timings_s`` (keypoint stage parts as
    ``keypoints.<stage>``): eval reads the whole stages, the silhouette stage included."""
    import json

    np.savez(
        tmp_path / "params.npz",
        betas=np.zeros(10),
        body_pose=np.zeros(69),
        global_orient=np.zeros(3),
        transl=np.zeros(3),
    )
    (tmp_path / "params.json").write_text(json.dumps({"timings": {"final": 1.0}}))
    (tmp_path / "metrics.json").write_text(
        json.dumps({"timings_s": {"keypoints.camera": 0.5, "keypoints": 2.0, "silhouette": 6.0}})
    )
    assert read_fit(tmp_path).timings == {"keypoints": 2.0, "silhouette": 6.0}
