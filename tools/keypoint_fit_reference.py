"""Rewrite ``tests/fitting/data/keypoint_fit_reference.npz``: keypoint-stage fits of the first
three shipped subjects with the short schedule of
``tests/fitting/test_keypoint_stage.py::test_single_image_fits_equal_the_reference``.
Run it (from the repository root) only when an energy term changes on purpose, and say so
in the commit.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def main() -> None:
    from silfit import fit_keypoints
    from silfit.dataset import list_subjects, load_subject
    from silfit.fitting import KeypointFitConfig

    root = Path(__file__).resolve().parents[1]
    cfg = KeypointFitConfig(camera_iters=15, pose_iters=(15, 15, 15), shape_iters=8, final_iters=15, init_poses=2, decision_iters=8)
    out = {}
    for path in list_subjects(root / "data" / "synthetic")[:3]:
        s = load_subject(path)
        r = fit_keypoints(s.keypoints, s.camera, config=cfg, progress=False)
        for k in ("betas", "body_pose", "global_orient", "transl"):
            out[f"{s.name}/{k}"] = np.asarray(getattr(r, k)[0])
        out[f"{s.name}/joints"] = np.asarray(r.joints[0])
        out[f"{s.name}/energy"] = np.asarray([r.energies["final"][0]])
        out[f"{s.name}/flipped"] = np.asarray([bool(r.flipped[0])])
    dest = root / "tests" / "fitting" / "data" / "keypoint_fit_reference.npz"
    np.savez(dest, **out)
    print(f"wrote {dest} ({len(out)} arrays)")


if __name__ == "__main__":
    main()
