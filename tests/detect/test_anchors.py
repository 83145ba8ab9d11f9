import numpy as np
import pytest

from silfit.detect.anchors import decode_detections, ssd_anchor_centres


def test_anchor_grid_matches_the_detector_output():
    a = ssd_anchor_centres()
    assert a.shape == (2254, 2)
    # Stride 8: 28 x 28 cells, 2 anchors each, row-major from the top-left cell.
    np.testing.assert_allclose(a[0], [0.5 / 28, 0.5 / 28])
    np.testing.assert_allclose(a[1], a[0])
    np.testing.assert_allclose(a[2], [1.5 / 28, 0.5 / 28])
    np.testing.assert_allclose(a[2 * 28], [0.5 / 28, 1.5 / 28])
    # Stride 16 starts after 28*28*2 anchors; the three stride-32 layers share a 7 x 7 map, 6 per cell.
    np.testing.assert_allclose(a[1568], [0.5 / 14, 0.5 / 14])
    tail = a[1568 + 392 :]
    assert len(tail) == 7 * 7 * 6
    np.testing.assert_allclose(tail[:6], np.tile([0.5 / 7, 0.5 / 7], (6, 1)))
    np.testing.assert_allclose(tail[6], [1.5 / 7, 0.5 / 7])
    assert (a > 0).all() and (a < 1).all()


def test_decode_offsets_relative_to_anchor_centres():
    a = ssd_anchor_centres()
    raw = np.zeros((2254, 12))
    raw[10] = [22.4, -11.2, 44.8, 22.4, 0, 0, 2.24, 0, 0, 2.24, -2.24, -2.24]
    logits = np.full(2254, -5.0)
    logits[10] = 200.0  # clipped at 100 before the sigmoid
    scores, boxes, kps = decode_detections(raw[None], logits[None, :, None])
    assert scores[10] == pytest.approx(1.0) and scores[0] == pytest.approx(1 / (1 + np.exp(5.0)))
    cx, cy = a[10] + [0.1, -0.05]
    np.testing.assert_allclose(boxes[10], [cx - 0.1, cy - 0.05, cx + 0.1, cy + 0.05])
    np.testing.assert_allclose(kps[10], a[10] + np.array([[0, 0], [0.01, 0], [0, 0.01], [-0.01, -0.01]]))
    np.testing.assert_allclose(kps[0], np.tile(a[0], (4, 1)))


def test_decode_rejects_wrong_sizes():
    with pytest.raises(ValueError, match="2254"):
        decode_detections(np.zeros((100, 12)), np.zeros(100))
