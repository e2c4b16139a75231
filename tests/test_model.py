"""Tests of hortishape.model: PCA with known answers, sampling, eq. 13 fitting, Statismo files."""

import h5py
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.special import ndtr

from hortishape.align import apply_transform, rigid_transform
from hortishape.errors import HortishapeError, MeshError, NotFittedError
from hortishape.mesh import Mesh
from hortishape.model import ShapeFit, ShapeModel, fit_pose_and_shape

TRUNC3_VAR = 1 - 2 * 3 * np.exp(-4.5) / np.sqrt(2 * np.pi) / (2 * ndtr(3.0) - 1)  # 0.9733


def _known_population(n_shapes=400, n_points=60, sigmas=(5.0, 3.0, 2.0, 1.0), seed=0):
    """mean + sum_i a_i * direction_i, a_i ~ N(0, sigma_i^2), orthonormal directions."""
    rng = np.random.default_rng(seed)
    mean = rng.normal(size=(n_points, 3)) * [40.0, 38.0, 45.0]
    directions, _ = np.linalg.qr(rng.normal(size=(3 * n_points, len(sigmas))))
    a = rng.normal(size=(n_shapes, len(sigmas))) * sigmas
    shapes = mean + (a @ directions.T).reshape(n_shapes, n_points, 3)
    return shapes, a, directions.T


def _random_pose(rng):
    return rigid_transform(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-50, 50, 3))


@pytest.fixture(scope="module")
def apples():
    """Ten synthetic apples in correspondence (ground truth), upright scanner poses."""
    synth = pytest.importorskip("hortishape.synth")
    pop = synth.make_population("apple", 10, random_state=3, n_vertices=2500, pose="upright")
    ref = pop[0]
    shapes = np.array([synth.true_correspondence(ref.canonical, p) for p in pop])
    return shapes, ref.mesh.faces


@pytest.fixture(scope="module")
def apple_model(apples):
    shapes, faces = apples
    return ShapeModel(procrustes=True).fit(shapes, faces, names=[f"apple_{i}" for i in range(len(shapes))])


# --------------------------------------------------------------------------
# PCA with known answers
# --------------------------------------------------------------------------


def test_init_only_stores_arguments():
    m = ShapeModel(0.9, procrustes=True)
    assert (m.n_components, m.procrustes) == (0.9, True)
    assert not hasattr(m, "components_")
    assert repr(m) == "ShapeModel(n_components=0.9, procrustes=True)"
    with pytest.raises(TypeError):
        ShapeModel(3, True)  # no positional booleans


def test_round_trip_with_all_modes():
    rng = np.random.default_rng(1)
    shapes = rng.normal(size=(9, 50, 3)) * 20.0 + 100.0
    model = ShapeModel().fit(shapes)
    assert model.fit(shapes) is model
    assert model.n_components_ == 8 and model.n_samples_ == 9 and model.n_points_ == 50
    coefficients = model.transform(shapes)
    assert coefficients.shape == (9, 8)
    np.testing.assert_allclose(model.inverse_transform(coefficients), shapes, atol=1e-9)
    np.testing.assert_allclose(model.project(shapes), shapes, atol=1e-9)
    np.testing.assert_allclose(model.scores_, coefficients, atol=1e-12)
    # training coefficients in standard deviations: zero mean, unit variance per mode
    np.testing.assert_allclose(coefficients.mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(coefficients.var(axis=0, ddof=1), 1.0, rtol=1e-10)
    assert model.noise_variance_ == pytest.approx(0.0, abs=1e-9)
    assert model.explained_variance_ratio_.sum() == pytest.approx(1.0, rel=1e-12)


def test_variances_and_modes_match_numpy_covariance():
    rng = np.random.default_rng(2)
    shapes = rng.normal(size=(7, 4, 3)) * [3.0, 2.0, 1.0]
    model = ShapeModel().fit(shapes)
    flat = shapes.reshape(7, 12)
    lam, vec = np.linalg.eigh(np.cov(flat, rowvar=False))  # the 12 x 12 covariance, small problem only
    lam, vec = lam[::-1][:6], vec[:, ::-1][:, :6]
    np.testing.assert_allclose(model.explained_variance_, lam, rtol=1e-10)
    np.testing.assert_allclose(np.abs(np.sum(model.components_ * vec.T, axis=1)), 1.0, atol=1e-10)
    np.testing.assert_allclose(model.components_ @ model.components_.T, np.eye(6), atol=1e-12)
    np.testing.assert_allclose(model.mean_, shapes.mean(axis=0), atol=1e-14)
    assert np.all(np.diff(model.explained_variance_) < 0)
    np.testing.assert_allclose(model.singular_values_, np.sqrt(6 * lam), rtol=1e-10)


def test_population_with_known_variances():
    sigmas = np.array([5.0, 3.0, 2.0, 1.0])
    shapes, a, directions = _known_population(sigmas=sigmas)
    model = ShapeModel().fit(shapes)
    # rank found: 4 directions of variation out of N - 1 = 399 possible
    assert model.n_components_ == 4
    # exactly the eigenvalues of the coefficients' sample covariance ...
    lam = np.linalg.eigvalsh(np.cov(a, rowvar=False))[::-1]
    np.testing.assert_allclose(model.explained_variance_, lam, rtol=1e-9)
    # ... and sigma^2 within sampling error (relative SE sqrt(2 / N) = 7 %)
    np.testing.assert_allclose(model.explained_variance_, sigmas**2, rtol=4 * np.sqrt(2 / 400))
    # the modes span the directions
    overlap = np.linalg.svd(model.components_ @ directions.T, compute_uv=False)
    np.testing.assert_allclose(overlap, 1.0, atol=1e-10)


def test_component_signs_are_deterministic():
    shapes, _, _ = _known_population(n_shapes=40)
    a = ShapeModel().fit(shapes)
    order = np.random.default_rng(3).permutation(40)
    b = ShapeModel().fit(shapes[order])
    np.testing.assert_allclose(b.components_, a.components_, atol=1e-10)
    np.testing.assert_allclose(b.scores_, a.scores_[order], atol=1e-9)
    # + grows the mean: mode 1 of a population that varies in size is "larger"
    rng = np.random.default_rng(4)
    base = rng.normal(size=(100, 3)) * [40.0, 40.0, 42.0]
    sized = base * rng.normal(1.0, 0.05, size=(12, 1, 1)) + rng.normal(0, 0.2, size=(12, 100, 3))
    model = ShapeModel().fit(sized)
    minus, plus = model.mode_shapes(0)
    assert np.ptp(plus, axis=0).prod() > np.ptp(model.mean_, axis=0).prod() > np.ptp(minus, axis=0).prod()


def test_float_and_int_n_components():
    shapes, _, _ = _known_population(n_shapes=60, sigmas=(4.0, 3.0, 2.0, 1.0))
    full = ShapeModel().fit(shapes)
    cum = np.cumsum(full.explained_variance_ratio_)
    assert ShapeModel(float(cum[1])).fit(shapes).n_components_ == 2  # "at least" that fraction
    assert ShapeModel(float(cum[1] + 1e-6)).fit(shapes).n_components_ == 3
    assert ShapeModel(0.5 * float(cum[0])).fit(shapes).n_components_ == 1
    assert ShapeModel(1.0).fit(shapes).n_components_ == 4
    two = ShapeModel(2).fit(shapes)
    assert two.n_components_ == 2 and two.components_.shape == (2, shapes.shape[1] * 3)
    np.testing.assert_allclose(two.explained_variance_ratio_, full.explained_variance_ratio_[:2])
    # the variance left out becomes the isotropic noise variance (probabilistic PCA)
    d = shapes.shape[1] * 3
    rest = full.explained_variance_[2:].sum()
    assert two.noise_variance_ == pytest.approx(rest / (d - 2), rel=1e-9)
    with pytest.raises(HortishapeError, match="only 4 modes"):
        ShapeModel(5).fit(shapes)


def test_pca_in_column_blocks_equals_the_whole(monkeypatch):
    # blocks of 7 columns (the last one shorter) against one block of all 180
    shapes, _, _ = _known_population(n_shapes=30, sigmas=(4.0, 3.0, 2.0, 1.0, 0.5))
    whole = ShapeModel().fit(shapes)
    monkeypatch.setattr("hortishape.model._BLOCK_COLUMNS", 7)
    blocks = ShapeModel().fit(shapes)
    np.testing.assert_allclose(blocks.explained_variance_, whole.explained_variance_, rtol=1e-11)
    np.testing.assert_allclose(blocks.components_, whole.components_, atol=1e-11)
    np.testing.assert_allclose(blocks.scores_, whole.scores_, atol=1e-9)
    # asking for two modes forms only two, equal to the leading two of all
    two = ShapeModel(2).fit(shapes)
    np.testing.assert_allclose(two.components_, whole.components_[:2], atol=1e-11)
    np.testing.assert_allclose(two.scores_, whole.scores_[:, :2], atol=1e-9)


def test_fit_holds_no_copy_of_the_shapes():
    # the "never an N x 3n dense copy": 200 shapes of 10,000 points
    # (48 MB); a centred copy alone would double that
    import tracemalloc

    rng = np.random.default_rng(5)
    base = rng.normal(size=(10_000, 3)) * 40.0
    shapes = base + rng.normal(size=(200, 10_000, 3))
    tracemalloc.start()
    try:
        ShapeModel(10).fit(shapes)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 0.5 * shapes.nbytes


@pytest.mark.parametrize("bad", [0, -2, 0.0, 1.5, True, "all", [3]])
def test_bad_n_components(bad):
    shapes, _, _ = _known_population(n_shapes=10)
    with pytest.raises(ValueError):
        ShapeModel(bad).fit(shapes)


# --------------------------------------------------------------------------
# scalismo vocabulary: instance, mode shapes, sample, truncate, mahalanobis
# --------------------------------------------------------------------------


def test_instance_mode_shapes_and_mahalanobis():
    shapes, _, _ = _known_population(n_shapes=50)
    model = ShapeModel().fit(shapes)
    np.testing.assert_allclose(model.instance(np.zeros(2)), model.mean_)
    c = np.array([1.5, -0.5, 2.0])
    x = model.instance(c)
    expected = model.mean_.reshape(-1) + (c * np.sqrt(model.explained_variance_[:3])) @ model.components_[:3]
    np.testing.assert_allclose(x, expected.reshape(-1, 3), atol=1e-12)
    np.testing.assert_allclose(model.transform(x)[0], [*c, 0.0], atol=1e-9)
    assert model.mahalanobis(x)[0] == pytest.approx(np.linalg.norm(c), rel=1e-9)
    minus, plus = model.mode_shapes(1, sd=2.0)
    np.testing.assert_allclose(minus, model.instance([0.0, -2.0]), atol=1e-12)
    np.testing.assert_allclose(plus, model.instance([0.0, 2.0]), atol=1e-12)
    # units: +1 SD moves the shape by sqrt(lambda) mm in total (the modes are unit vectors)
    assert np.linalg.norm(model.instance([1.0]) - model.mean_) == pytest.approx(
        np.sqrt(model.explained_variance_[0]), rel=1e-12)
    with pytest.raises(ValueError, match="mode"):
        model.mode_shapes(4)
    with pytest.raises(ValueError, match="columns"):
        model.inverse_transform(np.zeros((2, 5)))
    with pytest.raises(ValueError):
        model.instance(np.zeros((2, 2)))


def test_sample_follows_the_truncated_gaussian():
    shapes, _, _ = _known_population(n_shapes=200, sigmas=(5.0, 3.0, 2.0, 1.5, 1.0, 0.5, 0.25))
    model = ShapeModel().fit(shapes)
    n = 20000
    samples = model.sample(n, modes=5, truncate=3.0, random_state=0)
    assert samples.shape == (n, model.n_points_, 3)
    c = model.transform(samples)
    assert np.abs(c).max() <= 3.0 + 1e-9
    np.testing.assert_allclose(c[:, 5:], 0.0, atol=1e-9)  # modes beyond 5 are not varied
    np.testing.assert_allclose(c[:, :5].mean(axis=0), 0.0, atol=5 * np.sqrt(TRUNC3_VAR / n))
    np.testing.assert_allclose(c[:, :5].var(axis=0), TRUNC3_VAR, rtol=0.05)
    # in millimetres: the spread along mode i is sqrt(lambda_i) times that of c_i
    b = (samples.reshape(n, -1) - model.mean_.reshape(-1)) @ model.components_[:5].T
    np.testing.assert_allclose(b.var(axis=0), model.explained_variance_[:5] * TRUNC3_VAR, rtol=0.05)
    np.testing.assert_allclose(samples.mean(axis=0), model.mean_, atol=5 * np.sqrt(25 / n))
    # seeded: reproducible; without truncation the tails are there
    np.testing.assert_array_equal(model.sample(3, random_state=7), model.sample(3, random_state=7))
    free = model.sample_coefficients(n, modes=None, truncate=None, random_state=1)
    assert free.shape == (n, 7) and np.abs(free).max() > 3.0
    np.testing.assert_allclose(free.var(axis=0), 1.0, rtol=0.05)
    assert model.sample(0).shape == (0, model.n_points_, 3)
    # a model with fewer modes than asked uses all it has
    assert np.count_nonzero(model.truncate(2).sample_coefficients(10, modes=5, random_state=0)[0]) == 2
    with pytest.raises(ValueError):
        model.sample(-1)
    with pytest.raises(ValueError):
        model.sample(3, truncate=-1.0)
    with pytest.raises(ValueError):
        model.sample(3, modes=0)


def test_truncate_returns_a_new_model():
    shapes, _, _ = _known_population(n_shapes=50)
    model = ShapeModel().fit(shapes)
    small = model.truncate(2)
    assert small is not model and model.n_components_ == 4 and small.n_components_ == 2
    np.testing.assert_array_equal(small.components_, model.components_[:2])
    np.testing.assert_array_equal(small.explained_variance_ratio_, model.explained_variance_ratio_[:2])
    np.testing.assert_allclose(small.transform(shapes), model.transform(shapes)[:, :2])
    assert small.noise_variance_ > model.noise_variance_
    small.components_[0, 0] = 99.0  # a copy: the original is untouched
    assert model.components_[0, 0] != 99.0
    with pytest.raises(ValueError):
        model.truncate(5)


def test_procrustes_model_ignores_pose(apples):
    shapes, faces = apples
    rng = np.random.default_rng(5)
    moved = np.array([apply_transform(_random_pose(rng), s) for s in shapes])
    a = ShapeModel(procrustes=True).fit(shapes, faces)
    b = ShapeModel(procrustes=True).fit(moved, faces)
    np.testing.assert_allclose(b.explained_variance_, a.explained_variance_, rtol=1e-6)
    assert b.procrustes_transforms_.shape == (len(shapes), 4, 4)
    # new shapes are aligned onto the mean in transform(): coefficients do not depend on pose
    np.testing.assert_allclose(b.transform(moved), b.transform(shapes), atol=1e-6)
    np.testing.assert_allclose(b.transform(moved), b.scores_, atol=1e-6)
    # size stays in the model (no scaling): mode 1 is mostly size, +3 SD is larger
    minus, plus = b.mode_shapes(0)
    assert np.ptp(plus, axis=0).prod() > np.ptp(minus, axis=0).prod()


# --------------------------------------------------------------------------
# eq. 13: pose and shape of a new instance
# --------------------------------------------------------------------------


def test_fit_pose_and_shape_recovers_coefficients_and_pose(apple_model):
    rng = np.random.default_rng(6)
    model = apple_model
    truth_c = np.zeros(model.n_components_)
    truth_c[:5] = rng.uniform(-2.5, 2.5, size=5)
    pose = _random_pose(rng)
    points = apply_transform(pose, model.instance(truth_c))
    fit = fit_pose_and_shape(model, points)
    assert isinstance(fit, ShapeFit) and fit.converged
    np.testing.assert_allclose(fit.coefficients, truth_c, atol=1e-6)
    np.testing.assert_allclose(fit.pose, pose, atol=1e-8)
    assert fit.residual_max < 1e-6 and fit.residual_mean <= fit.residual_max
    np.testing.assert_allclose(fit.reconstruction, points, atol=1e-6)
    assert fit.mahalanobis == pytest.approx(np.linalg.norm(truth_c), rel=1e-6)
    # with fewer modes and scanner-like noise: close, residual at the noise level
    noisy = points + rng.normal(0, 0.2, points.shape)
    fit5 = fit_pose_and_shape(model, Mesh(noisy, model.faces_), modes=5)
    np.testing.assert_allclose(fit5.coefficients[:5], truth_c[:5], atol=0.1)
    assert np.all(fit5.coefficients[5:] == 0)
    assert 0.2 < fit5.residual_mean < 0.5


def test_fit_pose_and_shape_without_procrustes_model():
    # modes that include rigid motion (shapes in different poses, no Procrustes) make
    # pose and shape compete; the joint solve still reaches an exact fit
    shapes, _, _ = _known_population(n_shapes=12)
    rng = np.random.default_rng(7)
    moved = np.array([apply_transform(_random_pose(rng) if i % 2 else np.eye(4), s) for i, s in enumerate(shapes)])
    model = ShapeModel().fit(moved)
    target = apply_transform(_random_pose(rng), model.instance([1.0, -1.0, 0.5]))
    fit = fit_pose_and_shape(model, target)
    assert fit.converged and fit.residual_max < 1e-6


def test_fit_pose_and_shape_bad_input(apple_model):
    with pytest.raises(MeshError, match="points"):
        fit_pose_and_shape(apple_model, np.zeros((10, 3)))
    with pytest.raises(ValueError, match="modes"):
        fit_pose_and_shape(apple_model, apple_model.mean_, modes=100)
    with pytest.raises(NotFittedError):
        fit_pose_and_shape(ShapeModel(), apple_model.mean_)


# --------------------------------------------------------------------------
# model files
# --------------------------------------------------------------------------


def _fixed_string(attr_or_ds_type) -> tuple[int, int, bool]:
    return attr_or_ds_type.get_size(), attr_or_ds_type.get_strpad(), attr_or_ds_type.is_variable_str()


def test_save_load_round_trip(apple_model, tmp_path):
    model = apple_model
    path = model.save(tmp_path / "model.h5")
    assert path == tmp_path / "model.h5"
    assert [p.name for p in tmp_path.iterdir()] == ["model.h5"]  # no temporary left
    loaded = ShapeModel.load(path)
    for name in ("mean_", "components_", "explained_variance_", "explained_variance_ratio_", "scores_",
                 "faces_", "procrustes_transforms_", "singular_values_"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(model, name), err_msg=name)
    assert loaded.faces_.dtype == np.int64
    assert loaded.names_ == model.names_
    assert (loaded.n_components_, loaded.n_samples_, loaded.noise_variance_) == (
        model.n_components_, model.n_samples_, model.noise_variance_)
    assert (loaded.n_components, loaded.procrustes) == (None, True)
    np.testing.assert_array_equal(loaded.transform(model.mean_), model.transform(model.mean_))
    # saving again replaces the file
    model.truncate(3).save(path)
    assert ShapeModel.load(path).n_components_ == 3


def test_model_file_has_the_statismo_layout(apple_model, tmp_path):
    model = apple_model
    n, k, big_n = model.n_points_, model.n_components_, model.n_samples_
    m = len(model.faces_)
    path = model.save(tmp_path / "model.h5")
    with h5py.File(path, "r") as f:
        assert set(f) == {"version", "representer", "model", "modelinfo", "hortishape"}
        # /version: int32 scalars 0 and 9
        for name, value in (("majorVersion", 0), ("minorVersion", 9)):
            ds = f["version"][name]
            assert ds.shape == () and ds.dtype == np.int32 and ds[()] == value
        # /representer: fixed-length null-terminated string attributes, points and cells
        rep = f["representer"]
        expected = {"name": "vtkStandardMeshRepresenter", "version": "1.0", "datasetType": "POLYGON_MESH"}
        assert set(rep.attrs) == set(expected)
        for name, value in expected.items():
            assert rep.attrs[name] == value.encode()
            size, pad, variable = _fixed_string(rep.attrs.get_id(name).get_type())
            assert (size, pad, variable) == (len(value) + 1, h5py.h5t.STR_NULLTERM, False)
        assert set(rep) == {"points", "cells", "pointData", "cellData"}
        assert rep["points"].shape == (3, n) and rep["points"].dtype == np.float32
        np.testing.assert_allclose(rep["points"][()], model.mean_.T, rtol=1e-6)
        # int32: Statismo reads any integer type, scalismo (jhdf) only int32
        assert rep["cells"].shape == (3, m) and rep["cells"].dtype == np.int32
        np.testing.assert_array_equal(rep["cells"][()], model.faces_.T)
        # /model
        mod = f["model"]
        assert set(mod) == {"mean", "pcaBasis", "pcaVariance", "noiseVariance"}
        assert mod["mean"].shape == (3 * n,) and mod["mean"].dtype == np.float32
        np.testing.assert_allclose(mod["mean"][3:6], model.mean_[1], rtol=1e-6)  # interleaved x, y, z
        basis = mod["pcaBasis"][()]
        assert basis.shape == (3 * n, k) and basis.dtype == np.float32
        np.testing.assert_allclose(basis.astype(np.float64).T @ basis, np.eye(k), atol=1e-5)
        np.testing.assert_allclose(basis, model.components_.T, atol=1e-7)
        var = mod["pcaVariance"][()]
        assert var.shape == (k,) and var.dtype == np.float32 and np.all(np.diff(var) < 0)
        np.testing.assert_allclose(var, model.explained_variance_, rtol=1e-6)
        assert mod["noiseVariance"].shape == () and mod["noiseVariance"].dtype == np.float32
        # /modelinfo: build-time, scores K x N (columns = training shapes, in SD), builder info
        info = f["modelinfo"]
        assert {"build-time", "scores", "modelBuilder-0"} <= set(info)
        assert info["build-time"].shape == () and info["build-time"].dtype.kind == "S"
        assert info["scores"].shape == (k, big_n) and info["scores"].dtype == np.float32
        np.testing.assert_allclose(info["scores"][()], model.scores_.T, atol=1e-5)
        builder = info["modelBuilder-0"]
        assert {"builderName", "buildTime", "dataInfo", "parameters"} <= set(builder)
        uris = [builder["dataInfo"][f"URI_{i}"][()].decode() for i in range(big_n)]
        assert uris == list(model.names_)
        size, pad, variable = _fixed_string(builder["dataInfo"]["URI_0"].id.get_type())
        assert (size, pad, variable) == (len(uris[0]) + 1, h5py.h5t.STR_NULLTERM, False)
        # /hortishape: full precision and metadata
        h = f["hortishape"]
        assert h.attrs["units"] == "mm" and h.attrs["format"] == "hortishape-shape-model"
        assert bool(h.attrs["procrustes"]) is True and "hortishape_version" in h.attrs
        assert h["mean"].dtype == np.float64 and h["components"].shape == (k, 3 * n)
        assert [s.decode() for s in h["names"][()]] == list(model.names_)


def test_plain_statismo_file_loads(apple_model, tmp_path):
    model = apple_model
    path = model.save(tmp_path / "statismo.h5")
    with h5py.File(path, "a") as f:
        del f["hortishape"]
    loaded = ShapeModel.load(path)
    np.testing.assert_allclose(loaded.mean_, model.mean_, rtol=1e-6)
    np.testing.assert_allclose(loaded.components_, model.components_, atol=1e-6)
    np.testing.assert_allclose(loaded.explained_variance_, model.explained_variance_, rtol=1e-6)
    np.testing.assert_array_equal(loaded.faces_, model.faces_)
    np.testing.assert_allclose(loaded.scores_, model.scores_, atol=1e-5)
    assert loaded.names_ == model.names_ and loaded.n_samples_ == model.n_samples_
    assert loaded.procrustes is False
    np.testing.assert_allclose(loaded.instance([1.0, 2.0]), model.instance([1.0, 2.0]), atol=1e-3)


def _write_statismo(path, mean, basis, variance, *, cells=None, version=(0, 9), noise_shape=(),
                    representer="itkStandardMeshRepresenter", scores=None, cells_dtype=np.int32):
    """A Statismo/scalismo-style file written independently of hortishape."""
    with h5py.File(path, "w") as f:
        if version is not None:
            f["version/majorVersion"] = np.int32(version[0])
            f["version/minorVersion"] = np.int32(version[1])
        rep = f.create_group("representer")
        rep.attrs["name"] = representer  # variable-length string, as h5py writes by default
        rep.attrs["datasetType"] = "POLYGON_MESH" if cells is not None else "POINT_SET"
        rep["points"] = mean.reshape(-1, 3).T.astype(np.float32)
        if cells is not None:
            rep["cells"] = np.asarray(cells, dtype=cells_dtype).T
        f["model/mean"] = mean.astype(np.float32)
        f["model/pcaBasis"] = basis.astype(np.float32)
        f["model/pcaVariance"] = variance.astype(np.float32)
        f["model/noiseVariance"] = np.zeros(noise_shape, dtype=np.float32)
        f["modelinfo/build-time"] = "now"
        if scores is not None:
            f["modelinfo/scores"] = scores.astype(np.float32)


def test_scalismo_and_old_statismo_files_load(tmp_path):
    rng = np.random.default_rng(8)
    mean = rng.normal(size=30) * 10
    basis, _ = np.linalg.qr(rng.normal(size=(30, 3)))
    variance = np.array([9.0, 4.0, 1.0])
    cells = [[0, 1, 2], [2, 3, 4], [5, 6, 7]]
    # as scalismo writes it: noiseVariance of shape (1,), no scores, int32 cells
    _write_statismo(tmp_path / "scalismo.h5", mean, basis, variance, cells=cells, noise_shape=(1,))
    m = ShapeModel.load(tmp_path / "scalismo.h5")
    np.testing.assert_allclose(m.components_, basis.T, atol=1e-6)
    np.testing.assert_allclose(m.explained_variance_, variance)
    np.testing.assert_array_equal(m.faces_, cells)
    assert m.scores_ is None and m.n_samples_ is None and m.names_ is None
    # as Statismo writes it: uint32 cells, a scalar noiseVariance
    _write_statismo(tmp_path / "statismo.h5", mean, basis, variance, cells=cells, cells_dtype=np.uint32,
                    representer="vtkStandardMeshRepresenter")
    s = ShapeModel.load(tmp_path / "statismo.h5")
    np.testing.assert_array_equal(s.faces_, cells)
    assert s.faces_.dtype == np.int64
    # Statismo 0.8 stored U * sqrt(lambda); a point set has no cells
    _write_statismo(tmp_path / "old.h5", mean, basis * np.sqrt(variance), variance, version=None,
                    scores=np.arange(18.0).reshape(3, 6))
    old = ShapeModel.load(tmp_path / "old.h5")
    np.testing.assert_allclose(old.components_, basis.T, atol=1e-6)
    assert old.faces_ is None and old.n_samples_ == 6
    np.testing.assert_array_equal(old.scores_, np.arange(18.0).reshape(3, 6).T)
    # Statismo's marker for "no scores" is a 1 x 1 zero matrix
    _write_statismo(tmp_path / "noscores.h5", mean, basis, variance, scores=np.zeros((1, 1)))
    assert ShapeModel.load(tmp_path / "noscores.h5").scores_ is None


def test_load_errors(tmp_path):
    with pytest.raises(HortishapeError, match="no such file"):
        ShapeModel.load(tmp_path / "missing.h5")
    (tmp_path / "text.h5").write_text("not hdf5")
    with pytest.raises(HortishapeError, match="neither an HDF5 nor an HDF5-JSON"):
        ShapeModel.load(tmp_path / "text.h5")
    with h5py.File(tmp_path / "empty.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(HortishapeError, match="missing"):
        ShapeModel.load(tmp_path / "empty.h5")
    rng = np.random.default_rng(9)
    _write_statismo(tmp_path / "legacy.h5", rng.normal(size=12), np.eye(12)[:, :2], np.array([2.0, 1.0]),
                    representer="vtkPolyDataRepresenter")
    with pytest.raises(HortishapeError, match="legacy"):
        ShapeModel.load(tmp_path / "legacy.h5")
    model = ShapeModel().fit(rng.normal(size=(4, 5, 3)))
    with pytest.raises(HortishapeError, match="does not exist"):
        model.save(tmp_path / "no" / "such" / "model.h5")
    with pytest.raises(NotFittedError):
        ShapeModel().save(tmp_path / "model.h5")


def test_point_model_without_faces_saves_as_point_set(tmp_path):
    model = ShapeModel().fit(np.random.default_rng(10).normal(size=(5, 8, 3)))
    path = model.save(tmp_path / "points.h5")
    with h5py.File(path, "r") as f:
        assert f["representer"].attrs["datasetType"] == b"POINT_SET"
        assert "cells" not in f["representer"]
    assert ShapeModel.load(path).faces_ is None
    with pytest.raises(MeshError, match="no faces"):
        model.to_mesh(model.mean_)


# --------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------


def test_meshes_as_input_and_inputs_not_modified(apples):
    shapes, faces = apples
    meshes = [Mesh(s, faces) for s in shapes[:4]]
    model = ShapeModel().fit(meshes)
    np.testing.assert_array_equal(model.faces_, faces)
    arr = shapes[:4].copy()
    arr.flags.writeable = False
    other = ShapeModel().fit(arr, faces)
    np.testing.assert_array_equal(arr, shapes[:4])
    np.testing.assert_allclose(other.components_, model.components_, atol=1e-12)
    np.testing.assert_allclose(model.transform(meshes[1]), model.transform(shapes[1]))
    assert model.to_mesh(model.mean_).n_faces == len(faces)


def test_bad_input():
    rng = np.random.default_rng(11)
    good = rng.normal(size=(5, 10, 3))
    with pytest.raises(MeshError, match="at least 3"):
        ShapeModel().fit(good[:2])
    with pytest.raises(HortishapeError):  # the documented base class
        ShapeModel().fit(good[:2])
    with pytest.raises(MeshError, match="different sizes"):
        ShapeModel().fit([good[0], good[1], good[2][:9]])
    bad = good.copy()
    bad[2, 3, 1] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        ShapeModel().fit(bad)
    with pytest.raises(MeshError, match="shape"):
        ShapeModel().fit(good[..., :2])
    with pytest.raises(MeshError, match="no variation"):
        ShapeModel().fit(np.broadcast_to(good[0], (4, 10, 3)))
    with pytest.raises(MeshError):
        ShapeModel().fit(good, faces=[[0, 1, 20]])
    with pytest.raises(MeshError, match="other faces"):
        ShapeModel().fit([Mesh(good[0], [[0, 1, 2]]), Mesh(good[1], [[0, 1, 3]]), Mesh(good[2], [[0, 1, 2]])])
    with pytest.raises(ValueError, match="names"):
        ShapeModel().fit(good, names=["a", "b"])
    model = ShapeModel().fit(good)
    with pytest.raises(MeshError, match="points"):
        model.transform(good[:, :9])
    with pytest.raises(ValueError, match="NaN"):
        model.inverse_transform([np.nan])


@pytest.mark.parametrize(
    "call",
    [
        lambda m: m.transform(np.zeros((3, 10, 3))),
        lambda m: m.inverse_transform([[0.0]]),
        lambda m: m.project(np.zeros((3, 10, 3))),
        lambda m: m.mahalanobis(np.zeros((3, 10, 3))),
        lambda m: m.instance([0.0]),
        lambda m: m.sample(2),
        lambda m: m.mode_shapes(0),
        lambda m: m.truncate(1),
        lambda m: m.n_points_,
    ],
)
def test_unfitted_use_raises(call):
    with pytest.raises(NotFittedError, match="not fitted"):
        call(ShapeModel())
