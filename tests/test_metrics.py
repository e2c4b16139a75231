"""Quality measures (paper section 3.4, Tables 1-3): known answers on synthetic shapes."""

import numpy as np
import pytest
import trimesh

from hortishape.align import rotation_about
from hortishape.errors import HortishapeError
from hortishape.metrics import compactness, dimensions, generalization, specificity, transfer_landmarks
from hortishape.model import ShapeModel
from hortishape.procrustes import procrustes_align
from hortishape.surface import barycentric_interpolate, face_normals

SPHERE = trimesh.creation.icosphere(subdivisions=2, radius=1.0)


def _hadamard(n):
    h = np.array([[1.0]])
    while len(h) < n:
        h = np.block([[h, h], [h, -h]])
    return h


@pytest.fixture(scope="module")
def known_population():
    """8 shapes whose PCA variances are exactly (40, 9, 4, 1) mm^2: Hadamard coefficients on orthonormal directions."""
    rng = np.random.default_rng(0)
    base = SPHERE.vertices * 40.0
    directions, _ = np.linalg.qr(rng.normal(size=(base.size, 4)))  # orthonormal columns in 3n space
    variances = np.array([40.0, 9.0, 4.0, 1.0])
    n = 8
    coef = _hadamard(n)[:, 1:5] * np.sqrt(variances * (n - 1) / n)  # zero-mean, orthogonal columns
    shapes = base[None] + (coef @ directions.T).reshape(n, -1, 3)
    return shapes, variances


def test_compactness_of_known_variances(known_population):
    shapes, variances = known_population
    model = ShapeModel().fit(shapes)
    np.testing.assert_allclose(model.explained_variance_, variances, rtol=1e-9)
    c = compactness(model)
    assert c.modes.tolist() == [1, 2, 3, 4]
    np.testing.assert_allclose(c.variance_mm2, variances, rtol=1e-9)
    np.testing.assert_allclose(c.cumulative_mm2, [40.0, 49.0, 53.0, 54.0], rtol=1e-9)  # eq. 14
    np.testing.assert_allclose(c.ratio, np.cumsum(variances) / 54.0, rtol=1e-9)
    assert c.ratio[-1] == pytest.approx(1.0)
    # a truncated model keeps the population's total: 2 modes describe 49 / 54
    c2 = compactness(model.truncate(2))
    np.testing.assert_allclose(c2.ratio, [40.0 / 54.0, 49.0 / 54.0], rtol=1e-9)
    # plain variances, a subset of modes
    assert compactness([6.0, 3.0, 1.0], modes=2).ratio.tolist() == [0.6, 0.9]


def test_compactness_bad_input():
    with pytest.raises(ValueError, match="largest first"):
        compactness([1.0, 3.0])
    with pytest.raises(ValueError, match="non-negative"):
        compactness([3.0, -1.0])
    with pytest.raises(ValueError, match="non-empty"):
        compactness([])
    with pytest.raises(ValueError, match="total"):
        compactness([3.0, 1.0], total=2.0)
    with pytest.raises(HortishapeError, match="1..2"):
        compactness([3.0, 1.0], modes=3)


def _family(n, rng, n_bumps=3):
    """Smooth fruit-like shapes: ellipsoids with a few random bumps, in random rigid poses."""
    v = SPHERE.vertices
    out = []
    for _ in range(n):
        directions = rng.normal(size=(n_bumps, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        radial = 1.0 + (0.08 * rng.normal(size=n_bumps) * np.exp(3.0 * (v @ directions.T - 1.0))).sum(axis=1)
        shape = v * radial[:, None] * rng.normal([40.0, 38.0, 42.0], 2.0)
        out.append(shape @ rotation_about(rng.normal(size=3), rng.normal(0.0, 0.3)).T + rng.normal(0.0, 5.0, 3))
    return np.stack(out)


def test_generalization_never_increases_with_m():
    rng = np.random.default_rng(1)
    g = generalization(_family(10, rng))
    assert g.modes.tolist() == list(range(1, 9))
    assert np.all(np.diff(g.mean_sq) <= 1e-9 * g.mean_sq[0])  # eq. 15: a projection on more modes
    assert np.all(np.diff(g.mean_mm) <= 1e-9)
    assert np.all(g.se_mm > 0) and g.per_shape_mm.shape == (10, 8)
    # noisy points: the squared norm still never increases
    noisy = generalization(10.0 * rng.normal(size=(40, 3)) + rng.normal(size=(9, 40, 3)))
    assert np.all(np.diff(noisy.mean_sq) <= 1e-9 * noisy.mean_sq[0])


def test_shape_in_the_span_of_the_others_is_reconstructed_exactly():
    """Axis scalings of a reflection-symmetric shape are Procrustes-aligned as they are, and span 3 modes."""
    rng = np.random.default_rng(2)
    base = trimesh.creation.icosphere(subdivisions=2, radius=1.0).vertices  # symmetric under x, y, z -> -x, -y, -z
    scalings = rng.normal([40.0, 36.0, 44.0], 3.0, size=(8, 3))
    shapes = np.stack([
        (base * a) @ rotation_about(rng.normal(size=3), rng.uniform(0, np.pi)).T + rng.normal(0, 20, 3)
        for a in scalings
    ])
    g = generalization(shapes)
    assert g.mean_mm[0] > 0.1 and g.mean_mm[1] > 1e-3  # one or two modes are not enough
    np.testing.assert_allclose(g.mean_mm[2:], 0.0, atol=1e-9)  # 3 modes (and more) reconstruct it exactly
    np.testing.assert_allclose(g.mean_sq[2:], 0.0, atol=1e-15)


def test_generalization_equals_a_model_built_without_each_shape():
    """The Gram-matrix leave-one-out gives what building N models does."""
    rng = np.random.default_rng(3)
    x = _family(7, rng)
    g = generalization(x, modes=[1, 3, 5])
    for i in (0, 4):
        model = ShapeModel(procrustes=True).fit(np.delete(x, i, axis=0))
        aligned, _ = procrustes_align(x[i], model.mean_)
        r = (aligned - model.mean_).reshape(-1)
        for j, m in enumerate((1, 3, 5)):
            diff = r - (model.components_[:m] @ r) @ model.components_[:m]
            assert g.per_shape_mm[i, j] == pytest.approx(np.linalg.norm(diff.reshape(-1, 3), axis=1).mean(), rel=1e-7)


def test_generalization_bad_input():
    rng = np.random.default_rng(0)
    with pytest.raises(HortishapeError, match="at least 4"):
        generalization(rng.normal(size=(3, 10, 3)))
    with pytest.raises(HortishapeError, match="1..3"):
        generalization(rng.normal(size=(5, 10, 3)), modes=4)
    with pytest.raises(HortishapeError, match=r"\(N, n, 3\)"):
        generalization(rng.normal(size=(5, 10, 2)))


def test_specificity_of_a_model_sampling_a_single_shape_is_zero():
    """The mean is a training shape; coefficients truncated to ~0 make every sample that shape."""
    rng = np.random.default_rng(4)
    c = SPHERE.vertices * 40.0
    d, e = rng.normal(size=(2,) + c.shape)
    shapes = np.stack([c, c + d, c - d, c + e, c - e])
    model = ShapeModel().fit(shapes)
    s = specificity(model, shapes, n_samples=20, truncate=1e-12, random_state=0)
    assert s.modes.tolist() == [1, 2]
    np.testing.assert_allclose(s.mean_mm, 0.0, atol=1e-9)
    np.testing.assert_allclose(s.mean_sq, 0.0, atol=1e-15)
    assert (s.nearest == 0).all()


@pytest.mark.parametrize("n_components", [None, 2])
def test_specificity_equals_brute_force(n_components):
    rng = np.random.default_rng(5)
    shapes = _family(9, rng)
    model = ShapeModel(n_components=n_components, procrustes=True).fit(shapes)
    s = specificity(model, shapes, modes=2, n_samples=30, random_state=7)
    # the training shapes in the model's frame, and the same random shapes drawn by hand
    train = np.stack([procrustes_align(x, model.mean_)[0] for x in shapes])
    gen = np.random.default_rng(7)
    for j, m in enumerate((1, 2)):
        samples = model.sample(30, modes=m, random_state=gen)
        d2 = ((samples[:, None] - train[None]) ** 2).sum(axis=(2, 3))
        near = d2.argmin(axis=1)
        assert (s.nearest[j] == near).all()
        mm = np.linalg.norm(samples - train[near], axis=2).mean(axis=1)
        assert s.mean_sq[j] == pytest.approx(d2.min(axis=1).mean(), rel=1e-9)
        assert s.mean_mm[j] == pytest.approx(mm.mean(), rel=1e-5)  # float32 shape differences
        assert s.se_mm[j] == pytest.approx(mm.std(ddof=1) / np.sqrt(30), rel=1e-3)


def test_specificity_bad_input():
    rng = np.random.default_rng(0)
    shapes = rng.normal(size=(5, 10, 3))
    model = ShapeModel().fit(shapes)
    with pytest.raises(HortishapeError, match="correspond"):
        specificity(model, shapes[:, :8])
    with pytest.raises(HortishapeError, match="1..4"):
        specificity(model, shapes, modes=5)
    with pytest.raises(ValueError, match="n_samples"):
        specificity(model, shapes, n_samples=1)


def _instances(n, rng):
    """Shapes in true correspondence (one triangulation, smooth random deformations), random poses."""
    return _family(n, rng, n_bumps=4)


def test_landmark_transfer_on_ground_truth_correspondence_is_exact():
    rng = np.random.default_rng(6)
    shapes = _instances(6, rng)
    faces = SPHERE.faces
    where = np.array([17, 250]), np.array([[0.2, 0.3, 0.5], [0.6, 0.2, 0.2]])  # two places on the surface
    given = np.stack([barycentric_interpolate(x, faces, *where) for x in shapes])  # (N, 2, 3)
    t = transfer_landmarks(shapes, faces, given, names=["stalk_tip", "bottom"])
    assert t.names == ("stalk_tip", "bottom") and t.errors_mm.shape == (6, 2)
    np.testing.assert_allclose(t.errors_mm, 0.0, atol=1e-9)
    np.testing.assert_allclose(t.surface_mm, 0.0, atol=1e-9)
    np.testing.assert_allclose(t.transferred, given, atol=1e-9)
    mean = t.on_mean  # the same place on the (default: Procrustes) mean
    from hortishape.procrustes import generalized_procrustes

    np.testing.assert_allclose(mean, barycentric_interpolate(generalized_procrustes(shapes).mean, faces, *where),
                               atol=1e-9)


def test_landmark_marked_off_the_surface_and_missing():
    rng = np.random.default_rng(7)
    shapes = _instances(5, rng)
    faces = SPHERE.faces
    f, bc = np.array([40]), np.array([[0.3, 0.3, 0.4]])
    given = []
    for x in shapes:
        p = barycentric_interpolate(x, faces, f, bc)[0]
        given.append([p + 0.5 * face_normals(x, faces)[40]])  # 0.5 mm outside, along the face normal
    given = np.array(given)
    given[2] = np.nan  # instance 2 has no landmark
    t = transfer_landmarks(shapes, faces, given)
    assert np.isnan(t.errors_mm[2, 0]) and np.isnan(t.surface_mm[2, 0])
    ok = [0, 1, 3, 4]
    np.testing.assert_allclose(t.surface_mm[ok, 0], 0.5, atol=1e-9)
    np.testing.assert_allclose(t.errors_mm[ok, 0], 0.5, atol=1e-9)  # the transfer itself is exact
    with pytest.raises(HortishapeError, match="given on no instance"):
        transfer_landmarks(shapes, faces, np.full((5, 1, 3), np.nan), names=["tip"])
    with pytest.raises(HortishapeError, match=r"\(N, L, 3\)"):
        transfer_landmarks(shapes, faces, given[:3])


def test_dimensions_of_ellipsoids_with_a_stalk():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    stalk = trimesh.creation.cylinder(radius=1.5, height=20.0, sections=12)
    stalk.apply_translation([0.0, 0.0, 40.0])  # sticks 12 mm above a 60 mm-high body
    faces = np.vstack([sphere.faces, stalk.faces + len(sphere.vertices)])
    turn = rotation_about([0, 0, 1], 0.7)
    shapes = []
    for a, b, c in [(42.0, 36.0, 30.0), (40.0, 35.0, 31.0), (44.0, 37.0, 29.0)]:
        body = sphere.vertices * [a, b, c]
        shapes.append(np.vstack([body, stalk.vertices]) @ turn.T)  # turned about the height axis
    d = dimensions(shapes, faces)
    np.testing.assert_allclose(d.per_shape[:, 0], [84.0, 80.0, 88.0], rtol=2e-3)  # width: the major axis
    np.testing.assert_allclose(d.per_shape[:, 1], [72.0, 70.0, 74.0], rtol=2e-3)
    np.testing.assert_allclose(d.per_shape[:, 2], [60.0, 62.0, 58.0], rtol=1.5e-2)  # body, without the stalk
    np.testing.assert_allclose(d.overall_height, [80.0, 81.0, 79.0], rtol=1e-9)  # from the bottom to the stalk's top
    np.testing.assert_allclose(np.abs(d.axes[0] @ turn[:, 0]), 1.0, atol=1e-6)
    assert d.mean.shape == d.sd.shape == (3,)
    with pytest.raises(ValueError, match="up"):
        dimensions(shapes, faces, up=(0, 0, 0))
