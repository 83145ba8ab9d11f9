"""silfit: SMPL pose, shape and camera from one image's 2D keypoints and person silhouette."""
from .body import BodyModel, BodyOutput, load_body_model
from .camera import Camera

__version__ = "0.1.0"

__all__ = ["BodyModel", "BodyOutput", "Camera", "load_body_model", "__version__"]
