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


def _read_vtk_file(path: Path) -> _RawMesh:
    extension = path.suffix.lower()
    vtk = _import_vtk("reading", extension)
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
