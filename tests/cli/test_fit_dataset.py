"""``silfit fit-dataset`` end to end: layouts, failures, resuming (also after SIGKILL) and Ray."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from runner.helpers import FAST, SYNTHETIC, openpose_folder, synthetic_copy
from silfit.cli import main
from silfit.fitting.result import KeypointFitResult
from silfit.runner.store import read_jsonl

ROOT = Path(__file__).resolve().parents[2]


def _files(folder: Path) -> list:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def _by_item(out: Path) -> dict:
    rows = read_jsonl(out / "results.jsonl")
    keys = [r["item"] for r in rows]
    assert len(keys) == len(set(keys)), f"an item recorded twice: {keys}"
    return {r["item"]: r for r in rows}


def test_failures_are_isolated_and_runs_resume(tmp_path, capsys):
    names = [f"subject_{i:03d}" for i in range(5)]
    data = synthetic_copy(tmp_path / "data", names)
    (data / "subject_001" / "keypoints.json").write_text("{broken")
    (data / "subject_002" / "camera.json").write_text(
        '{"fx": 100, "fy": 100, "cx": 10, "cy": 10, "width": -5, "height": 4}'
    )
    # without camera.json and image.png a keypoint-only run reads the mask for the image size
    (data / "subject_003" / "mask.png").write_bytes(b"not a png")
    (data / "subject_003" / "camera.json").unlink()
    (data / "subject_003" / "image.png").unlink()
    out = tmp_path / "out"
    args = ["fit-dataset", str(data), "--out", str(out), "--no-silhouette", "--batch-size", "4", "--quiet", *FAST]
    assert main(args) == 13  # 10 + 3 failed
    assert "3 of 5 items failed" in capsys.readouterr().err
    records = _by_item(out)
    assert {k for k, r in records.items() if r["status"] == "ok"} == {"subject_000", "subject_004"}
    fails = {f["item"]: f for f in read_jsonl(out / "failures.jsonl")}
    assert fails["subject_001"]["file"] == str(data / "subject_001" / "keypoints.json")
    assert fails["subject_002"]["file"] == str(data / "subject_002" / "camera.json")
    assert (
        fails["subject_003"]["file"] == str(data / "subject_003" / "mask.png")
        and fails["subject_003"]["field"] == "mask"
    )
    assert all(f["message"] and "\n" not in f["message"] for f in fails.values())
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["report", "subject_000", "subject_004"]
    assert (out / "report" / "index.html").is_file()  # the gallery (tests/outputs/test_report.py opens it)
    for f in ("summary.md", "summary.png", "summary.json"):
        assert (out / f).is_file()
    fit = KeypointFitResult.load(out / "subject_000")
    assert fit.camera.fx == pytest.approx(json.loads((data / "subject_000" / "camera.json").read_text())["fx"])
    assert records["subject_000"]["reprojection_error_px"] < 10

    # a rerun fits nothing again; --retry-failed retries the failed ones only
    stamp = (out / "subject_000" / "params.npz").stat().st_mtime_ns
    assert main(args) == 13
    assert (out / "subject_000" / "params.npz").stat().st_mtime_ns == stamp
    (data / "subject_001" / "keypoints.json").write_text((SYNTHETIC / "subject_001" / "keypoints.json").read_text())
    assert main(args + ["--retry-failed"]) == 12
    records = _by_item(out)
    assert records["subject_001"]["status"] == "ok" and len(records) == 5
    assert (out / "subject_000" / "params.npz").stat().st_mtime_ns == stamp
    assert [f["item"] for f in read_jsonl(out / "failures.jsonl")] == ["subject_002", "subject_003"]


def test_openpose_people_all_matches_silfit_fit_layout(tmp_path):
    root = openpose_folder(tmp_path / "in", names=("subject_000", "subject_001"), two_people=("subject_001",))
    out = tmp_path / "out"
    sil = ["--silhouette-resolutions", "48", "--silhouette-iterations", "4"]
    rc = main(
        [
            "fit-dataset",
            str(root / "kp"),
            "--out",
            str(out),
            "--people",
            "all",
            "--masks",
            str(root / "masks"),
            "--images",
            str(root / "images"),
            "--camera",
            str(root / "cameras"),
            "--quiet",
            *FAST,
            *sil,
        ]
    )
    assert rc == 0
    records = _by_item(out)
    assert sorted(records) == ["subject_000_0", "subject_001_0", "subject_001_1"]
    with_mask, without = records["subject_001_0"], records["subject_001_1"]
    assert with_mask["stages"] == ["keypoints", "silhouette"] and 0 < with_mask["iou"] <= 1
    assert without["stages"] == ["keypoints"] and "iou" not in without and "no mask" in without["silhouette_stage"]
    assert (
        json.loads((out / "subject_001_1" / "metrics.json").read_text())["silhouette_stage"]
        == without["silhouette_stage"]
    )
    # the same files as `silfit fit` writes for one image with (and without) a mask
    single = tmp_path / "single"
    assert (
        main(
            [
                "fit",
                "--keypoints",
                str(root / "kp" / "subject_001_keypoints.json"),
                "--person",
                "0",
                "--mask",
                str(root / "masks" / "subject_001_0.png"),
                "--image",
                str(root / "images" / "subject_001.png"),
                "--camera",
                str(root / "cameras" / "subject_001.json"),
                "--out",
                str(single),
                "--quiet",
                *sil,
            ]
        )
        == 0
    )
    assert _files(out / "subject_001_0") == _files(single)
    kp_only = set(_files(single)) - {"silhouette.png", "iou_curve.png", "stages/keypoints/overlay.png"}
    assert set(_files(out / "subject_001_1")) == kp_only


def test_bad_command_is_one_line_exit_2(tmp_path, capsys):
    assert main(["fit-dataset", str(tmp_path / "none"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "dataset input not found" in err and len(err.splitlines()) == 1
    assert main(["fit-dataset", str(SYNTHETIC), "--out", str(tmp_path / "o"), "--keypoint-option", "nope=1"]) == 2
    assert "unknown keypoint-stage option 'nope'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    assert (
        main(
            [
                "fit-dataset",
                str(SYNTHETIC),
                "--out",
                str(tmp_path / "o"),
                "--silhouette-resolutions",
                "64",
                "--silhouette-iterations",
                "5,5",
            ]
        )
        == 2
    )
    assert "same number of levels" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    (tmp_path / "file").write_text("x")
    assert main(["fit-dataset", str(SYNTHETIC), "--out", str(tmp_path / "file")]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    for value, extra in (("0", []), ("two", []), ("2", ["--ray"])):  # local processes: a count, or auto; not with Ray
        assert main(["fit-dataset", str(SYNTHETIC), "--out", str(tmp_path / "o"), "--workers", value, *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--workers" in err, err
        assert not (tmp_path / "o").exists()
    # a model or pose prior that cannot be read is refused before anything is written (results.jsonl was left)
    for flag in ("--model", "--pose-prior"):
        assert main(["fit-dataset", str(SYNTHETIC), "--out", str(tmp_path / "o"), flag, "EVIL"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "EVIL" in err, err
        assert not (tmp_path / "o").exists()


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(
        [sys.executable, "-m", "silfit", "fit-dataset", *args],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )


def _workers_of(pid: int) -> list:
    """The fit-dataset worker processes of ``pid`` (spawned by multiprocessing; not its resource tracker)."""
    found = []
    try:
        children = [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return found
    for c in children:
        try:
            cmdline = Path(f"/proc/{c}/cmdline").read_bytes()
        except OSError:
            continue
        if b"multiprocessing.spawn" in cmdline and b"resource_tracker" not in cmdline:
            found.append(c)
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


_LINUX = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds the worker processes in /proc")


@pytest.mark.parametrize(
    "workers, victim",
    [("1", "driver"), pytest.param("2", "driver", marks=_LINUX), pytest.param("2", "worker", marks=_LINUX)],
)
def test_sigkill_mid_run_then_restart_finishes_each_item_once(tmp_path, workers, victim):
    """Also with ``--workers 2``: the worker processes end with a killed driver (none left writing into OUT);
    a killed worker stops the run with one line and status 2, the batches finished so far recorded."""
    if workers != "1" and not Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").exists():
        pytest.skip("this kernel lists no child processes in /proc")
    names = [f"subject_{i:03d}" for i in range(5)]
    data, out = synthetic_copy(tmp_path / "data", names), tmp_path / "out"
    args = [
        str(data),
        "--out",
        str(out),
        "--no-silhouette",
        "--batch-size",
        "1",
        "--quiet",
        *FAST,
        "--keypoint-option",
        "pose_iters=25,25,25",
        "--workers",
        workers,
    ]
    proc = _cli(*args)
    deadline = time.time() + 600  # the loop ends once two items are done; the CPU may be shared with other test workers
    while time.time() < deadline and proc.poll() is None:
        done = len(read_jsonl(out / "results.jsonl"))
        if done >= 2:
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be killed"
    children = _workers_of(proc.pid) if workers != "1" else []
    if victim == "worker":
        os.kill(children[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 2 and len(err.decode().strip().splitlines()) == 1, err.decode()[-2000:]
        assert "worker process ended without its results" in err.decode()
    else:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    deadline = time.time() + 30
    while time.time() < deadline and any(_alive(c) for c in children):
        time.sleep(0.1)
    assert len(children) == (0 if workers == "1" else 2)
    assert not [c for c in children if _alive(c)], "worker processes outlived the run"
    killed_at = len(read_jsonl(out / "results.jsonl"))
    assert 2 <= killed_at < len(names)
    proc = _cli(*args)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err.decode()[-2000:]
    records = _by_item(out)
    assert sorted(records) == names
    assert all(r["status"] == "ok" for r in records.values())
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no partial folder left
    for key in records:
        KeypointFitResult.load(out / key)


def test_sigterm_stops_a_ray_run_with_status_143(tmp_path):
    """``--ray``: ``ray.init`` installs its own SIGTERM handler in the driver (it exited with status 15, without the
    command line's line); the command line's handler comes back after it, so SIGTERM ends the run with its one line
    (below Ray's own log lines) and status 143, as a local run does, the items done recorded."""
    pytest.importorskip("ray")
    names = [f"subject_{i:03d}" for i in range(4)]
    data, out = synthetic_copy(tmp_path / "data", names), tmp_path / "out"
    args = [
        str(data),
        "--out",
        str(out),
        "--no-silhouette",
        "--batch-size",
        "1",
        "--quiet",
        "--ray",
        "--actors",
        "1",
        *FAST,
        "--keypoint-option",
        "pose_iters=25,25,25",
    ]
    proc = _cli(*args)
    deadline = time.time() + 600  # Ray's start, then one item done: SIGTERM lands after ray.init
    while time.time() < deadline and proc.poll() is None and not read_jsonl(out / "results.jsonl"):
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be stopped"
    os.kill(proc.pid, signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()  # (a run that did not end is not left behind)
    text = err.decode()
    assert proc.returncode == 143, text[-2000:]
    ours = [line for line in text.splitlines() if line.startswith("silfit ")]  # Ray's log lines around them
    assert ours == ["silfit fit-dataset: interrupted (SIGTERM)"], text[-2000:]
    assert "not the main thread" not in text, text[-2000:]  # no second Ray started by a Ray Data thread (CI, once)
    assert 1 <= len(read_jsonl(out / "results.jsonl")) <= len(names)


def test_worker_processes_match_one_process(tmp_path):
    """``--workers 2``: two spawned processes (one torch and one Dr.Jit thread each) fit the same bits as this
    process does alone (its Dr.Jit pool as large as the machine), silhouettes included; each item recorded
    once, and nothing is left behind but the items' folders."""
    names = [f"subject_{i:03d}" for i in range(4)]
    data = synthetic_copy(tmp_path / "data", names)
    common = [str(data), "--silhouette-iterations", "3,3", "--batch-size", "4", "--no-report", "--quiet", *FAST]
    assert main(["fit-dataset", "--out", str(tmp_path / "one"), *common]) == 0
    assert main(["fit-dataset", "--out", str(tmp_path / "two"), "--workers", "2", *common]) == 0
    one, two = _by_item(tmp_path / "one"), _by_item(tmp_path / "two")
    assert sorted(one) == sorted(two) == names
    assert {r["keypoint_batch_size"] for r in two.values()} == {2}  # batches cut so both processes get work
    assert all(r["silhouette_stage"] == "fitted" for r in two.values())
    for key in names:  # the records whole (warnings, errors, IoU), but the timings and the batch
        a, b = ({k: v for k, v in r[key].items() if k not in ("timings_s", "keypoint_batch_size")} for r in (one, two))
        assert a == b, key
        assert (tmp_path / "one" / key / "params.npz").read_bytes() == (
            tmp_path / "two" / key / "params.npz"
        ).read_bytes()
    assert sorted(p.name for p in (tmp_path / "two").iterdir() if p.is_dir()) == names


def test_ray_run_matches_local_run(tmp_path):
    """Same inputs, same fit (issue 22): the local run with two threads and batches of one, Ray's
    one-thread actors with batches of two: the same bits. (Before, in float32 with batch-dependent
    GEMMs, local and Ray runs agreed only with both at OMP_NUM_THREADS=1, and batch sizes 1 and 4
    changed all 12 fits, one by 106 mm PA-PVE.)"""
    pytest.importorskip("ray")
    names = [f"subject_{i:03d}" for i in range(4)]  # two batches of two: one per actor
    common = [str(synthetic_copy(tmp_path / "data", names)), "--no-silhouette", "--quiet", *FAST]
    root = Path(__file__).resolve().parents[2]
    env = {
        **os.environ,
        "OMP_NUM_THREADS": "2",
        "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]),
    }
    done = subprocess.run(
        [sys.executable, "-m", "silfit", "fit-dataset", "--out", str(tmp_path / "local"), "--batch-size", "1", *common],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    common += ["--batch-size", "2"]
    assert main(["fit-dataset", "--out", str(tmp_path / "ray"), "--ray", "--actors", "2", *common]) == 0
    import ray as ray_api

    assert not ray_api.is_initialized()
    with pytest.raises(Exception, match="not been started"):  # a late Ray Data thread's call starts no new Ray
        ray_api.put(1)
    local, ray = _by_item(tmp_path / "local"), _by_item(tmp_path / "ray")
    assert sorted(local) == sorted(ray) == names
    for key in local:
        a, b = (
            {k: v for k, v in r.items() if k not in ("timings_s", "keypoint_batch_size")}
            for r in (local[key], ray[key])
        )
        assert a.keys() == b.keys()
        for k in a:
            if isinstance(a[k], float):
                assert a[k] == pytest.approx(b[k], abs=1e-3), (key, k)
            else:
                assert a[k] == b[k], (key, k)
        pa, pb = (KeypointFitResult.load(tmp_path / d / key) for d in ("local", "ray"))
        for name in ("betas", "body_pose", "global_orient", "transl", "vertices"):
            np.testing.assert_array_equal(getattr(pa, name), getattr(pb, name), err_msg=f"{key} {name}")


def test_dataset_items_get_the_checks_of_one_image(tmp_path):
    """Keypoints at 1e30 fail the item (named file and field), one far-off wrist is dropped with a warning, as
    ``silfit fit`` does for one image (silfit.fitting.plausibility); a fit gets the same warnings."""
    data = synthetic_copy(tmp_path / "data", ["subject_000", "subject_001"])
    doc = json.loads((data / "subject_000" / "keypoints.json").read_text())
    values = np.asarray(doc["people"][0]["pose_keypoints_2d"], dtype=float).reshape(-1, 3)
    far = values.copy()
    far[:, :2] = 1e30
    (data / "subject_000" / "keypoints.json").write_text(
        json.dumps({**doc, "people": [{"pose_keypoints_2d": far.ravel().tolist()}]})
    )
    wrist = values.copy()
    wrist[4, :2] = 1e30
    (data / "subject_001" / "keypoints.json").write_text(
        json.dumps({**doc, "people": [{"pose_keypoints_2d": wrist.ravel().tolist()}]})
    )
    out = tmp_path / "out"
    assert main(["fit-dataset", str(data), "--out", str(out), "--no-silhouette", "--quiet", *FAST]) == 11
    fail = read_jsonl(out / "failures.jsonl")[0]
    assert (
        fail["item"] == "subject_000"
        and fail["field"] in ("keypoints", "people[0].pose_keypoints_2d")
        and "far outside" in fail["message"]
    )
    ok = _by_item(out)["subject_001"]
    assert ok["status"] == "ok" and any("right_wrist" in w and "treated as missing" in w for w in ok["warnings"])
    metrics = json.loads((out / "subject_001" / "metrics.json").read_text())
    assert metrics["warnings"] == ok["warnings"]


def test_export_and_no_report(tmp_path):
    import trimesh

    data = synthetic_copy(tmp_path / "data", ["subject_000", "subject_002"])
    out = tmp_path / "out"
    assert (
        main(
            [
                "fit-dataset",
                str(data),
                "--out",
                str(out),
                "--no-silhouette",
                "--export",
                "glb,ply",
                "--no-report",
                "--quiet",
                *FAST,
            ]
        )
        == 0
    )
    assert not (out / "report").exists()
    for item in ("subject_000", "subject_002"):
        joints = np.load(out / item / "params.npz")["joints"].reshape(-1, 3)
        glb = trimesh.load(out / item / "mesh.glb", process=False).geometry["body"]
        ply = trimesh.load(out / item / "mesh.ply", process=False)
        assert np.allclose(glb.vertices, ply.vertices, atol=1e-5)
        assert -joints[15, 1] > -joints[7, 1] and glb.vertices[:, 1].max() > -joints[15, 1]  # upright: head +Y
    assert main(["fit-dataset", str(data), "--out", str(tmp_path / "o2"), "--export", "fbx", "--quiet"]) == 2
    assert not (tmp_path / "o2").exists()
