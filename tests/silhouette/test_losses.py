"""Distance-transform silhouette energy and IoU."""
import numpy as np
import torch

from silfit.silhouette import MaskTarget, distance_transforms, silhouette_energy, soft_iou


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
