"""The shipped open body model: layout, mesh, skinning, shape space and keypoints."""

import numpy as np
import torch

from silfit.body.io import OPEN_BODY_PATH, load_model_arrays
from silfit.io.keypoints import BODY25_NAMES, COCO17_NAMES, model_keypoints


def stature(vertices: torch.Tensor) -> torch.Tensor:
    return vertices[..., 1].amax(-1) - vertices[..., 1].amin(-1)


def test_layout_and_counts(open_model):
    assert open_model.num_vertices == 13348
    assert tuple(open_model.faces.shape) == (26692, 3)
    assert open_model.num_joints == 24 and open_model.num_betas == 10
    assert open_model.joint_names[0] == "pelvis" and open_model.joint_names[23] == "right_hand"
    assert open_model.posedirs is None  # zero pose correctives are dropped on load
    assert {"nose", "left_big_toe", "right_heel", "left_ear"} <= set(open_model.landmark_names)
    with np.load(OPEN_BODY_PATH, allow_pickle=False) as data:  # the file itself has SMPL's keys
        assert {"v_template", "f", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table"} <= set(
            data.files
        )


def test_zero_parameters_give_the_template(open_model):
    out = open_model()
    assert torch.allclose(out.vertices[0], open_model.v_template, atol=1e-6)


def test_joints_are_the_regressor_on_the_shaped_template(open_model64):
    betas = torch.randn(3, 10, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    out = open_model64(betas=betas)
    shaped = open_model64.v_template + torch.einsum("vcl,bl->bvc", open_model64.shapedirs, betas)
    assert torch.allclose(out.vertices, shaped, atol=1e-10)
    assert torch.allclose(out.joints, torch.einsum("jv,bvc->bjc", open_model64.J_regressor, shaped), atol=1e-10)


def test_mesh_is_watertight_and_weights_are_normalised():
    arrays = load_model_arrays()
    faces = arrays.faces
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2), f"{np.sum(counts != 2)} edges not shared by exactly two faces"
    assert np.allclose(arrays.weights.sum(1), 1.0, atol=1e-5)
    assert np.all(arrays.weights >= -1e-6)
    assert np.allclose(arrays.J_regressor.sum(1), 1.0, atol=1e-5)
    assert np.allclose(arrays.landmark_regressor.sum(1), 1.0, atol=1e-5)


def test_outward_winding(open_model64):
    """Signed volume of a closed mesh with outward-facing triangles is positive."""
    v = open_model64.v_template
    a, b, c = (v[open_model64.faces[:, i]] for i in range(3))
    volume = (a * torch.cross(b, c, dim=-1)).sum() / 6.0
    assert 0.04 < volume.item() < 0.12  # m^3: an adult body is about 0.07


def test_shape_space_gives_plausible_statures(open_model):
    betas = torch.zeros(3, 10)
    betas[0, 0], betas[2, 0] = -2.0, 2.0
    s = stature(open_model.rest_vertices(betas))
    print(f"stature at beta0 = -2, 0, +2: {s.tolist()} m")
    assert 1.60 < s[1] < 1.80
    assert s[0] < s[1] < s[2]
    assert 1.35 < s[0] and s[2] < 2.10 and (s[2] - s[0]) > 0.2


def test_rest_pose_is_a_t_pose_facing_plus_z(open_model):
    j = open_model().joints[0]
    idx = {n: i for i, n in enumerate(open_model.joint_names)}
    for side, sign in (("left", 1.0), ("right", -1.0)):
        shoulder, elbow, wrist = (j[idx[f"{side}_{n}"]] for n in ("shoulder", "elbow", "wrist"))
        arm = wrist - shoulder
        assert sign * arm[0] > 0.4  # the arm points sideways, +x is the body's left
        assert abs(arm[1]) < 0.06 and abs(arm[2]) < 0.06  # horizontal and straight
        hip, ankle = j[idx[f"{side}_hip"]], j[idx[f"{side}_ankle"]]
        assert (hip - ankle)[1] > 0.7  # legs vertical-ish


def test_body25_and_coco_keypoints_sit_where_a_person_expects(open_model):
    out = open_model()
    kp = model_keypoints(open_model, out, "body25")[0]
    assert kp.shape == (25, 3)
    k = {n: kp[i] for i, n in enumerate(BODY25_NAMES)}
    assert k["nose"][1] > k["neck"][1] > k["mid_hip"][1] > k["left_knee"][1] > k["left_ankle"][1]
    assert k["nose"][2] > k["neck"][2]  # the nose is in front of the neck (facing +z)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        assert k[f"{side}_big_toe"][2] > k[f"{side}_heel"][2] + 0.1
        assert sign * k[f"{side}_eye"][0] > 0 and sign * k[f"{side}_ear"][0] > sign * k[f"{side}_eye"][0]
        assert sign * k[f"{side}_wrist"][0] > 0.5
    coco = model_keypoints(open_model, out, "coco17", prefer_landmarks=True)[0]
    assert coco.shape == (17, 3)
    # Surface landmarks are near but not on the joint centres (within a few cm).
    joints_version = model_keypoints(open_model, out, "coco17")[0]
    gap = (coco - joints_version).norm(dim=-1)
    assert gap[COCO17_NAMES.index("nose")] == 0
    assert gap.max() < 0.08


def test_gradcheck_through_the_whole_model(open_model64):
    gen = torch.Generator().manual_seed(3)
    picks = torch.randint(0, open_model64.num_vertices, (12,), generator=gen)
    inputs = (
        (torch.randn(1, 10, generator=gen, dtype=torch.float64) * 0.5).requires_grad_(),
        (torch.randn(1, 69, generator=gen, dtype=torch.float64) * 0.3).requires_grad_(),
        torch.randn(1, 3, generator=gen, dtype=torch.float64).requires_grad_(),
        torch.randn(1, 3, generator=gen, dtype=torch.float64).requires_grad_(),
    )

    def f(betas, body_pose, global_orient, transl):
        out = open_model64(betas=betas, body_pose=body_pose, global_orient=global_orient, transl=transl)
        return torch.cat([out.vertices[0, picks].flatten(), out.joints[0].flatten()])

    # fast mode: finite differences along random input directions against the analytic Jacobian-vector
    # products (one check per input tensor instead of one backward per output: 2 s instead of 25 s)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, fast_mode=True)


def test_float32_and_float64_models_agree_for_any_batch(open_model, open_model64):
    for batch in (1, 5):
        pose = torch.randn(batch, 69, dtype=torch.float64, generator=torch.Generator().manual_seed(batch)) * 0.4
        v64 = open_model64(body_pose=pose).vertices
        v32 = open_model(body_pose=pose.float()).vertices
        assert v32.dtype == torch.float32 and v32.shape == (batch, 13348, 3)
        assert torch.allclose(v32.double(), v64, atol=1e-5)
