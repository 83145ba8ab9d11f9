import math

import numpy as np
import pytest
from PIL import Image

from silfit.detect.photo import FULL_FRAME_DIAGONAL_MM, focal_from_exif, read_photo


def _jpeg(path, size=(120, 80), exif_tags=None, orientation=None):
    img = Image.fromarray(np.full((size[1], size[0], 3), 128, np.uint8))
    exif = Image.Exif()
    if orientation:
        exif[0x0112] = orientation
    ifd = exif.get_ifd(0x8769)
    for tag, value in (exif_tags or {}).items():
        ifd[tag] = value
    img.save(path, exif=exif.tobytes())
    return path


def test_focal_from_35mm_equivalent(tmp_path):
    photo = read_photo(_jpeg(tmp_path / "a.jpg", exif_tags={0xA405: 28, 0x920A: 4.2}))
    assert photo.exif["FocalLengthIn35mmFilm"] == 28
    focal, source = photo.focal()
    assert focal == pytest.approx(28 * math.hypot(120, 80) / FULL_FRAME_DIAGONAL_MM)
    assert "FocalLengthIn35mmFilm" in source
    # A 3:2 image: the diagonal rule equals f35 / 36 mm * width.
    assert focal == pytest.approx(28 / 36 * 120)


def test_focal_from_focal_length_and_sensor_resolution(tmp_path):
    # 5 mm lens, 1000 sensor pixels per cm (unit 3), image stored at half the sensor's 240 px width.
    tags = {0x920A: 5.0, 0xA20E: 1000.0, 0xA210: 3, 0xA002: 240}
    photo = read_photo(_jpeg(tmp_path / "b.jpg", exif_tags=tags))
    focal, source = photo.focal()
    assert focal == pytest.approx(5.0 * 100.0 * 120 / 240)
    assert "FocalPlaneXResolution" in source


def test_no_usable_focal(tmp_path):
    assert read_photo(_jpeg(tmp_path / "c.jpg")).focal() == (None, "no focal length in EXIF")
    focal, source = read_photo(_jpeg(tmp_path / "d.jpg", exif_tags={0x920A: 4.0})).focal()
    assert focal is None and "without the sensor size" in source
    assert focal_from_exif({}, (10, 10)) == (None, "no focal length in EXIF")


def test_exif_orientation_is_applied(tmp_path):
    photo = read_photo(_jpeg(tmp_path / "r.jpg", size=(120, 80), orientation=6))  # rotate 90 degrees
    assert photo.size == (80, 120) and photo.stored_width == 120


def test_bad_images_are_reported(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.jpg: image not found"):
        read_photo(tmp_path / "missing.jpg")
    (tmp_path / "empty.jpg").write_bytes(b"")
    with pytest.raises(ValueError, match="empty.jpg: (not a readable image|cannot read the image)"):
        read_photo(tmp_path / "empty.jpg")
    (tmp_path / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(ValueError, match="junk.png: (not a readable image|cannot read the image)"):
        read_photo(tmp_path / "junk.png")
