"""Plausible body poses that do not come from the pose library.

Each sample is one of a few **archetypes**, parameterised continuously and with the limbs
coupled as people move, then varied at random:

* ``squat`` (depth 0.3-1: hips flex 45-125 degrees with the knees 50-145, the ankles
  dorsiflex and the trunk leans forward with the depth), ``kneel_one`` / ``kneel_both``
  (upright, or sitting back on the heels), ``sit`` (chair to floor), ``run`` (a phase of
  the stride: the forward thigh's flexion drives its knee, the opposite arm swings
  forward, the trunk counter-rotates), ``lunge`` (front knee over the ankle, back knee
  toward the floor), ``reach_overhead`` / ``reach_forward`` (reaching forward bends the
  trunk and hips with the arm), and the **contact** archetypes ``hand_face``,
  ``hand_head`` and ``hand_hip``: the hand is brought to the face / head / hip until the
  mesh surfaces touch (:func:`silfit.poses.contact.settle_contact`);
* free arms get an arm state coupled within the arm (hanging, forward, hands on the
  knees, clasped in front, on the hips, crossed, guard) chosen per archetype;
* every joint is then perturbed (Gaussian, ``perturb_deg`` scaled per joint by
  :data:`silfit.poses.library.PERTURB_SCALE`), the pose mirrored left-right with
  probability 1/2 and clamped into the joint limits (:mod:`silfit.priors.limits`);
* a sample is drawn again if it self-intersects: its interpenetration
  (:class:`silfit.priors.SphereCollisionModel`, mean shape) exceeds
  ``max_interpenetration`` m^2, or, on the mesh (:func:`silfit.poses.contact.part_contact`),
  a forearm or hand lies more than ``max_depth`` inside the torso, a thigh, the head or
  the other arm (the spheres do not cover every surface).

Deterministic for a ``numpy.random.Generator`` (or a seed). Angles are degrees in the
parameters, radians in the arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch

from ..body import load_body_model
from ..body.lbs import axis_angle_to_matrix, blend_shapes, forward_kinematics, vertices_to_joints
from ..priors.interpenetration import SphereCollisionModel
from ..priors.limits import clamp_to_limits
from .contact import part_contact, posed_vertices, settle_contact
from .library import (
    BODY_JOINTS,
    PERTURB_SCALE,
    ankle,
    arm,
    axis_rot,
    build_pose,
    elbow,
    knee,
    leg,
    mirror_pose,
    mirror_rotvec,
    trunk,
)

__all__ = ["ARCHETYPES", "DEEP_FLEXION", "SampledPose", "PoseSampler", "sample_poses"]


@dataclass
class SampledPose:
    body_pose: np.ndarray  # [69]
    root: np.ndarray  # [3] axis-angle in the body frame
    archetype: str
    params: Dict[str, float] = field(default_factory=dict)  # the archetype's continuous parameters
    mirrored: bool = False
    interpenetration: float = 0.0  # m^2, mean shape
    tries: int = 1

    # The fields the dataset generator records for a library sample.
    name = property(lambda self: self.archetype)
    blend = None
    blend_weight = 0.0

    def describe(self) -> str:
        p = ", ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in self.params.items())
        return f"{self.archetype}" + (" (mirrored)" if self.mirrored else "") + (f": {p}" if p else "")


def _u(rng, lo, hi) -> float:
    return float(rng.uniform(lo, hi))


def _spine(flex=0.0, side_bend=0.0, twist=0.0) -> dict:
    return {f"spine{i + 1}": trunk(flex * s, side_bend * s, twist * s) for i, s in enumerate((0.4, 0.3, 0.3))}


def _head(flex=0.0, turn=0.0, tilt=0.0) -> dict:
    return {"neck": trunk(flex * 0.5, tilt * 0.5, turn * 0.5), "head": trunk(flex * 0.5, tilt * 0.5, turn * 0.5)}


# ----------------------------------------------------------------------------- arms
def _arm_state(rng, side: str, style: str) -> Tuple[dict, str]:
    S = side.lower() == "l" and "left" or "right"
    if style == "hanging":
        abd, fwd = _u(rng, 6, 25), _u(rng, -15, 25)
        d = (math.sin(math.radians(abd)), -math.cos(math.radians(abd)), math.tan(math.radians(fwd)))
        spec = {f"{S}_shoulder": arm(side, d, internal=_u(rng, 0, 30)), f"{S}_elbow": elbow(side, _u(rng, 5, 45))}
    elif style == "forward":  # reaching / balancing forward; elbow straighter the higher the arm
        up = _u(rng, -0.5, 0.4)
        spec = {
            f"{S}_shoulder": arm(side, (_u(rng, 0.1, 0.5), up, 1.0)),
            f"{S}_elbow": elbow(side, _u(rng, 5, 40) * (1 - up)),
        }
    elif style == "on_knees":
        spec = {
            f"{S}_shoulder": arm(side, (_u(rng, 0.1, 0.3), -1, _u(rng, 0.4, 0.8)), internal=_u(rng, 10, 30)),
            f"{S}_elbow": elbow(side, _u(rng, 20, 50)),
        }
    elif style == "clasped":
        spec = {
            f"{S}_shoulder": arm(side, (0.4, -0.8, _u(rng, 0.6, 1.0)), internal=_u(rng, 40, 55)),
            f"{S}_elbow": elbow(side, _u(rng, 80, 110)),
        }
    elif style == "guard":
        spec = {
            f"{S}_shoulder": arm(side, (0.4, -0.8, _u(rng, 0.5, 0.7)), internal=_u(rng, 25, 35)),
            f"{S}_elbow": elbow(side, _u(rng, 110, 130)),
        }
    else:
        raise ValueError(f"unknown arm style {style!r}")
    return spec, style


def _arms(rng, styles: Sequence[str]) -> Tuple[dict, str]:
    style = styles[int(rng.integers(len(styles)))]
    if style in ("clasped", "guard"):  # both arms together
        left, _ = _arm_state(rng, "L", style)
        right, _ = _arm_state(rng, "R", style)
        return {**left, **right}, style
    left, a = _arm_state(rng, "L", style)
    right, b = _arm_state(rng, "R", styles[int(rng.integers(len(styles)))])
    return {**left, **right}, f"{a}/{b}"


# ----------------------------------------------------------------------------- archetypes
def _squat(rng):
    t = _u(rng, 0.3, 1.0)
    abd, rot = _u(rng, 8, 25), _u(rng, 5, 20)
    hip, kn = 45 + 80 * t, 50 + 95 * t
    spec = {
        "left_hip": leg("L", flex=hip + _u(rng, -5, 5), abd=abd, ext_rot=rot),
        "right_hip": leg("R", flex=hip + _u(rng, -5, 5), abd=abd, ext_rot=rot),
        "left_knee": knee(kn),
        "right_knee": knee(kn + _u(rng, -5, 5)),
        "left_ankle": ankle("L", plantar=-(10 + 25 * t)),
        "right_ankle": ankle("R", plantar=-(10 + 25 * t)),
        **_spine(flex=15 + 25 * t),
        **_head(flex=-(5 + 20 * t)),
    }
    arms, style = _arms(rng, ("forward", "on_knees", "clasped", "hanging"))
    return {**spec, **arms}, np.zeros(3), {"depth": t, "arms": style}


def _kneel_one(rng):
    front, back_flex = _u(rng, 70, 100), _u(rng, -15, 10)
    spec = {
        "left_hip": leg("L", flex=front, abd=_u(rng, 0, 12)),
        "left_knee": knee(front + _u(rng, -5, 15)),
        "left_ankle": ankle("L", plantar=_u(rng, -15, 0)),
        "right_hip": leg("R", flex=back_flex, abd=_u(rng, 0, 8)),
        "right_knee": knee(_u(rng, 85, 110) - back_flex),
        "right_ankle": ankle("R", plantar=_u(rng, -25, 30)),
        **_spine(flex=_u(rng, 0, 25)),
    }
    arms, style = _arms(rng, ("on_knees", "hanging", "forward", "clasped"))
    return {**spec, **arms}, np.zeros(3), {"front_hip": front, "arms": style}


def _kneel_both(rng):
    s = _u(rng, 0.0, 1.0)  # 0 upright on the knees, 1 sitting back on the heels
    hip, kn = 5 + 55 * s, 95 + 50 * s
    spec = {
        "left_hip": leg("L", flex=hip, abd=_u(rng, 2, 12)),
        "right_hip": leg("R", flex=hip, abd=_u(rng, 2, 12)),
        "left_knee": knee(kn),
        "right_knee": knee(kn),
        "left_ankle": ankle("L", plantar=_u(rng, 20, 50)),
        "right_ankle": ankle("R", plantar=_u(rng, 20, 50)),
        **_spine(flex=_u(rng, 0, 20) + 15 * s),
    }
    arms, style = _arms(rng, ("hanging", "on_knees", "clasped", "forward"))
    return {**spec, **arms}, np.zeros(3), {"sit_back": s, "arms": style}


def _sit(rng):
    hip = _u(rng, 75, 110)
    kn = _u(rng, 60, 125)
    spec = {
        "left_hip": leg("L", flex=hip, abd=_u(rng, 3, 20), ext_rot=_u(rng, 0, 15)),
        "right_hip": leg("R", flex=hip + _u(rng, -8, 8), abd=_u(rng, 3, 20), ext_rot=_u(rng, 0, 15)),
        "left_knee": knee(kn),
        "right_knee": knee(kn + _u(rng, -15, 15)),
        **_spine(flex=_u(rng, 0, 25)),
        **_head(flex=_u(rng, -10, 10)),
    }
    arms, style = _arms(rng, ("on_knees", "hanging", "clasped", "forward"))
    return {**spec, **arms}, axis_rot(("x", -_u(rng, 0, 15))), {"hip": hip, "knee": kn, "arms": style}


def _stride(rng, front_hip, front_knee, back_hip, back_knee, lean, arm_swing):
    swing = arm_swing
    spec = {
        "left_hip": leg("L", flex=front_hip),
        "left_knee": knee(front_knee),
        "left_ankle": ankle("L", plantar=_u(rng, -10, 20)),
        "right_hip": leg("R", flex=back_hip),
        "right_knee": knee(back_knee),
        "right_ankle": ankle("R", plantar=_u(rng, -20, 35)),
        # Opposite arm forward: the right arm swings with the left thigh.
        "right_shoulder": arm("R", (0.2, -1, swing), internal=10),
        "right_elbow": elbow("R", _u(rng, 70, 100)),
        "left_shoulder": arm("L", (0.2, -1, -0.8 * swing), internal=10),
        "left_elbow": elbow("L", _u(rng, 70, 100)),
        **_spine(flex=lean, twist=-8 * swing),
    }
    return spec


def _run(rng):
    phase = _u(rng, 0.0, 1.0)  # 0 stance (front leg under the body) .. 1 flight (thigh driven high)
    front_hip = 15 + 55 * phase
    spec = _stride(
        rng,
        front_hip,
        30 + 70 * phase + _u(rng, -10, 20),
        -(10 + 20 * phase),
        _u(rng, 30, 110),
        _u(rng, 5, 18),
        0.4 + 0.4 * phase,
    )
    return spec, np.zeros(3), {"phase": phase}


def _lunge(rng):
    depth = _u(rng, 0.4, 1.0)
    spec = _stride(rng, 45 + 40 * depth, 45 + 45 * depth, -(10 + 25 * depth), 20 + 75 * depth, _u(rng, -5, 15), 0.0)
    arms, style = _arms(rng, ("hanging", "forward", "clasped"))
    spec.update(arms)
    return spec, np.zeros(3), {"depth": depth, "arms": style}


def _reach_overhead(rng):
    both = rng.random() < 0.5
    spec = {
        "right_shoulder": arm("R", (_u(rng, 0.1, 0.5), 1, _u(rng, -0.1, 0.4))),
        "right_elbow": elbow("R", _u(rng, 0, 30)),
        "right_collar": axis_rot(("z", -_u(rng, 5, 20))),
        **_spine(flex=-_u(rng, 0, 15)),
        **_head(flex=-_u(rng, 5, 25)),
        "left_ankle": ankle("L", plantar=_u(rng, 0, 30)),
        "right_ankle": ankle("R", plantar=_u(rng, 0, 30)),
    }
    if both:
        spec["left_shoulder"] = arm("L", (_u(rng, 0.1, 0.5), 1, _u(rng, -0.1, 0.4)))
        spec["left_elbow"] = elbow("L", _u(rng, 0, 30))
    else:
        spec.update(_arm_state(rng, "L", "hanging")[0])
    return spec, np.zeros(3), {"both": int(both)}


def _reach_forward(rng):
    t = _u(rng, 0.2, 1.0)  # how far: the trunk and hips bend with the reach
    spec = {
        "right_shoulder": arm("R", (_u(rng, 0.05, 0.3), _u(rng, -0.6, 0.1), 1)),
        "right_elbow": elbow("R", _u(rng, 0, 20)),
        "left_hip": leg("L", flex=10 + 40 * t),
        "right_hip": leg("R", flex=10 + 40 * t + _u(rng, -10, 10)),
        "left_knee": knee(_u(rng, 0, 30) * t),
        "right_knee": knee(_u(rng, 0, 40) * t),
        **_spine(flex=10 + 35 * t, twist=_u(rng, -15, 5)),
        **_head(flex=-15 * t),
    }
    spec.update(_arm_state(rng, "L", ("hanging", "forward")[int(rng.integers(2))])[0])
    return spec, axis_rot(("x", 10 * t)), {"reach": t}


#: contact targets: (shoulder direction ranges (out, up, fwd), internal rotation range,
#: elbow flexion that takes the hand into the target, joints touched)
_CONTACT = {
    "hand_face": (((0.3, 0.6), (0.1, 0.3), (0.7, 0.9)), (-70, -50), 150.0, ["head", "neck"]),
    "hand_head": (((0.6, 0.8), (0.6, 0.8), (0.1, 0.3)), (-95, -80), 150.0, ["head", "neck"]),
    "hand_hip": (
        ((0.5, 0.7), (-1.0, -1.0), (-0.15, 0.0)),
        (55, 65),
        100.0,
        ["pelvis", "spine1", "left_hip", "right_hip"],
    ),
}


def _contact(kind):
    def make(rng):
        (o, u, f), (i0, i1), flex, _ = _CONTACT[kind]
        base_name = ("stand", "sit", "kneel_both")[int(rng.choice(3, p=(0.6, 0.2, 0.2)))]
        base = {
            "stand": lambda r: (_arms(r, ("hanging",))[0], np.zeros(3), {}),
            "sit": _sit,
            "kneel_both": _kneel_both,
        }[base_name]
        spec, root, params = base(rng)
        d = (_u(rng, *o), _u(rng, *u), _u(rng, *f))
        spec["right_shoulder"] = arm("R", d, internal=_u(rng, i0, i1))
        spec["right_elbow"] = elbow("R", flex)
        spec["left_shoulder"] = spec.get("left_shoulder", arm("L", (0.15, -1, 0.1)))
        params = {"base": base_name, **{k: v for k, v in params.items() if k != "arms"}}
        return spec, root, params

    return make


#: ``{name: (weight in the hard mix, sampler)}``
ARCHETYPES: Dict[str, Tuple[float, Callable]] = {
    "squat": (0.16, _squat),
    "kneel_one": (0.09, _kneel_one),
    "kneel_both": (0.08, _kneel_both),
    "sit": (0.07, _sit),
    "run": (0.11, _run),
    "lunge": (0.11, _lunge),
    "reach_overhead": (0.06, _reach_overhead),
    "reach_forward": (0.06, _reach_forward),
    "hand_face": (0.1, _contact("hand_face")),
    "hand_head": (0.08, _contact("hand_head")),
    "hand_hip": (0.08, _contact("hand_hip")),
}
#: Archetypes whose front and back views are the hard ones (a limb along the viewing ray).
DEEP_FLEXION = ("squat", "kneel_one", "kneel_both", "run", "lunge", "hand_face", "hand_head")

_R_HAND = ["right_wrist", "right_hand"]
_ARMS = {side: [f"{side}_elbow", f"{side}_wrist", f"{side}_hand"] for side in ("left", "right")}
_MESH_PAIRS = [
    (_ARMS[side], target)
    for side in ("left", "right")
    for target in (["pelvis", "spine1", "spine2", "spine3"], ["left_hip"], ["right_hip"], ["head", "neck"])
] + [(_ARMS["left"], _ARMS["right"])]


class PoseSampler:
    """Draws :class:`SampledPose` objects; see the module docstring.

    ``model``: the body model (default the shipped open model); ``archetypes``: names to
    draw from (default all, with the weights of :data:`ARCHETYPES`)."""

    def __init__(
        self,
        model=None,
        archetypes: Optional[Sequence[str]] = None,
        perturb_deg: float = 5.0,
        max_interpenetration: float = 5e-5,
        max_depth: float = 0.015,
        max_tries: int = 30,
    ):
        if model is None:
            model = load_body_model()
        names = list(ARCHETYPES) if archetypes is None else list(archetypes)
        unknown = [n for n in names if n not in ARCHETYPES]
        if unknown or not names:
            raise ValueError(f"unknown or no archetypes {unknown}; known: {', '.join(ARCHETYPES)}")
        self.model, self.names = model, names
        w = np.array([ARCHETYPES[n][0] for n in names])
        self.weights = w / w.sum()
        self.perturb_deg, self.max_interpenetration, self.max_tries = (
            float(perturb_deg),
            float(max_interpenetration),
            int(max_tries),
        )
        self.max_depth = float(max_depth)
        self.collisions = SphereCollisionModel(model)
        self._sigma = np.repeat([PERTURB_SCALE[j] for j in BODY_JOINTS], 3) * math.radians(self.perturb_deg)

    def interpenetration(self, body_pose: np.ndarray) -> float:
        """Sphere interpenetration (m^2) of ``body_pose [69]`` on the mean shape."""
        m = self.model
        betas = torch.zeros(1, m.num_betas, dtype=m.dtype)
        full = torch.cat([torch.zeros(1, 3, dtype=m.dtype), torch.as_tensor(body_pose, dtype=m.dtype)[None]], 1)
        rest = vertices_to_joints(m.J_regressor, m.v_template + blend_shapes(betas, m.shapedirs))
        with torch.no_grad():
            _, T = forward_kinematics(axis_angle_to_matrix(full.reshape(1, -1, 3)), rest, m.parents, m._levels)
            return float(self.collisions(betas, T)[0])

    def mesh_depth(self, body_pose: np.ndarray) -> float:
        """Deepest forearm / hand vertex (m) inside the torso, a thigh, the head or the other arm."""
        v = posed_vertices(self.model, body_pose)
        return max(part_contact(self.model, v, a, b).depth for a, b in _MESH_PAIRS)

    def _draw(self, rng, name: str) -> SampledPose:
        spec, root, params = ARCHETYPES[name][1](rng)
        pose = build_pose(spec) + rng.normal(0.0, 1.0, 69) * self._sigma
        pose = clamp_to_limits(torch.as_tensor(pose, dtype=torch.float64)).numpy()
        if name in _CONTACT:
            pose, params["gap_cm"] = self._settle(pose, _CONTACT[name][3])
            pose = clamp_to_limits(torch.as_tensor(pose, dtype=torch.float64)).numpy()
        mirrored = bool(rng.random() < 0.5)
        if mirrored:
            pose, root = mirror_pose(pose), mirror_rotvec(root)
        return SampledPose(pose, np.asarray(root, dtype=np.float64), name, params, mirrored)

    def _settle(self, pose: np.ndarray, target: List[str]) -> Tuple[np.ndarray, float]:
        """Bend the right elbow (and bring the arm in) from ``pose`` back toward a bent-less
        arm until the right hand just touches ``target``."""
        apart = pose.reshape(23, 3).copy()
        e = BODY_JOINTS.index("right_elbow")
        apart[e] = elbow("R", 40.0)
        pairs = [(_R_HAND, target), (["right_elbow"], ["spine1", "spine2", "spine3", "pelvis"])]
        settled = settle_contact(self.model, apart.reshape(69), pose, pairs)
        c = part_contact(self.model, posed_vertices(self.model, settled), _R_HAND, target)
        return settled, round(c.gap * 100, 2)

    def sample(self, rng, archetype: Optional[str] = None) -> SampledPose:
        """One pose of ``archetype`` (default: drawn by weight), redrawn while it self-intersects
        (the least intersecting of ``max_tries`` draws if all do)."""
        rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
        best = None
        # The archetype is drawn once, so ones that are often redrawn keep their share.
        name = archetype or self.names[int(rng.choice(len(self.names), p=self.weights))]
        for k in range(self.max_tries):
            s = self._draw(rng, name)
            s.interpenetration, s.tries = self.interpenetration(s.body_pose), k + 1
            if s.interpenetration <= self.max_interpenetration:
                s.params["mesh_depth_cm"] = round(self.mesh_depth(s.body_pose) * 100, 2)
                if s.params["mesh_depth_cm"] <= self.max_depth * 100:
                    return s
            if best is None or s.interpenetration < best.interpenetration:
                best = s
        return best


def sample_poses(n: int, seed: int = 0, model=None, **settings) -> List[SampledPose]:
    """``n`` poses from a :class:`PoseSampler` (``settings``), pose ``i`` drawn with
    ``numpy.random.default_rng([seed, i])`` (so a prefix does not depend on ``n``)."""
    sampler = PoseSampler(model, **settings)
    return [sampler.sample(np.random.default_rng([int(seed), i])) for i in range(int(n))]
