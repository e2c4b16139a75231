"""Tests of hortishape.mesh: the Mesh type and its checks."""

import numpy as np
import pytest

from hortishape.errors import MeshError
from hortishape.mesh import Mesh, check_mesh, unique_edges

TETRA_V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
TETRA_F = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]


def test_mesh_is_a_read_only_copy_in_the_given_order():
    v = np.array(TETRA_V, dtype=np.float32)
    f = np.array(TETRA_F, dtype=np.int32)
    m = Mesh(v, f)
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    assert (m.n_vertices, m.n_faces) == (4, 4)
    np.testing.assert_array_equal(m.vertices, v)  # no vertex merged, dropped or reordered
    with pytest.raises(ValueError):
        m.vertices[0, 0] = 5.0
    v[0, 0] = 9.0  # the caller's array is not shared
    assert m.vertices[0, 0] == 0.0


def test_edges_of_a_tetrahedron():
    # 6 edges, each once, smaller index first, sorted
    assert Mesh(TETRA_V, TETRA_F).edges().tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]
    assert unique_edges(np.zeros((0, 3), dtype=np.int64)).shape == (0, 2)


def test_with_vertices_keeps_the_faces_and_checks_the_count():
    m = Mesh(TETRA_V, TETRA_F)
    moved = m.with_vertices(np.asarray(TETRA_V) * 2.0)
    np.testing.assert_array_equal(moved.faces, m.faces)
    assert moved.vertices[3, 2] == 2.0
    with pytest.raises(MeshError, match="expected"):
        m.with_vertices(TETRA_V[:3])


def test_to_trimesh_keeps_the_vertex_order():
    v = np.array(TETRA_V + [[0, 0, 0]], dtype=float)  # a duplicate vertex trimesh would merge when processing
    m = Mesh(v, TETRA_F)
    t = m.to_trimesh()
    assert len(t.vertices) == 5
    np.testing.assert_array_equal(t.vertices, v)


@pytest.mark.parametrize(
    "vertices, faces, message",
    [
        ([[0, 0]], [[0, 0, 0]], "shape"),
        (np.zeros((0, 3)), [[0, 1, 2]], "no vertices"),
        (TETRA_V, np.zeros((0, 3)), "point cloud is not a surface"),
        (TETRA_V, [[0, 1]], "triangles"),
        ([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], "1 vertices have NaN"),
        (TETRA_V, [[0, 1, 4]], r"\[0, 3\]"),
        (TETRA_V, [[0, 1, -1]], r"\[0, 3\]"),
        ([["a", "b", "c"]], [[0, 0, 0]], "numeric"),
    ],
)
def test_bad_arrays_name_the_mesh_and_the_problem(vertices, faces, message):
    with pytest.raises(MeshError, match=message) as exc:
        check_mesh(vertices, faces, name="scan_7.ply")
    assert str(exc.value).startswith("scan_7.ply: ")
