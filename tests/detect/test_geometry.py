import math

import numpy as np
import pytest

from silfit.detect.geometry import ROI, normalize_angle, roi_from_alignment_points, warp_from_crop, warp_to_crop


def test_crop_and_image_coordinates_are_inverse():
    roi = ROI(40.0, 30.0, 50.0, 0.7)
    pts = np.random.default_rng(0).uniform(0, 1, (20, 2))
    np.testing.assert_allclose(roi.image_to_crop(roi.crop_to_image(pts)), pts, atol=1e-12)
    np.testing.assert_allclose(roi.crop_to_image([[0.5, 0.5]]), [[40.0, 30.0]])
    # The crop's "up" points along (sin a, -cos a) in the image (y down).
    up = roi.crop_to_image([[0.5, 0.0]])[0] - [40.0, 30.0]
    np.testing.assert_allclose(up, 25.0 * np.array([math.sin(0.7), -math.cos(0.7)]))


def test_crop_matrix_maps_pixel_centres():
    roi = ROI(40.0, 30.0, 64.0, -0.4)
    M = roi.crop_matrix(16)
    q = np.array([[0.0, 0.0], [15.0, 3.0], [7.5, 7.5]])
    np.testing.assert_allclose(q @ M[:, :2].T + M[:, 2], roi.crop_to_image((q + 0.5) / 16))


def test_alignment_points_give_upright_and_lying_regions():
    upright = roi_from_alignment_points([50.0, 80.0], [50.0, 40.0], scale=1.25)
    assert upright.angle == pytest.approx(0.0) and upright.size == pytest.approx(100.0)
    assert (upright.cx, upright.cy) == (50.0, 80.0)
    lying = roi_from_alignment_points([50.0, 80.0], [90.0, 80.0], scale=1.0)  # head to the right
    assert lying.angle == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(lying.crop_to_image([[0.5, 0.0]])[0], [90.0, 80.0])
    assert normalize_angle(3 * math.pi) == pytest.approx(-math.pi)


def test_warps_sample_the_rotated_square_and_put_it_back():
    img = np.zeros((60, 80, 3), np.uint8)
    img[20:30, 50:60] = 255  # a bright square right of the centre
    roi = ROI(39.5, 29.5, 40.0, math.pi / 2)  # crop "up" = image right
    crop = warp_to_crop(img, roi, 40)
    ys, xs = np.nonzero(crop[..., 0] > 128)
    # Image offsets (dx, dy) from the centre land at crop offsets (dy, -dx): the square,
    # 10.5..19.5 px right of and 0.5..9.5 px above the centre, fills crop rows 0..9, columns 10..19.
    assert (ys.min(), ys.max(), xs.min(), xs.max()) == (0, 9, 10, 19)
    back = warp_from_crop(crop[..., 0].astype(np.float32) / 255, roi, 80, 60)
    assert back[25, 55] > 0.9 and back[25, 30] < 0.1 and back[5, 5] == 0.0


def test_large_reductions_are_area_filtered():
    img = np.zeros((400, 400, 3), np.uint8)
    img[:, ::2] = 255  # one-pixel stripes: aliasing would give 0 or 255, filtering ~128
    crop = warp_to_crop(img, ROI(199.5, 199.5, 400.0), 40)
    assert abs(float(crop[5:-5, 5:-5].mean()) - 127.5) < 10
