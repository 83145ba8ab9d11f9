"""Person keypoints and mask from a photo, offline on the CPU: MediaPipe's BlazePose GHUM
detector and landmark models (shipped, Apache-2.0) run through the LiteRT interpreter.

``detect_people(image)`` returns :class:`Person` objects with 33 landmarks (visibility,
presence), BODY_25 / COCO-17 keypoints for fitting and the person mask in image pixels.
"""

from .layout import BLAZEPOSE33_NAMES, blazepose_to_layout
from .person import DetectConfig, DetectionError, Person, detect_candidates, detect_people

__all__ = [
    "BLAZEPOSE33_NAMES",
    "DetectConfig",
    "DetectionError",
    "Person",
    "blazepose_to_layout",
    "detect_candidates",
    "detect_people",
]
