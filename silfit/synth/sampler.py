"""Random poses, shapes and camera placements for synthetic subjects.

All samplers take a ``numpy.random.Generator`` so a dataset is reproducible from its
seed. Angles in the public settings are degrees; arrays are radians (axis-angle).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..camera import UPRIGHT_FACING_CAMERA, Camera, project_points
from ..priors.limits import clamp_to_limits
from ..poses.library import BODY_JOINTS, PERTURB_SCALE, POSE_LIBRARY, mirror_pose, mirror_rotvec

__all__ = [
    "PoseSample",
    "Placement",
    "sample_pose",
    "sample_betas",
    "global_orientation",
    "sample_intrinsics",
    "place_body",
    "PERTURB_SCALE",
]

_SIGMA = np.repeat(np.array([PERTURB_SCALE[n] for n in BODY_JOINTS]), 3)


@dataclass
class PoseSample:
    body_pose: np.ndarray  # [69]
    root: np.ndarray  # [3] axis-angle in the body frame
    name: str  # the main library pose
    blend: Optional[str]  # the secondary pose, if blended
    blend_weight: float
    mirrored: bool

    def describe(self) -> str:
        s = self.name + (" (mirrored)" if self.mirrored else "")
        if self.blend:
            s += f" blended {self.blend_weight:.2f} with {self.blend}"
        return s


def _slerp_rotvecs(a: np.ndarray, b: np.ndarray, w: float) -> np.ndarray:
    """Per-row geodesic interpolation of axis-angle rows ``[..., 3]``: ``a`` at 0, ``b`` at 1."""
    ra = Rotation.from_rotvec(a.reshape(-1, 3))
    rb = Rotation.from_rotvec(b.reshape(-1, 3))
    delta = (ra.inv() * rb).as_rotvec() * w
    return (ra * Rotation.from_rotvec(delta)).as_rotvec().reshape(a.shape)


def sample_pose(
    rng: np.random.Generator,
    names: Optional[Sequence[str]] = None,
    perturb_deg: float = 6.0,
    blend_prob: float = 0.5,
    max_blend: float = 0.5,
    mirror_prob: float = 0.5,
) -> PoseSample:
    """A library pose (uniform over ``names``, default all), optionally mirrored, blended
    (geodesically, per joint) towards a second library pose with weight up to ``max_blend``,
    then perturbed by Gaussian noise of ``perturb_deg`` (scaled per joint) and clamped into
    the joint limits."""
    names = list(POSE_LIBRARY) if names is None else list(names)
    main = POSE_LIBRARY[names[rng.integers(len(names))]]
    pose, root = main.body_pose.copy(), main.root.copy()
    blend, weight = None, 0.0
    if blend_prob > 0 and rng.random() < blend_prob:
        other = POSE_LIBRARY[list(POSE_LIBRARY)[rng.integers(len(POSE_LIBRARY))]]
        if other.name != main.name:
            blend, weight = other.name, float(rng.uniform(0.1, max_blend))
            pose = _slerp_rotvecs(pose, other.body_pose, weight)
            root = _slerp_rotvecs(root, other.root, weight)
    mirrored = bool(mirror_prob > 0 and rng.random() < mirror_prob)
    if mirrored:
        pose, root = mirror_pose(pose), mirror_rotvec(root)
    if perturb_deg > 0:
        pose = pose + rng.normal(0.0, math.radians(perturb_deg), 69) * _SIGMA
    pose = clamp_to_limits(torch.as_tensor(pose, dtype=torch.float64)).numpy()
    return PoseSample(pose, root, main.name, blend, weight, mirrored)


def sample_betas(
    rng: np.random.Generator, num_betas: int = 10, truncation: float = 2.5, scale: float = 1.0
) -> np.ndarray:
    """Shape coefficients from the model's prior: unit Gaussian (times ``scale``), each entry
    truncated to ``|beta| <= truncation`` by resampling."""
    betas = rng.normal(0.0, scale, num_betas)
    for _ in range(100):
        bad = np.abs(betas) > truncation
        if not bad.any():
            break
        betas[bad] = rng.normal(0.0, scale, int(bad.sum()))
    return np.clip(betas, -truncation, truncation)


def global_orientation(yaw_deg: float, elevation_deg: float = 0.0, roll_deg: float = 0.0, root=None) -> np.ndarray:
    """``global_orient`` (axis-angle) of a body turned by ``yaw_deg`` about its own vertical
    axis (0: facing the camera, 180: back to the camera; positive turns the body towards its
    left, i.e. to the image's right), seen from a camera ``elevation_deg`` above it (looking
    down; the head comes nearer the camera) and rolled by ``roll_deg`` about the optical axis.
    ``root`` is an extra rotation in the body frame (lying poses), applied first."""
    r = Rotation.from_rotvec(np.zeros(3) if root is None else np.asarray(root, dtype=np.float64))
    r = Rotation.from_rotvec([0.0, math.radians(yaw_deg), 0.0]) * r
    r = Rotation.from_rotvec(UPRIGHT_FACING_CAMERA) * r
    r = Rotation.from_rotvec([math.radians(elevation_deg), 0.0, 0.0]) * r
    r = Rotation.from_rotvec([0.0, 0.0, math.radians(roll_deg)]) * r
    return r.as_rotvec()


def sample_intrinsics(
    rng: np.random.Generator, width: int, height: int, fov_deg: Tuple[float, float] = (45.0, 65.0)
) -> Tuple[Camera, float]:
    """A centred pinhole camera whose horizontal-or-vertical (the longer side) field of view
    is uniform in ``fov_deg``; returns ``(camera, fov)``."""
    fov = float(rng.uniform(*fov_deg))
    f = 0.5 * max(width, height) / math.tan(math.radians(fov) / 2)
    return Camera(fx=f, fy=f, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height), fov


#: metres: the nearest vertex of a placed body at least this far in front of the camera (a body that is long
#: along the view axis and short in the image was placed partly behind it, where the projection blows up); such a
#: body is framed closer than its target share says, and marked truncated where it leaves the image
_NEAREST_M = 0.3


@dataclass
class Placement:
    transl: np.ndarray  # [3]
    fill: float  # target share of the frame (longest projected side / image side)
    offset: Tuple[float, float]  # bbox-centre offset from the image centre, as a fraction of the size
    truncated: bool


def place_body(
    rng: np.random.Generator,
    vertices: np.ndarray,
    camera: Camera,
    fill: Tuple[float, float] = (0.55, 0.85),
    truncation_prob: float = 0.0,
    truncated_fill: Tuple[float, float] = (0.9, 1.3),
    jitter: float = 0.5,
) -> Placement:
    """Translation that puts posed ``vertices`` (camera-frame orientation, zero translation)
    in front of ``camera`` so that the projected bounding box's longer side (relative to
    the image) is a share ``fill`` of the frame, centred with a random offset within
    ``jitter`` of the free margin. With probability ``truncation_prob`` the body is framed
    larger and shifted so part of it leaves the image."""
    V = torch.as_tensor(vertices, dtype=torch.float64)
    truncated = bool(truncation_prob > 0 and rng.random() < truncation_prob)
    phi = float(rng.uniform(*(truncated_fill if truncated else fill)))
    W, H = camera.width, camera.height
    if truncated:
        ang = rng.uniform(0, 2 * math.pi)
        mag = rng.uniform(0.2, 0.4)
        off = (mag * math.cos(ang) * 0.5, mag * math.sin(ang))  # mostly vertical: cut head or feet
    else:
        margin = max(0.0, (1.0 - phi) / 2.0)
        off = tuple(float(rng.uniform(-jitter, jitter) * margin) for _ in range(2))

    lo, hi = V.amin(0).numpy(), V.amax(0).numpy()
    centre = (lo + hi) / 2
    extent = max(hi[1] - lo[1], (hi[0] - lo[0]) * H / W)
    z = camera.fy * extent / (phi * H)
    t_min = _NEAREST_M - lo[2]  # the depth translation that puts the nearest vertex _NEAREST_M in front
    clamped = z - centre[2] < t_min
    t = np.array([-centre[0], -centre[1], max(z - centre[2], t_min)])
    target = np.array([camera.cx + off[0] * W, camera.cy + off[1] * H])
    for _ in range(6):
        uv = project_points(V + torch.as_tensor(t), camera).numpy()
        u0, v0 = uv.min(0)
        u1, v1 = uv.max(0)
        size = max((v1 - v0) / H, (u1 - u0) / W)
        depth = centre[2] + t[2]
        new_depth = depth * size / phi
        t[2] += new_depth - depth
        if t[2] < t_min:  # a body long along the view axis: its near end stays in front of the camera
            t[2], clamped = t_min, True
            new_depth = centre[2] + t[2]
        uv = project_points(V + torch.as_tensor(t), camera).numpy()
        mid = (uv.min(0) + uv.max(0)) / 2
        t[0] -= (mid[0] - target[0]) * new_depth / camera.fx
        t[1] -= (mid[1] - target[1]) * new_depth / camera.fy
    if clamped:  # held near the camera: it may not fit the frame (then it is cut, whatever the target share)
        uv = project_points(V + torch.as_tensor(t), camera).numpy()
        truncated = truncated or bool((uv.min(0) < -0.5).any() or uv[:, 0].max() > W - 0.5 or uv[:, 1].max() > H - 0.5)
    return Placement(transl=t, fill=phi, offset=(float(off[0]), float(off[1])), truncated=truncated)
