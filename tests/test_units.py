"""Units: sizes checked against what fruit can be, the likely unit named, --scale applied in memory."""

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from hortishape.cli import main
from hortishape.errors import MeshError
from hortishape.io import read_mesh, write_mesh
from hortishape.units import PLAUSIBLE_EXTENT_MM, check_size, likely_unit, read_scan


def _ball(radius):
    s = trimesh.creation.icosphere(3, radius=radius)
    return s.vertices, s.faces


@pytest.mark.parametrize(
    "extent, unit",
    [(0.08, "metres"), (0.3, "metres"), (8e4, "micrometres"), (5000.0, "micrometres"), (2.0, "centimetres"),
     (1e-7, None), (1e9, None)],
)
def test_likely_unit(extent, unit):
    found = likely_unit(extent)
    assert (found[0] if found else None) == unit
    if found:
        lo, hi = PLAUSIBLE_EXTENT_MM
        assert lo <= extent * found[1] <= hi


def test_check_size_accepts_fruit_and_refuses_metres_and_micrometres():
    v, _ = _ball(40.0)
    assert check_size(v).extent_mm == pytest.approx(80.0)
    with pytest.raises(MeshError, match=r"apple\.ply: 0\.08 across: in metres\? use --scale 1000"):
        check_size(v / 1000, name="apple.ply")
    with pytest.raises(MeshError, match=r"8e\+04 across: in micrometres\? use --scale 0\.001"):
        check_size(v * 1000, name="apple.ply")
    # the scale applies, and the hint accounts for a scale already given
    assert check_size(v / 1000, scale=1000).extent_mm == pytest.approx(80.0)
    with pytest.raises(MeshError, match=r"0\.08 across: in metres\? use --scale 1e\+06"):
        check_size(v / 1e6, scale=1000)
    with pytest.raises(MeshError, match="not a fruit's size in any usual unit"):
        check_size(v * 1e9)
    with pytest.raises(MeshError, match="positive"):
        check_size(v, scale=0.0)


def test_read_scan_scales_in_memory_and_leaves_the_file(tmp_path):
    v, f = _ball(0.04)
    path = write_mesh(tmp_path / "m.ply", v, f)
    before = path.read_bytes()
    scan = read_scan(path, scale=1000)
    np.testing.assert_allclose(scan.mesh.vertices, read_mesh(path).vertices * 1000)
    assert scan.units.as_log()["scale"] == 1000 and scan.units.as_log()["unit"] == "mm"
    assert path.read_bytes() == before
    with pytest.raises(MeshError, match="m.ply.*in metres"):
        read_scan(path)


@pytest.fixture(scope="module")
def metres(tmp_path_factory):
    """Three synthetic apples written in metres, as some scanners export them."""
    from hortishape import synth

    folder = tmp_path_factory.mktemp("metres")
    for inst in synth.make_population("apple", 3, random_state=8, n_vertices=4000):
        write_mesh(folder / f"{inst.name}.ply", inst.mesh.vertices / 1000.0, inst.mesh.faces)
    return folder


def test_an_all_metres_population_is_refused_by_name(metres, tmp_path, capsys):
    scans = sorted(metres.glob("*.ply"))
    assert main(["register", str(scans[0]), *map(str, scans[1:]), "--out", str(tmp_path / "r"),
                 "--points", "1000"]) == 1
    err = capsys.readouterr().err
    assert str(scans[0]) in err and "in metres? use --scale 1000" in err
    assert main(["build", str(metres), "--out", str(tmp_path / "b"), "--points", "1000"]) == 1
    err = capsys.readouterr().err
    assert "in metres? use --scale 1000" in err and "apple_000.ply" in err


def test_register_with_scale_writes_mm_and_logs_each_scan_in_a_file(metres, tmp_path):
    scans = sorted(metres.glob("*.ply"))
    before = [p.read_bytes() for p in scans]
    out = tmp_path / "r"
    log = tmp_path / "log.txt"
    with open(log, "w") as fh:  # output to a file, as in CI or a batch job
        done = subprocess.run(
            [sys.executable, "-m", "hortishape.cli", "register", str(scans[0]), str(scans[1]), str(scans[2]),
             "--out", str(out), "--points", "1500", "--iterations", "10", "--scale", "1000", "--jobs", "1"],
            stdout=fh, stderr=subprocess.STDOUT, text=True, timeout=600)
    text = log.read_text()
    assert done.returncode == 0, text
    # a plain line when the stage starts and one per finished scan, with its seconds and fit
    assert "register: 2 scans" in text
    for i, name in enumerate(("apple_001", "apple_002"), start=1):
        line = next(x for x in text.splitlines() if x.startswith(f"register {i}/2"))
        assert "registered in" in line and " s, " in line and "geometric error" in line
        assert name in text
    assert "\r" not in text  # no progress bar drawn into the file
    for name in ("apple_001", "apple_002"):
        units = json.loads((out / f"{name}.json").read_text())["units"]
        assert units["scale"] == 1000 and 60 < units["extent_mm"] < 120
        assert 60 < np.ptp(read_mesh(out / f"{name}.ply").vertices, axis=0).max() < 120
    assert [p.read_bytes() for p in scans] == before  # inputs never modified
