"""Keypoint layouts as data: the names of each layout (OpenPose BODY_25, COCO-17, BlazePose-33,
OpenPose whole body), the whole-body layout's parts, and each keypoint's source on a body model
(:func:`keypoint_sources`, :func:`model_keypoints`): a model joint (the skeleton's joint centres, as
SMPLify and SMPLify-X match them) or a surface landmark (a vertex-weight row of the model: nose,
eyes, ears, toes and heels, fingertips, the face's 68 points, which have no joint).

Whole body (OpenPose's BODY_25 + 2 x 21 hand + 70 face points) on an SMPL-X-layout model
(:func:`wholebody_sources`):

* hands (OpenPose order: wrist, then thumb, index, middle, ring, pinky, four points each from the base to
  the tip): the wrist joint, the finger joints (``<side>_<finger>1..3``; the thumb's first is its CMC
  joint, as SMPL-X and SMPLify-X take it) and a fingertip surface landmark (``<side>_<finger>_tip``);
* face: the 68-point layout from :meth:`~silfit.body.smplx.SMPLXModel.face_landmarks` (landmark rows
  ``face_00`` .. ``face_67``, or the official file's embedding with its dynamic contour), and the two
  pupils (68 = right, 69 = left) at the eye joints (eyeball centres);
* body: BODY_25.

Readers and writers of keypoint files are in :mod:`silfit.io.keypoints` (body) and
:mod:`silfit.io.wholebody` (whole body).
"""

from __future__ import annotations

import torch

__all__ = [
    "BLAZEPOSE33_NAMES",
    "BODY25_NAMES",
    "COCO17_NAMES",
    "FACE70_NAMES",
    "FINGERS",
    "HAND21_NAMES",
    "DEFAULT_DEPTH_TOLERANCE",
    "KEYPOINT_DEPTH_TOLERANCE",
    "LAYOUTS",
    "PART_FIELDS",
    "WHOLEBODY_NAMES",
    "WHOLEBODY_PARTS",
    "hand_names",
    "keypoint_sources",
    "model_keypoints",
    "part_slices",
    "wholebody_keypoints",
    "wholebody_sources",
]

#: How far (metres) behind the nearest surface along its camera ray a keypoint may lie and still count
#: as visible (the synthetic data's visibility, :mod:`silfit.synth.generate`; the occlusion cue,
#: :mod:`silfit.fitting.occlusion`): surface landmarks 3 cm; joint centres their measured depth below the skin
#: (the larger of front and back views, over betas -2..2 on the open body model: neck 9.5,
#: shoulders 7.9, elbows 5.9, wrists 3.4, pelvis 14.4, hips 12.8, knees 7.0, ankles 6.0 cm)
#: plus 1.5-2.5 cm.
KEYPOINT_DEPTH_TOLERANCE = {
    "nose": 0.03,
    "neck": 0.11,
    "right_shoulder": 0.10,
    "right_elbow": 0.075,
    "right_wrist": 0.05,
    "left_shoulder": 0.10,
    "left_elbow": 0.075,
    "left_wrist": 0.05,
    "mid_hip": 0.17,
    "right_hip": 0.15,
    "right_knee": 0.09,
    "right_ankle": 0.075,
    "left_hip": 0.15,
    "left_knee": 0.09,
    "left_ankle": 0.075,
    "right_eye": 0.03,
    "left_eye": 0.03,
    "right_ear": 0.03,
    "left_ear": 0.03,
    "left_big_toe": 0.03,
    "left_small_toe": 0.03,
    "left_heel": 0.03,
    "right_big_toe": 0.03,
    "right_small_toe": 0.03,
    "right_heel": 0.03,
}
#: the depth tolerance (metres) of a keypoint not in :data:`KEYPOINT_DEPTH_TOLERANCE`
DEFAULT_DEPTH_TOLERANCE = 0.05

BODY25_NAMES = (
    "nose",
    "neck",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "mid_hip",
    "right_hip",
    "right_knee",
    "right_ankle",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_eye",
    "left_eye",
    "right_ear",
    "left_ear",
    "left_big_toe",
    "left_small_toe",
    "left_heel",
    "right_big_toe",
    "right_small_toe",
    "right_heel",
)
COCO17_NAMES = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)
#: MediaPipe BlazePose's 33 landmarks, as :mod:`silfit.detect` finds them.
BLAZEPOSE33_NAMES = (
    "nose",
    "left_eye_inner",
    "left_eye",
    "left_eye_outer",
    "right_eye_inner",
    "right_eye",
    "right_eye_outer",
    "left_ear",
    "right_ear",
    "mouth_left",
    "mouth_right",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_pinky",
    "right_pinky",
    "left_index",
    "right_index",
    "left_thumb",
    "right_thumb",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
)
_HAND_POINTS = ("wrist",) + tuple(
    f"{f}{k}" for f in ("thumb", "index", "middle", "ring", "pinky") for k in (1, 2, 3, 4)
)
#: OpenPose's whole-body layout as one list (137 points, :mod:`silfit.io.wholebody`): BODY_25, the left and
#: right hand (21 each, ``left_hand_wrist``, ``left_hand_thumb1`` ...), the face (``face_00`` .. ``face_67``,
#: ``right_pupil``, ``left_pupil``); sources on an SMPL-X-layout model only.
WHOLEBODY_NAMES = (
    BODY25_NAMES
    + tuple(f"left_hand_{n}" for n in _HAND_POINTS)
    + tuple(f"right_hand_{n}" for n in _HAND_POINTS)
    + tuple(f"face_{k:02d}" for k in range(68))
    + ("right_pupil", "left_pupil")
)
LAYOUTS = {
    "body25": BODY25_NAMES,
    "coco17": COCO17_NAMES,
    "blazepose33": BLAZEPOSE33_NAMES,
    "wholebody": WHOLEBODY_NAMES,
}

#: Keypoint name -> SMPL joint name, where a joint is the source.
_JOINT_SOURCES = {
    "neck": "neck",
    "mid_hip": "pelvis",
    "left_shoulder": "left_shoulder",
    "right_shoulder": "right_shoulder",
    "left_elbow": "left_elbow",
    "right_elbow": "right_elbow",
    "left_wrist": "left_wrist",
    "right_wrist": "right_wrist",
    "left_hip": "left_hip",
    "right_hip": "right_hip",
    "left_knee": "left_knee",
    "right_knee": "right_knee",
    "left_ankle": "left_ankle",
    "right_ankle": "right_ankle",
    # BlazePose's hand points: the model has no finger landmarks; SMPL's hand joint (at the
    # knuckles) is the nearest point to all three.
    "left_pinky": "left_hand",
    "left_index": "left_hand",
    "left_thumb": "left_hand",
    "right_pinky": "right_hand",
    "right_index": "right_hand",
    "right_thumb": "right_hand",
}
#: Keypoint name -> the model landmark it is fitted to, where the model has no landmark of
#: that name (BlazePose's points): the nearest one (eye corners -> the eye, mouth corners
#: -> the nose, a few cm above them; the foot's tip -> the big toe).
_LANDMARK_ALIASES = {
    "left_eye_inner": "left_eye",
    "left_eye_outer": "left_eye",
    "right_eye_inner": "right_eye",
    "right_eye_outer": "right_eye",
    "mouth_left": "nose",
    "mouth_right": "nose",
    "left_foot_index": "left_big_toe",
    "right_foot_index": "right_big_toe",
}


def keypoint_sources(model, layout: str = "body25", prefer_landmarks: bool = False) -> list[tuple[str, int]]:
    """For each keypoint of ``layout``: ``("joint", j)`` or ``("landmark", k)`` on ``model``.

    With ``prefer_landmarks`` the surface landmarks (where people annotate shoulders,
    hips, ... on the skin) are used wherever the model has them, else joint centres.
    The ``wholebody`` layout (SMPL-X-layout models) also has ``("none", 0)``: a point the model
    cannot place statically (an official SMPL-X file's dynamic jaw contour), fitted with weight 0.
    """
    names = layout_names(layout)
    if layout.lower() == "wholebody":
        return wholebody_sources(model, prefer_landmarks)
    joint_index = {n: i for i, n in enumerate(model.joint_names)}
    landmark_index = {n: i for i, n in enumerate(model.landmark_names)}
    sources = []
    for name in names:
        name = name if name in landmark_index else _LANDMARK_ALIASES.get(name, name)
        if prefer_landmarks and name in landmark_index:
            sources.append(("landmark", landmark_index[name]))
        elif name in _JOINT_SOURCES and _JOINT_SOURCES[name] in joint_index:
            sources.append(("joint", joint_index[_JOINT_SOURCES[name]]))
        elif name in landmark_index:
            sources.append(("landmark", landmark_index[name]))
        else:
            raise ValueError(f"{model.source}: the model has no joint or landmark for keypoint '{name}' ({layout})")
    return sources


def model_keypoints(model, output, layout: str = "body25", prefer_landmarks: bool = False) -> torch.Tensor:
    """3D keypoints ``[B, K, 3]`` of a body-model output in the order of ``layout``."""
    if layout.lower() == "wholebody":
        wb = wholebody_keypoints(model, output, prefer_landmarks)
        return torch.cat([wb[p] for p in WHOLEBODY_PARTS], dim=1)
    sources = keypoint_sources(model, layout, prefer_landmarks)
    J = output.joints.shape[1]
    stacked = output.joints
    if any(kind == "landmark" for kind, _ in sources):
        stacked = torch.cat([output.joints, model.landmarks(output.vertices)], dim=1)
    index = torch.as_tensor([i if kind == "joint" else J + i for kind, i in sources], device=stacked.device)
    return stacked[:, index]


def layout_names(layout: str) -> tuple:
    try:
        return LAYOUTS[layout.lower()]
    except KeyError:
        raise ValueError(f"unknown keypoint layout {layout!r} (expected one of {', '.join(LAYOUTS)})") from None


FINGERS = ("thumb", "index", "middle", "ring", "pinky")
HAND21_NAMES = ("wrist",) + tuple(f"{f}{k}" for f in FINGERS for k in (1, 2, 3, 4))
FACE70_NAMES = tuple(f"face_{k:02d}" for k in range(68)) + ("right_pupil", "left_pupil")
#: OpenPose JSON field -> (part name, point count)
PART_FIELDS = {
    "pose_keypoints_2d": ("body", len(BODY25_NAMES)),
    "hand_left_keypoints_2d": ("hand_left", len(HAND21_NAMES)),
    "hand_right_keypoints_2d": ("hand_right", len(HAND21_NAMES)),
    "face_keypoints_2d": ("face", len(FACE70_NAMES)),
}


#: The parts in the order of the ``wholebody`` keypoint layout (:data:`WHOLEBODY_NAMES`).
WHOLEBODY_PARTS = ("body", "hand_left", "hand_right", "face")
assert WHOLEBODY_NAMES[25:46] == tuple(f"left_hand_{n}" for n in HAND21_NAMES) and WHOLEBODY_NAMES[67:] == FACE70_NAMES


def part_slices() -> dict:
    """``{part: slice}`` of each part's points in the ``wholebody`` layout."""
    out, start = {}, 0
    for part, count in PART_FIELDS.values():
        out[part] = slice(start, start + count)
        start += count
    return out


def wholebody_sources(model, prefer_landmarks: bool = False) -> list:
    """``(kind, index)`` on ``model`` for each point of the ``wholebody`` layout (see
    :func:`keypoint_sources`): body as BODY_25, hands (wrist and finger joints, fingertip
    landmarks), face (landmark rows ``face_NN``; ``("none", 0)`` for the jaw contour of a model whose
    contour is dynamic) and the pupils (eye joints)."""
    if getattr(model, "kind", "smpl") != "smplx":
        raise ValueError(f"{model.source}: whole-body keypoints need an SMPL-X-layout model (this one is {model.kind})")
    joint = {n: i for i, n in enumerate(model.joint_names)}
    lmk = {n: i for i, n in enumerate(model.landmark_names)}
    out = list(keypoint_sources(model, "body25", prefer_landmarks))
    for side in ("left", "right"):
        out.append(("joint", joint[f"{side}_wrist"]))
        for f in FINGERS:
            for k in (1, 2, 3):
                name = f"{side}_{f}{k}"
                if name not in joint:
                    raise ValueError(f"{model.source}: the model has no joint for hand keypoint {name}")
                out.append(("joint", joint[name]))
            tip = f"{side}_{f}_tip"
            if tip not in lmk:
                raise ValueError(f"{model.source}: the model has no landmark for hand keypoint {tip}")
            out.append(("landmark", lmk[tip]))
    for k in range(68):
        name = f"face_{k:02d}"
        if name in lmk:
            out.append(("landmark", lmk[name]))
        elif k < 17 and getattr(model, "dynamic_lmk_faces_idx", None) is not None:
            out.append(("none", 0))
        else:
            raise ValueError(f"{model.source}: this model has no face landmark {name}")
    out += [("joint", joint["right_eye_smplhf"]), ("joint", joint["left_eye_smplhf"])]
    return out


def hand_names(side: str) -> tuple:
    return tuple(f"{side}_{n}" for n in HAND21_NAMES)


def _hand_points(model, output, side: str) -> torch.Tensor:
    joint = {n: i for i, n in enumerate(model.joint_names)}
    lmk = {n: i for i, n in enumerate(model.landmark_names)}
    tips = [f"{side}_{f}_tip" for f in FINGERS]
    missing = [n for n in tips if n not in lmk] + [
        f"{side}_{f}{k}" for f in FINGERS for k in (1, 2, 3) if f"{side}_{f}{k}" not in joint
    ]
    if missing:
        raise ValueError(
            f"{model.source}: the model has no joint or landmark for hand keypoint(s) {', '.join(missing[:4])}"
        )
    landmarks = model.landmarks(output.vertices)
    cols = [output.joints[:, joint[f"{side}_wrist"]]]
    for f in FINGERS:
        cols += [output.joints[:, joint[f"{side}_{f}{k}"]] for k in (1, 2, 3)]
        cols.append(landmarks[:, lmk[f"{side}_{f}_tip"]])
    return torch.stack(cols, dim=1)


def wholebody_keypoints(model, output, prefer_landmarks: bool = False) -> dict:
    """3D whole-body keypoints of a whole-body model output: ``{"body": [B, 25, 3], "hand_left":
    [B, 21, 3], "hand_right": [B, 21, 3], "face": [B, 70, 3]}`` in OpenPose's orders."""
    if getattr(model, "kind", "smpl") != "smplx":
        raise ValueError(f"{model.source}: whole-body keypoints need an SMPL-X-layout model (this one is {model.kind})")
    joint = {n: i for i, n in enumerate(model.joint_names)}
    face = model.face_landmarks(output)
    pupils = output.joints[:, [joint["right_eye_smplhf"], joint["left_eye_smplhf"]]]
    return {
        "body": model_keypoints(model, output, "body25", prefer_landmarks),
        "hand_left": _hand_points(model, output, "left"),
        "hand_right": _hand_points(model, output, "right"),
        "face": torch.cat([face, pupils], dim=1),
    }
