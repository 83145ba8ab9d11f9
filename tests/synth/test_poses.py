"""The pose library and the samplers."""

import math

import numpy as np
import torch

from silfit.priors import within_limits
from silfit.synth import FRONTAL_POSES, POSE_LIBRARY, mirror_pose, sample_betas, sample_pose
from silfit.synth.sampler import global_orientation, place_body, sample_intrinsics

REQUIRED_KINDS = (
    "stand",
    "walk",
    "run",
    "sit",
    "squat",
    "kneel",
    "lunge",
    "reach",
    "wave",
    "point",
    "arms_crossed",
    "hands_on_hips",
    "bend",
    "throw",
    "kick",
    "jump",
    "lie",
    "t_pose",
    "a_pose",
)


def test_library_is_large_named_and_covers_the_kinds():
    assert len(POSE_LIBRARY) >= 24
    for kind in REQUIRED_KINDS:
        assert any(kind in name for name in POSE_LIBRARY), kind
    assert all(p.description for p in POSE_LIBRARY.values())
    assert len(FRONTAL_POSES) >= 5
    assert np.all(POSE_LIBRARY["t_pose"].body_pose == 0)


def test_every_library_pose_is_within_the_joint_limits():
    poses = torch.tensor(np.stack([p.body_pose for p in POSE_LIBRARY.values()]))
    ok = within_limits(poses)
    assert ok.all(), [n for n, good in zip(POSE_LIBRARY, ok) if not good]
    # Mirrored library poses too (the sampler mirrors).
    assert within_limits(torch.tensor(np.stack([mirror_pose(p.body_pose) for p in POSE_LIBRARY.values()]))).all()


def test_every_sampled_pose_is_within_the_joint_limits():
    rng = np.random.default_rng(0)
    poses = np.stack([sample_pose(rng, perturb_deg=10.0).body_pose for _ in range(500)])
    assert within_limits(torch.tensor(poses)).all()
    assert np.abs(poses).max() < math.pi


def test_mirror_is_an_involution_and_swaps_sides():
    p = POSE_LIBRARY["wave_right"].body_pose
    m = mirror_pose(p)
    assert np.allclose(mirror_pose(m), p)
    # right shoulder (joint 17 -> body_pose row 16) of the mirror = mirrored left shoulder (row 15)
    assert np.allclose(m.reshape(23, 3)[15], p.reshape(23, 3)[16] * [1, -1, -1])


def test_pose_signs_on_the_model(open_model):
    """Knee flexion moves the foot back, hip flexion the knee forward, elbow flexion the hand forward."""
    names = open_model.joint_names
    out = open_model(
        body_pose=torch.tensor(
            np.stack([POSE_LIBRARY[n].body_pose for n in ("sit_chair", "arms_crossed")]), dtype=torch.float32
        )
    )
    J = out.joints
    j = {n: i for i, n in enumerate(names)}
    sit, crossed = J[0], J[1]
    assert sit[j["left_knee"], 2] - sit[j["left_hip"], 2] > 0.3  # thigh forward (+Z)
    assert sit[j["left_ankle"], 1] < sit[j["left_knee"], 1] - 0.3  # shank down
    assert sit[j["left_wrist"], 2] > sit[j["left_elbow"], 2] + 0.05  # bent forearm points forward
    assert crossed[j["left_wrist"], 0] < crossed[j["right_wrist"], 0] + 0.1  # crossed: wrists meet or cross
    assert crossed[j["left_wrist"], 0] < crossed[j["left_elbow"], 0] - 0.1  # forearm across the body


def test_betas_truncated_and_cameras_realistic():
    rng = np.random.default_rng(1)
    b = np.stack([sample_betas(rng, 10, 2.5) for _ in range(300)])
    assert np.abs(b).max() <= 2.5 and 0.8 < b.std() < 1.1
    cam, fov = sample_intrinsics(rng, 320, 320, (45, 65))
    assert 45 <= fov <= 65 and math.isclose(2 * math.degrees(math.atan(160 / cam.fx)), fov, rel_tol=1e-9)


def test_global_orientation_convention():
    from scipy.spatial.transform import Rotation

    assert np.allclose(Rotation.from_rotvec(global_orientation(0)).as_matrix(), np.diag([1, -1, -1]), atol=1e-12)
    back = Rotation.from_rotvec(global_orientation(180)).as_matrix()
    assert np.allclose(back @ [0, 0, 1], [0, 0, 1], atol=1e-12)  # facing away from the camera
    assert np.allclose(back @ [0, 1, 0], [0, -1, 0], atol=1e-12)  # still upright


def test_place_body_fills_the_requested_share(open_model):
    rng = np.random.default_rng(2)
    cam, _ = sample_intrinsics(rng, 200, 200)
    go = torch.tensor(global_orientation(30)[None], dtype=torch.float32)
    v = open_model(global_orient=go).vertices[0].double().numpy()
    pl = place_body(rng, v, cam, fill=(0.7, 0.7), jitter=0.0)
    from silfit.camera import project_points

    uv = project_points(torch.tensor(v + pl.transl), cam).numpy()
    size = max(np.ptp(uv[:, 0]), np.ptp(uv[:, 1])) / 200
    assert abs(size - 0.7) < 0.01
    assert np.allclose((uv.min(0) + uv.max(0)) / 2, [cam.cx, cam.cy], atol=0.5)


def test_place_body_keeps_a_body_long_along_the_view_axis_in_front_of_the_camera():
    """A body lying along the view axis is short in the image and long in depth: the placement once
    put its near end behind the camera, where the projection blew up (seed 10600's subject 25, 1.75 m
    deep and 0.76 m across: a translation of 6e19 m and no visible keypoint). Its nearest vertex now
    stays 0.3 m in front, the translation is finite, and the cut body is marked truncated."""
    from silfit.camera import Camera, project_points
    from silfit.synth.sampler import _NEAREST_M

    cam = Camera(fx=420.0, fy=420.0, cx=255.5, cy=255.5, width=512, height=512)
    corners = np.array([[x, y, z] for x in (-0.2, 0.55) for y in (-0.2, 0.56) for z in (-0.79, 0.96)], dtype=np.float64)
    pl = place_body(np.random.default_rng(0), corners, cam, fill=(0.74, 0.74), jitter=0.0)
    placed = corners + pl.transl
    assert np.isfinite(pl.transl).all() and np.abs(pl.transl).max() < 10
    assert placed[:, 2].min() >= _NEAREST_M - 1e-9
    uv = project_points(torch.tensor(placed), cam).numpy()
    assert np.isfinite(uv).all() and np.abs(uv).max() < 1e4
    # held that close it does not fit the frame: marked truncated, as the generator's metadata should say
    assert pl.truncated and (uv.min() < 0 or uv.max() > 511)
