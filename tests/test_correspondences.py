"""Tests of hortishape.registration.correspondences: normal-ray casting and its three filters."""

import numpy as np
import pytest
import trimesh

from hortishape.registration.correspondences import (
    CROSSING,
    DISTANCE,
    KEPT,
    NO_HIT,
    NORMAL,
    RayScene,
    correspond,
    find_correspondences,
    prepare_target,
)
from hortishape.errors import MeshError
from hortishape.mesh import Mesh
from hortishape.surface import vertex_normals


def sphere(radius, centre=(0.0, 0.0, 0.0), level=4):
    s = trimesh.creation.icosphere(level, radius=radius)
    return Mesh(s.vertices + np.asarray(centre), s.faces)


def _vertex_at(mesh, direction):
    return int(np.argmax(mesh.vertices @ np.asarray(direction, dtype=float)))


def test_concentric_spheres_outward_and_inward():
    src = sphere(10.0)
    c = correspond(src, sphere(12.0, level=5))
    assert c.found.all() and (c.status == KEPT).all()
    np.testing.assert_allclose(c.distances, 2.0, atol=0.05)
    np.testing.assert_allclose(np.linalg.norm(c.points, axis=1), 12.0, atol=0.05)
    # target inside the source: the inward ray is used
    c2 = correspond(src, sphere(8.0, level=5))
    assert c2.found.all()
    np.testing.assert_allclose(np.linalg.norm(c2.points, axis=1), 8.0, atol=0.05)


def test_filter_a_normal_rejects_opposite_facing_surface():
    src = sphere(10.0)
    # the top vertex's outward ray meets the underside of a small sphere above it:
    # the target normal there points down, opposite to the source normal
    tgt = sphere(3.0, centre=(0.0, 0.0, 20.0))
    top = _vertex_at(src, [0, 0, 1])
    c = correspond(src, tgt)
    assert c.status[top] == NORMAL and not c.found[top]
    # a wide tolerance lets it through
    c180 = correspond(src, tgt, max_angle=180.0)
    assert c180.found[top]
    # a vertex on the equator: neither ray meets the small sphere
    side = _vertex_at(src, [1, 0, 0])
    assert c.status[side] == NO_HIT


def test_filter_b_distance():
    src = sphere(10.0)
    tgt = sphere(12.0, level=5)
    c = correspond(src, tgt, max_distance=1.5)
    assert not c.found.any() and (c.status == DISTANCE).all()
    assert correspond(src, tgt, max_distance=2.5).found.all()


def test_filter_c_ray_crossing_the_source_first():
    src = sphere(10.0)
    # target beside the source: the leftmost vertex's inward ray passes through the
    # source before reaching it; its normals agree and there is no distance limit
    tgt = sphere(3.0, centre=(25.0, 0.0, 0.0))
    left = _vertex_at(src, [-1, 0, 0])
    c = correspond(src, tgt)
    assert c.status[left] == CROSSING and not c.found[left]
    c_off = correspond(src, tgt, check_crossings=False)
    assert c_off.found[left]
    np.testing.assert_allclose(c_off.points[left], [22.0, 0.0, 0.0], atol=0.05)
    # the rightmost vertex sees the target's facing side, whose normal opposes
    right = _vertex_at(src, [1, 0, 0])
    assert c.status[right] == NORMAL


def test_filter_c_skips_rays_shorter_than_crossing_min_distance():
    # the longest kept ray (the left vertex's, crossing) is 32 mm long: a
    # limit below that still runs the test, one above it does not
    src = sphere(10.0)
    tgt = prepare_target(sphere(3.0, centre=(25.0, 0.0, 0.0)))
    left = _vertex_at(src, [-1, 0, 0])
    n = vertex_normals(src.vertices, src.faces)
    near = find_correspondences(src.vertices, src.faces, n, tgt, crossing_min_distance=30.0)
    assert near.status[left] == CROSSING
    far = find_correspondences(src.vertices, src.faces, n, tgt, crossing_min_distance=35.0)
    assert far.found[left]
    np.testing.assert_allclose(far.distances[left], 32.0, atol=0.05)


def test_target_crossed_first_is_rejected():
    # a thin shell: the outward ray of the inner sphere first meets the inner
    # wall of a hollow target; only that first hit may be used
    src = sphere(10.0)
    a = trimesh.creation.icosphere(4, radius=14.0)
    b = trimesh.creation.icosphere(4, radius=16.0)
    b.faces = b.faces[:, ::-1]
    shell = trimesh.util.concatenate([a, b])
    with pytest.raises(MeshError, match="components"):
        prepare_target(Mesh(shell.vertices, shell.faces))


def test_prepared_target_reused_and_inputs_unchanged():
    src = sphere(10.0)
    tgt_mesh = sphere(11.0)
    tgt = prepare_target(tgt_mesh)
    before = src.vertices.copy()
    a = correspond(src, tgt)
    b = correspond(src, tgt_mesh)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(src.vertices, before)
    assert a.kept_fraction == 1.0 and np.isclose(a.mean_distance, 1.0, atol=0.05)


def test_ray_scene_max_distance():
    s = sphere(10.0)
    scene = RayScene(s.vertices, s.faces)
    o = np.zeros((3, 3))
    d = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    face, t, _ = scene.first_hit(o, d)
    assert (face >= 0).all()
    np.testing.assert_allclose(t, 10.0, atol=0.05)
    # a limit just at the hit keeps it (no float32 cut), a shorter one drops it
    face2, t2, bary2 = scene.first_hit(o, d, max_distance=[t[0], 9.0, np.inf])
    assert face2.tolist() == [face[0], -1, face[2]]
    assert t2[1] == np.inf and not bary2[1].any()
    np.testing.assert_allclose(t2[[0, 2]], t[[0, 2]])


def _random_rays(n, seed=0):
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3)) * 4.0
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True), rng.uniform(5.0, 20.0, n)


def test_a_scene_for_few_queries_gives_embreex_hits():
    from hortishape.registration import _embree

    if _embree.library() is None:
        pytest.skip("Embree's C library is not reachable here (embreex is used instead)")
    s = sphere(10.0, level=5)
    o, d, limit = _random_rays(1000 + 5)  # a last packet of 5 rays
    packets = RayScene(s.vertices, s.faces, few_queries=True)
    assert packets._packets is not None
    for lim in (None, limit):
        a = RayScene(s.vertices, s.faces).first_hit(o, d, max_distance=lim)
        b = packets.first_hit(o, d, max_distance=lim)
        assert (a[0] >= 0).any() and (a[0] < 0).any()
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)


def test_without_embree_the_fallback_finds_the_same_hits(monkeypatch):
    import sys

    s = sphere(10.0, level=2)
    o, d, limit = _random_rays(50)
    embree = RayScene(s.vertices, s.faces).first_hit(o, d, max_distance=limit)
    from hortishape.registration import correspondences

    monkeypatch.setitem(sys.modules, "embreex", None)  # import embreex now raises ImportError
    monkeypatch.setattr(correspondences, "_embree_library", lambda: None)
    scene = RayScene(s.vertices, s.faces, few_queries=True)
    assert scene._scene is None and scene._packets is None
    face, t, bary = scene.first_hit(o, d, max_distance=limit)
    assert (face >= 0).sum() > 10
    np.testing.assert_array_equal(face, embree[0])
    np.testing.assert_allclose(t, embree[1], atol=1e-4)  # Embree's barycentrics are float32
    np.testing.assert_allclose(bary, embree[2], atol=1e-4)


def test_ray_scene_threads_give_the_same_hits(monkeypatch):
    from hortishape.registration import correspondences

    s = sphere(10.0, level=5)
    scene = RayScene(s.vertices, s.faces)
    rng = np.random.default_rng(0)
    n = 4 * correspondences.RAY_THREAD_MIN + 7  # parts of unequal length
    o = rng.normal(size=(n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    limit = rng.uniform(5.0, 20.0, n)
    monkeypatch.setattr(correspondences, "_ray_threads", lambda k: 1)
    one = scene.first_hit(o, d, max_distance=limit)
    monkeypatch.setattr(correspondences, "_ray_threads", lambda k: 4)  # whatever this machine's cores
    split = scene.first_hit(o, d, max_distance=limit)
    assert (one[0] >= 0).any() and (one[0] < 0).any()
    for a, b in zip(one, split):
        np.testing.assert_array_equal(a, b)
