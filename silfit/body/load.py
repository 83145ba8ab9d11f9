"""Loading a body model: the factory beside the model classes (:mod:`.model`, :mod:`.smplx`),
so neither imports the other."""

from __future__ import annotations

import os
from typing import Optional, Union

import torch

from .io import find_smplx_file, load_model_arrays, OPEN_SMPLX_PATH
from .model import BodyModel
from .smplx import SMPLXModel

__all__ = ["load_body_model"]


def load_body_model(
    path: Union[str, os.PathLike, None] = None,
    gender: str = "neutral",
    dtype: torch.dtype = torch.float32,
    device: Union[str, torch.device, None] = None,
    kind: Optional[str] = None,
    **options,
) -> BodyModel:
    """Load a body model.

    ``path=None`` loads the open body model shipped with silfit (no registration
    needed). Otherwise ``path`` is an official SMPL ``.pkl``/``.npz`` file (chumpy
    pickles are read without chumpy) or a folder holding ``SMPL_<GENDER>.pkl`` /
    ``basicmodel_<g>_lbs_10_207_0_v1.x.pkl`` files, picked by ``gender``.

    The kind (``model.kind``) comes from the file: an SMPL-X-layout file (55 joints, e.g.
    ``SMPLX_NEUTRAL.npz``) gives a :class:`~silfit.body.smplx.SMPLXModel`, which takes ``options``
    (``num_betas``, ``num_expression``, ``use_pca``, ``num_pca_comps``, ``flat_hand_mean``).
    ``kind="smplx"`` with ``path=None`` loads the shipped open whole-body model; with a path, ``kind``
    must match the file's.
    """
    if kind not in (None, "smpl", "smplx"):
        raise ValueError(f"kind must be 'smpl' or 'smplx', got {kind!r}")
    if path is None and kind == "smplx":
        if not OPEN_SMPLX_PATH.is_file():
            raise FileNotFoundError(
                f"{OPEN_SMPLX_PATH}: the shipped open whole-body model is missing from the installation"
            )
        path = OPEN_SMPLX_PATH
    elif kind == "smplx" and os.path.isdir(os.path.expanduser(os.fspath(path))):
        path = find_smplx_file(path, gender)  # a folder may hold SMPL and SMPL-X files: take SMPL-X's
    arrays = load_model_arrays(path, gender)
    if kind is not None and arrays.kind != kind:
        raise ValueError(f"{arrays.source}: a {arrays.kind.upper()}-layout model file, not {kind.upper()} as requested")
    if arrays.kind == "smplx":
        model = SMPLXModel(arrays, dtype=dtype, **options)
    elif options:
        raise ValueError(f"{arrays.source}: option(s) {', '.join(options)} apply to SMPL-X models only")
    else:
        model = BodyModel(arrays, dtype=dtype)
    if device is not None:
        model = model.to(device)
    return model
