"""Broken files, as disks, downloads and exports break them: every reader loads a truncated or byte-mutated file
or gives hortishape's own one-line error, never a dependency's traceback, a crash or a hang.

Each format's mutations are read in a child process (a crash in a C++ reader must not take the test run
with it, and a hang must be seen), which reports every case as one JSON line.
"""

import json
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hortishape.io import Volume, write_mesh, write_volume
from hortishape.mesh import Mesh

SEED = 20261207
N_PER_FORMAT = 36  # mutations per format: a third truncations, the rest bytes changed

WORKER = textwrap.dedent('''
    import json, sys, traceback
    from hortishape.errors import HortishapeError
    from hortishape.io import find_sources, read_mesh, read_volume
    for kind, path in json.load(open(sys.argv[1])):
        print(json.dumps({"case": path, "status": "start"}), flush=True)
        try:
            if kind == "mesh":
                read_mesh(path)
            elif kind == "series":
                for source in find_sources(path).volumes:
                    read_volume(source, spacing=1.0)
            else:
                read_volume(path, spacing=1.0 if kind == "tiff" else None)
            status = "read"
        except HortishapeError as exc:
            status = "error" if "\\n" not in str(exc) and str(exc).startswith(path) else "bad message: " + str(exc)
        except Exception as exc:
            status = "traceback: " + "".join(traceback.format_exception_only(type(exc), exc)).strip()
        print(json.dumps({"case": path, "status": status}), flush=True)
''')


def _mutants(original: bytes, rng: np.random.Generator, n: int) -> list[bytes]:
    out = []
    for k in range(n):
        data = bytearray(original)
        if k % 3 == 0:  # truncated anywhere, the header too
            out.append(bytes(data[: int(rng.integers(0, len(data)))]))
            continue
        for _ in range(int(rng.integers(1, 9))):
            at = int(rng.integers(0, len(data)))
            if rng.random() < 0.5:  # a random byte
                data[at] = int(rng.integers(0, 256))
            else:  # a digit or a size field changed to a large value
                data[at] = ord("9") if chr(data[at]).isdigit() else 0xFF
        out.append(bytes(data))
    return out


def _shape():
    x, y, z = np.mgrid[:7, :6, :5]
    return (100 * x + 10 * y + z).astype(np.int16)


def _files(tmp_path):
    """Valid files of every format hortishape reads: (kind, path)."""
    mesh = Mesh([[0, 0, 0], [0, 10, 0], [10, 0, 0], [0, 0, 10]], [[0, 1, 2], [0, 2, 3], [0, 3, 1], [2, 1, 3]])
    files = []
    for name in ("ascii.ply", "binary.ply", "ascii.stl", "binary.stl", "mesh.obj", "mesh.off"):
        kw = {"binary": name.startswith("binary")} if name.endswith((".ply", ".stl")) else {}
        files.append(("mesh", write_mesh(tmp_path / name, mesh, **kw)))
    vol = Volume(_shape(), spacing=(0.5, 0.6, 0.7), origin=(1, 2, 3))
    files.append(("volume", write_volume(tmp_path / "v.mha", vol, compress=False)))
    files.append(("volume", write_volume(tmp_path / "z.mha", vol, compress=True)))
    try:
        import SimpleITK  # noqa: F401

        files += [("volume", write_volume(tmp_path / f"v{ext}", vol)) for ext in (".nrrd", ".nii", ".nii.gz")]
    except ImportError:
        pass
    try:
        import vtk  # noqa: F401

        files += [("mesh", write_mesh(tmp_path / f"mesh{ext}", mesh)) for ext in (".vtk", ".vtp")]
    except ImportError:
        pass
    try:
        import tifffile

        files.append(("tiff", write_volume(tmp_path / "v.tif", vol)))
        plain = tmp_path / "plain.tif"
        tifffile.imwrite(plain, np.ascontiguousarray(vol.data.transpose(2, 1, 0)), photometric="minisblack")
        files.append(("tiff", plain))
    except ImportError:
        pass
    return files


@pytest.mark.parametrize("family", ["meshes", "volumes", "dicom"])
def test_broken_files_load_or_give_hortishape_s_error(tmp_path, family):
    rng = np.random.default_rng([SEED, ["meshes", "volumes", "dicom"].index(family)])
    originals = tmp_path / "originals"
    originals.mkdir()
    cases = []
    if family == "dicom":
        pytest.importorskip("pydicom")
        from scanner_files import ROOT, write_dicom_series

        series = originals / "series"
        write_dicom_series(series, _shape(), series_uid=ROOT + "77")
        for k in range(N_PER_FORMAT * 2):  # one slice of the series broken (a file the scanner cut short)
            copy = tmp_path / f"series_{k}"
            shutil.copytree(series, copy)
            slice_file = copy / f"IM{int(rng.integers(0, 5)):04d}"
            slice_file.write_bytes(_mutants(slice_file.read_bytes(), rng, 3)[k % 3])
            cases.append(("series", str(copy)))
        import tifffile

        for k in range(N_PER_FORMAT // 2):  # TIFF slices with one of them broken
            folder = tmp_path / f"slices_{k}"
            folder.mkdir()
            for z in range(4):
                tifffile.imwrite(folder / f"s{z}.tif", _shape()[:, :, z].T.copy())
            bad = folder / f"s{int(rng.integers(0, 4))}.tif"
            bad.write_bytes(_mutants(bad.read_bytes(), rng, 3)[k % 3])
            cases.append(("tiff", str(folder)))
    else:
        for kind, path in _files(originals):
            if (kind == "mesh") != (family == "meshes"):
                continue
            for k, data in enumerate(_mutants(path.read_bytes(), rng, N_PER_FORMAT)):
                target = tmp_path / f"m{k}_{path.name}"
                target.write_bytes(data)
                cases.append((kind, str(target)))
    listing = tmp_path / "cases.json"
    listing.write_text(json.dumps(cases))
    try:
        run = subprocess.run([sys.executable, "-c", WORKER, str(listing)], capture_output=True, text=True,
                             encoding="utf-8", errors="replace", timeout=300)
    except subprocess.TimeoutExpired as exc:
        lines = exc.stdout.decode("utf-8", "replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        last = [json.loads(x) for x in lines.splitlines() if x.startswith("{")][-1:]
        pytest.fail(f"hung on {last}")
    reports = [json.loads(x) for x in run.stdout.splitlines() if x.startswith("{")]
    ends = [r for r in reports if r["status"] != "start"]
    assert run.returncode == 0, f"the reader crashed on {reports[-1]['case']}: {run.stderr[-2000:]}"
    assert len(ends) == len(cases)
    bad = [r for r in ends if r["status"] not in ("read", "error")]
    assert not bad, f"{len(bad)} of {len(cases)}: {bad[:5]}"
    # the mutations reach the parsers: most are refused, some still read
    statuses = [r["status"] for r in ends]
    assert statuses.count("error") > len(cases) // 3
