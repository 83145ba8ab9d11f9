"""Mitsuba silhouettes vs pyrender masks vs projected vertices, on the open body model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from silfit.camera import Camera, project_points
from silfit.render.offscreen import render_mask
from silfit.render.silhouette import SilhouetteRenderer

CASES = [
    # (pose seed, transl, global_orient, camera): ~200 px tall bodies, so that pixel-grid
    # quantisation of the binary masks stays well below the 0.1 px centroid tolerance.
    (0, (0.0, -0.2, 2.8), (math.pi, 0.0, 0.0), Camera(fx=360.0, fy=360.0, cx=159.5, cy=159.5, width=320, height=320)),
    (3, (0.15, -0.25, 3.4), (math.pi, 0.0, 0.0), Camera(fx=370.0, fy=350.0, cx=150.3, cy=160.8, width=300, height=320)),
    (7, (-0.1, -0.2, 2.9), (0.0, 0.0, math.pi), Camera(fx=330.0, fy=330.0, cx=130.0, cy=160.0, width=260, height=320)),
]


@pytest.fixture(scope="module")
def body(open_model):
    return open_model, SilhouetteRenderer(open_model.faces)


def _centroid(img):
    ys, xs = np.mgrid[: img.shape[0], : img.shape[1]]
    return np.array([(img * xs).sum(), (img * ys).sum()]) / img.sum()


@pytest.mark.parametrize("case", range(len(CASES)))
def test_mitsuba_matches_pyrender_mask(body, pose_body, case):
    model, renderer = body
    pose_seed, transl, orient, camera = CASES[case]
    verts, faces = pose_body(model, pose_seed, transl, orient)
    sil = renderer(verts, camera, spp=64, seed=case, sampler="multijitter").numpy()
    mask = render_mask(verts, faces, camera)
    assert mask.shape == sil.shape == (camera.height, camera.width)
    assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any()), "body must be in frame"
    binary = sil > 0.5
    iou = (binary & mask).sum() / (binary | mask).sum()
    # Thresholded vs binary: both switch where an edge crosses the pixel centre.  (The soft
    # silhouette's centroid is the exact area centroid; a binary mask's differs from it by
    # up to ~0.15 px here because flat soles and the crown are quantised to whole rows.)
    dc = np.abs(_centroid(binary.astype(np.float64)) - _centroid(mask.astype(np.float64)))
    print(f"case {case}: IoU {iou:.4f}, centroid difference {dc.round(4).tolist()} px, area {mask.sum()}")
    assert iou >= 0.99
    assert dc.max() <= 0.1

    # projected vertices land inside the rendered silhouette (the pixel holding them is covered)
    uv = project_points(verts, camera).round().long().numpy()
    assert ((uv >= 0).all(1) & (uv[:, 0] < camera.width) & (uv[:, 1] < camera.height)).all()
    covered = sil[uv[:, 1], uv[:, 0]]
    assert (covered > 0).mean() > 0.995
