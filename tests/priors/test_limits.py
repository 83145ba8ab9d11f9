import math

import pytest
import torch

from silfit.body import SMPL_JOINT_NAMES, SMPL_PARENTS
from silfit.body.lbs import axis_angle_to_matrix, forward_kinematics
from silfit.priors import BODY_JOINT_NAMES, JOINT_LIMITS, clamp_to_limits, limit_bounds, limit_violation, within_limits

# A rough SMPL T-pose skeleton (metres; Y up, facing +Z, +X the body's left).
_LEFT = {
    "pelvis": (0, 0, 0),
    "left_hip": (0.06, -0.09, 0),
    "spine1": (0, 0.11, 0),
    "left_knee": (0.1, -0.47, 0),
    "spine2": (0, 0.25, 0),
    "left_ankle": (0.09, -0.87, -0.04),
    "spine3": (0, 0.31, 0),
    "left_foot": (0.11, -0.93, 0.08),
    "neck": (0, 0.52, 0),
    "left_collar": (0.08, 0.43, 0),
    "head": (0, 0.6, 0.05),
    "left_shoulder": (0.18, 0.45, 0),
    "left_elbow": (0.44, 0.45, 0),
    "left_wrist": (0.7, 0.45, 0),
    "left_hand": (0.78, 0.45, 0),
}


def _skeleton():
    pts = []
    for n in SMPL_JOINT_NAMES:
        if n in _LEFT:
            pts.append(_LEFT[n])
        else:
            x, y, z = _LEFT[n.replace("right_", "left_")]
            pts.append((-x, y, z))
    return torch.tensor(pts, dtype=torch.float64)[None]


def toy_joints(body_pose):
    full = torch.cat([torch.zeros(body_pose.shape[0], 3, dtype=body_pose.dtype), body_pose], 1)
    rest = _skeleton().expand(body_pose.shape[0], -1, -1)
    joints, _ = forward_kinematics(axis_angle_to_matrix(full.reshape(-1, 24, 3)), rest, SMPL_PARENTS)
    return joints


def pose_with(**rotations):
    p = torch.zeros(1, 69, dtype=torch.float64)
    for name, value in rotations.items():
        j = BODY_JOINT_NAMES.index(name)
        p[0, 3 * j : 3 * j + 3] = torch.tensor(value, dtype=torch.float64)
    return p


J = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}

# (joint rotated, rotation, joint that moves, axis 0/1/2, expected sign of the move) per
# anatomical motion; all these rotations must be inside the limits.
MOTIONS = [
    ("left_knee", (1.2, 0, 0), "left_ankle", 2, -1),  # knee flexion: foot backwards
    ("right_knee", (1.2, 0, 0), "right_ankle", 2, -1),
    ("left_hip", (-1.2, 0, 0), "left_knee", 2, +1),  # hip flexion: knee forward
    ("right_hip", (-1.2, 0, 0), "right_knee", 2, +1),
    ("left_hip", (0, 0, 0.8), "left_knee", 0, +1),  # abduction: knee outwards (+X for left)
    ("right_hip", (0, 0, -0.8), "right_knee", 0, -1),
    ("left_elbow", (0, -1.5, 0), "left_wrist", 2, +1),  # elbow flexion: hand forward
    ("right_elbow", (0, 1.5, 0), "right_wrist", 2, +1),
    ("left_shoulder", (0, 0, -1.3), "left_elbow", 1, -1),  # arm down by the side
    ("right_shoulder", (0, 0, 1.3), "right_elbow", 1, -1),
    ("left_shoulder", (0, 0, 1.3), "left_elbow", 1, +1),  # arm raised overhead
    ("left_shoulder", (0, -1.2, 0), "left_elbow", 2, +1),  # arm swung forward
    ("right_shoulder", (0, 1.2, 0), "right_elbow", 2, +1),
    ("spine1", (0.6, 0, 0), "neck", 2, +1),  # bending forward
    ("neck", (0.6, 0, 0), "head", 1, -1),  # nodding: the head goes down... (it sits in front)
]


@pytest.mark.parametrize("joint,rot,moving,axis,sign", MOTIONS)
def test_anatomical_signs_on_a_skeleton(joint, rot, moving, axis, sign):
    p = pose_with(**{joint: rot})
    assert bool(within_limits(p)), f"{joint} {rot} should be inside the limits"
    moved = toy_joints(p)[0, J[moving]] - toy_joints(torch.zeros_like(p))[0, J[moving]]
    assert sign * moved[axis] > 0.02


@pytest.mark.parametrize("joint,rot,moving,axis,sign", MOTIONS)
def test_anatomical_signs_on_the_open_model(body_model, joint, rot, moving, axis, sign):
    p = pose_with(**{joint: rot}).float()
    moved = body_model(body_pose=p).joints[0, J[moving]] - body_model().joints[0, J[moving]]
    assert sign * moved[axis] > 0.02


def test_layout_and_zero_pose_inside():
    assert BODY_JOINT_NAMES == SMPL_JOINT_NAMES[1:]
    assert set(JOINT_LIMITS) == set(BODY_JOINT_NAMES)
    lo, hi = limit_bounds()
    assert lo.shape == (69,) and (lo < 0).all() and (hi > 0).all()
    assert bool(within_limits(torch.zeros(69)))
    # Left/right mirror: (x, y, z) -> (x, -y, -z).
    (lx, ly, lz), (rx, ry, rz) = JOINT_LIMITS["left_elbow"], JOINT_LIMITS["right_elbow"]
    assert rx == lx and ry == (-ly[1], -ly[0]) and rz == (-lz[1], -lz[0])


PLAUSIBLE = {
    "sitting": dict(
        left_hip=(-1.6, 0, 0.1),
        right_hip=(-1.6, 0, -0.1),
        left_knee=(1.6, 0, 0),
        right_knee=(1.6, 0, 0),
        left_shoulder=(0, 0, -1.3),
        right_shoulder=(0, 0, 1.3),
    ),
    "kneeling": dict(
        left_hip=(0.1, 0, 0),
        right_hip=(-1.4, 0, 0),
        left_knee=(2.3, 0, 0),
        right_knee=(1.5, 0, 0),
        left_ankle=(0.8, 0, 0),
    ),
    "lunge": dict(left_hip=(-1.3, 0, 0), right_hip=(0.6, 0, 0), left_knee=(1.4, 0, 0), right_knee=(0.3, 0, 0)),
    "kick": dict(right_hip=(-2.0, 0.3, -0.3), right_knee=(0.2, 0, 0), spine1=(-0.3, 0, 0)),
    "throw": dict(
        right_shoulder=(0.8, 1.0, -1.2), right_elbow=(0.5, 1.6, 0), spine2=(0, 0.4, 0.1), spine3=(0, 0.4, 0.1)
    ),
    "reach_up": dict(
        left_shoulder=(0, 0, 1.7),
        right_shoulder=(0, 0, -1.7),
        left_collar=(0, 0, 0.4),
        right_collar=(0, 0, -0.4),
        spine3=(-0.3, 0, 0),
    ),
}


@pytest.mark.parametrize("name", sorted(PLAUSIBLE))
def test_plausible_poses_are_within_limits(name):
    p = pose_with(**PLAUSIBLE[name])
    assert bool(within_limits(p)) and float(limit_violation(p)) == 0.0


@pytest.mark.parametrize(
    "rot",
    [
        dict(left_knee=(-0.6, 0, 0)),
        dict(right_knee=(0, 0, 0.9)),
        dict(left_elbow=(0, 0.8, 0)),
        dict(right_elbow=(0, -0.8, 0)),
        dict(neck=(0, 2.5, 0)),
    ],
)
def test_implausible_poses_violate_and_the_gradient_pulls_back(rot):
    p = pose_with(**rot).requires_grad_(True)
    v = limit_violation(p)
    assert not bool(within_limits(p.detach())) and float(v.detach()) > 0.05
    (g,) = torch.autograd.grad(v.sum(), p)
    stepped = (p - 0.1 * g).detach()
    assert float(limit_violation(stepped)) < float(v.detach())
    clamped = clamp_to_limits(p.detach())
    assert bool(within_limits(clamped)) and float(limit_violation(clamped)) == 0.0


def test_batched_and_tolerance():
    p = torch.zeros(3, 69)
    p[1, 9] = -0.15  # left knee 0.05 past its -0.1 bound
    p[2, 9] = -1.0
    assert within_limits(p).tolist() == [True, False, False]
    assert within_limits(p, tol=0.06).tolist() == [True, True, False]
    v = limit_violation(p)
    assert v.shape == (3,) and v[0] == 0 and math.isclose(float(v[1]), 0.05**2, rel_tol=1e-3)
    assert clamp_to_limits(torch.zeros(69)).shape == (69,)
    with pytest.raises(ValueError, match="69"):
        limit_violation(torch.zeros(2, 72))
