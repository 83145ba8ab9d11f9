"""Rewrite ``tests/fitting/data/keypoint_fit_reference.npz``: keypoint-stage fits of the first
three shipped subjects, in float64, with the short schedule stored in the file itself (``config``,
JSON), which ``tests/fitting/test_keypoint_stage.py::test_single_image_fits_equal_the_reference``
reads back. Run it (from the repository root) only when the single-image fit changes on
purpose, and say so in the commit.

Float64, because float32 fits differ between CPUs by millimetres (their SIMD kernels round
differently, and the optimiser amplifies it); in float64 the same code gives the same fits to
well under 0.1 mm.
"""

from __future__ import annotations

import silfit  # noqa: F401  (first: pins the CPU kernels before torch and numpy load, as the tests do: silfit.kernels)

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

#: the short schedule of the reference fits
CONFIG = {
    "camera_iters": 15,
    "pose_iters": [15, 15, 15],
    "shape_iters": 8,
    "final_iters": 15,
    "init_poses": 2,
    "decision_iters": 8,
    "branch_iters": 10,
    "branch_screen_iters": 5,
    "post_branch_iters": 10,
}


def main() -> None:
    import torch

    from silfit import fit_keypoints, load_body_model
    from silfit.io.subjects import list_subjects, load_subject
    from silfit.fitting import KeypointFitConfig

    root = Path(__file__).resolve().parents[1]
    model = load_body_model(dtype=torch.float64)
    cfg = KeypointFitConfig(**CONFIG)
    out = {"config": np.asarray(json.dumps(CONFIG))}
    for path in list_subjects(root / "data" / "synthetic")[:3]:
        s = load_subject(path)
        r = fit_keypoints(s.keypoints, s.camera, model, config=cfg, progress=False)
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
