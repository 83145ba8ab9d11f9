"""Synthetic camera rigs: one body seen by ``N`` calibrated cameras, with shared ground truth.

``silfit synth --cameras N`` writes, per subject::

    subject_000/cameras.json        the rig (silfit.io.rig's manifest: intrinsics, R, t per view)
    subject_000/gt.npz              the truth in world coordinates (params, vertices, joints,
                                    keypoints_3d) + per-view clean projections and visibility
    subject_000/view_0/             image.png, mask.png, keypoints.json, camera.json (with R, t)
    ...

World frame: y down (OpenCV-like, gravity along +y), the body's pelvis at the origin,
upright, turned by a random yaw. Cameras (:func:`rig_layout`): a ring around the body,
evenly spaced in azimuth from a random start (plus a few degrees of jitter), at heights
varied between ``heights_m`` (relative to the pelvis; two cameras: 90 degrees apart), looking at the pelvis, each at the
distance that makes the body fill a share ``fill`` of its frame; or the cameras of a given
``cameras.json`` (``layout``). Keypoints, visibility, noise and dropping per view as in
:mod:`silfit.synth.generate`; subject ``i`` uses ``default_rng([seed, i])``. With
``SynthConfig.whole_body`` (an SMPL-X-layout model) the body also gets hand poses, an expression and a
jaw as :func:`~silfit.synth.generate.sample_wholebody_params` draws them, and every view's
``keypoints.json`` holds OpenPose whole-body parts (hands and face, each point's visibility per view).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import numpy as np
import torch
from tqdm import tqdm

from .. import __version__
from ..camera import project_points
from ..io.subjects import INDEX_NAME, save_npz, write_png
from ..fitting.problem import View
from ..io.keypoints import BODY25_NAMES, model_keypoints, write_openpose_json
from ..io.rig import look_at, view_to_dict, write_cameras_json
from ..io.wholebody import wholebody_keypoints, write_wholebody_json
from .generate import (
    BODY_COLOURS,
    WHOLEBODY_DEPTH_TOLERANCE,
    WHOLEBODY_PARTS,
    SynthConfig,
    background_image,
    generation_start,
    keypoint_visibility,
    noisy_keypoints,
    render_subject,
    sample_wholebody_params,
    subject_name,
    wholebody_names,
)
from .sampler import global_orientation, sample_betas, sample_intrinsics, sample_pose

__all__ = ["RigConfig", "generate_rig_dataset", "generate_rig_subject", "rig_layout", "view_name"]


@dataclass
class RigConfig:
    """Camera placement of a synthetic rig (the rest comes from :class:`SynthConfig`)."""

    views: int = 4
    heights_m: Tuple[float, float] = (-0.3, 1.0)  # camera heights relative to the pelvis
    azimuth_jitter_deg: float = 10.0
    layout: Optional[List[View]] = None  # fixed cameras (from a cameras.json) instead of the ring

    def validate(self) -> "RigConfig":
        if self.layout is None and not 1 <= int(self.views) <= 64:
            raise ValueError(f"--cameras must be 1..64, got {self.views}")
        if self.heights_m[0] > self.heights_m[1]:
            raise ValueError(f"camera height range must be low first, got {self.heights_m}")
        return self


def view_name(i: int) -> str:
    return f"view_{i}"


def rig_layout(rng: np.random.Generator, vertices: np.ndarray, cfg: SynthConfig, rig: RigConfig) -> List[View]:
    """``rig.views`` cameras around world-frame ``vertices`` (see the module docstring)."""
    n = int(rig.views)
    start = rng.uniform(0.0, 360.0)
    lo, hi = vertices.min(0), vertices.max(0)
    height = float(hi[1] - lo[1])
    out = []
    for i in range(n):
        cam, _ = sample_intrinsics(rng, cfg.size, cfg.size, cfg.fov_deg)
        spacing = 90.0 if n == 2 else 360.0 / n  # two opposite cameras would see the body along one line
        az = math.radians(start + spacing * i + rng.uniform(-rig.azimuth_jitter_deg, rig.azimuth_jitter_deg))
        h = rng.uniform(*rig.heights_m)
        fill = rng.uniform(*cfg.fill)
        target = np.array([0.0, rng.uniform(-0.1, 0.1), 0.0])
        dist = cam.fy * height / (fill * cfg.size) + 0.3
        horiz = math.sqrt(max(dist**2 - h**2, 0.25))
        centre = np.array([horiz * math.sin(az), -h, -horiz * math.cos(az)])
        R, t = look_at(centre, target)
        out.append(View(cam, R, t))
    return out


def _view_part_keypoints(
    rng, parts3d: dict, view, depth, noise_px: float, drop_prob: float, cfg, wb_clean: dict
) -> dict:
    """Whole body: each part's (hands', face's) noisy keypoints in ``view``, visibility by its rendered ``depth``; the
    clean projections appended to ``wb_clean[part]``."""
    R, t = view.extrinsics()
    parts = {}
    for part, p3 in parts3d.items():
        pc = p3 @ R.T + t
        p2 = project_points(torch.as_tensor(pc), view.camera).numpy()
        pvis = keypoint_visibility(pc, p2, depth, wholebody_names(part), WHOLEBODY_DEPTH_TOLERANCE)
        scale = cfg.hand_noise_scale if part.startswith("hand") else cfg.face_noise_scale
        parts[part] = noisy_keypoints(rng, p2, pvis, noise_px * scale, drop_prob, cfg.conf_visible, cfg.conf_occluded)[
            0
        ]
        wb_clean.setdefault(part, []).append(p2)
    return parts


def _write_view_files(folder: Path, view, image, mask, kp, parts: dict) -> None:
    """One view's folder: image.png, mask.png, keypoints.json (whole-body where ``parts`` holds hands and face) and
    camera.json (with R, t)."""
    folder.mkdir(exist_ok=True)
    write_png(folder / "image.png", image)
    write_png(folder / "mask.png", mask)
    if parts:
        write_wholebody_json(folder / "keypoints.json", kp, parts["hand_left"], parts["hand_right"], parts["face"])
    else:
        write_openpose_json(folder / "keypoints.json", kp)
    (folder / "camera.json").write_text(json.dumps(view_to_dict(view), indent=2) + "\n", encoding="utf-8")


def _sample_rig_body(rng, model, cfg: SynthConfig) -> tuple:
    """``(pose sample, yaw, pose {betas, body_pose, global_orient}, extra whole-body parameters)`` of a rig subject,
    drawn from ``rng`` in that order (the whole-body parameters last: body-only rigs unchanged)."""
    ps = sample_pose(rng, perturb_deg=cfg.perturb_deg, blend_prob=cfg.blend_prob, mirror_prob=cfg.mirror_prob)
    yaw = float(rng.uniform(*cfg.yaw_range_deg))
    betas = sample_betas(rng, model.num_betas, cfg.beta_truncation)
    global_orient = global_orientation(yaw, 0.0, 0.0, root=ps.root)
    body_pose = ps.body_pose[: model.num_body_pose]
    extra = (
        sample_wholebody_params(rng, model, cfg)[0] if cfg.whole_body else {}
    )  # drawn last: body-only rigs unchanged
    return ps, yaw, {"betas": betas, "body_pose": body_pose, "global_orient": global_orient}, extra


@dataclass
class RigBody:
    """A rig subject's body in the world (pelvis at the origin): stored parameters, keypoints, vertices, stature."""

    params: dict
    kp3d: np.ndarray
    parts3d: dict
    vertices: np.ndarray
    joints: np.ndarray
    stature: float


def _posed_rig_body(model, whole_body: bool, pose: dict, extra: dict) -> RigBody:
    """The body ``pose`` (+ ``extra``) moved so that its pelvis is at the origin, evaluated at the stored precision."""
    betas, body_pose, global_orient = pose["betas"], pose["body_pose"], pose["global_orient"]
    as_t = lambda a: torch.as_tensor(np.asarray(a)[None], dtype=model.dtype, device=model.device)  # noqa: E731
    with torch.no_grad():
        out0 = model(
            betas=as_t(betas),
            body_pose=as_t(body_pose),
            global_orient=as_t(global_orient),
            **{k: as_t(v) for k, v in extra.items()},
        )
        transl = -out0.joints[0, 0].double().cpu().numpy()
        params = {
            "betas": betas.astype(np.float32),
            "body_pose": body_pose.astype(np.float32),
            "global_orient": global_orient.astype(np.float32),
            "transl": transl.astype(np.float32),
            **{k: np.asarray(v, np.float32) for k, v in extra.items()},
        }
        out = model(**{k: as_t(v) for k, v in params.items()})
        kp3d = model_keypoints(model, out, "body25")[0].double().cpu().numpy()
        parts3d = {}
        if whole_body:
            wb = wholebody_keypoints(model, out)
            parts3d = {p: wb[p][0].double().cpu().numpy() for p in WHOLEBODY_PARTS}
        rest = model.rest_vertices(as_t(betas))[0]
    vertices = out.vertices[0].double().cpu().numpy()
    joints = out.joints[0].cpu().numpy().astype(np.float32)
    stature = float(rest[:, 1].max() - rest[:, 1].min())
    return RigBody(params, kp3d, parts3d, vertices, joints, stature)


def _render_rig_views(
    rng, views, body: RigBody, faces, colour, cfg: SynthConfig, noise_px: float, drop_prob: float, out_dir: Path
) -> tuple:
    """Render, detect and write every view's folder; returns ``(clean 2D keypoints, visibility, visible counts,
    whole-body clean projections)``, one entry per view."""
    clean2d, visibility, counts, wb_clean = [], [], [], {}
    for c, view in enumerate(views):
        R, t = view.extrinsics()
        cam = view.camera
        v_cam = body.vertices @ R.T + t
        k_cam = body.kp3d @ R.T + t
        kp2d = project_points(torch.as_tensor(k_cam), cam).numpy()
        r = render_subject(v_cam.astype(np.float32), faces, cam, colour)
        bg, _ = background_image(rng, cfg.background, cam.height, cam.width)
        image = np.where(r.mask[..., None], r.color, bg).astype(np.uint8)
        vis = keypoint_visibility(k_cam, kp2d, r.depth, BODY25_NAMES)
        kp, _ = noisy_keypoints(rng, kp2d, vis, noise_px, drop_prob, cfg.conf_visible, cfg.conf_occluded)
        parts = _view_part_keypoints(rng, body.parts3d, view, r.depth, noise_px, drop_prob, cfg, wb_clean)
        _write_view_files(out_dir / view_name(c), view, image, r.mask, kp, parts)
        clean2d.append(kp2d)
        visibility.append(vis)
        counts.append(int((vis == 2).sum()))
    return clean2d, visibility, counts, wb_clean


def generate_rig_subject(model, index: int, config: SynthConfig, rig: RigConfig, out_dir: Path) -> dict:
    """Sample, render (every view) and write rig subject ``index`` into ``out_dir``; returns its record."""
    cfg = config
    rng = np.random.default_rng([int(cfg.seed), int(index)])
    clean = index < cfg.clean
    noise_px = 0.0 if clean else float(cfg.noise_px)
    drop_prob = 0.0 if clean else float(cfg.drop_prob)
    ps, yaw, pose, extra = _sample_rig_body(rng, model, cfg)
    body = _posed_rig_body(model, cfg.whole_body, pose, extra)
    views = rig.layout if rig.layout is not None else rig_layout(rng, body.vertices, cfg, rig)
    faces = model.faces.cpu().numpy()
    colour = BODY_COLOURS[int(rng.integers(len(BODY_COLOURS)))]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    clean2d, visibility, counts, wb_clean = _render_rig_views(
        rng, views, body, faces, colour, cfg, noise_px, drop_prob, out_dir
    )
    write_cameras_json(out_dir / "cameras.json", [(view_name(c), v) for c, v in enumerate(views)])
    save_npz(
        out_dir / "gt.npz",
        {
            **body.params,
            "vertices": body.vertices.astype(np.float32),
            "joints": body.joints,
            "keypoints_3d": body.kp3d.astype(np.float32),
            "keypoints_2d_clean": np.asarray(clean2d),
            "keypoints_visibility": np.asarray(visibility, np.int8),
            "stature": np.float64(body.stature),
            "noise_px": np.float64(noise_px),
            "views": np.int64(len(views)),
            **{f"{p}_3d": v.astype(np.float32) for p, v in body.parts3d.items()},
            **{f"{p}_2d_clean": np.asarray(v) for p, v in wb_clean.items()},
        },
    )
    return {
        "name": out_dir.name,
        "pose": ps.name,
        "yaw_deg": round(yaw, 4),
        "stature_m": round(body.stature, 4),
        "views": len(views),
        "noise_px": noise_px,
        "keypoints_visible_per_view": counts,
    }


def generate_rig_dataset(
    out, n: int, config: SynthConfig, rig: RigConfig, model=None, progress=False, command=None
) -> dict:
    """``n`` rig subjects into ``out`` and ``out/index.json`` (``"rig": views``)."""

    cfg, rig = config.validate(), rig.validate()
    model, out = generation_start(cfg, n, model, out)
    it: Sequence[int] = range(int(n))
    if progress:
        it = tqdm(it, desc="silfit synth --cameras", unit="subject")
    records = [generate_rig_subject(model, i, cfg, rig, out / subject_name(i)) for i in it]
    views = len(rig.layout) if rig.layout is not None else int(rig.views)
    index = {
        "format": "silfit-synthetic-rig",
        "version": 1,
        "silfit_version": __version__,
        "rig": views,
        "generator": {
            **cfg.to_dict(),
            "n": int(n),
            "views": views,
            "heights_m": list(rig.heights_m),
            "layout": rig.layout is not None,
            **({"command": command} if command else {}),
        },
        "subjects": records,
    }
    (out / INDEX_NAME).write_text(json.dumps(index, indent=2) + "\n", encoding="utf-8")
    return index
