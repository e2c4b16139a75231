"""Batch registration over files: outputs, resume, bad scans, --strict."""

import json

import numpy as np
import pytest

from hortishape import synth
from hortishape.errors import HortishapeError
from hortishape.io import read_mesh, write_mesh
from hortishape.pipeline import find_meshes, register_files
from hortishape.register import RegistrationConfig, prepare_reference

CONFIG = RegistrationConfig(n_iterations=12)


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scans")
    synth.write_population("apple", 3, folder, random_state=4, pose="upright", n_vertices=12000, n_jobs=1)
    return folder


@pytest.fixture(scope="module")
def template(scans):
    return prepare_reference(read_mesh(scans / "apple_000.ply"), 3000, coarse_vertices=800, search_vertices=300)


def test_writes_one_registered_mesh_and_log_per_scan(scans, template, tmp_path):
    targets = [scans / "apple_001.ply", scans / "apple_002.ply"]
    results = register_files(template, targets, tmp_path, config=CONFIG, n_jobs=2)
    assert [r.name for r in results] == ["apple_001", "apple_002"]
    assert all(r.ok and not r.resumed for r in results)
    for r in results:
        mesh = read_mesh(tmp_path / f"{r.name}.ply")
        np.testing.assert_array_equal(mesh.faces, template.mesh.faces)
        assert mesh.n_vertices == template.mesh.n_vertices
        log = json.loads((tmp_path / f"{r.name}.json").read_text())
        assert log["units"] == "mm" and len(log["iterations"]) == r.iterations
        assert {"beta", "mean_distance", "kept_fraction", "seconds"} <= set(log["iterations"][0])
        # the registered surface lies on the scan, in the scan's own coordinates
        assert r.geometric_error < 0.5


def test_resumes_without_redoing_and_redoes_what_changed(scans, template, tmp_path):
    targets = [scans / "apple_001.ply"]
    first = register_files(template, targets, tmp_path, config=CONFIG, n_jobs=1)
    stamp = (tmp_path / "apple_001.ply").stat().st_mtime_ns
    again = register_files(template, targets, tmp_path, config=CONFIG, n_jobs=1)
    assert again[0].resumed and again[0].seconds == first[0].seconds
    assert (tmp_path / "apple_001.ply").stat().st_mtime_ns == stamp
    # another configuration is another result
    other = register_files(template, targets, tmp_path, config=RegistrationConfig(n_iterations=10), n_jobs=1)
    assert not other[0].resumed


def test_a_bad_scan_is_reported_and_skipped(scans, template, tmp_path):
    broken = tmp_path / "broken.ply"
    broken.write_text("ply\nformat ascii 1.0\nelement vertex 3\n")
    metres = tmp_path / "metres.ply"
    m = read_mesh(scans / "apple_002.ply")
    write_mesh(metres, m.vertices / 1000.0, m.faces)
    before = broken.read_bytes()
    out = tmp_path / "out"
    results = register_files(template, [broken, scans / "apple_001.ply", metres], out, config=CONFIG, n_jobs=2)
    assert [r.ok for r in results] == [False, True, False]
    assert str(broken) in results[0].error
    assert str(metres) in results[2].error and "metres" in results[2].error
    assert sorted(p.name for p in out.iterdir()) == ["apple_001.json", "apple_001.ply"]
    assert broken.read_bytes() == before  # inputs are never modified


def test_strict_stops_at_the_first_bad_scan(scans, template, tmp_path):
    broken = tmp_path / "broken.stl"
    broken.write_bytes(b"")
    with pytest.raises(HortishapeError, match="broken.stl"):
        register_files(template, [broken, scans / "apple_001.ply"], tmp_path / "out", config=CONFIG,
                       n_jobs=1, strict=True)


def test_scans_sharing_a_name_are_refused(scans, template, tmp_path):
    other = tmp_path / "apple_001.ply"
    other.write_bytes((scans / "apple_001.ply").read_bytes())
    with pytest.raises(HortishapeError, match="share the name"):
        register_files(template, [scans / "apple_001.ply", other], tmp_path / "out", config=CONFIG)


def test_find_meshes(scans, tmp_path):
    assert [p.name for p in find_meshes(scans)] == ["apple_000.ply", "apple_001.ply", "apple_002.ply"]
    with pytest.raises(HortishapeError, match="no mesh files"):
        find_meshes(tmp_path)
    with pytest.raises(HortishapeError, match="not a folder"):
        find_meshes(tmp_path / "missing")
