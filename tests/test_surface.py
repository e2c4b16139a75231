"""Tests of hortishape.surface: remeshing, normals, closest points, checks."""

import numpy as np
import pytest
import trimesh

from hortishape.errors import MeshError
from hortishape.mesh import Mesh
from hortishape.surface import (
    barycentric_interpolate,
    check_closed_surface,
    closest_points,
    face_areas,
    remesh,
    vertex_normals,
)


@pytest.fixture(scope="module")
def ellipsoid():
    s = trimesh.creation.icosphere(5)
    return Mesh(s.vertices * [40.0, 30.0, 25.0], s.faces)


def test_remesh_exact_count_uniform_closed_and_mapped(ellipsoid):
    r = remesh(ellipsoid, 3000)
    m = r.mesh
    assert m.n_vertices == 3000
    assert check_closed_surface(m) == 1.0
    # area preserved (within 1%) and edges uniform
    a0 = face_areas(ellipsoid.vertices, ellipsoid.faces).sum()
    assert abs(face_areas(m.vertices, m.faces).sum() / a0 - 1) < 0.01
    e = m.edges()
    lengths = np.linalg.norm(m.vertices[e[:, 0]] - m.vertices[e[:, 1]], axis=1)
    assert lengths.std() / lengths.mean() < 0.2
    # the map reproduces the new vertices from the input
    back = barycentric_interpolate(ellipsoid.vertices, ellipsoid.faces, r.face_index, r.barycentric)
    np.testing.assert_allclose(back, m.vertices, atol=1e-9)


def test_remesh_rejects_open_surface(ellipsoid):
    with pytest.raises(MeshError, match="not closed"):
        remesh(Mesh(ellipsoid.vertices, ellipsoid.faces[10:]), 1000)


def test_vertex_normals_point_outward(ellipsoid):
    n = vertex_normals(ellipsoid.vertices, ellipsoid.faces)
    assert (np.einsum("ij,ij->i", n, ellipsoid.vertices) > 0).all()


def test_closest_points_on_sphere():
    s = trimesh.creation.icosphere(5, radius=10.0)
    m = Mesh(s.vertices, s.faces)
    q = np.array([[0.0, 0.0, 20.0], [3.0, 0.0, 0.0]])
    cp = closest_points(m, q)
    np.testing.assert_allclose(cp.distances, [10.0, 7.0], atol=0.02)
    back = barycentric_interpolate(m.vertices, m.faces, cp.face_index, cp.barycentric)
    np.testing.assert_allclose(back, cp.points, atol=1e-9)


def test_check_closed_surface_errors():
    s = trimesh.creation.icosphere(2)
    two = trimesh.util.concatenate([s, s.copy().apply_translation([5, 0, 0])])
    with pytest.raises(MeshError, match="2 connected components"):
        check_closed_surface(Mesh(two.vertices, two.faces))
    v = np.vstack([s.vertices, [[5.0, 5.0, 5.0]]])
    f2 = np.vstack([s.faces, [[0, 0, 1]]])
    with pytest.raises(MeshError):
        check_closed_surface(Mesh(v, s.faces))  # an unused vertex
    with pytest.raises(MeshError):
        check_closed_surface(Mesh(s.vertices, f2))  # non-manifold
    flipped = Mesh(s.vertices, s.faces[:, ::-1])
    assert check_closed_surface(flipped) == -1.0
