"""Ground-truth recovery on a shipped noise-free subject, with tolerances set from measurement.

``data/synthetic/subject_000`` has noise-free keypoints (``noise_px`` 0; they equal the
projected truth to 5e-5 px) and its rendered mask. The keypoint stage runs a short
schedule; the silhouette stage one 96-pixel level of 40 steps from a fixed perturbation of
the truth (:func:`perturbed_truth`). Both are deterministic on one machine; the bounds hold
with margin over the spread that starts moved by 1e-9 give (other CPUs' rounding). The
silhouette stage must beat its start by stated margins on pose (PA-MPJPE), mesh (PVE) and
shape, so a silhouette stage that stops refining the pose or the shape fails.
"""

from pathlib import Path

import numpy as np
import pytest
import torch

from silfit.io.subjects import load_subject
from silfit.eval.metrics import pa_mpjpe, pve, shape_pve
from silfit.fitting import KeypointFitConfig, fit_keypoints
from silfit.fitting.silhouette_stage import SilhouetteFitConfig, fit_silhouette

SUBJECT = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "subject_000"
KEYPOINT_CONFIG = KeypointFitConfig(camera_iters=20, pose_iters=(20, 20, 30), shape_iters=10, final_iters=20)
SILHOUETTE_CONFIG = SilhouetteFitConfig(resolutions=(96,), iterations=(40,))


def errors(model, params, gt) -> dict:
    """PA-MPJPE, PVE (root-aligned), shape PVE (T-pose) in mm and the root joint's error per axis."""
    t = {k: torch.as_tensor(np.asarray(v, np.float32).reshape(1, -1)) for k, v in params.items()}
    with torch.no_grad():
        out = model(**t)
    joints, verts = out.joints[0].double().numpy(), out.vertices[0].double().numpy()
    return {
        "pa_mpjpe": 1000 * pa_mpjpe(joints, gt.joints),
        "pve": 1000 * pve(verts, gt.vertices, joints[0], gt.joints[0]),
        "shape": 1000 * shape_pve(model, t["betas"][0].numpy(), gt.betas),
        "root": 1000 * (joints[0] - gt.joints[0]),
    }


def perturbed_truth(gt) -> dict:
    """The silhouette stage's start: the truth with every joint turned by about 7 degrees (seeded
    noise), a wider, shorter shape and the body 12 cm too far and off to one side. A fixed start,
    not a keypoint fit's: the keypoint optimiser's path is chaotic (1e-12 px on the keypoints moves
    its fits by millimetres), and a start that moved with it made this test follow float rounding."""
    p = {
        k: np.asarray(getattr(gt, k), np.float64).reshape(-1) for k in ("betas", "body_pose", "global_orient", "transl")
    }
    p["body_pose"] = p["body_pose"] + np.random.default_rng(7).normal(0.0, 0.12, p["body_pose"].shape)
    p["betas"] = p["betas"] + np.r_[0.6, -0.4, np.zeros(len(p["betas"]) - 2)]
    p["transl"] = p["transl"] + np.array([0.02, -0.015, 0.12])
    return p


@pytest.fixture(scope="module")
def fits(open_model):
    s = load_subject(SUBJECT)
    assert float(s.gt.extras["noise_px"]) == 0.0
    kp = fit_keypoints(s.keypoints, s.camera, open_model, config=KEYPOINT_CONFIG, progress=False)
    start = perturbed_truth(s.gt)
    sil = fit_silhouette(
        open_model, start, s.camera, s.mask, s.keypoints.as_array(), config=SILHOUETTE_CONFIG, progress=False
    )
    e_kp, e_start, e_sil = (errors(open_model, p, s.gt) for p in (kp.params(0), start, sil.params()))
    print(f"\nkeypoint stage {e_kp}\nsilhouette start {e_start}\nsilhouette stage {e_sil}")
    return kp, sil, e_kp, e_start, e_sil


def test_keypoint_stage_recovers_the_truth(fits):
    # measured (branch search and the inscribed-sphere interpenetration on): reprojection 0.23 px,
    # PA-MPJPE 14.4 mm, PVE 27.4 mm, shape 6.6 mm, root -0.8 / 0.2 / 10.6 mm
    kp, _, e, _, _ = fits
    assert kp.reprojection_error[0] < 0.4
    assert e["pa_mpjpe"] < 25.0
    assert e["pve"] < 40.0
    assert e["shape"] < 10.0
    dx, dy, dz = e["root"]
    assert abs(dx) < 2.0 and abs(dy) < 3.0
    assert abs(dz) < 20.0  # depth is the least constrained axis


def test_silhouette_stage_recovers_the_truth(fits):
    # From the perturbed truth (PA-MPJPE 67.7, PVE 144.2, shape 25.2 mm, root 20 / 24 / 116 mm,
    # IoU 0.632) one 96 px level of 40 steps gives (measured; in brackets the range over three
    # starts moved by 1e-9, the spread float rounding elsewhere would give) PA-MPJPE 36.8 [36.8-37.7],
    # PVE 55.0 [55.0-56.3], shape 21.8 [21.8-22.2] mm, root x 9.7 [8.0-9.7] mm, IoU 0.907 [0.905-0.908].
    # A stage restricted to the translation would leave PA-MPJPE and shape at the start's.
    # Since issue 24 the default stage runs its contour level (20 L-BFGS iterations, no rendering)
    # before the rendered level, so the first rendered step (``iou_start``) already sees 0.909 and the
    # stage ends at PA-MPJPE 11.3, PVE 26.5, shape 17.2 mm, root x -0.6 mm (aten-default: 11.0, 26.6, 16.6, -0.7).
    _, sil, _, start, e = fits
    assert not sil.warnings and sil.contour_iterations > 0 and sil.iou_end > 0.88
    assert e["pa_mpjpe"] < 45.0 and e["pa_mpjpe"] < start["pa_mpjpe"] - 20.0
    assert e["pve"] < 70.0 and e["pve"] < start["pve"] - 60.0
    assert e["shape"] < start["shape"] - 1.5  # the shape moves toward the truth (3.0-3.4 mm measured)
    assert abs(e["root"][0]) < 15.0  # across the image: from 20 mm (depth stays: one view)
