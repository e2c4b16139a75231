"""Several products in one volume (extract --split): a tray of touching fruit, each extracted on its own."""

import json

import numpy as np
import pytest

from hortishape.cli import main
from hortishape.extract import extract_products, split_products
from hortishape.io import Volume, read_mesh, write_volume
from hortishape.pipeline import find_scans
from hortishape.surface import check_closed_surface, signed_volume
from hortishape.synth import make_tray


@pytest.fixture(scope="module")
def tray():
    # six apples touching their neighbours on a plate that reaches the volume's edges
    return make_tray("apple", 6, random_state=21)


def _match(tray, centres):
    truth = np.array([inst.mesh.vertices.mean(axis=0) for inst in tray.instances])
    return [int(np.argmin(np.linalg.norm(truth - c, axis=1))) for c in centres]


@pytest.mark.slow
def test_a_tray_of_six_touching_apples_gives_six_surfaces_within_1_percent(tray, tmp_path, capsys):
    (tmp_path / "scans").mkdir()
    path = write_volume(tmp_path / "scans" / "tray.mha", tray.volume)
    surfaces = tmp_path / "model" / "surfaces"
    assert main(["extract", str(path), "--out", str(surfaces), "--split", "--no-picture"]) == 0
    out = capsys.readouterr().out
    assert "extracted 6 of 6 surfaces" in out
    summary = json.loads((surfaces / "tray.split.json").read_text())
    assert summary["products"] == [f"tray_{k}" for k in range(1, 7)] and summary["left_out"] == []
    centres = np.array(summary["centres_mm"])
    # in order of position: the front row (smaller y) first, each row along x
    assert np.all(np.diff(centres[:3, 0]) > 0) and np.all(np.diff(centres[3:, 0]) > 0)
    assert centres[:3, 1].max() < centres[3:, 1].min()
    for k, j in enumerate(_match(tray, centres)):
        mesh = read_mesh(surfaces / f"tray_{k + 1}.ply")
        check_closed_surface(mesh)
        log = json.loads((surfaces / f"tray_{k + 1}.json").read_text())
        assert log["genus"] == 0 and log["split_from"] == "tray" and log["product"] == k + 1
        assert abs(signed_volume(mesh.vertices, mesh.faces)) == pytest.approx(tray.true_volumes[j], rel=0.01)
    # the same bytes and options again: nothing redone
    again = extract_products(path, surfaces, picture=False)
    assert [r.name for r in again] == summary["products"] and all(r.resumed for r in again)
    # build --split takes each product as a scan (here found done: the same bytes and options)
    paths, failed, passed = find_scans(tmp_path / "scans", tmp_path / "model", n_jobs=1, split=True)
    assert [p.stem for p in paths] == summary["products"] and failed == [] and passed == []


@pytest.mark.slow
def test_pieces_cut_by_the_edge_or_too_small_are_left_out_and_said_so(tray, tmp_path):
    vol = tray.volume
    x_cut = int(vol.world_to_index([tray.instances[2].mesh.vertices.mean(axis=0)])[0][0])
    # the third apple of each row cut in half by the edge, 30 mm more air above
    data = np.pad(vol.data[:x_cut], ((0, 0), (0, 0), (0, 30)))
    # a speck of 0.3 mL floating above the first apple
    top = tray.instances[0].mesh.vertices
    speck = vol.world_to_index([[top[:, 0].mean(), top[:, 1].mean(), top[:, 2].max() + 15]])[0].round().astype(int)
    data[speck[0] - 3:speck[0] + 4, speck[1] - 3:speck[1] + 4, speck[2] - 3:speck[2] + 4] = 1000
    split = split_products(Volume(data, vol.spacing, vol.origin))
    assert len(split.products) == 4
    assert sorted(_match(tray, split.centres)) == [0, 1, 3, 4]
    reasons = " | ".join(split.left_out)
    assert "touches the volume's edge" in reasons and "too small to be a product" in reasons
    (tmp_path / "scans").mkdir()
    path = write_volume(tmp_path / "scans" / "cut.mha", Volume(data, vol.spacing, vol.origin))
    results = extract_products(path, tmp_path / "model" / "surfaces")
    assert [r.name for r in results] == [f"cut_{k}" for k in range(1, 5)] and all(r.ok for r in results)
    assert results[0].left_out == split.left_out
    # build --split lists them with what it passed over (the extraction found done)
    paths, failed, passed = find_scans(tmp_path / "scans", tmp_path / "model", n_jobs=1, split=True)
    assert len(paths) == 4 and failed == []
    assert [why for _, why in passed] == [f"left out of the split: {why}" for why in split.left_out]


def test_a_pear_is_not_parted_at_its_neck_nor_a_banana_along_it(tmp_path):
    for product in ("pear", "banana"):
        single = make_tray(product, 1, random_state=5, n_vertices=8000, voxel_size=1.5)
        split = split_products(single.volume)
        assert len(split.products) == 1, (product, split.left_out)


def test_nothing_but_a_plate_is_refused(tmp_path):
    data = np.zeros((30, 30, 20), np.int16)
    data[:, :, 5:8] = 1000  # a plate across the whole field of view
    results = extract_products(write_volume(tmp_path / "plate.mha", Volume(data, 1.0)), tmp_path / "s")
    assert len(results) == 1 and not results[0].ok
    assert results[0].error.startswith(str(tmp_path / "plate.mha") + ": ")


@pytest.mark.parametrize("coarse", [False, True])
def test_two_touching_balls_each_within_1_percent_also_told_apart_on_a_coarser_grid(monkeypatch, coarse):
    """Two balls of 12 and 10 mm radius touching at one point; on a volume too large for the full grid the
    products are told apart on one twice as coarse, and their boundary found again on the full one."""
    from scipy.special import erf

    from hortishape import extract
    from hortishape.extract import extract_surface

    if coarse:
        monkeypatch.setattr(extract, "SPLIT_COARSE_VOXELS", 1000)
    x, y, z = np.mgrid[:64, :40, :40] - np.array([0, 19.5, 19.5])[:, None, None, None]
    centres, radii = (14.0, 36.0), (12.0, 10.0)
    d = np.minimum(*(np.sqrt((x - c) ** 2 + y**2 + z**2) - r for c, r in zip(centres, radii)))
    data = (1000 * 0.5 * (1 - erf(d / (0.7 * np.sqrt(2))))).astype(np.float32)
    split = split_products(Volume(data, 1.0))
    assert split.left_out == () and [round(float(c)) for c in split.centres[:, 0]] == [14, 36]
    for product, r in zip(split.products, radii):
        assert extract_surface(product).volume == pytest.approx(4 / 3 * np.pi * r**3, rel=0.01)
