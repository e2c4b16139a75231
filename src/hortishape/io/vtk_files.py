"""Legacy VTK (read through the optional vtk package, written with numpy) and VTK XML PolyData (vtk)."""

from __future__ import annotations

import contextlib
import importlib
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ._common import _MissingDependencyError, _ParseError, _RawMesh, _fan, _strip_triangles, _floats_text, _ints_text


_VTK_MODULES = (
    "vtkmodules.vtkCommonCore",
    "vtkmodules.vtkCommonDataModel",
    "vtkmodules.vtkIOLegacy",
    "vtkmodules.vtkIOXML",
    "vtkmodules.util.numpy_support",
)


def _import_vtk(action: str, extension: str) -> dict[str, Any]:
    try:
        return {name.rsplit(".", 1)[-1]: importlib.import_module(name) for name in _VTK_MODULES}
    except ImportError:
        raise _MissingDependencyError(
            f"{action} {extension} files needs the optional dependency 'vtk' "
            '(pip install "hortishape[vtk]")'
        ) from None


@contextlib.contextmanager
def _vtk_messages(core) -> Iterator[list[str]]:
    """Collect VTK's error messages instead of letting it print them to stderr.

    VTK reports errors through a global output window and a global logger;
    both are swapped for the duration of the call and restored afterwards.
    """
    messages: list[str] = []
    window = core.vtkStringOutputWindow()
    previous_window = core.vtkOutputWindow.GetInstance()
    previous_verbosity = core.vtkLogger.GetCurrentVerbosityCutoff()
    core.vtkOutputWindow.SetInstance(window)
    core.vtkLogger.SetStderrVerbosity(core.vtkLogger.VERBOSITY_OFF)
    try:
        yield messages
    finally:
        core.vtkOutputWindow.SetInstance(previous_window)
        core.vtkLogger.SetStderrVerbosity(previous_verbosity)
        # Blocks look like "ERROR: In file.cxx, line 9\nvtkClass (0x..): message\n\n".
        for block in window.GetOutput().split("\n\n"):
            if block.strip().startswith("ERROR"):
                body = block.strip().split("\n", 2)
                text = body[1] if len(body) > 1 else body[0]
                messages.append(re.sub(r"^\w+ \(0x[0-9a-fA-F]+\): ", "", text).strip())


def _vtk_cells(cells) -> tuple[np.ndarray, np.ndarray]:
    from vtkmodules.util.numpy_support import vtk_to_numpy

    offsets = vtk_to_numpy(cells.GetOffsetsArray()).astype(np.int64)
    connectivity = vtk_to_numpy(cells.GetConnectivityArray()).astype(np.int64)
    return np.diff(offsets), connectivity


_LEGACY_SIZES = {"bit": None, "char": 1, "unsigned_char": 1, "short": 2, "unsigned_short": 2, "int": 4,
                 "unsigned_int": 4, "long": 8, "unsigned_long": 8, "float": 4, "double": 8,
                 "vtktypeint64": 8, "vtktypeuint64": 8, "vtkidtype": 8}
_LEGACY_CELLS = ("VERTICES", "LINES", "POLYGONS", "TRIANGLE_STRIPS", "CELLS")


class _Legacy:
    """A cursor over a legacy VTK file, ASCII or binary, for the structure check."""

    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0
        self.binary = False

    def line(self, *, needed: bool = True) -> str:
        """The next line that is not blank; "" at the end of the file where ``needed`` is False."""
        while self.pos < len(self.data):
            end = self.data.find(b"\n", self.pos)
            end = len(self.data) if end < 0 else end
            text = self.data[self.pos:end].decode("latin-1").strip()
            self.pos = end + 1
            if text:
                return text
        if needed:
            raise _ParseError("the file ends before its data")
        return ""

    def numbers(self, count: int, kind: str, what: str) -> np.ndarray:
        size = _LEGACY_SIZES.get(kind.lower())
        if size is None:
            raise _ParseError(f"{what}: unknown data type {kind!r}")
        if count < 0:
            raise _ParseError(f"{what}: a negative count")
        if self.binary:
            end = self.pos + count * size
            if end > len(self.data):
                raise _ParseError(f"{what}: the file ends inside its {count:,} values")
            dtype = (">f" if kind.lower() in ("float", "double") else ">u" if kind.startswith("unsigned") else ">i")
            values = np.frombuffer(self.data, dtype=f"{dtype}{size}", count=count, offset=self.pos)
            self.pos = end
            return values
        parts = self.data[self.pos:].split(maxsplit=count)  # ASCII: the next ``count`` numbers, split in C
        if len(parts) < count:
            raise _ParseError(f"{what}: the file ends inside its {count:,} values")
        self.pos = len(self.data) - (len(parts[count]) if len(parts) > count else 0)
        try:
            return np.array(parts[:count], dtype=np.float64)
        except ValueError:
            raise _ParseError(f"{what}: not a list of numbers") from None


def _check_cells(cells: np.ndarray, n_cells: int, n_points: int, what: str) -> None:
    """Each cell a count followed by that many point indices, ``n_cells`` of them, indices in range."""
    if not np.all(np.isfinite(cells)) or np.any(cells != np.round(cells)):
        raise _ParseError(f"{what}: not integers")
    cells = cells.astype(np.int64)
    first = int(cells[0]) if len(cells) else 0
    if n_cells and len(cells) == n_cells * (first + 1) and first > 0 and np.all(cells[:: first + 1] == first):
        starts = np.arange(0, len(cells), first + 1)  # every cell the same size (triangles): no walk needed
    else:
        starts, at = [], 0
        while at < len(cells):  # cells of several sizes: their starts, one after the other
            if cells[at] < 0 or at + cells[at] >= len(cells):
                raise _ParseError(f"{what}: a cell's point count runs past the list")
            starts.append(at)
            at += int(cells[at]) + 1
        starts = np.array(starts, dtype=np.int64)
    if len(starts) != n_cells:
        raise _ParseError(f"{what}: {len(starts):,} cells where the header says {n_cells:,}")
    indices = np.delete(cells, starts)
    if len(indices) and (indices.min() < 0 or indices.max() >= n_points):
        raise _ParseError(f"{what}: a point index outside the {n_points:,} points")


def _check_legacy_structure(path: Path) -> None:
    """Check a legacy VTK file's points and cells against their counts before VTK reads it.

    VTK's legacy reader trusts the counts: a cell whose point count was damaged makes it read past
    its buffer, which can crash the process (seen with VTK 9.4 and 9.7), and no Python code can
    catch that. Everything after the
    cells (point data, fields) is left to VTK, which checks it.
    """
    cur = _Legacy(path.read_bytes())
    if not cur.line().startswith("# vtk DataFile Version"):
        raise _ParseError("no '# vtk DataFile Version' line: not a legacy VTK file")
    cur.line()  # the title
    form = cur.line().upper()
    if form not in ("ASCII", "BINARY"):
        raise _ParseError(f"the third line says {form[:20]!r}, not ASCII or BINARY")
    cur.binary = form == "BINARY"
    n_points = None
    while words := cur.line(needed=False).split():
        key = words[0].upper()
        if key == "DATASET":
            continue
        if key == "POINTS" and len(words) == 3 and words[1].isdigit():
            n_points = int(words[1])
            cur.numbers(3 * n_points, words[2], "POINTS")
        elif key in _LEGACY_CELLS and len(words) == 3 and words[1].isdigit() and words[2].isdigit():
            if n_points is None:
                raise _ParseError(f"{key} before POINTS")
            n, size = int(words[1]), int(words[2])
            mark = cur.pos
            nxt = cur.line(needed=False).split() or [""]
            if nxt[0].upper() == "OFFSETS" and len(nxt) == 2:  # version 5.1: offsets, then connectivity
                offsets = cur.numbers(n, nxt[1], f"{key} offsets")
                conn_words = cur.line().split()
                if conn_words[0].upper() != "CONNECTIVITY" or len(conn_words) != 2:
                    raise _ParseError(f"{key}: no CONNECTIVITY after its OFFSETS")
                connectivity = cur.numbers(size, conn_words[1], f"{key} connectivity")
                if n and (offsets[0] != 0 or np.any(np.diff(offsets) < 0) or offsets[-1] != size):
                    raise _ParseError(f"{key}: its offsets do not run from 0 to the connectivity's {size:,}")
                if size and (connectivity.min() < 0 or connectivity.max() >= n_points):
                    raise _ParseError(f"{key}: a point index outside the {n_points:,} points")
            else:
                cur.pos = mark
                _check_cells(cur.numbers(size, "int", key), n, n_points, key)
        elif key == "CELL_TYPES" and len(words) == 2 and words[1].isdigit():
            cur.numbers(int(words[1]), "int", key)
        elif key == "METADATA":
            continue
        else:  # point or cell data, fields: VTK checks those itself
            return


def _read_vtk_file(path: Path) -> _RawMesh:
    extension = path.suffix.lower()
    vtk = _import_vtk("reading", extension)
    if extension == ".vtk":
        try:
            _check_legacy_structure(path)
        except _ParseError as exc:
            raise _ParseError(f"not a valid .vtk file ({exc})") from None
    to_numpy = vtk["numpy_support"].vtk_to_numpy
    if extension == ".vtp":
        reader = vtk["vtkIOXML"].vtkXMLPolyDataReader()
    else:
        reader = vtk["vtkIOLegacy"].vtkDataSetReader()
        reader.ReadAllScalarsOn()
        reader.ReadAllColorScalarsOn()
        reader.ReadAllFieldsOn()
    reader.SetFileName(str(path))
    with _vtk_messages(vtk["vtkCommonCore"]) as messages:
        reader.Update()
        output = reader.GetOutput()  # may re-read the header, and complain again
    if messages or output is None:
        detail = messages[0] if messages else "VTK could not read it"
        raise _ParseError(f"not a valid {extension} file ({detail})")
    kind = output.GetClassName()
    triangles = []
    if kind == "vtkPolyData":
        triangles.append(_fan(*_vtk_cells(output.GetPolys())))
        triangles.append(_strip_triangles(*_vtk_cells(output.GetStrips())))
    elif kind == "vtkUnstructuredGrid":
        counts, connectivity = _vtk_cells(output.GetCells())
        version = vtk["vtkCommonCore"].vtkVersion
        if (version.GetVTKMajorVersion(), version.GetVTKMinorVersion()) >= (9, 6):
            types = to_numpy(output.GetCellTypes())
        else:  # deprecated since 9.6; GetCellTypes meant something else before
            types = to_numpy(output.GetCellTypesArray())
        for cell_types, split in (((5, 7, 9), _fan), ((6,), _strip_triangles)):  # VTK cell type ids
            keep = np.isin(types, cell_types)
            triangles.append(split(counts[keep], connectivity[np.repeat(keep, counts)]))
    else:
        raise _ParseError(f"holds a {kind[3:]} dataset, not a surface (POLYDATA)")
    points = output.GetPoints()
    if points is None:
        raise _ParseError("the file holds no points")
    vertices = np.array(to_numpy(points.GetData()), dtype=np.float64)
    colors, scalars = None, {}
    point_data = output.GetPointData()
    for i in range(point_data.GetNumberOfArrays()):
        array = point_data.GetArray(i)
        if array is None:  # string arrays and the like
            continue
        values = to_numpy(array)
        n_components = array.GetNumberOfComponents()
        if n_components == 1:
            scalars[array.GetName() or f"array{i}"] = np.array(values, dtype=np.float64)
        elif values.dtype == np.uint8 and n_components in (3, 4) and colors is None:
            colors = np.array(values, dtype=np.uint8)
    return _RawMesh(vertices, np.concatenate(triangles), colors, scalars)


def _write_vtk(path: Path, vertices, faces, colors, scalars, binary: bool) -> None:
    """Legacy VTK 4.2 POLYDATA; numpy, because VTK's ASCII writer keeps only 11 digits.

    Version 4.2 (not 5.1) so that older readers (ParaView < 5.9, scalismo, ...) load it.
    """
    n, m = len(vertices), len(faces)
    cells = np.column_stack([np.full(m, 3, dtype=np.int64), faces])

    def block(values: np.ndarray, dtype: str, per_line: int) -> bytes:
        if binary:  # legacy binary VTK is big-endian, followed by a newline
            return np.ascontiguousarray(values, dtype=dtype).tobytes() + b"\n"
        text = _floats_text if dtype[1] == "f" else _ints_text
        return text(values, per_line).encode()

    with open(path, "wb") as fh:
        fh.write(
            b"# vtk DataFile Version 4.2\nwritten by hortishape\n"
            + (b"BINARY\n" if binary else b"ASCII\n")
            + b"DATASET POLYDATA\n"
            + f"POINTS {n} double\n".encode()
        )
        fh.write(block(vertices, ">f8", 3))
        fh.write(f"POLYGONS {m} {4 * m}\n".encode())
        fh.write(block(cells, ">i4", 4))
        if colors is None and not scalars:
            return
        fh.write(f"POINT_DATA {n}\n".encode())
        if colors is not None:
            k = colors.shape[1]
            fh.write(f"COLOR_SCALARS colors {k}\n".encode())
            # Binary colour scalars are bytes; ASCII ones are floats in [0, 1].
            fh.write(
                colors.tobytes() + b"\n"
                if binary
                else _floats_text(colors / 255.0, k).encode("ascii")
            )
        if scalars:
            fh.write(f"FIELD FieldData {len(scalars)}\n".encode())
            for name, values in scalars.items():
                fh.write(f"{name} 1 {n} double\n".encode())
                fh.write(block(values, ">f8", 1))


def _write_vtp(path: Path, vertices, faces, colors, scalars, binary: bool) -> None:
    vtk = _import_vtk("writing", ".vtp")
    to_vtk = vtk["numpy_support"].numpy_to_vtk
    to_ids = vtk["numpy_support"].numpy_to_vtkIdTypeArray
    polydata = vtk["vtkCommonDataModel"].vtkPolyData()
    points = vtk["vtkCommonCore"].vtkPoints()
    points.SetData(to_vtk(np.ascontiguousarray(vertices, dtype=np.float64), deep=True))
    polydata.SetPoints(points)
    cells = vtk["vtkCommonDataModel"].vtkCellArray()
    offsets = np.arange(0, 3 * len(faces) + 1, 3, dtype=np.int64)
    cells.SetData(
        to_ids(offsets, deep=True), to_ids(np.ascontiguousarray(faces.ravel()), deep=True)
    )
    polydata.SetPolys(cells)
    point_data = polydata.GetPointData()
    if colors is not None:
        array = to_vtk(np.ascontiguousarray(colors), deep=True)
        array.SetName("colors")
        point_data.SetScalars(array)
    for name, values in scalars.items():
        array = to_vtk(np.ascontiguousarray(values), deep=True)
        array.SetName(name)
        point_data.AddArray(array)
    writer = vtk["vtkIOXML"].vtkXMLPolyDataWriter()
    writer.SetFileName(str(path))
    writer.SetInputData(polydata)
    if binary:
        writer.SetDataModeToAppended()
        writer.EncodeAppendedDataOff()  # raw bytes, not base64
    else:
        writer.SetDataModeToAscii()
    with _vtk_messages(vtk["vtkCommonCore"]) as messages:
        ok = writer.Write()
    if not ok or messages:
        raise OSError(messages[0] if messages else "VTK could not write the file")
