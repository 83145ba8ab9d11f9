"""The generator: determinism, keypoints vs ground truth and mask, file format."""

import json

import numpy as np
import torch

from silfit.camera import load_camera, project_points
from silfit.io.subjects import load_subject
from silfit.io.keypoints import BODY25_NAMES, model_keypoints, read_keypoints
from silfit.priors import within_limits


def _files(root):
    return sorted(p for p in root.rglob("*") if p.is_file())


def test_same_seed_gives_identical_files(tiny_dataset, tmp_path, open_model):
    from silfit.synth.generate import generate_dataset

    out, _, cfg = tiny_dataset
    again = tmp_path / "again"
    generate_dataset(again, 3, cfg, model=open_model)
    a, b = _files(out), _files(again)
    assert [p.relative_to(out) for p in a] == [p.relative_to(again) for p in b]
    for pa, pb in zip(a, b):
        assert pa.read_bytes() == pb.read_bytes(), pa.relative_to(out)


def test_index_and_files(tiny_dataset):
    out, index, cfg = tiny_dataset
    on_disk = json.loads((out / "index.json").read_text())
    assert on_disk == json.loads(json.dumps(index))
    assert on_disk["generator"]["seed"] == 11 and on_disk["generator"]["size"] == 128
    assert on_disk["generator"]["noise_px"] == 3.0 and on_disk["version"] == 1
    assert [s["name"] for s in on_disk["subjects"]] == ["subject_000", "subject_001", "subject_002"]
    assert [s["noise_px"] for s in on_disk["subjects"]] == [0.0, 0.0, 3.0]
    for s in on_disk["subjects"]:
        for f in ("image.png", "mask.png", "keypoints.json", "camera.json", "gt.npz"):
            assert (out / s["name"] / f).is_file()
        assert 1.3 < s["stature_m"] < 2.1 and 0.5 < s["distance_m"] < 15
    first = on_disk["subjects"][0]
    assert abs(first["yaw_deg"]) <= 20 and not first["truncated"]


def test_ground_truth_reproduces_vertices_and_keypoints(tiny_dataset, open_model):
    out, index, _ = tiny_dataset
    for s in index["subjects"]:
        sub = load_subject(out / s["name"], require=("keypoints", "camera", "mask", "image", "gt"))
        gt, cam = sub.gt, load_camera(out / s["name"] / "camera.json")
        assert within_limits(torch.tensor(gt.body_pose[None])).all()
        with torch.no_grad():
            o = open_model(**{k: torch.tensor(v) for k, v in gt.params().items()})
            kp = project_points(model_keypoints(open_model, o, "body25")[0].double(), cam).numpy()
        assert np.abs(o.vertices[0].numpy() - gt.vertices).max() < 1e-6
        assert np.abs(o.joints[0].numpy() - gt.joints).max() < 1e-6
        clean = gt.extras["keypoints_2d_clean"]
        assert np.abs(kp - clean).max() < 1e-3
        # The stored keypoints: clean + noise where kept, (0, 0, 0) where outside / dropped.
        stored = read_keypoints(out / s["name"] / "keypoints.json").as_array()
        vis, dropped = gt.extras["keypoints_visibility"], gt.extras["keypoints_dropped"]
        kept = (vis > 0) & ~dropped
        assert np.all(stored[~kept] == 0)
        err = np.linalg.norm(stored[kept, :2] - clean[kept], axis=1)
        if s["noise_px"] == 0:
            assert err.max() < 1e-3 and not dropped.any()
        else:
            assert 0 < np.median(err) < 4 * s["noise_px"]
        conf = stored[:, 2]
        assert np.all((conf[kept & (vis == 2)] >= 0.6) & (conf[kept & (vis == 2)] <= 1.0))
        assert np.all((conf[kept & (vis == 1)] >= 0.1) & (conf[kept & (vis == 1)] <= 0.3))


def test_visible_keypoints_lie_on_the_mask(tiny_dataset):
    from scipy.ndimage import distance_transform_edt

    out, index, _ = tiny_dataset
    for s in index["subjects"]:
        sub = load_subject(out / s["name"], require=("mask", "gt", "camera"))
        dist = distance_transform_edt(~sub.mask)  # 0 inside, distance to the mask outside
        clean = sub.gt.extras["keypoints_2d_clean"]
        vis = sub.gt.extras["keypoints_visibility"]
        assert (vis == 2).sum() >= 8, s["name"]
        for k in np.flatnonzero(vis == 2):
            u, v = np.round(clean[k]).astype(int)
            assert dist[v, u] <= 2.0, (s["name"], BODY25_NAMES[k], dist[v, u])
        # The mask and the image agree on the body, and the body is inside the frame.
        assert sub.mask.mean() > 0.05


def test_frontal_subject_sees_the_face(tiny_dataset):
    out, _, _ = tiny_dataset
    sub = load_subject(out / "subject_000", require=("gt",))
    vis = dict(zip(BODY25_NAMES, sub.gt.extras["keypoints_visibility"]))
    assert vis["nose"] == 2 and vis["left_shoulder"] == 2 and vis["right_shoulder"] == 2


def test_back_facing_nose_is_occluded(open_model, tmp_path):
    """A body seen from behind: the nose and eyes fail the depth test (low confidence)."""
    from silfit.synth.generate import SynthConfig, generate_subject

    cfg = SynthConfig(
        seed=5,
        size=128,
        noise_px=0.0,
        frontal_first=False,
        yaw_range_deg=(180.0, 180.0),
        elevation_deg=0.0,
        roll_deg=0.0,
        blend_prob=0.0,
        perturb_deg=0.0,
    )
    rec = generate_subject(open_model, 1, cfg, tmp_path / "back")
    sub = load_subject(tmp_path / "back", require=("gt",))
    vis = dict(zip(BODY25_NAMES, sub.gt.extras["keypoints_visibility"]))
    if rec.pose not in ("lie_reclined", "lie_side"):
        assert vis["nose"] == 1 and vis["left_eye"] == 1 and vis["right_eye"] == 1
    kp = read_keypoints(tmp_path / "back" / "keypoints.json")
    assert kp.conf[BODY25_NAMES.index("nose")] <= 0.3
