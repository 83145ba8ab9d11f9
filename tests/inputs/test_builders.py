"""The input builders (silfit.inputs): what each makes of plain values and what it refuses; every caller (the
command line, the dataset worker, the evaluator) ends by calling them."""

import ast
from pathlib import Path

import numpy as np
import pytest

from silfit.camera import Camera
from silfit.fitting.problem import Observation, Problem, View
from silfit.inputs import Job, image_job, item_job, rig_job, rig_video_job, video_job
from silfit.io.keypoints import KeypointSet

ROOT = Path(__file__).resolve().parents[2]
CAM = Camera.from_image_size(64, 48)


def _kp(shift: float = 0.0) -> KeypointSet:
    return KeypointSet(np.full((25, 2), 20.0 + shift), np.ones(25), "body25")


def test_the_old_homes_give_the_same_objects():
    import silfit.run

    assert silfit.run.Job is Job and silfit.run.image_job is image_job and silfit.run.video_job is video_job


def test_image_job_from_keypoints_mask_and_camera():
    mask = np.zeros((48, 64), np.uint8)
    mask[10:30, 20:40] = 1
    known = np.ones((48, 64), bool)
    image = np.zeros((48, 64, 3), np.uint8)
    job = image_job(
        _kp(),
        mask,
        CAM,
        image=image,
        known=known,
        silhouette=False,
        warnings=("w",),
        record={"a": 1},
        mask_source="m.png",
        detected_person="p",
    )
    (o,) = job.problem.observations
    assert o.view.camera is CAM and o.mask.dtype == bool and o.mask.sum() == 400 and o.known is known
    assert job.mode == "image" and job.silhouette is False and job.progress is False and job.warnings == ["w"]
    assert job.record == {"a": 1} and job.images[(0, 0)] is image and job.mask_sources == {(0, 0): "m.png"}
    assert job.people == {(0, 0): "p"}
    plain = image_job(_kp(), camera=CAM)  # the defaults: nothing but the observation
    assert plain.images == {} and plain.mask_sources == {} and plain.people == {} and plain.record == {}
    assert plain.silhouette is True and plain.problem.observations[0].known is None


def test_image_job_derives_the_camera_and_applies_the_focal_length():
    arr = np.concatenate([_kp().xy, np.ones((25, 1))], axis=1)  # a [K, 3] array: its layout from its size
    job = image_job(arr, np.zeros((48, 64), bool))  # the mask's size
    assert job.layout == "body25" and job.problem.observations[0].view.camera.size == (64, 48)
    cam = image_job(_kp(), image_size=(300, 200), focal=500.0).problem.observations[0].view.camera
    assert (cam.width, cam.height, cam.fx, cam.fy) == (300, 200, 500.0, 500.0)
    cam = image_job(_kp(), camera=CAM, focal=90.0).problem.observations[0].view.camera
    assert (cam.fx, cam.fy, cam.width) == (90.0, 90.0, 64)


def test_image_job_refuses_no_camera_and_several_people():
    with pytest.raises(ValueError, match="no camera"):
        image_job(_kp())
    with pytest.raises(ValueError, match="one person's keypoints, got 2"):
        image_job([_kp(), _kp(1)], camera=CAM)


def test_video_job_one_observation_per_frame():
    masks = [np.ones((48, 64), bool), None]
    job = video_job([_kp(), None], CAM, masks=masks, numbers=(7, 9), warnings=["w"], silhouette=False)
    grid = job.problem.grid()
    assert job.mode == "video" and job.frame_numbers == [7, 9] and job.silhouette is False and job.video
    assert grid[1][0].keypoints is None and grid[0][0].mask is masks[0] and grid[0][0].view is grid[1][0].view
    assert video_job([_kp()], CAM).mode == "video"  # one frame stays a video


def test_video_job_refuses_no_frames_and_lists_of_another_length():
    with pytest.raises(ValueError, match="without frames"):
        video_job([], CAM)
    with pytest.raises(ValueError, match="1 masks for 2 frames"):
        video_job([_kp(), _kp()], CAM, masks=[None])
    with pytest.raises(ValueError, match="3 numbers for 2 frames"):
        video_job([_kp(), _kp()], CAM, numbers=[1, 2, 3])


def _views(n: int) -> list:
    return [View(CAM, np.eye(3), np.array([0.1 * c, 0.0, 0.0])) for c in range(n)]


def test_rig_job_from_a_problem():
    problem = Problem([Observation(v, _kp(c), None, 0, c) for c, v in enumerate(_views(2))])
    image = np.zeros((48, 64, 3), np.uint8)
    job = rig_job(problem, ("a", "b"), images={(0, 1): image}, record={"subject": "s"}, silhouette=False)
    assert job.mode == "rig" and job.rig and job.view_names == ["a", "b"] and job.images == {(0, 1): image}
    assert job.problem is problem and job.record == {"subject": "s"} and job.silhouette is False
    one = rig_job(Problem([problem.observations[0]]), ["a"])
    assert one.mode == "rig"  # a rig of one view left is still a rig (its world frame)


def test_rig_job_refuses_names_not_one_per_view_and_several_frames():
    views = _views(2)
    problem = Problem([Observation(v, _kp(), None, 0, c) for c, v in enumerate(views)])
    with pytest.raises(ValueError, match="1 view_names for 2 views"):
        rig_job(problem, ["a"])
    frames = Problem([Observation(views[0], _kp(), None, f, 0) for f in range(2)])
    with pytest.raises(ValueError, match="use rig_video_job"):
        rig_job(frames, ["a"])


def test_rig_video_job_frames_by_views():
    views = _views(2)
    masks = [[None, np.ones((48, 64), bool)], [None, None]]
    job = rig_video_job([[_kp(), None], [_kp(), _kp()]], views, ["a", "b"], masks=masks, numbers=[3, 4])
    grid = job.problem.grid()
    assert (
        job.mode == "video" and job.rig and job.video and job.view_names == ["a", "b"] and job.frame_numbers == [3, 4]
    )
    assert grid[0][1].keypoints is None and grid[0][1].mask is masks[0][1] and grid[1][1].view is views[1]
    assert [(o.frame, o.view_index) for o in job.problem.observations] == [(0, 0), (0, 1), (1, 0), (1, 1)]


def test_rig_video_job_refuses_ragged_frames():
    views = _views(2)
    with pytest.raises(ValueError, match="without frames"):
        rig_video_job([], views, ["a", "b"])
    with pytest.raises(ValueError, match="1 keypoint sets in frame 1 for 2 views"):
        rig_video_job([[_kp(), _kp()], [_kp()]], views, ["a", "b"])
    with pytest.raises(ValueError, match="3 masks in frame 0 for 2 views"):
        rig_video_job([[_kp(), _kp()]], views, ["a", "b"], masks=[[None, None, None]])
    with pytest.raises(ValueError, match="2 masks for 1 frames"):
        rig_video_job([[_kp(), _kp()]], views, ["a", "b"], masks=[[None, None], [None, None]])
    with pytest.raises(ValueError, match="1 view_names for 2 views"):
        rig_video_job([[_kp(), _kp()]], views, ["a"])


def test_item_job_is_an_image_job_with_the_items_files():
    from silfit.runner.items import Item, LoadedItem

    mask = np.ones((48, 64), bool)
    li = LoadedItem(Item("k", "kp.json"), _kp(), 0, 1, CAM, mask, "m.png", None, ["seen"])
    job = item_job(li, "MODEL", focal=80.0, keypoint_config="K", silhouette=False)
    (o,) = job.problem.observations
    assert o.view.camera.fx == 80.0 and li.camera.fx != 80.0 and o.mask is mask and job.model == "MODEL"
    assert job.mask_sources == {(0, 0): "m.png"} and job.warnings == ["seen"] and job.warnings is not li.warnings
    assert job.keypoint_config == "K" and job.silhouette is False and job.progress is False and job.images == {}
    li.mask_file = None
    assert (
        item_job(li, None).mask_sources == {(0, 0): "mask"}
        and item_job(li, None).problem.observations[0].view.camera is CAM
    )


@pytest.mark.parametrize(
    "path", ["silfit/cli/jobs.py", "silfit/runner/worker.py", "silfit/eval/evaluate.py", "silfit/eval/score_rig.py"]
)
def test_the_callers_build_jobs_with_the_builders(path):
    """The command line, the dataset worker and the evaluator make no Job themselves (issue 57)."""
    tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
    calls = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "Job"]
    assert not calls, f"{path}: Job(...) at lines {calls}"


@pytest.mark.parametrize("first", ["silfit.inputs", "silfit.run"])
def test_inputs_and_run_import_in_either_order(first):
    import subprocess
    import sys

    other = {"silfit.inputs": "silfit.run", "silfit.run": "silfit.inputs"}[first]
    code = f"import {first}, {other}; assert {other}.__name__"
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True)


def test_the_rig_file_readers_moved_to_the_input_builders_and_answer_at_their_old_home():
    """The fitting core reads no file (issue 57): rig_problem and its readers live in silfit.inputs.rig; the old
    names in silfit.fitting.rig_fit work for one release, with a DeprecationWarning naming the new home."""
    import pytest
    import silfit.fitting.rig_fit as old
    import silfit.inputs.rig as new

    for name in ("rig_problem", "fit_keypoints_of", "has_wholebody_parts"):
        with pytest.warns(DeprecationWarning, match=f"silfit.inputs.rig.{name}"):
            assert getattr(old, name) is getattr(new, name)
    with pytest.raises(AttributeError):
        old.no_such_name
    import silfit.fitting.rig_pipeline as pipeline

    with pytest.warns(DeprecationWarning, match="silfit.inputs.rig.read_rig_sequence_masks"):
        assert pipeline.read_rig_sequence_masks is new.read_rig_sequence_masks
