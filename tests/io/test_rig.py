"""Camera rigs: camera.json with extrinsics, cameras.json, EasyMocap's intri/extri.yml, rig folders."""

import json

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from silfit.camera import Camera
from silfit.cli import main
from silfit.errors import InputError
from silfit.fitting.problem import View
from silfit.io.keypoints import write_openpose_json
from silfit.io.rig import (
    load_rig,
    look_at,
    project_world,
    read_cameras_json,
    read_easymocap,
    read_view_camera,
    ring_layout,
    write_cameras_json,
)

CAM = {"fx": 500.0, "fy": 500.0, "cx": 63.5, "cy": 63.5, "width": 128, "height": 128}
R0 = Rotation.from_rotvec([0.1, -0.7, 0.05]).as_matrix()
T0 = [0.2, -0.1, 3.0]


def write(path, data):
    path.write_text(json.dumps(data))
    return path


def test_camera_json_with_and_without_extrinsics(tmp_path):
    v = read_view_camera(write(tmp_path / "c.json", {**CAM, "R": R0.tolist(), "t": T0}))
    R, t = v.extrinsics()
    assert np.allclose(R, R0) and np.allclose(t, T0)
    plain = read_view_camera(write(tmp_path / "p.json", CAM))
    assert plain.R is None and np.allclose(plain.extrinsics()[0], np.eye(3))


@pytest.mark.parametrize(
    "extra, field, words",
    [
        ({"R": R0.tolist()}, "t", "give both"),
        ({"R": (2 * R0).tolist(), "t": T0}, "R", "not a rotation"),
        ({"R": [[1, 0], [0, 1]], "t": T0}, "R", "shape"),
        ({"R": R0.tolist(), "t": [0, 0]}, "t", "shape"),
        ({"R": R0.tolist(), "t": ["a", 0, 0]}, "t", "numbers"),
        ({"R": R0.tolist(), "t": [0, 0, float("nan")]}, "t", "NaN"),
        ({"R": R0.tolist(), "t": [0, 0, 1e6]}, "t", "metres"),
        ({"R": R0.tolist(), "t": [True, 0, 0]}, "t", "boolean"),
    ],
)
def test_bad_extrinsics_name_the_file_and_field(tmp_path, extra, field, words):
    f = write(tmp_path / "camera.json", {**CAM, **extra})
    with pytest.raises(InputError) as err:
        read_view_camera(f)
    assert err.value.field == field and str(f) in str(err.value) and words in str(err.value)
    assert "\n" not in str(err.value)


def test_cameras_json_round_trip_and_errors(tmp_path):
    views = [("a", View(Camera(**CAM), *look_at([0, 0, -3], [0, 0, 0]))), ("b", View(Camera(**CAM), R0, np.array(T0)))]
    write_cameras_json(tmp_path / "cameras.json", views)
    back = read_cameras_json(tmp_path / "cameras.json")
    assert [v.name for v in back] == ["a", "b"]
    assert np.allclose(back[1].view.extrinsics()[0], R0) and back[0].keypoints == tmp_path / "a" / "keypoints.json"
    for data, words in (
        ({"views": []}, "views"),
        ({"views": [{**CAM, "name": "x"}, {**CAM, "name": "x"}]}, "two views"),
        ({"views": [{**CAM, "name": "../up"}]}, "plain folder name"),
        ({"views": [{"name": "a", "fx": 1}]}, "missing"),
    ):
        with pytest.raises(InputError, match=words):
            read_cameras_json(write(tmp_path / "bad.json", data))


def _write_easymocap(d, names, K, rvecs, ts, dist=None, rot=False):
    fi = cv2.FileStorage(str(d / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    fi.write("names", names)
    for n in names:
        fi.write(f"K_{n}", K)
        fi.write(f"dist_{n}", np.zeros((5, 1)) if dist is None else dist)
    fi.release()
    fe = cv2.FileStorage(str(d / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    fe.write("names", names)
    for n, r, t in zip(names, rvecs, ts):
        if rot:
            fe.write(f"Rot_{n}", Rotation.from_rotvec(r).as_matrix())
        else:
            fe.write(f"R_{n}", np.asarray(r, float).reshape(3, 1))
        fe.write(f"T_{n}", np.asarray(t, float).reshape(3, 1))
    fe.release()


@pytest.mark.parametrize("rot", [False, True])
def test_easymocap_calibration(tmp_path, rot):
    K = np.array([[500.0, 0, 63.5], [0, 510.0, 60.0], [0, 0, 1]])
    rv = [[0.1, 0.2, 0.3], [0.0, -1.0, 0.0]]
    _write_easymocap(tmp_path, ["1", "2"], K, rv, [[0, 0, 3], [0.5, 0, 3]], rot=rot)
    views = read_easymocap(tmp_path / "intri.yml", tmp_path / "extri.yml", sizes={"1": (128, 128), "2": (128, 120)})
    assert [v.name for v in views] == ["1", "2"]
    assert views[1].view.camera.fy == 510.0 and views[1].view.camera.height == 120
    assert np.allclose(views[0].view.extrinsics()[0], Rotation.from_rotvec(rv[0]).as_matrix())
    assert np.allclose(views[1].view.extrinsics()[1], [0.5, 0, 3]) and not views[0].warnings


def test_easymocap_bad_files(tmp_path):
    K = np.array([[500.0, 0, 63.5], [0, 500.0, 63.5], [0, 0, 1]])
    _write_easymocap(tmp_path, ["a"], K, [[0, 0, 0]], [[0, 0, 3]], dist=np.array([[0.1, 0, 0, 0, 0]]))
    # no image size anywhere: an error naming the camera's K
    with pytest.raises(InputError, match="no image size"):
        read_easymocap(tmp_path / "intri.yml", tmp_path / "extri.yml")
    views = read_easymocap(tmp_path / "intri.yml", tmp_path / "extri.yml", sizes={"a": (128, 128)})
    assert "distortion" in views[0].warnings[0]
    text = (tmp_path / "extri.yml").read_text()
    (tmp_path / "extri.yml").write_text(text.replace("T_a", "X_a"))
    with pytest.raises(InputError) as err:
        read_easymocap(tmp_path / "intri.yml", tmp_path / "extri.yml", sizes={"a": (128, 128)})
    assert err.value.field == "T_a" and "extri.yml" in str(err.value)
    (tmp_path / "extri.yml").write_text("just: [text\n")
    with pytest.raises(InputError, match="extri.yml"):
        read_easymocap(tmp_path / "intri.yml", tmp_path / "extri.yml", sizes={"a": (128, 128)})


@pytest.mark.parametrize(
    "node",
    [
        "T_a: 3",
        'T_a: "abc"',
        "T_a: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ 1., 2. ]",
        "T_a: !!opencv-matrix\n   rows: 300000000\n   cols: 1\n   dt: d\n   data: [ 1., 2., 3. ]",
    ],
)
def test_easymocap_malformed_matrix_is_an_input_error(tmp_path, node):
    # OpenCV asserts (cv2.error) on a scalar node's or a mis-sized matrix's .mat(): one InputError instead
    K = np.array([[500.0, 0, 63.5], [0, 500.0, 63.5], [0, 0, 1]])
    _write_easymocap(tmp_path, ["a"], K, [[0, 0, 0]], [[0, 0, 3]])
    (tmp_path / "extri.yml").write_text(
        "%YAML:1.0\n---\nnames:\n   - a\nR_a: !!opencv-matrix\n   rows: 3\n   cols: 1\n"
        f"   dt: d\n   data: [ 0., 0., 0. ]\n{node}\n"
    )
    with pytest.raises(InputError, match="opencv-matrix") as err:
        read_easymocap(tmp_path / "intri.yml", tmp_path / "extri.yml", sizes={"a": (128, 128)})
    assert err.value.field == "T_a"


def test_easymocap_yaml_is_parsed_not_executed(tmp_path):
    # A PyYAML-style object tag must not construct anything: OpenCV's parser refuses it.
    marker = tmp_path / "marker"
    (tmp_path / "intri.yml").write_text(f'%YAML:1.0\n---\nnames: !!python/object/apply:os.system ["touch {marker}"]\n')
    (tmp_path / "extri.yml").write_text("%YAML:1.0\n---\nnames: []\n")
    with pytest.raises(InputError):
        read_easymocap(tmp_path / "intri.yml", tmp_path / "extri.yml")
    assert not marker.exists()


def _rig_folder(d, with_manifest):
    views = []
    for i, (R, t) in enumerate(ring_layout(3, 3.0, [0.0, 0.5, 1.0])):
        v = View(Camera(**CAM), R, t)
        sub = d / f"cam{i}"
        sub.mkdir(parents=True)
        write_openpose_json(sub / "keypoints.json", np.ones((25, 3)))
        if not with_manifest:
            write(sub / "camera.json", {**CAM, "R": R.tolist(), "t": t.tolist()})
        views.append((f"cam{i}", v))
    if with_manifest:
        write_cameras_json(d / "cameras.json", views)
    return views


@pytest.mark.parametrize("manifest", [True, False])
def test_load_rig_layouts(tmp_path, manifest):
    expected = _rig_folder(tmp_path, manifest)
    views = load_rig(tmp_path)
    assert [v.name for v in views] == [n for n, _ in expected]
    assert all(v.mask is None and v.image is None for v in views)
    for v, (_, e) in zip(views, expected):
        assert np.allclose(v.view.extrinsics()[0], e.extrinsics()[0])


def test_load_rig_errors(tmp_path):
    with pytest.raises(InputError, match="not a rig"):
        load_rig(tmp_path)
    _rig_folder(tmp_path, True)
    (tmp_path / "cam1" / "keypoints.json").unlink()
    with pytest.raises(InputError, match="keypoint file not found"):
        load_rig(tmp_path)


def test_ring_cameras_look_at_the_target():
    for R, t in ring_layout(5, 2.5, [0.0, 0.3, 0.6, 0.9, 1.2]):
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
        v = View(Camera(**CAM), R, t)
        assert np.allclose(project_world(np.zeros((1, 3)), v), [[63.5, 63.5]])
        assert (R @ [0.0, 1.0, 0.0])[1] > 0  # world down (+y) is image down


def test_fit_rig_cli_bad_camera_is_one_line(tmp_path, capsys):
    _rig_folder(tmp_path / "rig", False)
    write(tmp_path / "rig" / "cam1" / "camera.json", {**CAM, "R": [[1, 0, 0]], "t": [0, 0, 1]})
    rc = main(["fit", "--rig", str(tmp_path / "rig"), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "cam1/camera.json" in err and "'R'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_load_rig_reads_an_easymocap_folder(tmp_path):
    from silfit.io.subjects import write_png

    K = np.array([[500.0, 0, 63.5], [0, 500.0, 63.5], [0, 0, 1]])
    _write_easymocap(tmp_path, ["c1", "c2"], K, [[0, 0, 0], [0, 1.5, 0]], [[0, 0, 3], [0, 0, 3]])
    for n in ("c1", "c2"):
        (tmp_path / n).mkdir()
        write_openpose_json(tmp_path / n / "keypoints.json", np.ones((25, 3)))
        mask = np.zeros((100, 128), bool)
        mask[20:80, 40:90] = True
        write_png(tmp_path / n / "mask.png", mask)
    views = load_rig(tmp_path)
    assert [v.name for v in views] == ["c1", "c2"]
    assert views[0].view.camera.size == (128, 100) and views[1].mask == tmp_path / "c2" / "mask.png"


_values = st.recursive(
    st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(-(10**30), 10**30),
        st.booleans(),
        st.none(),
        st.text(max_size=4),
    ),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner, max_size=3),
    max_leaves=20,
)


@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), database=None)
@given(
    R=st.one_of(st.just(R0.tolist()), _values),
    t=st.one_of(st.just(T0), _values),
    manifest=st.booleans(),
    drop=st.sampled_from([None, "R", "t", "fx"]),
)
def test_fuzzed_extrinsics_are_read_or_refused_cleanly(tmp_path_factory, R, t, manifest, drop):
    doc = {**CAM, "R": R, "t": t}
    if drop:
        doc.pop(drop)
    d = tmp_path_factory.mktemp("fuzz")
    path = d / ("cameras.json" if manifest else "camera.json")
    write(path, {"views": [{"name": "a", **doc}]} if manifest else doc)
    try:
        view = read_cameras_json(path)[0].view if manifest else read_view_camera(path)
    except InputError as err:
        assert str(err).startswith(str(path)) and "\n" not in str(err)
        return
    R_, t_ = view.extrinsics()
    assert np.isfinite(R_).all() and np.isfinite(t_).all() and np.allclose(R_ @ R_.T, np.eye(3), atol=1e-2)


@pytest.mark.parametrize("layout", ["manifest", "subfolders", "easymocap"])
def test_a_rig_video_aligns_each_views_frames_by_number(tmp_path, layout):
    """A rig video: a rig folder (any of the three calibrations) whose views are video folders; frames are
    matched across views by number, a view without a frame's number has no detection there."""
    from silfit.io.subjects import write_png
    from silfit.io.video import is_rig_video, load_rig_sequence

    views = _rig_folder(tmp_path, layout == "manifest")
    if layout == "easymocap":
        _write_easymocap(
            tmp_path,
            [n for n, _ in views],
            np.array([[500.0, 0, 63.5], [0, 500.0, 63.5], [0, 0, 1]]),
            [Rotation.from_matrix(v.extrinsics()[0]).as_rotvec() for _, v in views],
            [v.extrinsics()[1] for _, v in views],
        )
        for n, _ in views:
            (tmp_path / n / "camera.json").unlink()
    ranges = {"cam0": range(0, 3), "cam1": range(1, 4), "cam2": range(0, 4)}
    for name, frames in ranges.items():
        (tmp_path / name / "keypoints.json").unlink()
        for sub in ("keypoints", "masks"):
            (tmp_path / name / sub).mkdir()
        for f in frames:
            write_openpose_json(
                tmp_path / name / "keypoints" / f"{name}_{f:012d}_keypoints.json", np.full((25, 3), 1.0 + f)
            )
            write_png(tmp_path / name / "masks" / f"{name}_{f:012d}.png", np.ones((128, 128), bool))
    assert is_rig_video(tmp_path)
    with pytest.raises(InputError, match="keypoint file not found .its folder holds a video"):
        load_rig(tmp_path)
    seq = load_rig_sequence(tmp_path)
    assert seq.names == ["cam0", "cam1", "cam2"] and seq.numbers == [0, 1, 2, 3]
    assert [[ks is not None for ks in row] for row in seq.frames] == [
        [True, False, True],
        [True, True, True],
        [True, True, True],
        [False, True, True],
    ]
    assert seq.frames[2][1].xy[0, 0] == 3.0  # cam1's frame 2 in row 2
    assert seq.per_view(1, "masks")[0] is None and seq.per_view(1, "masks")[3].name == "cam1_000000000003.png"
    assert np.allclose(seq.views[1].view.extrinsics()[0], views[1][1].extrinsics()[0])
    two = load_rig_sequence(tmp_path, names=["cam2", "cam1"])
    assert two.names == ["cam1", "cam2"] and two.numbers == [0, 1, 2, 3]
    with pytest.raises(InputError, match="unknown view.s. cam9"):
        load_rig_sequence(tmp_path, names=["cam9"])
    with pytest.raises(InputError, match="no per-frame keypoints"):
        for p in (tmp_path / "cam2" / "keypoints").iterdir():
            p.unlink()
        (tmp_path / "cam2" / "keypoints").rmdir()
        load_rig_sequence(tmp_path)
