"""Distance-transform silhouette energy and IoU."""

import numpy as np
import pytest
import torch

from silfit.silhouette import MaskTarget, distance_transforms, silhouette_energy, soft_iou
from silfit.fitting.silhouette_stage import MaskHandling


def disc(size=64, centre=(32, 32), radius=12):
    yy, xx = np.mgrid[:size, :size]
    return (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius**2


def test_distance_transforms_are_exact_euclidean():
    mask = np.zeros((40, 40), bool)
    mask[20, 20] = True
    out, inside = distance_transforms(mask)
    assert out[20, 20] == 0 and abs(out[23, 24] - 5.0) < 1e-3 and abs(out[0, 0] - np.hypot(20, 20)) < 1e-3
    assert inside[20, 20] == 1.0 and inside[0, 0] == 0


def test_energy_is_zero_at_the_mask_and_positive_elsewhere():
    mask = disc()
    target = MaskTarget.from_mask(mask)
    exact = torch.as_tensor(mask, dtype=torch.float32)
    assert silhouette_energy(exact, target).item() == 0.0
    shifted = torch.as_tensor(disc(centre=(36, 32)), dtype=torch.float32)
    assert silhouette_energy(shifted, target).item() > 0.1
    assert soft_iou(exact, target.mask).item() == 1.0


def test_gradient_moves_a_shifted_blob_toward_the_mask():
    """A soft disc parameterised by its centre: gradient descent on x moves it onto the mask."""
    target = MaskTarget.from_mask(disc(centre=(30, 32)))
    yy, xx = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    cx = torch.tensor(38.0, requires_grad=True)
    opt = torch.optim.Adam([cx], lr=0.5)
    for _ in range(60):
        sil = torch.sigmoid(12.0 - torch.sqrt((xx - cx) ** 2 + (yy - 32.0) ** 2 + 1e-6))
        loss = silhouette_energy(sil, target)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert abs(cx.item() - 30.0) < 1.0


def test_contour_points_lie_on_the_outline_evenly():
    from silfit.silhouette import contour_points

    mask = disc()
    pts = contour_points(mask, 40)
    assert pts.shape == (40, 2)
    r = np.hypot(pts[:, 0] - 32, pts[:, 1] - 32)
    assert np.all(np.abs(r - 12) < 1.0)  # outline pixels of a radius-12 disc
    angles = np.sort(np.arctan2(pts[:, 1] - 32, pts[:, 0] - 32))
    assert np.diff(angles).max() < 2.5 * (2 * np.pi / 40)  # spread around, not bunched
    assert len(contour_points(mask, 10_000)) < 200  # never more than the outline has
    assert np.array_equal(contour_points(mask, 40), pts)


def test_contour_energies_are_zero_on_a_match_and_pull_toward_the_mask():
    from silfit.silhouette import contour_points, cover_energy, outside_distance_energy

    mask = disc()
    target = MaskTarget.from_mask(mask)
    outline = torch.as_tensor(contour_points(mask, 64))
    inside = torch.tensor([[32.0, 32.0], [30.0, 35.0]])
    assert outside_distance_energy(inside, target.dt_out).item() == 0.0
    assert cover_energy(outline.clone(), outline).item() == 0.0
    # points shifted right by 5 px: the gradients of both terms point left (back onto the mask)
    uv = (outline + torch.tensor([5.0, 0.0])).requires_grad_(True)
    for energy in (outside_distance_energy(uv, target.dt_out), cover_energy(uv, outline)):
        (g,) = torch.autograd.grad(energy, uv)
        assert energy.item() > 0 and g[:, 0].sum() > 0 and abs(g[:, 1].sum()) < 0.2 * g[:, 0].sum()
    # a point outside the image costs its distance to the image on top of the border's value
    far = outside_distance_energy(torch.tensor([[-10.0, 32.0]]), target.dt_out).sqrt().item()
    assert abs(far - (float(target.dt_out[32, 0]) + 10.0)) < 1e-5


def test_cover_energy_pairs_each_outline_point_with_its_exactly_nearest_point(monkeypatch):
    """The cover term's nearest points (a k-d tree in float64) are the exact nearest ones, where the
    float32 product over all pairs (the path before issue 24's sampling part, kept for points that
    are not finite) rounds near ties at window coordinates; both give the same energy on separated points."""
    from silfit.silhouette import cover_energy, losses

    rng = np.random.default_rng(3)
    u = torch.as_tensor(rng.uniform(0, 512, (2000, 2)), dtype=torch.float32)
    pts = torch.as_tensor(rng.uniform(0, 512, (256, 2)), dtype=torch.float32)
    d = ((pts.double()[:, None] - u.double()[None]) ** 2).sum(-1)  # exact (float64) squared distances
    got = losses._nearest(u, pts)
    assert torch.equal(d[torch.arange(256), got], d.min(1).values)
    # two points 0.004 px apart at x ~ 500: the product's float32 sum cannot tell them apart, the tree can
    near = torch.tensor([[500.0, 300.0], [500.004, 300.0]])
    q = torch.tensor([[500.003, 300.0]])
    assert int(losses._nearest(near, q)[0]) == 1
    monkeypatch.setattr(losses, "NEAREST_BY_TREE", False)
    assert int(losses._nearest(near, q)[0]) == 0  # the product's choice: the farther point
    monkeypatch.setattr(losses, "NEAREST_BY_TREE", True)
    # a point of either side that is not finite: the product's choice, no error
    bad = torch.cat([u[:5], torch.tensor([[float("inf"), 0.0]])])
    assert losses._nearest(bad, pts[:3]).shape == (3,)
    assert losses._nearest(u[:5], torch.tensor([[float("nan"), 1.0]])).shape == (1,)
    # on separated points both paths give the same energy
    grid = torch.stack(torch.meshgrid(torch.arange(0.0, 64, 8), torch.arange(0.0, 64, 8), indexing="ij"), -1).reshape(
        -1, 2
    )
    outline = grid[::3] + 0.7
    tree = cover_energy(grid, outline)
    monkeypatch.setattr(losses, "NEAREST_BY_TREE", False)
    assert float(cover_energy(grid, outline)) == float(tree)


def test_outside_the_image_is_unknown_not_background():
    """Truncation (issue 23): a mask cut by the image's border. Beyond the border a body costs nothing,
    the cut is not an outline, and the distance inside the mask is to the visible background only."""
    from silfit.silhouette.losses import contour_points, distance_transforms

    valid = np.zeros((40, 30), bool)
    valid[:30] = True  # rows 30.. lie below the image
    mask = np.zeros((40, 30), bool)
    mask[10:30, 10:20] = True  # the person runs out of the image at its bottom
    dt_out, dt_in = distance_transforms(mask, valid)
    plain_out, plain_in = distance_transforms(mask)
    assert (dt_out[30:] == 0).all() and plain_out[35, 15] > 0  # a leg below the border: free with valid
    assert dt_in[29, 15] > plain_in[29, 15] and dt_in[29, 15] == pytest.approx(
        5.0
    )  # the sides are the edge, not the cut
    pts = contour_points(mask, 500, valid)
    bottom = (pts[:, 1] >= 27) & (pts[:, 0] > 10) & (pts[:, 0] < 19)
    assert len(pts) and pts[:, 1].max() < 29 and not bottom.any()  # the sides only: no outline along the cut
    assert contour_points(mask, 500)[:, 1].max() >= 29
    body = torch.zeros(40, 30)
    body[10:40, 10:20] = 1.0  # the true body continues below the image
    assert (
        soft_iou(body, torch.as_tensor(mask, dtype=torch.float32), torch.as_tensor(valid, dtype=torch.float32)) == 1.0
    )
    assert soft_iou(body, torch.as_tensor(mask, dtype=torch.float32)) < 0.7


def test_cover_profile_is_shallow_within_the_margin_and_capped():
    from silfit.silhouette import CoverProfile

    p = CoverProfile(margin=4.0, inner=0.25, cap=6.0)
    d = np.array([0.0, 2.0, 4.0, 5.0, 20.0])
    assert np.allclose(p(d), [0.0, 0.5, 1.0, 2.0, 6.0])
    assert torch.allclose(p(torch.as_tensor(d)), torch.as_tensor([0.0, 0.5, 1.0, 2.0, 6.0], dtype=torch.float64))
    assert CoverProfile().plain and not p.plain
    with pytest.raises(ValueError, match="CoverProfile"):
        CoverProfile(inner=2.0)


def test_a_grown_mask_pulls_the_body_outward_less_with_the_robust_profile():
    """Clothing (issue 23): the mask is the body grown by 3 px. Growing the body to fill it lowers the
    plain energy by much; with the robust profile (margin 4 px, inner 0.25) by a quarter as much
    at most, while a body outside the mask still costs the same."""
    from silfit.silhouette import CoverProfile

    mask = disc(radius=15)
    plain, robust = MaskTarget.from_mask(mask), MaskTarget.from_mask(mask, cover=CoverProfile(4.0, 0.25, 8.0))
    assert robust.w_in is not None and (robust.w_in <= robust.dt_in + 1e-6).all() and robust.w_in.max() <= 8.0
    body = torch.as_tensor(disc(radius=12), dtype=torch.float32)
    full = torch.as_tensor(mask, dtype=torch.float32)
    gain_plain = (silhouette_energy(body, plain) - silhouette_energy(full, plain)).item()
    gain_robust = (silhouette_energy(body, robust) - silhouette_energy(full, robust)).item()
    assert gain_plain > 0.5 and 0 < gain_robust <= 0.26 * gain_plain
    too_big = torch.as_tensor(disc(radius=18), dtype=torch.float32)
    assert silhouette_energy(too_big, robust).item() == pytest.approx(silhouette_energy(too_big, plain).item())


def test_robust_cover_energy_ignores_an_outline_far_from_the_body():
    """Contour level: outline points beyond the cap (a leak, an object) exert no pull; near ones do."""
    from silfit.silhouette import CoverProfile, cover_energy

    uv = torch.tensor([[10.0, 10.0], [12.0, 10.0]], requires_grad=True)
    far = torch.tensor([[60.0, 10.0]])
    near = torch.tensor([[15.0, 10.0]])
    profile = CoverProfile(margin=1.0, inner=0.5, cap=10.0)
    cover_energy(uv, far, profile).backward()
    assert uv.grad.abs().max() == 0
    uv.grad = None
    cover_energy(uv, far).backward()
    assert uv.grad.abs().max() > 0  # the plain energy pulls toward the far outline
    uv.grad = None
    cover_energy(uv, near, profile).backward()
    assert uv.grad[1, 0] > 0 or uv.grad[1, 0] < 0


def test_clothing_thickness_tells_a_grown_mask_from_a_leak_and_trim_undoes_it():
    """A mask grown all around (clothing) is thick by the growth; a blob joined on one side (a
    leak) or a matching mask is not; trimming the grown mask by its thickness gives the body back."""
    import cv2

    from silfit.silhouette import clothing_thickness, trim_clothing

    body = np.zeros((120, 100), bool)
    body[20:100, 40:60] = True  # a torso
    body[30:36, 20:80] = True  # arms
    grown = cv2.dilate(body.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9))).astype(bool)
    leak = body.copy()
    leak[50:70, 60:95] = True
    assert clothing_thickness(body, body) == pytest.approx(0.0, abs=0.5)
    assert clothing_thickness(grown, body) == pytest.approx(4.0, abs=1.0)
    assert clothing_thickness(leak, body) < 1.0
    both = clothing_thickness(leak, body, (0.25, 0.9))  # several quantiles in one pass: a tuple
    assert both == (clothing_thickness(leak, body, 0.25), clothing_thickness(leak, body, 0.9)) and both[1] > 5.0
    assert clothing_thickness(leak, np.zeros_like(body), (0.25, 0.5)) == (0.0, 0.0)
    trimmed = trim_clothing(grown, clothing_thickness(grown, body))
    iou = (trimmed & body).sum() / (trimmed | body).sum()
    assert iou > 0.85 and (trimmed & body).sum() / (grown & body).sum() > 0.85
    cut = grown.copy()
    cut[90:] = True  # runs out of the image at the bottom: the border is no edge
    assert trim_clothing(cut, 4)[-1].sum() > 0.9 * cut[-1].sum()
    assert trim_clothing(body, 0).sum() == body.sum()


def test_the_stage_builds_robust_targets_and_the_plain_energy_stays_available():
    from silfit.fitting.silhouette_stage import SilhouetteFitConfig, choose_window, window_target
    from silfit.camera import Camera

    mask = disc(size=96, centre=(48, 48), radius=20)
    cam = Camera(100.0, 100.0, 47.5, 47.5, 96, 96)
    uv = np.argwhere(mask)[:, ::-1].astype(float)
    window = choose_window(mask, uv, cam, 64, 0.12)
    cfg = SilhouetteFitConfig()
    robust, _ = window_target(mask, window, cover=cfg.cover_profile(64))
    plain, _ = window_target(
        mask, window, cover=SilhouetteFitConfig(mask=MaskHandling(robust_cover=False)).cover_profile(64)
    )
    assert robust.cover is not None and robust.cover.margin == pytest.approx(cfg.mask.cover_margin * 64)
    assert cfg.cover_profile(64).inner == cfg.mask.cover_inner and cfg.cover_profile(64, 1.0).inner == 1.0
    assert plain.cover is None and plain.w_in is None
    assert (robust.w_in <= plain.dt_in + 1e-6).all() and robust.w_in.sum() < 0.7 * plain.dt_in.sum()


def test_leaks_far_from_the_body_and_small_holes_are_unknown():
    from silfit.silhouette.losses import unknown_regions

    body = disc(size=96, centre=(48, 48), radius=20)
    mask = body.copy()
    mask[44:52, 60:90] = True  # a leak running far from the body
    mask[46:49, 46:49] = False  # a small hole
    gap = np.zeros_like(mask)
    gap[30:66, 40:43] = True  # a large hole: a real gap between limbs
    mask &= ~gap
    known = unknown_regions(mask, body, far=5.0, hole_fraction=0.02)
    assert known is not None
    assert not known[48, 85] and known[48, 62]  # far along the leak unknown, near the body kept
    assert not known[47, 47]  # the small hole unknown
    assert known[gap].all()  # the large one stays background
    assert known[body & mask].all()
    assert unknown_regions(body, body, far=5.0, hole_fraction=0.02) is None
    assert unknown_regions(mask, body, far=0.0, hole_fraction=0.0) is None


def test_a_small_hole_the_body_leaves_open_is_background():
    """``hole_covered`` (issue 55, the demo's IoU): a small hole of the mask is unknown (a gap in the segmentation)
    only where the keypoint fit's body covers that share of it; one it leaves open (a clean render's gap between an
    arm and the torso) stays background; 0: every small hole unknown."""
    from silfit.silhouette.losses import unknown_regions

    body = disc(size=96, centre=(48, 48), radius=20)
    mask = body.copy()
    mask[46:49, 46:49] = False  # a hole inside the body: a segmentation gap
    body_open = body.copy()
    body_open[44:53, 44:53] = False  # the body leaves the same place open: a real gap
    known = unknown_regions(mask, body, far=0.0, hole_fraction=0.02, hole_covered=0.5)
    assert known is not None and not known[47, 47] and known[body & mask].all()
    assert unknown_regions(mask, body_open, far=0.0, hole_fraction=0.02, hole_covered=0.5) is None
    assert not unknown_regions(mask, body_open, far=0.0, hole_fraction=0.02)[47, 47]  # 0: every small hole


def test_unknown_pixels_cost_nothing_and_pull_nothing():
    from silfit.fitting.silhouette_stage import choose_window, window_target
    from silfit.camera import Camera

    body = disc(size=96, centre=(48, 48), radius=20)
    mask = body.copy()
    mask[44:52, 60:90] = True
    known = np.ones_like(mask)
    known[:, 75:] = False
    cam = Camera(100.0, 100.0, 47.5, 47.5, 96, 96)
    uv = np.argwhere(mask)[:, ::-1].astype(float)
    window = choose_window(mask, uv, cam, 96, 0.12)
    with_leak, _ = window_target(mask, window)
    trusted, _ = window_target(mask, window, known=known)
    assert trusted.valid is not None and trusted.mask.sum() < with_leak.mask.sum()
    sil_body, _ = window_target(body, window)
    e_leak = silhouette_energy(sil_body.mask, with_leak).item()
    e_trusted = silhouette_energy(sil_body.mask, trusted).item()
    assert e_trusted < 0.5 * e_leak  # the far part of the leak no longer pulls
    # a body over unknown pixels costs nothing there
    over = sil_body.mask.clone()
    over[(trusted.valid < 0.5)] = 1.0
    assert silhouette_energy(over, trusted).item() == pytest.approx(e_trusted, abs=1e-5)


def test_unknown_pixels_do_not_switch_truncation_on():
    # a person at the image's left edge: with truncation_aware=False the pixels beyond the image stay
    # background (valid) whether or not some of the image's pixels are unknown
    from silfit.camera import Camera
    from silfit.fitting.silhouette_stage import choose_window, window_target

    body = disc(size=96, centre=(10, 48), radius=20)
    known = np.ones_like(body)
    known[40:56, 16:28] = False  # inside the window
    cam = Camera(100.0, 100.0, 47.5, 47.5, 96, 96)
    window = choose_window(body, np.argwhere(body)[:, ::-1].astype(float), cam, 96, 0.12)
    aware, _ = window_target(body, window)
    assert aware.valid is not None and (aware.valid < 0.5).any()  # the window reaches beyond the image
    beyond = aware.valid < 0.5
    plain, _ = window_target(body, window, truncation_aware=False, known=known)
    assert plain.valid is not None and (plain.valid < 0.5).any() and (plain.valid[beyond] > 0.5).all()
    both, _ = window_target(body, window, known=known)
    assert (both.valid[beyond] < 0.5).all()


def test_the_concavities_of_the_body_are_unknown_when_a_grown_mask_fills_them():
    from silfit.silhouette.losses import concave_region, unknown_regions

    body = np.zeros((96, 96), bool)  # a torso with an arm hanging 4 px beside it, legs 6 px apart
    body[10:60, 30:60] = True  # torso
    body[14:58, 64:70] = True  # arm
    body[10:16, 60:64] = True  # shoulder
    body[60:90, 30:42] = True  # legs
    body[60:90, 48:60] = True
    region = concave_region(body, 5)
    assert not (region & body).any()
    assert region[30:50, 60:64].all()  # between the arm and the torso
    assert region[62:70, 42:48].all()  # between the thighs, near the crotch
    assert not region[:, :28].any() and not region[:, 72:].any()  # nothing outside the convexities
    assert not region[92:].any()  # no closing against the image's border
    assert not concave_region(body, 0).any()
    assert not concave_region(body, 1)[30:50, 60:64].any()  # too small a disc to bridge a 4 px gap

    grown = body | region
    grown[5:10, 30:60] = True  # and a little above the head: clothing outside the concavities
    known = unknown_regions(grown, body, far=0.0, hole_fraction=0.0, concave=5)
    assert known is not None
    assert not known[region].any() and known[body].all() and known[5:10, 30:60].all()
    assert unknown_regions(grown, body, far=0.0, hole_fraction=0.0) is None  # off by default
    assert unknown_regions(body, body, far=0.0, hole_fraction=0.0, concave=5) is None  # a clean mask: nothing unknown
