"""A library of hand-authored, named, realistic SMPL body poses (shared by the synthetic
data generator, :mod:`silfit.synth`, and the default pose prior, :mod:`silfit.priors.library_prior`).

No motion-capture data can be downloaded here, so the poses are written by hand with a
few anatomical helpers instead of raw axis-angle numbers. Conventions (SMPL's rest
frame, T-pose rest): Y up, the body facing +Z, +X the body's **left**; every joint's
rotation is relative to its parent and, at rest, every local frame is aligned with the
model frame. See :mod:`silfit.priors.limits` for the signs (knee flexion positive about
+X, hip flexion negative about X, elbow flexion negative Y on the left, ...).

Limb helpers are written for the **left** side in a "side frame" whose +X points
*outward* (away from the midline); the right side's rotation is the mirror image
``(x, y, z) -> (x, -y, -z)``. So ``arm("R", (1, 0, 0))`` is the right arm straight out
to the side, exactly as ``arm("L", (1, 0, 0))`` is the left one.

Every entry is a :class:`LibraryPose`: ``body_pose [69]`` (radians, axis-angle,
SMPL joint order 1..23) and an optional ``root`` rotation (axis-angle in the body's own
frame, applied before the camera placement; used by the lying poses), plus a one-line
description. All library poses lie inside :func:`silfit.priors.within_limits`
(checked by the tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Sequence, Tuple

import numpy as np
from scipy.spatial.transform import Rotation

from ..body.io import SMPL_JOINT_NAMES

__all__ = [
    "BODY_JOINTS",
    "LibraryPose",
    "POSE_LIBRARY",
    "FRONTAL_POSES",
    "pose_names",
    "get_pose",
    "mirror_pose",
    "mirror_rotvec",
    "arm",
    "leg",
    "axis_rot",
    "PERTURB_SCALE",
    "build_pose",
    "blend_poses",
    "elbow",
    "knee",
    "ankle",
    "trunk",
    "collar",
    "wrist",
]

#: The 23 joints of ``body_pose`` in SMPL order (joint 1..23).
BODY_JOINTS = SMPL_JOINT_NAMES[1:]
_INDEX = {name: i for i, name in enumerate(BODY_JOINTS)}

D = math.radians


#: Per-joint scale of the random perturbation around a library pose (1 = the configured sigma).
PERTURB_SCALE = {
    "left_hip": 1.0,
    "right_hip": 1.0,
    "spine1": 0.6,
    "left_knee": 1.0,
    "right_knee": 1.0,
    "spine2": 0.5,
    "left_ankle": 0.8,
    "right_ankle": 0.8,
    "spine3": 0.5,
    "left_foot": 0.3,
    "right_foot": 0.3,
    "neck": 0.8,
    "left_collar": 0.4,
    "right_collar": 0.4,
    "head": 1.0,
    "left_shoulder": 1.5,
    "right_shoulder": 1.5,
    "left_elbow": 1.5,
    "right_elbow": 1.5,
    "left_wrist": 1.2,
    "right_wrist": 1.2,
    "left_hand": 0.5,
    "right_hand": 0.5,
}


# ----------------------------------------------------------------------------- rotation helpers
def mirror_rotvec(rv) -> np.ndarray:
    """Axis-angle of the rotation mirrored through the body's sagittal plane (x -> -x)."""
    rv = np.asarray(rv, dtype=np.float64)
    return rv * np.array([1.0, -1.0, -1.0])


def _R(axis: str, deg: float) -> Rotation:
    return Rotation.from_rotvec(np.eye(3)["xyz".index(axis)] * D(deg))


def axis_rot(*steps: Tuple[str, float]) -> np.ndarray:
    """Axis-angle of elementary rotations applied in order, e.g. ``axis_rot(("z", 30), ("x", -20))``
    rotates about Z by 30 degrees first, then about X by -20 degrees (both in the parent frame)."""
    r = Rotation.identity()
    for axis, deg in steps:
        r = _R(axis, deg) * r
    return r.as_rotvec()


def _min_rotation(a: np.ndarray, b: np.ndarray) -> Rotation:
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-9:
        if c > 0:
            return Rotation.identity()
        raise ValueError("cannot rotate a limb onto its exact opposite direction")
    return Rotation.from_rotvec(axis / s * math.atan2(s, c))


def _side(rv: np.ndarray, side: str) -> np.ndarray:
    side = side.upper()
    if side not in ("L", "R"):
        raise ValueError(f"side must be 'L' or 'R', got {side!r}")
    return rv if side == "L" else mirror_rotvec(rv)


def arm(side: str, direction: Sequence[float], internal: float = 0.0) -> np.ndarray:
    """Shoulder rotation that points the upper arm along ``direction`` = (outward, up,
    forward) in the side frame, then rotates the arm about its own axis by ``internal``
    degrees (internal rotation positive: with the arm hanging down and the elbow bent, the
    forearm swings across the belly; negative = external, e.g. -90 with the arm out to the
    side puts the bent forearm vertical as in waving)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    r = Rotation.from_rotvec(d * D(internal)) * _min_rotation(np.array([1.0, 0.0, 0.0]), d)
    return _side(r.as_rotvec(), side)


def leg(side: str, flex: float = 0.0, abd: float = 0.0, ext_rot: float = 0.0) -> np.ndarray:
    """Hip rotation: external rotation of the thigh about its axis (toes out), then
    abduction (thigh out to the side), then flexion (thigh forward; negative = extension),
    all in degrees."""
    rv = axis_rot(("y", ext_rot), ("z", abd), ("x", -flex))
    return _side(rv, side)


def elbow(side: str, flex: float, pron: float = 0.0) -> np.ndarray:
    """Elbow flexion in degrees (0 straight); ``pron`` twists the forearm about its axis."""
    return _side(np.array([D(pron), -D(flex), 0.0]), side)


def knee(flex: float) -> np.ndarray:
    return np.array([D(flex), 0.0, 0.0])


def ankle(side: str, plantar: float = 0.0, inv: float = 0.0) -> np.ndarray:
    """Plantar flexion (toes down) positive, dorsiflexion negative; inversion (sole inward) positive."""
    return _side(axis_rot(("z", -inv), ("x", plantar)), side)


def trunk(flex: float = 0.0, side_bend: float = 0.0, twist: float = 0.0) -> np.ndarray:
    """Spine / neck / head segment: forward flexion, bend towards the body's left, turn
    towards the body's left (degrees)."""
    return axis_rot(("y", twist), ("z", -side_bend), ("x", flex))


def collar(side: str, elev: float = 0.0, protract: float = 0.0) -> np.ndarray:
    """Clavicle: shoulder shrug (elevation) and protraction (shoulder forward), degrees."""
    return _side(axis_rot(("z", elev), ("y", -protract)), side)


def wrist(side: str, flex: float = 0.0, dev: float = 0.0) -> np.ndarray:
    """Wrist flexion (palm side) and radial deviation, degrees (small)."""
    return _side(axis_rot(("z", -flex), ("y", dev)), side)


# ----------------------------------------------------------------------------- pose container
@dataclass(frozen=True)
class LibraryPose:
    name: str
    description: str
    body_pose: np.ndarray  # [69]
    root: np.ndarray = field(default_factory=lambda: np.zeros(3))  # axis-angle in the body frame
    frontal: bool = False  # reads well from the front (used for subject 0)

    def as_dict(self) -> dict:
        return {"name": self.name, "description": self.description}


def build_pose(spec: Dict[str, np.ndarray]) -> np.ndarray:
    """``body_pose [69]`` from ``{joint name: axis-angle}`` (other joints at rest)."""
    pose = np.zeros((23, 3))
    for name, rv in spec.items():
        if name not in _INDEX:
            raise KeyError(f"unknown body joint {name!r}")
        pose[_INDEX[name]] = np.asarray(rv, dtype=np.float64)
    return pose.reshape(69)


def _spine(flex=0.0, side_bend=0.0, twist=0.0, split=(0.4, 0.3, 0.3)) -> dict:
    return {f"spine{i + 1}": trunk(flex * s, side_bend * s, twist * s) for i, s in enumerate(split)}


def _head(flex=0.0, turn=0.0, tilt=0.0) -> dict:
    return {"neck": trunk(flex * 0.5, tilt * 0.5, turn * 0.5), "head": trunk(flex * 0.5, tilt * 0.5, turn * 0.5)}


def _arms_down(abd=8.0, fwd=0.0, elbow_flex=10.0) -> dict:
    d = (math.sin(D(abd)), -math.cos(D(abd)), math.tan(D(fwd)))
    return {
        "left_shoulder": arm("L", d),
        "right_shoulder": arm("R", d),
        "left_elbow": elbow("L", elbow_flex),
        "right_elbow": elbow("R", elbow_flex),
    }


def _dir(out: float, up: float, fwd: float) -> Tuple[float, float, float]:
    return (out, up, fwd)


_POSES: list[LibraryPose] = []


def _add(name: str, description: str, spec: dict, root=(0.0, 0.0, 0.0), frontal: bool = False) -> None:
    _POSES.append(LibraryPose(name, description, build_pose(spec), np.asarray(root, dtype=np.float64), frontal))


# ----------------------------------------------------------------------------- the library
_add("t_pose", "T-pose: arms straight out to the sides, legs together (SMPL's rest pose)", {}, frontal=True)

_add(
    "a_pose",
    "A-pose: arms 45 degrees below horizontal, legs slightly apart",
    {
        "left_shoulder": arm("L", (1, -1, 0)),
        "right_shoulder": arm("R", (1, -1, 0)),
        "left_hip": leg("L", abd=5),
        "right_hip": leg("R", abd=5),
    },
    frontal=True,
)

_add(
    "stand_relaxed",
    "standing relaxed, arms hanging by the sides, elbows a little bent",
    {
        **_arms_down(abd=9, fwd=3, elbow_flex=12),
        "left_hip": leg("L", abd=3, ext_rot=5),
        "right_hip": leg("R", abd=3, ext_rot=5),
        "left_knee": knee(3),
        "right_knee": knee(3),
        **_head(flex=5),
    },
    frontal=True,
)

_add(
    "stand_contrapposto",
    "standing with weight on the right leg, left knee relaxed, head turned",
    {
        **_arms_down(abd=10, fwd=2, elbow_flex=15),
        "left_hip": leg("L", flex=8, abd=6, ext_rot=10),
        "right_hip": leg("R", abd=-2),
        "left_knee": knee(15),
        "left_ankle": ankle("L", plantar=8),
        **_spine(side_bend=-6),
        **_head(turn=20, tilt=5),
    },
)

_add(
    "walk_left_heel_strike",
    "walking: left heel strikes ahead, right leg pushing off behind, arms swinging",
    {
        "left_hip": leg("L", flex=25),
        "left_knee": knee(5),
        "left_ankle": ankle("L", plantar=-10),
        "right_hip": leg("R", flex=-15),
        "right_knee": knee(20),
        "right_ankle": ankle("R", plantar=20),
        "left_shoulder": arm("L", (0.15, -1, -0.35)),
        "left_elbow": elbow("L", 15),
        "right_shoulder": arm("R", (0.15, -1, 0.4)),
        "right_elbow": elbow("R", 35),
        **_spine(twist=-6),
    },
)

_add(
    "walk_right_midswing",
    "walking: right leg swinging through with the knee bent, left leg in midstance",
    {
        "left_hip": leg("L", flex=-5),
        "left_knee": knee(8),
        "right_hip": leg("R", flex=20),
        "right_knee": knee(55),
        "right_ankle": ankle("R", plantar=5),
        "left_shoulder": arm("L", (0.15, -1, 0.15)),
        "left_elbow": elbow("L", 20),
        "right_shoulder": arm("R", (0.15, -1, -0.1)),
        "right_elbow": elbow("R", 15),
    },
)

_add(
    "run_flight",
    "running, flight phase: left thigh driven forward, right leg trailing behind with the knee bent",
    {
        "left_hip": leg("L", flex=55),
        "left_knee": knee(80),
        "left_ankle": ankle("L", plantar=10),
        "right_hip": leg("R", flex=-25),
        "right_knee": knee(85),
        "right_ankle": ankle("R", plantar=30),
        "left_shoulder": arm("L", (0.2, -1, -0.6), internal=10),
        "left_elbow": elbow("L", 85),
        "right_shoulder": arm("R", (0.2, -1, 0.7), internal=10),
        "right_elbow": elbow("R", 95),
        **_spine(flex=12, twist=8),
    },
)

_add(
    "run_stance",
    "running, stance phase: right foot under the body, left knee swinging through high",
    {
        "right_hip": leg("R", flex=10),
        "right_knee": knee(35),
        "right_ankle": ankle("R", plantar=-10),
        "left_hip": leg("L", flex=15),
        "left_knee": knee(110),
        "left_ankle": ankle("L", plantar=20),
        "left_shoulder": arm("L", (0.2, -1, 0.5), internal=10),
        "left_elbow": elbow("L", 90),
        "right_shoulder": arm("R", (0.2, -1, -0.5), internal=10),
        "right_elbow": elbow("R", 80),
        **_spine(flex=10, twist=-6),
    },
)

_add(
    "sit_chair",
    "sitting on a chair, hands resting on the thighs",
    {
        "left_hip": leg("L", flex=88, abd=8),
        "right_hip": leg("R", flex=88, abd=8),
        "left_knee": knee(88),
        "right_knee": knee(85),
        "left_shoulder": arm("L", (0.2, -1, 0.45), internal=15),
        "right_shoulder": arm("R", (0.2, -1, 0.45), internal=15),
        "left_elbow": elbow("L", 50),
        "right_elbow": elbow("R", 50),
        **_spine(flex=8),
        **_head(flex=5),
    },
    frontal=True,
)

_add(
    "sit_floor",
    "sitting on the floor with the knees drawn up and the arms around them",
    {
        "left_hip": leg("L", flex=105, abd=12, ext_rot=10),
        "right_hip": leg("R", flex=105, abd=12, ext_rot=10),
        "left_knee": knee(125),
        "right_knee": knee(125),
        "left_ankle": ankle("L", plantar=15),
        "right_ankle": ankle("R", plantar=15),
        "left_shoulder": arm("L", (0.2, -0.4, 1), internal=45),
        "right_shoulder": arm("R", (0.2, -0.4, 1), internal=45),
        "left_elbow": elbow("L", 55),
        "right_elbow": elbow("R", 55),
        **_spine(flex=25),
        **_head(flex=-10),
    },
    root=axis_rot(("x", -10)),
)

_add(
    "squat_deep",
    "deep squat, heels down, arms reaching forward for balance",
    {
        "left_hip": leg("L", flex=115, abd=20, ext_rot=15),
        "right_hip": leg("R", flex=115, abd=20, ext_rot=15),
        "left_knee": knee(135),
        "right_knee": knee(135),
        "left_ankle": ankle("L", plantar=-30),
        "right_ankle": ankle("R", plantar=-30),
        "left_shoulder": arm("L", (0.15, -0.1, 1)),
        "right_shoulder": arm("R", (0.15, -0.1, 1)),
        "left_elbow": elbow("L", 10),
        "right_elbow": elbow("R", 10),
        **_spine(flex=35),
        **_head(flex=-20),
    },
)

_add(
    "squat_half",
    "half squat with the hands clasped in front of the chest",
    {
        "left_hip": leg("L", flex=70, abd=12, ext_rot=10),
        "right_hip": leg("R", flex=70, abd=12, ext_rot=10),
        "left_knee": knee(80),
        "right_knee": knee(80),
        "left_ankle": ankle("L", plantar=-15),
        "right_ankle": ankle("R", plantar=-15),
        "left_shoulder": arm("L", (0.4, -0.8, 0.6), internal=55),
        "right_shoulder": arm("R", (0.4, -0.8, 0.6), internal=55),
        "left_elbow": elbow("L", 110),
        "right_elbow": elbow("R", 110),
        **_spine(flex=25),
        **_head(flex=-15),
    },
)

_add(
    "kneel_one",
    "kneeling on the right knee, left foot planted in front, hands on the left knee",
    {
        "left_hip": leg("L", flex=85, abd=5),
        "left_knee": knee(90),
        "right_hip": leg("R", flex=-5),
        "right_knee": knee(95),
        "right_ankle": ankle("R", plantar=-20),
        "left_shoulder": arm("L", (0.1, -1, 0.5), internal=20),
        "left_elbow": elbow("L", 30),
        "right_shoulder": arm("R", (0.1, -1, 0.6), internal=25),
        "right_elbow": elbow("R", 40),
        **_spine(flex=10),
    },
)

_add(
    "kneel_both",
    "kneeling upright on both knees, arms by the sides",
    {
        "left_hip": leg("L", flex=5, abd=4),
        "right_hip": leg("R", flex=5, abd=4),
        "left_knee": knee(100),
        "right_knee": knee(100),
        "left_ankle": ankle("L", plantar=40),
        "right_ankle": ankle("R", plantar=40),
        **_arms_down(abd=12, fwd=10, elbow_flex=20),
    },
    frontal=True,
)

_add(
    "lunge_forward",
    "forward lunge: left foot ahead with the knee over the ankle, right knee near the floor",
    {
        "left_hip": leg("L", flex=80),
        "left_knee": knee(90),
        "left_ankle": ankle("L", plantar=-5),
        "right_hip": leg("R", flex=-30),
        "right_knee": knee(95),
        "right_ankle": ankle("R", plantar=-25),
        "left_shoulder": arm("L", (0.3, -1, 0.1)),
        "right_shoulder": arm("R", (0.3, -1, 0.1)),
        "left_elbow": elbow("L", 15),
        "right_elbow": elbow("R", 15),
    },
)

_add(
    "lunge_side",
    "side lunge to the left with the right leg straight, hands together in front",
    {
        "left_hip": leg("L", flex=60, abd=40, ext_rot=20),
        "left_knee": knee(85),
        "right_hip": leg("R", abd=35),
        "right_ankle": ankle("R", inv=-10),
        "left_shoulder": arm("L", (0.3, -0.6, 1), internal=45),
        "right_shoulder": arm("R", (0.3, -0.6, 1), internal=45),
        "left_elbow": elbow("L", 60),
        "right_elbow": elbow("R", 60),
        **_spine(flex=20, side_bend=8),
    },
)

_add(
    "reach_up_both",
    "reaching up with both arms overhead, on the toes",
    {
        "left_shoulder": arm("L", (0.25, 1, 0.1)),
        "right_shoulder": arm("R", (0.25, 1, 0.1)),
        "left_elbow": elbow("L", 5),
        "right_elbow": elbow("R", 5),
        "left_collar": collar("L", elev=15),
        "right_collar": collar("R", elev=15),
        "left_ankle": ankle("L", plantar=25),
        "right_ankle": ankle("R", plantar=25),
        **_spine(flex=-8),
        **_head(flex=-20),
    },
    frontal=True,
)

_add(
    "reach_up_one",
    "reaching up high to a shelf with the right hand, left arm down",
    {
        "right_shoulder": arm("R", (0.15, 1, 0.25)),
        "right_elbow": elbow("R", 10),
        "right_collar": collar("R", elev=20),
        "left_shoulder": arm("L", (0.2, -1, 0.1)),
        "left_elbow": elbow("L", 20),
        "right_ankle": ankle("R", plantar=20),
        "left_ankle": ankle("L", plantar=20),
        **_spine(side_bend=6),
        **_head(flex=-15),
    },
)

_add(
    "wave_right",
    "waving with the right hand raised beside the head, left arm relaxed",
    {
        "right_shoulder": arm("R", (1, 0.35, 0.15), internal=-75),
        "right_elbow": elbow("R", 95),
        "left_shoulder": arm("L", (0.15, -1, 0.05)),
        "left_elbow": elbow("L", 15),
        "left_hip": leg("L", abd=4),
        "right_hip": leg("R", abd=4),
        **_head(tilt=-5),
    },
    frontal=True,
)

_add(
    "wave_both",
    "waving both hands above the shoulders (greeting)",
    {
        "right_shoulder": arm("R", (1, 0.2, 0.2), internal=-80),
        "right_elbow": elbow("R", 80),
        "left_shoulder": arm("L", (1, 0.2, 0.2), internal=-80),
        "left_elbow": elbow("L", 80),
        "left_hip": leg("L", abd=6),
        "right_hip": leg("R", abd=6),
    },
    frontal=True,
)

_add(
    "point_forward",
    "pointing straight ahead with the left arm, right arm down",
    {
        "left_shoulder": arm("L", (0.25, 0.05, 1)),
        "left_elbow": elbow("L", 5),
        "left_collar": collar("L", protract=10),
        "right_shoulder": arm("R", (0.15, -1, 0.05)),
        "right_elbow": elbow("R", 15),
        **_spine(twist=-10),
        **_head(turn=10),
    },
)

_add(
    "point_side",
    "pointing to the side with the right arm, head turned to look",
    {
        "right_shoulder": arm("R", (1, 0.1, 0.3)),
        "right_elbow": elbow("R", 5),
        "left_shoulder": arm("L", (0.2, -1, 0.2)),
        "left_elbow": elbow("L", 20),
        **_head(turn=-45),
    },
)

_add(
    "arms_crossed",
    "standing with the arms crossed over the chest",
    {
        "left_shoulder": arm("L", (0.25, -1, 0.35), internal=75),
        "right_shoulder": arm("R", (0.25, -1, 0.35), internal=75),
        "left_elbow": elbow("L", 110),
        "right_elbow": elbow("R", 110),
        "left_hip": leg("L", abd=5),
        "right_hip": leg("R", abd=5),
    },
    frontal=True,
)

_add(
    "hands_on_hips",
    "standing with the hands on the hips, elbows out",
    {
        "left_shoulder": arm("L", (0.75, -1, -0.1), internal=30),
        "right_shoulder": arm("R", (0.75, -1, -0.1), internal=30),
        "left_elbow": elbow("L", 95),
        "right_elbow": elbow("R", 95),
        "left_wrist": wrist("L", dev=-20),
        "right_wrist": wrist("R", dev=-20),
        "left_hip": leg("L", abd=8),
        "right_hip": leg("R", abd=8),
    },
    frontal=True,
)

_add(
    "bend_forward",
    "bending forward from the hips with straight legs, hands hanging towards the shins",
    {
        "left_hip": leg("L", flex=50, abd=4),
        "right_hip": leg("R", flex=50, abd=4),
        "left_ankle": ankle("L", plantar=5),
        "right_ankle": ankle("R", plantar=5),
        **_spine(flex=35),
        **_head(flex=-10),
        "left_shoulder": arm("L", (0.15, -0.35, 1)),
        "right_shoulder": arm("R", (0.15, -0.35, 1)),
        "left_elbow": elbow("L", 10),
        "right_elbow": elbow("R", 10),
    },
    root=axis_rot(("x", 50)),
)

_add(
    "pick_up",
    "bending the knees and the back to pick something up from the floor with the right hand",
    {
        "left_hip": leg("L", flex=85, abd=10),
        "right_hip": leg("R", flex=70, abd=10),
        "left_knee": knee(90),
        "right_knee": knee(70),
        "left_ankle": ankle("L", plantar=-20),
        "right_ankle": ankle("R", plantar=-15),
        **_spine(flex=30, twist=-8),
        **_head(flex=-10),
        "right_shoulder": arm("R", (0.1, -0.6, 1)),
        "right_elbow": elbow("R", 10),
        "left_shoulder": arm("L", (0.2, -1, 0.6), internal=20),
        "left_elbow": elbow("L", 45),
    },
    root=axis_rot(("x", 25)),
)

_add(
    "throw_windup",
    "throwing wind-up: right arm cocked back with the elbow bent, left arm pointing forward",
    {
        "right_shoulder": arm("R", (1, 0.15, -0.35), internal=-85),
        "right_elbow": elbow("R", 90),
        "left_shoulder": arm("L", (0.6, 0.1, 1)),
        "left_elbow": elbow("L", 15),
        "left_hip": leg("L", flex=30, abd=10),
        "left_knee": knee(15),
        "right_hip": leg("R", flex=-10, abd=8),
        "right_knee": knee(20),
        **_spine(twist=-30, side_bend=-8),
        **_head(turn=25),
    },
)

_add(
    "throw_release",
    "throwing follow-through: right arm swept forward and across, weight on the front leg",
    {
        "right_shoulder": arm("R", (0.1, -0.3, 1), internal=40),
        "right_elbow": elbow("R", 25),
        "left_shoulder": arm("L", (0.6, -1, -0.4)),
        "left_elbow": elbow("L", 45),
        "left_hip": leg("L", flex=35),
        "left_knee": knee(30),
        "right_hip": leg("R", flex=-20),
        "right_knee": knee(30),
        "right_ankle": ankle("R", plantar=30),
        **_spine(flex=20, twist=25),
    },
)

_add(
    "kick_front",
    "front kick with the right leg raised high, arms up for balance",
    {
        "right_hip": leg("R", flex=80),
        "right_knee": knee(20),
        "right_ankle": ankle("R", plantar=20),
        "left_knee": knee(10),
        "left_hip": leg("L", flex=5),
        "left_shoulder": arm("L", (1, -0.4, 0.3)),
        "left_elbow": elbow("L", 60),
        "right_shoulder": arm("R", (0.8, -0.6, -0.2)),
        "right_elbow": elbow("R", 40),
        **_spine(flex=-10),
    },
)

_add(
    "kick_side",
    "side kick with the left leg, torso leaning away",
    {
        "left_hip": leg("L", flex=15, abd=60, ext_rot=-15),
        "left_knee": knee(15),
        "right_hip": leg("R", abd=10),
        "right_knee": knee(15),
        "left_shoulder": arm("L", (0.6, -1, 0.5), internal=30),
        "left_elbow": elbow("L", 90),
        "right_shoulder": arm("R", (0.5, -1, 0.6), internal=30),
        "right_elbow": elbow("R", 100),
        **_spine(side_bend=-20),
    },
)

_add(
    "jump_tuck",
    "tuck jump: knees pulled up, arms swung forward",
    {
        "left_hip": leg("L", flex=95, abd=8),
        "right_hip": leg("R", flex=95, abd=8),
        "left_knee": knee(110),
        "right_knee": knee(110),
        "left_ankle": ankle("L", plantar=30),
        "right_ankle": ankle("R", plantar=30),
        "left_shoulder": arm("L", (0.25, 0.3, 1)),
        "right_shoulder": arm("R", (0.25, 0.3, 1)),
        "left_elbow": elbow("L", 30),
        "right_elbow": elbow("R", 30),
        **_spine(flex=15),
    },
)

_add(
    "star_jump",
    "star jump: arms and legs spread wide",
    {
        "left_hip": leg("L", abd=30),
        "right_hip": leg("R", abd=30),
        "left_knee": knee(8),
        "right_knee": knee(8),
        "left_ankle": ankle("L", plantar=35),
        "right_ankle": ankle("R", plantar=35),
        "left_shoulder": arm("L", (1, 0.8, 0.05)),
        "right_shoulder": arm("R", (1, 0.8, 0.05)),
        "left_elbow": elbow("L", 5),
        "right_elbow": elbow("R", 5),
        **_head(flex=-10),
    },
    frontal=True,
)

_add(
    "lie_reclined",
    "reclining on the back propped on the elbows, legs stretched out, one knee up",
    {
        "left_hip": leg("L", flex=55),
        "right_hip": leg("R", flex=85),
        "right_knee": knee(95),
        "left_shoulder": arm("L", (0.35, -1, -0.5), internal=-10),
        "right_shoulder": arm("R", (0.35, -1, -0.5), internal=-10),
        "left_elbow": elbow("L", 70),
        "right_elbow": elbow("R", 70),
        **_spine(flex=15),
        **_head(flex=30),
    },
    root=axis_rot(("x", -60)),
)

_add(
    "lie_side",
    "lying on the right side, head on the right arm, knees bent",
    {
        "left_hip": leg("L", flex=50),
        "right_hip": leg("R", flex=40),
        "left_knee": knee(70),
        "right_knee": knee(60),
        "right_shoulder": arm("R", (0.2, 1, 0.3)),
        "right_elbow": elbow("R", 100),
        "left_shoulder": arm("L", (0.1, -1, 0.4)),
        "left_elbow": elbow("L", 30),
        **_spine(flex=10),
        **_head(tilt=15),
    },
    root=axis_rot(("z", -85)),
)

_add(
    "phone_call",
    "standing with the right hand at the ear (phone call), left hand in front",
    {
        "right_shoulder": arm("R", (0.3, -0.7, 0.6), internal=30),
        "right_elbow": elbow("R", 140),
        "left_shoulder": arm("L", (0.2, -1, 0.2), internal=30),
        "left_elbow": elbow("L", 80),
        "left_hip": leg("L", flex=5, abd=3),
        "left_knee": knee(10),
        **_head(tilt=-10, flex=5),
    },
)

_add(
    "boxing_guard",
    "boxing guard: fists up in front of the face, knees bent, left foot forward",
    {
        "left_shoulder": arm("L", (0.35, -0.8, 0.6), internal=35),
        "left_elbow": elbow("L", 120),
        "right_shoulder": arm("R", (0.35, -0.9, 0.4), internal=40),
        "right_elbow": elbow("R", 135),
        "left_hip": leg("L", flex=25, abd=8),
        "left_knee": knee(25),
        "right_hip": leg("R", flex=-10, abd=10),
        "right_knee": knee(25),
        "right_ankle": ankle("R", plantar=15),
        **_spine(flex=12, twist=-15),
        **_head(flex=10),
    },
)

_add(
    "side_stretch",
    "standing side stretch: left arm arched overhead, torso bent to the right",
    {
        "left_shoulder": arm("L", (0.1, 1, 0.05)),
        "left_elbow": elbow("L", 20),
        "right_shoulder": arm("R", (0.5, -1, 0.2), internal=20),
        "right_elbow": elbow("R", 60),
        "left_hip": leg("L", abd=10),
        "right_hip": leg("R", abd=10),
        **_spine(side_bend=-30),
        **_head(tilt=-10),
    },
    frontal=True,
)

_add(
    "arabesque",
    "balancing on the left leg with the right leg extended behind, arms out",
    {
        "right_hip": leg("R", flex=-45, ext_rot=10),
        "right_knee": knee(5),
        "right_ankle": ankle("R", plantar=40),
        "left_hip": leg("L", flex=40),
        "left_knee": knee(5),
        "left_shoulder": arm("L", (0.3, 0.3, 1)),
        "right_shoulder": arm("R", (1, 0.1, -0.2)),
        "left_elbow": elbow("L", 5),
        "right_elbow": elbow("R", 5),
        **_spine(flex=30),
        **_head(flex=-30),
    },
)

_add(
    "climb_step",
    "stepping up: left foot raised onto a high step, right hand reaching forward",
    {
        "left_hip": leg("L", flex=70),
        "left_knee": knee(95),
        "left_ankle": ankle("L", plantar=-10),
        "right_knee": knee(5),
        "right_ankle": ankle("R", plantar=15),
        "right_shoulder": arm("R", (0.2, 0.2, 1)),
        "right_elbow": elbow("R", 25),
        "left_shoulder": arm("L", (0.2, -1, -0.3)),
        "left_elbow": elbow("L", 30),
        **_spine(flex=15),
    },
)


#: ``{name: LibraryPose}`` in authoring order.
POSE_LIBRARY: Dict[str, LibraryPose] = {p.name: p for p in _POSES}
assert len(POSE_LIBRARY) == len(_POSES), "duplicate pose names"
#: Poses that read clearly from the front (used for a dataset's subject 0).
FRONTAL_POSES = tuple(p.name for p in _POSES if p.frontal)


def pose_names() -> Tuple[str, ...]:
    return tuple(POSE_LIBRARY)


def get_pose(name: str) -> LibraryPose:
    try:
        return POSE_LIBRARY[name]
    except KeyError:
        raise KeyError(f"unknown pose {name!r}; the library has: {', '.join(POSE_LIBRARY)}") from None


def blend_poses(a, b, w: float) -> np.ndarray:
    """Per-joint geodesic interpolation of axis-angle rows (``[..., 3]`` or flat ``[69]``):
    ``a`` at ``w = 0``, ``b`` at ``w = 1``."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    ra, rb = Rotation.from_rotvec(a.reshape(-1, 3)), Rotation.from_rotvec(b.reshape(-1, 3))
    return (ra * Rotation.from_rotvec((ra.inv() * rb).as_rotvec() * w)).as_rotvec().reshape(a.shape)


def mirror_pose(body_pose) -> np.ndarray:
    """The left-right mirror image of a ``body_pose [69]`` (swap sides, mirror every rotation)."""
    pose = np.asarray(body_pose, dtype=np.float64).reshape(23, 3)
    out = np.empty_like(pose)
    for i, name in enumerate(BODY_JOINTS):
        if name.startswith("left_"):
            j = _INDEX["right_" + name[5:]]
        elif name.startswith("right_"):
            j = _INDEX["left_" + name[6:]]
        else:
            j = i
        out[j] = mirror_rotvec(pose[i])
    return out.reshape(69)
