"""Synthetic subjects with known ground truth, written in the format of :mod:`silfit.io.subjects`.

One subject = a sampled library pose, a shape from the prior, a camera and placement; the
body is rendered offscreen (pyrender on OSMesa, :mod:`silfit.render.offscreen`) for the shaded
``image.png`` and the binary ``mask.png``; BODY_25 keypoints are the projections of the
model's keypoints (:func:`silfit.io.keypoints.model_keypoints`), with

* visibility: 0 outside the image, 1 self-occluded (the rendered depth at the keypoint's
  pixel is nearer than the keypoint by more than a per-keypoint tolerance: joint centres
  lie inside the body, so their tolerance is about the limb's half thickness), 2 visible;
* confidences: uniform in ``conf_visible`` for visible points, ``conf_occluded`` for
  self-occluded ones, 0 (and coordinates 0, 0, as OpenPose writes) outside the image or
  dropped (probability ``drop_prob`` per in-image point);
* Gaussian pixel noise of ``noise_px`` (standard deviation per coordinate) on the kept points.

With ``whole_body`` (an SMPL-X-layout model) a subject also gets library hand poses
(:mod:`.hands`), an expression, a jaw opening and eye rotations, and ``keypoints.json`` holds
OpenPose's whole-body parts (:mod:`silfit.io.wholebody`): hands with ``hand_noise_scale`` and the
face with ``face_noise_scale`` times the body's pixel noise (detectors locate these small, sharp
features more precisely in pixels), visibility from the rendered depth with the tolerances of
:data:`WHOLEBODY_DEPTH_TOLERANCE`; ``gt.npz`` adds every parameter, the finger angles and each
part's 3D points, clean projections, visibility and drop flags.

The dataset is deterministic for a seed: subject ``i`` uses ``numpy.random.default_rng([seed, i])``
and every file is written without timestamps.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch
from PIL import Image
from tqdm import tqdm

from silfit.render.offscreen import render_mesh

from .. import __version__
from ..body import load_body_model
from ..camera import Camera, project_points, save_camera
from ..io.subjects import INDEX_NAME, save_npz, write_png
from ..io.keypoints import BODY25_NAMES, COCO17_NAMES, model_keypoints, write_openpose_json
from ..layouts import DEFAULT_DEPTH_TOLERANCE, KEYPOINT_DEPTH_TOLERANCE
from ..io.wholebody import FACE70_NAMES, hand_names, wholebody_keypoints, write_wholebody_json
from .hands import hand_axes, hand_pose_to_axis_angle, sample_hand_pose
from ..poses.library import FRONTAL_POSES
from .hard import hard_pose_and_yaw
from .sampler import global_orientation, place_body, sample_betas, sample_intrinsics, sample_pose

__all__ = [
    "SynthConfig",
    "SubjectRecord",
    "generate_subject",
    "generate_dataset",
    "FORMAT_VERSION",
    "KEYPOINT_DEPTH_TOLERANCE",
]

FORMAT_VERSION = 1


@dataclass
class SynthConfig:
    """Generator settings (all recorded in ``index.json``)."""

    seed: int = 0
    size: int = 512  # image width = height, pixels
    noise_px: float = 2.0  # keypoint noise (std. dev. per coordinate, pixels)
    clean: int = 0  # the first `clean` subjects get no noise and no dropped keypoints
    drop_prob: float = 0.0  # probability of dropping each in-image keypoint
    conf_visible: Tuple[float, float] = (0.6, 1.0)
    conf_occluded: Tuple[float, float] = (0.1, 0.3)
    fov_deg: Tuple[float, float] = (45.0, 65.0)  # across the image (square images)
    fill: Tuple[float, float] = (0.55, 0.85)  # longest side of the body's box / image size
    elevation_deg: float = 15.0  # camera elevation uniform in +-this
    roll_deg: float = 5.0  # camera roll uniform in +-this
    yaw_range_deg: Tuple[float, float] = (-180.0, 180.0)  # body yaw (0 = facing the camera)
    truncation_prob: float = 0.0  # probability of a partly truncated body
    beta_truncation: float = 2.5
    perturb_deg: float = 6.0
    blend_prob: float = 0.5
    mirror_prob: float = 0.5
    background: str = "mixed"  # plain | textured | mixed
    frontal_first: bool = True  # subject 0: a clearly human, front-facing pose, uncropped
    coco: bool = False  # also write keypoints_coco17.json
    whole_body: bool = False  # SMPL-X-layout model: hand poses, expressions, OpenPose whole-body keypoints
    hand_perturb_deg: float = 8.0  # finger-angle perturbation of the library hand poses
    hand_noise_scale: float = 0.5  # hand keypoint noise = this x noise_px
    face_noise_scale: float = 0.4  # face keypoint noise = this x noise_px
    expression_std: float = 0.7  # expression coefficients ~ N(0, std^2), clipped to +-2
    jaw_open_max_deg: float = 25.0  # jaw opening uniform in [0, this] (half the subjects keep it closed)
    poses: str = "library"  # library (sampled around the pose library) | hard (silfit.poses.sampler, see synth.hard)

    def validate(self) -> "SynthConfig":
        if self.size < 16:
            raise ValueError(f"--size must be at least 16 pixels, got {self.size}")
        if self.noise_px < 0:
            raise ValueError(f"--noise-px must be >= 0, got {self.noise_px}")
        for name in ("drop_prob", "truncation_prob", "blend_prob", "mirror_prob"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {v}")
        if self.poses not in ("library", "hard"):
            raise ValueError(f"poses must be library or hard, got {self.poses!r}")
        if self.background not in ("plain", "textured", "mixed"):
            raise ValueError(f"background must be plain, textured or mixed, got {self.background!r}")
        if not (0 < self.fov_deg[0] <= self.fov_deg[1] < 170):
            raise ValueError(f"field-of-view range must be within (0, 170) degrees, got {self.fov_deg}")
        if not (-180.0 <= self.yaw_range_deg[0] <= self.yaw_range_deg[1] <= 180.0):
            raise ValueError(f"yaw range must be within -180..180 degrees, low first, got {self.yaw_range_deg}")
        if not (0 < self.fill[0] <= self.fill[1]):
            raise ValueError(f"fill range must be positive, got {self.fill}")
        for name in ("hand_perturb_deg", "hand_noise_scale", "face_noise_scale", "expression_std", "jaw_open_max_deg"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        return self

    def to_dict(self) -> dict:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}


@dataclass
class SubjectRecord:
    """What ``index.json`` says about one subject (besides its files)."""

    name: str
    pose: str
    description: str
    blend: Optional[str]
    blend_weight: float
    mirrored: bool
    yaw_deg: float
    elevation_deg: float
    roll_deg: float
    fov_deg: float
    focal_px: float
    distance_m: float  # depth (z) of the pelvis joint
    stature_m: float  # height of the T-posed body
    fill: float
    truncated: bool
    noise_px: float
    keypoints_visible: int
    keypoints_occluded: int
    keypoints_outside: int
    keypoints_dropped: int
    background: str
    hand_left: Optional[str] = None  # whole-body subjects: the library hand poses
    hand_right: Optional[str] = None

    def to_dict(self) -> dict:
        d = {k: v for k, v in asdict(self).items() if not (k in ("hand_left", "hand_right") and v is None)}
        for k, v in d.items():
            if isinstance(v, float):
                d[k] = round(v, 4)
        return d


WHOLEBODY_PARTS = ("hand_left", "hand_right", "face")
#: Whole-body keypoints: how far behind the rendered surface still counts as visible (metres): finger
#: joints lie about 6-10 mm under the skin, the wrist about 2.5 cm, the pupils (eyeball centres) 12 mm.
WHOLEBODY_DEPTH_TOLERANCE = {
    **{n: 0.015 for side in ("left", "right") for n in hand_names(side)},
    **{f"{side}_wrist": 0.04 for side in ("left", "right")},
    **{n: 0.01 for n in FACE70_NAMES},
    "right_pupil": 0.025,
    "left_pupil": 0.025,
}


def wholebody_names(part: str) -> tuple:
    return FACE70_NAMES if part == "face" else hand_names(part.split("_")[1])


def sample_wholebody_params(rng: np.random.Generator, model, cfg: SynthConfig):
    """Hand poses (a library pose per hand, perturbed within the finger limits), an expression, a jaw
    opening (half the subjects) and small eye rotations. Returns ``(params, finger_angles, hand_names)``:
    model parameters ``{name: array}``, ``{"left_hand_flex": [5, 3], "left_hand_spread": [5], ...}``
    and the two library pose names."""
    if model.use_pca:
        raise ValueError(
            f"{model.source}: whole-body synthesis poses hands joint by joint: load the model without use_pca"
        )
    with torch.no_grad():
        joints = model(**model.zero_params(1)).joints[0].double().cpu().numpy()
    mean = model.pose_mean.double().cpu().numpy()  # the model adds its mean hand pose (flat_hand_mean=False)
    params, angles, names = {}, {}, []
    for side, start in (("left", 75), ("right", 120)):
        name, flex, spread = sample_hand_pose(rng, perturb_deg=cfg.hand_perturb_deg)
        aa = hand_pose_to_axis_angle(flex, spread, hand_axes(joints, model.joint_names, side))
        params[f"{side}_hand_pose"] = aa - mean[start : start + 45]
        angles[f"{side}_hand_flex"], angles[f"{side}_hand_spread"] = flex, spread
        names.append(name)
    params["expression"] = np.clip(rng.normal(0.0, cfg.expression_std, model.num_expression), -2.0, 2.0)
    jaw = np.radians(rng.uniform(0.0, cfg.jaw_open_max_deg)) if rng.random() < 0.5 else 0.0
    params["jaw_pose"] = np.array([jaw, 0.0, 0.0])
    gaze = np.radians(rng.uniform(-8.0, 8.0, 2))
    params["leye_pose"] = params["reye_pose"] = np.array([gaze[0], gaze[1], 0.0])
    return params, angles, tuple(names)


# ----------------------------------------------------------------------------- pieces
def background_image(rng: np.random.Generator, kind: str, h: int, w: int) -> Tuple[np.ndarray, str]:
    if kind == "mixed":
        kind = "plain" if rng.random() < 0.4 else "textured"
    base = rng.uniform(0.35, 0.95, 3)
    if kind == "plain":
        img = np.broadcast_to(base, (h, w, 3)).copy()
        return (img * 255).round().astype(np.uint8), "plain"
    style = int(rng.integers(3))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    other = rng.uniform(0.2, 0.9, 3)
    if style == 0:  # vertical gradient (wall to floor)
        t = (yy / max(h - 1, 1))[..., None]
        img = base * (1 - t) + other * t
        label = "gradient"
    elif style == 1:  # checker / tiles
        period = rng.uniform(0.06, 0.2) * max(h, w)
        ang = rng.uniform(0, math.pi)
        u = xx * math.cos(ang) + yy * math.sin(ang)
        v = -xx * math.sin(ang) + yy * math.cos(ang)
        t = ((np.floor(u / period) + np.floor(v / period)) % 2)[..., None]
        img = base * (1 - 0.35 * t) + other * 0.35 * t
        label = "tiles"
    else:  # smooth blobs (low-frequency noise from a coarse grid)
        g = rng.uniform(0, 1, (6, 6, 3))
        coarse = Image.fromarray((g * 255).astype(np.uint8)).resize((w, h), Image.BICUBIC)
        t = np.asarray(coarse, dtype=np.float64) / 255.0
        img = base * 0.7 + t * 0.3
        label = "blobs"
    img = img + rng.normal(0, 0.01, img.shape)  # a little sensor-like grain
    return (np.clip(img, 0, 1) * 255).round().astype(np.uint8), label


BODY_COLOURS = (
    (0.80, 0.62, 0.50),
    (0.62, 0.45, 0.35),
    (0.45, 0.32, 0.25),
    (0.90, 0.74, 0.62),
    (0.55, 0.60, 0.75),
    (0.70, 0.45, 0.45),
    (0.50, 0.65, 0.55),
    (0.62, 0.68, 0.78),
)


def render_subject(vertices: np.ndarray, faces: np.ndarray, camera: Camera, colour):
    return render_mesh(vertices, faces, camera, color=colour)


def keypoint_visibility(
    points_3d: np.ndarray,
    points_2d: np.ndarray,
    depth: np.ndarray,
    names: Sequence[str],
    tolerance: Optional[Dict[str, float]] = None,
) -> np.ndarray:
    """``int8 [K]``: 0 outside the image (or behind the camera), 1 self-occluded, 2 visible,
    by comparing each keypoint's depth with the rendered ``depth [H, W]`` (0 = background):
    occluded when even the farthest surface in the 3x3 pixels around it is nearer than the
    keypoint by more than its tolerance (:data:`KEYPOINT_DEPTH_TOLERANCE`)."""
    tol = KEYPOINT_DEPTH_TOLERANCE if tolerance is None else tolerance
    H, W = depth.shape
    vis = np.zeros(len(names), dtype=np.int8)
    for k, name in enumerate(names):
        u, v = points_2d[k]
        z = points_3d[k, 2]
        if not (np.isfinite(u) and np.isfinite(v)) or z <= 0 or not (-0.5 <= u < W - 0.5 and -0.5 <= v < H - 0.5):
            continue
        r, c = int(round(v)), int(round(u))
        # The farthest surface in the 3x3 neighbourhood: an occluder must cover all of it, so
        # edge pixels and coarse images do not produce false occlusions.
        d = depth[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2].max()
        vis[k] = 1 if (d > 0 and z - d > tol.get(name, DEFAULT_DEPTH_TOLERANCE)) else 2
    return vis


def noisy_keypoints(
    rng: np.random.Generator,
    clean_2d: np.ndarray,
    visibility: np.ndarray,
    noise_px: float,
    drop_prob: float,
    conf_visible=(0.6, 1.0),
    conf_occluded=(0.1, 0.3),
) -> Tuple[np.ndarray, np.ndarray]:
    """``(keypoints [K, 3], dropped bool [K])`` from clean projections and visibility codes."""
    K = len(clean_2d)
    # Draw every random number for every point (fixed count): results do not depend on which are visible.
    noise = rng.normal(0.0, 1.0, (K, 2)) * noise_px
    c_vis = rng.uniform(*conf_visible, K)
    c_occ = rng.uniform(*conf_occluded, K)
    drop = rng.random(K) < drop_prob
    kp = np.zeros((K, 3))
    keep = (visibility > 0) & ~drop
    kp[keep, :2] = clean_2d[keep] + noise[keep]
    kp[keep, 2] = np.where(visibility[keep] == 2, c_vis[keep], c_occ[keep])
    return kp, drop & (visibility > 0)


# ----------------------------------------------------------------------------- one subject
def _sample_pose_and_view(model, rng: np.random.Generator, cfg: SynthConfig, frontal: bool) -> tuple:
    """``(pose sample, yaw, elevation, roll)`` in degrees of one subject: a frontal library pose facing the camera
    for the dataset's first subject (``frontal``), else a library or hard pose at a random yaw, elevation and roll."""
    if frontal:
        ps = sample_pose(rng, names=FRONTAL_POSES, perturb_deg=min(cfg.perturb_deg, 4.0), blend_prob=0.0)
        yaw = float(rng.uniform(-20, 20))
        elev = float(rng.uniform(-5, 5))
        return ps, yaw, elev, 0.0
    if cfg.poses == "hard":
        ps, yaw = hard_pose_and_yaw(model, rng, cfg.yaw_range_deg)
    else:
        ps = sample_pose(rng, perturb_deg=cfg.perturb_deg, blend_prob=cfg.blend_prob, mirror_prob=cfg.mirror_prob)
        yaw = float(rng.uniform(*cfg.yaw_range_deg))
    elev = float(rng.uniform(-cfg.elevation_deg, cfg.elevation_deg))
    roll = float(rng.uniform(-cfg.roll_deg, cfg.roll_deg))
    return ps, yaw, elev, roll


def _wholebody_keypoints(rng, parts3d: dict, parts2d: dict, depth, noise_px: float, drop_prob: float, cfg) -> tuple:
    """``(gt arrays, noisy keypoints)`` of the hands and face: visibility by ``depth``, the hands' and face's own noise."""
    wb_arrays, wb_kp = {}, {}
    for part in parts3d:
        names = wholebody_names(part)
        scale = cfg.hand_noise_scale if part.startswith("hand") else cfg.face_noise_scale
        pvis = keypoint_visibility(parts3d[part], parts2d[part], depth, names, WHOLEBODY_DEPTH_TOLERANCE)
        pkp, pdrop = noisy_keypoints(
            rng, parts2d[part], pvis, noise_px * scale, drop_prob, cfg.conf_visible, cfg.conf_occluded
        )
        wb_kp[part] = pkp
        wb_arrays.update(
            {
                f"{part}_3d": parts3d[part].astype(np.float32),
                f"{part}_2d_clean": parts2d[part].astype(np.float64),
                f"{part}_visibility": pvis,
                f"{part}_dropped": pdrop,
            }
        )
    return wb_arrays, wb_kp


def _write_subject_files(out_dir: Path, cfg, image, mask, kp, wb_kp: dict, coco_kp, camera) -> None:
    """A subject's image.png, mask.png, keypoints.json (whole-body with hands and face where ``cfg.whole_body``),
    keypoints_coco17.json (``cfg.coco``) and camera.json, into ``out_dir`` (created)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    write_png(out_dir / "image.png", image)
    write_png(out_dir / "mask.png", mask)
    if cfg.whole_body:
        write_wholebody_json(out_dir / "keypoints.json", kp, wb_kp["hand_left"], wb_kp["hand_right"], wb_kp["face"])
    else:
        write_openpose_json(out_dir / "keypoints.json", kp)
    if cfg.coco:
        write_openpose_json(out_dir / "keypoints_coco17.json", coco_kp)
    save_camera(camera, out_dir / "camera.json")


def _projected_keypoints(model, out, camera, whole_body: bool) -> tuple:
    """``((body25 3D, 2D), (coco17 3D, 2D), hands and face 3D, 2D)`` of a posed body ``out`` (numpy, float64; the
    parts' dicts empty without ``whole_body``)."""
    kp3d = model_keypoints(model, out, "body25")[0]
    kp2d = project_points(kp3d.double(), camera).cpu().numpy()
    coco3d = model_keypoints(model, out, "coco17")[0]
    coco2d = project_points(coco3d.double(), camera).cpu().numpy()
    parts3d, parts2d = {}, {}
    if whole_body:
        wb = wholebody_keypoints(model, out)
        parts3d = {p: wb[p][0].double() for p in WHOLEBODY_PARTS}
        parts2d = {p: project_points(v, camera).cpu().numpy() for p, v in parts3d.items()}
        parts3d = {p: v.cpu().numpy() for p, v in parts3d.items()}
    body = (kp3d.cpu().numpy().astype(np.float64), kp2d)
    return body, (coco3d.cpu().numpy().astype(np.float64), coco2d), parts3d, parts2d


def _render_over_background(rng: np.random.Generator, background: str, vertices, faces, camera) -> tuple:
    """``(rendering, image, background label)``: the body in a random colour over a random ``background`` (plain,
    textured or mixed), at the camera's size."""
    colour = BODY_COLOURS[int(rng.integers(len(BODY_COLOURS)))]
    bg, bg_label = background_image(rng, background, camera.height, camera.width)
    r = render_subject(vertices, faces, camera, colour)
    return r, np.where(r.mask[..., None], r.color, bg).astype(np.uint8), bg_label


@dataclass
class PosedSubject:
    """A subject's body as written: the stored (float32) parameters, its placement, keypoints and vertices."""

    params: Dict[str, np.ndarray]
    place: object  # silfit.synth.sampler's placement (transl, fill, truncated)
    kp3d: np.ndarray
    kp2d: np.ndarray
    coco3d: np.ndarray
    coco2d: np.ndarray
    parts3d: dict
    parts2d: dict
    vertices: np.ndarray
    joints: np.ndarray
    stature: float


def _pose_and_place(model, rng, cfg: SynthConfig, camera, frontal: bool, pose: dict, extra: dict) -> PosedSubject:
    """Place the body ``pose`` (``betas``, ``body_pose``, ``global_orient``) and ``extra`` whole-body parameters in
    front of ``camera`` (draws the placement from ``rng``), then evaluate the stored parameters once more."""
    dtype = model.dtype
    as_t = lambda a: torch.as_tensor(np.asarray(a)[None], dtype=dtype, device=model.device)  # noqa: E731
    betas, body_pose, global_orient = pose["betas"], pose["body_pose"], pose["global_orient"]
    with torch.no_grad():
        out0 = model(
            betas=as_t(betas),
            body_pose=as_t(body_pose),
            global_orient=as_t(global_orient),
            **{k: as_t(v) for k, v in extra.items()},
        )
        place = place_body(
            rng,
            out0.vertices[0].double().cpu().numpy(),
            camera,
            fill=cfg.fill,
            truncation_prob=0.0 if frontal else cfg.truncation_prob,
        )
        # Store the parameters at the precision they are written with, then evaluate once more,
        # so gt.npz's vertices are exactly model(params) for the stored params.
        params = {
            "betas": betas.astype(np.float32),
            "body_pose": body_pose.astype(np.float32),
            "global_orient": global_orient.astype(np.float32),
            "transl": place.transl.astype(np.float32),
            **{k: v.astype(np.float32) for k, v in extra.items()},
        }
        out = model(**{k: as_t(v) for k, v in params.items()})
        (kp3d, kp2d), (coco3d, coco2d), parts3d, parts2d = _projected_keypoints(model, out, camera, cfg.whole_body)
        rest = model.rest_vertices(as_t(betas))[0]
    vertices = out.vertices[0].cpu().numpy().astype(np.float32)
    joints = out.joints[0].cpu().numpy().astype(np.float32)
    stature = float(rest[:, 1].max() - rest[:, 1].min())
    return PosedSubject(params, place, kp3d, kp2d, coco3d, coco2d, parts3d, parts2d, vertices, joints, stature)


@dataclass
class SubjectKeypoints:
    """A subject's keypoints as detected: visibility codes, noisy keypoints and drop flags (body, COCO-17, parts)."""

    vis: np.ndarray
    kp: np.ndarray
    dropped: np.ndarray
    coco_vis: np.ndarray
    coco_kp: np.ndarray
    wb_arrays: dict
    wb_kp: dict


def _subject_keypoints(rng, body: PosedSubject, depth, noise_px: float, drop_prob: float, cfg) -> SubjectKeypoints:
    """Visibility by the rendered ``depth`` and noisy keypoints of the body, COCO-17 and (whole body) the parts."""
    vis = keypoint_visibility(body.kp3d, body.kp2d, depth, BODY25_NAMES)
    kp, dropped = noisy_keypoints(rng, body.kp2d, vis, noise_px, drop_prob, cfg.conf_visible, cfg.conf_occluded)
    coco_vis = keypoint_visibility(body.coco3d, body.coco2d, depth, COCO17_NAMES)
    coco_kp, coco_dropped = noisy_keypoints(
        rng, body.coco2d, coco_vis, noise_px, drop_prob, cfg.conf_visible, cfg.conf_occluded
    )
    wb_arrays, wb_kp = {}, {}
    if cfg.whole_body:
        wb_arrays, wb_kp = _wholebody_keypoints(rng, body.parts3d, body.parts2d, depth, noise_px, drop_prob, cfg)
    return SubjectKeypoints(vis, kp, dropped, coco_vis, coco_kp, wb_arrays, wb_kp)


def _subject_truth(body: PosedSubject, kps: SubjectKeypoints, noise_px: float, angles: dict) -> dict:
    """The arrays of a subject's ``gt.npz``."""
    return {
        **body.params,
        "vertices": body.vertices,
        "joints": body.joints,
        "keypoints_3d": body.kp3d.astype(np.float32),
        "keypoints_2d_clean": body.kp2d.astype(np.float64),
        "keypoints_visibility": kps.vis,
        "keypoints_dropped": kps.dropped,
        "coco17_3d": body.coco3d.astype(np.float32),
        "coco17_2d_clean": body.coco2d.astype(np.float64),
        "coco17_visibility": kps.coco_vis,
        "stature": np.float64(body.stature),
        "noise_px": np.float64(noise_px),
        **kps.wb_arrays,
        **{k: v.astype(np.float32) for k, v in angles.items()},
    }


def generate_subject(model, index: int, config: SynthConfig, out_dir: Path) -> SubjectRecord:
    """Sample, render and write subject ``index`` of a dataset into ``out_dir`` (created)."""
    cfg = config
    rng = np.random.default_rng([int(cfg.seed), int(index)])
    frontal = cfg.frontal_first and index == 0
    clean = index < cfg.clean
    noise_px = 0.0 if clean else float(cfg.noise_px)
    drop_prob = 0.0 if clean else float(cfg.drop_prob)
    W = H = int(cfg.size)

    # Pose, shape, orientation.
    ps, yaw, elev, roll = _sample_pose_and_view(model, rng, cfg, frontal)
    betas = sample_betas(rng, model.num_betas, cfg.beta_truncation)
    global_orient = global_orientation(yaw, elev, roll, root=ps.root)
    camera, fov = sample_intrinsics(rng, W, H, cfg.fov_deg)
    body_pose = ps.body_pose[: model.num_body_pose]  # SMPL-X: joints 1..21 (no SMPL hand joints)
    extra, angles, hands = {}, {}, (None, None)
    if cfg.whole_body:
        extra, angles, hands = sample_wholebody_params(rng, model, cfg)
    pose = {"betas": betas, "body_pose": body_pose, "global_orient": global_orient}
    body = _pose_and_place(model, rng, cfg, camera, frontal, pose, extra)

    # Render.
    faces = model.faces.cpu().numpy()
    r, image, bg_label = _render_over_background(rng, cfg.background, body.vertices, faces, camera)

    # Keypoints.
    kps = _subject_keypoints(rng, body, r.depth, noise_px, drop_prob, cfg)

    out_dir = Path(out_dir)
    _write_subject_files(out_dir, cfg, image, r.mask, kps.kp, kps.wb_kp, kps.coco_kp, camera)
    save_npz(out_dir / "gt.npz", _subject_truth(body, kps, noise_px, angles))

    vis = kps.vis
    return SubjectRecord(
        name=out_dir.name,
        pose=ps.name,
        description=ps.describe() + f"; yaw {yaw:.0f} deg",
        blend=ps.blend,
        blend_weight=ps.blend_weight,
        mirrored=ps.mirrored,
        yaw_deg=yaw,
        elevation_deg=elev,
        roll_deg=roll,
        fov_deg=fov,
        focal_px=camera.fx,
        distance_m=float(body.joints[0, 2]),
        stature_m=body.stature,
        fill=body.place.fill,
        truncated=body.place.truncated,
        noise_px=noise_px,
        keypoints_visible=int((vis == 2).sum()),
        keypoints_occluded=int((vis == 1).sum()),
        keypoints_outside=int((vis == 0).sum()),
        keypoints_dropped=int(kps.dropped.sum()),
        background=bg_label,
        hand_left=hands[0],
        hand_right=hands[1],
    )


# ----------------------------------------------------------------------------- a dataset
def subject_name(index: int) -> str:
    return f"subject_{index:03d}"


def generation_start(cfg: "SynthConfig", n, model, out) -> tuple:
    """The checks and set-up every generator shares: ``n`` positive, the model (the shipped open one of
    the kind ``cfg`` needs when ``None``; a whole-body set needs an SMPL-X-layout one), the output
    folder created. Returns ``(model, out)``."""
    if int(n) <= 0:
        raise ValueError(f"--n must be a positive number of subjects, got {n}")
    if model is None:
        model = load_body_model(kind="smplx" if cfg.whole_body else None)
    if cfg.whole_body and getattr(model, "kind", "smpl") != "smplx":
        raise ValueError(f"{model.source}: --whole-body needs an SMPL-X-layout model (this one is {model.kind})")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return model, out


def generate_dataset(
    out: os.PathLike,
    n: int,
    config: Optional[SynthConfig] = None,
    model=None,
    progress: bool = False,
    command: Optional[str] = None,
) -> dict:
    """Generate ``n`` subjects into ``out`` (``out/subject_000`` ...) and write ``out/index.json``;
    returns the index. ``model`` defaults to the shipped open body model."""
    cfg = (config or SynthConfig()).validate()
    model, out = generation_start(cfg, n, model, out)
    records: List[SubjectRecord] = []
    iterator = range(int(n))
    if progress:
        iterator = tqdm(iterator, desc="silfit synth", unit="subject")
    for i in iterator:
        records.append(generate_subject(model, i, cfg, out / subject_name(i)))
    index = {
        "format": "silfit-synthetic",
        "version": FORMAT_VERSION,
        "silfit_version": __version__,
        "generator": {
            **cfg.to_dict(),
            "n": int(n),
            "body_model": {
                "file": Path(str(model.source)).name,
                "vertices": int(model.num_vertices),
                "betas": int(model.num_betas),
                "kind": getattr(model, "kind", "smpl"),
            },
            "keypoints": "OpenPose BODY_25"
            + (" + hands 2x21 + face 70 (OpenPose whole-body)" if cfg.whole_body else "")
            + (" + COCO-17" if cfg.coco else ""),
            **({"command": command} if command else {}),
        },
        "subjects": [r.to_dict() for r in records],
    }
    (out / INDEX_NAME).write_text(json.dumps(index, indent=2) + "\n", encoding="utf-8")
    return index


def dataset_summary(index: dict) -> dict:
    """Distribution (min, median, max, mean) of statures, distances, yaws and fills of an index."""
    subs = index["subjects"]
    summary = {}
    for key in ("stature_m", "distance_m", "yaw_deg", "fov_deg", "fill"):
        vals = np.array([s[key] for s in subs], dtype=np.float64)
        summary[key] = {
            "min": round(float(vals.min()), 3),
            "median": round(float(np.median(vals)), 3),
            "max": round(float(vals.max()), 3),
            "mean": round(float(vals.mean()), 3),
        }
    summary["back_facing"] = int(sum(abs(s["yaw_deg"]) > 90 for s in subs))
    summary["truncated"] = int(sum(bool(s["truncated"]) for s in subs))
    return summary


def generate_hard_dataset(
    out: os.PathLike,
    n: int,
    seed: int = 0,
    size: int = 512,
    noise_px: float = 2.0,
    model=None,
    progress: bool = False,
    **settings,
) -> dict:
    """Write ``n`` hard subjects into ``out`` (``silfit synth --poses hard``); returns the index.
    ``settings`` are further :class:`silfit.synth.generate.SynthConfig` fields."""
    cfg = SynthConfig(seed=seed, size=size, noise_px=noise_px, poses="hard", frontal_first=False, **settings)
    return generate_dataset(out, n, cfg, model=model, progress=progress)
