"""The functional SMPL core against hand-computed examples and finite differences."""

import math

import numpy as np
import pytest
import torch

from silfit.body.io import ModelArrays
from silfit.body.lbs import axis_angle_to_matrix, kinematic_levels, lbs
from silfit.body.model import BodyModel


def test_axis_angle_known_rotations():
    R = axis_angle_to_matrix(torch.tensor([[0.0, 0.0, math.pi / 2], [math.pi, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    expected = torch.tensor(
        [
            [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]],
            torch.eye(3).tolist(),
        ]
    )
    assert torch.allclose(R, expected, atol=1e-6)


@pytest.mark.parametrize("scale", [0.0, 1e-5, 1e-2, 1.0, 3.0])
def test_axis_angle_matches_matrix_exponential(scale):
    aa = torch.randn(8, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * scale
    K = torch.zeros(8, 3, 3, dtype=torch.float64)
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -aa[:, 2], aa[:, 1], -aa[:, 0]
    K = K - K.transpose(1, 2)
    assert torch.allclose(axis_angle_to_matrix(aa), torch.linalg.matrix_exp(K), atol=1e-12)


def test_axis_angle_gradcheck_including_zero():
    for aa in (torch.zeros(2, 3, dtype=torch.float64), torch.randn(4, 3, dtype=torch.float64)):
        assert torch.autograd.gradcheck(axis_angle_to_matrix, (aa.requires_grad_(),))


def test_kinematic_levels_rejects_child_before_parent():
    assert kinematic_levels([-1, 0, 0, 1]) == [[0], [1, 2], [3]]
    with pytest.raises(ValueError, match="parent"):
        kinematic_levels([-1, 2, 0])


def chain_model(dtype=torch.float64) -> BodyModel:
    """Three joints on the x axis at 0, 1, 2; one vertex rigidly on each joint, offset +y by 0.5,
    plus one vertex half on joint 1 and half on joint 2. Joints are regressed from the
    vertices (regressor picks the vertex and removes its offset via a twin vertex)."""
    verts = np.array(
        [[0, 0.5, 0], [1, 0.5, 0], [2, 0.5, 0], [1.5, 0, 0], [0, -0.5, 0], [1, -0.5, 0], [2, -0.5, 0]], float
    )
    regressor = np.zeros((3, 7))
    for j in range(3):  # mean of the +y and -y vertex of each joint = the joint
        regressor[j, j] = regressor[j, j + 4] = 0.5
    weights = np.zeros((7, 3))
    for j in range(3):
        weights[j, j] = weights[j + 4, j] = 1.0
    weights[3, 1] = weights[3, 2] = 0.5
    arrays = ModelArrays(
        v_template=verts,
        faces=np.array([[0, 1, 2]]),
        shapedirs=np.zeros((7, 3, 1)),
        posedirs=None,
        J_regressor=regressor,
        weights=weights,
        parents=(-1, 0, 1),
        joint_names=("a", "b", "c"),
    )
    return BodyModel(arrays, dtype=dtype)


def test_skinning_three_joint_chain_by_hand():
    model = chain_model()
    # Joint b turns 90 degrees about z; joint c turns a further 90 degrees about z.
    body_pose = torch.tensor([[0.0, 0.0, math.pi / 2, 0.0, 0.0, math.pi / 2]], dtype=torch.float64)
    out = model(body_pose=body_pose, transl=torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))
    # By hand: b stays at (1,0); c = b + Rz(90)(1,0) = (1,1); c's vertex offset (0,.5) is
    # turned 180 degrees: (1,1) + (0,-.5) = (1,.5). b's vertex: (1,0) + Rz90 (0,.5) = (.5,0).
    # The blended vertex (1.5,0): under b -> (1,.5); under c -> c + R180 (1.5-2, 0) = (1.5,1); mean (1.25,.75).
    expected_joints = torch.tensor([[0, 0, 1], [1, 0, 1], [1, 1, 1]], dtype=torch.float64)
    expected_verts = torch.tensor(
        [[0, 0.5, 1], [0.5, 0, 1], [1, 0.5, 1], [1.25, 0.75, 1], [0, -0.5, 1], [1.5, 0, 1], [1, 1.5, 1]],
        dtype=torch.float64,
    )
    assert torch.allclose(out.joints[0], expected_joints, atol=1e-12)
    assert torch.allclose(out.vertices[0], expected_verts, atol=1e-12)


def test_root_rotation_moves_everything_rigidly():
    model = chain_model()
    rest = model().vertices
    R = axis_angle_to_matrix(torch.tensor([0.3, -0.7, 0.2], dtype=torch.float64))
    out = model(global_orient=torch.tensor([[0.3, -0.7, 0.2]], dtype=torch.float64))
    assert torch.allclose(out.vertices[0], rest[0] @ R.T, atol=1e-12)


def test_forward_kinematics_batches_independently():
    model = chain_model()
    poses = torch.randn(4, 6, dtype=torch.float64)
    batched = model(body_pose=poses).vertices
    single = torch.cat([model(body_pose=p[None]).vertices for p in poses])
    assert torch.allclose(batched, single, atol=1e-12)


def test_pose_correctives_are_added():
    model = chain_model()
    posedirs = torch.zeros(18, 7 * 3, dtype=torch.float64)
    posedirs[0, 0] = 1.0  # first pose-feature entry moves vertex 0 in x
    model.posedirs = posedirs
    pose = torch.tensor([[0.0, 0.0, 0.5, 0.0, 0.0, 0.0]], dtype=torch.float64)
    R = axis_angle_to_matrix(pose[:, :3])[0]
    out = model(body_pose=pose)
    base = chain_model()(body_pose=pose)
    assert torch.allclose(out.vertices[0, 0, 0] - base.vertices[0, 0, 0], R[0, 0] - 1.0, atol=1e-12)


def test_lbs_float32_and_float64_agree():
    m64, m32 = chain_model(torch.float64), chain_model(torch.float32)
    pose = torch.randn(2, 6, dtype=torch.float64)
    assert torch.allclose(m64(body_pose=pose).vertices.float(), m32(body_pose=pose.float()).vertices, atol=1e-5)


def test_axis_angle_agrees_with_kornia():
    """An independent implementation (kornia) as the reference for Rodrigues' formula."""
    from kornia.geometry.conversions import axis_angle_to_rotation_matrix

    aa = torch.randn(64, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(7)) * 1.5
    assert torch.allclose(axis_angle_to_matrix(aa), axis_angle_to_rotation_matrix(aa), atol=1e-10)


def _row_alone_and_in_batches(fn, rows, dtype):
    """``fn``'s value and gradient for ``rows[0]`` computed alone, then at each position of
    batches of 2 to 8 (the other rows different each time): all must be the same bits."""
    out = []
    for B in (1, 2, 3, 8):
        for pos in sorted({0, B // 2, B - 1}):
            x = rows[1 : B + 1].clone()
            x[pos] = rows[0]
            x = x.to(dtype).requires_grad_(True)
            y = fn(x)
            w = torch.linspace(0.5, 1.5, y[0].numel(), dtype=dtype).reshape(y.shape[1:])
            (g,) = torch.autograd.grad((y[pos] * w).sum(), x)
            out.append((B, pos, y[pos].detach(), g[pos]))
    return out


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_body_does_not_depend_on_the_rest_of_its_batch(open_model, dtype):
    """Batch invariance (silfit.body.lbs): a GEMM over a batch rounds differently with its row count,
    and a fit's optimiser amplifies a last-bit difference into another fit (issue 22), so a body's
    vertices, joints and gradients are the same bits alone and anywhere in any batch."""
    from silfit.body import model_in_dtype

    model = model_in_dtype(open_model, dtype)
    gen = torch.Generator().manual_seed(3)
    V = model.num_vertices
    posedirs = 1e-3 * torch.randn(207, V * 3, generator=gen, dtype=torch.float64)  # pose correctives too
    widths = dict(betas=10, body_pose=69, global_orient=3)
    rows = torch.randn(9, sum(widths.values()), generator=gen, dtype=torch.float64) * 0.4

    def body(x):
        b, p, o = x.split(tuple(widths.values()), dim=1)
        v, j = lbs(
            b,
            torch.cat([o, p], 1),
            model.v_template,
            model.shapedirs,
            posedirs.to(dtype),
            model.J_regressor,
            model.parents,
            model.lbs_weights,
            model._levels,
        )
        return torch.cat([v, j], 1)

    runs = _row_alone_and_in_batches(body, rows, dtype)
    _, _, y0, g0 = runs[0]
    for B, pos, y, g in runs[1:]:
        assert torch.equal(y, y0) and torch.equal(g, g0), f"row at position {pos} of a batch of {B} differs"


def test_sqrt_is_the_square_root_within_two_ulp_and_keeps_zero_and_infinity():
    """silfit.body.lbs.sqrt (no MKL vector maths: the same bits on every processor) against numpy's correctly
    rounded square root, its ends and its gradient."""
    import numpy as np

    from silfit.body.lbs import sqrt

    x = torch.rand(10000, generator=torch.Generator().manual_seed(3), dtype=torch.float64) * 100
    exact = np.sqrt(x.numpy())
    assert (np.abs(sqrt(x).numpy() - exact) <= 2 * np.spacing(exact)).all()
    ends = sqrt(torch.tensor([0.0, float("inf")], dtype=torch.float64))
    assert ends[0] == 0 and torch.isinf(ends[1])
    assert torch.autograd.gradcheck(sqrt, (torch.rand(8, dtype=torch.float64) + 0.1).requires_grad_())
