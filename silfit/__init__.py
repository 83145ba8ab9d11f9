"""silfit: SMPL pose, shape and camera from one image's 2D keypoints and person silhouette.

``load_body_model`` gives the body model, ``fit_keypoints`` the keypoint stage (batched),
``fit`` the whole fit of one image (keypoints, then silhouette) and ``save_fit`` its
output folder.
"""
from .body import BodyModel, BodyOutput, load_body_model
from .camera import Camera
from .fitting import KeypointFitResult, fit_keypoints
from .pipeline import FitResult, fit, save_fit

__version__ = "0.1.0"

__all__ = [
    "BodyModel",
    "BodyOutput",
    "Camera",
    "FitResult",
    "KeypointFitResult",
    "fit",
    "fit_keypoints",
    "load_body_model",
    "save_fit",
    "__version__",
]
