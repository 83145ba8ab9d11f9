"""Whole-body errors against hand-computed values."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from silfit.body import load_body_model
from silfit.eval.score_wholebody import part_vertices, wholebody_errors


@pytest.fixture(scope="module")
def posed():
    m = load_body_model(kind="smplx")
    out = m(**m.zero_params(1))
    return m, {
        "vertices": out.vertices[0].double().numpy(),
        "joints": out.joints[0].double().numpy(),
        "expression": np.zeros(m.num_expression),
    }


def test_parts_are_disjoint_and_where_expected(posed):
    m, gt = posed
    parts = part_vertices(m)
    assert min(len(v) for v in parts.values()) > 500
    assert not set(parts["hand_left"]) & set(parts["hand_right"])
    x = gt["vertices"][:, 0]
    assert (x[parts["hand_left"]] > 0.5).all() and (x[parts["hand_right"]] < -0.5).all()  # +X is the body's left


def test_errors_of_moved_parts(posed):
    m, gt = posed
    parts = part_vertices(m)
    assert all(v == pytest.approx(0.0, abs=1e-6) for k, v in wholebody_errors(m, gt, gt).items())
    pred = {k: np.array(v, copy=True) for k, v in gt.items()}
    # the right hand moved 2 cm away from its wrist: wrist-aligned error 20 mm on that hand (mean of both: 10),
    # no Procrustes error (a translation)
    pred["vertices"][parts["hand_right"]] += np.array([0.0, 0.02, 0.0])
    # the face rotated and scaled about its centre: no Procrustes error
    f = parts["face"]
    c = gt["vertices"][f].mean(0)
    pred["vertices"][f] = 1.1 * Rotation.from_rotvec([0.2, 0.1, 0.0]).apply(gt["vertices"][f] - c) + c
    pred["expression"] = np.full(m.num_expression, 0.5)
    e = wholebody_errors(m, pred, gt)
    assert e["hand_wrist_mm"] == pytest.approx(10.0, abs=1e-6)
    assert e["hand_pa_mm"] == pytest.approx(0.0, abs=1e-6)
    assert e["face_pa_mm"] == pytest.approx(0.0, abs=1e-6)
    assert e["expression_err"] == pytest.approx(0.5)
    assert e["pa_pve_mm"] > 0.5


def test_eval_scores_a_whole_body_fit_folder(tmp_path):
    """A fit folder holding the ground truth's SMPL-X parameters scores zero hand/face/expression error;
    the same fit with the hands at rest does not."""
    from pathlib import Path

    from silfit.io.subjects import load_subject
    from silfit.eval.evaluate import read_fit, score_fit
    from silfit.fitting.result import KeypointFitResult

    src = Path(__file__).resolve().parents[2] / "data" / "synthetic_wholebody" / "subject_000"
    subject = load_subject(src, require=("keypoints", "camera", "gt"))
    m = load_body_model(kind="smplx")
    gt = subject.gt.params()
    smpl = {k: gt[k] for k in ("betas", "body_pose", "global_orient", "transl")}
    extra = {k: v for k, v in gt.items() if k not in smpl}
    KeypointFitResult(**smpl, cameras=[subject.camera], extra_params=extra).save(tmp_path / "truth")
    at_rest = {
        **extra,
        "left_hand_pose": np.zeros_like(extra["left_hand_pose"]),
        "right_hand_pose": np.zeros_like(extra["right_hand_pose"]),
    }
    KeypointFitResult(**smpl, cameras=[subject.camera], extra_params=at_rest).save(tmp_path / "rest")
    good = score_fit(m, subject, read_fit(tmp_path / "truth", m), iou=False)
    bad = score_fit(m, subject, read_fit(tmp_path / "rest", m), iou=False)
    assert good["hand_pa"] < 1e-3 and good["face_pa"] < 1e-3 and good["expression_err"] < 1e-6 and good["pa_pve"] < 1e-3
    assert bad["hand_pa"] > 3.0 and bad["face_pa"] < 1e-3
