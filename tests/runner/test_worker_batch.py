"""The dataset worker refines a batch's masked items in one silhouette-stage call (issue 24), through the
one path (silfit.run.run_batch -> silfit.fitting.cores.run_steps on an image core)."""

import numpy as np
import pytest

from runner.helpers import SYNTHETIC, synthetic_copy
from silfit.runner import FitOptions
from silfit.runner.items import list_items
from silfit.fitting import cores
from silfit.runner.worker import DatasetFitter

KP_FAST = {
    "starts.poses": "1",
    "camera_iters": "10",
    "pose_iters": "10,10,10",
    "shape_iters": "5",
    "final_iters": "10",
    "branches.post_iters": "0",
}


def _fitter():
    return DatasetFitter(FitOptions(keypoint_options=KP_FAST, silhouette_resolutions=(48,), silhouette_iterations=(3,)))


def test_masked_items_are_refined_in_one_call(tmp_path, monkeypatch):
    data = synthetic_copy(tmp_path / "in", ["subject_000", "subject_001", "subject_002"])
    items = list_items(data)
    calls = []
    real = cores.refine_silhouettes

    def counting(model, hooks, *args, **kwargs):
        calls.append(len(hooks.masks))
        return real(model, hooks, *args, **kwargs)

    monkeypatch.setattr(cores, "refine_silhouettes", counting)
    records = _fitter().run_batch(items, tmp_path / "out")
    assert calls == [3]
    assert [r["status"] for r in records] == ["ok"] * 3
    for r in records:
        assert r["stages"] == ["keypoints", "silhouette"] and 0 < r["iou"] <= 1
        assert r["timings_s"]["silhouette"] > 0 and r["timings_s"]["keypoints"] > 0


def test_a_bad_mask_fails_alone(tmp_path):
    data = synthetic_copy(tmp_path / "in", ["subject_000", "subject_001"])
    from PIL import Image

    mask = np.zeros_like(np.asarray(Image.open(SYNTHETIC / "subject_001" / "mask.png")))
    mask[:2, :2] = 255  # a mask far from the person: the batch call refuses it, the other item still fits
    Image.fromarray(mask).save(data / "subject_001" / "mask.png")
    records = _fitter().run_batch(list_items(data), tmp_path / "out")
    assert records[0]["status"] == "ok" and records[0]["stages"] == ["keypoints", "silhouette"]
    assert records[1]["status"] == "failed" and records[1]["stage"] == "silhouette"


def test_keypoint_options_parse_by_the_field_and_optional_ones_take_none():
    from silfit.runner.worker import keypoint_config

    cfg = keypoint_config(
        {
            "final_tol_change": "none",
            "final_iters_unsearched": "None",
            "final_iters": "30",
            "pose_iters": "5,6,7",
            "branches.search": "false",
        }
    )
    assert cfg.final_tol_change is None and cfg.final_iters_unsearched is None
    assert cfg.final_iters == 30 and cfg.pose_iters == (5, 6, 7) and cfg.branches.search is False
    assert keypoint_config({"final_tol_change": "1e-3"}).final_tol_change == 1e-3
    with pytest.raises(ValueError, match="final_iters='none'"):
        keypoint_config({"final_iters": "none"})  # not optional


def test_silhouette_options_reach_the_workers_stage():
    """``FitOptions.silhouette_options`` (fit-dataset's ``--silhouette-option``): read by the field's type, beside the
    levels; an unknown one is a ValueError naming the silhouette stage."""
    from silfit.runner.worker import silhouette_config

    cfg = silhouette_config(
        FitOptions(
            silhouette_options={
                "alternatives_margin": "0",
                "mask.trim_clothing": "false",
                "render.edge_density": "none",
            },
            silhouette_iterations=(4, 5),
        )
    )
    assert cfg.alternatives_margin == 0.0 and cfg.mask.trim_clothing is False and cfg.render.edge_density is None
    assert cfg.iterations == (4, 5)
    with pytest.raises(ValueError, match="unknown silhouette-stage option 'nope'"):
        silhouette_config(FitOptions(silhouette_options={"nope": "1"}))
    with pytest.raises(ValueError, match="level_proxy_faces cannot be given on the command line"):
        silhouette_config(FitOptions(silhouette_options={"level_proxy_faces": ""}))  # a mapping: not dict("")


def test_keypoint_options_whose_default_is_none_parse_by_their_declared_type():
    """A field that defaults to None is read by its declared type (before: always as an integer, so a list of hand
    weights was refused); a video's base (final_tol_change None) does not change how a value is read."""
    from silfit.fitting.sequence import SequenceFitConfig
    from silfit.runner.worker import keypoint_config

    cfg = keypoint_config(
        {"hands_face.hand_weights": "0,0.5,1", "final_iters_unsearched": "30", "solutions.joint_max_m": "0.4"}
    )
    assert (
        cfg.hands_face.hand_weights == (0.0, 0.5, 1.0)
        and cfg.final_iters_unsearched == 30
        and cfg.solutions.joint_max_m == 0.4
    )
    video = keypoint_config({"final_tol_change": "1e-5"}, SequenceFitConfig().keypoint)
    assert video.final_tol_change == 1e-5 and video.branches.refine == SequenceFitConfig().keypoint.branches.refine
    assert keypoint_config({"hands_face.face_weights": "1,2,3"}).hands_face.face_weights == (1.0, 2.0, 3.0)
    assert keypoint_config({"hands_face.hand_weights": "none"}).hands_face.hand_weights is None
    with pytest.raises(ValueError, match="schedule cannot be given on the command line"):
        keypoint_config({"schedule": "x"})
    with pytest.raises(
        ValueError, match=r"hand_weights='a': expected comma-separated numbers \(e.g. 0,0.5,1\) or none"
    ):
        keypoint_config({"hands_face.hand_weights": "a"})


def test_an_interrupt_while_saving_stops_the_run_and_is_not_an_items_failure(tmp_path, monkeypatch):
    """A signal inside np.savez leaves a zip member open and closing it raises ValueError: that is the
    interrupt (the run stops), not an item that failed to save (recorded, and the run going on)."""
    import silfit.run as writer  # silfit.run.write calls the one writer, silfit.outputs.write's, by this name

    data = synthetic_copy(tmp_path / "in", ["subject_000"])

    def interrupted(*args, **kwargs):
        try:
            raise KeyboardInterrupt
        finally:
            raise ValueError("Can't close the ZIP file while there is an open writing handle on it.")

    monkeypatch.setattr(writer, "write_folder", interrupted)
    fitter = DatasetFitter(FitOptions(keypoint_options=KP_FAST, silhouette=False))
    with pytest.raises(ValueError) as caught:
        fitter.run_batch(list_items(data), tmp_path / "out")
    assert isinstance(caught.value.__context__, KeyboardInterrupt)

    from silfit.fitting.keypoint_stage import KeypointFitter

    monkeypatch.setattr(KeypointFitter, "fit", interrupted)  # in a stage: not a failure to isolate row by row
    with pytest.raises(ValueError) as caught:
        fitter.run_batch(list_items(data), tmp_path / "out1")
    assert isinstance(caught.value.__context__, KeyboardInterrupt)
    monkeypatch.undo()

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(writer, "write_folder", full)  # (after undo: the real fit again)
    records = fitter.run_batch(list_items(data), tmp_path / "out2")
    assert records[0]["status"] == "failed" and records[0]["stage"] == "save"
