"""Tests of hortishape.procrustes: known rigid and similarity transforms recovered, gauge, bad input."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hortishape.errors import ConvergenceWarning, HortishapeError, MeshError
from hortishape.mesh import Mesh
from hortishape.procrustes import Procrustes, generalized_procrustes, procrustes_align


def _body(n=300, seed=0):
    """An asymmetric point cloud (no rotational symmetry, so poses are identifiable)."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * [30.0, 20.0, 12.0]
    p[:, 0] += 0.02 * p[:, 1] ** 2
    return p


def _similarity(rng, scale=1.0):
    t = np.eye(4)
    t[:3, :3] = scale * Rotation.random(random_state=rng).as_matrix()
    t[:3, 3] = rng.uniform(-100, 100, size=3)
    return t


def _apply(t, p):
    return p @ t[:3, :3].T + t[:3, 3]


def test_recovers_known_rigid_transforms():
    rng = np.random.default_rng(1)
    base = _body()
    applied = np.array([_similarity(rng) for _ in range(7)])
    shapes = np.array([_apply(t, base) for t in applied])
    gpa = generalized_procrustes(shapes)
    assert isinstance(gpa, Procrustes)
    assert gpa.converged and gpa.n_iter >= 1
    assert gpa.aligned.shape == shapes.shape and gpa.transforms.shape == (7, 4, 4)
    # every aligned shape is the same shape ...
    np.testing.assert_allclose(gpa.aligned, np.broadcast_to(gpa.aligned[0], shapes.shape), atol=1e-9)
    # ... in the pose of the first input shape (the gauge), and the mean is that shape
    np.testing.assert_allclose(gpa.aligned[0], shapes[0], atol=1e-9)
    np.testing.assert_allclose(gpa.mean, shapes[0], atol=1e-9)
    # transforms[i] undoes the applied transform i (then applies the first one)
    for i in range(7):
        np.testing.assert_allclose(gpa.transforms[i] @ applied[i], applied[0], atol=1e-9)
        np.testing.assert_allclose(_apply(gpa.transforms[i], shapes[i]), gpa.aligned[i], atol=1e-9)
        r = gpa.transforms[i, :3, :3]
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)  # rigid: no scale
        assert np.linalg.det(r) > 0
        np.testing.assert_array_equal(gpa.transforms[i, 3], [0, 0, 0, 1])


def test_recovers_scale_with_scaling():
    rng = np.random.default_rng(2)
    base = _body()
    scales = np.array([1.0, 0.5, 1.7, 2.5, 0.8])
    applied = np.array([_similarity(rng, s) for s in scales])
    shapes = np.array([_apply(t, base) for t in applied])
    gpa = generalized_procrustes(shapes, scaling=True)
    np.testing.assert_allclose(gpa.aligned, np.broadcast_to(shapes[0], shapes.shape), atol=1e-9)
    for i, s in enumerate(scales):
        np.testing.assert_allclose(gpa.transforms[i] @ applied[i], applied[0], atol=1e-9)
        # the scale folded into the 3x3 block is s_0 / s_i
        found = np.linalg.det(gpa.transforms[i, :3, :3]) ** (1 / 3)
        assert found == pytest.approx(scales[0] / s, rel=1e-12)


def test_no_scaling_by_default_keeps_sizes():
    rng = np.random.default_rng(3)
    base = _body()
    shapes = np.array([_apply(_similarity(rng, s), base) for s in (1.0, 1.2, 0.9)])
    gpa = generalized_procrustes(shapes)
    for i in range(3):
        r = gpa.transforms[i, :3, :3]
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        size_in = np.linalg.norm(shapes[i] - shapes[i].mean(0))
        size_out = np.linalg.norm(gpa.aligned[i] - gpa.aligned[i].mean(0))
        assert size_out == pytest.approx(size_in, rel=1e-12)


def _noisy_population(n_shapes=8, seed=4):
    rng = np.random.default_rng(seed)
    base = _body(seed=seed)
    return np.array([
        _apply(_similarity(rng), base + rng.normal(0, 2.0, base.shape)) for _ in range(n_shapes)
    ])


def test_noisy_population_is_a_fixed_point():
    shapes = _noisy_population()
    gpa = generalized_procrustes(shapes, tol=1e-12)
    assert gpa.converged
    np.testing.assert_allclose(gpa.mean, gpa.aligned.mean(axis=0), atol=1e-12)
    # each aligned shape is optimally aligned to the mean ...
    for a in gpa.aligned:
        _, t = procrustes_align(a, gpa.mean)
        np.testing.assert_allclose(t, np.eye(4), atol=1e-6)
    # ... and the mean sits in the first shape's pose (the gauge)
    _, g = procrustes_align(gpa.mean, shapes[0])
    np.testing.assert_allclose(g, np.eye(4), atol=1e-6)


def test_gauge_is_deterministic_and_independent_of_the_order_of_the_others():
    shapes = _noisy_population()
    a = generalized_procrustes(shapes, tol=1e-12)
    b = generalized_procrustes(shapes, tol=1e-12)
    np.testing.assert_array_equal(a.aligned, b.aligned)
    order = [0, 5, 2, 7, 1, 3, 6, 4]
    c = generalized_procrustes(shapes[order], tol=1e-12)
    np.testing.assert_allclose(c.mean, a.mean, atol=1e-7)
    np.testing.assert_allclose(c.aligned, a.aligned[order], atol=1e-7)


def test_input_is_not_modified_and_meshes_are_accepted():
    shapes = _noisy_population(4)
    keep = shapes.copy()
    shapes.flags.writeable = False
    generalized_procrustes(shapes)
    np.testing.assert_array_equal(shapes, keep)
    faces = [[0, 1, 2], [1, 2, 3]]
    gpa = generalized_procrustes([Mesh(s, faces) for s in keep])
    np.testing.assert_allclose(gpa.aligned, generalized_procrustes(keep).aligned, atol=1e-12)


def test_zero_weights_ignore_outliers():
    rng = np.random.default_rng(5)
    base = _body()
    applied = [_similarity(rng) for _ in range(4)]
    shapes = np.array([_apply(t, base) for t in applied])
    shapes[1:, :10] += rng.normal(0, 50.0, size=(3, 10, 3))  # wild points on some shapes
    w = np.ones(len(base))
    w[:10] = 0.0
    gpa = generalized_procrustes(shapes, weights=w)
    for i in range(4):
        np.testing.assert_allclose(gpa.transforms[i] @ applied[i], applied[0], atol=1e-9)


def test_procrustes_align_recovers_a_known_transform():
    rng = np.random.default_rng(6)
    ref = _body()
    t = _similarity(rng)
    aligned, found = procrustes_align(_apply(t, ref), ref)
    np.testing.assert_allclose(aligned, ref, atol=1e-9)
    np.testing.assert_allclose(found @ t, np.eye(4), atol=1e-9)
    t2 = _similarity(rng, 3.0)
    aligned, found = procrustes_align(_apply(t2, ref), ref, scaling=True)
    np.testing.assert_allclose(aligned, ref, atol=1e-9)
    np.testing.assert_allclose(found @ t2, np.eye(4), atol=1e-9)


def test_convergence_warning():
    with pytest.warns(ConvergenceWarning):
        gpa = generalized_procrustes(_noisy_population(), max_iter=1, tol=1e-15)
    assert not gpa.converged and gpa.n_iter == 1


@pytest.mark.parametrize(
    "shapes, message",
    [
        (np.zeros((3, 10, 2)), "shape"),
        (np.zeros((10, 3)), "shape"),
        (np.zeros((0, 10, 3)), "empty"),
        ([np.zeros((10, 3)), np.zeros((11, 3))], "different sizes"),
        (np.full((3, 10, 3), np.nan), "NaN"),
        (np.ones((3, 2, 3)), "at least 3"),
        (np.ones((3, 10, 3)), "one place"),
        ("abc", "numeric"),
    ],
)
def test_bad_shapes(shapes, message):
    with pytest.raises(MeshError, match=message):
        generalized_procrustes(shapes)


def test_bad_options_and_meshes():
    shapes = _noisy_population(3)
    with pytest.raises(ValueError, match="weights"):
        generalized_procrustes(shapes, weights=np.ones(5))
    with pytest.raises(ValueError, match="weights"):
        generalized_procrustes(shapes, weights=-np.ones(shapes.shape[1]))
    with pytest.raises(ValueError, match="tol"):
        generalized_procrustes(shapes, tol=0.0)
    with pytest.raises(ValueError, match="max_iter"):
        generalized_procrustes(shapes, max_iter=0)
    meshes = [Mesh(shapes[0], [[0, 1, 2]]), Mesh(shapes[1], [[0, 2, 1]]), Mesh(shapes[2], [[0, 1, 2]])]
    with pytest.raises(MeshError, match="other faces"):
        generalized_procrustes(meshes)
    with pytest.raises(MeshError, match="same number"):
        procrustes_align(shapes[0], shapes[0][:-1])
    with pytest.raises(HortishapeError):
        procrustes_align(shapes, shapes[0])
