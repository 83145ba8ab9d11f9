"""Whole-body pieces of the fitting core: the hand and face terms of the energy and the per-problem
gates that hold absent parts at rest.

The ``wholebody`` keypoint layout (:data:`silfit.io.keypoints.WHOLEBODY_NAMES`) is one keypoint vector
per observation (body, left hand, right hand, face), so the parts are :class:`KeypointTerm` s over
masks of it: ``keypoints`` (the body's 25, as for BODY_25), ``hands`` (both hands' 42) and ``face``
(70), each with its own robust scale. Their priors are :class:`PriorTerm` s: ``hand_pose``
(:class:`~silfit.priors.smplx_priors.HandPosePrior` per hand), ``jaw`` and ``expression`` (L2).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Dict, List

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..io.keypoints import KeypointSet
from ..priors.smplx_priors import HandPosePrior, l2, library_hand_set
from ..io.wholebody import part_slices
from .losses import reprojection_energy
from .terms import KeypointTerm, PointsTerm, PriorTerm, Term, evaluate

__all__ = ["GATED_PARTS", "choose_hand_starts", "hand_priors", "part_gates", "part_masks", "wholebody_terms"]

#: parameter -> the keypoint part whose confident points free it
GATED_PARTS = {"left_hand_pose": "hand_left", "right_hand_pose": "hand_right", "jaw_pose": "face", "expression": "face"}

_PRIORS: Dict[tuple, tuple] = {}


def hand_priors(model, dtype) -> tuple:
    """The left and right :class:`HandPosePrior` of ``model`` (built once per model file and setting)."""
    key = (model.source, bool(getattr(model, "use_pca", False)), getattr(model, "num_pca_comps", 45), dtype)
    if key not in _PRIORS:
        _PRIORS[key] = tuple(HandPosePrior(model, side, dtype=dtype) for side in ("left", "right")) + tuple(
            library_hand_set(model, side).to(dtype) for side in ("left", "right")
        )
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
    """The body terms (``keypoints`` and ``points`` restricted to the body's points) plus the hand and face terms
    (``config``: :class:`~silfit.fitting.keypoint_stage.HandsFace`, their robust scales)."""
    masks = part_masks(dtype)
    robust = sigma is not None
    body = {"keypoints": KeypointTerm("keypoints", sigma, mask=masks["body"])}
    body.update({t.name: PointsTerm(t.sigma, t.scale, mask=masks["body"]) for t in terms if t.name == "points"})
    out = [body.get(t.name, t) for t in terms]
    left, right = hand_priors(model, dtype)[:2]
    out += [
        KeypointTerm("hands", config.hand_sigma if robust else None, mask=masks["hands"]),
        KeypointTerm("face", config.face_sigma if robust else None, mask=masks["face"]),
        PriorTerm("hand_pose", (left, right), ("left_hand_pose", "right_hand_pose")),
        PriorTerm("jaw", l2, "jaw_pose"),
        PriorTerm("expression", l2, "expression"),
    ]
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
    return [{k[len("gate_") :]: bool(v[b].any()) for k, v in gates.items()} for b in range(P)]


#: wrist offsets tried by :func:`choose_hand_starts` (degrees): twist about the forearm, then flexion
WRIST_TWIST_DEG = (-135.0, -90.0, -45.0, 0.0, 45.0, 90.0, 135.0, 180.0)
WRIST_FLEX_DEG = (-40.0, 0.0, 40.0)


def _wrist_offsets(side: str, dtype) -> torch.Tensor:
    """``[R, 3, 3]`` local wrist rotations: twists about the rest forearm axis (+-X) times flexions
    about the rest palm's side axis (Z), in the joint's rest frame (SMPL-X's rest hands are flat, palm down)."""
    sign = 1.0 if side == "left" else -1.0
    mats = [
        (
            Rotation.from_rotvec([sign * np.radians(t), 0, 0]) * Rotation.from_rotvec([0, 0, sign * np.radians(f)])
        ).as_matrix()
        for t in WRIST_TWIST_DEG
        for f in WRIST_FLEX_DEG
    ]
    return torch.as_tensor(np.stack(mats), dtype=dtype)


def _compose_wrist(body_pose: torch.Tensor, j: int, offset: torch.Tensor) -> torch.Tensor:
    """``body_pose`` with joint ``j``'s rotation ``R`` replaced by ``R @ offset``."""
    shape = body_pose.shape
    flat = body_pose.reshape(-1, shape[-1]).clone()
    sl = slice(3 * (j - 1), 3 * j)
    R = Rotation.from_rotvec(flat[:, sl].double().numpy()) * Rotation.from_matrix(offset.double().numpy())
    flat[:, sl] = torch.as_tensor(R.as_rotvec(), dtype=body_pose.dtype)
    return flat.reshape(shape)


@torch.no_grad()
def choose_hand_starts(model, body, layout, state, views, data, sigma) -> dict:
    """Each problem's hands started from the library pose (or its current pose) and the wrist
    rotation (the current one turned by :data:`WRIST_TWIST_DEG` x :data:`WRIST_FLEX_DEG`) whose
    keypoints fit that hand's 2D points best, each hand on its own (one batched evaluation per
    candidate); hands without confident points keep their values. Returns the new state."""
    sl = part_slices()
    dt = state["body_pose"].dtype
    sides = (("left", "left_hand_pose", "hand_left"), ("right", "right_hand_pose", "hand_right"))
    libs = dict(zip(("left_hand_pose", "right_hand_pose"), hand_priors(model, dt)[2:]))
    joint = {side: model.joint_names.index(f"{side}_wrist") for side, _, _ in sides}
    offsets = {side: _wrist_offsets(side, dt) for side, _, _ in sides}
    P = state["body_pose"].shape[0]
    hands = {n: [state[n]] + [lib[h].expand_as(state[n]) for h in range(len(lib))] for n, lib in libs.items()}
    wrists = {side: [_compose_wrist(state["body_pose"], joint[side], o) for o in offsets[side]] for side, _, _ in sides}
    best = {
        side: (
            torch.full((P,), float("inf"), dtype=dt),
            torch.zeros(P, dtype=torch.long),
            torch.zeros(P, dtype=torch.long),
        )
        for side, _, _ in sides
    }
    for r in range(len(offsets["left"])):
        pose = wrists["left"][r].clone()
        right_sl = slice(3 * (joint["right"] - 1), 3 * joint["right"])
        pose[..., right_sl] = wrists["right"][r][..., right_sl]
        for h in range(len(hands["left_hand_pose"])):
            trial = {**state, "body_pose": pose, **{n: hands[n][h] for n in libs}}
            ev = evaluate(body, layout, trial, views, data)
            for side, n, part in sides:
                k = sl[part]
                K = k.stop - k.start
                e = reprojection_energy(
                    ev.keypoints_2d[..., k, :].reshape(-1, K, 2),
                    data["target"][..., k, :].reshape(-1, K, 2),
                    data["weights"][..., k].reshape(-1, K),
                    data["scale"].reshape(-1),
                    sigma,
                )
                e = e.reshape(P, -1).sum(1)
                val, bh, br = best[side]
                better = e < val
                best[side] = (torch.where(better, e, val), torch.where(better, h, bh), torch.where(better, r, br))
    out = dict(state)
    body_pose = state["body_pose"].clone()
    for side, n, _ in sides:
        _, bh, br = best[side]
        gate = data.get(f"gate_{n}")
        keep = torch.ones(P, dtype=torch.bool) if gate is None else gate.reshape(P, -1)[:, 0] > 0
        rows = torch.arange(P)
        chosen = torch.stack(hands[n], 0)[bh, rows]
        wsl = slice(3 * (joint[side] - 1), 3 * joint[side])
        wrist = torch.stack(wrists[side], 0)[br, rows][..., wsl]
        out[n] = torch.where(keep.view(P, *[1] * (chosen.ndim - 1)), chosen, state[n])
        body_pose[..., wsl] = torch.where(keep.view(P, *[1] * (wrist.ndim - 1)), wrist, body_pose[..., wsl])
    out["body_pose"] = body_pose
    return out


def wholebody_summary(keypoints) -> tuple:
    """``(summary, notes)`` for a fit's metrics: which parts had confident points, which parameters
    were fitted and which were held at rest, and a line for each part held at rest."""
    sl = part_slices()
    present = {p: bool((keypoints.conf[sl[p]] > 0).any()) for p in sl}
    fitted = {n: present[p] for n, p in GATED_PARTS.items()}
    rest = [n for n, f in fitted.items() if not f]
    notes = []
    for part, params in (
        ("hand_left", "left_hand_pose"),
        ("hand_right", "right_hand_pose"),
        ("face", "jaw_pose and expression"),
    ):
        if not present[part]:
            notes.append(f"no {part.replace('_', ' ')} keypoints: {params} left at rest")
    return {"parts_present": present, "parameters_fitted": fitted, "held_at_rest": rest}, notes


#: the silhouette stage's whole-body additions, relative to its weights: the hand and face keypoint terms
#: (x its keypoint weight), their priors (absolute; the stage's keypoint energies are about 1.6e-4 x the
#: keypoint stage's, so these are the keypoint stage's final prior weights scaled by that) and learning rates
SILHOUETTE_PART_WEIGHTS = {"hands": 2.0, "face": 2.0}
SILHOUETTE_PRIOR_WEIGHTS = {"hand_pose": 3e-4, "jaw": 8e-3, "expression": 3e-4}
SILHOUETTE_PART_LR = {"left_hand_pose": 0.01, "right_hand_pose": 0.01, "jaw_pose": 0.005, "expression": 0.02}


def wholebody_silhouette_inputs(model, keypoints, config, dtype) -> tuple:
    """What the silhouette stage (:func:`~silfit.fitting.silhouette_stage.fit_silhouette_problems`)
    needs to fit a whole-body mesh to one image per problem, keeping the hand and face keypoints:
    ``(config, body_keypoints, terms, weights, data)``. The stage's own keypoint term sees the body
    points (the parts' confidences zeroed, so its normalisation is the body's); ``hands`` and ``face``
    terms read ``part_weights`` (confidence / the observation's body confidence sum). The parts are
    optimised only when every problem of the batch has them (a part that is absent anywhere stays
    where the keypoint stage left it: at rest for the problems without it)."""

    sl = part_slices()
    conf = torch.as_tensor(np.stack([k.conf for k in keypoints]), dtype=dtype)  # [P, K]
    body = conf.clone()
    body[:, sl["body"].stop :] = 0.0
    body_sum = body.sum(1, keepdim=True).clamp(min=1e-12)
    part = conf.clone()
    part[:, sl["body"]] = 0.0
    body_sets = [KeypointSet(k.xy, b.numpy(), k.layout, k.source) for k, b in zip(keypoints, body.double())]
    present = {p: bool((conf[:, sl[p]] > 0).any(1).all()) for p in ("hand_left", "hand_right", "face")}
    free = tuple(n for n, p in GATED_PARTS.items() if present[p])
    cfg = replace(
        config,
        optimise=tuple(config.optimise) + tuple(n for n in free if n not in config.optimise),
        lr={**SILHOUETTE_PART_LR, **config.lr},
    )
    masks = part_masks(dtype)
    left, right = hand_priors(model, dtype)[:2]
    terms = [
        KeypointTerm("hands", config.kp_sigma, mask=masks["hands"], weights_key="part_weights"),
        KeypointTerm("face", config.kp_sigma, mask=masks["face"], weights_key="part_weights"),
        PriorTerm("hand_pose", (left, right), ("left_hand_pose", "right_hand_pose")),
        PriorTerm("jaw", l2, "jaw_pose"),
        PriorTerm("expression", l2, "expression"),
    ]
    weights = {k: v * config.w_keypoints for k, v in SILHOUETTE_PART_WEIGHTS.items()}
    weights.update(SILHOUETTE_PRIOR_WEIGHTS)
    data = {"part_weights": (part / body_sum)[:, None, None]}  # [P, F=1, C=1, K]
    return cfg, body_sets, terms, weights, data


def silhouette_inputs(model, keypoints, config, dtype) -> tuple:
    """What the silhouette stage needs for the keypoint layout of ``keypoints`` (one
    :class:`~silfit.io.keypoints.KeypointSet` per problem): ``(config, keypoint sets, terms,
    weights, data)``, the whole-body terms for the ``wholebody`` layout
    (:func:`wholebody_silhouette_inputs`), none beyond the stage's own for a body layout. The
    one place the layout decides the silhouette stage's terms."""
    if keypoints and keypoints[0].layout == "wholebody":
        return wholebody_silhouette_inputs(model, keypoints, config, dtype)
    return config, list(keypoints), (), {}, {}
