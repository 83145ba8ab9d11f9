"""silfit: SMPL pose, shape and camera from one image's 2D keypoints and person silhouette."""
from .body import BodyModel, BodyOutput, load_body_model
from .camera import Camera
from .fitting import KeypointFitResult, fit_keypoints

__version__ = "0.1.0"

__all__ = ["BodyModel", "BodyOutput", "Camera", "KeypointFitResult", "fit_keypoints", "load_body_model", "__version__"]
