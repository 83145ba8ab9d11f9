"""Pictures of fits: overlays, silhouette comparisons, IoU curves and per-vertex error maps.

All functions return or write RGB ``uint8`` images; nothing here changes a fit.
"""

from __future__ import annotations

import os
import sys
from typing import Optional, Sequence

import cv2
import numpy as np

from silfit.render.offscreen import framing_camera, overlay, rotate_about_vertical

from ..camera import Camera
from ..io.subjects import write_png

__all__ = [
    "write_png",
    "fit_overlay",
    "paint_mesh",
    "draw_keypoints",
    "silhouette_comparison",
    "iou_curve",
    "error_heatmap",
    "contact_sheet",
    "side_view",
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


def draw_keypoints(
    image: np.ndarray, xy: np.ndarray, color, conf: Optional[np.ndarray] = None, radius: int = 0
) -> np.ndarray:
    """Dots at ``xy [K, 2]`` (skipping zero-confidence ones and those off the image), radius scaled to the image."""
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
    keypoints in green and the fitted body's keypoints in red.

    The body comes from the offscreen GL renderer when this process has already loaded it
    (then it costs a few ms), else it is painted with OpenCV (:func:`paint_mesh`; no
    pyrender import and GL context, which take seconds (docs/benchmarks/defaults.md), for a
    picture every ``silfit fit`` writes)."""
    canvas = _canvas(image, camera)
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must be in [0, 1], got {alpha}")
    if "pyrender" in sys.modules:
        out = overlay(canvas, vertices, faces, camera, alpha=alpha)
    else:
        rgba = paint_mesh(vertices, faces, camera)
        a = (rgba[..., 3:].astype(np.float32) / 255.0) * float(alpha)
        out = canvas.astype(np.float32) * (1.0 - a) + rgba[..., :3].astype(np.float32) * a
        out = np.clip(out + 0.5, 0, 255).astype(np.uint8)
    if keypoints_xy is not None:
        out = draw_keypoints(out, keypoints_xy, DETECTED, conf)
    if fitted_xy is not None:
        out = draw_keypoints(out, fitted_xy, FITTED, conf, radius=max(1, round(max(out.shape[:2]) / 256)))
    return out


BODY_RGB = (0.58, 0.64, 0.74)  # the offscreen renderer's clay colour (linear RGB)


def paint_mesh(vertices, faces, camera: Camera, color=BODY_RGB) -> np.ndarray:
    """``[H, W, 4]`` uint8 RGBA of a closed camera-frame mesh: the faces turned towards the
    camera painted far to near (painter's algorithm) with flat shading ``0.3 + 0.7 |cos|``
    of the angle to the viewing ray; alpha 255 where a face touches the pixel (the
    outline is about half a pixel wider than pixel-centre coverage)."""
    v = np.asarray(vertices.detach().cpu().numpy() if hasattr(vertices, "detach") else vertices, dtype=np.float64)
    f = np.asarray(faces.detach().cpu().numpy() if hasattr(faces, "detach") else faces, dtype=np.int64)
    out = np.zeros((camera.height, camera.width, 4), np.uint8)
    tri = v[f]
    keep = (tri[:, :, 2] > 1e-3).all(1)
    tri = tri[keep]
    if tri.shape[0] == 0:
        return out
    z = tri[:, :, 2]
    uv = np.stack([camera.fx * tri[:, :, 0] / z + camera.cx, camera.fy * tri[:, :, 1] / z + camera.cy], axis=-1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = tri.mean(1)
    facing = (normal * centre).sum(1)
    # a closed mesh's outward side: the sign of its signed volume; drop faces turned away
    outward = np.sign(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum()) or 1.0
    front = facing * outward < 0
    tri, uv, z, normal, centre, facing = tri[front], uv[front], z[front], normal[front], centre[front], facing[front]
    cos = np.abs(facing) / np.maximum(np.linalg.norm(normal, axis=1) * np.linalg.norm(centre, axis=1), 1e-20)
    rgb = (np.clip(np.asarray(color, dtype=np.float64)[None] * (0.3 + 0.7 * cos[:, None]), 0, 1) ** (1 / 2.2)) * 255
    lo, hi = uv.min(1), uv.max(1)
    onscreen = (hi[:, 0] >= -1) & (hi[:, 1] >= -1) & (lo[:, 0] <= camera.width) & (lo[:, 1] <= camera.height)
    shift = 4  # sub-pixel vertex positions (1/16 px)
    pts = np.round(uv * (1 << shift)).astype(np.int32)
    colours = np.concatenate([np.round(rgb), np.full((len(rgb), 1), 255.0)], axis=1).astype(int).tolist()
    for i in np.flatnonzero(onscreen)[np.argsort(-z[onscreen].mean(1), kind="stable")]:
        cv2.fillConvexPoly(out, pts[i], colours[i], lineType=cv2.LINE_8, shift=shift)
    return out


REFERENCE_RGB = (0.95, 0.45, 0.10)  # the keypoint-stage body behind the final one in side views (linear RGB)


def side_view(
    vertices: np.ndarray,
    faces: np.ndarray,
    reference: Optional[np.ndarray] = None,
    size: tuple = (320, 400),
    degrees: float = 90.0,
    labels: tuple = ("final", "keypoint fit"),
) -> np.ndarray:
    """The body seen from the side: camera-frame ``vertices [V, 3]`` (OpenCV axes) turned
    ``degrees`` about the camera's vertical axis through the body's centre, painted (no GL,
    :func:`paint_mesh`) over ``reference`` (the keypoint-stage body, same frame) in orange, both
    framed by one camera so their placement in depth compares; the original camera looks from
    the left (an arrow). Failures a front view hides show here: legs folded into the frame,
    a body pushed in depth, a swollen belly. ``size`` is ``(W, H)``; RGB uint8."""

    v = np.asarray(vertices, dtype=np.float64)
    centre = (v.min(0) + v.max(0)) / 2
    meshes = [rotate_about_vertical(v, degrees, centre)]
    if reference is not None:
        meshes.append(rotate_about_vertical(np.asarray(reference, dtype=np.float64), degrees, centre))
    union = np.concatenate(meshes).astype(np.float64)
    W, H = int(size[0]), int(size[1])
    camera, moved = framing_camera(union, W, H, fov_degrees=20.0, margin=0.1)
    shift = moved[0].astype(np.float64) - union[0]
    out = np.full((H, W, 3), 255.0, np.float32)
    layers = [(meshes[1], REFERENCE_RGB, 0.55)] if reference is not None else []
    for mesh, colour, alpha in layers + [(meshes[0], BODY_RGB, 0.8)]:
        rgba = paint_mesh(mesh + shift, faces, camera, colour)
        a = rgba[..., 3:].astype(np.float32) / 255.0 * alpha
        out = out * (1 - a) + rgba[..., :3].astype(np.float32) * a
    img = np.ascontiguousarray(np.clip(out + 0.5, 0, 255).astype(np.uint8))
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, max(0.35, H / 900)
    y = int(18 * scale / 0.45)
    (tw, _), _ = cv2.getTextSize("camera", font, scale, 1)
    cv2.putText(img, "camera", (6, y + 4), font, scale, (90, 90, 90), 1, cv2.LINE_AA)
    cv2.arrowedLine(img, (10 + tw, y), (int(10 + tw + W * 0.12), y), (90, 90, 90), 1, cv2.LINE_AA, tipLength=0.3)
    legend = [(labels[0], BODY_RGB)] + ([(labels[1], REFERENCE_RGB)] if reference is not None else [])
    for k, (text, colour) in enumerate(legend):
        yy = H - 8 - int(k * 18 * scale / 0.45)
        rgb = tuple(int(round(255 * c ** (1 / 2.2))) for c in colour)
        cv2.rectangle(img, (6, yy - 9), (16, yy + 1), rgb, -1)
        cv2.putText(img, text, (22, yy), font, scale, (40, 40, 40), 1, cv2.LINE_AA)
    return img


def silhouette_comparison(body: np.ndarray, mask: np.ndarray, fitted: Optional[np.ndarray] = None) -> np.ndarray:
    """White where body and mask agree, red body outside the mask, blue mask the body does not cover, black
    neither; with ``fitted`` (the mask pixels the silhouette stage fitted as body) the mask pixels it did not
    (treated as clothing, hair, a leak or another person: trimmed or unknown) and the body does not cover are
    tan instead of blue (issue 55)."""
    body, mask = np.asarray(body, bool), np.asarray(mask, bool)
    out = np.zeros(body.shape + (3,), np.uint8)
    out[body & mask] = (255, 255, 255)
    out[body & ~mask] = (230, 50, 50)
    out[~body & mask] = (60, 110, 240)
    if fitted is not None:
        out[~body & mask & ~np.asarray(fitted, bool)] = (205, 170, 100)
    return out


def iou_curve(history: dict, path: os.PathLike, title: str = "silhouette stage") -> None:
    """IoU (window, soft; left axis) and energy (log scale; right axis) per step; dashed
    lines where the resolution changes.  Drawn with OpenCV (no matplotlib import: this
    picture is written by every ``silfit fit`` with a silhouette stage)."""
    W, H, left, right, top, bottom = 600, 340, 62, 70, 34, 44
    img = np.full((H, W, 3), 255, np.uint8)
    x0, x1, y0, y1 = left, W - right, top, H - bottom  # plot box (y0 top)
    iou = np.asarray(history.get("iou", []), dtype=np.float64)
    energy = np.asarray(history.get("energy", []), dtype=np.float64)
    n = max(len(iou), 2)
    font, blue, orange, grey = cv2.FONT_HERSHEY_SIMPLEX, (31, 119, 180), (255, 127, 14), (150, 150, 150)

    def px(i):
        return x0 + (x1 - x0) * np.asarray(i, dtype=np.float64) / (n - 1)

    def text(s, org, color=(0, 0, 0), scale=0.4, anchor="left"):
        (tw, th), _ = cv2.getTextSize(s, font, scale, 1)
        x = org[0] - (tw if anchor == "right" else tw // 2 if anchor == "centre" else 0)
        cv2.putText(img, s, (int(x), int(org[1] + th / 2)), font, scale, color, 1, cv2.LINE_AA)

    lo = min(0.5, float(iou.min()) if iou.size else 0.5)
    for k in range(6):  # IoU grid and ticks
        v = lo + (1.0 - lo) * k / 5
        y = int(round(y1 - (y1 - y0) * k / 5))
        cv2.line(img, (x0, y), (x1, y), (230, 230, 230), 1)
        text(f"{v:.2f}", (x0 - 6, y), blue, anchor="right")
    for k in range(6):  # step ticks
        step = int(round((n - 1) * k / 5))
        text(str(step), (int(px(step)), y1 + 12), anchor="centre")
    levels = np.asarray(history.get("level", []))
    for s in np.flatnonzero(np.diff(levels)) + 1:
        x = int(round(px(s)))
        for ya in range(y0, y1, 8):
            cv2.line(img, (x, ya), (x, min(ya + 4, y1)), grey, 1)
    finite = energy[np.isfinite(energy) & (energy > 0)]
    if finite.size:
        e_lo, e_hi = np.log10(finite.min()), np.log10(finite.max())
        e_hi = e_hi if e_hi > e_lo else e_lo + 1.0
        for k in range(3):
            v = e_lo + (e_hi - e_lo) * k / 2
            text(f"{10**v:.3g}", (x1 + 6, int(round(y1 - (y1 - y0) * k / 2))), orange)
        pts = [
            (px(i), y1 - (y1 - y0) * (np.log10(e) - e_lo) / (e_hi - e_lo))
            for i, e in enumerate(energy)
            if e > 0 and np.isfinite(e)
        ]
        if len(pts) > 1:
            cv2.polylines(img, [np.round(np.array(pts)).astype(np.int32)], False, orange, 1, cv2.LINE_AA)
    if iou.size > 1:
        pts = np.stack([px(np.arange(len(iou))), y1 - (y1 - y0) * (iou - lo) / (1.0 - lo)], axis=1)
        cv2.polylines(img, [np.round(pts).astype(np.int32)], False, blue, 2, cv2.LINE_AA)
    cv2.rectangle(img, (x0, y0), (x1, y1), (0, 0, 0), 1)
    text(title, (W // 2, top // 2), scale=0.5, anchor="centre")
    text("step", ((x0 + x1) // 2, H - 14), anchor="centre")
    text("IoU", (8, top - 14), blue)
    text("energy", (x1 + 6, top - 14), orange)
    write_png(path, img)


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

    vmax = vmax or float(max(np.percentile(e, 99) for e in errors_mm))
    centre = vertices.mean(0)
    fig, axes = plt.subplots(
        len(views), len(errors_mm), figsize=(2.6 * len(errors_mm) + 0.8, 3.6 * len(views)), dpi=100, squeeze=False
    )
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
            ax.add_collection(
                PolyCollection(tri[order][:, :, :2] * [1, -1], facecolors=colours[order], edgecolors="none")
            )
            ax.autoscale_view()
            ax.set_aspect("equal")
            ax.axis("off")
            if r == 0:
                ax.set_title(f"{title}\nmean {np.mean(err):.0f} mm", fontsize=10)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, vmax))
    fig.colorbar(sm, ax=axes, fraction=0.04, label="per-vertex error (mm)")
    _save_figure(fig, path)


def contact_sheet(
    images: Sequence[Optional[np.ndarray]], titles: Sequence[str], path: os.PathLike, columns: int = 3
) -> None:
    """A titled grid of RGB images, one title per image (``None``: an empty cell)."""
    import matplotlib

    if len(images) != len(titles):
        raise ValueError(f"contact_sheet: {len(images)} images but {len(titles)} titles")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = int(np.ceil(len(images) / columns))
    lines = max([t.count("\n") for t in titles] + [0])  # room for titles of several lines
    fig, axes = plt.subplots(
        rows, columns, figsize=(3.6 * columns, (3.8 + 0.25 * lines) * rows), dpi=100, squeeze=False
    )
    for ax in axes.ravel():
        ax.axis("off")
    for ax, img, title in zip(axes.ravel(), images, titles):
        if img is None:
            continue
        ax.imshow(img)
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    _save_figure(fig, path)
