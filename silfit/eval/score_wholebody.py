"""Whole-body errors (SMPL-X-layout fits against the ground truth): hands, face, expression.

* hand vertices: the vertices whose largest skinning weight belongs to that side's wrist or finger
  joints; their error after translating the fit's wrist joint onto the truth's (``hand_wrist_mm``)
  and after a similarity Procrustes alignment of the hand's vertices (``hand_pa_mm``);
* face vertices: the vertices skinned mostly to the head, jaw or eyes; error after Procrustes
  (``face_pa_mm``: shape, expression and jaw, not the head's placement);
* ``expression_err``: RMS difference of the expression coefficients (unit-variance space);
* ``pa_pve_mm``: the body error as elsewhere (all vertices, Procrustes).
All in millimetres; one number per subject (the two hands averaged, a hand that the fit held at rest
for lack of keypoints still counts).
"""

from __future__ import annotations

from typing import Dict

import numpy as np

from .metrics import pa_pve, procrustes_align

__all__ = ["part_vertices", "wholebody_errors"]

_FACE_JOINTS = ("head", "jaw", "left_eye_smplhf", "right_eye_smplhf")


def part_vertices(model) -> Dict[str, np.ndarray]:
    """``{"hand_left", "hand_right", "face": vertex indices}`` by the largest skinning weight."""
    owner = model.lbs_weights.detach().cpu().numpy().argmax(1)
    names = model.joint_names
    out = {}
    for side in ("left", "right"):
        joints = [
            i
            for i, n in enumerate(names)
            if n == f"{side}_wrist"
            or (
                n.startswith(f"{side}_")
                and n[len(side) + 1 :].rstrip("123") in ("thumb", "index", "middle", "ring", "pinky")
            )
        ]
        out[f"hand_{side}"] = np.flatnonzero(np.isin(owner, joints))
    out["face"] = np.flatnonzero(np.isin(owner, [names.index(n) for n in _FACE_JOINTS if n in names]))
    return out


def wholebody_errors(model, pred: dict, gt: dict) -> dict:
    """Errors of one fit: ``pred``/``gt`` hold ``vertices [V, 3]``, ``joints [J, 3]`` and the
    ``expression`` coefficients (see the module docstring)."""
    parts = part_vertices(model)
    names = model.joint_names
    pv, gv = np.asarray(pred["vertices"], np.float64), np.asarray(gt["vertices"], np.float64)
    pj, gj = np.asarray(pred["joints"], np.float64), np.asarray(gt["joints"], np.float64)
    out = {"pa_pve_mm": 1000 * pa_pve(pv, gv)}
    wrist, pa = [], []
    for side in ("left", "right"):
        idx = parts[f"hand_{side}"]
        w = names.index(f"{side}_wrist")
        wrist.append(np.linalg.norm((pv[idx] - pj[w]) - (gv[idx] - gj[w]), axis=1).mean())
        pa.append(np.linalg.norm(procrustes_align(pv[idx], gv[idx]) - gv[idx], axis=1).mean())
        out[f"hand_{side}_pa_mm"] = 1000 * float(pa[-1])
    out["hand_wrist_mm"] = 1000 * float(np.mean(wrist))
    out["hand_pa_mm"] = 1000 * float(np.mean(pa))
    f = parts["face"]
    out["face_pa_mm"] = 1000 * float(np.linalg.norm(procrustes_align(pv[f], gv[f]) - gv[f], axis=1).mean())
    pe, ge = pred.get("expression"), gt.get("expression")
    if pe is not None and ge is not None:
        pe, ge = np.asarray(pe, np.float64).reshape(-1), np.asarray(ge, np.float64).reshape(-1)
        n = min(len(pe), len(ge))
        out["expression_err"] = float(np.sqrt(np.mean((pe[:n] - ge[:n]) ** 2)))
    return out
