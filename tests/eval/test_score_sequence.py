"""Scoring sequences: the acceleration error by hand, the truth scores zero, the evaluator's table."""

import json

import numpy as np
import pytest

from silfit.eval.metrics import acceleration_error
from silfit.eval.score_sequence import evaluate_sequences, is_sequence_dataset, score_sequence, sequence_table


def test_acceleration_error_by_hand():
    gt = np.zeros((4, 2, 3))
    pred = gt.copy()
    pred[1, 1, 0] = 0.003  # joint 1 off by 3 mm at frame 1: second differences -6 and +3 mm, joint 0 none
    assert acceleration_error(pred, gt, root=None) == pytest.approx((0.006 + 0.003) / 4)
    shifted = pred + np.array([1.0, 2.0, 3.0])  # a constant offset changes no acceleration
    assert acceleration_error(shifted, gt, root=None) == pytest.approx(acceleration_error(pred, gt, root=None))
    with pytest.raises(ValueError, match="at least 3 frames"):
        acceleration_error(gt[:2], gt[:2])


@pytest.fixture(scope="module")
def sequence_dataset(tmp_path_factory, open_model):
    from silfit.synth.motion import SequenceConfig, generate_sequence_dataset

    out = tmp_path_factory.mktemp("seqeval") / "data"
    generate_sequence_dataset(
        out, 1, SequenceConfig(seed=9, frames=5, size=32, noise_px=0.0, motions=("walk",)), model=open_model
    )
    return out


def test_truth_scores_zero_and_a_jittered_fit_does_not(sequence_dataset, open_model, tmp_path):
    gt = dict(np.load(sequence_dataset / "seq_000" / "gt.npz"))
    row = score_sequence(open_model, gt, gt)
    assert row["pa_mpjpe"] < 1e-3 and row["accel"] < 1e-3 and row["shape"] < 1e-3
    pose = gt["body_pose"].copy()
    pose[2] += 0.1
    bad = score_sequence(open_model, gt, dict(gt, body_pose=pose), bridged=[False, False, True, False, False])
    assert bad["accel"] > 1.0 and bad["pa_mpjpe_bridged"] > bad["pa_mpjpe"]


def test_a_two_frame_sequence_scores_without_acceleration(sequence_dataset, open_model):
    gt = {
        k: (v[:2] if k != "betas" and np.ndim(v) > 1 else v)
        for k, v in np.load(sequence_dataset / "seq_000" / "gt.npz").items()
    }
    pose = gt["body_pose"].copy()
    pose[1] += 0.1
    row = score_sequence(open_model, gt, dict(gt, body_pose=pose))
    assert np.isnan(row["accel"]) and row["pa_mpjpe"] > 1.0


def test_evaluate_sequences_scores_existing_fits(sequence_dataset, open_model, tmp_path):
    assert is_sequence_dataset(sequence_dataset) and not is_sequence_dataset(tmp_path)
    gt = dict(np.load(sequence_dataset / "seq_000" / "gt.npz"))
    fit = tmp_path / "fits" / "seq_000" / "temporal"
    (fit / "stages" / "per_frame").mkdir(parents=True)
    params = {k: gt[k] for k in ("betas", "body_pose", "global_orient", "transl")}
    np.savez(fit / "params.npz", **params, frames=np.arange(5), bridged=np.zeros(5, bool))
    np.savez(
        fit / "stages" / "per_frame" / "params.npz", **dict(params, betas=np.repeat(gt["betas"][None], 5, 0) + 0.5)
    )
    (fit / "metrics.json").write_text(json.dumps({"timings": {"per_frame_init": 1.0, "total": 2.0}}))
    report = evaluate_sequences(sequence_dataset, fits=tmp_path / "fits", model=open_model)
    s = report["summary"]
    assert s["temporal"]["pa_mpjpe"]["mean"] < 1e-3 and s["per_frame"]["shape"]["mean"] > 5.0
    assert s["temporal"]["seconds_per_frame"]["mean"] == pytest.approx(0.4)
    table = sequence_table(report)
    assert "acceleration error (mm/frame^2)" in table and "Sequences scored: 1" in table
