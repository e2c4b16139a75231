"""Tests of hortishape.statismo: Statismo/Scalismo model files, HDF5 and HDF5-JSON, both ways."""

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from hortishape.errors import HortishapeError
from hortishape.model import ShapeModel
from hortishape.statismo import H5Tree, model_format, read_tree, write_tree

DATA = Path(__file__).parent / "data" / "scalismo"
SCALISMO_H5 = DATA / "asmData_model.h5"  # written by Scalismo (see SOURCE.md)
SCALISMO_JSON = DATA / "hdf5json_sampleFile.json"  # HDF5-JSON, Scalismo 0.92+'s form


def _raw_h5(path):
    with h5py.File(path, "r") as f:
        return {k: f[k][()] for k in ("model/mean", "model/pcaBasis", "model/pcaVariance", "representer/cells")}


def test_a_model_scalismo_wrote_loads_with_scalismos_numbers():
    raw = _raw_h5(SCALISMO_H5)
    m = ShapeModel.load(SCALISMO_H5)
    # Scalismo's model: the stored mean, basis columns and variances (float32), the cells as triangles
    assert m.mean_.shape == (1400, 3) and m.faces_.shape == (2800, 3) and m.n_components_ == 50
    np.testing.assert_array_equal(m.mean_, raw["model/mean"].astype(np.float64).reshape(-1, 3))
    order = np.argsort(-raw["model/pcaVariance"], kind="stable")
    np.testing.assert_array_equal(m.explained_variance_, raw["model/pcaVariance"][order].astype(np.float64))
    np.testing.assert_array_equal(m.components_, raw["model/pcaBasis"][:, order].T.astype(np.float64))
    np.testing.assert_array_equal(m.faces_, raw["representer/cells"].T)
    # what the file lacks is absent, not invented
    assert m.scores_ is None and m.n_samples_ is None and m.names_ is None
    # the +3 SD instance of mode 1, as Scalismo computes it: mean + 3 sqrt(lambda_1) u_1
    inst = m.instance(np.r_[3.0, np.zeros(49)])
    u = raw["model/pcaBasis"][:, order[0]].astype(np.float64)
    expected = raw["model/mean"].astype(np.float64) + 3.0 * np.sqrt(float(raw["model/pcaVariance"][order[0]])) * u
    np.testing.assert_allclose(inst.reshape(-1), expected, atol=1e-9)


def test_an_hdf5_json_model_loads():
    doc = json.loads(SCALISMO_JSON.read_text())
    values = {d["alias"][0]: d["value"] for d in doc["datasets"].values()}
    assert model_format(SCALISMO_JSON) == "json"
    m = ShapeModel.load(SCALISMO_JSON)
    np.testing.assert_array_equal(m.mean_.reshape(-1), np.float32(values["/model/mean"]).astype(np.float64))
    np.testing.assert_array_equal(m.faces_, np.array(values["/representer/cells"]).T)
    variances = np.float32(values["/model/pcaVariance"]).astype(np.float64)
    order = np.argsort(-variances, kind="stable")
    np.testing.assert_array_equal(m.explained_variance_, variances[order])
    np.testing.assert_array_equal(m.components_, np.float32(values["/model/pcaBasis"]).astype(np.float64)[:, order].T)


def test_the_form_is_told_by_the_content_not_the_name(tmp_path):
    renamed = tmp_path / "model.h5"
    renamed.write_bytes(b"\xef\xbb\xbf" + SCALISMO_JSON.read_bytes())  # with a byte-order mark
    np.testing.assert_array_equal(ShapeModel.load(renamed).mean_, ShapeModel.load(SCALISMO_JSON).mean_)
    h5_named_json = tmp_path / "model.json"
    h5_named_json.write_bytes(SCALISMO_H5.read_bytes())
    assert model_format(h5_named_json) == "hdf5"
    assert ShapeModel.load(h5_named_json).n_components_ == 50


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(3)
    base = np.random.default_rng(0).normal(size=(40, 3)) * 20
    shapes = base + rng.normal(size=(12, 40, 3)) * [3.0, 2.0, 1.0]
    faces = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]])
    return ShapeModel(n_components=5).fit(shapes, faces, names=[f"apple_{i}" for i in range(12)])


@pytest.mark.parametrize("form", ["hdf5", "json"])
def test_round_trip_keeps_everything(fitted, tmp_path, form):
    path = fitted.save(tmp_path / "model.bin", format=form)
    assert model_format(path) == form
    back = ShapeModel.load(path)
    for key in ("mean_", "components_", "explained_variance_", "explained_variance_ratio_", "scores_", "faces_"):
        np.testing.assert_array_equal(getattr(back, key), getattr(fitted, key))
    assert back.names_ == fitted.names_ and back.n_samples_ == 12 and back.n_components == 5
    assert back.noise_variance_ == fitted.noise_variance_


def test_json_by_extension_and_the_statismo_part_alone(fitted, tmp_path):
    path = fitted.save(tmp_path / "model.json")
    assert model_format(path) == "json"
    # what Scalismo reads: drop hortishape's own group; float32 precision remains
    tree = read_tree(path)
    assert "/hortishape" in tree.groups
    plain = H5Tree(
        groups={g for g in tree.groups if not g.startswith("/hortishape")},
        datasets={k: v for k, v in tree.datasets.items() if not k.startswith("/hortishape")},
        attrs={k: v for k, v in tree.attrs.items() if not k.startswith("/hortishape")},
    )
    for form in ("json", "hdf5"):
        m = ShapeModel.load(write_tree(plain, tmp_path / f"plain.{form}", form))
        np.testing.assert_allclose(m.mean_, fitted.mean_, atol=1e-4)
        np.testing.assert_allclose(m.explained_variance_, fitted.explained_variance_, rtol=1e-6)
        np.testing.assert_allclose(m.components_, fitted.components_, atol=1e-6)
        np.testing.assert_allclose(m.scores_, fitted.scores_, atol=1e-5)
        assert m.names_ == fitted.names_


def test_json_is_written_as_scalismo_writes_it(fitted, tmp_path):
    doc = json.loads(fitted.save(tmp_path / "model.json").read_text())
    by_path = {d["alias"][0]: d for d in doc["datasets"].values()}
    assert by_path["/model/mean"]["type"] == {"class": "H5T_FLOAT", "base": "H5T_IEEE_F32LE"}
    assert by_path["/model/pcaBasis"]["shape"]["dims"] == [120, 5]
    assert by_path["/representer/cells"]["type"]["base"] == "H5T_STD_I32LE"
    assert by_path["/version/majorVersion"]["shape"] == {"class": "H5S_SCALAR"}
    root = doc["groups"][doc["root"]]
    assert {link["title"] for link in root["links"]} >= {"model", "representer", "version", "modelinfo"}
    rep = next(g for g in doc["groups"].values() if g["alias"] == ["/representer"])
    dataset_type = next(a for a in rep["attributes"] if a["name"] == "datasetType")
    # a scalar variable-length string: Scalismo's reader takes nothing else
    assert dataset_type["value"] == "POLYGON_MESH" and dataset_type["shape"] == {"class": "H5S_SCALAR"}
    assert dataset_type["type"]["length"] == "H5T_VARIABLE"


def test_scalismo_copied_through_both_forms(tmp_path):
    m = ShapeModel.load(SCALISMO_H5)
    for name in ("again.json", "again.h5"):
        back = ShapeModel.load(m.save(tmp_path / name))
        np.testing.assert_array_equal(back.mean_, m.mean_)
        np.testing.assert_array_equal(back.components_, m.components_)
        np.testing.assert_array_equal(back.faces_, m.faces_)


@pytest.mark.parametrize("strings", ["fixed", "variable", "array", "variable-array"])
@pytest.mark.parametrize("cells", [np.int32, np.uint32, None])
def test_statismo_variants_load(tmp_path, strings, cells):
    rng = np.random.default_rng(5)
    mean = rng.normal(size=18) * 10
    basis, _ = np.linalg.qr(rng.normal(size=(18, 2)))
    path = tmp_path / "variant.h5"
    with h5py.File(path, "w") as f:
        f["version/majorVersion"] = np.int32(0)
        f["version/minorVersion"] = np.int32(9)
        rep = f.create_group("representer")
        kind = "POLYGON_MESH" if cells is not None else "POINT_SET"
        for key, text in (("name", "itkStandardMeshRepresenter"), ("datasetType", kind)):
            if strings == "fixed":
                rep.attrs.create(key, np.bytes_(text))
            elif strings == "variable":
                rep.attrs[key] = text
            elif strings == "array":  # as Scalismo writes them
                rep.attrs.create(key, np.array([text.encode()]))
            else:
                rep.attrs.create(key, [text], dtype=h5py.string_dtype())
        rep["points"] = mean.reshape(-1, 3).T.astype(np.float32)
        if cells is not None:
            rep["cells"] = np.array([[0, 1, 2], [3, 4, 5]], dtype=cells).T
        f["model/mean"] = mean.astype(np.float32)
        f["model/pcaBasis"] = basis.astype(np.float32)
        f["model/pcaVariance"] = np.array([4.0, 1.0], np.float32)
        f["model/noiseVariance"] = np.float32(0.0)
    m = ShapeModel.load(path)
    assert (m.faces_ is None) == (cells is None) and m.scores_ is None
    np.testing.assert_allclose(m.components_, basis.T, atol=1e-6)


def test_unreadable_files_say_what_is_wrong(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(HortishapeError, match="not valid JSON"):
        ShapeModel.load(bad)
    other = tmp_path / "other.json"
    other.write_text('{"a": 1}')
    with pytest.raises(HortishapeError, match="not an HDF5-JSON file"):
        ShapeModel.load(other)
    empty = tmp_path / "empty.json"
    write_tree(H5Tree(), empty, "json")
    with pytest.raises(HortishapeError, match="not a Statismo model file"):
        ShapeModel.load(empty)
    with pytest.raises(HortishapeError, match="unknown model file format"):
        ShapeModel.load(SCALISMO_H5).save(tmp_path / "m.h5", format="vtk")
