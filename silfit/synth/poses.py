"""Re-export of :mod:`silfit.poses.library` (the pose library's former home), so that
``from silfit.synth.poses import ...`` keeps working."""

from ..poses.library import *  # noqa: F401,F403
from ..poses.library import __all__  # noqa: F401
