"""Whole-body fitting: the reduced body, part gates, terms, and recovery of a noise-free subject
with a body-only and a one-handed copy of it in the same batch."""

import numpy as np
import pytest
import torch

from silfit.body import load_body_model
from silfit.camera import Camera, project_points
from silfit.eval.score_wholebody import wholebody_errors
from silfit.fitting.body import KeypointBody
from silfit.fitting.keypoint_stage import KeypointFitConfig, KeypointFitter
from silfit.fitting.stages import gated
from silfit.fitting.terms import PriorTerm
from silfit.fitting.hands_face import part_gates
from silfit.io.keypoints import KeypointSet, model_keypoints
from silfit.poses.library import POSE_LIBRARY
from silfit.priors.smplx_priors import l2, library_hand_set, padded
from silfit.io.wholebody import part_slices
from silfit.fitting.keypoint_stage import Starts


@pytest.fixture(scope="module")
def smplx():
    return load_body_model(kind="smplx", dtype=torch.float64)


def test_reduced_body_matches_the_mesh_keypoints(smplx):
    torch.manual_seed(0)
    p = {n: 0.3 * torch.randn(2, w, dtype=torch.float64) for n, w in smplx.parameter_sizes.items()}
    body = KeypointBody(smplx, "wholebody")
    assert body.lm_pair_joint.numel() < 400  # (landmark, joint) pairs, not the landmarks' support vertices (162)
    ref = model_keypoints(smplx, smplx(**p), "wholebody")
    assert torch.allclose(body(**p).keypoints, ref, atol=1e-6)


def test_part_gates_and_gated_values():
    w = torch.zeros(2, 1, 1, 137)
    w[:, ..., :25] = 1.0
    w[0, ..., 30] = 0.5  # problem 0: one left-hand point; problem 1: body only
    w[1, ..., 100] = 1.0  # problem 1: a face point
    g = part_gates(w)
    assert g["gate_left_hand_pose"][:, 0, 0].tolist() == [1.0, 0.0]
    assert g["gate_right_hand_pose"][:, 0, 0].tolist() == [0.0, 0.0]
    assert g["gate_jaw_pose"][:, 0, 0].tolist() == g["gate_expression"][:, 0, 0].tolist() == [0.0, 1.0]
    start = {"left_hand_pose": torch.zeros(2, 1, 45)}
    new = gated({"left_hand_pose": torch.ones(2, 1, 45)}, start, g)
    assert new["left_hand_pose"][0].eq(1).all() and new["left_hand_pose"][1].eq(0).all()


def test_prior_term_over_two_parameters_and_padding():
    class Ev:
        P = 2
        params = {"a": torch.tensor([[1.0, 2.0], [0.0, 3.0]]), "b": torch.tensor([[1.0], [2.0]])}

        @staticmethod
        def per_problem(v):
            return v.reshape(2, -1).sum(1)

    term = PriorTerm("both", (l2, lambda x: 2 * x.sum(-1)), ("a", "b"))
    assert term(Ev).tolist() == [5.0 + 2.0, 9.0 + 4.0]
    seen = {}
    fn = padded(lambda x: seen.setdefault("w", x.shape[-1]) * 0 + x.sum(-1))
    assert fn(torch.ones(1, 63)).item() == 63.0 and seen["w"] == 69


def test_marginal_pose_prior_matches_the_gaussian_block(smplx):
    from silfit.priors.pose import MaxMixturePrior
    from silfit.priors.smplx_priors import marginal_mixture

    rng = np.random.default_rng(0)
    A = rng.normal(size=(2, 4, 4))
    cov = A @ A.transpose(0, 2, 1) + np.eye(4)
    prior = MaxMixturePrior(rng.normal(size=(2, 4)), cov, [0.3, 0.7], dtype=torch.float64)
    m = marginal_mixture(prior, 2)
    x = torch.tensor([[0.3, -0.2]], dtype=torch.float64)
    # by hand: min_k 0.5 d^T S_k[:2,:2]^-1 d - log w_k + 0.5 log det S_k[:2,:2], minus the smallest constant
    consts, vals = [], []
    for k, w in enumerate((0.3, 0.7)):
        S = cov[k, :2, :2]
        c = -np.log(w) + 0.5 * np.log(np.linalg.det(S))
        d = x.numpy()[0] - prior.means.numpy()[k, :2]
        consts.append(c)
        vals.append(0.5 * d @ np.linalg.inv(S) @ d + c)
    assert m(x).item() == pytest.approx(min(vals) - min(consts), rel=1e-9)


def test_hand_prior_is_zero_at_its_mean_and_a_quadratic(smplx):
    from silfit.fitting.hands_face import hand_priors

    left = hand_priors(smplx, torch.float64)[0]
    assert left(left.mean[None]).item() == pytest.approx(0.0, abs=1e-12)
    d = torch.zeros(1, 45, dtype=torch.float64)
    d[0, 3] = 0.1
    assert left(left.mean[None] + d).item() == pytest.approx(0.5 * 0.01 * left.precision[3, 3].item(), rel=1e-9)


def _subject(model):
    """Noise-free whole-body keypoints of a known body (fist + relaxed hands, an expression, the jaw open)."""
    libs = {s: library_hand_set(model, s).double() for s in ("left", "right")}
    rng = np.random.default_rng(3)
    gt = model.zero_params(1)
    gt["body_pose"] = torch.as_tensor(
        POSE_LIBRARY["wave"].body_pose[:63]
        if "wave" in POSE_LIBRARY
        else next(iter(POSE_LIBRARY.values())).body_pose[:63]
    )[None].double()
    gt["global_orient"] = torch.tensor([[np.pi, 0.25, 0.0]], dtype=torch.float64)
    gt["transl"] = torch.tensor([[0.0, 0.1, 2.6]], dtype=torch.float64)
    gt["betas"] = torch.as_tensor(rng.normal(0, 0.7, (1, model.num_betas)))
    gt["expression"] = torch.as_tensor(rng.normal(0, 0.7, (1, model.num_expression)))
    gt["jaw_pose"] = torch.tensor([[0.25, 0.0, 0.0]], dtype=torch.float64)
    gt["left_hand_pose"], gt["right_hand_pose"] = libs["left"][3:4], libs["right"][1:2]  # fist, relaxed
    out = model(**gt)
    cam = Camera.from_image_size(512, 512, 600.0)
    xy = project_points(model_keypoints(model, out, "wholebody"), cam)[0].numpy()
    return gt, out, cam, xy


def test_whole_body_recovery_body_only_and_missing_hand(smplx):
    gt, out, cam, xy = _subject(smplx)
    sl = part_slices()
    full = np.ones(137)
    body_only = full.copy()
    body_only[25:] = 0.0
    one_hand = full.copy()
    one_hand[sl["hand_left"]] = 0.0
    sets = [
        KeypointSet(xy, c, "wholebody", source=n) for n, c in (("full", full), ("body", body_only), ("one", one_hand))
    ]
    fitter = KeypointFitter(smplx, "wholebody", KeypointFitConfig(starts=Starts(poses=2)))
    r = fitter.fit(sets, cam, progress=False)
    truth = {
        "vertices": out.vertices[0].numpy(),
        "joints": out.joints[0].numpy(),
        "expression": gt["expression"][0].numpy(),
    }
    err = wholebody_errors(
        smplx, {"vertices": r.vertices[0], "joints": r.joints[0], "expression": r.extra_params["expression"][0]}, truth
    )
    # noise-free keypoints: hands and face recovered (tolerances well above what the fit reaches, far below
    # what the hands and face at rest give: hands 15-25 mm, face 4 mm)
    assert err["hand_pa_mm"] < 8.0, err
    assert err["face_pa_mm"] < 3.0, err
    assert err["pa_pve_mm"] < 30.0, err
    rest = wholebody_errors(smplx, {"vertices": r.vertices[1], "joints": r.joints[1]}, truth)
    assert rest["hand_pa_mm"] > err["hand_pa_mm"] + 4.0
    # body only: the body still fits, hands, jaw and expression exactly at rest
    assert rest["pa_pve_mm"] < 80.0, rest  # hands at rest and no face: the body alone, as a BODY_25 fit
    for n in ("left_hand_pose", "right_hand_pose", "jaw_pose", "expression"):
        assert np.all(r.extra_params[n][1] == 0.0), n
    assert float(np.median(r.reprojection_error[1:2])) < 3.0
    # a missing hand stays at rest (priors, interpenetration and the optimiser do not move it), the other fits
    assert np.all(r.extra_params["left_hand_pose"][2] == 0.0)
    assert np.abs(r.extra_params["right_hand_pose"][2]).max() > 0.05
    one = wholebody_errors(smplx, {"vertices": r.vertices[2], "joints": r.joints[2]}, truth)
    assert one["hand_right_pa_mm"] < 8.0, one


def test_silhouette_inputs_keep_body_normalisation_and_part_weights(smplx):
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig
    from silfit.fitting.hands_face import wholebody_silhouette_inputs

    conf = np.zeros(137)
    conf[:25] = 0.5  # body: sum 12.5
    conf[25:46] = 1.0  # left hand
    conf[100] = 0.25  # a face point; no right hand
    ks = KeypointSet(np.zeros((137, 2)), conf, "wholebody")
    cfg, body_sets, terms, weights, data = wholebody_silhouette_inputs(
        smplx, [ks], SilhouetteFitConfig(), torch.float64
    )
    assert np.all(body_sets[0].conf[25:] == 0) and np.all(body_sets[0].conf[:25] == 0.5)
    pw = data["part_weights"][0, 0, 0]
    assert (
        pw[30].item() == pytest.approx(1.0 / 12.5)
        and pw[100].item() == pytest.approx(0.25 / 12.5)
        and pw[:25].abs().sum() == 0
    )
    # the right hand is absent: not optimised; the left hand, jaw and expression are
    assert "right_hand_pose" not in cfg.optimise and {"left_hand_pose", "jaw_pose", "expression"} <= set(cfg.optimise)
    assert {t.name for t in terms} == {"hands", "face", "hand_pose", "jaw", "expression"} and set(weights) == {
        t.name for t in terms
    }


def test_whole_body_result_saves_and_loads_smplx_names(tmp_path, smplx):
    from silfit.fitting.result import KeypointFitResult

    z = lambda w: np.full((1, w), 0.1, np.float32)  # noqa: E731
    r = KeypointFitResult(
        betas=z(10),
        body_pose=z(63),
        global_orient=z(3),
        transl=z(3),
        cameras=[Camera.from_image_size(64, 64)],
        extra_params={"expression": z(16), "jaw_pose": z(3), "left_hand_pose": z(45)},
    )
    r.save(tmp_path)
    back = KeypointFitResult.load(tmp_path)
    assert back.body_pose.shape == (1, 63) and set(back.extra_params) == {"expression", "jaw_pose", "left_hand_pose"}
    assert np.allclose(back.params(0)["left_hand_pose"], 0.1)


def test_hand_prior_lives_in_the_pca_space_when_the_model_has_one():
    from silfit.priors.smplx_priors import HandPosePrior, library_hand_set

    pca = load_body_model(kind="smplx", dtype=torch.float64, use_pca=True, num_pca_comps=12)
    prior = HandPosePrior(pca, "right", count=200)
    assert prior.dim == 12 and "PCA" in prior.space
    lib = library_hand_set(pca, "right")
    assert lib.shape[1] == 12
    # the library's poses in PCA coefficients reproduce their axis-angle poses to the components' accuracy
    full = library_hand_set(load_body_model(kind="smplx", dtype=torch.float64), "right")
    recon = lib @ pca.hand_components_r
    assert torch.linalg.norm(recon - full, dim=1).max() < 0.25 * torch.linalg.norm(full, dim=1).max()
