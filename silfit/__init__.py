"""silfit: SMPL pose, shape and camera from one image's 2D keypoints and person silhouette.

``load_body_model`` gives the body model, ``fit_keypoints`` the keypoint stage (batched),
``fit`` the whole fit of one image (keypoints, then silhouette) and ``save_fit`` its
output folder; ``read_sequence``, ``fit_sequence`` and ``save_sequence_fit`` the same for a
video's frames.

Names are resolved on first use (PEP 562), so ``import silfit`` (and ``silfit --help``,
``silfit synth``) does not pay for torch, scipy and the fitting code until they are needed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .kernels import late_import_message, pin_kernels

pin_kernels()  # before anything loads torch or numpy (silfit.kernels)
if late_import_message():  # numpy or torch came first: say so once, where the script imports silfit
    import warnings

    warnings.warn(late_import_message(), RuntimeWarning, stacklevel=2)

from ._lazy import alias_moved_modules, lazy_exports  # noqa: E402

#: modules moved by issue 57's layout (old name -> new): the old names still import, with a DeprecationWarning
MOVED_MODULES = {
    "silfit.fitio": "silfit.io.fit",
    "silfit.imagefile": "silfit.io.images",
    "silfit.meshio": "silfit.io.meshes",
    "silfit.safe_pickle": "silfit.io.safe_pickle",
    "silfit.keypoints": "silfit.io.keypoints",
    "silfit.input_limits": "silfit.io.limits",
    "silfit.dataset": "silfit.io.subjects",
    "silfit.rig": "silfit.io.rig",
    "silfit.video": "silfit.io.video",
    "silfit.wholebody": "silfit.io.wholebody",
    "silfit.figures": "silfit.outputs.figures",
    "silfit.outfolder": "silfit.outputs.folder",
    "silfit.image_fit": "silfit.fitting.image_fit",
    "silfit.rig_pipeline": "silfit.fitting.rig_pipeline",
    "silfit.plausibility": "silfit.fitting.plausibility",
    "silfit.demo": "silfit.demos.body",
    "silfit.demo_wholebody": "silfit.demos.wholebody",
}
alias_moved_modules(MOVED_MODULES)

__version__ = "0.1.0"

_EXPORTS = {
    "BodyModel": "body",
    "BodyOutput": "body",
    "load_body_model": "body",
    "Camera": "camera",
    "KeypointFitResult": "fitting",
    "fit_keypoints": "fitting",
    "FitResult": "fitting.image_fit",
    "fit": "run",
    "save_fit": "outputs.write",
    "fit_sequence": "run",
    "read_sequence": "io.video",
    "save_sequence_fit": "outputs.write",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())


if TYPE_CHECKING:  # pragma: no cover
    from .body import BodyModel, BodyOutput, load_body_model
    from .camera import Camera
    from .fitting import KeypointFitResult, fit_keypoints
    from .fitting.image_fit import FitResult
    from .run import fit, fit_sequence
    from .io.video import read_sequence
    from .outputs.write import save_fit, save_sequence_fit
