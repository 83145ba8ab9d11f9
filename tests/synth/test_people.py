import numpy as np

from silfit.synth.people import bystander


def test_bystander_is_a_smaller_shifted_copy():
    kp = np.array([[10.0, 20.0, 0.9], [30.0, 60.0, 0.8], [0.0, 0.0, 0.0], [50.0, 40.0, 0.5]])
    other = np.asarray(
        bystander({"pose_keypoints_2d": kp.reshape(-1).tolist()}, dx=100.0, scale=0.5)["pose_keypoints_2d"]
    ).reshape(-1, 3)
    seen = kp[:, 2] > 0
    np.testing.assert_array_equal(other[:, 2], kp[:, 2])
    np.testing.assert_array_equal(other[~seen], 0.0)  # undetected points stay (0, 0, 0)
    np.testing.assert_allclose(other[seen, :2].mean(0), kp[seen, :2].mean(0) + [100.0, 0.0], atol=1e-3)
    np.testing.assert_allclose(np.ptp(other[seen, :2], 0), 0.5 * np.ptp(kp[seen, :2], 0), atol=1e-3)
