"""Small dataset inputs built from the shipped synthetic subjects (shared by the runner and
fit-dataset tests)."""

import json
import shutil
from pathlib import Path

from silfit.synth.people import bystander

SYNTHETIC = Path(__file__).resolve().parents[2] / "data" / "synthetic"
#: keypoint-stage options that keep a fit to about 0.1 s (tests check plumbing, not accuracy)
FAST = [
    "--keypoint-option",
    "starts.poses=1",
    "--keypoint-option",
    "camera_iters=10",
    "--keypoint-option",
    "pose_iters=10,10,10",
    "--keypoint-option",
    "shape_iters=5",
    "--keypoint-option",
    "final_iters=10",
    "--keypoint-option",
    "branches.refine=1",
    "--keypoint-option",
    "branches.post_iters=0",
]


def subject_people(name: str) -> list:
    """The subject's keypoints as OpenPose ``people`` entries."""
    return json.loads((SYNTHETIC / name / "keypoints.json").read_text())["people"]


def openpose_folder(root: Path, names=("subject_000", "subject_001", "subject_002"), two_people=("subject_001",)):
    """``root/kp/<stem>_keypoints.json`` (two people for ``two_people``), ``root/masks/<stem>_0.png``
    (person 0's mask), ``root/images/<stem>.png`` and ``root/cameras/<stem>.json``."""
    for d in ("kp", "masks", "images", "cameras"):
        (root / d).mkdir(parents=True, exist_ok=True)
    for name in names:
        people = subject_people(name)
        if name in two_people:
            people.append(bystander(people[0]))
        (root / "kp" / f"{name}_keypoints.json").write_text(json.dumps({"version": 1.3, "people": people}))
        shutil.copy(SYNTHETIC / name / "mask.png", root / "masks" / f"{name}_0.png")
        shutil.copy(SYNTHETIC / name / "image.png", root / "images" / f"{name}.png")
        shutil.copy(SYNTHETIC / name / "camera.json", root / "cameras" / f"{name}.json")
    return root


def synthetic_copy(root: Path, names) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    for name in names:
        shutil.copytree(SYNTHETIC / name, root / name)
    return root
