"""``BodyModel``: a thin ``nn.Module`` over the functional SMPL core in :mod:`.lbs`."""

from __future__ import annotations

import copy
import weakref
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .io import ModelArrays
from .lbs import kinematic_levels, lbs, vertices_to_joints

__all__ = ["BodyModel", "BodyOutput", "SMPL_PARAMETER_NAMES", "model_in_dtype"]

#: SMPL's parameter names in call order (the one list; a model's own set is ``model.parameter_sizes``)
SMPL_PARAMETER_NAMES = ("betas", "global_orient", "body_pose", "transl")


@dataclass
class BodyOutput:
    """What a body model returns; ``vertices [B, V, 3]`` and ``joints [B, J, 3]`` in metres."""

    vertices: torch.Tensor
    joints: torch.Tensor
    betas: torch.Tensor
    body_pose: torch.Tensor
    global_orient: torch.Tensor
    transl: torch.Tensor


class BodyModel(nn.Module):
    """SMPL: shape blend shapes, forward kinematics and linear blend skinning.

    Call with ``betas [B, L<=num_betas]``, ``body_pose [B, (J-1)*3]``,
    ``global_orient [B, 3]``, ``transl [B, 3]`` (axis-angle; any omitted argument is
    zero). Axes: Y up, the rest body facing +Z, metres.
    """

    def __init__(self, arrays: ModelArrays, dtype: torch.dtype = torch.float32):
        super().__init__()
        self.source = arrays.source
        self.meta = dict(arrays.meta)
        self.joint_names = tuple(arrays.joint_names)
        self.parents = tuple(arrays.parents)
        self.landmark_names = tuple(arrays.landmark_names)
        self._levels = kinematic_levels(self.parents)

        def buf(name, value, as_dtype=dtype):
            self.register_buffer(name, torch.as_tensor(np.ascontiguousarray(value), dtype=as_dtype))

        buf("v_template", arrays.v_template)
        buf("shapedirs", arrays.shapedirs)
        buf("J_regressor", arrays.J_regressor)
        buf("lbs_weights", arrays.weights)
        buf("faces_tensor", arrays.faces, torch.long)
        V = arrays.num_vertices
        if arrays.posedirs is not None:
            # [(J-1)*9, V*3], the layout the pose feature multiplies.
            buf("posedirs", arrays.posedirs.reshape(V * 3, -1).T)
        else:
            self.posedirs = None
        if arrays.landmark_regressor is not None:
            buf("landmark_regressor", arrays.landmark_regressor)
        else:
            self.landmark_regressor = None

    # ------------------------------------------------------------------ properties
    @property
    def faces(self) -> torch.Tensor:
        """Triangles ``[F, 3]`` (int64)."""
        return self.faces_tensor

    @property
    def num_vertices(self) -> int:
        return self.v_template.shape[0]

    @property
    def num_joints(self) -> int:
        return self.J_regressor.shape[0]

    @property
    def num_betas(self) -> int:
        return self.shapedirs.shape[-1]

    @property
    def num_body_pose(self) -> int:
        return (self.num_joints - 1) * 3

    #: which layout this model has: ``"smpl"`` here (``"smplx"`` for the whole-body model)
    kind = "smpl"

    @property
    def parameter_sizes(self) -> dict:
        """The model's parameters in call order: name -> width (``betas`` first, ``transl`` last).

        Fitting code takes its parameter set from here, so any model kind goes through it."""
        widths = (self.num_betas, 3, self.num_body_pose, 3)
        return dict(zip(SMPL_PARAMETER_NAMES, widths))

    @property
    def parameter_names(self) -> tuple:
        return tuple(self.parameter_sizes)

    def zero_params(self, batch: int = 1) -> dict:
        """Zero parameters ``{name: [batch, width]}`` in the model's dtype and device."""
        return {n: torch.zeros(batch, w, dtype=self.dtype, device=self.device) for n, w in self.parameter_sizes.items()}

    @property
    def dtype(self) -> torch.dtype:
        return self.v_template.dtype

    @property
    def device(self) -> torch.device:
        return self.v_template.device

    # ------------------------------------------------------------------ evaluation
    def _param(self, name: str, value, width: int, batch: int) -> torch.Tensor:
        if value is None:
            return torch.zeros(batch, width, dtype=self.dtype, device=self.device)
        value = torch.as_tensor(value, dtype=self.dtype, device=self.device)
        if value.ndim == 1:
            value = value[None]
        if value.ndim != 2 or value.shape[1] != width or value.shape[0] != batch:
            raise ValueError(f"argument '{name}' has shape {tuple(value.shape)}, expected [{batch}, {width}]")
        return value

    def batch_size_of(self, **params) -> int:
        sizes = {}
        for name, value in params.items():
            if value is None:
                continue
            shape = tuple(torch.as_tensor(value).shape)
            sizes[name] = shape[0] if len(shape) == 2 else 1
        if len(set(sizes.values())) > 1:
            shown = ", ".join(f"{k}: {v}" for k, v in sizes.items())
            raise ValueError(f"parameters disagree on the batch size ({shown})")
        return next(iter(sizes.values()), 1)

    def forward(self, betas=None, body_pose=None, global_orient=None, transl=None) -> BodyOutput:
        B = self.batch_size_of(betas=betas, body_pose=body_pose, global_orient=global_orient, transl=transl)
        if betas is not None:
            nb = torch.as_tensor(betas).shape[-1]
            if nb > self.num_betas:
                raise ValueError(f"argument 'betas' has {nb} values, this model has {self.num_betas} shape directions")
            betas = self._param("betas", betas, nb, B)
        else:
            betas = self._param("betas", None, self.num_betas, B)
        body_pose = self._param("body_pose", body_pose, self.num_body_pose, B)
        global_orient = self._param("global_orient", global_orient, 3, B)
        transl = self._param("transl", transl, 3, B)
        full_pose = torch.cat([global_orient, body_pose], dim=1)
        vertices, joints = lbs(
            betas,
            full_pose,
            self.v_template,
            self.shapedirs,
            self.posedirs,
            self.J_regressor,
            self.parents,
            self.lbs_weights,
            self._levels,
        )
        return BodyOutput(
            vertices=vertices + transl[:, None],
            joints=joints + transl[:, None],
            betas=betas,
            body_pose=body_pose,
            global_orient=global_orient,
            transl=transl,
        )

    def landmarks(self, vertices: torch.Tensor) -> torch.Tensor:
        """Surface landmarks ``[B, K, 3]`` (names in ``landmark_names``) of posed vertices."""
        if self.landmark_regressor is None:
            raise ValueError(f"{self.source}: this model has no landmark (extra keypoint) regressor")
        return vertices_to_joints(self.landmark_regressor.to(vertices.dtype), vertices)

    def rest_vertices(self, betas: torch.Tensor) -> torch.Tensor:
        """T-posed (zero pose) vertices ``[B, V, 3]`` of the given shapes, no translation."""
        return self.forward(betas=betas).vertices

    def extra_repr(self) -> str:
        return (
            f"source={self.source!r}, vertices={self.num_vertices}, joints={self.num_joints}, "
            f"betas={self.num_betas}, pose_correctives={self.posedirs is not None}"
        )


_CONVERTED: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def model_in_dtype(model: BodyModel, dtype: torch.dtype) -> BodyModel:
    """``model`` itself if it is in ``dtype``, else a copy in ``dtype`` (made once per model and
    dtype, kept while ``model`` lives; the caller's model is never changed)."""
    if model.dtype == dtype:
        return model
    copies = _CONVERTED.setdefault(model, {})
    if dtype not in copies:
        copies[dtype] = copy.deepcopy(model).to(dtype)
    return copies[dtype]
