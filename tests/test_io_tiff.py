"""TIFF stacks with their voxel size from where scanners put it, and refused without one."""

import json
import re

import numpy as np
import pytest

tifffile = pytest.importorskip("tifffile")

from scanner_files import ball_ct, write_skyscan_log, write_tiff_slices  # noqa: E402

from hortishape.cli import main  # noqa: E402
from hortishape.errors import VolumeError  # noqa: E402
from hortishape.io import find_sources, read_volume  # noqa: E402
from hortishape.io.tiff import parse_scanner_log  # noqa: E402


def _stack(n=48, radius=20.0):
    """A ball of 2 * radius voxels across, stored as uint16 as micro-CT software exports it."""
    return np.clip(ball_ct(n, (radius, radius, radius), noise=10.0).astype(np.int32) + 1000, 0, None).astype(np.uint16)


def test_slices_with_a_skyscan_log_take_its_voxel_size(tmp_path):
    data = _stack()
    folder = tmp_path / "apple_rec"
    write_tiff_slices(folder, data, names="apple_rec{:08d}.tif")
    write_skyscan_log(folder / "apple_rec.log", pixel_um=400.0)
    vol = read_volume(folder)
    np.testing.assert_array_equal(vol.data, data)
    # the reconstruction's pixel size, not the acquisition's (twice as large before binning)
    np.testing.assert_allclose(vol.spacing, [0.4, 0.4, 0.4])
    assert vol.spacing_source == f"scanner log {folder / 'apple_rec.log'}"
    found = find_sources(tmp_path)
    assert [(v.name, v.kind) for v in found.volumes] == [("apple_rec", "tiff-slices")] and found.skipped == ()


def test_without_a_voxel_size_extract_and_build_exit_1_naming_spacing(tmp_path, capsys):
    data = _stack()
    scans = tmp_path / "scans"
    write_tiff_slices(scans / "apple", data)
    assert main(["extract", str(scans / "apple"), "--out", str(tmp_path / "s"), "--no-picture"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"hortishape: error: {scans / 'apple'}: no voxel size")
    assert "--spacing SX SY SZ" in err
    assert main(["build", str(scans), "--out", str(tmp_path / "m")]) == 1
    err = capsys.readouterr().err
    assert f"{scans / 'apple'}: no voxel size" in err and "--spacing SX SY SZ" in err
    # with the log beside the slices the voxel size is known, and recorded in the JSON with its source
    write_skyscan_log(scans / "apple" / "apple.log", pixel_um=400.0)
    assert main(["extract", str(scans), "--out", str(tmp_path / "s"), "--no-picture"]) == 0
    log = json.loads((tmp_path / "s" / "apple.json").read_text())
    assert log["units"]["spacing_mm"] == [0.4, 0.4, 0.4]
    assert log["units"]["spacing_source"].startswith("scanner log ")
    true_ml = 4 / 3 * np.pi * (20 * 0.4) ** 3 / 1000
    assert log["volume_mm3"] / 1000 == pytest.approx(true_ml, rel=0.02)


def test_a_voxel_size_that_makes_no_fruit_is_refused_with_one_that_would(tmp_path, capsys):
    data = _stack()
    write_tiff_slices(tmp_path / "apple", data)
    # a 2.8-litre apple: the stack read as 10 mm voxels
    assert main(["extract", str(tmp_path / "apple"), "--out", str(tmp_path / "s"), "--no-picture",
                 "--spacing", "10", "10", "10"]) == 1
    err = capsys.readouterr().err
    assert "not a fruit's size (10-600 mm, 1 mL-10 L)" in err and "times this one would make it one" in err


def test_imagej_ome_and_nikon_voxel_sizes(tmp_path):
    data = _stack(n=16, radius=6.0)
    zyx = np.ascontiguousarray(data.transpose(2, 1, 0))
    tifffile.imwrite(tmp_path / "ij.tif", zyx, imagej=True, resolution=(1 / 0.02, 1 / 0.025),
                     metadata={"spacing": 0.05, "unit": "micron", "axes": "ZYX"})
    ij = read_volume(tmp_path / "ij.tif")
    np.testing.assert_allclose(ij.spacing, [0.02e-3, 0.025e-3, 0.05e-3])
    assert ij.spacing_source.startswith("ImageJ")
    tifffile.imwrite(tmp_path / "ome.ome.tif", zyx, ome=True, photometric="minisblack",
                     metadata={"axes": "ZYX", "PhysicalSizeX": 40.0, "PhysicalSizeY": 40.0, "PhysicalSizeZ": 80.0})
    np.testing.assert_allclose(read_volume(tmp_path / "ome.ome.tif").spacing, [0.04, 0.04, 0.08])  # µm
    nikon = tmp_path / "nikon"
    nikon.mkdir()
    tifffile.imwrite(nikon / "carrot.tif", zyx, photometric="minisblack")
    (nikon / "carrot.xtekct").write_text("[XTekCT]\nName=carrot\nVoxelSizeX=0.0625\nVoxelSizeY=0.0625\n"
                                         "VoxelSizeZ=0.125\nUnits=mm\n")
    vol = read_volume(nikon / "carrot.tif")
    np.testing.assert_allclose(vol.spacing, [0.0625, 0.0625, 0.125])
    assert vol.spacing_source == f"scanner log {nikon / 'carrot.xtekct'}"
    assert parse_scanner_log(nikon / "carrot.tif") is None


def test_a_slice_of_another_size_is_named(tmp_path):
    data = _stack(n=12, radius=4.0)
    folder = tmp_path / "stack"
    write_tiff_slices(folder, data)
    tifffile.imwrite(folder / "slice_0005.tif", np.zeros((12, 10), np.uint16))
    with pytest.raises(VolumeError, match="^" + re.escape(f"{folder}: slice slice_0005.tif is 10 x 12 pixels, "
                                                           "the others 12 x 12")):
        read_volume(folder, spacing=0.5)
