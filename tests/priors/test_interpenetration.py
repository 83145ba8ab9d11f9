"""Interpenetration charges intersection, not contact.

Contact poses (:func:`silfit.poses.contact.contact_examples`) are built from the pose library
by :func:`silfit.poses.contact.settle_contact` (the blend from a pose where the parts are apart toward one where they intersect, stopped
where the mesh test says they touch: gap under 1.2 cm, no vertex more than 5 mm inside).
Measured on the open body model, mean shape (energy in m^2; the fitter weighs it 1e5):

| pose                            | gap cm | depth cm | old x 1e5 | new x 1e5 |
|---------------------------------|-------:|---------:|----------:|----------:|
| arms hanging against the sides  | 0.57   | 0        | 426       | 0         |
| hand resting on the head        | 0.57   | 0        | 115       | 0         |
| seated, hands on the thighs     | 0.56   | 0        | 347       | 0         |
| arms crossed, touching          | 0.02   | 0.50     | 118       | 0         |
| arms crossed through the chest  | 0.25   | 6.0      | 1737      | 21871     |
| hands clasped inside the belly  | 0.18   | 6.0      | 926       | 1892      |
| forearm through the thigh       | 0.16   | 3.4      | 634       | 130       |

(old term: the former spheres of 0.8 x the RMS slice radius; numbers from
``benchmarks/bench_interpenetration.py``.)
"""

import copy

import numpy as np
import pytest
import torch

from silfit.fitting.body import body_transforms
from silfit.poses.contact import contact_examples, intersecting_examples, part_contact, posed_vertices
from silfit.priors import SphereCollisionModel


def energy(col, model, body_pose, betas=None):
    if not torch.is_tensor(body_pose):
        body_pose = torch.as_tensor(np.asarray(body_pose), dtype=torch.float32)
    body_pose = body_pose.reshape(-1, 69)
    betas = torch.zeros(len(body_pose), 10) if betas is None else betas
    T = body_transforms(model, betas, torch.zeros(len(body_pose), 3), body_pose)
    return col(betas, T)


@pytest.fixture(scope="module")
def col(body_model):
    return SphereCollisionModel(body_model)


@pytest.fixture(scope="module")
def contacts(body_model):
    return contact_examples(body_model)


def test_zero_for_the_t_pose_for_any_shape(col, body_model):
    assert col.num_spheres > 100 and len(col.pair_a) > 5000
    betas = torch.tensor([[0.0] * 10, [2.0] + [0.0] * 9, [-2.0] + [0.0] * 9, [0.0, 2.0] + [0.0] * 8])
    assert energy(col, body_model, torch.zeros(4, 69), betas).abs().max() == 0


def test_spheres_follow_the_shape(col):
    _, r0 = col.rest_spheres(torch.zeros(1, 10))
    _, r1 = col.rest_spheres(torch.tensor([[0.0, 2.0] + [0.0] * 8]))  # beta 2: heavier on the open model
    _, r2 = col.rest_spheres(torch.tensor([[0.0, -2.0] + [0.0] * 8]))
    assert float((r1 - r0).mean()) > 0 > float((r2 - r0).mean())


def test_contact_poses_touch_on_the_mesh_and_cost_nothing(col, body_model, contacts):
    for name, (pose, pairs) in contacts.items():
        v = posed_vertices(body_model, pose)
        c = [part_contact(body_model, v, a, b) for a, b in pairs]
        assert min(x.gap for x in c) < 0.012, (name, c)  # the surfaces touch ...
        assert max(x.depth for x in c) <= 0.005, (name, c)  # ... and do not intersect
        e = float(energy(col, body_model, pose))
        assert e < 1e-5, (name, e)  # x 1e5 in the fitter: under 1 unit (the old term: 200-4000 units)


def test_intersecting_poses_cost_a_lot_and_the_gradient_separates_them(col, body_model, contacts):
    for name, (pose, pairs) in intersecting_examples().items():
        c = part_contact(body_model, posed_vertices(body_model, pose), *pairs[0])
        assert c.depth > 0.03 and c.inside > 100, (name, c)
        p = torch.as_tensor(pose, dtype=torch.float32)[None].requires_grad_(True)
        e = energy(col, body_model, p)
        assert float(e.detach()) > 5e-4, (name, float(e.detach()))  # > 50 units x 1e5
        (g,) = torch.autograd.grad(e.sum(), p)
        # Descending the energy takes the parts apart: penetration on the mesh shrinks.
        q = p.detach()
        for _ in range(10):
            q = q.requires_grad_(True)
            (g,) = torch.autograd.grad(energy(col, body_model, q).sum(), q)
            q = (q - 0.02 * g / g.norm().clamp(min=1e-12)).detach()
        assert float(energy(col, body_model, q)) < 0.5 * float(e.detach()), name
        c2 = part_contact(body_model, posed_vertices(body_model, q[0].numpy()), *pairs[0])
        assert c2.inside < c.inside, (name, c, c2)
    # Contact poses have a zero gradient: nothing pushes touching parts apart.
    for name, (pose, _) in contacts.items():
        p = torch.as_tensor(pose, dtype=torch.float32)[None].requires_grad_(True)
        e = energy(col, body_model, p)
        (g,) = torch.autograd.grad(e.sum(), p)
        assert float(g.abs().max()) < 1e-4, name


def test_gradient_matches_finite_differences(col, open_model64):
    pose = torch.as_tensor(intersecting_examples()["forearm_through_the_thigh"][0], dtype=torch.float64)[None]
    col64 = copy.deepcopy(col).double()

    def f(x):
        T = body_transforms(
            open_model64, torch.zeros(1, 10, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64), x
        )
        return col64(torch.zeros(1, 10, dtype=torch.float64), T).sum()

    x = pose.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(f(x), x)
    k = int(g.abs().argmax())
    h = 1e-5
    d = torch.zeros_like(pose)
    d[0, k] = h
    fd = (f(pose + d) - f(pose - d)) / (2 * h)
    assert abs(float(fd) - float(g[0, k])) < 1e-3 * abs(float(g[0, k])) + 1e-9


def test_sphere_set_round_trips_through_the_disk_cache_bit_for_bit(col, body_model, tmp_path, monkeypatch):
    """A process that finds the sphere set on disk (``$SILFIT_CACHE_DIR/spheres``) gets the very
    buffers a fresh build gives (so a fit is the same bits), without building; a damaged file is rebuilt."""
    from silfit.priors import interpenetration as ip

    monkeypatch.setenv("SILFIT_CACHE_DIR", str(tmp_path))
    built = copy.copy(ip._CACHE)
    monkeypatch.setattr(ip, "_CACHE", {})
    key = ip._cache_key(body_model)
    path = ip.sphere_cache_dir() / f"{ip._disk_key(key)}.npz"
    ip._save_spheres(path, built[key])
    monkeypatch.setattr(ip, "build_spheres", lambda *a, **k: pytest.fail("built although the file is there"))
    again = SphereCollisionModel(body_model)
    for name, buf in col.named_buffers():
        assert buf.dtype == getattr(again, name).dtype and torch.equal(buf, getattr(again, name)), name
    path.write_bytes(b"not a zip")
    monkeypatch.setattr(ip, "_CACHE", {})
    monkeypatch.setattr(ip, "build_spheres", lambda *a, **k: built[key])
    assert torch.equal(SphereCollisionModel(body_model).pair_mask, col.pair_mask)
    assert ip._load_spheres(path) is not None  # rewritten whole


def _dense_penalty(col, betas, T):
    """The penalty by its definition: every sphere's radius the minimum over its neighbours, every
    tested pair's overlap, all with the gradient (what the fast path must equal)."""
    c = col.centre_template + (betas[:, None, None, :] * col.centre_dirs).sum(-1)
    nv = col.neighbour_template + (betas[:, None, None, None, :] * col.neighbour_dirs).sum(-1)
    r = col.radius_scale * (((nv - c[:, :, None]) ** 2).sum(-1) + 1e-12).amin(-1).sqrt() - col.margin
    Tw = (col.sphere_weights[None, :, :, None, None] * T[:, None, :, :3, :]).sum(2)
    p = (Tw[..., :3] * c[..., None, :]).sum(-1) + Tw[..., 3]
    d = torch.linalg.vector_norm(p[:, col.pair_a] - p[:, col.pair_b], dim=-1)
    return (torch.relu(r[:, col.pair_a] + r[:, col.pair_b] - d) ** 2).sum(-1)


def test_the_fast_penalty_equals_its_definition_in_value_and_gradient(col, open_model64):
    """Only the overlapping pairs' spheres carry the gradient (and each radius only its nearest
    neighbour's): the value and the gradient in pose and shape are the dense definition's."""
    col64 = copy.deepcopy(col).double()
    g = torch.Generator().manual_seed(5)
    B = 12
    examples = intersecting_examples()
    pose = torch.cat(
        [torch.as_tensor(np.asarray(examples[n][0]), dtype=torch.float64).reshape(1, 69) for n in examples]
    )
    pose = torch.cat([pose, 0.6 * torch.randn(B - len(pose), 69, generator=g, dtype=torch.float64)])
    betas = torch.randn(B, 10, generator=g, dtype=torch.float64)
    values = []
    for fn in (col64, lambda b, T: _dense_penalty(col64, b, T)):
        x, b = pose.clone().requires_grad_(True), betas.clone().requires_grad_(True)
        T = body_transforms(open_model64, b, torch.zeros(B, 3, dtype=torch.float64), x)
        e = fn(b, T)
        values.append((e.detach(), *torch.autograd.grad(e.sum(), (x, b))))
    (e, gx, gb), (e_ref, gx_ref, gb_ref) = values
    assert int((e_ref > 0).sum()) >= len(examples)  # the intersecting examples and some random poses overlap
    # the radius's offsets (neighbour - centre) are rounded once to the model's float32 from float64: 1e-7 apart
    assert torch.allclose(e, e_ref, rtol=1e-5, atol=1e-12)
    assert torch.allclose(gx, gx_ref, rtol=0, atol=1e-5 * float(gx_ref.abs().max()))
    assert torch.allclose(gb, gb_ref, rtol=0, atol=1e-5 * float(gb_ref.abs().max()))


def test_a_rows_penalty_does_not_depend_on_the_batch(col, body_model):
    g = torch.Generator().manual_seed(6)
    B = 9
    pose, betas = 0.7 * torch.randn(B, 69, generator=g), torch.randn(B, 10, generator=g)
    T = body_transforms(body_model, betas, torch.zeros(B, 3), pose)
    together = col(betas, T)
    assert int((together > 0).sum()) >= 2
    alone = torch.cat([col(betas[i : i + 1], T[i : i + 1]) for i in range(B)])
    assert torch.equal(together, alone)
    assert torch.equal(together[3:7], col(betas[3:7], T[3:7]))


def test_the_penalty_and_its_gradient_are_the_same_bits_with_one_or_two_threads(col, body_model):
    """Enough overlapping pairs that a parallel scatter-add would split (index_put_ accumulating adds in
    parallel from 32,768 elements with more than one thread, in the order the threads come; the gathers
    are index_select). With advanced indexing 5-6 of 6 two-thread runs differed from one thread."""
    g = torch.Generator().manual_seed(7)
    B = 48
    pose, betas = 0.9 * torch.randn(B, 69, generator=g), torch.randn(B, 10, generator=g)
    T0 = body_transforms(body_model, betas, torch.zeros(B, 3), pose)
    results = []
    before = torch.get_num_threads()
    try:
        for threads in (1, 2, 2, 2, 2, 2, 2, 1):
            torch.set_num_threads(threads)
            b, T = betas.clone().requires_grad_(True), T0.clone().requires_grad_(True)
            e = col(b, T)
            results.append((e.detach(), *torch.autograd.grad((e * torch.arange(1.0, B + 1)).sum(), (b, T))))
            c, r = col.posed_spheres(b, T)
            results[-1] += torch.autograd.grad(col.penalty(c, r).sum(), (b, T))
    finally:
        torch.set_num_threads(before)
    assert int((results[0][0] > 0).sum()) >= 20
    for other in results[1:]:
        for x, y in zip(results[0], other):
            assert torch.equal(x, y)
