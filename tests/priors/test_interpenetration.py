import torch

from silfit.fitting.body import body_transforms
from silfit.priors import SphereCollisionModel

# Left arm swung forward and across, elbow bent: the left hand ends inside the chest.
HAND_IN_TORSO = {15: (0.0, -1.3, -0.9), 17: (0.0, -2.4, 0.0)}


def posed(model, rotations):
    p = torch.zeros(1, 69)
    for j, v in rotations.items():
        p[0, 3 * j : 3 * j + 3] = torch.tensor(v)
    return p


def penalty(col, model, body_pose, betas=None):
    betas = torch.zeros(body_pose.shape[0], 10) if betas is None else betas
    T = body_transforms(model, betas, torch.zeros(body_pose.shape[0], 3), body_pose)
    return col(betas, T)


def test_zero_for_the_t_pose_and_positive_with_the_hand_in_the_torso(body_model):
    col = SphereCollisionModel(body_model)
    assert col.num_spheres > 24 and len(col.pair_a) > 100
    zero = torch.zeros(3, 69)
    betas = torch.tensor([[0.0] * 10, [1.0] + [0.0] * 9, [-1.0] + [0.0] * 9])
    assert penalty(col, body_model, zero, betas).abs().max() == 0
    p = posed(body_model, HAND_IN_TORSO)
    assert float(penalty(col, body_model, p)) > 1e-4


def test_gradient_pushes_the_hand_out(body_model):
    col = SphereCollisionModel(body_model)
    p = posed(body_model, HAND_IN_TORSO).requires_grad_(True)
    e = penalty(col, body_model, p)
    (g,) = torch.autograd.grad(e.sum(), p)
    assert g.abs().sum() > 0
    hand = body_model.joint_names.index("left_wrist")
    chest = body_model.joint_names.index("spine3")

    def gap(pose):
        j = body_model(body_pose=pose).joints[0]
        return float((j[hand] - j[chest]).norm())

    q = p.detach()
    for _ in range(20):
        q = q.requires_grad_(True)
        (g,) = torch.autograd.grad(penalty(col, body_model, q).sum(), q)
        q = (q - 0.5 * g / g.norm().clamp(min=1e-12) * 0.05).detach()
    assert float(penalty(col, body_model, q)) < 0.5 * float(e.detach())
    assert gap(q) > gap(p.detach())
