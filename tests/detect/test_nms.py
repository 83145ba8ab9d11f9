import numpy as np

from silfit.detect.nms import box_iou, weighted_nms


def test_box_iou():
    b = np.array([0.0, 0.0, 2.0, 2.0])
    others = np.array([[0.0, 0.0, 2.0, 2.0], [1.0, 0.0, 3.0, 2.0], [5.0, 5.0, 6.0, 6.0], [1.0, 1.0, 1.0, 1.0]])
    np.testing.assert_allclose(box_iou(b, others), [1.0, 2.0 / 6.0, 0.0, 0.0])


def test_weighted_nms_merges_overlaps_and_keeps_separate_people():
    scores = np.array([0.9, 0.6, 0.8, 0.3])
    boxes = np.array([[0.0, 0.0, 1.0, 1.0], [0.1, 0.0, 1.1, 1.0], [3.0, 3.0, 4.0, 4.0], [0.0, 0.0, 1.0, 1.0]])
    kps = np.stack([np.full((4, 2), v) for v in (1.0, 2.0, 7.0, 9.0)])
    s, b, k = weighted_nms(scores, boxes, kps, min_score=0.5, iou_threshold=0.3)
    np.testing.assert_allclose(s, [0.9, 0.8])  # the 0.3 detection is below the threshold
    w = np.array([0.9, 0.6]) / 1.5
    np.testing.assert_allclose(b[0], w @ boxes[:2])
    np.testing.assert_allclose(k[0], np.full((4, 2), w @ [1.0, 2.0]))
    np.testing.assert_allclose(b[1], boxes[2])
    s, b, k = weighted_nms(scores, boxes, kps, min_score=0.5, max_detections=1)
    assert len(s) == 1
    s, b, k = weighted_nms(scores, boxes, kps, min_score=0.95)
    assert s.shape == (0,) and b.shape == (0, 4) and k.shape == (0, 4, 2)
