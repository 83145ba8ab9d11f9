import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from silfit.fitting.occlusion import (
    hidden_keypoints,
    keypoint_tolerances,
    occlusion_cost,
    occlusion_parts,
    surface_depth,
)
from silfit.io.keypoints import BODY25_NAMES, model_keypoints

# a square of two triangles at depth 2 m, x and y in -1..1
SQUARE = torch.tensor([[[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [1.0, 1.0, 2.0], [-1.0, 1.0, 2.0]]], dtype=torch.float64)
FACES = torch.tensor([[0, 1, 2], [0, 2, 3]])


def test_surface_depth_is_the_nearest_surface_along_the_ray():
    pts = torch.tensor([[[0.0, 0.0, 3.0], [0.3, -0.2, 1.0], [5.0, 0.0, 3.0]]], dtype=torch.float64)
    d = surface_depth(SQUARE, FACES, pts)[0]
    assert d[0] == pytest.approx(2.0) and d[1] == pytest.approx(2.0)
    assert math.isinf(float(d[2]))  # the ray misses the square
    # five rays: a point whose ray runs along the edge counts the farthest surface (here: none)
    edge = torch.tensor([[[1.0 * 1.5, 0.0, 1.5]]], dtype=torch.float64)  # normalised x = 1.0 at 1.5 m: beyond 0.5
    assert math.isinf(float(surface_depth(SQUARE, FACES, edge, offset=0.01)[0, 0]))
    inside = torch.tensor([[[0.4 * 3.0, 0.0, 3.0]]], dtype=torch.float64)  # normalised 0.4, inside the square's 0.5
    assert float(surface_depth(SQUARE, FACES, inside, offset=0.01)[0, 0]) == pytest.approx(2.0)


def test_hidden_uses_each_keypoints_tolerance():
    pts = torch.tensor([[[0.0, 0.0, 2.05], [0.0, 0.0, 2.3], [0.0, 0.0, 1.9]]], dtype=torch.float64)
    hidden = hidden_keypoints(SQUARE, FACES, pts, torch.tensor([0.1, 0.1, 0.1]))[0]
    assert hidden.tolist() == [False, True, False]


def test_cost_counts_confident_hidden_and_unsure_visible_keypoints():
    hidden = torch.tensor([[True, False, True, False, True, False]])
    conf = torch.tensor([[0.9, 0.1, 0.1, 0.9, 0.0, 0.45]], dtype=torch.float64)
    a, b = occlusion_parts(hidden, conf, (0.3, 0.6))
    assert float(a[0]) == pytest.approx(1.0)  # the confident hidden one (undetected ones cost nothing)
    assert float(b[0]) == pytest.approx(1.0 + 0.5)  # the unsure visible one, and half of the 0.45 one
    assert float(occlusion_cost(hidden, conf, (0.3, 0.6))[0]) == pytest.approx(2.5)


def test_a_body_facing_away_hides_its_face(body_model):
    # seen from behind, the nose and eyes are behind the head; from the front they are visible
    out = {}
    for name, yaw in (("front", 0.0), ("back", 180.0)):
        orient = (Rotation.from_rotvec([math.pi, 0, 0]) * Rotation.from_rotvec([0, math.radians(yaw), 0])).as_rotvec()
        o = body_model(
            betas=torch.zeros(1, 10),
            body_pose=torch.zeros(1, 69),
            global_orient=torch.tensor(orient, dtype=torch.float32)[None],
            transl=torch.tensor([[0.0, 0.2, 3.0]]),
        )
        kp = model_keypoints(body_model, o, "body25").double()
        out[name] = hidden_keypoints(
            o.vertices.double(), body_model.faces, kp, keypoint_tolerances(BODY25_NAMES), 1 / 500
        )[0]
    face = [BODY25_NAMES.index(n) for n in ("nose", "left_eye", "right_eye")]
    assert not out["front"][face].any() and out["back"][face].all()
    conf = torch.ones(1, 25, dtype=torch.float64)  # every keypoint detected confidently: the back view costs more
    assert float(occlusion_cost(out["back"][None], conf)[0]) > float(occlusion_cost(out["front"][None], conf)[0])
    assert np.isfinite(occlusion_cost(out["front"][None], conf).numpy()).all()
