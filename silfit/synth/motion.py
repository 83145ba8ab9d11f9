"""Short synthetic motions with per-frame ground truth (``silfit synth --videos``).

A motion is a cycle of key poses from the pose library (:mod:`silfit.poses.library`),
interpolated by a periodic cubic spline of every joint's axis-angle components (smooth to
the second derivative, so the truth's acceleration is well defined), plus a root motion in
a Y-up world: a heading (yaw) over time and a speed along it. The feet are kept on the
ground (each frame is lifted or lowered so its lowest vertex stays at the standing
height), and an optional camera orbit turns the world about the trajectory's centre.

Motions (:data:`MOTIONS`): ``walk``, ``run``, ``squat``, ``wave``, ``turn``.

A sequence folder (one camera)::

    seq_000/
      camera.json
      keypoints/seq_000_000000000000_keypoints.json ...   OpenPose JSON per frame, named as
                                                          OpenPose names a video's frames
      masks/seq_000_000000000000.png ...                  person masks
      images/seq_000_000000000000.png ...                 renders
      gt.npz   betas [10]; per frame: body_pose [F, 69], global_orient [F, 3], transl [F, 3],
               joints [F, 24, 3], keypoints_3d [F, 25, 3], keypoints_2d_clean [F, 25, 2],
               keypoints_visibility [F, 25], keypoints_dropped [F, 25], frame_dropped [F]
               (whole frames written with no person), fps, noise_px

and the dataset's ``index.json`` has ``"format": "silfit-synthetic-sequence"``.

A rig sequence (``silfit synth --videos --cameras N``, :func:`generate_rig_sequence`): the same
motion seen by ``N`` calibrated cameras on a ring (:func:`silfit.synth.camera_rigs.rig_layout`, placed so the
whole trajectory fits their frames), a rig folder whose views are video folders::

    seq_000/
      cameras.json                                      the rig (intrinsics, R, t per view)
      view_0/keypoints/view_0_000000000000_keypoints.json ...   per frame, as above
      view_0/masks/ ..., view_0/images/ ..., view_0/camera.json
      view_1/ ...
      gt.npz   world coordinates (y down, the trajectory's mean pelvis at the origin): betas [10];
               per frame body_pose, global_orient, transl, joints, keypoints_3d; per frame and view
               keypoints_2d_clean [F, C, 25, 2], keypoints_visibility [F, C, 25], frame_dropped [F, C]

(``index.json``: ``"format": "silfit-synthetic-sequence"``, ``"rig": N``).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from .. import __version__
from ..body import load_body_model
from ..camera import UPRIGHT_FACING_CAMERA, project_points, save_camera
from ..io.subjects import INDEX_NAME, save_npz, write_png
from ..io.keypoints import BODY25_NAMES, model_keypoints, write_openpose_json
from ..io.rig import view_to_dict, write_cameras_json
from ..poses.library import BODY_JOINTS, PERTURB_SCALE, get_pose, mirror_pose
from .camera_rigs import RigConfig, rig_layout, view_name
from .generate import BODY_COLOURS, SynthConfig, background_image, keypoint_visibility, noisy_keypoints, render_subject
from .sampler import place_body, sample_betas, sample_intrinsics

__all__ = [
    "MOTIONS",
    "SEQUENCE_FORMAT",
    "SequenceConfig",
    "frame_stem",
    "generate_rig_sequence",
    "generate_sequence",
    "generate_sequence_dataset",
    "motion_trajectory",
]

SEQUENCE_FORMAT = "silfit-synthetic-sequence"


@dataclass(frozen=True)
class Motion:
    """Key poses of one cycle (library names; ``~name`` is the mirrored pose; ``name@k``
    changes the right elbow's flexion by ``k`` degrees), the cycle's period (s), the speed
    along the heading (m/s) and the heading's total turn over the clip (degrees)."""

    keys: Tuple[str, ...]
    period: float
    speed: float = 0.0
    turn_deg: float = 0.0


MOTIONS: Dict[str, Motion] = {
    "walk": Motion(
        ("walk_left_heel_strike", "walk_right_midswing", "~walk_left_heel_strike", "~walk_right_midswing"), 1.1, 0.6
    ),
    "run": Motion(("run_stance", "run_flight", "~run_stance", "~run_flight"), 0.7, 1.0),
    "squat": Motion(("stand_relaxed", "squat_half", "squat_deep", "squat_half"), 2.0),
    "wave": Motion(("wave_right@-35", "wave_right@25"), 0.8),
    "turn": Motion(("stand_relaxed", "stand_contrapposto", "stand_relaxed", "~stand_contrapposto"), 1.6, 0.0, 150.0),
}


def _key_pose(spec: str) -> np.ndarray:
    bend = 0.0
    if "@" in spec:
        spec, k = spec.split("@")
        bend = float(k)
    mirrored = spec.startswith("~")
    pose = get_pose(spec.lstrip("~")).body_pose.copy()
    if mirrored:
        pose = mirror_pose(pose)
    if bend:
        i = BODY_JOINTS.index("right_elbow")
        pose[3 * i + 1] += math.radians(bend)  # the right elbow flexes about +Y (library.elbow, mirrored)
    return pose


def motion_trajectory(name: str, frames: int, fps: float, phase: float = 0.0) -> Dict[str, np.ndarray]:
    """``body_pose [F, 69]``, heading ``yaw [F]`` (degrees, relative to the start) and the
    distance travelled along it ``distance [F]`` (m) of motion ``name`` over ``frames``
    frames at ``fps``; ``phase`` (0..1) shifts the cycle's start."""
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; expected one of {', '.join(MOTIONS)}")
    m = MOTIONS[name]
    keys = np.stack([_key_pose(k) for k in m.keys])
    n = len(keys)
    knots = np.linspace(0.0, m.period, n + 1)
    spline = CubicSpline(knots, np.concatenate([keys, keys[:1]]), axis=0, bc_type="periodic")
    t = np.arange(int(frames)) / float(fps)
    pose = spline((t + phase * m.period) % m.period)
    u = t / max(t[-1], 1e-9)
    yaw = m.turn_deg * (0.5 - 0.5 * np.cos(math.pi * u))  # eased turn
    return {"body_pose": pose, "yaw": yaw, "distance": m.speed * t}


@dataclass
class SequenceConfig:
    """Settings of ``silfit synth --videos`` (recorded in ``index.json``)."""

    seed: int = 0
    frames: int = 60
    fps: float = 30.0
    size: int = 512
    noise_px: float = 2.0
    drop_prob: float = 0.0  # per keypoint and frame
    drop_frames: float = 0.0  # probability of a frame with no person detected (never the first or last)
    motions: Tuple[str, ...] = tuple(MOTIONS)  # sequence i gets motions[i % len]
    orbit_deg: float = 0.0  # camera orbit about the trajectory's centre over the clip
    fov_deg: Tuple[float, float] = (45.0, 65.0)
    fill: Tuple[float, float] = (0.6, 0.85)  # the whole trajectory's box / image
    elevation_deg: float = 10.0
    perturb_deg: float = 4.0  # one perturbation of the joints for the whole clip
    background: str = "mixed"
    conf_visible: Tuple[float, float] = (0.6, 1.0)
    conf_occluded: Tuple[float, float] = (0.1, 0.3)

    def validate(self) -> "SequenceConfig":
        if self.frames < 3:
            raise ValueError(f"--frames must be at least 3, got {self.frames}")
        if self.fps <= 0:
            raise ValueError(f"--fps must be positive, got {self.fps}")
        if self.size < 16:
            raise ValueError(f"--size must be at least 16 pixels, got {self.size}")
        if self.noise_px < 0:
            raise ValueError(f"--noise-px must be >= 0, got {self.noise_px}")
        for name in ("drop_prob", "drop_frames"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        unknown = [m for m in self.motions if m not in MOTIONS]
        if unknown or not self.motions:
            raise ValueError(
                f"unknown motion(s) {', '.join(unknown) or '(none)'}; expected some of {', '.join(MOTIONS)}"
            )
        return self

    def to_dict(self) -> dict:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}


def frame_stem(sequence: str, frame: int) -> str:
    """OpenPose's name of a video frame: ``<video>_<frame, 12 digits>``."""
    return f"{sequence}_{int(frame):012d}"


def _perturbation(rng, deg: float) -> np.ndarray:
    scale = np.repeat([PERTURB_SCALE.get(j, 1.0) for j in BODY_JOINTS], 3)
    return rng.normal(0.0, math.radians(deg), 69) * scale


def _world_motion(model, rng, cfg: SequenceConfig, index: int, orbit: Optional[np.ndarray] = None) -> dict:
    """Sequence ``index``'s motion in a Y-up world (draws the phase, a perturbation, the shape and the
    heading from ``rng``, in that order): ``motion``, ``betas [L]``, ``body_pose [F, 69]``, the root's
    rotation ``R_world`` (``F`` rotations), ``T_w [F, 3]`` (translation of the body posed at the
    origin: feet on the ground), ``v_w [F, V, 3]`` (vertices posed at the origin), ``j0`` (the shaped
    pelvis: the centre of the root rotation) and ``yaw0``. ``orbit [F]`` (degrees) turns the world
    about the trajectory's centre (a camera circling the subject)."""
    F = int(cfg.frames)
    motion = cfg.motions[index % len(cfg.motions)]
    traj = motion_trajectory(motion, F, cfg.fps, phase=float(rng.uniform()))
    body_pose = traj["body_pose"] + _perturbation(rng, cfg.perturb_deg)
    betas = sample_betas(rng, model.num_betas, 2.0)
    yaw0 = float(rng.uniform(-180.0, 180.0))
    orbit = np.zeros(F) if orbit is None else orbit
    # World (Y up): heading yaw0 + yaw(t), position along it; the orbit turns the world about
    # the trajectory's centre (a camera circling the subject).
    yaw = yaw0 + traj["yaw"]
    heading = np.stack([np.sin(np.radians(yaw)), np.zeros(F), np.cos(np.radians(yaw))], 1)
    step = np.diff(traj["distance"], prepend=0.0)[:, None] * heading
    pos = np.cumsum(step, 0)
    pos -= pos.mean(0)
    R_world = Rotation.from_rotvec(np.radians(yaw - orbit)[:, None] * np.array([0.0, 1.0, 0.0]))
    pos = Rotation.from_rotvec(-np.radians(orbit)[:, None] * np.array([0.0, 1.0, 0.0])).apply(pos)
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=model.dtype, device=model.device)  # noqa: E731
    with torch.no_grad():
        out_w = model(
            betas=T(np.repeat(betas[None], F, 0)),
            body_pose=T(body_pose),
            global_orient=T(R_world.as_rotvec()),
            transl=T(np.zeros((F, 3))),
        )
        v_w = out_w.vertices.double().cpu().numpy()
        rest = model(
            betas=T(betas[None]),
            body_pose=T(np.zeros((1, 69))),
            global_orient=T(np.zeros((1, 3))),
            transl=T(np.zeros((1, 3))),
        )
    j0 = rest.joints[0, 0].double().cpu().numpy()  # the shaped pelvis: the centre of the root rotation
    # feet on the ground: the lowest vertex of each frame at the first frame's height
    low = v_w[..., 1].min(1)
    T_w = pos + np.stack([np.zeros(F), low[0] - low, np.zeros(F)], 1)
    return {
        "motion": motion,
        "betas": betas,
        "body_pose": body_pose,
        "R_world": R_world,
        "T_w": T_w,
        "v_w": v_w,
        "j0": j0,
        "yaw0": yaw0,
    }


def _posed_frames(model, params: dict, F: int) -> tuple:
    """``(model output, BODY_25 keypoints [F, 25, 3] as a float64 tensor)`` of a sequence's ``params`` (one shape)."""
    T = lambda a: torch.as_tensor(np.asarray(a), dtype=model.dtype, device=model.device)  # noqa: E731
    with torch.no_grad():
        out = model(
            betas=T(np.repeat(params["betas"][None], F, 0)),
            body_pose=T(params["body_pose"]),
            global_orient=T(params["global_orient"]),
            transl=T(params["transl"]),
        )
        kp3d = model_keypoints(model, out, "body25").double()
    return out, kp3d


def _camera_frame_params(rng, cfg: SequenceConfig, wm: dict, W: int) -> tuple:
    """``(params, camera, fov, elevation)``: the world motion ``wm`` seen by one camera at a random elevation (drawn
    from ``rng``, then the intrinsics, then the placement framing the whole trajectory)."""
    R_world, T_w, v_w, j0 = wm["R_world"], wm["T_w"], wm["v_w"], wm["j0"]
    elev = float(rng.uniform(-cfg.elevation_deg, cfg.elevation_deg))
    camera, fov = sample_intrinsics(rng, W, W, cfg.fov_deg)
    C = Rotation.from_rotvec([math.radians(elev), 0.0, 0.0]) * Rotation.from_rotvec(UPRIGHT_FACING_CAMERA)
    v_cam = C.apply((v_w + T_w[:, None]).reshape(-1, 3)).reshape(v_w.shape)
    place = place_body(rng, v_cam[:, ::20].reshape(-1, 3), camera, fill=cfg.fill)
    orient_c = (C * R_world).as_rotvec()
    transl_c = C.apply(j0 + T_w) + place.transl - j0
    params = {
        "betas": wm["betas"].astype(np.float32),
        "body_pose": wm["body_pose"].astype(np.float32),
        "global_orient": orient_c.astype(np.float32),
        "transl": transl_c.astype(np.float32),
    }
    return params, camera, fov, elev


def _write_video_frames(
    rng, folder: Path, name: str, frames: dict, camera, faces, colour, bg, frame_dropped, cfg: SequenceConfig
) -> tuple:
    """Render, detect and write every frame (``frames``: ``vertices``, ``kp3d``, ``kp2d`` per frame, camera frame) of
    one video folder (keypoints/, masks/, images/); returns ``(visibility [F, 25], dropped keypoints [F, 25])``."""
    F = len(frame_dropped)
    vis_all, drop_all = np.zeros((F, 25), np.int8), np.zeros((F, 25), bool)
    for f in range(F):
        r = render_subject(frames["vertices"][f], faces, camera, colour)
        vis = keypoint_visibility(frames["kp3d"][f], frames["kp2d"][f], r.depth, BODY25_NAMES)
        kp, dropped = noisy_keypoints(
            rng, frames["kp2d"][f], vis, cfg.noise_px, cfg.drop_prob, cfg.conf_visible, cfg.conf_occluded
        )
        vis_all[f], drop_all[f] = vis, dropped
        stem = frame_stem(name, f)
        write_openpose_json(
            folder / "keypoints" / f"{stem}_keypoints.json", np.zeros((0, 25, 3)) if frame_dropped[f] else kp
        )
        write_png(folder / "masks" / f"{stem}.png", r.mask)
        write_png(folder / "images" / f"{stem}.png", np.where(r.mask[..., None], r.color, bg).astype(np.uint8))
    return vis_all, drop_all


def generate_sequence(model, index: int, cfg: SequenceConfig, out_dir: Path) -> dict:
    """Sample, render and write sequence ``index`` into ``out_dir``; returns its index record."""
    rng = np.random.default_rng([int(cfg.seed), int(index), 7])
    F, W = int(cfg.frames), int(cfg.size)
    orbit = cfg.orbit_deg * np.linspace(0.0, 1.0, F)
    wm = _world_motion(model, rng, cfg, index, orbit)
    params, camera, fov, elev = _camera_frame_params(rng, cfg, wm, W)
    out, kp3d = _posed_frames(model, params, F)
    kp2d = project_points(kp3d, camera).cpu().numpy()
    vertices = out.vertices.cpu().numpy().astype(np.float32)
    joints = out.joints.cpu().numpy().astype(np.float32)
    kp3d = kp3d.cpu().numpy()

    colour = BODY_COLOURS[int(rng.integers(len(BODY_COLOURS)))]
    bg, _ = background_image(rng, cfg.background, W, W)
    faces = model.faces.cpu().numpy()
    frame_dropped = rng.random(F) < cfg.drop_frames
    frame_dropped[[0, -1]] = False
    out_dir = Path(out_dir)
    for sub in ("keypoints", "masks", "images"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    name = out_dir.name
    frames = {"vertices": vertices, "kp3d": kp3d, "kp2d": kp2d}
    vis_all, drop_all = _write_video_frames(rng, out_dir, name, frames, camera, faces, colour, bg, frame_dropped, cfg)
    save_camera(camera, out_dir / "camera.json")
    save_npz(
        out_dir / "gt.npz",
        {
            **params,
            "joints": joints,
            "keypoints_3d": kp3d.astype(np.float32),
            "keypoints_2d_clean": kp2d,
            "keypoints_visibility": vis_all,
            "keypoints_dropped": drop_all,
            "frame_dropped": frame_dropped,
            "fps": np.float64(cfg.fps),
            "noise_px": np.float64(cfg.noise_px),
        },
    )
    return {
        "name": name,
        "motion": wm["motion"],
        "frames": F,
        "fps": cfg.fps,
        "yaw_deg": round(wm["yaw0"], 2),
        "elevation_deg": round(elev, 2),
        "fov_deg": round(fov, 3),
        "orbit_deg": cfg.orbit_deg,
        "frames_dropped": int(frame_dropped.sum()),
        "keypoints_dropped": int(drop_all.sum()),
        "distance_m": round(float(joints[:, 0, 2].mean()), 3),
    }


def _rig_world_params(wm: dict) -> dict:
    """The stored parameters of a world motion ``wm`` in the rig's world: y down (the Y-up world turned 180 degrees
    about x), the mean pelvis at the origin."""
    flip = Rotation.from_rotvec([math.pi, 0.0, 0.0])
    j0 = wm["j0"]
    orient = (flip * wm["R_world"]).as_rotvec()
    transl = flip.apply(j0 + wm["T_w"]) - j0
    transl -= transl.mean(0) + j0
    return {
        "betas": wm["betas"].astype(np.float32),
        "body_pose": wm["body_pose"].astype(np.float32),
        "global_orient": orient.astype(np.float32),
        "transl": transl.astype(np.float32),
    }


def _trajectory_layout(rng, vertices: np.ndarray, cfg: SequenceConfig, views: int) -> list:
    """``views`` cameras on a ring framing the whole trajectory (its box's largest side stands in for the body's
    height)."""
    box = vertices.reshape(-1, 3)
    extent = float((box.max(0) - box.min(0)).max())
    synth = SynthConfig(seed=cfg.seed, size=int(cfg.size), fov_deg=tuple(cfg.fov_deg), fill=tuple(cfg.fill))
    return rig_layout(rng, np.array([[0.0, -extent / 2, 0.0], [0.0, extent / 2, 0.0]]), synth, RigConfig(views=views))


def _write_rig_video_view(
    rng, folder: Path, view, vertices, kp3d, faces, colour, cfg: SequenceConfig
) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One view of a rig sequence: its video folder (camera.json, keypoints/, masks/, images/) written; returns
    ``(clean 2D keypoints [F, 25, 2], visibility [F, 25], frames dropped [F])``."""
    F, W = len(vertices), int(cfg.size)
    name = folder.name
    for sub in ("keypoints", "masks", "images"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    (folder / "camera.json").write_text(json.dumps(view_to_dict(view), indent=2) + "\n", encoding="utf-8")
    R, t = view.extrinsics()
    bg, _ = background_image(rng, cfg.background, W, W)
    drop = rng.random(F) < cfg.drop_frames
    drop[[0, -1]] = False
    clean, vis_all = np.zeros((F, 25, 2)), np.zeros((F, 25), np.int8)
    for f in range(F):
        v_cam, k_cam = vertices[f] @ R.T + t, kp3d[f] @ R.T + t
        kp2d = project_points(torch.as_tensor(k_cam), view.camera).numpy()
        r = render_subject(v_cam.astype(np.float32), faces, view.camera, colour)
        vis = keypoint_visibility(k_cam, kp2d, r.depth, BODY25_NAMES)
        kp, _ = noisy_keypoints(rng, kp2d, vis, cfg.noise_px, cfg.drop_prob, cfg.conf_visible, cfg.conf_occluded)
        clean[f], vis_all[f] = kp2d, vis
        stem = frame_stem(name, f)
        write_openpose_json(folder / "keypoints" / f"{stem}_keypoints.json", np.zeros((0, 25, 3)) if drop[f] else kp)
        write_png(folder / "masks" / f"{stem}.png", r.mask)
        write_png(folder / "images" / f"{stem}.png", np.where(r.mask[..., None], r.color, bg).astype(np.uint8))
    return clean, vis_all, drop


def generate_rig_sequence(model, index: int, cfg: SequenceConfig, views: int, out_dir: Path) -> dict:
    """Sample, render and write rig sequence ``index`` (``views`` cameras, module docstring) into
    ``out_dir``; returns its index record."""
    rng = np.random.default_rng([int(cfg.seed), int(index), 11])
    F = int(cfg.frames)
    wm = _world_motion(model, rng, cfg, index)
    params = _rig_world_params(wm)
    out, kp3d = _posed_frames(model, params, F)
    kp3d = kp3d.cpu().numpy()
    vertices = out.vertices.double().cpu().numpy()
    layout = _trajectory_layout(rng, vertices, cfg, views)
    colour = BODY_COLOURS[int(rng.integers(len(BODY_COLOURS)))]
    faces = model.faces.cpu().numpy()
    out_dir = Path(out_dir)
    C = len(layout)
    clean, vis_all, dropped_frames = np.zeros((F, C, 25, 2)), np.zeros((F, C, 25), np.int8), np.zeros((F, C), bool)
    for c, view in enumerate(layout):
        folder = out_dir / view_name(c)
        clean[:, c], vis_all[:, c], dropped_frames[:, c] = _write_rig_video_view(
            rng, folder, view, vertices, kp3d, faces, colour, cfg
        )
    write_cameras_json(out_dir / "cameras.json", [(view_name(c), v) for c, v in enumerate(layout)])
    save_npz(
        out_dir / "gt.npz",
        {
            **params,
            "joints": out.joints.cpu().numpy().astype(np.float32),
            "keypoints_3d": kp3d.astype(np.float32),
            "keypoints_2d_clean": clean,
            "keypoints_visibility": vis_all,
            "frame_dropped": dropped_frames,
            "fps": np.float64(cfg.fps),
            "noise_px": np.float64(cfg.noise_px),
            "views": np.int64(C),
        },
    )
    return {
        "name": out_dir.name,
        "motion": wm["motion"],
        "frames": F,
        "fps": cfg.fps,
        "views": C,
        "yaw_deg": round(wm["yaw0"], 2),
        "frames_dropped": int(dropped_frames.sum()),
    }


def generate_sequence_dataset(
    out: os.PathLike,
    n: int,
    config: Optional[SequenceConfig] = None,
    model=None,
    progress: bool = False,
    command: Optional[str] = None,
    views: Optional[int] = None,
) -> dict:
    """Generate ``n`` sequences into ``out/seq_000`` ... and write ``out/index.json``; with ``views``,
    rig sequences (:func:`generate_rig_sequence`)."""
    cfg = (config or SequenceConfig()).validate()
    if int(n) <= 0:
        raise ValueError(f"--n must be a positive number of sequences, got {n}")
    if model is None:
        model = load_body_model()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    iterator = range(int(n))
    if progress:
        iterator = tqdm(iterator, desc="silfit synth --videos", unit="sequence")
    if views is not None and not 1 <= int(views) <= 64:
        raise ValueError(f"--cameras must be 1..64, got {views}")
    records: List[dict] = [
        generate_sequence(model, i, cfg, out / f"seq_{i:03d}")
        if views is None
        else generate_rig_sequence(model, i, cfg, int(views), out / f"seq_{i:03d}")
        for i in iterator
    ]
    index = {
        "format": SEQUENCE_FORMAT,
        "version": 1,
        "silfit_version": __version__,
        **({"rig": int(views)} if views else {}),
        "generator": {**cfg.to_dict(), "n": int(n), **({"command": command} if command else {})},
        "sequences": records,
    }
    (out / INDEX_NAME).write_text(json.dumps(index, indent=2) + "\n", encoding="utf-8")
    return index
