#!/usr/bin/env python
"""Contact sheet of the open whole-body model (``docs/open_smplx_sheet.png``): the left hand in each
library pose seen from the back (with its 21 keypoints) and from the palm, expressions and jaw opening, the face and hand keypoints, and (with ``--reference``, the exporter's
posed meshes) our skinning next to anny's own posing.

    PYTHONPATH=. .venv/bin/python tools/open_smplx_sheet.py --reference /tmp/open_smplx_sheet.npz
"""

from __future__ import annotations

import argparse
from pathlib import Path

import silfit  # noqa: F401  (first: the CPU kernels are pinned before numpy and torch load, silfit.kernels)
import numpy as np
import torch
from PIL import Image, ImageDraw

from silfit.render.offscreen import render_mesh
from silfit.body import load_body_model
from silfit.camera import Camera, project_points
from silfit.synth.hands import HAND_LIBRARY, hand_axes, hand_pose_to_axis_angle
from silfit.io.wholebody import wholebody_keypoints

TILE = 220
TOP = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # camera axes (rows) in body axes: looking down
FRONT = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # looking at the face
BELOW = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # looking up at the palm


def view(points: np.ndarray, R: np.ndarray, centre: np.ndarray, distance: float) -> np.ndarray:
    return (points - centre) @ R.T + np.array([0.0, 0.0, distance])


def tile(vertices, faces, R, centre, distance, label, points=None, colour=(0.8, 0.65, 0.55)):
    cam = Camera.from_image_size(TILE, TILE, focal=TILE * 2.2)
    v = view(vertices, R, centre, distance)
    img = render_mesh(v.astype(np.float32), faces, cam, color=colour)
    im = Image.fromarray(np.where(img.mask[..., None], img.color, 255).astype(np.uint8))
    d = ImageDraw.Draw(im)
    if points is not None:
        uv = project_points(torch.as_tensor(view(points, R, centre, distance)), cam).numpy()
        for u, w in uv:
            d.ellipse([u - 1.5, w - 1.5, u + 1.5, w + 1.5], fill=(220, 20, 20))
    d.text((4, 4), label, fill=(0, 0, 0))
    return im


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="docs/open_smplx_sheet.png")
    ap.add_argument("--reference", default=None, help="the exporter's posed meshes (ours vs anny)")
    args = ap.parse_args(argv)
    m = load_body_model(kind="smplx", dtype=torch.float64)
    faces = m.faces.numpy()
    rest = m(**m.zero_params(1))
    J = rest.joints[0].numpy()
    names = list(m.joint_names)
    axes = hand_axes(J, names, "left")
    rows = []

    hand_c = J[names.index("left_middle1")] + np.array([0.0, 0.0, 0.0])
    row, palms = [], []
    for pose in HAND_LIBRARY.values():
        hp = hand_pose_to_axis_angle(pose.flex, pose.spread, axes)
        out = m(left_hand_pose=torch.as_tensor(hp)[None])
        kp = wholebody_keypoints(m, out)["hand_left"][0].numpy()
        row.append(tile(out.vertices[0].numpy(), faces, TOP, hand_c, 0.55, f"{pose.name} (back, 21 kps)", kp))
        palms.append(tile(out.vertices[0].numpy(), faces, BELOW, hand_c, 0.45, f"{pose.name} (palm)"))
    rows += [row, palms]

    head_c = J[names.index("jaw")] + np.array([0.0, 0.01, 0.0])
    row = []
    exprs = [("neutral + 70 face kps", {}), ("jaw open 20 deg", {"jaw_pose": [[0.35, 0, 0]]})]
    for k in range(3):
        for s in (2.0, -2.0):
            e = np.zeros((1, m.num_expression))
            e[0, k] = s
            exprs.append((f"expression[{k}] = {s:+.0f}", {"expression": e}))
    for label, p in exprs[:8]:
        out = m(**{k: torch.as_tensor(np.asarray(v, dtype=np.float64)) for k, v in p.items()})
        kp = wholebody_keypoints(m, out)["face"][0].numpy()
        row.append(tile(out.vertices[0].numpy(), faces, FRONT, head_c, 0.5, label, kp))
    rows.append(row)

    if args.reference:
        ref = np.load(args.reference)
        row = []
        for key in ref.files:
            if key == "faces":
                continue
            ours, theirs = ref[key]
            is_jaw = key.startswith("jaw")
            R, c, d = (FRONT, head_c, 0.5) if is_jaw else (TOP, hand_c, 0.55)
            if key.startswith("both"):
                R, c, d = FRONT, hand_c, 0.55
            row.append(tile(ours, faces, R, c, d, f"ours: {key[:22]}"))
            row.append(tile(theirs, faces, R, c, d, "anny", colour=(0.55, 0.65, 0.8)))
        rows.append(row)

    width = max(len(r) for r in rows) * TILE
    sheet = Image.new("RGB", (width, len(rows) * TILE), (255, 255, 255))
    for i, r in enumerate(rows):
        for k, im in enumerate(r):
            sheet.paste(im, (k * TILE, i * TILE))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(args.out, optimize=True)
    print(f"wrote {args.out} ({sheet.size[0]}x{sheet.size[1]})")


if __name__ == "__main__":
    main()
