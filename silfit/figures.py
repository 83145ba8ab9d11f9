"""Pictures of fits: overlays, silhouette comparisons, IoU curves and per-vertex error maps.

All functions return or write RGB ``uint8`` images; nothing here changes a fit.
"""
from __future__ import annotations

import os
from typing import Optional, Sequence

import numpy as np

from .camera import Camera
from .dataset import write_png

__all__ = [
    "write_png",
    "fit_overlay",
    "draw_keypoints",
    "silhouette_comparison",
    "iou_curve",
    "error_heatmap",
    "contact_sheet",
]

DETECTED = (40, 200, 40)  # keypoints given to the fit
FITTED = (230, 40, 40)  # the fitted body's keypoints


def _canvas(image: Optional[np.ndarray], camera: Camera) -> np.ndarray:
    if image is None:
        return np.full((camera.height, camera.width, 3), 235, np.uint8)
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return img[..., :3].astype(np.uint8)


def draw_keypoints(image: np.ndarray, xy: np.ndarray, color, conf: Optional[np.ndarray] = None, radius: int = 0) -> np.ndarray:
    """Dots at ``xy [K, 2]`` (skipping zero-confidence ones and those off the image), radius scaled to the image."""
    import cv2

    out = np.ascontiguousarray(image.copy())
    r = radius or max(2, round(max(out.shape[:2]) / 160))
    h, w = out.shape[:2]
    for k, (x, y) in enumerate(np.asarray(xy, dtype=np.float64)):
        if (conf is None or conf[k] > 0) and -r <= x <= w + r and -r <= y <= h + r:  # (False for NaN)
            cv2.circle(out, (int(round(x)), int(round(y))), r, tuple(int(c) for c in color), -1, lineType=cv2.LINE_AA)
    return out


def fit_overlay(
    image: Optional[np.ndarray],
    vertices: np.ndarray,
    faces: np.ndarray,
    camera: Camera,
    keypoints_xy: Optional[np.ndarray] = None,
    fitted_xy: Optional[np.ndarray] = None,
    conf: Optional[np.ndarray] = None,
    alpha: float = 0.65,
) -> np.ndarray:
    """The shaded body over the image (a light grey canvas without one), with the given
    keypoints in green and the fitted body's keypoints in red."""
    from renderers.offscreen import overlay

    out = overlay(_canvas(image, camera), vertices, faces, camera, alpha=alpha)
    if keypoints_xy is not None:
        out = draw_keypoints(out, keypoints_xy, DETECTED, conf)
    if fitted_xy is not None:
        out = draw_keypoints(out, fitted_xy, FITTED, conf, radius=max(1, round(max(out.shape[:2]) / 256)))
    return out


def silhouette_comparison(body: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """White where body and mask agree, red body only, blue mask only, black neither."""
    body, mask = np.asarray(body, bool), np.asarray(mask, bool)
    out = np.zeros(body.shape + (3,), np.uint8)
    out[body & mask] = (255, 255, 255)
    out[body & ~mask] = (230, 50, 50)
    out[~body & mask] = (60, 110, 240)
    return out


def iou_curve(history: dict, path: os.PathLike, title: str = "silhouette stage") -> None:
    """IoU (window, soft) and energy per step; dashed lines where the resolution changes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.arange(len(history["iou"]))
    fig, ax = plt.subplots(figsize=(6, 3.4), dpi=100)
    ax.plot(steps, history["iou"], color="tab:blue", label="IoU")
    ax.set_xlabel("step")
    ax.set_ylabel("IoU", color="tab:blue")
    ax.set_ylim(min(0.5, min(history["iou"], default=0.5)), 1.0)
    ax.grid(alpha=0.3)
    twin = ax.twinx()
    twin.plot(steps, history["energy"], color="tab:orange", alpha=0.8, label="energy")
    twin.set_ylabel("energy", color="tab:orange")
    twin.set_yscale("log")
    levels = np.asarray(history.get("level", []))
    for s in np.flatnonzero(np.diff(levels)) + 1:
        ax.axvline(s, color="grey", ls="--", lw=0.8)
    ax.set_title(title)
    fig.tight_layout()
    _save_figure(fig, path)


def _save_figure(fig, path: os.PathLike) -> None:
    import matplotlib.pyplot as plt

    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    write_png(path, rgb)


def error_heatmap(
    vertices: np.ndarray,
    faces: np.ndarray,
    errors_mm: Sequence[np.ndarray],
    titles: Sequence[str],
    path: os.PathLike,
    views: Sequence[float] = (0.0, 90.0),
    vmax: Optional[float] = None,
) -> None:
    """Meshes coloured by per-vertex error (mm), one column per error array and one row per
    view (degrees about the camera's vertical axis), with a shared colour bar.

    ``vertices [V, 3]`` in camera coordinates (OpenCV: y down) give the shape drawn;
    faces are painted back to front (orthographic), so no GL is needed.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from renderers.offscreen import rotate_about_vertical

    vmax = vmax or float(max(np.percentile(e, 99) for e in errors_mm))
    centre = vertices.mean(0)
    fig, axes = plt.subplots(len(views), len(errors_mm), figsize=(2.6 * len(errors_mm) + 0.8, 3.6 * len(views)), dpi=100,
                             squeeze=False)  # fmt: skip
    cmap = plt.get_cmap("inferno")
    for c, (err, title) in enumerate(zip(errors_mm, titles)):
        face_err = np.asarray(err)[faces].mean(1)
        for r, deg in enumerate(views):
            v = rotate_about_vertical(vertices, deg, centre).astype(np.float64)
            tri = v[faces]
            order = np.argsort(-tri[:, :, 2].mean(1))  # far to near
            normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            shade = 0.55 + 0.45 * np.abs(normal[:, 2]) / np.maximum(np.linalg.norm(normal, axis=1), 1e-12)
            colours = cmap(np.clip(face_err / vmax, 0, 1))[:, :3] * shade[:, None]
            ax = axes[r, c]
            ax.add_collection(PolyCollection(tri[order][:, :, :2] * [1, -1], facecolors=colours[order], edgecolors="none"))
            ax.autoscale_view()
            ax.set_aspect("equal")
            ax.axis("off")
            if r == 0:
                ax.set_title(f"{title}\nmean {np.mean(err):.0f} mm", fontsize=10)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, vmax))
    fig.colorbar(sm, ax=axes, fraction=0.04, label="per-vertex error (mm)")
    _save_figure(fig, path)


def contact_sheet(images: Sequence[np.ndarray], titles: Sequence[str], path: os.PathLike, columns: int = 3) -> None:
    """A titled grid of RGB images (resized to a common height)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = int(np.ceil(len(images) / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(3.6 * columns, 3.8 * rows), dpi=100, squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, img, title in zip(axes.ravel(), images, titles):
        ax.imshow(img)
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    _save_figure(fig, path)
