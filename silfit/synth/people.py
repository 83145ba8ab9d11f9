"""Extra people in a synthetic subject's keypoint file (multi-person inputs for dataset runs)."""

from __future__ import annotations

import numpy as np

__all__ = ["bystander"]


def bystander(person: dict, dx: float = 60.0, scale: float = 0.6) -> dict:
    """A keypoint-only second person for an OpenPose ``people`` list: ``person``'s keypoints
    shrunk by ``scale`` about their centre and moved ``dx`` pixels right (undetected points
    stay ``(0, 0, 0)``)."""
    kp = np.asarray(person["pose_keypoints_2d"], dtype=float).reshape(-1, 3)
    centre = kp[kp[:, 2] > 0, :2].mean(0)
    kp[:, :2] = np.where(kp[:, 2:] > 0, (kp[:, :2] - centre) * scale + centre + [dx, 0.0], 0.0)
    return {"person_id": [-1], "pose_keypoints_2d": kp.reshape(-1).round(3).tolist()}
