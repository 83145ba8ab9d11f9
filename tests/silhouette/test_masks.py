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
