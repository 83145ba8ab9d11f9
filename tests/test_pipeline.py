"""The whole fit (keypoints, then silhouette) on shipped synthetic subjects."""
from pathlib import Path

import numpy as np
import pytest

from silfit.dataset import load_subject
from silfit.run import fit

SHIPPED = Path(__file__).resolve().parents[1] / "data" / "synthetic"


@pytest.fixture(scope="module")
def subject():
    s = load_subject(SHIPPED / "subject_000")
    assert s.gt.extras["noise_px"] == 0.0  # the noise-free subject the issue asks for
    return s


def test_silhouette_stage_raises_iou_on_a_noise_free_subject(open_model, subject):
    result = fit(subject.keypoints, subject.mask, subject.camera, model=open_model, progress=False)
    m = result.metrics
    print(f"IoU keypoint stage {m['iou_keypoint_stage']:.3f} -> silhouette stage {m['iou']:.3f}")
    assert m["iou"] > m["iou_keypoint_stage"]
    assert m["iou"] >= 0.9
    assert m["reprojection_error_px"] < 2.0  # the keypoints still hold
    assert result.vertices.shape == (open_model.num_vertices, 3) and not m["warnings"]


def test_keypoints_only_when_no_mask(open_model, subject):
    result = fit(subject.keypoints, camera=subject.camera, model=open_model, progress=False)
    assert result.silhouette is None and result.metrics["stages"] == ["keypoints"]
    assert np.allclose(result.params["body_pose"], result.keypoint.body_pose[0])


def test_mask_that_misses_the_body_is_an_error(open_model, subject):
    far = np.zeros_like(subject.mask)
    far[:10, :10] = True  # a corner far from the person
    with pytest.raises(ValueError, match="does not overlap"):
        fit(subject.keypoints, far, subject.camera, model=open_model, progress=False)


def test_mask_of_another_size_is_an_error(open_model, subject):
    with pytest.raises(ValueError, match="256x128.*256x256"):
        fit(subject.keypoints, subject.mask[:128], subject.camera, model=open_model, progress=False)


def test_save_fit_leaves_nothing_when_a_write_fails(open_model, subject, tmp_path, monkeypatch):
    from silfit import figures
    from silfit.fitting import KeypointFitConfig
    from silfit.pipeline import save_fit

    cfg = KeypointFitConfig(camera_iters=5, pose_iters=(5, 5, 5), shape_iters=0, final_iters=0, branch_search=False)
    result = fit(subject.keypoints, camera=subject.camera, model=open_model, keypoint_config=cfg, progress=False)
    faces = open_model.faces.numpy()
    old = tmp_path / "old"
    save_fit(result, old, faces, subject.keypoints)
    before = sorted(p.relative_to(old) for p in old.rglob("*"))

    def broken(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(figures, "write_png", broken)  # fails after params.npz and mesh.obj are written
    with pytest.raises(RuntimeError, match="disk full"):
        save_fit(result, tmp_path / "new", faces, subject.keypoints)
    with pytest.raises(RuntimeError, match="disk full"):
        save_fit(result, old, faces, subject.keypoints, overwrite=True)
    assert not (tmp_path / "new").exists()
    assert sorted(p.relative_to(old) for p in old.rglob("*")) == before  # the earlier output is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old"]  # no temporary folders left
