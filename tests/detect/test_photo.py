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


@pytest.mark.parametrize(
    "tags, name",
    [
        ({0xA405: 65535}, "FocalLengthIn35mmFilm (65535 mm)"),  # fx = 1.1e6 px on a 512 px image
        ({0x920A: 1e9, 0xA20E: 1000.0, 0xA210: 3}, "FocalLength (1e+09 mm)"),
        ({0x920A: 1e-6, 0xA20E: 1000.0, 0xA210: 3}, "FocalLength (1e-06 mm)"),  # would put the body behind the camera
    ],
)
def test_an_exif_focal_outside_the_camera_bounds_is_ignored_with_a_warning(tmp_path, tags, name):
    from silfit.camera import FOCAL_RANGE

    photo = read_photo(_jpeg(tmp_path / "e.jpg", exif_tags=tags))
    focal, source = photo.focal()
    assert focal is None and name in source and "ignored" in source
    (warning,) = photo.warnings()
    assert warning.startswith(str(tmp_path / "e.jpg")) and f"{FOCAL_RANGE[0]:g} to {FOCAL_RANGE[1]:g} times" in warning
    # the bounds themselves are accepted: 1000 x the longer side (120 px)
    assert focal_from_exif(
        {"FocalLengthIn35mmFilm": 1000 * 120 * FULL_FRAME_DIAGONAL_MM / math.hypot(120, 80) * (1 - 1e-9)}, (120, 80)
    )[0]
    assert read_photo(_jpeg(tmp_path / "ok.jpg", exif_tags={0xA405: 28})).warnings() == []


def _with_app1(path, payload: bytes):
    import io

    buf = io.BytesIO()
    Image.fromarray(np.full((80, 120, 3), 128, np.uint8)).save(buf, format="JPEG")
    data = buf.getvalue()
    segment = b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload
    path.write_bytes(data[:2] + segment + data[2:])
    return path


def test_malformed_exif_is_one_warning_of_ours_not_pillows(tmp_path):
    import struct
    import warnings

    tiff = b"MM\x00\x2a\x00\x00\x00\x08" + struct.pack(">H", 3)
    tiff += struct.pack(">HHII", 0x010F, 2, 100, 0x1000) + struct.pack(
        ">HHII", 0x0110, 2, 5000, 0x20
    )  # data past the end
    tiff += struct.pack(">HHII", 0x8769, 4, 1, 0xFFFF) + b"\x00\x00\x00\x00"  # an EXIF IFD past the end
    path = _with_app1(tmp_path / "g.jpg", b"Exif\x00\x00" + tiff)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        photo = read_photo(path)
    assert [str(w.message) for w in caught] == []
    (note,) = photo.warnings()
    assert note.startswith(str(path)) and "malformed EXIF data ignored" in note
    assert photo.image.shape == (80, 120, 3) and photo.focal()[0] is None


def test_16_bit_greyscale_is_scaled_not_clipped_and_cmyk_is_refused(tmp_path):
    from silfit.errors import InputError
    from silfit.io.images import read_rgb

    ramp = np.tile(np.linspace(0, 65535, 64).astype(np.uint16), (16, 1))
    Image.fromarray(ramp).save(tmp_path / "g16.png")
    for rgb in (read_photo(tmp_path / "g16.png").image, read_rgb(tmp_path / "g16.png")):
        assert rgb.shape == (16, 64, 3) and rgb.dtype == np.uint8
        assert np.array_equal(rgb[..., 0], np.round(ramp / 257).astype(np.uint8)), rgb[0, :8, 0]
        assert (rgb == 255).mean() < 0.05  # (Pillow's own conversion clips: 98 % at 255)
    Image.fromarray(np.full((8, 8, 3), 90, np.uint8)).convert("CMYK").save(tmp_path / "c.jpg")
    for read in (read_photo, read_rgb):
        with pytest.raises(InputError, match=r"c\.jpg: image is in CMYK"):
            read(tmp_path / "c.jpg")
