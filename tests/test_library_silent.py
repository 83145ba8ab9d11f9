"""The library prints no progress bars unless asked (``progress=True``); the command line asks unless
``--quiet``."""

import inspect

import pytest
from silfit.fitting.keypoint_stage import BranchSearch, Starts


@pytest.mark.parametrize(
    "where, name",
    [
        ("silfit.run", "fit"),
        ("silfit.run", "image_job"),
        ("silfit.run", "video_job"),
        ("silfit.run", "fit_sequence"),
        ("silfit.run", "Job"),
        ("silfit.fitting.keypoint_stage", "fit_keypoints"),
        ("silfit.fitting.keypoint_stage", "KeypointFitter.fit"),
        ("silfit.fitting.silhouette_stage", "fit_silhouette"),
        ("silfit.fitting.image_fit", "refine"),
        ("silfit.fitting.image_fit", "refine_batch"),
        ("silfit.runner", "fit_dataset"),
        ("silfit.demos.body", "run_demo"),
    ],
)
def test_progress_is_off_by_default(where, name):
    import importlib

    obj = importlib.import_module(where)
    for part in name.split("."):
        obj = getattr(obj, part)
    assert inspect.signature(obj).parameters["progress"].default is False


def test_a_library_fit_prints_nothing(capsys):
    import silfit
    from silfit.fitting import KeypointFitConfig
    from silfit.io.keypoints import read_keypoints
    from silfit.camera import read_camera_file
    from pathlib import Path

    subject = Path(__file__).resolve().parents[1] / "data" / "synthetic" / "subject_000"
    camera, _, _ = read_camera_file(subject / "camera.json")
    config = KeypointFitConfig(
        pose_iters=(5, 5, 5),
        shape_iters=3,
        final_iters=5,
        starts=Starts(poses=1, flip=False),
        branches=BranchSearch(post_iters=0, search=False),
    )
    silfit.fit_keypoints(read_keypoints(subject / "keypoints.json"), camera, config=config)
    out = capsys.readouterr()
    assert out.out == "" and "it/s" not in out.err and "%|" not in out.err, out
