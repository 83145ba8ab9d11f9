"""Body evaluators for fitting, keyed by the model's own parameter names.

:class:`KeypointBody` is a reduced forward: joints, skinning transforms and only the
surface vertices the keypoints need (the full mesh is posed once, at the end of a fit).
:class:`MeshBody` poses the whole mesh (for the silhouette stage). Both take the
parameters by name (``body(**params)``, rows ``[R, width]``) and return a
:class:`BodyState`, so the energy terms do not depend on the model kind.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
from torch import nn

from ..body.lbs import axis_angle_to_matrix, blend_shapes, forward_kinematics, per_row, pose_feature, vertices_to_joints
from ..io.keypoints import keypoint_sources, model_keypoints

__all__ = ["BodyState", "KeypointBody", "MeshBody", "body_transforms", "pose_parameter_names"]


@dataclass
class BodyState:
    """A body evaluated for rows of parameters (world frame, metres): ``keypoints [R, K, 3]``
    of the fitter's layout, ``joints [R, J, 3]``, skinning ``transforms [R, J, 4, 4]``
    (without ``transl``; ``None`` where the evaluator does not give them) and, for the
    mesh evaluator, ``vertices [R, V, 3]``."""

    keypoints: torch.Tensor
    joints: torch.Tensor
    transforms: Optional[torch.Tensor] = None
    vertices: Optional[torch.Tensor] = None


def pose_parameter_names(model) -> tuple:
    """The model's rotation parameters in kinematic-tree order (``global_orient`` first),
    which concatenated give the full axis-angle pose ``[B, J * 3]``."""
    return tuple(n for n in model.parameter_sizes if n == "global_orient" or n.endswith("_pose"))


class KeypointBody(nn.Module):
    """Keypoints ``[B, K, 3]`` (camera frame) of a layout, computed from SMPL parameters
    without skinning the whole mesh."""

    def __init__(self, model, layout: str = "body25", prefer_landmarks: bool = False):
        super().__init__()
        self.model_source = model.source
        self.pose_names = pose_parameter_names(model)
        self.parents = tuple(model.parents)
        self.levels = model._levels
        sources = keypoint_sources(model, layout, prefer_landmarks)
        self.layout = layout
        L = model.num_betas
        self.num_betas = L
        # the joint regressor over its nonzeros, as the model's own forward (silfit.body.lbs, "No BLAS"): each
        # joint's rest position and shape directions the same bits on every processor and thread count
        Jr, V, L = model.J_regressor, model.num_vertices, model.shapedirs.shape[-1]
        self.register_buffer("J_template", vertices_to_joints(Jr, model.v_template[None])[0])
        self.register_buffer(
            "J_shapedirs", vertices_to_joints(Jr, model.shapedirs.reshape(1, V, 3 * L))[0].reshape(-1, 3, L)
        )
        lm_used = sorted({i for kind, i in sources if kind == "landmark"})
        J = model.num_joints
        if lm_used:
            self._reduce_landmarks(model, lm_used)
            lm_pos = {i: k for k, i in enumerate(lm_used)}
        else:
            self.lm_count = 0
            lm_pos = {}
        index = [i if kind in ("joint", "none") else J + lm_pos[i] for kind, i in sources]
        self.register_buffer("kp_index", torch.as_tensor(index, dtype=torch.long))
        #: 1 where the model places the keypoint, 0 for ``("none", 0)`` sources (weight them 0)
        self.register_buffer("kp_valid", torch.as_tensor([kind != "none" for kind, _ in sources], dtype=model.dtype))
        # Whole-body (SMPL-X-layout) models blend [betas, expression] and may take hand poses as PCA
        # coefficients plus a mean hand (their forward's conventions, repeated here on the reduced body).
        self.expression = "expression" in model.parameter_sizes
        if getattr(model, "use_pca", False):
            self.register_buffer("hand_components_l", model.hand_components_l)
            self.register_buffer("hand_components_r", model.hand_components_r)
        pose_mean = getattr(model, "pose_mean", None)
        self.register_buffer("pose_mean", None if pose_mean is None or not bool(pose_mean.abs().any()) else pose_mean)

    def _reduce_landmarks(self, model, used: list) -> None:
        """Precompute the landmarks' skinning, exactly. A landmark is a fixed mix of vertices,
        ``l_k = sum_v R_kv sum_j w_vj (A_j v_v + b_j)`` with ``v_v`` linear in the shape (and in
        the pose feature, where the model has pose correctives), so it is
        ``l_k = sum_j A_j M_kj + c_kj b_j`` with ``c_kj = sum_v R_kv w_vj`` and
        ``M_kj = sum_v R_kv w_vj v_v`` linear in the same coefficients: the fit poses a few dozen
        (landmark, joint) pairs instead of the thousands of vertices under the landmarks."""
        dt = model.dtype
        R = model.landmark_regressor[used].double()  # [k, V]
        W = model.lbs_weights.double()
        V = model.num_vertices
        pd = None if model.posedirs is None else model.posedirs.double().reshape(-1, V, 3)  # [P, V, 3]
        pk, pj, c, M0, Ms, Mp = [], [], [], [], [], []
        for k in range(len(used)):
            sup = (R[k].abs() > 0).nonzero().squeeze(1)
            Rw = R[k, sup, None] * W[sup]  # [s, J]
            for j in (Rw.abs() > 0).any(0).nonzero().squeeze(1).tolist():
                r = Rw[:, j]
                pk.append(k)
                pj.append(j)
                c.append(r.sum())
                M0.append((r[:, None] * model.v_template.double()[sup]).sum(0))
                Ms.append((r[:, None, None] * model.shapedirs.double()[sup]).sum(0))
                if pd is not None:
                    Mp.append((r[None, :, None] * pd[:, sup]).sum(1).T)
        self.lm_count = len(used)
        self.register_buffer("lm_pair_landmark", torch.as_tensor(pk, dtype=torch.long))
        self.register_buffer("lm_pair_joint", torch.as_tensor(pj, dtype=torch.long))
        self.register_buffer("lm_pair_weight", torch.stack(c).to(dt))  # c [Q]
        self.register_buffer("lm_pair_template", torch.stack(M0).to(dt))  # [Q, 3]
        self.register_buffer("lm_pair_shapedirs", torch.stack(Ms).to(dt))  # [Q, 3, L]
        self.register_buffer("lm_pair_posedirs", torch.stack(Mp).to(dt) if Mp else None)  # [Q, 3, P]

    def _landmarks(self, betas: torch.Tensor, rot: torch.Tensor, T: torch.Tensor) -> torch.Tensor:
        """Landmarks ``[B, k, 3]`` (no translation) from the precomputed pairs (:meth:`_reduce_landmarks`)."""
        B = betas.shape[0]
        M = self.lm_pair_template + blend_shapes(betas, self.lm_pair_shapedirs)  # [B, Q, 3]
        if self.lm_pair_posedirs is not None:
            dirs = self.lm_pair_posedirs
            M = M + per_row(lambda f: (f[:, None, None, :] * dirs).sum(-1), pose_feature(rot))
        Tq = T[:, self.lm_pair_joint, :3]  # [B, Q, 3, 4]
        part = (Tq[..., :3] * M[:, :, None, :]).sum(-1) + self.lm_pair_weight[:, None] * Tq[..., 3]
        out = torch.zeros(B, self.lm_count, 3, dtype=part.dtype, device=part.device)
        return out.index_add(1, self.lm_pair_landmark, part)

    def _pose_value(self, name: str, value: torch.Tensor) -> torch.Tensor:
        if name in ("left_hand_pose", "right_hand_pose") and getattr(self, "hand_components_l", None) is not None:
            comps = self.hand_components_l if name[0] == "l" else self.hand_components_r
            return per_row(lambda v: (v[:, :, None] * comps).sum(1), value)
        return value

    def shaped_joints(self, betas: torch.Tensor) -> torch.Tensor:
        return self.J_template + blend_shapes(betas, self.J_shapedirs)

    def forward(self, **params) -> BodyState:
        """Keypoints, joints and transforms of parameter rows given by name (``betas``,
        the pose parameters, ``transl``)."""
        betas, transl = params["betas"], params["transl"]
        B = betas.shape[0]
        if self.expression:
            betas = torch.cat([betas, params["expression"]], dim=1)
        rest_joints = self.shaped_joints(betas)
        full = torch.cat([self._pose_value(n, params[n]) for n in self.pose_names], dim=1)
        if self.pose_mean is not None:
            full = full + self.pose_mean
        full = full.reshape(B, -1, 3)
        rot = axis_angle_to_matrix(full)
        joints, T = forward_kinematics(rot, rest_joints, self.parents, self.levels)
        pts = joints
        if self.lm_count:
            pts = torch.cat([joints, self._landmarks(betas, rot, T)], dim=1)
        kp = pts[:, self.kp_index] + transl[:, None]
        return BodyState(kp, joints + transl[:, None], T)


class MeshBody(nn.Module):
    """The whole posed mesh and the layout's keypoints from it (silhouette stage)."""

    def __init__(self, model, layout: str = "body25", prefer_landmarks: bool = False):
        super().__init__()
        self.model = model
        self.layout = layout
        self.prefer_landmarks = prefer_landmarks

    def forward(self, **params) -> BodyState:
        out = self.model(**params)
        kp = model_keypoints(self.model, out, self.layout, self.prefer_landmarks)
        return BodyState(kp, out.joints, None, out.vertices)


def body_transforms(model, betas, global_orient, body_pose):
    """Skinning transforms ``[B, J, 4, 4]`` (rest point -> posed point, no translation)."""
    B = betas.shape[0]
    rest_joints = vertices_to_joints(model.J_regressor, model.v_template + blend_shapes(betas, model.shapedirs))
    full = torch.cat([global_orient, body_pose], dim=1).reshape(B, -1, 3)
    _, T = forward_kinematics(axis_angle_to_matrix(full), rest_joints, model.parents, model._levels)
    return T
