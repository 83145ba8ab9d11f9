"""The SMPL body model in torch: functional core (:mod:`.lbs`), file loading (:mod:`.io`), the
``nn.Module`` wrapper (:mod:`.model`), the SMPL-X whole-body model (:mod:`.smplx`) and the
factory that loads either (:mod:`.load`)."""

from .io import (
    OPEN_BODY_PATH,
    OPEN_SMPLX_PATH,
    SMPL_JOINT_NAMES,
    SMPL_PARENTS,
    SMPLX_JOINT_NAMES,
    SMPLX_PARENTS,
    ModelArrays,
    load_model_arrays,
)
from .load import load_body_model
from .model import SMPL_PARAMETER_NAMES, BodyModel, BodyOutput, model_in_dtype
from .smplx import SMPLXModel, SMPLXOutput

__all__ = [
    "BodyModel",
    "BodyOutput",
    "ModelArrays",
    "OPEN_BODY_PATH",
    "OPEN_SMPLX_PATH",
    "SMPL_JOINT_NAMES",
    "SMPL_PARAMETER_NAMES",
    "SMPL_PARENTS",
    "SMPLX_JOINT_NAMES",
    "SMPLX_PARENTS",
    "SMPLXModel",
    "SMPLXOutput",
    "load_body_model",
    "model_in_dtype",
    "load_model_arrays",
]
