"""``SMPLXModel``: the whole-body model (SMPL-X layout: hands, jaw, eyes, expressions) over the
same functional core (:mod:`.lbs`) as :class:`~silfit.body.model.BodyModel`.

Parameters (SMPL-X's names, axis-angle): ``betas [B, n]``, ``expression [B, m]``,
``global_orient [B, 3]``, ``body_pose [B, 63]`` (joints 1..21), ``jaw_pose``, ``leye_pose``,
``reye_pose [B, 3]``, ``left_hand_pose``, ``right_hand_pose [B, 45]`` (or ``[B, num_pca_comps]``
with ``use_pca``), ``transl [B, 3]``. 55 joints in SMPL-X's order and tree
(:data:`~silfit.body.io.SMPLX_JOINT_NAMES`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch

from .io import ModelArrays
from .lbs import axis_angle_to_matrix, lbs, matmul, sqrt
from .model import BodyModel, BodyOutput

__all__ = ["SMPLXModel", "SMPLXOutput", "HAND_JOINTS", "NECK_CHAIN", "dynamic_contour_bin"]

HAND_JOINTS = 15
#: Shape / expression spaces up to this size are used whole by default (larger: the first 10).
DEFAULT_SPACE_LIMIT = 32
#: Joints from the head to the root: their chained rotation gives the head's yaw for the
#: dynamic face contour (as the ``smplx`` package does).
NECK_CHAIN = (15, 12, 9, 6, 3, 0)


@dataclass
class SMPLXOutput(BodyOutput):
    """A whole-body model's output: :class:`BodyOutput` plus the face and hand parameters
    (``left_hand_pose``/``right_hand_pose`` as full 45-value axis-angle, after any PCA and mean)
    and ``full_pose [B, 165]`` (55 joints x 3)."""

    expression: torch.Tensor
    jaw_pose: torch.Tensor
    leye_pose: torch.Tensor
    reye_pose: torch.Tensor
    left_hand_pose: torch.Tensor
    right_hand_pose: torch.Tensor
    full_pose: torch.Tensor


def dynamic_contour_bin(full_pose: torch.Tensor, chain=NECK_CHAIN) -> torch.Tensor:
    """Row of SMPL-X's dynamic contour tables ``[79, 17]`` for each pose ``[B, 55*3]``: the head's
    yaw (degrees, rounded, clamped to +-39) from the chained rotations of ``chain``; rows 0..39 for
    yaw 0..39, rows 40..78 for yaw -1..-39 (the ``smplx`` package's convention)."""
    B = full_pose.shape[0]
    rots = axis_angle_to_matrix(full_pose.reshape(B, -1, 3)[:, list(chain)])
    rel = torch.eye(3, dtype=full_pose.dtype, device=full_pose.device).expand(B, 3, 3)
    for k in range(len(chain)):
        rel = matmul(rots[:, k], rel)  # not a GEMM (silfit.body.lbs)
    sy = sqrt(rel[:, 0, 0] ** 2 + rel[:, 1, 0] ** 2)
    yaw = torch.round(torch.clamp(-torch.atan2(-rel[:, 2, 0], sy) * 180.0 / np.pi, max=39)).long()
    return torch.where(yaw < 0, torch.where(yaw < -39, torch.full_like(yaw, 78), 39 - yaw), yaw)


class SMPLXModel(BodyModel):
    """SMPL-X: shape + expression blend shapes, 55-joint kinematics, linear blend skinning.

    ``num_betas``/``num_expression`` keep the first directions of the file's shape and expression
    spaces (``None``: all of them when there are at most :data:`DEFAULT_SPACE_LIMIT`, else the first
    10, as the ``smplx`` package does for official files' 300 + 100). ``use_pca`` takes hand poses as ``num_pca_comps``
    coefficients of the file's hand PCA (``hands_componentsl/r``); ``flat_hand_mean=False`` (the
    ``smplx`` default) adds the file's mean hand pose (``hands_meanl/r``, zero when absent).
    """

    kind = "smplx"

    def __init__(
        self,
        arrays: ModelArrays,
        dtype: torch.dtype = torch.float32,
        num_betas: Optional[int] = None,
        num_expression: Optional[int] = None,
        use_pca: bool = False,
        num_pca_comps: int = 6,
        flat_hand_mean: bool = False,
    ):
        if arrays.kind != "smplx":
            raise ValueError(f"{arrays.source}: not an SMPL-X-layout model file (it has {arrays.num_joints} joints)")
        extras = arrays.extras
        shape, expr = arrays.shapedirs, extras["exprdirs"]

        def default(n: int) -> int:
            return n if n <= DEFAULT_SPACE_LIMIT else 10

        nb = default(shape.shape[-1]) if num_betas is None else int(num_betas)
        ne = default(expr.shape[-1]) if num_expression is None else int(num_expression)
        if not 0 < nb <= shape.shape[-1]:
            raise ValueError(f"{arrays.source}: num_betas={nb}, the file has {shape.shape[-1]} shape directions")
        if not 0 <= ne <= expr.shape[-1]:
            raise ValueError(
                f"{arrays.source}: num_expression={ne}, the file has {expr.shape[-1]} expression directions"
            )
        # The core blends one coefficient vector [betas, expression] with [shapedirs, exprdirs].
        combined = ModelArrays(
            **{**arrays.__dict__, "shapedirs": np.concatenate([shape[..., :nb], expr[..., :ne]], -1)}
        )
        super().__init__(combined, dtype=dtype)
        self._num_betas, self._num_expression = nb, ne
        self.use_pca, self.flat_hand_mean = bool(use_pca), bool(flat_hand_mean)
        self.num_pca_comps = int(num_pca_comps) if use_pca else 45
        if use_pca:
            if "hands_componentsl" not in extras:
                raise ValueError(
                    f"{arrays.source}: use_pca needs a hand PCA (fields 'hands_componentsl/r'), the file has none"
                )
            avail = extras["hands_componentsl"].shape[0]
            if not 0 < self.num_pca_comps <= avail:
                raise ValueError(
                    f"{arrays.source}: num_pca_comps={self.num_pca_comps}, the file has {avail} hand components"
                )
            for side in ("l", "r"):
                comps = extras[f"hands_components{side}"][: self.num_pca_comps]
                self.register_buffer(f"hand_components_{side}", torch.as_tensor(comps, dtype=dtype))
        mean = np.zeros(55 * 3)
        if not flat_hand_mean:
            for side, start in (("l", 25), ("r", 40)):
                if f"hands_mean{side}" in extras:
                    mean[start * 3 : (start + HAND_JOINTS) * 3] = extras[f"hands_mean{side}"]
        self.register_buffer("pose_mean", torch.as_tensor(mean, dtype=dtype))
        dyn = "dynamic_lmk_faces_idx" in extras
        self.register_buffer("dynamic_lmk_faces_idx", torch.as_tensor(extras["dynamic_lmk_faces_idx"]) if dyn else None)
        self.register_buffer(
            "dynamic_lmk_bary_coords", torch.as_tensor(extras["dynamic_lmk_bary_coords"], dtype=dtype) if dyn else None
        )

    # ------------------------------------------------------------------ properties
    @property
    def num_betas(self) -> int:
        return self._num_betas

    @property
    def num_expression(self) -> int:
        return self._num_expression

    @property
    def num_body_pose(self) -> int:
        return 21 * 3

    @property
    def parameter_sizes(self) -> dict:
        """Parameters in call order: name -> width (SMPL-X's names)."""
        hand = self.num_pca_comps
        return {
            "betas": self.num_betas,
            "expression": self.num_expression,
            "global_orient": 3,
            "body_pose": self.num_body_pose,
            "jaw_pose": 3,
            "leye_pose": 3,
            "reye_pose": 3,
            "left_hand_pose": hand,
            "right_hand_pose": hand,
            "transl": 3,
        }

    # ------------------------------------------------------------------ evaluation
    def _hand(self, pose: torch.Tensor, side: str) -> torch.Tensor:
        if not self.use_pca:
            return pose
        return (pose[..., :, None] * getattr(self, f"hand_components_{side}")).sum(-2)  # not a GEMM (silfit.body.lbs)

    def forward(
        self,
        betas=None,
        body_pose=None,
        global_orient=None,
        transl=None,
        expression=None,
        jaw_pose=None,
        leye_pose=None,
        reye_pose=None,
        left_hand_pose=None,
        right_hand_pose=None,
    ) -> SMPLXOutput:
        given = dict(
            betas=betas,
            body_pose=body_pose,
            global_orient=global_orient,
            transl=transl,
            expression=expression,
            jaw_pose=jaw_pose,
            leye_pose=leye_pose,
            reye_pose=reye_pose,
            left_hand_pose=left_hand_pose,
            right_hand_pose=right_hand_pose,
        )
        B = self.batch_size_of(**given)
        sizes = self.parameter_sizes
        p = {}
        for name, width in sizes.items():
            value = given[name]
            if name == "betas" and value is not None:
                width = torch.as_tensor(value).shape[-1]
                if width > self.num_betas:
                    raise ValueError(
                        f"argument 'betas' has {width} values, this model has {self.num_betas} shape directions"
                    )
            p[name] = self._param(name, value, width, B)
        betas = p["betas"]
        coeffs = torch.cat([betas, betas.new_zeros(B, self.num_betas - betas.shape[1]), p["expression"]], dim=1)
        left, right = self._hand(p["left_hand_pose"], "l"), self._hand(p["right_hand_pose"], "r")
        full_pose = (
            torch.cat(
                [p["global_orient"], p["body_pose"], p["jaw_pose"], p["leye_pose"], p["reye_pose"], left, right], dim=1
            )
            + self.pose_mean
        )
        vertices, joints = lbs(
            coeffs,
            full_pose,
            self.v_template,
            self.shapedirs,
            self.posedirs,
            self.J_regressor,
            self.parents,
            self.lbs_weights,
            self._levels,
        )
        transl = p["transl"]
        return SMPLXOutput(
            vertices=vertices + transl[:, None],
            joints=joints + transl[:, None],
            betas=betas,
            body_pose=p["body_pose"],
            global_orient=p["global_orient"],
            transl=transl,
            expression=p["expression"],
            jaw_pose=p["jaw_pose"],
            leye_pose=p["leye_pose"],
            reye_pose=p["reye_pose"],
            left_hand_pose=full_pose[:, 75:120],
            right_hand_pose=full_pose[:, 120:165],
            full_pose=full_pose,
        )

    def face_landmarks(self, output: SMPLXOutput) -> torch.Tensor:
        """The 68-point face layout ``[B, 68, 3]`` on posed vertices: ``face_00`` ... ``face_67``
        landmark rows, with the jaw contour (points 0..16) from the file's dynamic contour where it
        has one (official SMPL-X: chosen by the head's yaw) instead of fixed rows."""
        index = {n: i for i, n in enumerate(self.landmark_names)}
        lm = self.landmarks(output.vertices)
        static = [f"face_{k:02d}" for k in range(17 if self.dynamic_lmk_faces_idx is not None else 0, 68)]
        missing = [n for n in static if n not in index]
        if missing:
            raise ValueError(f"{self.source}: this model has no face landmark(s) {', '.join(missing[:3])} ...")
        points = lm[:, [index[n] for n in static]]
        if self.dynamic_lmk_faces_idx is None:
            return points
        row = dynamic_contour_bin(output.full_pose)
        faces = self.faces[self.dynamic_lmk_faces_idx[row]]  # [B, 17, 3] vertex ids
        bary = self.dynamic_lmk_bary_coords[row].to(output.vertices.dtype)  # [B, 17, 3]
        tri = torch.gather(output.vertices, 1, faces.reshape(faces.shape[0], -1, 1).expand(-1, -1, 3))
        contour = (tri.reshape(faces.shape[0], faces.shape[1], 3, 3) * bary[..., None]).sum(2)
        return torch.cat([contour, points], dim=1)

    def extra_repr(self) -> str:
        return super().extra_repr() + f", expression={self.num_expression}, use_pca={self.use_pca}"
