"""Loading body-model files in the official SMPL layouts, and clear errors for bad ones."""

import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse
import torch

from silfit import load_body_model
from silfit.body.io import load_model_arrays

V, J = 30, 24


def official_arrays(seed=0, num_betas=10):
    rng = np.random.default_rng(seed)
    regressor = rng.random((J, V))
    regressor /= regressor.sum(1, keepdims=True)
    weights = rng.random((V, J))
    weights /= weights.sum(1, keepdims=True)
    parents = np.array([-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21])
    kintree = np.stack([parents.astype(np.int64) % (2**32), np.arange(J)])  # the root as 2**32 - 1, as SMPL stores it
    return {
        "v_template": rng.normal(size=(V, 3)),
        "f": rng.integers(0, V, size=(40, 3)).astype(np.uint32),
        "shapedirs": rng.normal(size=(V, 3, num_betas)) * 0.01,
        "posedirs": rng.normal(size=(V, 3, 207)) * 0.01,
        "J_regressor": regressor,
        "weights": weights,
        "kintree_table": kintree,
    }


class _FakeCh:
    """Pickles under chumpy's module path the way chumpy's Ch objects are pickled (state 'x')."""

    def __init__(self, x):
        self.x = x


def write_chumpy_pickle(path, arrays):
    fake = types.ModuleType("chumpy.ch")
    _FakeCh.__module__, _FakeCh.__qualname__ = "chumpy.ch", "Ch"
    fake.Ch = _FakeCh
    saved = {k: sys.modules.get(k) for k in ("chumpy", "chumpy.ch")}
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = types.ModuleType("chumpy"), fake
    try:
        data = dict(arrays)
        data["shapedirs"] = _FakeCh(arrays["shapedirs"])
        data["J_regressor"] = scipy.sparse.csc_matrix(arrays["J_regressor"])
        data["bs_style"], data["bs_type"] = "lbs", "lrotmin"
        with open(path, "wb") as fh:
            pickle.dump(data, fh, protocol=2)
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
    assert "chumpy" not in sys.modules


def test_npz_and_chumpy_pickle_load_to_the_same_model(tmp_path):
    arrays = official_arrays()
    np.savez(tmp_path / "SMPL_NEUTRAL.npz", **arrays)
    write_chumpy_pickle(tmp_path / "model.pkl", arrays)
    from_npz = load_body_model(tmp_path / "SMPL_NEUTRAL.npz", dtype=torch.float64)
    from_pkl = load_body_model(tmp_path / "model.pkl", dtype=torch.float64)
    from_dir = load_body_model(tmp_path, gender="neutral", dtype=torch.float64)
    pose = torch.randn(3, 69, dtype=torch.float64) * 0.3
    betas = torch.randn(3, 10, dtype=torch.float64)
    a, b, c = (m(betas=betas, body_pose=pose) for m in (from_npz, from_pkl, from_dir))
    assert torch.allclose(a.vertices, b.vertices) and torch.allclose(a.vertices, c.vertices)
    assert from_pkl.parents[0] == -1 and from_pkl.num_betas == 10
    assert from_pkl.posedirs is not None  # non-zero correctives are kept
    assert from_pkl.joint_names[0] == "pelvis"
    assert torch.equal(from_pkl.faces, torch.as_tensor(arrays["f"].astype(np.int64)))


def test_official_topology_gets_the_fields_extra_keypoints(tmp_path):
    arrays = official_arrays()
    rng = np.random.default_rng(1)
    arrays["v_template"] = rng.normal(size=(6890, 3))
    arrays["shapedirs"] = np.zeros((6890, 3, 10))
    arrays["posedirs"] = np.zeros((6890, 3, 207))
    arrays["J_regressor"] = np.full((J, 6890), 1.0 / 6890)
    arrays["weights"] = np.full((6890, J), 1.0 / J)
    np.savez(tmp_path / "SMPL_MALE.npz", **arrays)
    model = load_body_model(tmp_path, gender="male")
    assert model.posedirs is None  # all-zero correctives are dropped
    nose = model.landmarks(model().vertices)[0, model.landmark_names.index("nose")]
    assert torch.allclose(nose, torch.as_tensor(arrays["v_template"][332], dtype=torch.float32))


def test_more_than_ten_shape_directions(tmp_path):
    np.savez(tmp_path / "m.npz", **official_arrays(num_betas=300))
    model = load_body_model(tmp_path / "m.npz")
    assert model.num_betas == 300
    assert model(betas=torch.zeros(2, 10)).vertices.shape == (2, V, 3)  # fewer betas are fine
    with pytest.raises(ValueError, match="betas"):
        model(betas=torch.zeros(1, 301))


def test_missing_file_and_folder_name_the_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.pkl"):
        load_body_model(tmp_path / "nothere.pkl")
    with pytest.raises(FileNotFoundError, match="SMPL_FEMALE.pkl"):
        load_body_model(tmp_path, gender="female")
    with pytest.raises(ValueError, match="gender"):
        load_body_model(tmp_path, gender="other")


def test_missing_key_and_wrong_shape_name_the_field(tmp_path):
    arrays = official_arrays()
    del arrays["weights"]
    np.savez(tmp_path / "a.npz", **arrays)
    with pytest.raises(ValueError, match=r"a\.npz.*weights"):
        load_model_arrays(tmp_path / "a.npz")
    arrays = official_arrays()
    arrays["shapedirs"] = arrays["shapedirs"][:5]
    np.savez(tmp_path / "b.npz", **arrays)
    with pytest.raises(ValueError, match=r"b\.npz.*'shapedirs'.*shape"):
        load_model_arrays(tmp_path / "b.npz")
    (tmp_path / "c.txt").write_text("x")
    with pytest.raises(ValueError, match="c.txt"):
        load_model_arrays(tmp_path / "c.txt")
    (tmp_path / "d.pkl").write_bytes(b"not a pickle")
    with pytest.raises(ValueError, match="d.pkl"):
        load_model_arrays(tmp_path / "d.pkl")


def test_smplx_like_file_loads_its_body_generically(tmp_path):
    """An SMPL-X-like file (55 joints) loads with the same code: pose sizes follow the tree."""
    rng = np.random.default_rng(2)
    nj = 55
    parents = np.concatenate([[-1], rng.integers(0, np.arange(1, nj))])
    arrays = official_arrays()
    arrays.update(
        J_regressor=np.full((nj, V), 1.0 / V),
        weights=np.full((V, nj), 1.0 / nj),
        kintree_table=np.stack([parents, np.arange(nj)]),
        posedirs=np.zeros((V, 3, (nj - 1) * 9)),
    )
    np.savez(tmp_path / "SMPLX_NEUTRAL.npz", **arrays)
    model = load_body_model(tmp_path / "SMPLX_NEUTRAL.npz")
    assert model.num_joints == 55 and model.num_body_pose == 54 * 3
    assert model(body_pose=torch.zeros(1, 162)).joints.shape == (1, 55, 3)
    with pytest.raises(ValueError, match="body_pose"):
        model(body_pose=torch.zeros(1, 69))


def test_parameter_shape_errors_name_the_argument(tmp_path):
    np.savez(tmp_path / "m.npz", **official_arrays())
    model = load_body_model(tmp_path / "m.npz")
    with pytest.raises(ValueError, match="body_pose"):
        model(body_pose=torch.zeros(1, 72))
    with pytest.raises(ValueError, match="batch size"):
        model(betas=torch.zeros(2, 10), transl=torch.zeros(3, 3))
    with pytest.raises(ValueError, match="global_orient"):
        model(global_orient=torch.zeros(1, 4))
