"""The one path (silfit.run): the checks every job gets, run_batch's batching and isolation,
the one result type's shapes for an image, a rig and a video."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from silfit.io.subjects import load_subject
from silfit.errors import InputError
from silfit.fitting import KeypointFitConfig
from silfit.fitting.problem import Observation, Problem, View
from silfit.fitting.silhouette_stage import SilhouetteFitConfig
from silfit.io.keypoints import KeypointSet
from silfit.run import Job, StageFailure, check, image_job, keypoint_stage_fit, run, run_batch, video_job, write
from silfit.fitting.keypoint_stage import BranchSearch

SHIPPED = Path(__file__).resolve().parents[1] / "data" / "synthetic"
FAST = KeypointFitConfig(
    camera_iters=5, pose_iters=(5, 5, 5), shape_iters=0, final_iters=0, branches=BranchSearch(search=False)
)


@pytest.fixture(scope="module")
def subject():
    return load_subject(SHIPPED / "subject_000")


def _far(ks: KeypointSet, index: int) -> KeypointSet:
    xy = ks.xy.copy()
    xy[index] = [1e6, 1e6]
    return KeypointSet(xy, ks.conf.copy(), ks.layout, ks.source)


def _unusable(ks: KeypointSet) -> KeypointSet:
    return KeypointSet(np.full_like(ks.xy, 1e30), ks.conf.copy(), ks.layout, ks.source)


def test_check_drops_far_points_of_an_image_and_refuses_an_unusable_one(subject):
    job = check(image_job(_far(subject.keypoints, 4), camera=subject.camera))
    assert job.problem.observations[0].keypoints.conf[4] == 0 and any("outside" in w for w in job.warnings)
    with pytest.raises(InputError):
        check(image_job(_unusable(subject.keypoints), camera=subject.camera))


def test_check_sets_a_rig_view_aside_and_a_video_frame_becomes_undetected(subject):
    ks, cam = subject.keypoints, subject.camera
    rig = Job(
        Problem([Observation(View(cam), ks, None, 0, 0), Observation(View(cam), _unusable(ks), None, 0, 1)]),
        view_names=["a", "b"],
        rig=True,
    )
    checked = check(rig)
    assert list(checked.view_names) == ["a"] and checked.num_views == 1 and checked.mode == "rig"
    assert any(w.startswith("view b set aside") for w in checked.warnings)
    video = Job(
        Problem([Observation(View(cam), k, None, f) for f, k in enumerate([ks, _unusable(ks), ks])]),
        frame_numbers=[10, 11, 12],
    )
    checked = check(video)
    assert checked.mode == "video" and checked.problem.grid()[1][0].keypoints is None
    assert any("11" in w and "unusable" in w for w in checked.warnings)


def test_run_batch_isolates_a_failing_silhouette_stage(open_model, subject):
    far = np.zeros_like(subject.mask)
    far[:10, :10] = True  # a mask far from the person: the silhouette stage refuses it
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig

    sil = SilhouetteFitConfig(resolutions=(32,), iterations=(2,))
    jobs = [
        image_job(
            subject.keypoints,
            mask,
            subject.camera,
            model=open_model,
            keypoint_config=FAST,
            silhouette_config=sil,
            progress=False,
        )
        for mask in (far, None)
    ]
    bad, good = run_batch(jobs, isolate=True)
    assert isinstance(bad, StageFailure) and bad.stage == "silhouette" and "does not overlap" in str(bad)
    assert bad.partial is not None and bad.partial.silhouette is None  # the keypoint stage's fit is kept
    assert good.vertices.shape == (1, open_model.num_vertices, 3) and good.keypoints_2d.shape[:2] == (1, 1)
    # the same image alone: the batch changed nothing (rows are independent)
    alone = run(
        image_job(subject.keypoints, None, subject.camera, model=open_model, keypoint_config=FAST, progress=False)
    )
    assert np.allclose(alone.params["body_pose"], good.params["body_pose"], atol=1e-5)
    with pytest.raises(ValueError, match="does not overlap"):
        run_batch(jobs[:1])


def test_run_gives_one_result_type_for_a_video(open_model, subject):
    from silfit.fitting.sequence import SequenceFitConfig

    ks, cam = subject.keypoints, subject.camera
    cfg = SequenceFitConfig(keypoint=FAST, iterations=3, neighbour_starts=False)
    job = Job(
        Problem([Observation(View(cam), k, None, f) for f, k in enumerate([ks, None, ks])]),
        open_model,
        sequence_config=cfg,
        progress=False,
    )
    fit = run(job)
    assert fit.vertices.shape == (3, open_model.num_vertices, 3) and fit.reprojection_error.shape == (3, 1)
    assert fit.params["betas"].ndim == 1 and fit.params["body_pose"].shape == (3, 69)
    assert np.isnan(fit.reprojection_error[1, 0]) and any("bridged" in w for w in fit.warnings)


def test_a_one_frame_video_stays_a_video(open_model, subject):
    """A video of one frame (or a rig video of one frame) is fitted and written as a video, not as one image."""
    from silfit.fitting.sequence import SequenceFitConfig, SequenceFitResult

    ks, cam = subject.keypoints, subject.camera
    job = video_job(
        [ks],
        cam,
        open_model,
        config=SequenceFitConfig(keypoint=FAST, iterations=3, neighbour_starts=False),
        progress=False,
        numbers=[7],
    )
    assert job.mode == "video" and check(job).mode == "video"
    fit = run(job)
    assert isinstance(fit.stage, SequenceFitResult) and fit.params["body_pose"].shape == (1, 69)


def test_the_public_fit_sequence_goes_through_run(open_model, subject):
    """``silfit.fit_sequence`` is run on a video job: the sequence core's result, the same fit as the core alone on
    frames the checks leave as they are; a frame whose keypoints the checks refuse is bridged."""
    import silfit
    from silfit.fitting import sequence
    from silfit.fitting.sequence import SequenceFitConfig, SequenceFitResult

    ks, cam = subject.keypoints, subject.camera
    cfg = SequenceFitConfig(keypoint=FAST, iterations=3, neighbour_starts=False)
    fit = silfit.fit_sequence([ks, ks, ks], cam, open_model, config=cfg)
    core = sequence.fit_sequence([ks, ks, ks], cam, open_model, config=cfg)
    assert isinstance(fit, SequenceFitResult)
    assert all(np.array_equal(v, core.params()[n]) for n, v in fit.params().items())
    refused = silfit.fit_sequence([ks, _unusable(ks), ks], cam, open_model, config=cfg)
    assert refused.bridged.tolist() == [False, True, False]


def test_check_reindexes_a_rig_videos_pictures_when_a_view_is_set_aside(subject):
    ks, cam = subject.keypoints, subject.camera
    obs = [Observation(View(cam), k, None, f, c) for f in range(2) for c, k in enumerate([_unusable(ks), ks])]
    pics = {(f, c): np.full((2, 2, 3), 10 * f + c, np.uint8) for f in range(2) for c in range(2)}
    job = Job(
        Problem(obs),
        view_names=["a", "b"],
        rig=True,
        images=pics,
        mask_sources={(f, c): f"m{f}{c}" for f in range(2) for c in range(2)},
    )
    checked = check(job)
    assert list(checked.view_names) == ["b"] and sorted(checked.images) == [(0, 0), (1, 0)]
    assert checked.images[(1, 0)][0, 0, 0] == 11 and checked.mask_sources == {(0, 0): "m01", (1, 0): "m11"}


def test_the_old_home_of_fit_still_gives_it():
    import silfit.pipeline
    import silfit.run
    from silfit.pipeline import fit

    assert fit is silfit.run.fit is silfit.pipeline.fit


def test_batches_with_the_same_settings_share_one_keypoint_fitter(open_model):
    """fit-dataset's batches reuse the keypoint fitter (settings compared by value); other
    settings, or the same settings object changed in place, get a fitter of their own."""
    from dataclasses import replace

    from silfit.fitting.image_fit import _keypoint_fitter

    cfg = replace(FAST)
    first = _keypoint_fitter(open_model, "body25", cfg, None)
    assert _keypoint_fitter(open_model, "body25", replace(FAST), None) is first
    cfg.final_iters = 3  # changed in place: not the fitter built for the old values
    again = _keypoint_fitter(open_model, "body25", cfg, None)
    assert again is not first and again.config.final_iters == 3


def test_write_adds_metrics_fields_and_draws_on_the_images_given(open_model, subject, tmp_path):
    import json

    fit = run(image_job(subject.keypoints, None, subject.camera, model=open_model, keypoint_config=FAST))
    write(fit, tmp_path / "plain")
    write(fit, tmp_path / "more", extra={"note": "x", "warnings": ["w"]}, images={(0, 0): subject.image})
    plain, more = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("plain", "more"))
    assert list(more) == list(plain) + ["note"] and more["warnings"] == ["w"]
    assert (tmp_path / "plain" / "overlay.png").read_bytes() != (tmp_path / "more" / "overlay.png").read_bytes()
    with pytest.raises(ValueError, match="rig"):
        keypoint_stage_fit(fit)  # a rig's keypoint stage alone; an image's keypoint fit is its own folder's stages/


WRITERS = {"write_folder", "save_fit", "save_sequence_fit"}
#: run.write, the one writer of output folders, and the writer's own module (save_fit and save_sequence_fit: a
#: core's result written without its job, through the same writer)
WRITER_MODULES = {"run.py", "outputs/write.py"}


def test_only_run_write_calls_the_writer():
    import ast

    package = Path(__file__).resolve().parents[1] / "silfit"
    calls = []
    for p in sorted(package.rglob("*.py")):
        if p.relative_to(package).as_posix() in WRITER_MODULES:
            continue
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call):
                f = node.func
                name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
                if name in WRITERS:
                    calls.append(f"{p.relative_to(package)}:{node.lineno} {name}")
    assert not calls, f"write output folders with silfit.run.write: {calls}"


def test_the_writer_reads_the_cores_result_in_one_place():
    """The output folder is written from the Fit's fields; what only the core's own result holds is read by
    silfit.outputs.write.stage_parts alone."""
    import ast

    source = (Path(__file__).resolve().parents[1] / "silfit" / "outputs" / "write.py").read_text(encoding="utf-8")
    readers = set()
    for fn in ast.parse(source).body:
        if isinstance(fn, ast.FunctionDef):
            if any(isinstance(n, ast.Attribute) and n.attr == "stage" for n in ast.walk(fn)):
                readers.add(fn.name)
    assert readers == {"stage_parts"}


def test_save_fit_writes_the_folder_run_write_writes(open_model, subject, tmp_path):
    """silfit.save_fit (a FitResult without its job) goes through the one writer: the same files, the same bytes."""
    import json

    from silfit import save_fit

    job = image_job(subject.keypoints, subject.mask, subject.camera, model=open_model, keypoint_config=FAST)
    fit = run(replace(job, silhouette_config=SilhouetteFitConfig(resolutions=(32,), iterations=(2,))))
    write(fit, tmp_path / "write", images={(0, 0): subject.image})
    save_fit(fit.stage, tmp_path / "save", open_model.faces.numpy(), subject.keypoints, subject.image, subject.mask)
    files = sorted(p.relative_to(tmp_path / "write") for p in (tmp_path / "write").rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "save") for p in (tmp_path / "save").rglob("*") if p.is_file())
    assert "silhouette.png" in {f.name for f in files}
    for f in files:
        a, b = (tmp_path / d / f for d in ("write", "save"))
        if f.suffix != ".json":
            assert a.read_bytes() == b.read_bytes(), f
    timings = lambda d: {k: v for k, v in d.items() if k != "timings"}  # noqa: E731
    one, two = (json.loads((tmp_path / d / "params.json").read_text()) for d in ("write", "save"))
    assert timings(one) == timings(two)


def test_a_video_without_its_reader_is_written_and_save_sequence_fit_writes_the_same(open_model, subject, tmp_path):
    """A video fitted from Python (no reader: grey canvases) goes through the one writer, as does
    silfit.save_sequence_fit (a SequenceFitResult without its job): the same files, the same bytes."""
    from types import SimpleNamespace

    from silfit import save_sequence_fit
    from silfit.fitting.sequence import SequenceFitConfig

    ks, cam = subject.keypoints, subject.camera
    cfg = SequenceFitConfig(keypoint=FAST, iterations=3, neighbour_starts=False)
    fit = run(video_job([ks, None, ks], cam, open_model, config=cfg, numbers=[4, 5, 6]))
    write(fit, tmp_path / "write", meshes=True)
    reader = SimpleNamespace(numbers=[4, 5, 6], images={})
    save_sequence_fit(fit.stage, tmp_path / "save", open_model, reader, meshes=True, extra_metrics={"warnings": []})
    files = sorted(p.relative_to(tmp_path / "write") for p in (tmp_path / "write").rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "save") for p in (tmp_path / "save").rglob("*") if p.is_file())
    assert {"overlay.gif", "strip.png", "frame_000000000005.obj"} <= {f.name for f in files}
    for f in files:
        if f.suffix != ".json":
            assert (tmp_path / "write" / f).read_bytes() == (tmp_path / "save" / f).read_bytes(), f


def test_write_refuses_pictures_for_a_video():
    """A video's overlays are drawn on the frames its reader found; pictures given to write would be ignored."""
    from types import SimpleNamespace

    from silfit.run import write

    fit = SimpleNamespace(job=SimpleNamespace(mode="video"))
    with pytest.raises(ValueError, match="a video's pictures come from its reader"):
        write(fit, "unused", images={(0, 0): np.zeros((2, 2, 3), np.uint8)})


def test_the_removed_writers_old_homes_answer_for_one_release_with_a_warning():
    """``silfit.fitting.image_fit.save_fit`` and ``silfit.io.video.save_sequence_fit`` left for the one writer: the
    old names give the same functions, with a DeprecationWarning naming the new home; other names stay errors."""
    import importlib

    from silfit.outputs import write

    for module, name in (("silfit.fitting.image_fit", "save_fit"), ("silfit.io.video", "save_sequence_fit")):
        m = importlib.import_module(module)
        with pytest.warns(DeprecationWarning, match=f"silfit.outputs.write.{name}"):
            assert getattr(m, name) is getattr(write, name)
        with pytest.raises(AttributeError):
            m.no_such_writer


def test_a_fit_gives_its_keypoint_stage_seconds_history_and_masks_by_the_same_names(open_model, subject):
    """What callers read of a fit (the keypoint stage's result, seconds per stage, the silhouette steps, the
    rendered masks) is the Fit's, whatever the mode: the core's own record stays behind ``Fit.stage``."""
    from silfit.fitting.sequence import SequenceFitConfig

    sil = SilhouetteFitConfig(resolutions=(32,), iterations=(2,))
    make = lambda mask: image_job(  # noqa: E731
        subject.keypoints, mask, subject.camera, model=open_model, keypoint_config=FAST, silhouette_config=sil
    )
    fit, alone = run_batch([make(subject.mask), make(None)])
    kp = fit.keypoint_fit
    assert fit.refined and kp is not None and kp.keypoint_fit is None and not kp.refined
    for name, value in fit.stage.keypoint.params(0).items():
        assert np.array_equal(kp.frame_params(0)[name], np.asarray(value, np.float32)), name
    assert np.array_equal(kp.vertices[0], fit.stage.keypoint.vertices[0])
    # its record (what write() puts in params.json) is the keypoint stage's too, not the final fit's
    assert np.array_equal(kp.stage.final.body_pose, fit.stage.keypoint.body_pose)
    assert not np.array_equal(kp.stage.final.body_pose, fit.stage.final.body_pose)
    assert kp.iou[0, 0] == fit.metrics["iou_keypoint_stage"] and fit.iou[0, 0] == fit.metrics["iou"]
    assert set(fit.seconds) == {"keypoints", "silhouette"} and set(alone.seconds) == {"keypoints"}
    assert len(fit.history["iou"]) > 0 and alone.history is None
    assert fit.masks[0].shape == subject.mask.shape and fit.masks[0].dtype == bool and alone.masks == {}
    assert kp.masks[0].shape == subject.mask.shape and not np.array_equal(kp.masks[0], fit.masks[0])
    assert alone.keypoint_fit is None and not alone.refined
    assert fit.camera is fit.job.problem.observations[0].view.camera

    video = run(
        video_job(
            [subject.keypoints] * 2,
            subject.camera,
            open_model,
            progress=False,
            config=SequenceFitConfig(keypoint=FAST, iterations=3, neighbour_starts=False),
        )
    )
    assert video.keypoint_fit is None and video.history is None and video.masks == {}
    assert set(video.seconds) == {"keypoints"} and video.seconds["keypoints"] > 0


def test_check_keeps_every_field_of_an_observation_but_the_keypoints_it_checks(subject):
    ks, cam = subject.keypoints, subject.camera
    obs = [Observation(View(cam), ks, subject.mask, 0, c, known=subject.mask, cover_inner=0.7) for c in range(2)]
    checked = check(Job(Problem(obs), None, ["a", "b"], rig=True))
    for o in checked.problem.observations:
        assert o.cover_inner == 0.7 and o.known is subject.mask and o.mask is subject.mask
        assert isinstance(o.keypoints, KeypointSet)
