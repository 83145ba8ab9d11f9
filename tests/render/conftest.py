"""Shared fixtures for the renderer tests: small meshes and cameras (64-128 px)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from silfit.camera import Camera


@pytest.fixture(scope="session")
def sphere():
    """Icosphere of radius 0.3 m (vertices [V,3] float32 tensor, faces int64 array)."""
    m = trimesh.creation.icosphere(subdivisions=4, radius=0.3)
    return torch.tensor(m.vertices, dtype=torch.float32), np.asarray(m.faces, dtype=np.int64)


@pytest.fixture(scope="session")
def capsule():
    """A tilted capsule (smooth, convex, no self-intersection), centred at the origin."""
    m = trimesh.creation.capsule(height=0.5, radius=0.15, count=[24, 24])
    m.apply_transform(trimesh.transformations.euler_matrix(0.3, 0.2, 0.5))
    return torch.tensor(m.vertices, dtype=torch.float32), np.asarray(m.faces, dtype=np.int64)


@pytest.fixture(scope="session")
def cam64():
    return Camera(fx=100.0, fy=100.0, cx=31.5, cy=31.5, width=64, height=64)


@pytest.fixture(scope="session")
def pose_body():
    """``pose_body(model, pose_seed, transl, orient)`` -> (vertices [V,3], faces): the body
    upright facing the camera (``orient`` = axis-angle (pi, 0, 0)) with a small random
    pose and shape (none for seed 0)."""

    def _pose(model, pose_seed: int = 0, transl=(0.0, 0.1, 2.8), orient=(math.pi, 0.0, 0.0)):
        g = torch.Generator().manual_seed(pose_seed)
        nb, npose = min(10, model.num_betas), model.num_body_pose
        body_pose = 0.25 * torch.randn(1, npose, generator=g) if pose_seed else torch.zeros(1, npose)
        betas = 0.5 * torch.randn(1, nb, generator=g) if pose_seed else torch.zeros(1, nb)
        with torch.no_grad():
            out = model(
                betas=betas,
                body_pose=body_pose,
                global_orient=torch.tensor([orient], dtype=torch.float32),
                transl=torch.tensor([transl], dtype=torch.float32),
            )
        return out.vertices[0].float(), model.faces

    return _pose


@pytest.fixture(scope="session")
def edge_gradient_check():
    """``check(render, verts, loss, p0, steps)`` -> ``(ad, fd, rel)``: d loss / d p by AD
    (mean of two seeds, 64 spp, 256 edge samples) vs central differences (4096 stratified
    samples with the same seed on both sides, steps ``steps[i]`` chosen as ~0.05 px of edge
    motion); ``render(vertices, spp=, edge_spp=, seed=, sampler=)`` returns a silhouette."""

    def check(render, verts, loss, p0, steps):
        ad = []
        for seed in (11, 12):
            p = p0.clone().requires_grad_()
            loss(render(verts(p), spp=64, edge_spp=256, seed=seed, sampler="multijitter")).backward()
            ad.append(p.grad)
        ad = torch.stack(ad).mean(0)
        fd = []
        for i, h in enumerate(steps):
            e = torch.zeros_like(p0)
            e[i] = h
            with torch.no_grad():
                plus = loss(render(verts(p0 + e), spp=4096, seed=5, sampler="multijitter"))
                minus = loss(render(verts(p0 - e), spp=4096, seed=5, sampler="multijitter"))
            fd.append(float(plus - minus) / (2 * h))
        fd = torch.tensor(fd)
        rel = ((ad - fd).abs() / fd.abs()).tolist()
        print("AD", ad.tolist(), "FD", fd.tolist(), "rel", rel)
        return ad, fd, rel

    return check
