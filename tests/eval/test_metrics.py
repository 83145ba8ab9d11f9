"""Metrics: known answers."""

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from silfit.eval.metrics import mask_iou, mpjpe, pa_mpjpe, procrustes_align, pve, reprojection_error, translation_error


@pytest.fixture
def joints():
    return np.random.default_rng(0).normal(0, 0.3, (24, 3))


def test_pa_mpjpe_of_a_similar_copy_is_zero(joints):
    R = Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix()
    moved = 1.7 * joints @ R.T + np.array([0.4, -2.0, 5.0])
    assert pa_mpjpe(moved, joints) < 1e-9
    assert np.allclose(procrustes_align(moved, joints), joints, atol=1e-9)
    # Not a similarity: a mirror image is not aligned away (reflections are excluded).
    assert pa_mpjpe(joints * np.array([-1, 1, 1]), joints) > 0.05


def test_pa_mpjpe_batched_and_never_above_mpjpe(joints):
    rng = np.random.default_rng(1)
    pred = joints[None] + rng.normal(0, 0.05, (4, 24, 3))
    gt = np.repeat(joints[None], 4, 0)
    pa = pa_mpjpe(pred, gt)
    assert pa.shape == (4,)
    assert np.all(pa <= mpjpe(pred, gt) + 1e-12)


def test_mpjpe_is_pelvis_aligned(joints):
    assert mpjpe(joints + np.array([1.0, 2.0, 3.0]), joints) < 1e-12
    assert mpjpe(joints + np.array([1.0, 2.0, 3.0]), joints, root=None) == pytest.approx(math.sqrt(14))
    off = joints.copy()
    off[5] += np.array([0.0, 0.03, 0.04])  # one joint off by 5 cm
    assert mpjpe(off, joints) == pytest.approx(0.05 / 24)


def test_pve_identical_and_known_offset():
    v = np.random.default_rng(2).normal(0, 0.3, (500, 3))
    assert pve(v, v) == 0.0
    shifted = v + np.array([0.0, 0.0, 0.02])
    assert pve(shifted, v, align=False) == pytest.approx(0.02)
    assert pve(shifted, v) == pytest.approx(0.0, abs=1e-12)  # centroid-aligned
    half = v.copy()
    half[:250] += np.array([0.006, 0.0, 0.008])  # half the vertices 1 cm off
    assert pve(half, v, align=False) == pytest.approx(0.005)


def test_translation_and_reprojection_errors():
    assert translation_error([0, 0, 3], [0.03, 0.04, 3]) == pytest.approx(0.05)
    a = np.zeros((4, 2))
    b = np.array([[3.0, 4.0], [0.0, 1.0], [100.0, 0.0], [0.0, 0.0]])
    assert reprojection_error(a, b) == pytest.approx(26.5)
    assert reprojection_error(a, b, [True, True, False, True]) == pytest.approx(2.0)
    assert math.isnan(reprojection_error(a, b, [False] * 4))


def test_mask_iou_of_known_masks():
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    a[0:4, 0:5] = True  # 20 px
    b[2:6, 0:5] = True  # 20 px, overlap 10
    assert mask_iou(a, b) == pytest.approx(10 / 30)
    assert mask_iou(a, a) == 1.0
    assert mask_iou(a, ~a) == 0.0
    assert mask_iou(a.astype(np.uint8) * 255, b.astype(np.float32)) == pytest.approx(1 / 3)
    with pytest.raises(ValueError):
        mask_iou(a, np.zeros((5, 5)))


def test_shape_pve_is_zero_for_the_same_shape_and_stature_alignment_removes_scale(open_model):
    from silfit.eval.metrics import shape_pve

    betas = np.zeros(10)
    taller = betas.copy()
    taller[0] = 2.0  # beta0 is mostly stature
    assert shape_pve(open_model, betas, betas) == pytest.approx(0.0, abs=1e-9)
    plain = shape_pve(open_model, taller, betas)
    scaled = shape_pve(open_model, taller, betas, scale=True)
    print(f"beta0 = 2 vs 0: shape PVE {1000 * plain:.1f} mm, stature aligned {1000 * scaled:.1f} mm")
    assert plain > 0.03 and scaled < 0.5 * plain


def test_the_metrics_import_with_numpy_only():
    """``silfit.eval`` and its metrics load no torch (``shape_pve`` imports it when called; ``evaluate`` is lazy)."""
    code = "import sys, silfit.eval, silfit.eval.metrics; print('torch' in sys.modules, 'scipy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.split() == ["False", "False"], out.stderr
