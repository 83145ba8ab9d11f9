"""Renderers for silfit: differentiable Mitsuba 3 silhouettes and pyrender offscreen images.

Both follow the project's one camera convention (:mod:`silfit.camera`): meshes in OpenCV
camera coordinates (x right, y down, z forward), pixel centres on integer coordinates,
``u = fx * x / z + cx``.  Rendered silhouettes, masks and :func:`silfit.camera.project_points`
agree to sub-pixel precision.

* :mod:`silfit.render.silhouette` - :class:`SilhouetteRenderer`, :func:`render_silhouette`
  (Mitsuba 3 ``prb_projective``; torch in, torch out; gradients include the visibility
  edge term; region-of-interest mode).  Imports Mitsuba/Dr.Jit on first use.
* :mod:`silfit.render.raycast` - the default silhouette method (issue 24): Mitsuba/Embree ray
  tests, sampling and the visibility-edge integral in torch; bit-identical for any number
  of Dr.Jit threads; one acceleration structure for all views of a body.
* :mod:`silfit.render.batch` - :class:`BatchSilhouetteRenderer`, :func:`render_batch`: several
  subjects' silhouettes (own vertices, own window camera) in tiles of one film per call.
* :mod:`silfit.render.proxy` - :class:`RenderProxy`, :func:`get_proxy`, :func:`build_proxy`:
  a decimated mesh whose vertices are fixed affine combinations of the body's (for fast
  silhouettes).  Needs no Mitsuba.
* :mod:`silfit.render.offscreen` - :func:`render_mesh`, :func:`render_mask`,
  :func:`render_depth`, :func:`overlay`, :func:`render_views`, :func:`framing_camera`
  (pyrender on OSMesa).  Imports pyrender on first use.
* :mod:`silfit.render._llvm` - libLLVM discovery and Mitsuba variant selection.

Names are resolved lazily, so ``import silfit.render`` loads neither Mitsuba nor pyrender.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from silfit._lazy import lazy_exports

_EXPORTS = {
    # silhouette (Mitsuba / Dr.Jit; Mitsuba itself is imported when a renderer is built)
    "SilhouetteRenderer": "silhouette",
    "RoiWindow": "silhouette",
    "render_silhouette": "silhouette",
    "get_silhouette_renderer": "silhouette",
    "roi_window": "silhouette",
    "paste_roi": "silhouette",
    "check_camera": "silhouette",
    "check_mesh": "silhouette",
    # batched silhouettes (tiles of one film)
    "BatchSilhouetteRenderer": "batch",
    "render_batch": "batch",
    "get_batch_renderer": "batch",
    # render proxy (numpy / torch only)
    "RenderProxy": "proxy",
    "get_proxy": "proxy",
    "build_proxy": "proxy",
    "DEFAULT_PROXY_FACES": "proxy",
    # offscreen (pyrender / OSMesa)
    "BODY_COLOR": "offscreen",
    "Rendering": "offscreen",
    "OffscreenRenderer": "offscreen",
    "render_mesh": "offscreen",
    "render_mask": "offscreen",
    "render_depth": "offscreen",
    "overlay": "offscreen",
    "render_views": "offscreen",
    "framing_camera": "offscreen",
    "view_angles": "offscreen",
    # bootstrap
    "import_mitsuba": "_llvm",
    "configure_libllvm": "_llvm",
    "select_variant": "_llvm",
    "LibLLVMNotFoundError": "_llvm",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())


if TYPE_CHECKING:  # pragma: no cover
    from ._llvm import LibLLVMNotFoundError, configure_libllvm, import_mitsuba, select_variant
    from .offscreen import (
        BODY_COLOR,
        OffscreenRenderer,
        Rendering,
        framing_camera,
        overlay,
        render_depth,
        render_mask,
        render_mesh,
        render_views,
        view_angles,
    )
    from .batch import BatchSilhouetteRenderer, get_batch_renderer, render_batch
    from .proxy import DEFAULT_PROXY_FACES, RenderProxy, build_proxy, get_proxy
    from .silhouette import (
        RoiWindow,
        SilhouetteRenderer,
        check_camera,
        check_mesh,
        get_silhouette_renderer,
        paste_roi,
        render_silhouette,
        roi_window,
    )
