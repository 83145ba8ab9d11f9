"""The SMPL-X-layout whole-body model: official-layout files (written here), parameters, PCA hands,
face landmarks, and gradients through the whole model."""

import pickle

import numpy as np
import pytest
import torch

from silfit import load_body_model
from silfit.body.io import SMPL_PARENTS, SMPLX_JOINT_NAMES, SMPLX_PARENTS, load_model_arrays
from silfit.body.smplx import SMPLXModel, dynamic_contour_bin

V, J, F = 60, 55, 80


def official_smplx_arrays(seed=0, num_betas=300, num_expression=100, with_landmarks=True, V=V):
    """Random arrays in the official SMPL-X file layout (as SMPLX_NEUTRAL.npz holds them)."""
    rng = np.random.default_rng(seed)
    regressor = rng.random((J, V))
    regressor /= regressor.sum(1, keepdims=True)
    weights = rng.random((V, J)) ** 4
    weights /= weights.sum(1, keepdims=True)
    parents = np.array(SMPLX_PARENTS)
    arrays = {
        "v_template": rng.normal(size=(V, 3)),
        "f": rng.integers(0, V, size=(F, 3)).astype(np.int32),
        "shapedirs": rng.normal(size=(V, 3, num_betas + num_expression)) * 0.01,
        "posedirs": rng.normal(size=(V, 3, (J - 1) * 9)) * 0.01,
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": np.stack([parents.astype(np.int64) % (2**32), np.arange(J)]),
        "hands_componentsl": np.linalg.qr(rng.normal(size=(45, 45)))[0],
        "hands_componentsr": np.linalg.qr(rng.normal(size=(45, 45)))[0],
        "hands_meanl": rng.normal(size=45) * 0.1,
        "hands_meanr": rng.normal(size=45) * 0.1,
    }
    if with_landmarks:
        bary = rng.random((51, 3))
        arrays["lmk_faces_idx"] = rng.integers(0, F, 51).astype(np.int64)
        arrays["lmk_bary_coords"] = bary / bary.sum(1, keepdims=True)
        dbary = rng.random((79, 17, 3))
        arrays["dynamic_lmk_faces_idx"] = rng.integers(0, F, (79, 17)).astype(np.int64)
        arrays["dynamic_lmk_bary_coords"] = dbary / dbary.sum(-1, keepdims=True)
    return arrays


@pytest.fixture(scope="module")
def smplx_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("smplx") / "SMPLX_NEUTRAL.npz"
    np.savez(path, **official_smplx_arrays())
    return path


def test_official_npz_and_pickle_load_as_smplx(smplx_file, tmp_path):
    raw = dict(np.load(smplx_file))
    with open(tmp_path / "SMPLX_NEUTRAL.pkl", "wb") as fh:
        pickle.dump(raw, fh, protocol=2)
    a = load_body_model(smplx_file, dtype=torch.float64)
    b = load_body_model(tmp_path / "SMPLX_NEUTRAL.pkl", dtype=torch.float64)
    smpl = {k: raw[k] for k in ("v_template", "f")}  # an SMPL file beside the SMPL-X one in the same folder
    smpl.update(
        shapedirs=raw["shapedirs"][..., :10],
        J_regressor=raw["J_regressor"][:24],
        weights=np.full((V, 24), 1 / 24),
        kintree_table=np.stack([np.array(SMPL_PARENTS) % (2**32), np.arange(24)]),
    )
    np.savez(smplx_file.parent / "SMPL_NEUTRAL.npz", **smpl)
    c = load_body_model(smplx_file.parent, gender="neutral", dtype=torch.float64, kind="smplx")
    assert load_body_model(smplx_file.parent).kind == "smpl"
    assert all(isinstance(m, SMPLXModel) and m.kind == "smplx" for m in (a, b, c))
    assert a.joint_names == SMPLX_JOINT_NAMES and a.parents == SMPLX_PARENTS and a.num_joints == 55
    # official 300 + 100 space: the first 10 of each by default, as the smplx package does
    assert a.num_betas == 10 and a.num_expression == 10
    params = {k: torch.randn(2, w, dtype=torch.float64) * 0.3 for k, w in a.parameter_sizes.items()}
    assert torch.allclose(a(**params).vertices, b(**params).vertices)
    assert torch.allclose(a(**params).vertices, c(**params).vertices)


def test_shape_and_expression_parts_of_shapedirs(smplx_file, tmp_path):
    raw = np.load(smplx_file)
    m = load_body_model(smplx_file, dtype=torch.float64, num_betas=20, num_expression=5, flat_hand_mean=True)
    assert list(m.parameter_sizes.items()) == [
        ("betas", 20),
        ("expression", 5),
        ("global_orient", 3),
        ("body_pose", 63),
        ("jaw_pose", 3),
        ("leye_pose", 3),
        ("reye_pose", 3),
        ("left_hand_pose", 45),
        ("right_hand_pose", 45),
        ("transl", 3),
    ]
    assert m.parameter_names[0] == "betas" and set(m.zero_params(4)) == set(m.parameter_sizes)
    betas, expr = torch.randn(1, 20, dtype=torch.float64), torch.randn(1, 5, dtype=torch.float64)
    out = m(betas=betas, expression=expr)
    sd = torch.as_tensor(raw["shapedirs"])
    want = torch.as_tensor(raw["v_template"]) + sd[..., :20] @ betas[0] + sd[..., 300:305] @ expr[0]
    assert torch.allclose(out.vertices[0], want, atol=1e-10)
    # v1.0 files: 10 shape + 10 expression
    np.savez(tmp_path / "SMPLX_MALE.npz", **official_smplx_arrays(num_betas=10, num_expression=10))
    small = load_model_arrays(tmp_path / "SMPLX_MALE.npz")
    assert small.kind == "smplx" and small.shapedirs.shape[-1] == 10 and small.extras["exprdirs"].shape[-1] == 10


def test_zero_parameters_give_the_template_with_a_flat_hand_mean(smplx_file):
    m = load_body_model(smplx_file, dtype=torch.float64, flat_hand_mean=True)
    out = m(**m.zero_params(2))
    assert torch.allclose(out.vertices, m.v_template.expand(2, -1, -1), atol=1e-12)
    assert out.joints.shape == (2, 55, 3) and out.full_pose.shape == (2, 165)


def test_pca_hands_and_the_hand_mean(smplx_file):
    raw = np.load(smplx_file)
    pca = load_body_model(smplx_file, dtype=torch.float64, use_pca=True, num_pca_comps=6)
    full = load_body_model(smplx_file, dtype=torch.float64)
    assert pca.parameter_sizes["left_hand_pose"] == 6 and full.parameter_sizes["left_hand_pose"] == 45
    coeffs_l, coeffs_r = torch.randn(3, 6, dtype=torch.float64), torch.randn(3, 6, dtype=torch.float64)
    a = pca(left_hand_pose=coeffs_l, right_hand_pose=coeffs_r)
    aa_l = coeffs_l @ torch.as_tensor(raw["hands_componentsl"][:6])
    aa_r = coeffs_r @ torch.as_tensor(raw["hands_componentsr"][:6])
    b = full(left_hand_pose=aa_l, right_hand_pose=aa_r)  # both add the mean (flat_hand_mean=False)
    assert torch.allclose(a.vertices, b.vertices, atol=1e-10)
    assert torch.allclose(a.left_hand_pose, aa_l + torch.as_tensor(raw["hands_meanl"]))
    with pytest.raises(ValueError, match="num_pca_comps=50"):
        load_body_model(smplx_file, use_pca=True, num_pca_comps=50)


def test_face_landmarks_from_the_embedding_and_the_dynamic_contour(smplx_file):
    raw = np.load(smplx_file)
    m = load_body_model(smplx_file, dtype=torch.float64)
    out = m(jaw_pose=torch.tensor([[0.2, 0.0, 0.0]], dtype=torch.float64))
    face = m.face_landmarks(out)
    assert face.shape == (1, 68, 3)
    tri = out.vertices[0][torch.as_tensor(raw["f"][raw["lmk_faces_idx"]].astype(np.int64))]
    want = (tri * torch.as_tensor(raw["lmk_bary_coords"])[..., None]).sum(1)
    assert torch.allclose(face[0, 17:], want, atol=1e-10)
    # zero yaw: contour row 0; a head turned by +20 degrees (about Y) picks row 20, -20 picks row 59
    pose = torch.zeros(3, 165, dtype=torch.float64)
    pose[1, 15 * 3 + 1], pose[2, 15 * 3 + 1] = np.radians(-20), np.radians(20)
    rows = dynamic_contour_bin(pose).tolist()
    assert rows[0] == 0 and sorted(rows[1:]) == [20, 59]
    row0 = torch.as_tensor(raw["f"][raw["dynamic_lmk_faces_idx"][0]].astype(np.int64))
    contour = (out.vertices[0][row0] * torch.as_tensor(raw["dynamic_lmk_bary_coords"][0])[..., None]).sum(1)
    assert torch.allclose(face[0, :17], contour, atol=1e-10)


def test_hand_and_jaw_move_only_their_own_parts(smplx_file):
    m = load_body_model(smplx_file, dtype=torch.float64, flat_hand_mean=True)
    w = m.lbs_weights
    rest = m().vertices[0]
    cases = {"left_hand_pose": (25, 40), "right_hand_pose": (40, 55), "jaw_pose": (22, 23)}
    for name, (lo, hi) in cases.items():
        width = m.parameter_sizes[name]
        moved = (m(**{name: torch.full((1, width), 0.4, dtype=torch.float64)}).vertices[0] - rest).norm(dim=1) > 1e-12
        influenced = w[:, lo:hi].sum(1) > 0
        assert moved.any() and not (moved & ~influenced).any(), name


def test_gradcheck_through_the_whole_model_float64(smplx_file):
    m = load_body_model(smplx_file, dtype=torch.float64, num_betas=4, num_expression=3, use_pca=True, num_pca_comps=4)
    g = torch.Generator().manual_seed(0)
    names = list(m.parameter_sizes)
    inputs = tuple(
        (torch.randn(1, w, generator=g, dtype=torch.float64) * 0.3).requires_grad_() for w in m.parameter_sizes.values()
    )
    probe = torch.randn(V, 3, generator=g, dtype=torch.float64)

    def f(*xs):
        out = m(**dict(zip(names, xs)))
        return torch.stack(
            [(out.vertices[0] * probe).sum(), out.joints[0, 30:40].sum(), m.face_landmarks(out)[0, 20:].sum()]
        )

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, fast_mode=True)


def test_bad_smplx_files_fail_clearly(tmp_path):
    arrays = official_smplx_arrays()
    arrays["hands_componentsl"] = arrays["hands_componentsl"][:, :40]
    np.savez(tmp_path / "a.npz", **arrays)
    with pytest.raises(ValueError, match=r"a.npz: field 'hands_componentsl' has shape \(45, 40\), expected \?x45"):
        load_body_model(tmp_path / "a.npz")
    arrays = official_smplx_arrays()
    arrays["lmk_faces_idx"][0] = F + 5
    np.savez(tmp_path / "b.npz", **arrays)
    with pytest.raises(ValueError, match="b.npz: field 'lmk_faces_idx' indexes triangles outside"):
        load_body_model(tmp_path / "b.npz")
    arrays = official_smplx_arrays()
    del arrays["hands_componentsl"], arrays["hands_componentsr"]
    np.savez(tmp_path / "c.npz", **arrays)
    with pytest.raises(ValueError, match="use_pca needs a hand PCA"):
        load_body_model(tmp_path / "c.npz", use_pca=True)
    with pytest.raises(ValueError, match="SMPLX-layout model file, not SMPL"):
        load_body_model(tmp_path / "c.npz", kind="smpl")
    with pytest.raises(ValueError, match="apply to SMPL-X models only"):
        load_body_model(None, use_pca=True)


def test_whole_body_keypoints_of_an_official_topology_file(tmp_path):
    """On SMPL-X's own mesh (10475 vertices) the fingertips and BODY_25 extras are the smplx package's
    vertex ids and the face comes from the landmark embedding with its dynamic contour."""
    from silfit.body.io import SMPLX_LANDMARK_VERTICES
    from silfit.io.wholebody import wholebody_keypoints

    arrays = official_smplx_arrays(num_betas=10, num_expression=10, V=10475)
    del arrays["posedirs"]  # 10475 x 3 x 486 random numbers would only slow the test down
    np.savez(tmp_path / "SMPLX_FEMALE.npz", **arrays)
    m = load_body_model(tmp_path, gender="female", dtype=torch.float64)
    out = m(body_pose=torch.randn(1, 63, dtype=torch.float64) * 0.2)
    kp = wholebody_keypoints(m, out)
    v = out.vertices[0]
    assert torch.equal(kp["hand_left"][0, 4], v[SMPLX_LANDMARK_VERTICES["left_thumb_tip"]])
    assert torch.equal(kp["hand_right"][0, 20], v[SMPLX_LANDMARK_VERTICES["right_pinky_tip"]])
    assert torch.equal(kp["body"][0, 0], v[SMPLX_LANDMARK_VERTICES["nose"]])
    assert torch.allclose(kp["face"][0, :68], m.face_landmarks(out)[0])
