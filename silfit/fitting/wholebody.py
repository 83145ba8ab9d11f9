"""Whole-body pieces of the fitting core: the hand and face terms of the energy and the per-problem
gates that hold absent parts at rest.

The ``wholebody`` keypoint layout (:data:`silfit.keypoints.WHOLEBODY_NAMES`) is one keypoint vector
per observation (body, left hand, right hand, face), so the parts are :class:`KeypointTerm` s over
masks of it: ``keypoints`` (the body's 25, as for BODY_25), ``hands`` (both hands' 42) and ``face``
(70), each with its own robust scale. Their priors are :class:`PriorTerm` s: ``hand_pose``
(:class:`~silfit.priors.wholebody.HandPosePrior` per hand), ``jaw`` and ``expression`` (L2).
"""
from __future__ import annotations

from typing import Dict, List

import torch

from ..priors.wholebody import HandPosePrior, l2, library_hand_set
from ..wholebody import part_slices
from .terms import KeypointTerm, PriorTerm, Term, evaluate

__all__ = ["GATED_PARTS", "choose_hand_starts", "hand_priors", "part_gates", "part_masks", "wholebody_terms"]

#: parameter -> the keypoint part whose confident points free it
GATED_PARTS = {"left_hand_pose": "hand_left", "right_hand_pose": "hand_right", "jaw_pose": "face", "expression": "face"}

_PRIORS: Dict[tuple, tuple] = {}


def hand_priors(model, dtype) -> tuple:
    """The left and right :class:`HandPosePrior` of ``model`` (built once per model file and setting)."""
    key = (model.source, bool(getattr(model, "use_pca", False)), getattr(model, "num_pca_comps", 45), dtype)
    if key not in _PRIORS:
        _PRIORS[key] = tuple(HandPosePrior(model, side, dtype=dtype) for side in ("left", "right")) + tuple(
            library_hand_set(model, side).to(dtype) for side in ("left", "right"))
    return _PRIORS[key]


def part_masks(dtype=torch.float64) -> Dict[str, torch.Tensor]:
    """``{part: [137]}`` 0/1 masks of the ``wholebody`` layout (``hands``: both hands)."""
    sl = part_slices()
    K = sl["face"].stop
    out = {}
    for name, parts in (("body", ("body",)), ("hands", ("hand_left", "hand_right")), ("face", ("face",))):
        m = torch.zeros(K, dtype=dtype)
        for p in parts:
            m[sl[p]] = 1.0
        out[name] = m
    return out


def wholebody_terms(model, terms: List[Term], sigma, config, dtype) -> List[Term]:
    """The body terms (``keypoints`` restricted to the body's points) plus the hand and face terms."""
    masks = part_masks(dtype)
    robust = sigma is not None
    out = [KeypointTerm("keypoints", sigma, mask=masks["body"]) if t.name == "keypoints" else t for t in terms]
    left, right = hand_priors(model, dtype)[:2]
    out += [
        KeypointTerm("hands", config.hand_sigma if robust else None, mask=masks["hands"]),
        KeypointTerm("face", config.face_sigma if robust else None, mask=masks["face"]),
        PriorTerm("hand_pose", (left, right), ("left_hand_pose", "right_hand_pose")),
        PriorTerm("jaw", l2, "jaw_pose"), PriorTerm("expression", l2, "expression"),
    ]  # fmt: skip
    return out


def part_gates(weights: torch.Tensor) -> Dict[str, torch.Tensor]:
    """``{"gate_<param>": [P, F, 1]}`` from the keypoint weights ``[P, F, C, 137]``: 1 where any view
    of the frame has a confident point of the part that frees the parameter, else 0 (held at rest)."""
    sl = part_slices()
    present = {p: (weights[..., sl[p]] > 0).any(-1).any(-1) for p in set(GATED_PARTS.values())}
    return {f"gate_{n}": present[p].to(weights.dtype)[..., None] for n, p in GATED_PARTS.items()}


def parts_fitted(gates: Dict[str, torch.Tensor]) -> List[dict]:
    """Per problem: ``{param: bool}`` whether the parameter was fitted (not held at rest)."""
    P = next(iter(gates.values())).shape[0]
    return [{k[len("gate_"):]: bool(v[b].any()) for k, v in gates.items()} for b in range(P)]


@torch.no_grad()
def choose_hand_starts(model, body, layout, state, views, data, sigma) -> dict:
    """Each problem's hands started from the library pose (or its current pose) whose keypoints fit
    that hand's 2D points best, each hand on its own (one batched evaluation per candidate); hands
    without confident points keep their value. Returns the new state (hand poses replaced)."""
    from .losses import reprojection_energy

    sl = part_slices()
    libs = dict(zip(("left_hand_pose", "right_hand_pose"), hand_priors(model, state["body_pose"].dtype)[2:]))
    cands = {n: [state[n]] + [lib[h].expand_as(state[n]) for h in range(len(lib))] for n, lib in libs.items()}
    H = len(cands["left_hand_pose"])
    P = state["body_pose"].shape[0]
    scores = {n: [] for n in libs}
    for h in range(H):
        trial = {**state, **{n: cands[n][h] for n in libs}}
        ev = evaluate(body, layout, trial, views, data)
        for n, part in (("left_hand_pose", "hand_left"), ("right_hand_pose", "hand_right")):
            k = sl[part]
            K = k.stop - k.start
            e = reprojection_energy(ev.keypoints_2d[..., k, :].reshape(-1, K, 2), data["target"][..., k, :].reshape(-1, K, 2),
                                    data["weights"][..., k].reshape(-1, K), data["scale"].reshape(-1), sigma)  # fmt: skip
            scores[n].append(e.reshape(P, -1).sum(1))
    out = dict(state)
    for n in libs:
        best = torch.stack(scores[n], 1).argmin(1)  # [P]
        stacked = torch.stack(cands[n], 0)  # [H, P, F, w]
        chosen = stacked[best, torch.arange(P)]
        gate = data.get(f"gate_{n}")
        out[n] = chosen if gate is None else state[n] + gate.to(chosen.dtype) * (chosen - state[n])
    return out


def wholebody_summary(keypoints) -> tuple:
    """``(summary, notes)`` for a fit's metrics: which parts had confident points, which parameters
    were fitted and which were held at rest, and a line for each part held at rest."""
    sl = part_slices()
    present = {p: bool((keypoints.conf[sl[p]] > 0).any()) for p in sl}
    fitted = {n: present[p] for n, p in GATED_PARTS.items()}
    rest = [n for n, f in fitted.items() if not f]
    notes = []
    for part, params in (("hand_left", "left_hand_pose"), ("hand_right", "right_hand_pose"), ("face", "jaw_pose and expression")):
        if not present[part]:
            notes.append(f"no {part.replace('_', ' ')} keypoints: {params} left at rest")
    return {"parts_present": present, "parameters_fitted": fitted, "held_at_rest": rest}, notes
