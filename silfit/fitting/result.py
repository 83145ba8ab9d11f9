"""``KeypointFitResult``: SMPL parameters, camera, mesh and fit diagnostics; save/load."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional, Union

import numpy as np
from scipy.spatial.transform import Rotation

from ..body.model import SMPL_PARAMETER_NAMES as PARAM_NAMES
from ..camera import Camera
from ..io.fit import read_fit, write_fit
from ..io.subjects import SubjectError

__all__ = ["KeypointFitResult", "PARAM_NAMES", "WHOLEBODY_EXTRA_NAMES", "faces_camera"]

#: SMPL-X's parameters besides SMPL's four
WHOLEBODY_EXTRA_NAMES = ("expression", "jaw_pose", "leye_pose", "reye_pose", "left_hand_pose", "right_hand_pose")


def faces_camera(global_orient, transl) -> bool:
    """Whether a body (camera-frame ``global_orient [3]``, ``transl [3]``) faces the camera:
    its forward axis (+Z of the model) points toward the camera centre rather than away."""
    forward = Rotation.from_rotvec(np.asarray(global_orient, dtype=np.float64).reshape(3)).apply([0.0, 0.0, 1.0])
    return float(forward @ -np.asarray(transl, dtype=np.float64).reshape(3)) > 0.0


@dataclass
class KeypointFitResult:
    """Batched result (leading dimension ``B``; numpy arrays, float32).

    ``betas [B, L]``, ``body_pose [B, 69]``, ``global_orient [B, 3]``, ``transl [B, 3]``
    are SMPL parameters whose model output is in the camera frame of ``cameras[b]``.
    ``vertices [B, V, 3]``, ``joints [B, 24, 3]``, ``keypoints_2d [B, K, 2]`` (projected
    fitted keypoints), ``energies`` (stage name -> ``[B]`` final energy), ``timings``
    (stage name -> seconds for the whole batch), ``flipped [B]`` (the start from the
    180-degree flipped orientation won; ``start_flipped`` in ``params.json``, which also
    records ``faces_camera``: whether the final body faces the camera, see :func:`faces_camera`), ``reprojection_error [B]`` (median px over keypoints
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
    #: the body model's record (:func:`silfit.io.fit.model_record`: kind, source, sha256)
    model: Optional[dict] = None
    #: per sample, each branch-search stage's hypotheses that ran to its end and their energies at
    #: its end (``[{"stage", "kept", "tried": [{"flip", "energy", "shift_mm", "max_shift_mm"}, ...]}]``, lowest
    #: first; ``shift_mm``/``max_shift_mm``: the mean and the largest joint distance, mm, from the row at that
    #: search's end to the fit); where the last search's best branches were refined to the end
    #: (``branches.refine``), one more entry with ``"refined": True`` (``stage``: the last stage) lists the
    #: distinct ones with their final energies (``tried`` entries also with ``differs``), ordered by the
    #: score that chose (the final energy; with the occlusion cue on, times its factor), the fit first; a search
    #: whose best rows each ran the final stage before a later search (the late one, ``settle``) also lists them
    #: with those energies (``"settled": [{"flip", "energy"}, ...]``, the pick first), and its ``kept`` is that pick
    branch_search: Optional[list] = None
    #: with ``KeypointFitConfig.solutions.count > 1``: per sample, the distinct hypotheses refined to the
    #: end, lowest energy first (the first is the fit): ``[{"label", "energy", "params", "differs", "refined",
    #: "shift_mm", "max_shift_mm"}]``, then branch-search survivors not refined (``refined: False``, with
    #: ``stage`` and ``gap``; a row that settled higher, ``stage`` ``settle``, with its final-weight energy and its gap to the
    #: fit's) where fewer than K refined ones are distinct (:func:`~silfit.fitting.keypoint_stage.distinct_hypotheses`)
    hypotheses: Optional[list] = None
    #: per sample, the other distinct branches refined to the end (``branches.refine``), lowest score first, in
    #: :attr:`hypotheses`' form plus ``gap``: their final energy's relative gap to the fit's (above it, unless the
    #: occlusion cue, ``occlusion_weight``, chose the fit by more than its energy: then it can be negative); whatever
    #: ``hypotheses`` is. With a mask the close ones are refined against it too, and the mask may choose one
    #: (:class:`image_fit.ImageRefinement`, ``SilhouetteFitConfig.alternatives_margin``); ``None``: no branch
    #: was refined (no search, rigs, videos) or the result was read from a file (:meth:`load`)
    alternatives: Optional[list] = None

    def __len__(self) -> int:
        return self.betas.shape[0]

    @property
    def camera(self) -> Camera:
        return self.cameras[0]

    def params(self, i: int = 0) -> dict:
        return {
            **{name: getattr(self, name)[i] for name in PARAM_NAMES},
            **{k: v[i] for k, v in self.extra_params.items()},
        }

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
            betas=self.betas[idx],
            body_pose=self.body_pose[idx],
            global_orient=self.global_orient[idx],
            transl=self.transl[idx],
            cameras=[self.cameras[i] for i in idx],
            vertices=pick(self.vertices),
            joints=pick(self.joints),
            keypoints_2d=pick(self.keypoints_2d),
            layout=self.layout,
            energies={k: v[idx] for k, v in self.energies.items()},
            timings=dict(self.timings),
            flipped=pick(self.flipped),
            reprojection_error=pick(self.reprojection_error),
            term_energies={s: {t: v[idx] for t, v in d.items()} for s, d in self.term_energies.items()},
            config=self.config,
            branches=None if self.branches is None else [self.branches[i] for i in idx],
            extra_params={k: v[idx] for k, v in self.extra_params.items()},
            model=self.model,
            branch_search=None if self.branch_search is None else [self.branch_search[i] for i in idx],
            hypotheses=None if self.hypotheses is None else [self.hypotheses[i] for i in idx],
            alternatives=None if self.alternatives is None else [self.alternatives[i] for i in idx],
        )

    # ------------------------------------------------------------------ I/O
    def save(self, directory: Union[str, os.PathLike], index: int = 0) -> Path:
        """Write sample ``index`` as ``params.npz`` and ``params.json`` into ``directory`` with
        :func:`silfit.io.fit.write_fit` (one frame, one view; the schema is described there)."""
        pick = lambda name: None if getattr(self, name) is None else getattr(self, name)[index]  # noqa: E731
        return write_fit(
            directory,
            {name: self.params(index)[name] for name in self.parameter_names},
            [self.cameras[index]],
            layout=self.layout,
            model=self.model,
            vertices=pick("vertices"),
            joints=pick("joints"),
            keypoints_2d=pick("keypoints_2d"),
            record=self.record(index),
        )

    def record(self, index: int = 0) -> dict:
        """Sample ``index``'s ``params.json`` fields beside the parameters (:meth:`save`): energies, timings,
        the configuration, branches, facing, branch search and reprojection error."""
        record = {
            "energies": {k: float(v[index]) for k, v in self.energies.items()},
            "timings": {k: float(v) for k, v in self.timings.items()},
        }
        if self.term_energies:
            record["energy_terms"] = {
                s: {t: float(v[index]) for t, v in d.items()} for s, d in self.term_energies.items()
            }
        if self.config:
            record["config"] = self.config
        if self.branches is not None:
            record["branches"] = list(self.branches[index])
        if self.flipped is not None:
            record["start_flipped"] = bool(self.flipped[index])
        record["faces_camera"] = bool(faces_camera(self.global_orient[index], self.transl[index]))
        if self.branch_search is not None:
            record["branch_search"] = self.branch_search[index]
        if self.reprojection_error is not None:
            record["reprojection_error_px"] = float(self.reprojection_error[index])
        return record

    @classmethod
    def load(cls, path: Union[str, os.PathLike]) -> "KeypointFitResult":
        """Read one image's fit (``params.npz`` or ``params.json``, a file or the folder holding
        them) with :func:`silfit.io.fit.read_fit` (all four parameters and the camera are required)."""
        fit = read_fit(path, require=PARAM_NAMES, require_camera=True)
        if fit.num_frames != 1 or len(fit.cameras) != 1:
            raise SubjectError(
                fit.path,
                "frames",
                f"holds {fit.num_frames} frame(s) x {len(fit.cameras)} view(s); a KeypointFitResult is one image's fit",
            )
        params = fit.frame(0)
        get = lambda n: fit.arrays[n][0].astype(np.float32)[None] if n in fit.arrays else None  # noqa: E731
        kp2d = get("keypoints_2d")
        return cls(
            **{n: params[n][None].astype(np.float32) for n in PARAM_NAMES},
            cameras=[fit.camera],
            vertices=get("vertices"),
            joints=get("joints"),
            keypoints_2d=None if kp2d is None else kp2d[:, 0],
            layout=fit.layout or "body25",
            energies={k: np.array([v]) for k, v in fit.energies.items()},
            timings=dict(fit.timings),
            flipped=None if fit.flipped is None else np.array([fit.flipped]),
            reprojection_error=None if fit.reprojection_error is None else np.array([fit.reprojection_error]),
            extra_params={n: params[n][None].astype(np.float32) for n in WHOLEBODY_EXTRA_NAMES if n in params},
            model=fit.model,
        )
