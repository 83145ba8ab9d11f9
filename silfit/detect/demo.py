"""``silfit demo --photo``: a photograph in, the fitted body out, with the detection drawn.

Writes into the output folder::

    detection/        what ``silfit detect`` writes (keypoints.json, mask.png, detection.json/png)
    fit/              what ``silfit fit`` writes
    summary.png       detection | keypoint fit | keypoint + silhouette fit | silhouette match | side view
    report.md         detection and fit summary

The default photo is ``data/photos/astronaut.jpg`` of a source checkout (NASA's public-domain
portrait of Eileen Collins, the image scikit-image ships as ``astronaut``), else
scikit-image's own copy when it is installed.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

from ..body import load_body_model
from ..io.subjects import read_image
from ..outputs import figures
from ..run import image_job, run, write
from .output import detect_photo, save_detection

__all__ = ["SAMPLE_PHOTO", "sample_photo", "run_photo_demo"]

SAMPLE_PHOTO = Path(__file__).resolve().parents[2] / "data" / "photos" / "astronaut.jpg"


def sample_photo() -> Path:
    if SAMPLE_PHOTO.is_file():
        return SAMPLE_PHOTO
    try:
        import skimage

        shipped = Path(skimage.__file__).parent / "data" / "astronaut.png"
        if shipped.is_file():
            return shipped
    except ImportError:
        pass
    raise FileNotFoundError(f"{SAMPLE_PHOTO}: sample photo not found (not a source checkout): give --photo PATH")


def run_photo_demo(
    out: Path, photo_path: Optional[Path] = None, progress: bool = False, silhouette_config=None
) -> dict:
    """Detect, fit and draw (see the module docstring); returns the report."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = Path(photo_path) if photo_path else sample_photo()
    t0 = time.perf_counter()
    photo, people = detect_photo(path)
    t_detect = time.perf_counter() - t0
    save_detection(out / "detection", photo, people, overwrite=True)
    person = people[0]
    keypoints, mask = person.keypoint_set(source=f"{path} (detected)"), person.mask()
    focal, focal_source = photo.focal()
    model = load_body_model()
    faces = model.faces.cpu().numpy()
    fitted = run(
        image_job(
            keypoints,
            mask,
            None,
            image_size=photo.size,
            focal=focal,
            model=model,
            silhouette_config=silhouette_config,
            progress=progress,
        )
    )
    warnings = photo.warnings() + [f"detection: {w}" for w in person.warnings()] + fitted.warnings
    extra = {"image": str(path), "camera_source": focal_source if focal else "default max(W, H)", "warnings": warnings}
    write(fitted, out / "fit", overwrite=True, extra=extra, images={(0, 0): photo.image})  # fitted without the image

    cam, kp_vertices, vertices = fitted.camera, fitted.keypoint_fit.vertices[0], fitted.vertices[0]
    panels = [
        read_image(out / "detection" / "detection.png"),
        figures.fit_overlay(photo.image, kp_vertices, faces, cam, keypoints.xy, None, keypoints.conf),
        figures.fit_overlay(photo.image, vertices, faces, cam, keypoints.xy, None, keypoints.conf),
        figures.silhouette_comparison(fitted.masks[0], mask),
        figures.side_view(vertices, faces, kp_vertices),
    ]
    titles = [
        "detection",
        "keypoint fit",
        "keypoint + silhouette fit",
        "silhouette vs detected mask",
        "side: final over keypoint fit",
    ]
    figures.contact_sheet(panels, titles, out / "summary.png", columns=5)

    m = fitted.metrics
    rows = [
        ("photo", f"{path.name} ({photo.size[0]}x{photo.size[1]})"),
        ("people found", str(len(people))),
        ("detector score / pose presence", f"{person.score:.2f} / {person.presence_score:.2f}"),
        ("camera", extra["camera_source"]),
        ("lower body visible", "yes" if person.lower_body_visible() else "no"),
        ("reprojection error (px, median)", f"{m['reprojection_error_px']:.1f}"),
        ("silhouette IoU, keypoint fit -> final", f"{m['iou_keypoint_stage']:.3f} -> {m['iou']:.3f}"),
        (
            "time: detection / fit (s)",
            f"{t_detect:.1f} / {sum(v for k, v in m['timings_s'].items() if '.' not in k):.1f}",
        ),
    ]
    table = "| | |\n|---|---|\n" + "\n".join(f"| {a} | {b} |" for a, b in rows)
    (out / "report.md").write_text(f"# silfit photo demo: {path.name}\n\n{table}\n")
    return {"photo": str(path), "table": table, "warnings": warnings}
