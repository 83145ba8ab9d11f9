"""``silfit.outputs.export``: GLB / PLY in the upright world frame, read back by trimesh; the animated
glTF of a video holds every frame (decoded here from the file's own accessors)."""

import json
import struct

import numpy as np
import pytest
import torch
import trimesh

from silfit.camera import Camera
from silfit.outputs.export import parse_formats, to_upright, vertex_normals, write_fit_exports, write_glb


def glb_json_and_blob(path):
    data = path.read_bytes()
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and total == len(data)
    n, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON"
    gltf = json.loads(data[20 : 20 + n])
    m, kind = struct.unpack_from("<I4s", data, 20 + n)
    assert kind == b"BIN\0"
    return gltf, data[28 + n : 28 + n + m]


def accessor(gltf, blob, index):
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    dtype = {5126: np.float32, 5125: np.uint32}[acc["componentType"]]
    width = {"SCALAR": 1, "VEC3": 3}[acc["type"]]
    arr = np.frombuffer(blob, dtype, acc["count"] * width, view["byteOffset"])
    return arr.reshape(acc["count"], width) if width > 1 else arr


@pytest.fixture(scope="module")
def posed(open_model):
    """The open body standing 3 m in front of an OpenCV camera (head towards -y in the image frame)."""
    with torch.no_grad():
        out = open_model(global_orient=torch.tensor([[np.pi, 0.0, 0.0]]), transl=torch.tensor([[0.0, 0.2, 3.0]]))
    names = list(open_model.joint_names)
    return out.vertices[0].double().numpy(), open_model.faces.numpy(), names, out.joints[0].double().numpy()


def test_glb_is_upright_with_normals_and_the_camera(posed, tmp_path):
    v, f, names, joints = posed
    cam = Camera.from_image_size(320, 240)
    write_glb(tmp_path / "body.glb", v, f, cam)
    scene = trimesh.load(tmp_path / "body.glb", process=False)
    mesh = scene.geometry["body"]
    assert np.allclose(mesh.vertices, to_upright(v), atol=1e-5) and np.array_equal(mesh.faces, f)
    head, foot = to_upright(joints[names.index("head")]), to_upright(joints[names.index("left_ankle")])
    assert head[1] > foot[1] + 1.0  # head up (+Y); in the camera frame it is the other way round
    assert joints[names.index("head")][1] < joints[names.index("left_ankle")][1]
    top = mesh.vertices[:, 1].argmax()
    assert mesh.vertex_normals[top][1] > 0.9  # outward normals, stored in the file
    gltf, _ = glb_json_and_blob(tmp_path / "body.glb")
    assert "NORMAL" in gltf["meshes"][0]["primitives"][0]["attributes"]
    assert "camera" in scene.graph.nodes
    intr = gltf["cameras"][0]["extras"]["intrinsics"]
    assert intr["fx"] == cam.fx and intr["width"] == 320
    assert gltf["cameras"][0]["perspective"]["yfov"] == pytest.approx(2 * np.arctan(120 / cam.fy))
    assert mesh.vertices[:, 2].max() < 0  # in front of the camera, which looks down -z


def test_animated_glb_holds_every_frame(posed, tmp_path):
    v, f, _, _ = posed
    frames = np.stack([v + [0.05 * k, 0.0, 0.0] for k in range(4)])
    frames[2, 0] += 0.3  # one vertex moves alone in frame 2
    write_glb(
        tmp_path / "anim.glb", frames, f, Camera.from_image_size(320, 240), fps=10, frame_numbers=[10, 11, 12, 13]
    )
    gltf, blob = glb_json_and_blob(tmp_path / "anim.glb")
    prim = gltf["meshes"][0]["primitives"][0]
    base = accessor(gltf, blob, prim["attributes"]["POSITION"])
    sampler = gltf["animations"][0]["samplers"][0]
    times, weights = accessor(gltf, blob, sampler["input"]), accessor(gltf, blob, sampler["output"]).reshape(4, -1)
    assert len(prim["targets"]) == 4 and np.allclose(times, [0, 0.1, 0.2, 0.3]) and sampler["interpolation"] == "STEP"
    for k in range(4):
        shown = base + sum(w * accessor(gltf, blob, t["POSITION"]) for w, t in zip(weights[k], prim["targets"]))
        assert np.allclose(shown, to_upright(frames[k]), atol=1e-5), k
    assert gltf["meshes"][0]["extras"]["targetNames"] == [f"frame_{n}" for n in (10, 11, 12, 13)]
    scene = trimesh.load(tmp_path / "anim.glb", process=False)  # trimesh reads it (the base frame)
    assert np.allclose(scene.geometry["body"].vertices, to_upright(frames[0]), atol=1e-5)


def test_ply_is_upright_with_normals(posed, tmp_path):
    v, f, _, _ = posed
    write_fit_exports(tmp_path, v, f, Camera.from_image_size(320, 240), ("ply",))
    text = (tmp_path / "mesh.ply").read_text()
    assert "comment silfit upright camera frame" in text and "property float nx" in text
    mesh = trimesh.load(tmp_path / "mesh.ply", process=False)
    assert np.allclose(mesh.vertices, to_upright(v), atol=1e-5) and np.array_equal(mesh.faces, f)
    normals = np.loadtxt(
        tmp_path / "mesh.ply", skiprows=text[: text.index("end_header")].count("\n") + 1, max_rows=len(v)
    )[:, 3:6]
    assert np.allclose(normals, vertex_normals(to_upright(v), f), atol=1e-5)


def test_normals_point_outward_and_match_batched(posed):
    v, f, _, _ = posed
    n = vertex_normals(v, f)
    centre = v.mean(0)
    assert ((v - centre) * n).sum(1).mean() > 0  # outward on average
    assert np.allclose(vertex_normals(np.stack([v, v * 2.0]), f)[1], n)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)


def test_parse_formats():
    assert parse_formats("glb,ply") == ("glb", "ply") and parse_formats("PLY") == ("ply",) and parse_formats(None) == ()
    for bad in ("obj", "glb,", ","):
        with pytest.raises(ValueError, match="--export"):
            parse_formats(bad)
