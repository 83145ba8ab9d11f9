"""``silfit export-model``: the open models load in the real ``smplx`` package (pinned in the test extra)
and its forward pass gives silfit's vertices, joints, extra joints and face landmarks."""

import json
import pickle

import numpy as np
import pytest
import torch

import smplx  # noqa: E402  (pinned in the test extra)
from smplx.vertex_joint_selector import VertexJointSelector  # noqa: E402

from silfit import load_body_model  # noqa: E402
from silfit.body.export_model import read_vertex_ids  # noqa: E402
from silfit.cli import main  # noqa: E402

TOL = 1e-5  # metres: 0.01 mm


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("models")
    assert main(["export-model", "smpl", str(folder)]) == 0
    assert main(["export-model", "smplx", str(folder)]) == 0
    return folder


def _random(shape, seed, scale):
    return torch.randn(*shape, dtype=torch.float64, generator=torch.Generator().manual_seed(seed)) * scale


def test_files_are_plain_arrays_in_smplx_layout(exported):
    with open(exported / "smpl" / "SMPL_NEUTRAL.pkl", "rb") as fh:
        data = pickle.load(fh)  # a dict of numpy arrays: nothing else is pickled
    assert isinstance(data, dict) and all(type(v) is np.ndarray for v in data.values())
    assert {"v_template", "f", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table"} <= set(data)
    with np.load(exported / "smplx" / "SMPLX_NEUTRAL.npz", allow_pickle=False) as npz:
        assert npz["shapedirs"].shape[-1] == 400 and npz["lmk_faces_idx"].shape == (51,)
        assert npz["dynamic_lmk_faces_idx"].shape == (79, 17) and npz["hands_componentsl"].shape == (45, 45)
    ids = read_vertex_ids(exported, "smplx")
    assert len(ids) == 21 and json.loads((exported / "smplx" / "vertex_ids.json").read_text())["vertex_ids"] == ids


def test_smpl_loads_in_smplx_and_matches_silfit(exported):
    ids = read_vertex_ids(exported, "smpl")
    theirs = smplx.create(str(exported), model_type="smpl", dtype=torch.float64, vertex_ids=ids)
    ours = load_body_model(dtype=torch.float64)
    params = dict(
        betas=_random((3, 10), 0, 1.0),
        body_pose=_random((3, 69), 1, 0.3),
        global_orient=_random((3, 3), 2, 0.5),
        transl=_random((3, 3), 3, 0.5),
    )
    a, b = theirs(**params), ours(**params)
    assert a.vertices.shape == b.vertices.shape
    assert (a.vertices - b.vertices).abs().max() < TOL
    assert (a.joints[:, :24] - b.joints).abs().max() < TOL
    extra = b.vertices[:, list(ids.values())]  # smplx's order is the selector's; ids are in that order
    assert (a.joints[:, 24:] - extra).abs().max() < TOL
    # the extra joints sit on silfit's own landmarks (the heels' within 2.5 cm: silfit's is inside the foot)
    lm = ours.landmarks(b.vertices)
    names = list(ours.landmark_names)
    for key, name in (("nose", "nose"), ("leye", "left_eye"), ("rear", "right_ear"), ("LBigToe", "left_big_toe")):
        assert (a.joints[:, 24 + list(ids).index(key)] - lm[:, names.index(name)]).norm(dim=-1).max() < 0.02


@pytest.mark.parametrize("use_pca", [True, False])
def test_smplx_loads_in_smplx_and_matches_silfit(exported, use_pca):
    ids = read_vertex_ids(exported, "smplx")
    kw = dict(use_pca=use_pca, num_pca_comps=12, flat_hand_mean=False)
    theirs = smplx.create(
        str(exported),
        model_type="smplx",
        dtype=torch.float64,
        num_expression_coeffs=16,
        use_face_contour=True,
        batch_size=2,
        **kw,
    )
    theirs.vertex_joint_selector = VertexJointSelector(vertex_ids=ids).to(torch.float64)
    ours = load_body_model(kind="smplx", dtype=torch.float64, num_expression=16, **kw)
    hand = 12 if use_pca else 45
    params = dict(
        betas=_random((2, 10), 0, 1.0),
        expression=_random((2, 16), 1, 1.0),
        body_pose=_random((2, 63), 2, 0.3),
        global_orient=_random((2, 3), 3, 0.5),
        transl=_random((2, 3), 4, 0.5),
        jaw_pose=_random((2, 3), 5, 0.2),
        leye_pose=_random((2, 3), 6, 0.1),
        reye_pose=_random((2, 3), 7, 0.1),
        left_hand_pose=_random((2, hand), 8, 0.5),
        right_hand_pose=_random((2, hand), 9, 0.5),
    )
    a, b = theirs(**params), ours(**params)
    assert (a.vertices - b.vertices).abs().max() < TOL
    assert (a.joints[:, :55] - b.joints).abs().max() < TOL
    assert (a.joints[:, 55:76] - b.vertices[:, list(ids.values())]).abs().max() < TOL
    face = ours.face_landmarks(b)  # 68 points: contour 0..16, then 17..67
    assert (a.joints[:, 76:127] - face[:, 17:]).abs().max() < TOL
    assert (a.joints[:, 127:144] - face[:, :17]).abs().max() < TOL
    assert a.joints.shape[1] == 144


def test_smplx_default_expression_count_uses_the_first_ten(exported):
    theirs = smplx.create(str(exported), model_type="smplx", dtype=torch.float64, use_pca=False)
    ours = load_body_model(kind="smplx", dtype=torch.float64, num_expression=16)
    assert theirs.num_expression_coeffs == 10
    e = _random((1, 16), 3, 1.0)
    e[:, 10:] = 0
    assert (theirs(expression=e[:, :10]).vertices - ours(expression=e).vertices).abs().max() < TOL


def test_export_model_rejects_an_unknown_kind(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["export-model", "smplh", str(tmp_path)])
    assert stop.value.code == 2 and not any(tmp_path.iterdir())


def test_a_fitted_whole_body_params_file_goes_through_smplx_as_it_is(exported, tmp_path):
    """The fit file (silfit.io.fit: every parameter ``[frames, w]``, SMPL-X names) of a whole-body fit feeds
    ``smplx.SMPLX(...)(**params)`` with no reshaping, and gives the fit's own mesh."""
    from silfit.camera import Camera
    from silfit.io.fit import write_fit

    ours = load_body_model(kind="smplx", dtype=torch.float64)
    rng = np.random.default_rng(4)
    fitted = {n: rng.normal(scale=0.2, size=(2, w)) for n, w in ours.parameter_sizes.items()}  # two frames
    fitted["transl"] = np.array([[0.0, 0.2, 3.0], [0.1, 0.2, 3.0]])
    with torch.no_grad():
        verts = ours(**{n: torch.as_tensor(v) for n, v in fitted.items()}).vertices.numpy()
    write_fit(tmp_path, fitted, [Camera.from_image_size(64, 64)], layout="wholebody", model=ours, vertices=verts)
    npz = np.load(tmp_path / "params.npz")
    names = [n for n in npz.files if n in ours.parameter_sizes]
    assert str(npz["model"]) == "smplx" and sorted(names) == sorted(ours.parameter_sizes)
    params = {n: torch.as_tensor(npz[n], dtype=torch.float64) for n in names}
    theirs = smplx.SMPLX(
        str(exported / "smplx"),
        dtype=torch.float64,
        use_pca=False,
        num_expression_coeffs=16,
        num_betas=10,
        batch_size=2,
    )
    out = theirs(**params)
    assert (out.vertices - torch.as_tensor(npz["vertices"], dtype=torch.float64)).abs().max() < 1e-4  # float32 file
    # the hands also as smplx's default PCA coefficients (all 45 components: exact)
    assert npz["left_hand_pca"].shape == (2, 45) and npz["right_hand_pca"].shape == (2, 45)
    pca = smplx.SMPLX(
        str(exported / "smplx"),
        dtype=torch.float64,
        use_pca=True,
        num_pca_comps=45,
        num_expression_coeffs=16,
        batch_size=2,
    )
    hands = {
        "left_hand_pose": torch.as_tensor(npz["left_hand_pca"], dtype=torch.float64),
        "right_hand_pose": torch.as_tensor(npz["right_hand_pca"], dtype=torch.float64),
    }
    assert (pca(**{**params, **hands}).vertices - out.vertices).abs().max() < 1e-4
