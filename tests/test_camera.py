"""The camera convention: projection, crops, defaults and camera files."""

import json
import math

import pytest
import torch

from silfit.camera import Camera, default_focal, load_camera, project_points, save_camera, weak_perspective_project


def test_projection_follows_opencv_pixel_centres():
    cam = Camera(fx=100.0, fy=120.0, cx=31.5, cy=47.0, width=64, height=96)
    pts = torch.tensor([[[0.0, 0.0, 2.0], [1.0, -0.5, 2.0]]])
    uv = project_points(pts, cam)
    assert torch.allclose(uv, torch.tensor([[[31.5, 47.0], [81.5, 17.0]]]))
    # The same through a batched intrinsics tensor.
    intr = torch.tensor([[100.0, 120.0, 31.5, 47.0]])
    assert torch.allclose(project_points(pts, intr), uv)


def test_centred_default_camera():
    cam = Camera.from_image_size(640, 480)
    assert cam.fx == cam.fy == default_focal(640, 480) == 640.0
    assert (cam.cx, cam.cy) == (319.5, 239.5)
    fov = 2 * math.degrees(math.atan(640 / (2 * cam.fx)))
    assert 50 < fov < 56


def test_crop_maps_pixels_consistently():
    cam = Camera(fx=500.0, fy=500.0, cx=300.0, cy=200.0, width=640, height=480)
    pts = torch.tensor([[0.1, 0.2, 3.0], [-0.3, 0.05, 2.0]])
    full = project_points(pts, cam)
    crop = cam.crop(100.0, 50.0, 128, 128, scale=0.5)
    # Pixel-edge coordinates scale: (u + 0.5 - x0) * s - 0.5.
    expected = (full + 0.5 - torch.tensor([100.0, 50.0])) * 0.5 - 0.5
    assert torch.allclose(project_points(pts, crop), expected, atol=1e-4)


def test_weak_perspective():
    pts = torch.tensor([[[1.0, 2.0, 5.0]]])
    out = weak_perspective_project(pts, torch.tensor([10.0]), torch.tensor([[3.0, 4.0]]))
    assert torch.allclose(out, torch.tensor([[[13.0, 24.0]]]))


@pytest.mark.parametrize(
    "kwargs, message",
    [(dict(fx=0.0), "focal"), (dict(fy=-1.0), "focal"), (dict(width=0), "width"), (dict(cx=float("nan")), "cx")],
)
def test_bad_cameras_are_rejected(kwargs, message):
    fields = dict(fx=100.0, fy=100.0, cx=10.0, cy=10.0, width=20, height=20)
    fields.update(kwargs)
    with pytest.raises(ValueError, match=message):
        Camera(**fields)


def test_camera_file_round_trip_and_errors(tmp_path):
    cam = Camera(fx=400.0, fy=410.0, cx=100.0, cy=120.5, width=200, height=240)
    save_camera(cam, tmp_path / "camera.json")
    assert load_camera(tmp_path / "camera.json") == cam
    (tmp_path / "bad.json").write_text(json.dumps({"fx": 1, "fy": 1, "cx": 0, "width": 10, "height": 10}))
    with pytest.raises(ValueError, match=r"bad\.json.*cy"):
        load_camera(tmp_path / "bad.json")
    with pytest.raises(FileNotFoundError, match="missing.json"):
        load_camera(tmp_path / "missing.json")


def test_camera_from_stored_intrinsics():
    import numpy as np

    cam = Camera.from_intrinsics(np.array([500.0, 510.0, 320.0, 240.5]), np.array([640, 480]))
    assert cam == Camera(fx=500.0, fy=510.0, cx=320.0, cy=240.5, width=640, height=480)
    with pytest.raises(ValueError, match="width"):
        Camera.from_intrinsics([500.0, 500.0, 1.0, 1.0], [640.5, 480])


# --------------------------------------------------------------------------- hostile / broken files
@pytest.mark.parametrize(
    "change,expect",
    [
        ({"fx": "500"}, r"'fx' must be a finite number, got '500'"),
        (
            {"width": 100000, "height": 100000, "cx": 5e4, "cy": 5e4},
            r"100000x100000 pixels is larger than silfit accepts",
        ),
        ({"width": 9000, "height": 9000, "cx": 4500, "cy": 4500}, r"megapixels"),
        ({"width": 10**400}, r"'width' must be a finite number"),
        ({"fx": 1e-3}, r"'fx' = 0\.001 px .* times the image's longer side"),
        ({"cy": 1e9}, r"'cy' = 1e\+09 lies far outside"),
        ({"width": 64.5}, r"positive integers"),
    ],
    ids=["string", "huge", "megapixels", "big-int", "tiny-focal", "far-principal-point", "fractional"],
)
def test_bad_camera_files_name_file_and_field(tmp_path, change, expect):
    from silfit.errors import InputError

    data = dict(fx=500.0, fy=500.0, cx=319.5, cy=239.5, width=640, height=480)
    data.update(change)
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=expect) as info:
        load_camera(path)
    assert str(info.value).startswith(str(path))


def test_camera_size_limit_applies_to_every_camera():
    from silfit.io.limits import MAX_IMAGE_SIDE

    with pytest.raises(ValueError, match="larger than silfit accepts"):
        Camera.from_image_size(MAX_IMAGE_SIDE + 1, 10)
    assert Camera.from_image_size(MAX_IMAGE_SIDE, 100).width == MAX_IMAGE_SIDE
    with pytest.raises(ValueError, match="camera_intrinsics must be 4 numbers"):
        Camera.from_intrinsics([1.0, 2.0, 3.0], [10, 10])
    with pytest.raises(ValueError, match="image_size must be 2 numbers"):
        Camera.from_intrinsics([1.0, 1.0, 3.0, 3.0], ["a", "b"])
