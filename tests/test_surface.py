"""Tests of hortishape.surface: remeshing, normals, closest points, checks."""

import numpy as np
import pytest
import trimesh

from hortishape.errors import MeshError
from hortishape.mesh import Mesh
from hortishape.surface import (
    barycentric_interpolate,
    boundary_loops,
    check_closed_surface,
    checked_surface,
    closest_points,
    component_labels,
    face_areas,
    fill_holes,
    remesh,
    signed_volume,
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


def test_component_labels_agree_with_a_graph_search():
    # pieces of random sizes, vertices numbered at random, a few used by no face, and a fan
    # whose hub has the largest number (the case where joining one root at a time would crawl)
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(5)
    for _ in range(60):
        pieces, n = [], 0
        for _ in range(rng.integers(1, 6)):
            s = trimesh.creation.icosphere(int(rng.integers(0, 3)))
            pieces.append(np.asarray(s.faces) + n)
            n += len(s.vertices)
        rim = int(rng.integers(3, 200))
        pieces.append(np.stack([np.arange(rim) + n, (np.arange(rim) + 1) % rim + n, np.full(rim, n + rim)], axis=1))
        n += rim + 1 + int(rng.integers(0, 4))
        faces = rng.permutation(n)[np.concatenate(pieces)]
        graph = sp.csr_matrix((np.ones(3 * len(faces)), (faces.ravel(), faces[:, [1, 2, 0]].ravel())), shape=(n, n))
        expected_n, expected = connected_components(graph, directed=False)
        got_n, got = component_labels(faces, n)
        assert got_n == expected_n
        np.testing.assert_array_equal(got, expected)


def _without(mesh: trimesh.Trimesh, drop: np.ndarray) -> Mesh:
    """``mesh`` without the faces ``drop``, and without the vertices no face uses then."""
    cut = trimesh.Trimesh(mesh.vertices, mesh.faces[~drop], process=False)
    cut.remove_unreferenced_vertices()
    return Mesh(cut.vertices, cut.faces)


def test_a_hole_is_closed_by_a_patch_that_continues_the_surface():
    # an apple-sized sphere missing a cap of 5 % of its surface (3.5 mm high)
    sphere = trimesh.creation.icosphere(5, radius=35.0)
    scan = _without(sphere, sphere.triangles_center[:, 2] > 35.0 * 0.9)
    sign, loops = checked_surface(scan, allow_holes=True)
    assert sign == 1.0 and len(loops) == 1
    with pytest.raises(MeshError, match="not closed"):
        check_closed_surface(scan)
    out = fill_holes(scan)
    assert check_closed_surface(out.mesh) == 1.0 and out.n_holes == 1
    # the input first and unchanged, the patch after it
    np.testing.assert_array_equal(out.mesh.vertices[: scan.n_vertices], scan.vertices)
    np.testing.assert_array_equal(out.mesh.faces[: len(scan.faces)], scan.faces)
    assert not out.filled[: len(scan.faces)].any() and out.filled[len(scan.faces):].all()
    assert out.n_input_vertices == scan.n_vertices
    assert out.hole_share == pytest.approx(0.05, abs=0.005)
    # a flat cap would lie 3.5 mm inside the sphere; the patch is within 0.5 mm of it (measured 0.32)
    radius = np.linalg.norm(out.mesh.vertices[scan.n_vertices:], axis=1)
    assert np.abs(radius - 35.0).max() < 0.5
    assert abs(signed_volume(out.mesh.vertices, out.mesh.faces)) == pytest.approx(4 / 3 * np.pi * 35.0**3, rel=2e-3)


def test_several_holes_and_holes_that_touch():
    sphere = trimesh.creation.icosphere(4, radius=30.0)
    z = sphere.triangles_center[:, 2]
    scan = _without(sphere, (z > 27.0) | (z < -28.0))
    loops = boundary_loops(scan.faces, scan.n_vertices)
    assert len(loops) == 2
    # each rim runs the way its faces wind: every step is an edge of a face
    edges = {tuple(e) for e in np.vstack([scan.faces[:, [0, 1]], scan.faces[:, [1, 2]], scan.faces[:, [2, 0]]])}
    assert all((a, b) in edges for lp in loops for a, b in zip(lp, np.roll(lp, -1)))
    assert fill_holes(scan).n_holes == 2
    assert fill_holes(Mesh(sphere.vertices, sphere.faces)).n_holes == 0
    # two faces apart at one vertex: two holes meeting there
    v0 = sphere.faces[0, 0]
    around = np.flatnonzero((sphere.faces == v0).any(axis=1))
    ring = [f for f in around if not set(sphere.faces[f]) & (set(sphere.faces[around[0]]) - {v0})]
    drop = np.zeros(len(sphere.faces), dtype=bool)
    drop[[around[0], ring[0]]] = True
    with pytest.raises(MeshError, match="touch at a vertex"):
        fill_holes(Mesh(sphere.vertices, sphere.faces[~drop]))


def test_int32_faces_of_a_large_open_surface_name_its_holes():
    from hortishape.surface import _checked_arrays

    # 163,842 vertices: an edge key (vertex * n + vertex) overflows int32
    s = trimesh.creation.icosphere(7)
    faces = s.faces.astype(np.int32)
    assert _checked_arrays(s.vertices, faces, name="ball", allow_degenerate=False, allow_holes=False)[0] == 1.0
    with pytest.raises(MeshError, match=r"ball: the surface is not closed \(3 boundary edges\)"):
        _checked_arrays(s.vertices, faces[1:], name="ball", allow_degenerate=False, allow_holes=False)
