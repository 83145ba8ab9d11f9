"""Mesh files: OBJ and PLY written with the model's vertex order, read back by trimesh."""

import numpy as np
import trimesh

from silfit.io.meshes import write_obj, write_ply


def test_obj_and_ply_round_trip_keep_vertex_order(open_model, tmp_path):
    vertices = open_model().vertices[0].numpy()
    faces = open_model.faces.numpy()
    colours = np.tile(np.array([[200, 100, 50]], np.uint8), (len(vertices), 1))
    write_obj(tmp_path / "body.obj", vertices, faces)
    write_ply(tmp_path / "body.ply", vertices, faces, colours)
    for name in ("body.obj", "body.ply"):
        mesh = trimesh.load(tmp_path / name, process=False)
        assert np.allclose(mesh.vertices, vertices, atol=1e-5), name
        assert np.array_equal(mesh.faces, faces), name
    ply = trimesh.load(tmp_path / "body.ply", process=False)
    assert np.array_equal(ply.visual.vertex_colors[:, :3], colours)
