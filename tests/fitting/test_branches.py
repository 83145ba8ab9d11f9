"""silfit.fitting.branches: rotations between directions and limbs turned onto 3D points."""
import numpy as np
import torch

from silfit.fitting.body import KeypointBody
from silfit.fitting.branches import align_segments, rotation_between
from silfit.keypoints import BODY25_NAMES


def test_rotation_between_turns_one_direction_onto_another():
    rng = np.random.default_rng(3)
    v, w = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    w[0] = -v[0]  # opposite: a half turn
    w[1] = 2.0 * v[1]  # the same direction: no turn
    R = rotation_between(v, w)
    turned = np.einsum("rij,rj->ri", R, v)
    unit = lambda a: a / np.linalg.norm(a, axis=-1, keepdims=True)  # noqa: E731
    assert np.allclose(unit(turned), unit(w), atol=1e-9)
    assert np.allclose(R[1], np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1.0)


def test_limbs_are_turned_onto_the_points_of_a_posed_body(body_model):
    body = KeypointBody(body_model, "body25")
    rng = np.random.default_rng(5)
    pose = torch.zeros(2, 69, dtype=body_model.dtype)
    for j in (1, 2, 4, 5, 16, 17, 18, 19):  # hips, knees, shoulders, elbows
        pose[:, 3 * (j - 1) : 3 * j] = torch.as_tensor(rng.uniform(-0.8, 0.8, size=(2, 3)), dtype=pose.dtype)
    rows = {"betas": torch.zeros(2, 10, dtype=pose.dtype), "global_orient": torch.zeros(2, 3, dtype=pose.dtype),
            "transl": torch.zeros(2, 3, dtype=pose.dtype)}  # fmt: skip
    with torch.no_grad():
        target = body(**rows, body_pose=pose).keypoints.double().numpy()
    w = np.ones(target.shape[:2])
    w[1, BODY25_NAMES.index("left_wrist")] = 0.0  # not seen: that forearm keeps its turn
    start = dict(rows, body_pose=torch.zeros_like(pose))
    aligned = align_segments(body, start, target, w, body_model.joint_names, body_model.parents, BODY25_NAMES)
    with torch.no_grad():
        kp = body(**rows, body_pose=aligned).keypoints.double().numpy()

    def cos(a, b, p, d):
        u, v = a[:, d] - a[:, p], b[:, d] - b[:, p]
        return (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)

    I = BODY25_NAMES.index  # noqa: E741
    for p, d in (("left_hip", "left_knee"), ("right_knee", "right_ankle"), ("left_shoulder", "left_elbow"),
                 ("right_elbow", "right_wrist")):  # fmt: skip
        assert (cos(kp, target, I(p), I(d)) > 0.9999).all(), (p, d)
    lw = (I("left_elbow"), I("left_wrist"))
    assert cos(kp, target, *lw)[0] > 0.9999
    j = body_model.joint_names.index("left_elbow")
    assert torch.all(aligned[1, 3 * (j - 1) : 3 * j] == 0) and torch.any(aligned[0, 3 * (j - 1) : 3 * j] != 0)
