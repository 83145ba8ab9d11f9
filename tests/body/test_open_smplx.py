"""The shipped open whole-body model (SMPL-X layout): layout, articulation regions, expressions and the
face landmarks the exporter chose."""

import numpy as np
import pytest
import torch

from silfit import load_body_model
from silfit.body.io import SMPLX_JOINT_NAMES


@pytest.fixture(scope="module")
def wb():
    return load_body_model(kind="smplx", dtype=torch.float64)


def face(wb, **params):
    return wb.face_landmarks(wb(**params))[0].numpy()


def test_layout_matches_the_open_body_vertex_for_vertex(wb, open_model64):
    assert wb.kind == "smplx" and wb.num_joints == 55 and wb.joint_names == SMPLX_JOINT_NAMES
    assert wb.num_vertices == open_model64.num_vertices and torch.equal(wb.faces, open_model64.faces)
    assert wb.num_betas == 10 and wb.num_expression >= 10
    assert not wb.use_pca
    betas = torch.randn(2, 10, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    a, b = wb(betas=betas), open_model64(betas=betas)
    assert torch.allclose(a.vertices, b.vertices, atol=1e-6)
    assert torch.allclose(a.joints[:, :22], b.joints[:, :22], atol=1e-6)  # the body joints are SMPL's


def test_zero_parameters_give_the_template(wb):
    out = wb(**wb.zero_params(1))
    assert torch.allclose(out.vertices[0], wb.v_template, atol=1e-12)


def moved(wb, **params):
    rest = wb().vertices[0]
    return ((wb(**params).vertices[0] - rest).norm(dim=1) > 1e-9).numpy()


def test_hands_jaw_and_expressions_move_only_their_regions(wb):
    W = wb.lbs_weights.numpy()
    names = list(wb.joint_names)
    left = W[:, 25:40].sum(1) > 0
    right = W[:, 40:55].sum(1) > 0
    head = W[:, [names.index(n) for n in ("head", "jaw", "left_eye_smplhf", "right_eye_smplhf")]].sum(1) > 0
    g = torch.Generator().manual_seed(0)
    ml = moved(wb, left_hand_pose=torch.randn(1, 45, generator=g, dtype=torch.float64) * 0.4)
    mr = moved(wb, right_hand_pose=torch.randn(1, 45, generator=g, dtype=torch.float64) * 0.4)
    mj = moved(wb, jaw_pose=torch.tensor([[0.35, 0.0, 0.0]], dtype=torch.float64))
    assert ml.sum() > 500 and not (ml & ~left).any()
    assert mr.sum() > 500 and not (mr & ~right).any()
    assert mj.sum() > 300 and not (mj & ~(W[:, names.index("jaw")] > 0)).any()
    for k in range(wb.num_expression):
        e = torch.zeros(1, wb.num_expression, dtype=torch.float64)
        e[0, k] = 1.0
        d = (wb(expression=e).vertices[0] - wb.v_template).norm(dim=1).numpy()
        assert 3e-4 < d.max() < 0.03, k  # unit coefficients move the face by millimetres, not more than 3 cm
        if k == 0:
            assert d.max() > 5e-3
        assert not ((d > 1e-6) & ~head).any(), k


def test_jaw_opens_the_mouth_downwards(wb):
    closed = face(wb)
    opened = face(wb, jaw_pose=torch.tensor([[0.35, 0.0, 0.0]], dtype=torch.float64))
    # the lower lip drops; the chin's underside less (anny's jawOpen moves it about half as far as the lip)
    assert opened[57, 1] < closed[57, 1] - 0.01 and opened[8, 1] < closed[8, 1] - 0.003
    assert np.abs(opened[17:27] - closed[17:27]).max() < 1e-4 and np.abs(opened[36:48] - closed[36:48]).max() < 1e-4
    assert np.abs(opened[27:36] - closed[27:36]).max() < 2e-3  # brows and eyes stay, the nose nearly
    assert np.abs(opened[51] - closed[51]).max() < 2e-3  # the upper lip barely moves


def test_face_landmarks_form_the_68_point_arrangement(wb):
    f = face(wb)
    mirror = f * np.array([-1.0, 1.0, 1.0])
    pairs = (
        [(i, 16 - i) for i in range(8)]
        + [(17 + i, 26 - i) for i in range(5)]
        + [
            (31, 35),
            (32, 34),
            (36, 45),
            (37, 44),
            (38, 43),
            (39, 42),
            (40, 47),
            (41, 46),
            (48, 54),
            (49, 53),
            (50, 52),
            (59, 55),
            (58, 56),
        ]
    )
    assert max(np.linalg.norm(f[a] - mirror[b]) for a, b in pairs) < 1e-3  # left/right symmetric
    assert np.abs(f[[8, 27, 28, 29, 30, 33, 51, 57, 62, 66], 0]).max() < 2e-3  # the midline points
    # subject's right (-X, image left when facing the camera) first
    assert f[0, 0] < f[8, 0] < f[16, 0] and f[36, 0] < f[39, 0] < 0 < f[42, 0] < f[45, 0] and f[48, 0] < f[54, 0]
    # vertical order: brows, eyes, nose tip, subnasale, upper lip, lip line, lower lip, chin
    y = f[:, 1]
    assert y[17:27].min() > y[36:48].max() > y[30] > y[33] > y[51] > y[62] >= y[66] > y[57] > y[8]
    assert y[8] == y[:17].min()  # the chin is the contour's lowest point
    assert all(y[k] > y[k + 1] for k in range(0, 8)) and all(y[k] < y[k + 1] for k in range(8, 16))
    # mouth corners on the lip line, between the lips; eye corners on the eyelids around the eyeball centre
    assert y[57] < y[48] < y[51] and abs(y[48] - y[62]) < 3e-3
    joints = wb().joints[0].numpy()
    for corners, eye in (((36, 39), "right_eye_smplhf"), ((42, 45), "left_eye_smplhf")):
        centre = joints[wb.joint_names.index(eye)]
        for c in corners:
            assert np.linalg.norm(f[c] - centre) < 0.03 and abs(f[c, 1] - centre[1]) < 0.01
        assert min(f[corners[0], 0], f[corners[1], 0]) < centre[0] < max(f[corners[0], 0], f[corners[1], 0])
        upper, lower = ((37, 38), (40, 41)) if corners[0] == 36 else ((43, 44), (46, 47))
        assert f[list(upper), 1].min() > f[list(lower), 1].max()  # lids: upper above lower
    # jaw contour on the jaw line: the lower contour follows the jaw, the upper part stays with the head
    W = wb.lbs_weights.numpy()[:, wb.joint_names.index("jaw")]
    idx = {n: i for i, n in enumerate(wb.landmark_names)}
    vid = [int(np.argmax(wb.landmark_regressor[idx[f"face_{k:02d}"]].numpy())) for k in range(68)]
    assert W[vid[8]] > 0.5 and W[vid[7]] > 0.5 and W[vid[9]] > 0.5
    assert W[vid[0]] < 0.05 and W[vid[16]] < 0.05
    assert W[vid[57]] > 0.5 and W[vid[51]] < 0.2


def test_pca_hands_span_the_hand_library():
    from silfit.synth.hands import HAND_LIBRARY, hand_axes, hand_pose_to_axis_angle

    full = load_body_model(kind="smplx", dtype=torch.float64)
    pca = load_body_model(kind="smplx", dtype=torch.float64, use_pca=True, num_pca_comps=12)
    assert pca.parameter_sizes["left_hand_pose"] == 12
    J = full().joints[0].numpy()
    comps = pca.hand_components_l.numpy()  # [12, 45], orthonormal rows
    assert np.allclose(comps @ comps.T, np.eye(12), atol=1e-5)
    axes = hand_axes(J, full.joint_names, "left")
    aa = np.stack([hand_pose_to_axis_angle(p.flex, p.spread, axes) for p in HAND_LIBRARY.values()])
    with torch.no_grad():
        a = pca(left_hand_pose=torch.as_tensor(aa @ comps.T)).vertices
        b = full(left_hand_pose=torch.as_tensor(aa)).vertices
    err = (a - b).norm(dim=-1).amax(dim=1)
    assert err.max() < 0.01, dict(zip(HAND_LIBRARY, err.tolist()))  # 12 components: every library hand within 1 cm


def test_gradcheck_through_the_open_model_float64(wb):
    g = torch.Generator().manual_seed(3)
    names = list(wb.parameter_sizes)
    inputs = tuple(
        (torch.randn(1, w, generator=g, dtype=torch.float64) * 0.2).requires_grad_()
        for w in wb.parameter_sizes.values()
    )
    probe = torch.randn(wb.num_vertices, 3, generator=g, dtype=torch.float64)

    def f(*xs):
        out = wb(**dict(zip(names, xs)))
        kp = wb.face_landmarks(out)
        return torch.stack([(out.vertices[0] * probe).sum(), out.joints[0, 25:].sum(), kp.sum()])

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, fast_mode=True)
