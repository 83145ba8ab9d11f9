"""Reading person masks: accepted encodings and clear errors."""

import cv2
import numpy as np
import pytest

from silfit.silhouette import read_mask


def person(h=48, w=32):
    m = np.zeros((h, w), np.uint8)
    m[10:40, 8:24] = 255
    return m


@pytest.mark.parametrize(
    "encode",
    [
        lambda m: m,
        lambda m: m.astype(np.uint16) * 257,
        lambda m: np.dstack([m, m, m]),
        lambda m: np.dstack([m, m, m, np.full_like(m, 255)]),
        lambda m: np.dstack([np.zeros_like(m)] * 3 + [m]),
    ],
    ids=["grey8", "grey16", "rgb", "rgba-opaque", "alpha-carries-mask"],
)
def test_sensible_encodings_are_accepted(tmp_path, encode):
    cv2.imwrite(str(tmp_path / "m.png"), encode(person()))
    mask = read_mask(tmp_path / "m.png", size=(32, 48))
    assert mask.dtype == bool and np.array_equal(mask, person() > 0)


def test_bad_masks_name_the_file(tmp_path):
    m = person()
    cases = {
        "empty.png": np.zeros_like(m),
        "white.png": np.full_like(m, 255),
        "colour.png": np.dstack([m, np.zeros_like(m), m // 2]),
    }
    for name, img in cases.items():
        cv2.imwrite(str(tmp_path / name), img)
    with pytest.raises(ValueError, match=r"empty\.png.*empty"):
        read_mask(tmp_path / "empty.png")
    with pytest.raises(ValueError, match=r"white\.png.*everywhere"):
        read_mask(tmp_path / "white.png")
    with pytest.raises(ValueError, match=r"colour\.png.*colour"):
        read_mask(tmp_path / "colour.png")
    cv2.imwrite(str(tmp_path / "ok.png"), m)
    with pytest.raises(ValueError, match=r"ok\.png.*32x48.*64x64"):
        read_mask(tmp_path / "ok.png", size=(64, 64))
    with pytest.raises(FileNotFoundError, match="nope.png"):
        read_mask(tmp_path / "nope.png")
    (tmp_path / "junk.png").write_bytes(b"junk")
    with pytest.raises(ValueError, match="junk.png"):
        read_mask(tmp_path / "junk.png")


# --------------------------------------------------------------------------- odd files
def _png_header_only(path, width, height):
    """A PNG whose header claims ``width x height`` (with almost no pixel data)."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 16)) + chunk(b"IEND", b"")
    )


def test_huge_mask_is_refused_from_its_header(tmp_path):
    from silfit.errors import InputError

    _png_header_only(tmp_path / "huge.png", 100000, 100000)
    with pytest.raises(InputError, match=r"huge\.png.*larger than silfit accepts"):
        read_mask(tmp_path / "huge.png")
    _png_header_only(tmp_path / "wide.png", 20000, 10)  # under PIL's own limit: silfit's per-side one
    with pytest.raises(InputError, match=r"wide\.png.*20000x10 pixels is larger than silfit accepts"):
        read_mask(tmp_path / "wide.png")
    _png_header_only(tmp_path / "trunc.png", 64, 48)  # a plausible size, but no pixels
    with pytest.raises(InputError, match=r"trunc\.png"):
        read_mask(tmp_path / "trunc.png")


@pytest.mark.parametrize("mode", ["1", "P", "LA", "I", "F", "CMYK", "I;16"])
def test_odd_png_modes_are_read_or_refused_cleanly(tmp_path, mode):
    from PIL import Image

    from silfit.errors import InputError

    grey = Image.fromarray(person())
    img = grey.convert(mode) if mode not in ("I;16",) else Image.fromarray(person().astype(np.uint16) * 257)
    suffix = ".tif" if mode in ("F", "CMYK", "I") else ".png"
    path = tmp_path / f"m{suffix}"
    img.save(path)
    try:
        mask = read_mask(path, size=(32, 48))
    except InputError as err:
        assert str(err).startswith(str(path)) and "\n" not in str(err)
    else:
        assert np.array_equal(mask, person() > 0)


def test_mask_size_is_checked_before_decoding(tmp_path):
    from silfit.errors import InputError

    cv2.imwrite(str(tmp_path / "m.png"), person())
    with pytest.raises(InputError, match=r"m\.png: mask is 32x48 pixels but the image/camera is 64x48"):
        read_mask(tmp_path / "m.png", size=(64, 48))
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(InputError, match=r"text\.png.*cannot read the mask"):
        read_mask(tmp_path / "text.png")
