"""``silfit eval --run``: both methods fitted over a dataset, then scored."""

from silfit.eval.evaluate import evaluate_dataset


def test_run_fits_both_methods_and_scores_them(eval_dataset, tmp_path, open_model):
    fits = tmp_path / "fits"
    report = evaluate_dataset(eval_dataset, fits=fits, model=open_model, run=True, methods=("keypoints", "silhouette"))
    assert report["methods"] == ["keypoints", "silhouette"] and not report["skipped"]
    summary = report["summary"]
    assert summary["keypoints"]["iou"]["n"] == summary["silhouette"]["iou"]["n"] == 2
    print(
        f"IoU keypoints {summary['keypoints']['iou']['mean']:.3f} -> silhouette {summary['silhouette']['iou']['mean']:.3f}"
    )
    assert summary["silhouette"]["iou"]["mean"] > summary["keypoints"]["iou"]["mean"]
    for subject in (p.name for p in eval_dataset.iterdir() if p.is_dir()):
        for method, files in (
            ("keypoints", ("params.npz", "metrics.json")),
            ("silhouette", ("params.npz", "metrics.json", "mesh.obj", "silhouette.png")),
        ):
            for f in files:
                assert (fits / subject / method / f).is_file(), (subject, method, f)
    assert not [p for p in fits.rglob(".keypoints.*")]  # no temporary folder left behind
