"""silfit.fitting.branches: rotations between directions and limbs turned onto 3D points."""

import numpy as np
import torch

from silfit.fitting.body import KeypointBody
from silfit.fitting.branches import align_segments, rotation_between
from silfit.io.keypoints import BODY25_NAMES


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
    rows = {
        "betas": torch.zeros(2, 10, dtype=pose.dtype),
        "global_orient": torch.zeros(2, 3, dtype=pose.dtype),
        "transl": torch.zeros(2, 3, dtype=pose.dtype),
    }
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
    for p, d in (
        ("left_hip", "left_knee"),
        ("right_knee", "right_ankle"),
        ("left_shoulder", "left_elbow"),
        ("right_elbow", "right_wrist"),
    ):
        assert (cos(kp, target, I(p), I(d)) > 0.9999).all(), (p, d)
    lw = (I("left_elbow"), I("left_wrist"))
    assert cos(kp, target, *lw)[0] > 0.9999
    j = body_model.joint_names.index("left_elbow")
    assert torch.all(aligned[1, 3 * (j - 1) : 3 * j] == 0) and torch.any(aligned[0, 3 * (j - 1) : 3 * j] != 0)


def test_joint_hypotheses_flip_pairs_and_the_hip_keeps_the_legs(body_model):
    from silfit.fitting.branches import depth_ratios, flip_hip, joint_hypotheses

    body = KeypointBody(body_model, "body25")
    names, parents = body_model.joint_names, body_model.parents
    pose = torch.zeros(1, 69, dtype=body_model.dtype)
    for j, v in {1: (-1.2, 0, 0), 2: (-1.1, 0, 0), 4: (1.5, 0, 0), 5: (1.4, 0, 0), 3: (0.5, 0, 0)}.items():
        pose[0, 3 * (j - 1) : 3 * j] = torch.tensor(v)  # both thighs forward (toward the camera), knees bent, a lean
    rows = {
        "betas": torch.zeros(1, 10, dtype=pose.dtype),
        "body_pose": pose,
        "global_orient": torch.tensor([[np.pi, 0.0, 0.0]], dtype=pose.dtype),
        "transl": torch.tensor([[0.0, 0.2, 3.0]], dtype=pose.dtype),
    }
    ratios = depth_ratios(body, rows, names)
    hyps = {label: p for _, label, p in joint_hypotheses(body, rows, names, parents, ratios, 0.3)}
    assert "both_thighs" in hyps and "both_legs" in hyps
    with torch.no_grad():
        j0 = body(**rows).joints[0].numpy()
        j2 = body(**dict(rows, **{k: v[None] for k, v in hyps["both_thighs"].items()})).joints[0].numpy()
    for hip, knee in (("left_hip", "left_knee"), ("right_hip", "right_knee")):
        a, b = names.index(hip), names.index(knee)
        assert np.sign(j0[b, 2] - j0[a, 2]) != np.sign(
            j2[b, 2] - j2[a, 2]
        )  # each thigh now points the other way in depth
        assert (
            abs(np.linalg.norm(j2[b, :2] / j2[b, 2] - j0[b, :2] / j0[b, 2])) < 0.03
        )  # and projects about where it did
    hip = flip_hip(body, rows, names)
    with torch.no_grad():
        jh = body(**dict(rows, **hip)).joints[0].numpy()
    ankles = [names.index(n) for n in ("left_ankle", "right_ankle")]
    neck = names.index("neck")
    assert np.abs(jh[ankles] - j0[ankles]).max() < 0.05  # the legs stay (the hips only move with the pelvis' turn)
    assert np.sign(jh[neck, 2] - jh[0, 2]) != np.sign(j0[neck, 2] - j0[0, 2])  # the torso leans the other way


def test_root_turns_mirror_the_torso_yaw_and_keep_the_pelvis(body_model):
    from silfit.fitting.branches import turn_hypotheses, turn_root

    body = KeypointBody(body_model, "body25")
    names, parents = body_model.joint_names, body_model.parents
    from scipy.spatial.transform import Rotation

    yaw = 0.5  # turned 0.5 rad about the vertical (the camera frame is upside down: pi about x first)
    orient = torch.tensor((Rotation.from_rotvec([0, yaw, 0]) * Rotation.from_rotvec([np.pi, 0, 0])).as_rotvec())
    rows = {
        "betas": torch.zeros(1, 10, dtype=body_model.dtype),
        "body_pose": torch.zeros(1, 69, dtype=body_model.dtype),
        "global_orient": orient[None].to(body_model.dtype),
        "transl": torch.tensor([[0.0, 0.2, 3.0]], dtype=body_model.dtype),
    }
    with torch.no_grad():
        j0 = body(**rows).joints[0].numpy()
        jm = body(**dict(rows, **turn_root(body, rows, names, "mirror"))).joints[0].numpy()
        jt = body(**dict(rows, **turn_root(body, rows, names, 30.0))).joints[0].numpy()
    lh, r = names.index("left_hip"), names.index("right_hip")
    assert np.abs(jm[0] - j0[0]).max() < 1e-4 and np.abs(jt[0] - j0[0]).max() < 1e-4  # turned about the pelvis
    assert np.sign(jm[r, 2] - jm[lh, 2]) != np.sign(
        j0[r, 2] - j0[lh, 2]
    )  # the hips' line now points the other way in depth
    proj = lambda j, k: j[k, :2] / j[k, 2]  # noqa: E731
    assert (
        abs(np.linalg.norm(proj(jm, r) - proj(jm, lh)) - np.linalg.norm(proj(j0, r) - proj(j0, lh))) < 0.01
    )  # same width
    v0, vt = j0[r] - j0[lh], jt[r] - jt[lh]
    assert abs(np.degrees(np.arccos(v0 @ vt / np.linalg.norm(v0) / np.linalg.norm(vt))) - 30.0) < 1.0
    hyps = turn_hypotheses(body, rows, names, parents, ["mirror", 30.0])
    labels = [h[1] for h in hyps]
    assert "yaw" in labels and "turn+30" in labels and all(set(h[2]) == {"body_pose", "global_orient"} for h in hyps)


def test_a_hinge_flip_bends_the_hinge_the_natural_way_and_keeps_the_projection(body_model):
    """The forearm mirrored in depth (issue 25: a hand at the chest fitted as an arm held out to the
    camera) is reached by twisting the upper arm and flexing the elbow, not by the smallest turn at
    the elbow, which bends it sideways (the pose prior then pulls the branch back before it is scored)."""
    from scipy.spatial.transform import Rotation

    from silfit.fitting.branches import flip_segment

    body = KeypointBody(body_model, "body25")
    names, parents = body_model.joint_names, body_model.parents
    sh, el, wr = (names.index(n) for n in ("left_shoulder", "left_elbow", "left_wrist"))
    pose = torch.zeros(3, 69, dtype=body_model.dtype)
    pose[:, 3 * (sh - 1) : 3 * sh] = torch.tensor(
        [[0.3, -1.2, 0.2], [0.5, -1.0, 0.0], [-0.2, -1.4, 0.4]]
    )  # arm forward
    pose[1:, 3 * (el - 1) : 3 * el] = torch.tensor(
        [[0.0, -0.6, 0.0], [0.1, -0.3, 0.05]]
    )  # straight, bent, bent a little
    rows = {
        "betas": torch.zeros(3, 10, dtype=pose.dtype),
        "body_pose": pose,
        "global_orient": torch.tensor([[np.pi, 0.0, 0.0]] * 3, dtype=pose.dtype),
        "transl": torch.tensor([[0.0, 0.2, 3.0]] * 3, dtype=pose.dtype),
    }
    flipped = flip_segment(body, rows, "left_forearm", names, parents)
    with torch.no_grad():
        j0 = body(**rows).joints.numpy()
        j1 = body(**dict(rows, body_pose=flipped)).joints.numpy()
    assert np.abs(j1[:, [sh, el]] - j0[:, [sh, el]]).max() < 1e-5  # shoulder and elbow stay
    before, after = j0[:, wr] - j0[:, el], j1[:, wr] - j1[:, el]
    assert (np.sign(before[:, 2]) != np.sign(after[:, 2])).all()  # the forearm points the other way in depth
    assert (
        np.linalg.norm(j1[:, wr, :2] / j1[:, wr, 2:] - j0[:, wr, :2] / j0[:, wr, 2:], axis=-1).max() < 0.03
    )  # seen alike
    elbow = Rotation.from_rotvec(flipped[:, 3 * (el - 1) : 3 * el].double().numpy()).as_rotvec()
    assert (elbow[:, 1] < -0.5).all()  # the left elbow flexes: a negative turn about its Y axis (priors.limits)
    assert (np.abs(elbow[:, [0, 2]]).max(axis=1) < 0.1 * np.abs(elbow[:, 1]) + 0.1).all()  # and about little else
    sideways = flip_segment(body, rows, "left_forearm", names, parents, hinge=False)  # the smallest turn at the elbow
    turn = Rotation.from_rotvec(sideways[:, 3 * (el - 1) : 3 * el].double().numpy()).as_rotvec()
    assert not (turn[:, 1] < -0.5).all()


def test_every_hinge_flexes_its_natural_way_and_a_nearly_straight_mirror_takes_the_smallest_turn(body_model):
    """Both forearms and both shins (the flexion axes of silfit.priors.limits: left elbow -Y, right elbow
    +Y, knees +X); a segment whose mirror image lies within HINGE_MIN_BEND_DEG of its upper segment's
    line (an arm held almost in the image plane) takes the smallest turn, as the twist is ill-defined there."""
    from scipy.spatial.transform import Rotation

    from silfit.fitting.branches import flip_segment

    body = KeypointBody(body_model, "body25")
    names, parents = body_model.joint_names, body_model.parents
    cases = {  # segment: (upper joint, its rotation pointing the segment at the camera, hinge, flexion axis, sign)
        "left_forearm": ("left_shoulder", (0.3, -1.2, 0.2), "left_elbow", 1, -1.0),
        "right_forearm": ("right_shoulder", (0.3, 1.2, -0.2), "right_elbow", 1, 1.0),
        "left_shin": ("left_hip", (-1.2, 0.0, 0.1), "left_knee", 0, 1.0),
        "right_shin": ("right_hip", (-1.1, 0.0, -0.1), "right_knee", 0, 1.0),
    }
    rows = {
        "betas": torch.zeros(2, 10, dtype=body_model.dtype),
        "global_orient": torch.tensor([[np.pi, 0.0, 0.0]] * 2, dtype=body_model.dtype),
        "transl": torch.tensor([[0.0, 0.2, 3.0]] * 2, dtype=body_model.dtype),
    }
    for segment, (upper, turn, hinge, axis, sign) in cases.items():
        u, h = names.index(upper), names.index(hinge)
        pose = torch.zeros(2, 69, dtype=body_model.dtype)
        pose[:, 3 * (u - 1) : 3 * u] = torch.tensor(turn)
        pose[1, 3 * (h - 1) + axis] = sign * 0.5  # row 1 bent a little, the natural way
        flipped = flip_segment(body, dict(rows, body_pose=pose), segment, names, parents)
        bend = Rotation.from_rotvec(flipped[:, 3 * (h - 1) : 3 * h].double().numpy()).as_rotvec()
        assert (sign * bend[:, axis] > 0.5).all(), segment
        assert (np.abs(np.delete(bend, axis, axis=1)).max(axis=1) < 0.1 * np.abs(bend[:, axis]) + 0.1).all(), segment
    el = names.index("left_elbow")
    flat = torch.zeros(1, 69, dtype=body_model.dtype)
    flat[0, 3 * (names.index("left_shoulder") - 1) + 1] = -0.12  # a straight arm 7 degrees out of the image plane
    hinged = flip_segment(
        body, dict({k: v[:1] for k, v in rows.items()}, body_pose=flat), "left_forearm", names, parents
    )
    turned = flip_segment(
        body, dict({k: v[:1] for k, v in rows.items()}, body_pose=flat), "left_forearm", names, parents, hinge=False
    )
    assert torch.equal(hinged, turned) and torch.any(hinged[0, 3 * (el - 1) : 3 * el] != 0)
    toward = torch.zeros(1, 69, dtype=body_model.dtype)
    toward[0, 3 * (names.index("left_shoulder") - 1) + 1] = -1.5  # a straight arm held out to the camera: its mirror
    fold = flip_segment(
        body, dict({k: v[:1] for k, v in rows.items()}, body_pose=toward), "left_forearm", names, parents
    )
    bend = Rotation.from_rotvec(fold[0, 3 * (el - 1) : 3 * el].double().numpy()).as_rotvec()  # folds back: the elbow's
    assert (
        bend[1] < -2.0 and np.abs(bend[[0, 2]]).max() < 0.2
    )  # to make, not a sideways turn (issue 25's hand at the chest)


def test_a_hinge_flip_by_the_smallest_turn_is_its_own_hypothesis_and_names_its_segment(body_model):
    from silfit.fitting.branches import limb_hypotheses
    from silfit.fitting.plausibility import label_segments

    body = KeypointBody(body_model, "body25")
    names, parents = body_model.joint_names, body_model.parents
    pose = torch.zeros(1, 69, dtype=body_model.dtype)
    pose[0, 3 * (names.index("left_shoulder") - 1) : 3 * names.index("left_shoulder")] = torch.tensor([0.3, -1.2, 0.2])
    rows = {
        "betas": torch.zeros(1, 10, dtype=pose.dtype),
        "body_pose": pose,
        "global_orient": torch.tensor([[np.pi, 0.0, 0.0]], dtype=pose.dtype),
        "transl": torch.tensor([[0.0, 0.2, 3.0]], dtype=pose.dtype),
    }
    labels = lambda **kw: [h[1] for h in limb_hypotheses(body, rows, names, parents, **kw)]  # noqa: E731
    both, alone = labels(hinge_turns=True), labels(hinge_turns=False)
    assert "left_forearm" in alone and "left_forearm/turn" not in alone
    assert set(both) - set(alone) == {"left_forearm/turn"}
    assert label_segments("left_forearm/turn") == ["left_forearm"]
    assert label_segments("left_upper_arm+left_forearm") == ["left_upper_arm", "left_forearm"]
    assert label_segments("turn+30+left_shin") == ["facing", "left_shin"] and label_segments("yaw") == ["facing"]
    assert label_segments("keep") == []
