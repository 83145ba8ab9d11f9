"""The keypoint stage: SMPLify in torch, batched.

Stages (each an independent per-sample L-BFGS, see :mod:`silfit.fitting.optim`):

1. ``init``: depth by similar triangles (the model's rest torso length vs the 2D torso
   length), translation from the 2D torso centre, in-plane roll from the 2D torso
   direction; two starts per sample, facing the camera and the 180-degree flipped one
   (a doubled batch).
2. ``camera``: ``global_orient`` and ``transl`` on the torso keypoints, with a depth
   regulariser towards the similar-triangles depth.
3. ``pose_1..3``: ``body_pose`` (+ orientation, translation) on all keypoints with the
   pose prior weight annealed from high to low. ``pose_1`` starts every placed start
   (facing / flipped) from several initial body poses (the zero pose and the pose prior's
   most probable means, ``init_poses``), all in one batch; after ``decision_iters`` steps
   each sample keeps the start with the lowest energy: the torso alone cannot tell a side
   view's facing, the nose, ears and feet can, and a good initial pose avoids the wrong
   branch of the depth ambiguity of bent limbs.
4. ``shape``: ``betas`` (+ translation) with the L2 shape prior.
5. ``final``: everything together with the interpenetration penalty on.

Data term: Geman-McClure (SMPLify's robust penalty, ``sigma`` = 100) on residuals in
*normalised pixels*: each sample's residuals are scaled so the extent of its confident
keypoints is ``norm_extent`` (500) pixels, which makes the weights independent of the
image resolution and of how large the person appears. Each keypoint is weighted by its
confidence times a per-keypoint weight (hips 0.5: SMPL's hip joints sit higher and
further inside than detectors' hip points). Zero-confidence keypoints contribute
nothing.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Optional, Sequence, Union

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..camera import UPRIGHT_BACK_TO_CAMERA, UPRIGHT_FACING_CAMERA, Camera, project_points
from ..keypoints import LAYOUTS, KeypointSet
from ..priors import SphereCollisionModel, angle_prior, limit_violation, load_pose_prior, shape_prior
from .body import KeypointBody
from .losses import reprojection_energy
from .optim import batched_lbfgs
from .result import KeypointFitResult
from .threads import torch_threads

__all__ = ["KeypointFitConfig", "KeypointFitter", "fit_keypoints", "prepare_keypoints"]

_UPPER = ("left_shoulder", "right_shoulder", "neck")
_LOWER = ("left_hip", "right_hip", "mid_hip")
_TORSO_ALL = _UPPER + _LOWER
MIN_TORSO_KEYPOINTS = 3


@dataclass
class KeypointFitConfig:
    """Weights and iteration counts of the keypoint stage (defaults tuned on synthetic data)."""

    sigma: float = 100.0
    norm_extent: float = 500.0
    hip_weight: float = 0.5
    keypoint_weights: dict = field(default_factory=dict)  # name -> extra weight
    prefer_landmarks: bool = False
    flip_test: bool = True
    #: initial body poses tried per sample (and per facing): the zero pose, then the pose
    #: prior's most probable mixture means; all run as one batch (the camera stage is shared
    #: by a facing's starts) and the lowest energy is kept. 4 starts cut the median PA-MPJPE
    #: on 30 library-posed synthetic subjects from 95 to 66 mm (benchmarks/bench_fit.py) at
    #: about 1.5x the batched cost; set 1 for the fastest batched throughput.
    init_poses: int = 4
    #: after which pose sub-stage (0-based) each sample keeps the best of its starts
    flip_decision_stage: int = 0
    #: steps of that sub-stage run with every start before choosing (0: the whole sub-stage);
    #: its remaining steps continue from the chosen start only
    decision_iters: int = 20
    robust: bool = True  # False: plain L2 data term (for comparisons)
    camera_iters: int = 30
    pose_iters: Sequence[int] = (30, 30, 40)
    #: Annealed pose-prior weights, tuned for the shipped library mixture
    #: (:class:`~silfit.priors.LibraryMixturePrior`; about 10x the weights that suited the
    #: old split-normal default, whose energies are on a similar scale but which needed less
    #: pull; see ``benchmarks/bench_fit.py``). With ``pose_prior="limits"`` or SMPLify's
    #: ``gmm_08.pkl`` consider lower weights (the old defaults were 200, 40, 8 and 4).
    pose_prior_weights: Sequence[float] = (2000.0, 400.0, 80.0)
    angle_prior_weights: Sequence[float] = (10.0, 5.0, 2.0)
    shape_iters: int = 20
    shape_weight: float = 20.0
    final_iters: int = 40
    final_pose_prior_weight: float = 40.0
    final_angle_prior_weight: float = 1.0
    final_shape_weight: float = 5.0
    limit_weight: float = 1e4
    interpenetration_weight: float = 1e5
    depth_weight: float = 1e3
    history: int = 10
    #: torch threads during the fit (the per-iteration tensors are small, so one thread
    #: avoids synchronisation overhead; ``None`` leaves torch's setting alone).
    threads: Optional[int] = 1


def _names(layout):
    return LAYOUTS[layout]


def prepare_keypoints(keypoints, layout: Optional[str] = None) -> list:
    """Normalise API input to a list of :class:`KeypointSet` (validated)."""
    if isinstance(keypoints, KeypointSet):
        return [keypoints]
    if isinstance(keypoints, (list, tuple)) and keypoints and all(isinstance(k, KeypointSet) for k in keypoints):
        return list(keypoints)
    arr = np.asarray(keypoints.detach().cpu() if isinstance(keypoints, torch.Tensor) else keypoints, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"keypoints array has shape {arr.shape}, expected [K, 3] or [B, K, 3] of x, y, confidence")
    if layout is None:
        matches = [n for n, names in LAYOUTS.items() if len(names) == arr.shape[1]]
        if not matches:
            raise ValueError(f"keypoints array has {arr.shape[1]} points; expected 25 (body25) or 17 (coco17)")
        layout = matches[0]
    return [KeypointSet(a[:, :2], a[:, 2], layout, source=f"<array>[{i}]") for i, a in enumerate(arr)]


def _check_torso(ks: KeypointSet):
    names = ks.names
    have = [n for n in _TORSO_ALL if n in names and ks.conf[names.index(n)] > 0]
    up = [n for n in _UPPER if n in have]
    low = [n for n in _LOWER if n in have]
    if len(have) < MIN_TORSO_KEYPOINTS or not up or not low:
        raise ValueError(
            f"{ks.source}: only {len(have)} usable torso keypoint(s) ({', '.join(have) or 'none'}); need at least "
            f"{MIN_TORSO_KEYPOINTS} of {', '.join(n for n in _TORSO_ALL if n in names)} with confidence > 0, "
            f"including a shoulder/neck and a hip"
        )


def _resolve_cameras(sets, cameras, image_size, focal) -> list:
    B = len(sets)
    if cameras is None:
        if image_size is None:
            raise ValueError("no camera: give a camera (intrinsics) or the image size to derive the default one")
        sizes = [image_size] * B if isinstance(image_size[0], (int, float, np.integer)) else list(image_size)
        cams = [Camera.from_image_size(int(w), int(h), focal) for w, h in sizes]
    else:
        cams = [cameras] * B if isinstance(cameras, Camera) else list(cameras)
        if focal is not None:
            cams = [replace(c, fx=float(focal), fy=float(focal)) for c in cams]
    if len(cams) != B:
        raise ValueError(f"{len(cams)} cameras for {B} keypoint sets")
    return cams


class KeypointFitter:
    """Holds the model-derived pieces (reduced keypoint body, priors, collision spheres)
    so many batches can be fitted without rebuilding them."""

    def __init__(self, model=None, layout: str = "body25", config: Optional[KeypointFitConfig] = None, pose_prior=None):
        from ..body import load_body_model

        self.model = load_body_model() if model is None else model
        self.config = config or KeypointFitConfig()
        self.layout = layout
        self.dtype = self.model.dtype
        self.body = KeypointBody(self.model, layout, self.config.prefer_landmarks)
        if pose_prior is None or isinstance(pose_prior, str):
            pose_prior = load_pose_prior(pose_prior, dtype=self.dtype)
        self.pose_prior = pose_prior
        self.collisions = SphereCollisionModel(self.model)
        names = _names(layout)
        w = np.ones(len(names))
        for i, n in enumerate(names):
            if n.endswith("hip"):
                w[i] = self.config.hip_weight
            w[i] *= self.config.keypoint_weights.get(n, 1.0)
        self.kp_weights = torch.as_tensor(w, dtype=self.dtype)
        self.torso_mask = torch.as_tensor([n in _TORSO_ALL for n in names], dtype=self.dtype)
        with torch.no_grad():
            z = torch.zeros(1, 3, dtype=self.dtype)
            kp, _, _ = self.body(
                torch.zeros(1, self.model.num_betas, dtype=self.dtype), z, torch.zeros(1, 69, dtype=self.dtype), z
            )
        self.rest_keypoints = kp[0].double().numpy()

    # ------------------------------------------------------------------ init
    def _initial_placement(self, xy, conf, cam: Camera, flipped: bool):
        names = _names(self.layout)

        def mean_of(group, pts):
            sel = [names.index(n) for n in group if n in names and conf[names.index(n)] > 0]
            return pts[sel].mean(0)

        up2, low2 = mean_of(_UPPER, xy), mean_of(_LOWER, xy)
        up3, low3 = mean_of(_UPPER, self.rest_keypoints), mean_of(_LOWER, self.rest_keypoints)
        h2 = max(float(np.linalg.norm(up2 - low2)), 1.0)
        h3 = float(np.linalg.norm(up3 - low3))
        z0 = 0.5 * (cam.fx + cam.fy) * h3 / h2
        u = (up2 - low2) / h2
        roll = math.atan2(u[0], -u[1])
        base = Rotation.from_rotvec(UPRIGHT_BACK_TO_CAMERA if flipped else UPRIGHT_FACING_CAMERA)
        R = Rotation.from_rotvec([0.0, 0.0, roll]) * base
        c2 = 0.5 * (up2 + low2)
        c3 = 0.5 * (up3 + low3)
        target = np.array([(c2[0] - cam.cx) * z0 / cam.fx, (c2[1] - cam.cy) * z0 / cam.fy, z0])
        transl = target - R.apply(c3)
        return R.as_rotvec(), transl, z0

    def _initial_poses(self, count: int) -> list:
        """The zero pose, then the pose prior's most probable mixture means (if it has any)."""
        poses = [torch.zeros(69, dtype=self.dtype)]
        means = getattr(self.pose_prior, "means", None)
        if means is not None and count > 1:
            constants = getattr(self.pose_prior, "constants", torch.zeros(len(means)))
            poses += [means[i].detach() for i in torch.argsort(constants)[: count - 1].tolist()]
        return poses[: max(1, count)]

    # ------------------------------------------------------------------ fit
    def fit(self, keypoints, cameras=None, *, image_size=None, focal=None, progress: bool = True) -> KeypointFitResult:
        with torch_threads(self.config.threads):
            return self._fit(keypoints, cameras, image_size, focal, progress)

    def _fit(self, keypoints, cameras, image_size, focal, progress) -> KeypointFitResult:
        cfg = self.config
        sets = prepare_keypoints(keypoints, self.layout)
        for ks in sets:
            if ks.layout != self.layout:
                raise ValueError(f"{ks.source}: keypoints are {ks.layout}, this fitter was built for {self.layout}")
            _check_torso(ks)
        cams = _resolve_cameras(sets, cameras, image_size, focal)
        B = len(sets)
        dt = self.dtype
        # Starts: each facing (and the 180-degree flip) is placed by the camera stage, then
        # every placed start is combined with each initial body pose for the first pose stage.
        facings = (False, True) if cfg.flip_test else (False,)
        init_poses = self._initial_poses(cfg.init_poses)
        starts = [(flip, h) for h in range(len(init_poses)) for flip in facings]
        F, S = len(facings), len(starts)
        N = B * F
        xy = np.stack([ks.xy for ks in sets])
        conf = np.stack([ks.conf for ks in sets])
        orient, transl, z0 = np.zeros((N, 3)), np.zeros((N, 3)), np.zeros(N)
        for f, flip in enumerate(facings):
            for b in range(B):
                orient[f * B + b], transl[f * B + b], z0[f * B + b] = self._initial_placement(xy[b], conf[b], cams[b], flip)
        rep = lambda a: np.concatenate([a] * F, 0)  # noqa: E731
        T = lambda a: torch.as_tensor(a, dtype=dt)  # noqa: E731
        extent = []
        for b in range(B):
            vis = xy[b][conf[b] > 0]
            extent.append(max(float((vis.max(0) - vis.min(0)).max()), 1.0))
        data = {
            "target": T(rep(xy)),
            "weights": T(rep(conf)) * self.kp_weights,
            "scale": T(rep(cfg.norm_extent / np.asarray(extent))),
            "intr": T(rep(np.array([[c.fx, c.fy, c.cx, c.cy] for c in cams]))),
            "z0": T(z0),
        }
        state = {
            "betas": torch.zeros(N, self.model.num_betas, dtype=dt),
            "global_orient": T(orient),
            "body_pose": torch.zeros(N, 69, dtype=dt),
            "transl": T(transl),
        }
        energies, timings = {}, {}
        sigma = cfg.sigma if cfg.robust else None

        def run(name, free, weights, iters, torso_only=False):
            nonlocal state
            t0 = time.perf_counter()
            widths = [state[n].shape[1] for n in free]
            x0 = torch.cat([state[n] for n in free], 1)
            kp_mask = self.torso_mask if torso_only else None

            def fun(x, idx):
                p = {n: v[idx] for n, v in state.items()}
                for n, part in zip(free, torch.split(x, widths, dim=1)):
                    p[n] = part
                return self._energy(p, {k: v[idx] for k, v in data.items()}, weights, kp_mask, sigma)

            bar = None
            if progress:
                from tqdm.auto import tqdm

                bar = tqdm(total=iters, desc=f"keypoint fit: {name}", leave=False)
            cb = (lambda it, f: bar.update(1)) if bar is not None else None
            x, f, _ = batched_lbfgs(fun, x0, max_iter=iters, history=cfg.history, callback=cb)
            if bar is not None:
                bar.close()
            for n, part in zip(free, torch.split(x, widths, dim=1)):
                state[n] = part.detach()
            energies[name] = f.detach().clone()
            timings[name] = time.perf_counter() - t0
            return f

        t_all = time.perf_counter()
        pose_free = ("global_orient", "transl", "body_pose")
        run("camera", ("global_orient", "transl"), {"depth": cfg.depth_weight}, cfg.camera_iters, torso_only=True)
        H = len(init_poses)
        if H > 1:  # row (h * F + f) * B + b: placed start f of sample b with initial pose h
            state = {k: v.repeat(H, *([1] * (v.dim() - 1))) for k, v in state.items()}
            state["body_pose"] = torch.cat([p.to(dt).expand(N, -1) for p in init_poses], 0)
            data = {k: v.repeat(H, *([1] * (v.dim() - 1))) for k, v in data.items()}
            energies = {k: v.repeat(H) for k, v in energies.items()}
        flipped = np.zeros(B, dtype=bool)
        decide = min(cfg.flip_decision_stage, len(cfg.pose_iters) - 1) if S > 1 else -1
        for i, (it, wp, wa) in enumerate(zip(cfg.pose_iters, cfg.pose_prior_weights, cfg.angle_prior_weights)):
            weights = {"pose": wp, "angle": wa, "limits": cfg.limit_weight}
            if i != decide:
                run(f"pose_{i + 1}", pose_free, weights, it)
                continue
            together = cfg.decision_iters if 0 < cfg.decision_iters < it else it
            f = run(f"pose_{i + 1}", pose_free, weights, together)  # every start
            choose = f.view(S, B).argmin(0)
            flipped = np.array([starts[c][0] for c in choose.tolist()], dtype=bool)
            keep = torch.arange(B) + B * choose
            state = {k: v[keep] for k, v in state.items()}
            data = {k: v[keep] for k, v in data.items()}
            energies = {k: v.view(S, B)[choose, torch.arange(B)] for k, v in energies.items()}
            if it > together:  # the rest of the sub-stage from the chosen start only
                run(f"pose_{i + 1}_chosen", pose_free, weights, it - together)
        if cfg.shape_iters:
            run("shape", ("betas", "transl"), {"shape": cfg.shape_weight}, cfg.shape_iters)
        if cfg.final_iters:
            w = {
                "pose": cfg.final_pose_prior_weight, "angle": cfg.final_angle_prior_weight,
                "limits": cfg.limit_weight, "shape": cfg.final_shape_weight,
                "interpenetration": cfg.interpenetration_weight,
            }  # fmt: skip
            run("final", ("betas",) + pose_free, w, cfg.final_iters)
        timings["total"] = time.perf_counter() - t_all

        with torch.no_grad():
            out = self.model(**state)
            kp3, _, _ = self.body(state["betas"], state["global_orient"], state["body_pose"], state["transl"])
            proj = project_points(kp3, data["intr"])
            err = (proj - data["target"]).norm(dim=-1).numpy()
        reproj = np.array([np.median(err[b][conf[b] > 0]) for b in range(B)])
        np_ = lambda t: t.detach().cpu().numpy().astype(np.float32)  # noqa: E731
        return KeypointFitResult(
            betas=np_(state["betas"]), body_pose=np_(state["body_pose"]), global_orient=np_(state["global_orient"]),
            transl=np_(state["transl"]), cameras=cams, vertices=np_(out.vertices), joints=np_(out.joints),
            keypoints_2d=np_(proj), layout=self.layout, energies={k: np_(v) for k, v in energies.items()},
            timings=timings, flipped=flipped, reprojection_error=reproj,
        )  # fmt: skip

    def _energy(self, p, d, w, kp_mask, sigma):
        kp3, _, transforms = self.body(p["betas"], p["global_orient"], p["body_pose"], p["transl"])
        proj = project_points(kp3, d["intr"])
        weights = d["weights"] if kp_mask is None else d["weights"] * kp_mask
        e = reprojection_energy(proj, d["target"], weights, d["scale"], sigma)
        if w.get("depth"):
            e = e + w["depth"] * (p["transl"][:, 2] - d["z0"]) ** 2
        if w.get("pose"):
            e = e + w["pose"] * self.pose_prior(p["body_pose"])
        if w.get("angle"):
            e = e + w["angle"] * angle_prior(p["body_pose"])
        if w.get("limits"):
            e = e + w["limits"] * limit_violation(p["body_pose"])
        if w.get("shape"):
            e = e + w["shape"] * shape_prior(p["betas"])
        if w.get("interpenetration"):
            e = e + w["interpenetration"] * self.collisions(p["betas"], transforms)
        return e


def fit_keypoints(
    keypoints,
    camera: Union[Camera, Sequence[Camera], None] = None,
    model=None,
    *,
    image_size=None,
    focal: Optional[float] = None,
    layout: Optional[str] = None,
    config: Optional[KeypointFitConfig] = None,
    pose_prior=None,
    progress: bool = True,
) -> KeypointFitResult:
    """Fit SMPL to 2D keypoints of one person or a batch of people.

    ``keypoints``: a :class:`~silfit.keypoints.KeypointSet`, a list of them (a batch), or
    an array ``[K, 3]`` / ``[B, K, 3]`` of ``x, y, confidence`` (layout inferred from K:
    25 BODY_25, 17 COCO-17). ``camera``: one :class:`~silfit.camera.Camera` for all or one
    per sample; without it ``image_size=(W, H)`` (or a list) gives the documented default
    camera, ``focal`` overrides the focal length. ``model`` defaults to the shipped open
    body model; ``pose_prior``: ``None`` (shipped default), a ``gmm_08.pkl`` path or a
    module scoring ``body_pose [B, 69] -> [B]``.
    """
    sets = prepare_keypoints(keypoints, layout)
    fitter = KeypointFitter(model, sets[0].layout, config, pose_prior)
    return fitter.fit(sets, camera, image_size=image_size, focal=focal, progress=progress)
