"""``KeypointFitResult``: SMPL parameters, camera, mesh and fit diagnostics; save/load."""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional, Union

import numpy as np

from ..body.model import SMPL_PARAMETER_NAMES as PARAM_NAMES
from ..camera import Camera

__all__ = ["KeypointFitResult", "PARAM_NAMES", "WHOLEBODY_EXTRA_NAMES"]

#: SMPL-X's parameters besides SMPL's four
WHOLEBODY_EXTRA_NAMES = ("expression", "jaw_pose", "leye_pose", "reye_pose", "left_hand_pose", "right_hand_pose")


@dataclass
class KeypointFitResult:
    """Batched result (leading dimension ``B``; numpy arrays, float32).

    ``betas [B, L]``, ``body_pose [B, 69]``, ``global_orient [B, 3]``, ``transl [B, 3]``
    are SMPL parameters whose model output is in the camera frame of ``cameras[b]``.
    ``vertices [B, V, 3]``, ``joints [B, 24, 3]``, ``keypoints_2d [B, K, 2]`` (projected
    fitted keypoints), ``energies`` (stage name -> ``[B]`` final energy), ``timings``
    (stage name -> seconds for the whole batch), ``flipped [B]`` (the 180-degree flipped
    initial orientation was kept), ``reprojection_error [B]`` (median px over keypoints
    with confidence > 0), ``term_energies`` (stage name -> term name -> ``[B]``, each
    term's unweighted value at the stage's end) and ``config`` (the run's settings and
    schedule).
    """

    betas: np.ndarray
    body_pose: np.ndarray
    global_orient: np.ndarray
    transl: np.ndarray
    cameras: List[Camera]
    vertices: Optional[np.ndarray] = None
    joints: Optional[np.ndarray] = None
    keypoints_2d: Optional[np.ndarray] = None
    layout: str = "body25"
    energies: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    flipped: Optional[np.ndarray] = None
    reprojection_error: Optional[np.ndarray] = None
    term_energies: dict = field(default_factory=dict)
    config: dict = field(default_factory=dict)
    #: per sample, the limb-branch flips the search kept (e.g. ``["left_shin"]``)
    branches: Optional[list] = None
    #: a whole-body (SMPL-X-layout) model's other parameters by their SMPL-X names
    #: (``expression``, ``jaw_pose``, ``leye_pose``, ``reye_pose``, ``left_hand_pose``, ``right_hand_pose``), ``[B, w]``
    extra_params: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return self.betas.shape[0]

    @property
    def camera(self) -> Camera:
        return self.cameras[0]

    def params(self, i: int = 0) -> dict:
        return {**{name: getattr(self, name)[i] for name in PARAM_NAMES}, **{k: v[i] for k, v in self.extra_params.items()}}

    @property
    def parameter_names(self) -> tuple:
        return PARAM_NAMES + tuple(self.extra_params)

    def __getitem__(self, i: int) -> "KeypointFitResult":
        """The single-sample result ``i`` (a batch of one)."""
        return self.select([i])

    def select(self, indices) -> "KeypointFitResult":
        """The samples ``indices`` (in that order) as a batched result."""
        idx = [int(i) for i in indices]
        pick = lambda a: None if a is None else a[idx]  # noqa: E731
        return KeypointFitResult(
            betas=self.betas[idx], body_pose=self.body_pose[idx], global_orient=self.global_orient[idx],
            transl=self.transl[idx], cameras=[self.cameras[i] for i in idx], vertices=pick(self.vertices),
            joints=pick(self.joints), keypoints_2d=pick(self.keypoints_2d), layout=self.layout,
            energies={k: v[idx] for k, v in self.energies.items()}, timings=dict(self.timings),
            flipped=pick(self.flipped), reprojection_error=pick(self.reprojection_error),
            term_energies={s: {t: v[idx] for t, v in d.items()} for s, d in self.term_energies.items()},
            config=self.config, branches=None if self.branches is None else [self.branches[i] for i in idx],
            extra_params={k: v[idx] for k, v in self.extra_params.items()},
        )  # fmt: skip

    # ------------------------------------------------------------------ I/O
    def save(self, directory: Union[str, os.PathLike], index: int = 0) -> Path:
        """Write sample ``index`` as ``params.npz`` and ``params.json`` (SMPL parameter
        names, one sample, no batch dimension) into ``directory``."""
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        cam = self.cameras[index]
        arrays = {name: np.asarray(self.params(index)[name], dtype=np.float32) for name in self.parameter_names}
        extra = {
            "camera_intrinsics": np.array([cam.fx, cam.fy, cam.cx, cam.cy], dtype=np.float64),
            "image_size": np.array([cam.width, cam.height], dtype=np.int64),
            "layout": np.array(self.layout),
        }
        for name in ("vertices", "joints", "keypoints_2d"):
            if getattr(self, name) is not None:
                extra[name] = np.asarray(getattr(self, name)[index], dtype=np.float32)
        np.savez(out / "params.npz", **arrays, **extra)
        payload = {name: arrays[name].astype(float).tolist() for name in self.parameter_names}
        payload["camera"] = cam.to_dict()
        payload["layout"] = self.layout
        payload["energies"] = {k: float(v[index]) for k, v in self.energies.items()}
        payload["timings"] = {k: float(v) for k, v in self.timings.items()}
        if self.term_energies:
            payload["energy_terms"] = {s: {t: float(v[index]) for t, v in d.items()} for s, d in self.term_energies.items()}
        if self.config:
            payload["config"] = self.config
        if self.branches is not None:
            payload["branches"] = list(self.branches[index])
        if self.flipped is not None:
            payload["flipped"] = bool(self.flipped[index])
        if self.reprojection_error is not None:
            payload["reprojection_error_px"] = float(self.reprojection_error[index])
        (out / "params.json").write_text(json.dumps(payload, indent=2))
        return out

    @classmethod
    def load(cls, path: Union[str, os.PathLike]) -> "KeypointFitResult":
        """Read ``params.npz`` or ``params.json`` (a file or the folder holding them) with
        :func:`silfit.fitio.read_fit` (all four parameters and the camera are required)."""
        from ..fitio import read_fit

        from ..fitio import PARAM_SIZES, SubjectError

        sizes = {**PARAM_SIZES, **dict.fromkeys(WHOLEBODY_EXTRA_NAMES)}
        try:
            fit = read_fit(path, require=PARAM_NAMES, require_camera=True, sizes=sizes)
        except SubjectError as err:  # SMPL-X's 21-joint body_pose, in a whole-body fit only
            if err.field != "body_pose":
                raise
            try:
                fit = read_fit(path, require=PARAM_NAMES, require_camera=True, sizes={**sizes, "body_pose": 63})
            except SubjectError:
                raise err from None
            if not any(n in fit.params for n in WHOLEBODY_EXTRA_NAMES):
                raise err from None
        get = lambda n: fit.arrays[n][None].astype(np.float32) if n in fit.arrays else None  # noqa: E731
        extra = {n: fit.params[n][None].astype(np.float32) for n in WHOLEBODY_EXTRA_NAMES if n in fit.params}
        return cls(
            **{n: fit.params[n][None].astype(np.float32) for n in PARAM_NAMES}, cameras=[fit.camera],
            vertices=get("vertices"), joints=get("joints"), keypoints_2d=get("keypoints_2d"),
            layout=fit.layout or "body25", energies={k: np.array([v]) for k, v in fit.energies.items()},
            timings=dict(fit.timings),
            flipped=None if fit.flipped is None else np.array([fit.flipped]),
            reprojection_error=None if fit.reprojection_error is None else np.array([fit.reprojection_error]),
            extra_params=extra,
        )  # fmt: skip
