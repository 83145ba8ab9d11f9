from silfit.detect.demo import SAMPLE_PHOTO, run_photo_demo
from silfit.fitting.silhouette_stage import SilhouetteFitConfig


def test_photo_demo_detects_fits_and_draws(tmp_path):
    assert SAMPLE_PHOTO.is_file()
    report = run_photo_demo(
        tmp_path, progress=False, silhouette_config=SilhouetteFitConfig(resolutions=(64,), iterations=(10,))
    )
    for f in (
        "summary.png",
        "report.md",
        "detection/keypoints.json",
        "detection/mask.png",
        "fit/params.npz",
        "fit/silhouette.png",
        "fit/side.png",
        "fit/metrics.json",
    ):
        assert (tmp_path / f).is_file(), f
    assert "| lower body visible | no |" in report["table"]
    assert any("lower body not visible" in w for w in report["warnings"])
