"""Reading and writing triangle meshes and CT volumes.

Meshes
------
:func:`read_mesh` / :func:`write_mesh` handle ``.ply``, ``.stl``, ``.obj``,
``.off``, ``.vtk`` (legacy POLYDATA) and ``.vtp`` (VTK XML PolyData), chosen
by the file extension (case-insensitive) through a registry keyed by extension.

Vertex order is the correspondence in hortishape, so no reader merges, drops or
reorders vertices, with one documented exception: STL is a triangle soup that
cannot store vertex order. STL corners with identical coordinates are welded,
numbered in order of first appearance. An STL round trip therefore keeps the
order only for meshes whose vertices are numbered in order of first use in
``faces`` (no unreferenced vertices, no two vertices at the same position);
:func:`write_mesh` warns when a mesh does not meet that.

Polygons with more than three corners are fan-triangulated on read; lines and
points are ignored; a file without any triangle is an error.

Precision: binary STL stores float32 coordinates. Every other format stores
float64 (binary PLY/VTK/VTP) or the shortest decimal text that reads back to
the same float64 (ASCII PLY/STL/VTK, OBJ, OFF), so coordinates round-trip
exactly. (VTK's own legacy ASCII writer keeps only 11 digits, which is why
``.vtk`` is written here with numpy.)

Backends: PLY, STL, OBJ, OFF and writing legacy VTK are implemented with numpy
(vectorised; no Python loops over vertices or faces). Reading ``.vtk`` and
reading or writing ``.vtp`` use the optional ``vtk`` package
(``pip install "hortishape[vtk]"``), imported only when needed.

Volumes
-------
:class:`Volume` holds ``data`` indexed ``[x, y, z]``: ITK and SimpleITK
arrays are indexed ``(z, y, x)`` and are transposed once, here, at the
boundary. Lengths are millimetres. World coordinates follow ITK's convention
(the one MetaImage, NRRD and DICOM headers and SimpleITK use)::

    world = origin + direction @ (spacing * [i, j, k])

MetaImage (``.mha`` / ``.mhd``) is read and written natively with numpy;
NRRD, NIfTI, DICOM series folders and TIFF stacks go through the optional
``SimpleITK`` package (``pip install "hortishape[ct]"``).

All writers are atomic: data go to a temporary file next to the target,
which replaces the target only once complete.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import re
import secrets
import warnings
import zlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from itertools import chain
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple, TypeAlias

import numpy as np
import numpy.typing as npt

from .errors import MeshError, VolumeError
from .mesh import Mesh, check_mesh

__all__ = [
    "MeshData",
    "Volume",
    "is_mesh_file",
    "mesh_formats",
    "read_mesh",
    "read_mesh_data",
    "read_volume",
    "volume_formats",
    "write_mesh",
    "write_volume",
]

PathLike: TypeAlias = "str | os.PathLike[str]"


class _ParseError(Exception):
    """A format parser found broken content; the caller adds the file name."""


class _MissingDependencyError(Exception):
    """An optional package is not installed; the message names it."""


# --------------------------------------------------------------------------
# Files: checks shared by readers and the atomic writer
# --------------------------------------------------------------------------


def _full_suffix(path: Path) -> str:
    """Lower-case extension, treating ``.nii.gz`` as one extension."""
    name = path.name.lower()
    if name.endswith(".nii.gz"):
        return ".nii.gz"
    return path.suffix.lower()


def _check_exists(path: Path, error: type[Exception]) -> None:
    if not path.exists():
        raise error(f"{path}: no such file")
    if path.is_dir():
        raise error(f"{path}: is a directory, not a file")


def _check_not_empty(path: Path, error: type[Exception]) -> None:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise error(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    if size == 0:
        raise error(f"{path}: the file is empty")


@contextlib.contextmanager
def atomic_path(path: Path, error: type[Exception]) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; move it onto ``path`` on success.

    Every hortishape file is written through this (meshes, volumes, models,
    pictures, logs), so no reader ever sees a half-written file.

    The temporary name starts with a dot (so folder scans skip it) and ends with
    the target's extension (SimpleITK picks its writer by extension). On any
    exception the temporary file is removed and ``path`` is left untouched.
    """
    if path.is_dir():
        raise error(f"{path}: is a directory")
    parent = path.parent
    if not parent.is_dir():
        raise error(f"{path}: cannot write, the folder {parent} does not exist")
    suffix = _full_suffix(path)
    for _ in range(100):
        tmp = parent / f".{path.name}.{secrets.token_hex(4)}.tmp{suffix}"
        try:
            # O_EXCL: never clobber another writer's file; mode 0o666 lets the
            # umask give the file the permissions a normal open() would.
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise error(f"{path}: cannot write ({exc.strerror or exc})") from None
        os.close(fd)
        break
    else:  # pragma: no cover - 100 collisions of 32 random bits
        raise error(f"{path}: cannot create a temporary file next to it")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise error(f"{path}: cannot write ({exc.strerror or exc})") from None
        raise


# --------------------------------------------------------------------------
# Meshes: public types
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class MeshData:
    """A mesh together with the per-vertex attributes its file carried.

    Attributes
    ----------
    mesh : Mesh
        Vertices ``(n, 3) float64`` and triangles ``(m, 3) int64``.
    vertex_colors : (n, 3) or (n, 4) uint8 ndarray or None
        RGB or RGBA colours, when the file has integer-typed colours.
    vertex_scalars : mapping of str to (n,) float64 ndarray
        Every other numeric single-valued vertex property, by name (for PLY
        e.g. ``nx``, ``s``, ``quality``; for VTK/VTP the one-component point
        data arrays). Empty for STL, OBJ and OFF.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = pathlib.Path(tmp.name)
    >>> m = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> path = write_mesh(folder / "tri.ply", m, vertex_scalars={"error": [0.0, 0.5, 1.0]})
    >>> read_mesh_data(path).vertex_scalars["error"].tolist()
    [0.0, 0.5, 1.0]
    """

    mesh: Mesh
    vertex_colors: np.ndarray | None = None
    vertex_scalars: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = self.mesh.n_vertices
        colors = _check_colors(self.vertex_colors, n, name="mesh data")
        scalars = _check_scalars(self.vertex_scalars, n, name="mesh data")
        if colors is not None:
            colors.flags.writeable = False
        for values in scalars.values():
            values.flags.writeable = False
        object.__setattr__(self, "vertex_colors", colors)
        object.__setattr__(self, "vertex_scalars", MappingProxyType(scalars))


class _RawMesh(NamedTuple):
    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None = None
    scalars: dict[str, np.ndarray] | None = None


class _MeshFormat(NamedTuple):
    name: str
    read: Callable[[Path], _RawMesh]
    write: Callable[..., None]
    binary: tuple[bool, ...]  # allowed values of ``binary``; the first is the default
    attributes: bool  # can store vertex colours and scalars


_COLOR_NAMES = ("red", "green", "blue", "alpha")
# "colors" is the name of the colour array in VTK files; a scalar of that name would replace it.
_RESERVED_NAMES = frozenset(("x", "y", "z", *_COLOR_NAMES, "colors"))


def _check_colors(colors: Any, n: int, *, name: str) -> np.ndarray | None:
    if colors is None:
        return None
    c = np.asarray(colors)
    if c.ndim != 2 or c.shape[0] != n or c.shape[1] not in (3, 4):
        raise MeshError(
            f"{name}: vertex_colors must have shape ({n}, 3) or ({n}, 4), got {c.shape}"
        )
    in_range = c.dtype.kind in "iu" and (c.size == 0 or (c.min() >= 0 and c.max() <= 255))
    if c.dtype != np.uint8 and not in_range:
        raise MeshError(f"{name}: vertex_colors must be integers in 0..255 (uint8), got {c.dtype}")
    return np.array(c, dtype=np.uint8)


def _check_scalars(scalars: Any, n: int, *, name: str) -> dict[str, np.ndarray]:
    if scalars is None:
        return {}
    if not isinstance(scalars, Mapping):
        raise MeshError(f"{name}: vertex_scalars must be a dict of name -> (n,) array")
    out: dict[str, np.ndarray] = {}
    for key, values in scalars.items():
        if not isinstance(key, str) or not re.fullmatch(r"[^\s]+", key) or key in _RESERVED_NAMES:
            raise MeshError(
                f"{name}: vertex scalar name {key!r} must be a non-empty string without "
                f"spaces and not one of {sorted(_RESERVED_NAMES)}"
            )
        try:
            v = np.array(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise MeshError(f"{name}: vertex scalar {key!r} is not numeric") from None
        if v.shape != (n,):
            raise MeshError(f"{name}: vertex scalar {key!r} must have shape ({n},), got {v.shape}")
        out[key] = v
    return out


# --------------------------------------------------------------------------
# Polygon helpers (vectorised)
# --------------------------------------------------------------------------


def _segments(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start offsets of runs of the given lengths, and each element's rank in its run."""
    counts = np.asarray(counts, dtype=np.int64)
    ends = np.cumsum(counts)
    starts = ends - counts
    total = int(ends[-1]) if counts.size else 0
    within = np.arange(total, dtype=np.int64) - np.repeat(starts, counts)
    return starts, within


def _fan(counts: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons given as lengths and concatenated corner indices.

    Parameters
    ----------
    counts : (k,) int
        Number of corners of each polygon; polygons with fewer than 3 are skipped.
    corners : (sum(counts),) int

    Returns
    -------
    (t, 3) int64 ndarray
        Polygon ``(a, b, c, d)`` gives ``(a, b, c), (a, c, d)``.
    """
    counts = np.asarray(counts, dtype=np.int64)
    corners = np.asarray(corners, dtype=np.int64)
    starts, _ = _segments(counts)
    keep = counts >= 3
    n_tri = counts[keep] - 2
    first = np.repeat(starts[keep], n_tri)
    _, t = _segments(n_tri)
    return np.stack([corners[first], corners[first + t + 1], corners[first + t + 2]], axis=1)


def _strip_triangles(counts: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Triangles of triangle strips, every other one flipped to keep the orientation."""
    counts = np.asarray(counts, dtype=np.int64)
    corners = np.asarray(corners, dtype=np.int64)
    starts, _ = _segments(counts)
    keep = counts >= 3
    n_tri = counts[keep] - 2
    first = np.repeat(starts[keep], n_tri)
    _, t = _segments(n_tri)
    a, b, c = corners[first + t], corners[first + t + 1], corners[first + t + 2]
    odd = t % 2 == 1
    return np.stack([np.where(odd, b, a), np.where(odd, a, b), c], axis=1)


def _floats_text(values: np.ndarray, per_line: int, prefix: str = "") -> str:
    """Rows of floats as the shortest text that reads back to the same float64.

    One %-format over all rows, so the loop runs in C (``repr`` of a Python
    float is the shortest exact decimal).
    """
    n = values.size // per_line
    line = prefix + " ".join(["%r"] * per_line) + "\n"
    return (line * n) % tuple(np.asarray(values, dtype=np.float64).ravel().tolist())


def _ints_text(values: np.ndarray, per_line: int, prefix: str = "") -> str:
    """Rows of integers as text, like :func:`_floats_text`."""
    n = values.size // per_line
    line = prefix + " ".join(["%d"] * per_line) + "\n"
    return (line * n) % tuple(np.asarray(values, dtype=np.int64).ravel().tolist())


# --------------------------------------------------------------------------
# PLY
# --------------------------------------------------------------------------

_PLY_TYPES = MappingProxyType(
    {
        "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
        "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
        "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
        "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
    }
)  # fmt: skip


class _PlyProperty(NamedTuple):
    name: str
    code: str  # numpy type code without byte order, e.g. "f4"
    length_code: str | None  # type code of a list's length, None for a scalar


class _PlyElement(NamedTuple):
    name: str
    n_records: int
    props: tuple[_PlyProperty, ...]


def _ply_header(data: bytes) -> tuple[str, list[_PlyElement], int]:
    """Parse a PLY header: format, elements and the offset where the body starts."""
    if data[:64].lstrip()[:3] != b"ply":
        raise _ParseError("does not start with 'ply' (not a PLY file)")
    # A whole line, so that "comment ... end_header" does not end the header.
    match = re.search(rb"^end_header[ \t]*(\r?\n|$)", data, re.M)
    if match is None:
        raise _ParseError("the header has no 'end_header' line (truncated, or not a PLY file)")
    end, body = match.start(), match.end()
    fmt = None
    elements: list[_PlyElement] = []
    props: list[_PlyProperty] = []
    for line in data[:end].decode("latin-1").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
                if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
                    raise _ParseError(f"unknown PLY format {fmt!r}")
            elif words[0] == "element":
                if elements:
                    elements[-1] = elements[-1]._replace(props=tuple(props))
                count = int(words[2])
                if count < 0:
                    raise ValueError
                elements.append(_PlyElement(words[1], count, ()))
                props = []
            elif words[0] == "property":
                if not elements:
                    raise _ParseError(f"header line {line.strip()!r} comes before any element")
                if words[1] == "list":
                    props.append(_PlyProperty(words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]]))
                else:
                    props.append(_PlyProperty(words[2], _PLY_TYPES[words[1]], None))
            else:
                raise _ParseError(f"unexpected header line {line.strip()!r}")
        except (IndexError, KeyError, ValueError):
            raise _ParseError(f"bad header line {line.strip()!r}") from None
    if elements:
        elements[-1] = elements[-1]._replace(props=tuple(props))
    if fmt is None:
        raise _ParseError("the header has no 'format' line")
    return fmt, elements, body


class _AsciiStream:
    """ASCII PLY body as one float64 array of tokens; a value is one position."""

    def __init__(self, values: np.ndarray) -> None:
        self.values = values
        self.length = int(values.size)

    def size(self, code: str) -> int:
        return 1

    def get(self, pos: np.ndarray, code: str, *, clip: bool = False) -> np.ndarray:
        if clip:
            if self.length == 0:
                return np.zeros(pos.shape, dtype=np.int64 if code[0] != "f" else np.float64)
            v = self.values[np.clip(pos, 0, self.length - 1)]
            if code[0] == "f":
                return v
            # Guesses may land on any token: keep them finite and castable.
            return np.where(np.isfinite(v), np.clip(v, -1, 2**40), -1).astype(np.int64)
        v = self.values[pos]
        if code[0] == "f":
            return v
        if not np.all(np.isfinite(v) & (v == np.floor(v))):
            raise _ParseError("an integer property holds a non-integer value")
        return v.astype(np.int64)


class _BinaryStream:
    """Binary PLY body as bytes; a value is ``itemsize`` positions."""

    def __init__(self, buffer: np.ndarray, byteorder: str) -> None:
        self.buffer = buffer
        self.byteorder = byteorder
        self.length = int(buffer.size)

    def size(self, code: str) -> int:
        return int(code[1])

    def get(self, pos: np.ndarray, code: str, *, clip: bool = False) -> np.ndarray:
        size = int(code[1])
        if clip:
            if self.length < size:
                return np.zeros(pos.shape, dtype=code)
            pos = np.clip(pos, 0, self.length - size)
        raw = self.buffer[pos[:, None] + np.arange(size)]
        return raw.view(self.byteorder + code).reshape(-1)


def _ply_walk(stream: _AsciiStream | _BinaryStream, pos: np.ndarray, props) -> np.ndarray:
    """End positions of records starting at ``pos`` (corrupt lengths run past the end)."""
    p = np.array(pos, dtype=np.int64)
    for prop in props:
        if prop.length_code is None:
            p += stream.size(prop.code)
        else:
            c = stream.get(p, prop.length_code, clip=True).astype(np.int64)
            c[c < 0] = stream.length + 1
            p += stream.size(prop.length_code) + c * stream.size(prop.code)
    return p


def _ply_chain(stream: _AsciiStream | _BinaryStream, start: int, count: int, props) -> np.ndarray:
    """Starts of ``count`` consecutive variable-length records, without a Python loop per record.

    Every position is given its successor (where a record starting there would
    end); the chain from ``start`` is then built by pointer doubling, in
    O(N log count) vectorised steps.
    """
    n = stream.length
    nxt = np.minimum(_ply_walk(stream, np.arange(start, n, dtype=np.int64), props), n)
    jump = np.append(nxt, n)  # indexed by position - start; the end maps to itself
    chain_ = np.array([start], dtype=np.int64)
    while chain_.size < count:
        chain_ = np.concatenate([chain_, jump[chain_ - start]])
        jump = jump[jump - start]
    return chain_[:count]


def _ply_element(stream: _AsciiStream | _BinaryStream, start: int, element: _PlyElement):
    """Parse one element: its columns (scalars as arrays, lists as (counts, values)) and end."""
    props, count = element.props, element.n_records
    # Every record needs at least its scalars and list lengths: reject absurd
    # counts before allocating per-record arrays.
    least = sum(stream.size(p.length_code or p.code) for p in props)
    if start + count * least > stream.length:
        raise _ParseError(
            f"truncated: the {count} '{element.name}' records need more data than the file holds"
        )
    if count == 0 or not props:
        starts = np.zeros(0, dtype=np.int64)
        end = start
    elif all(p.length_code is None for p in props):
        record = sum(stream.size(p.code) for p in props)
        starts = start + np.arange(count, dtype=np.int64) * record
        end = start + count * record
    else:
        # Fast path: every record as long as the first (e.g. all triangles).
        first = int(_ply_walk(stream, np.array([start]), props)[0]) - start
        starts = start + np.arange(count, dtype=np.int64) * first
        if not np.array_equal(_ply_walk(stream, starts, props), starts + first):
            starts = _ply_chain(stream, start, count, props)
        end = int(_ply_walk(stream, starts[-1:], props)[0])
    if end > stream.length:
        raise _ParseError(
            f"truncated: the {count} '{element.name}' records need more data than the file holds"
        )
    columns: dict[str, Any] = {}
    p = starts.copy()
    for prop in props:
        if prop.length_code is None:
            columns[prop.name] = stream.get(p, prop.code)
            p += stream.size(prop.code)
        else:
            c = stream.get(p, prop.length_code).astype(np.int64)
            if c.size and c.min() < 0:
                raise _ParseError(
                    f"negative list length in '{element.name}' property '{prop.name}'"
                )
            p += stream.size(prop.length_code)
            _, within = _segments(c)
            flat = np.repeat(p, c) + within * stream.size(prop.code)
            columns[prop.name] = (c, stream.get(flat, prop.code))
            p += c * stream.size(prop.code)
    return columns, end


def _read_ply(path: Path) -> _RawMesh:
    data = path.read_bytes()
    fmt, elements, body = _ply_header(data)
    if fmt == "ascii":
        try:
            values = np.array(data[body:].split(), dtype=np.float64)
        except ValueError as exc:
            raise _ParseError(
                f"the ASCII data hold something that is not a number ({exc})"
            ) from None
        stream: _AsciiStream | _BinaryStream = _AsciiStream(values)
        pos = 0
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        stream = _BinaryStream(np.frombuffer(data, dtype=np.uint8, offset=body), order)
        pos = 0
    found: dict[str, tuple[_PlyElement, dict]] = {}
    for element in elements:
        columns, pos = _ply_element(stream, pos, element)
        if element.name in ("vertex", "face") and element.name not in found:
            found[element.name] = (element, columns)
        if len(found) == 2:  # later elements (edges, materials) are not needed
            break
    if "vertex" not in found:
        raise _ParseError("the header declares no 'vertex' element")
    velement, vcols = found["vertex"]
    if not {"x", "y", "z"} <= vcols.keys():
        raise _ParseError("the vertex element has no x, y, z properties")
    vertices = np.column_stack([vcols[k] for k in "xyz"]).astype(np.float64)
    codes = {p.name: p.code for p in velement.props if p.length_code is None}
    color_names = [c for c in _COLOR_NAMES if c in codes]
    colors = None
    # Integer-typed red/green/blue are colours; float-typed ones have no agreed
    # scale (0..1 or 0..255), so they are passed on as scalars instead.
    if {"red", "green", "blue"} <= set(color_names) and all(
        codes[c][0] in "iu" for c in color_names
    ):
        colors = np.clip(np.column_stack([vcols[c] for c in color_names]), 0, 255).astype(np.uint8)
    else:
        color_names = []
    scalars = {
        name: np.asarray(vcols[name], dtype=np.float64)
        for name in codes
        if name not in ("x", "y", "z") and name not in color_names
    }
    faces = np.zeros((0, 3), dtype=np.int64)
    if "face" in found:
        felement, fcols = found["face"]
        lists = [p.name for p in felement.props if p.length_code is not None]
        key: str | None = next((k for k in ("vertex_indices", "vertex_index") if k in lists), None)
        if key is None and len(lists) == 1:
            key = lists[0]
        if key is None:
            raise _ParseError("the face element has no 'vertex_indices' list")
        counts, corners = fcols[key]
        faces = _fan(counts, corners)
    return _RawMesh(vertices, faces, colors, scalars)


def _write_ply(path: Path, vertices, faces, colors, scalars, binary: bool) -> None:
    n, m = len(vertices), len(faces)
    columns: list[tuple[str, str, np.ndarray]] = [
        (k, "f8", vertices[:, i]) for i, k in enumerate("xyz")
    ]
    if colors is not None:
        columns += [(_COLOR_NAMES[i], "u1", colors[:, i]) for i in range(colors.shape[1])]
    columns += [(name, "f8", values) for name, values in scalars.items()]
    index = "int" if n < 2**31 else "uint"
    header = (
        "ply\n"
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0\n"
        "comment written by hortishape\n"
        f"element vertex {n}\n"
        + "".join(
            f"property {'double' if code == 'f8' else 'uchar'} {name}\n"
            for name, code, _ in columns
        )
        + f"element face {m}\n"
        f"property list uchar {index} vertex_indices\n"
        "end_header\n"
    )
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        if binary:
            records = np.empty(n, dtype=[(name, "<" + code) for name, code, _ in columns])
            for name, _, values in columns:
                records[name] = values
            fh.write(records.tobytes())
            tris = np.empty(m, dtype=[("n", "u1"), ("i", "<i4" if index == "int" else "<u4", (3,))])
            tris["n"] = 3
            tris["i"] = faces
            fh.write(tris.tobytes())
        else:
            line = " ".join("%r" if code == "f8" else "%d" for _, code, _ in columns) + "\n"
            cols = [
                values.tolist() if code == "u1" else np.asarray(values, np.float64).tolist()
                for _, code, values in columns
            ]
            fh.write(((line * n) % tuple(chain.from_iterable(zip(*cols, strict=True)))).encode())
            fh.write(_ints_text(faces, 3, prefix="3 ").encode())


# --------------------------------------------------------------------------
# STL
# --------------------------------------------------------------------------

_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def _weld(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge identical corner coordinates, numbering vertices in order of first appearance.

    Parameters
    ----------
    corners : (m, 3, 3) float
        Triangle soup.

    Returns
    -------
    vertices : (n, 3) float64 ndarray
    faces : (m, 3) int64 ndarray
    """
    flat = np.ascontiguousarray(corners.reshape(-1, 3)) + 0.0  # -0.0 -> 0.0, so signed zeros weld
    rows = flat.view(np.dtype((np.void, flat.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    vertices = flat[first[order]].astype(np.float64)
    faces = rank[inverse.ravel()].reshape(-1, 3).astype(np.int64)
    return vertices, faces


def _read_stl(path: Path) -> _RawMesh:
    data = path.read_bytes()
    announced = int.from_bytes(data[80:84], "little") if len(data) >= 84 else -1
    is_text = data[:512].lstrip()[:5].lower() == b"solid"
    binary_size = 84 + 50 * announced
    # Binary files may also start with "solid", so the exact size decides first;
    # some exporters append padding, tolerated when the file is not text.
    if announced >= 0 and (len(data) == binary_size or (not is_text and len(data) > binary_size)):
        records = np.frombuffer(data, dtype=_STL_RECORD, count=announced, offset=84)
        vertices, faces = _weld(records["corners"])
        return _RawMesh(vertices, faces)
    if not is_text:
        raise _ParseError(
            f"neither a binary STL (its header announces {announced} triangles, "
            f"which need {binary_size} bytes, the file has {len(data)}) nor an ASCII STL "
            "(it does not start with 'solid')"
            if announced >= 0
            else "too short to be a binary STL and does not start with 'solid'"
        )
    # Tokens as one numpy bytes array: much faster than a regex on 100 MB of text.
    tokens = np.array(data.lower().split())
    at = np.flatnonzero(tokens == b"vertex")
    loops = int(np.count_nonzero(tokens == b"endloop"))
    if at.size != 3 * loops or (at.size and at[-1] + 3 >= tokens.size):
        raise _ParseError(
            f"found {at.size} vertices in {loops} facets; ASCII STL facets need exactly 3 "
            "(truncated file?)"
        )
    corners = tokens[at[:, None] + np.arange(1, 4)].astype(np.float64).reshape(-1, 3, 3)
    vertices, faces = _weld(corners)
    return _RawMesh(vertices, faces)


def _face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def _write_stl(path: Path, vertices, faces, colors, scalars, binary: bool) -> None:
    normals = _face_normals(vertices, faces)
    if binary:
        records = np.zeros(len(faces), dtype=_STL_RECORD)
        records["normal"] = normals
        records["corners"] = vertices[faces]
        # The header must not start with "solid": readers would take it for ASCII.
        header = b"binary STL written by hortishape".ljust(80, b" ")
        with open(path, "wb") as fh:
            fh.write(header)
            fh.write(np.uint32(len(faces)).tobytes())
            fh.write(records.tobytes())
        return
    facet = (
        "facet normal %r %r %r\n outer loop\n  vertex %r %r %r\n  vertex %r %r %r\n"
        "  vertex %r %r %r\n endloop\nendfacet\n"
    )
    values = np.concatenate([normals, vertices[faces].reshape(-1, 9)], axis=1)
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("solid hortishape\n")
        fh.write((facet * len(faces)) % tuple(values.ravel().tolist()))
        fh.write("endsolid hortishape\n")


def _stl_keeps_order(vertices: np.ndarray, faces: np.ndarray, binary: bool) -> bool:
    """True if writing then reading STL gives back the same vertex numbering."""
    used, first = np.unique(faces.ravel(), return_index=True)
    # ``used`` is sorted: all vertices used, and vertex i first used before vertex i + 1.
    if used.size != len(vertices) or np.any(np.diff(first) <= 0):
        return False
    stored = (vertices.astype(np.float32) if binary else vertices) + 0.0
    return np.unique(stored, axis=0).shape[0] == len(vertices)


# --------------------------------------------------------------------------
# OBJ
# --------------------------------------------------------------------------


def _polygon_lines(lines: list[str]) -> tuple[np.ndarray, list[str]]:
    """Number of tokens on each line and all tokens, in order."""
    tokens = list(map(str.split, lines))
    counts = np.fromiter(map(len, tokens), dtype=np.int64, count=len(tokens))
    return counts, list(chain.from_iterable(tokens))


def _read_obj(path: Path) -> _RawMesh:
    text = path.read_bytes().decode("latin-1").replace("\\\n", " ")
    coords = re.findall(r"^[ \t]*v[ \t]+(\S+)[ \t]+(\S+)[ \t]+(\S+)", text, re.M)
    n_v_lines = len(re.findall(r"^[ \t]*v[ \t]", text, re.M))
    if len(coords) != n_v_lines:
        raise _ParseError("a 'v' line has fewer than 3 coordinates")
    vertices = np.array(coords, dtype=np.float64).reshape(-1, 3)
    face_lines = re.findall(r"^[ \t]*f[ \t]+(.*)$", text, re.M)
    counts, tokens = _polygon_lines(face_lines)
    # "v/vt/vn": only the position index matters, texture and normal indices
    # have their own numbering and never re-index the vertices.
    indices = np.array(re.sub(r"/\S*", "", " ".join(tokens)).split(), dtype=np.int64)
    if indices.size != counts.sum():
        raise _ParseError("a face corner has no vertex index")
    if np.any(indices == 0):
        raise _ParseError("face index 0 found; OBJ indices start at 1")
    if np.any(indices < 0):
        # Negative indices count back from the last vertex defined before the face.
        kinds = np.array(re.findall(r"^[ \t]*([vf])[ \t]", text, re.M))
        defined = np.cumsum(kinds == "v")[kinds == "f"]
        indices = np.where(indices < 0, np.repeat(defined, counts) + indices, indices - 1)
    else:
        indices = indices - 1
    return _RawMesh(vertices, _fan(counts, indices))


def _write_obj(path: Path, vertices, faces, colors, scalars, binary: bool) -> None:
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write("# written by hortishape\n")
        fh.write(_floats_text(vertices, 3, prefix="v "))
        fh.write(_ints_text(faces + 1, 3, prefix="f "))


# --------------------------------------------------------------------------
# OFF
# --------------------------------------------------------------------------


def _read_off(path: Path) -> _RawMesh:
    text = re.sub(r"#[^\n]*", "", path.read_bytes().decode("latin-1"))
    lines = list(filter(None, map(str.strip, text.splitlines())))
    if not lines:
        raise _ParseError("holds only comments")
    first = lines[0].split()
    if not re.fullmatch(r"(ST)?C?N?OFF", first[0]):
        if re.fullmatch(r"(ST)?C?N?4?n?OFF", first[0]):
            raise _ParseError(f"{first[0]} files (homogeneous or n-dimensional) are not supported")
        raise _ParseError("does not start with 'OFF' (not an OFF file)")
    if first[1:2] == ["BINARY"]:
        raise _ParseError("binary OFF files are not supported")
    counts_words, body = (
        (first[1:], 1) if len(first) > 1 else (lines[1].split() if len(lines) > 1 else [], 2)
    )
    try:
        n_vertices, n_faces = int(counts_words[0]), int(counts_words[1])
    except (IndexError, ValueError):
        raise _ParseError("the line after 'OFF' must give the vertex and face counts") from None
    vertex_lines = lines[body : body + n_vertices]
    face_lines = lines[body + n_vertices : body + n_vertices + n_faces]
    if len(vertex_lines) < n_vertices or len(face_lines) < n_faces:
        raise _ParseError(
            f"truncated: the header announces {n_vertices} vertices and {n_faces} faces"
        )
    coords = re.findall(r"^(\S+)[ \t]+(\S+)[ \t]+(\S+)", "\n".join(vertex_lines), re.M)
    if len(coords) != n_vertices:
        raise _ParseError("a vertex line has fewer than 3 coordinates")
    vertices = np.array(coords, dtype=np.float64).reshape(-1, 3)
    lengths, tokens = _polygon_lines(face_lines)
    values = np.array(tokens, dtype=np.float64)  # face lines may end with colour floats
    starts, _ = _segments(lengths)
    corners_per_face = values[starts] if n_faces else np.zeros(0)
    if np.any(corners_per_face != np.floor(corners_per_face)) or np.any(
        corners_per_face + 1 > lengths
    ):
        raise _ParseError("a face line has fewer indices than its corner count")
    k = corners_per_face.astype(np.int64)
    _, within = _segments(k)
    corners = values[np.repeat(starts + 1, k) + within]
    if np.any(corners != np.floor(corners)):
        raise _ParseError("a face index is not an integer")
    return _RawMesh(vertices, _fan(k, corners.astype(np.int64)))


def _write_off(path: Path, vertices, faces, colors, scalars, binary: bool) -> None:
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        fh.write(f"OFF\n{len(vertices)} {len(faces)} 0\n")
        fh.write(_floats_text(vertices, 3))
        fh.write(_ints_text(faces, 3, prefix="3 "))


# --------------------------------------------------------------------------
# VTK legacy and XML (through the optional vtk package)
# --------------------------------------------------------------------------

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


# --------------------------------------------------------------------------
# Mesh registry and public functions
# --------------------------------------------------------------------------

_MESH_FORMATS: Mapping[str, _MeshFormat] = MappingProxyType(
    {
        ".obj": _MeshFormat("OBJ", _read_obj, _write_obj, (False,), False),
        ".off": _MeshFormat("OFF", _read_off, _write_off, (False,), False),
        ".ply": _MeshFormat("PLY", _read_ply, _write_ply, (True, False), True),
        ".stl": _MeshFormat("STL", _read_stl, _write_stl, (True, False), False),
        ".vtk": _MeshFormat("legacy VTK", _read_vtk_file, _write_vtk, (True, False), True),
        ".vtp": _MeshFormat("VTK XML PolyData", _read_vtk_file, _write_vtp, (True, False), True),
    }
)


def mesh_formats() -> tuple[str, ...]:
    """The mesh file extensions :func:`read_mesh` and :func:`write_mesh` support.

    Returns
    -------
    tuple of str
        Lower-case extensions with the dot, sorted.

    Examples
    --------
    >>> mesh_formats()
    ('.obj', '.off', '.ply', '.stl', '.vtk', '.vtp')
    """
    return tuple(sorted(_MESH_FORMATS))


def is_mesh_file(path: PathLike) -> bool:
    """Whether ``path`` is an existing file with a supported mesh extension.

    Hidden files (name starting with a dot) are not mesh files: they are
    editor or OS leftovers (macOS ``._name.ply``) or temporary files of a write
    in progress.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    bool

    Examples
    --------
    >>> is_mesh_file("no/such/apple.ply")
    False
    """
    p = Path(path)
    return p.suffix.lower() in _MESH_FORMATS and not p.name.startswith(".") and p.is_file()


def _mesh_format(path: Path) -> _MeshFormat:
    fmt = _MESH_FORMATS.get(path.suffix.lower())
    if fmt is None:
        shown = path.suffix or "(none)"
        raise MeshError(
            f"{path}: unknown mesh format {shown!r}; supported: {', '.join(mesh_formats())}"
        )
    return fmt


def read_mesh_data(path: PathLike) -> MeshData:
    """Read a mesh and its per-vertex colours and scalars.

    Like :func:`read_mesh`, which returns only the mesh.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply``, ``.stl``, ``.obj``, ``.off``, ``.vtk`` or ``.vtp`` file.

    Returns
    -------
    MeshData
        ``mesh``, ``vertex_colors (n, 3|4) uint8 or None`` and
        ``vertex_scalars`` (name -> ``(n,) float64``).

    Raises
    ------
    MeshError
        See :func:`read_mesh`.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = pathlib.Path(tmp.name)
    >>> m = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> path = write_mesh(folder / "tri.ply", m, vertex_colors=[[255, 0, 0]] * 3)
    >>> read_mesh_data(path).vertex_colors[0].tolist()
    [255, 0, 0]
    """
    p = Path(path)
    _check_exists(p, MeshError)
    fmt = _mesh_format(p)
    _check_not_empty(p, MeshError)
    try:
        raw = fmt.read(p)
    except MeshError:
        raise
    except (_ParseError, _MissingDependencyError) as exc:
        raise MeshError(f"{p}: {exc}") from None
    except OSError as exc:
        raise MeshError(f"{p}: cannot read the file ({exc.strerror or exc})") from None
    except (ValueError, IndexError, TypeError, OverflowError) as exc:
        raise MeshError(f"{p}: not a valid {fmt.name} file ({exc})") from exc
    vertices, faces = check_mesh(raw.vertices, raw.faces, name=str(p))
    return MeshData(Mesh(vertices, faces), raw.colors, raw.scalars or {})


def read_mesh(path: PathLike) -> Mesh:
    """Read a triangle mesh, keeping the file's vertex order.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply`` (ASCII or binary, either byte order; extra vertex
        properties are ignored), ``.stl`` (ASCII or binary), ``.obj``,
        ``.off``, ``.vtk`` (legacy POLYDATA or UNSTRUCTURED_GRID) or ``.vtp``
        file. The extension is case-insensitive. ``.vtk`` and ``.vtp`` need
        the optional ``vtk`` package.

    Returns
    -------
    Mesh
        ``vertices (n, 3) float64`` in file order (STL: welded, in order of
        first appearance, see the module notes) and ``faces (m, 3) int64``;
        polygons are fan-triangulated, lines and points dropped.

    Raises
    ------
    MeshError
        The message starts with the path and names the problem: missing file,
        a directory, unknown extension, empty file, unparsable or truncated
        content, NaN or infinite coordinates, no triangles, a face index out
        of range, a missing optional dependency.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = pathlib.Path(tmp.name)
    >>> _ = (folder / "quad.obj").write_text("v 0 0 0\\nv 1 0 0\\nv 1 1 0\\nv 0 1 0\\nf 1 2 3 4\\n")
    >>> read_mesh(folder / "quad.obj").faces.tolist()
    [[0, 1, 2], [0, 2, 3]]
    """
    return read_mesh_data(path).mesh


def write_mesh(
    path: PathLike,
    mesh: Mesh | npt.ArrayLike,
    faces: npt.ArrayLike | None = None,
    *,
    vertex_colors: npt.ArrayLike | None = None,
    vertex_scalars: Mapping[str, npt.ArrayLike] | None = None,
    binary: bool | None = None,
) -> Path:
    """Write a triangle mesh atomically, in the format given by the extension.

    Parameters
    ----------
    path : str or os.PathLike
        Target file; its extension (case-insensitive) picks the format, see
        :func:`mesh_formats`. The folder must exist.
    mesh : Mesh or (n, 3) array_like of float
        The mesh, or its vertices (then ``faces`` is required).
    faces : (m, 3) array_like of int, optional
        Triangles, only when ``mesh`` is a vertex array.
    vertex_colors : (n, 3) or (n, 4) array_like of uint8, optional
        RGB(A) per vertex. Stored by ``.ply``, ``.vtk`` and ``.vtp`` only.
    vertex_scalars : dict of str to (n,) array_like of float, optional
        Named per-vertex values (e.g. an error map), stored as float64 vertex
        properties in ``.ply`` and as point data in ``.vtk`` / ``.vtp``.
        Names must not contain spaces nor be x, y, z, red, green, blue, alpha
        or colors.
    binary : bool, optional
        Binary or ASCII, for the formats that have both (PLY, STL, VTK, VTP).
        Default: binary for those; ``.obj`` and ``.off`` are text only and
        reject ``binary=True``.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        Unknown extension, invalid mesh or attributes, attributes the format
        cannot store, a missing folder, or the file cannot be written. The
        target is then left as it was and no temporary file remains.

    Warns
    -----
    UserWarning
        When writing STL a mesh whose vertex order STL cannot keep.

    Notes
    -----
    Binary STL stores float32 coordinates; every other format keeps float64
    coordinates exactly.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = pathlib.Path(tmp.name)
    >>> path = write_mesh(folder / "tri.off", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> read_mesh(path).n_faces
    1
    """
    p = Path(path)
    fmt = _mesh_format(p)
    if isinstance(mesh, Mesh):
        if faces is not None:
            raise MeshError(f"{p}: pass either a Mesh, or vertices and faces; not a Mesh and faces")
        vertices, tris = mesh.vertices, mesh.faces
    else:
        if faces is None:
            raise MeshError(f"{p}: faces are required when the mesh is given as a vertex array")
        vertices, tris = check_mesh(mesh, faces, name=str(p))
    colors = _check_colors(vertex_colors, len(vertices), name=str(p))
    scalars = _check_scalars(vertex_scalars, len(vertices), name=str(p))
    if not fmt.attributes and (colors is not None or scalars):
        raise MeshError(
            f"{p}: {fmt.name} files cannot store vertex colours or scalars; use .ply, .vtk or .vtp"
        )
    if binary is None:
        binary = fmt.binary[0]
    elif not isinstance(binary, (bool, np.bool_)):
        raise MeshError(f"{p}: binary must be True, False or None, got {binary!r}")
    elif bool(binary) not in fmt.binary:
        raise MeshError(f"{p}: {fmt.name} files are text only; binary=True is not possible")
    if fmt.name == "STL" and not _stl_keeps_order(vertices, tris, bool(binary)):
        warnings.warn(
            f"{p}: STL cannot store vertex order; reading it back renumbers the vertices in "
            "order of first use in the faces and drops unreferenced or duplicate vertices. "
            "Use .ply to keep correspondence.",
            UserWarning,
            stacklevel=2,
        )
    try:
        with atomic_path(p, MeshError) as tmp:
            fmt.write(tmp, vertices, tris, colors, scalars, bool(binary))
    except _MissingDependencyError as exc:
        raise MeshError(f"{p}: {exc}") from None
    return p


# --------------------------------------------------------------------------
# Volumes
# --------------------------------------------------------------------------


def _check_volume(data, spacing, origin, direction, *, name: str):
    """Validate and convert the parts of a volume; see :class:`Volume`."""
    arr = np.asarray(data)
    if arr.dtype.kind not in "biuf":
        raise VolumeError(f"{name}: voxel values must be numbers, got dtype {arr.dtype}")
    if arr.ndim != 3:
        what = "a 2D image" if arr.ndim == 2 else f"{arr.ndim}-dimensional"
        raise VolumeError(f"{name}: is {what}, not a 3D volume (shape {arr.shape})")
    if min(arr.shape) < 2:
        raise VolumeError(f"{name}: needs at least 2 voxels along each axis, got shape {arr.shape}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = int((~np.isfinite(arr)).sum())
        raise VolumeError(f"{name}: {bad} voxels are NaN or infinite")
    try:
        s = np.array(spacing, dtype=np.float64).reshape(-1)
        o = np.array(origin, dtype=np.float64).reshape(-1)
        d = np.array(direction, dtype=np.float64)
    except (TypeError, ValueError):
        raise VolumeError(f"{name}: spacing, origin and direction must be numeric") from None
    if s.size == 1:
        s = np.repeat(s, 3)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise VolumeError(
            f"{name}: spacing must be 3 positive finite numbers (mm), got {s.tolist()}"
        )
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise VolumeError(f"{name}: origin must be 3 finite numbers (mm), got {o.tolist()}")
    if d.shape != (3, 3) or not np.all(np.isfinite(d)):
        raise VolumeError(f"{name}: direction must be a finite 3 x 3 matrix, got shape {d.shape}")
    # Headers store directions with a few digits only, hence the tolerance.
    if np.abs(d.T @ d - np.eye(3)).max() > 1e-3:
        raise VolumeError(f"{name}: direction must be orthonormal (a rotation or reflection)")
    return arr, s, o, d


@dataclass(frozen=True, eq=False)
class Volume:
    """A 3D image: voxel values indexed ``[x, y, z]`` with its geometry in millimetres.

    Parameters
    ----------
    data : (nx, ny, nz) array_like of numbers
        Voxel values, at least 2 voxels along each axis, no NaN or infinity.
        Indexed ``data[x, y, z]`` (the transpose of ITK/SimpleITK's
        ``(z, y, x)`` arrays). Stored as a read-only view, not copied
        (volumes are large): do not modify the array you passed.
    spacing : (3,) array_like of float or float
        Voxel size along x, y, z in mm, positive.
    origin : (3,) array_like of float, default: (0, 0, 0)
        World position of voxel ``[0, 0, 0]`` in mm.
    direction : (3, 3) array_like of float, default: identity
        Orthonormal; column ``j`` is the world direction of index axis ``j``.

    Examples
    --------
    >>> v = Volume(np.zeros((4, 5, 6)), spacing=(0.5, 0.5, 2.0), origin=(10, 0, 0))
    >>> v.shape
    (4, 5, 6)
    >>> v.index_to_world([1, 2, 3]).tolist()
    [[10.5, 1.0, 6.0]]
    """

    data: np.ndarray
    spacing: np.ndarray
    origin: np.ndarray = None  # type: ignore[assignment]
    direction: np.ndarray = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        origin = np.zeros(3) if self.origin is None else self.origin
        direction = np.eye(3) if self.direction is None else self.direction
        arr, s, o, d = _check_volume(self.data, self.spacing, origin, direction, name="volume")
        view = arr.view()
        for a in (view, s, o, d):
            a.flags.writeable = False
        object.__setattr__(self, "data", view)
        object.__setattr__(self, "spacing", s)
        object.__setattr__(self, "origin", o)
        object.__setattr__(self, "direction", d)

    @property
    def shape(self) -> tuple[int, int, int]:
        """Number of voxels along x, y, z."""
        return tuple(int(k) for k in self.data.shape)  # type: ignore[return-value]

    def index_to_world(self, ijk: npt.ArrayLike) -> np.ndarray:
        """World coordinates (mm) of voxel indices.

        Parameters
        ----------
        ijk : (k, 3) or (3,) array_like of float
            Indices along x, y, z (may be fractional).

        Returns
        -------
        (k, 3) float64 ndarray
            ``origin + direction @ (spacing * ijk)`` for each row.

        Examples
        --------
        >>> Volume(np.zeros((2, 2, 2)), spacing=2.0).index_to_world([[1, 0, 0]]).tolist()
        [[2.0, 0.0, 0.0]]
        """
        p = np.atleast_2d(np.asarray(ijk, dtype=np.float64))
        if p.ndim != 2 or p.shape[1] != 3:
            raise VolumeError(f"indices must have shape (k, 3), got {np.shape(ijk)}")
        return self.origin + (p * self.spacing) @ self.direction.T

    def world_to_index(self, xyz: npt.ArrayLike) -> np.ndarray:
        """Continuous voxel indices of world points (mm); the inverse of :meth:`index_to_world`.

        Parameters
        ----------
        xyz : (k, 3) or (3,) array_like of float

        Returns
        -------
        (k, 3) float64 ndarray
            Fractional indices along x, y, z; round them to get a voxel.

        Examples
        --------
        >>> Volume(np.zeros((2, 2, 2)), spacing=2.0).world_to_index([[2, 0, 0]]).tolist()
        [[1.0, 0.0, 0.0]]
        """
        p = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
        if p.ndim != 2 or p.shape[1] != 3:
            raise VolumeError(f"points must have shape (k, 3), got {np.shape(xyz)}")
        return np.linalg.solve(self.direction, (p - self.origin).T).T / self.spacing


# MetaImage element types: numpy code (without byte order).
_MET_TYPES = MappingProxyType(
    {
        "MET_CHAR": "i1", "MET_UCHAR": "u1", "MET_SHORT": "i2", "MET_USHORT": "u2",
        "MET_INT": "i4", "MET_UINT": "u4", "MET_LONG": "i4", "MET_ULONG": "u4",
        "MET_LONG_LONG": "i8", "MET_ULONG_LONG": "u8", "MET_FLOAT": "f4", "MET_DOUBLE": "f8",
    }
)  # fmt: skip
_MET_NAMES = MappingProxyType(
    {"i1": "MET_CHAR", "u1": "MET_UCHAR", "i2": "MET_SHORT", "u2": "MET_USHORT", "i4": "MET_INT",
     "u4": "MET_UINT", "i8": "MET_LONG_LONG", "u8": "MET_ULONG_LONG", "f4": "MET_FLOAT",
     "f8": "MET_DOUBLE"}
)  # fmt: skip
_SITK_READ = (".nrrd", ".nhdr", ".nii", ".nii.gz", ".tif", ".tiff")
_SITK_WRITE = (".nrrd", ".nii", ".nii.gz", ".tif", ".tiff")
_TIFF = (".tif", ".tiff")


def volume_formats() -> tuple[str, ...]:
    """The volume file extensions :func:`read_volume` supports.

    Folders of DICOM files or of 2D TIFF slices are read as well.

    Returns
    -------
    tuple of str

    Examples
    --------
    >>> ".mha" in volume_formats()
    True
    """
    return tuple(sorted((".mha", ".mhd", *_SITK_READ)))


def _metaimage_header(path: Path) -> tuple[dict[str, str], int]:
    """Header fields (lower-case keys) and the byte offset just after the header."""
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
        while True:
            match = re.search(rb"^[ \t]*ElementDataFile[ \t]*=[^\n]*(\n|$)", head, re.M | re.I)
            if match and (match.group(1) or len(head) == path.stat().st_size):
                break
            more = fh.read(1 << 16)
            if not more or len(head) > (1 << 22):
                raise _ParseError("no 'ElementDataFile' line: not a MetaImage header, or truncated")
            head += more
    fields = {}
    for line in head[: match.end()].decode("latin-1").splitlines():
        key, sep, value = line.partition("=")
        if sep:
            fields[key.strip().lower()] = value.strip()
    return fields, match.end()


def _numbers(fields: dict[str, str], keys: tuple[str, ...], count: int, default) -> np.ndarray:
    for key in keys:
        if key.lower() in fields:
            try:
                values = np.array(fields[key.lower()].split(), dtype=np.float64)
            except ValueError:
                raise _ParseError(
                    f"{key} = {fields[key.lower()]!r} is not a list of numbers"
                ) from None
            if values.size != count:
                raise _ParseError(f"{key} must have {count} numbers, got {values.size}")
            return values
    return np.asarray(default, dtype=np.float64)


def _read_metaimage(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    fields, header_end = _metaimage_header(path)
    ndims = fields.get("ndims", "3")
    if ndims != "3":
        if ndims == "2":
            raise _ParseError("is a 2D image (NDims = 2), not a 3D volume")
        raise _ParseError(f"has NDims = {ndims}; only 3D volumes are supported")
    try:
        dims = [int(k) for k in fields["dimsize"].split()]
    except (KeyError, ValueError):
        raise _ParseError("the header has no valid DimSize") from None
    if len(dims) != 3 or min(dims) < 0:
        raise _ParseError(f"DimSize must be 3 non-negative integers, got {fields['dimsize']!r}")
    element = fields.get("elementtype", "").upper()
    if element not in _MET_TYPES:
        raise _ParseError(
            f"unsupported ElementType {element or '(none)'!r}; supported: {', '.join(_MET_TYPES)}"
        )
    if fields.get("elementnumberofchannels", "1") != "1":
        raise _ParseError("has several channels per voxel; only scalar volumes are supported")
    spacing = _numbers(fields, ("ElementSpacing", "ElementSize"), 3, np.ones(3))
    origin = _numbers(fields, ("Offset", "Origin", "Position"), 3, np.zeros(3))
    # TransformMatrix lists the axis directions one after the other, i.e. the
    # direction matrix column by column (checked against ITK's writer).
    direction = _numbers(
        fields, ("TransformMatrix", "Rotation", "Orientation"), 9, np.eye(3).ravel()
    )
    direction = direction.reshape(3, 3).T
    true = ("true", "1", "yes")
    big_endian = (
        fields.get("binarydatabyteordermsb", fields.get("elementbyteordermsb", "false")).lower()
        in true
    )
    compressed = fields.get("compresseddata", "false").lower() in true
    binary = fields.get("binarydata", "true").lower() in true
    dtype = np.dtype((">" if big_endian else "<") + _MET_TYPES[element])
    count = int(np.prod(dims))
    expected = count * dtype.itemsize

    source = fields.get("elementdatafile", "")
    if source.upper() == "LOCAL":
        with open(path, "rb") as fh:
            fh.seek(header_end)
            raw = fh.read()
    else:
        if (
            not source
            or source.upper().startswith("LIST")
            or "%" in source
            or len(source.split()) > 1
        ):
            raise _ParseError(
                f"ElementDataFile = {source!r} (slice lists or patterns) is not supported"
            )
        data_path = path.parent / source
        if not data_path.is_file():
            raise _ParseError(f"its data file {data_path} does not exist")
        raw = data_path.read_bytes()
        skip = int(fields.get("headersize", "0"))
        if skip < 0:  # -1: the (uncompressed) data are the last bytes of the file
            skip = 0 if compressed else max(len(raw) - expected, 0)
        raw = raw[skip:]
    if compressed:
        inflater = zlib.decompressobj(zlib.MAX_WBITS | 32)  # zlib or gzip header
        try:
            raw = inflater.decompress(raw)
        except zlib.error as exc:
            raise _ParseError(f"the compressed voxel data are corrupt ({exc})") from None
        if not inflater.eof:
            raise _ParseError("truncated: the compressed voxel data end early")
    if binary:
        if len(raw) != expected:
            problem = "truncated: " if len(raw) < expected else ""
            raise _ParseError(
                f"{problem}DimSize {dims} of {element} needs {expected} bytes of voxel data, "
                f"found {len(raw)}"
            )
        flat = np.frombuffer(raw, dtype=dtype)
    else:
        flat = np.array(raw.split(), dtype=np.float64)
        if flat.size != count:
            raise _ParseError(f"DimSize {dims} needs {count} ASCII values, found {flat.size}")
        flat = flat.astype(dtype)
    flat = flat.astype(dtype.newbyteorder("="), copy=False)
    data = flat.reshape(dims[::-1]).transpose(2, 1, 0)  # file order is x fastest
    return data, spacing, origin, direction


def _metaimage_text(
    volume: Volume, code: str, data_file: str, compressed_size: int | None
) -> bytes:
    def nums(values) -> str:
        return " ".join(repr(float(v)) for v in np.ravel(values))

    lines = [
        "ObjectType = Image",
        "NDims = 3",
        "BinaryData = True",
        "BinaryDataByteOrderMSB = False",
        f"CompressedData = {compressed_size is not None}",
    ]
    if compressed_size is not None:
        lines.append(f"CompressedDataSize = {compressed_size}")
    lines += [
        f"TransformMatrix = {nums(volume.direction.T)}",
        f"Offset = {nums(volume.origin)}",
        "CenterOfRotation = 0 0 0",
        f"ElementSpacing = {nums(volume.spacing)}",
        f"DimSize = {' '.join(str(k) for k in volume.shape)}",
        f"ElementType = {_MET_NAMES[code]}",
        f"ElementDataFile = {data_file}",
    ]
    return ("\n".join(lines) + "\n").encode("latin-1")


def _metaimage_payload(
    volume: Volume, compress: bool
) -> tuple[str, list[bytes | memoryview], int | None]:
    data = volume.data.astype(np.uint8) if volume.data.dtype == bool else volume.data
    code = data.dtype.kind + str(data.dtype.itemsize)
    # x fastest on disk: the C-order bytes of the (z, y, x) transpose.
    raw = np.ascontiguousarray(data.transpose(2, 1, 0), dtype=np.dtype("<" + code))
    view = raw.reshape(-1).data.cast("B")
    if not compress:
        return code, [view], None
    # Level 1: CT volumes are hundreds of MB; higher levels cost far more time
    # than they save space on noisy data.
    deflater = zlib.compressobj(1)
    chunk = 1 << 24
    parts: list[bytes | memoryview] = [
        deflater.compress(view[i : i + chunk]) for i in range(0, len(view), chunk)
    ]
    parts.append(deflater.flush())
    return code, parts, sum(len(p) for p in parts)


def _write_metaimage(path: Path, volume: Volume, compress: bool) -> None:
    code, parts, size = _metaimage_payload(volume, compress)
    if _full_suffix(path) == ".mha":
        with atomic_path(path, VolumeError) as tmp, open(tmp, "wb") as fh:
            fh.write(_metaimage_text(volume, code, "LOCAL", size))
            for part in parts:
                fh.write(part)
        return
    # .mhd: header plus a data file next to it; the header is replaced last, so
    # an interrupted write never leaves a header pointing at missing data.
    data_path = path.with_suffix(".zraw" if compress else ".raw")
    with atomic_path(data_path, VolumeError) as tmp, open(tmp, "wb") as fh:
        for part in parts:
            fh.write(part)
    with atomic_path(path, VolumeError) as tmp:
        tmp.write_bytes(_metaimage_text(volume, code, data_path.name, size))


def _import_sitk(path: Path, action: str, what: str):
    try:
        return importlib.import_module("SimpleITK")
    except ImportError:
        raise VolumeError(
            f"{path}: {action} {what} needs the optional dependency 'SimpleITK' "
            '(pip install "hortishape[ct]")'
        ) from None


def _sitk_message(exc: Exception) -> str:
    """The useful last line of a SimpleITK exception (which starts with C++ source paths)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return re.sub(r"^sitk::ERROR:\s*", "", lines[-1]) if lines else type(exc).__name__


def _natural_key(path: Path) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def _read_sitk(path: Path):
    """A SimpleITK image from a file, a DICOM series folder or a folder of TIFF slices."""
    if path.is_dir():
        files = sorted(
            (f for f in path.iterdir() if f.is_file() and not f.name.startswith(".")),
            key=_natural_key,
        )
        slices = [f for f in files if f.suffix.lower() in _TIFF]
        what = "TIFF slices" if slices else "DICOM series"
        sitk = _import_sitk(path, "reading", what)
        if slices:
            if len(slices) < 2:
                raise VolumeError(
                    f"{path}: holds a single TIFF slice, need at least 2 for a volume"
                )
            return sitk.ReadImage([str(f) for f in slices]), True
        series = sitk.ImageSeriesReader.GetGDCMSeriesIDs(str(path))
        if not series:
            raise VolumeError(f"{path}: the folder holds no DICOM series and no .tif slices")
        if len(series) > 1:
            raise VolumeError(
                f"{path}: the folder holds {len(series)} DICOM series ({', '.join(series)}); "
                "put each series in its own folder"
            )
        names = sitk.ImageSeriesReader.GetGDCMSeriesFileNames(str(path), series[0])
        reader = sitk.ImageSeriesReader()
        reader.SetFileNames(names)
        return reader.Execute(), False
    extension = _full_suffix(path)
    sitk = _import_sitk(path, "reading", f"{extension} files")
    return sitk.ReadImage(str(path)), extension in _TIFF


def read_volume(path: PathLike, *, spacing: npt.ArrayLike | None = None) -> Volume:
    """Read a CT volume.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.mha`` / ``.mhd`` MetaImage (read natively), a ``.nrrd`` /
        ``.nhdr``, ``.nii`` / ``.nii.gz``, a multi-page ``.tif`` / ``.tiff``,
        a folder holding one DICOM series, or a folder of 2D ``.tif`` slices
        (in natural name order: ``s2`` before ``s10``). All but MetaImage need
        the optional ``SimpleITK`` package.
    spacing : (3,) array_like of float or float, optional
        Voxel size (mm) along x, y, z replacing the file's. TIFF stores no
        trustworthy spacing: without ``spacing`` it is read as 1 mm on every
        axis, with a warning.

    Returns
    -------
    Volume
        ``data`` indexed ``[x, y, z]``, spacing and origin in mm, direction.
        NIfTI units (``xyzt_units``) are converted to mm by SimpleITK; unknown
        units are taken as mm.

    Raises
    ------
    VolumeError
        The message starts with the path and names the problem: missing,
        empty, unknown format, not 3D, several channels, NaN voxels, zero or
        negative spacing, truncated or corrupt data, missing SimpleITK.

    Warns
    -----
    UserWarning
        TIFF read without ``spacing``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = pathlib.Path(tmp.name)
    >>> path = write_volume(folder / "ct.mha", Volume(np.zeros((2, 3, 4), np.int16), spacing=0.5))
    >>> read_volume(path).shape
    (2, 3, 4)
    """
    p = Path(path)
    if not p.exists():
        raise VolumeError(f"{p}: no such file or folder")
    extension = _full_suffix(p)
    if not p.is_dir():
        if extension == ".dcm":
            raise VolumeError(
                f"{p}: a single DICOM file holds one slice; pass the folder of the series"
            )
        if extension not in volume_formats():
            shown = extension or "(none)"
            raise VolumeError(
                f"{p}: unknown volume format {shown!r}; supported: {', '.join(volume_formats())}, "
                "or a folder of DICOM files or of .tif slices"
            )
        _check_not_empty(p, VolumeError)
    is_tiff = False
    try:
        if extension in (".mha", ".mhd") and not p.is_dir():
            data, file_spacing, origin, direction = _read_metaimage(p)
        else:
            image, is_tiff = _read_sitk(p)
            if image.GetNumberOfComponentsPerPixel() != 1:
                raise _ParseError(
                    f"has {image.GetNumberOfComponentsPerPixel()} values per voxel (colour?); "
                    "only scalar volumes are supported"
                )
            if image.GetDimension() != 3:
                raise _ParseError(f"is a {image.GetDimension()}D image, not a 3D volume")
            sitk = importlib.import_module("SimpleITK")
            data = sitk.GetArrayFromImage(image).transpose(2, 1, 0)  # (z, y, x) -> [x, y, z]
            file_spacing = np.array(image.GetSpacing())
            origin = np.array(image.GetOrigin())
            direction = np.array(image.GetDirection()).reshape(3, 3)
    except VolumeError:
        raise
    except _ParseError as exc:
        raise VolumeError(f"{p}: {exc}") from None
    except OSError as exc:
        raise VolumeError(f"{p}: cannot read ({exc.strerror or exc})") from None
    except RuntimeError as exc:  # SimpleITK reports every failure as RuntimeError
        raise VolumeError(f"{p}: cannot read it ({_sitk_message(exc)})") from None
    except ValueError as exc:
        raise VolumeError(f"{p}: cannot read it ({exc})") from exc
    if is_tiff:
        # TIFF resolution tags are usually screen DPI, not voxel size.
        origin, direction = np.zeros(3), np.eye(3)
        if spacing is None:
            warnings.warn(
                f"{p}: TIFF stores no reliable voxel spacing; assuming 1 mm along x, y and z "
                "(set it with spacing=, or hortishape extract --spacing SX SY SZ)",
                UserWarning,
                stacklevel=2,
            )
            file_spacing = np.ones(3)
    if spacing is not None:
        file_spacing = np.asarray(spacing, dtype=np.float64)
    arr, s, o, d = _check_volume(data, file_spacing, origin, direction, name=str(p))
    return Volume(arr, s, o, d)


def write_volume(path: PathLike, volume: Volume, *, compress: bool = True) -> Path:
    """Write a volume atomically, in the format given by the extension.

    Parameters
    ----------
    path : str or os.PathLike
        ``.mha`` (one file) or ``.mhd`` (header plus ``.raw`` / ``.zraw`` data
        file next to it), written natively; ``.nrrd``, ``.nii``, ``.nii.gz``,
        ``.tif`` / ``.tiff`` through SimpleITK. TIFF keeps no spacing, origin
        or direction.
    volume : Volume
    compress : bool, default: True
        zlib-compress the voxel data (MetaImage, NRRD; NIfTI by extension).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    VolumeError
        Unknown extension, not a :class:`Volume`, missing folder or the file
        cannot be written; the target is then left as it was.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = pathlib.Path(tmp.name)
    >>> v = Volume(np.arange(24, dtype=np.uint8).reshape(2, 3, 4), spacing=(1, 1, 2))
    >>> int(read_volume(write_volume(folder / "ct.mha", v)).data[1, 2, 3])
    23
    """
    p = Path(path)
    if not isinstance(volume, Volume):
        raise VolumeError(f"{p}: expected a Volume, got {type(volume).__name__}")
    extension = _full_suffix(p)
    if extension in (".mha", ".mhd"):
        try:
            _write_metaimage(p, volume, compress)
        except KeyError:
            raise VolumeError(f"{p}: MetaImage cannot store {volume.data.dtype} voxels") from None
        return p
    if extension not in _SITK_WRITE:
        raise VolumeError(
            f"{p}: cannot write volume format {extension or '(none)'!r}; "
            f"supported: {', '.join(sorted(('.mha', '.mhd', *_SITK_WRITE)))}"
        )
    sitk = _import_sitk(p, "writing", f"{extension} files")
    data = volume.data.astype(np.uint8) if volume.data.dtype == bool else volume.data
    image = sitk.GetImageFromArray(np.ascontiguousarray(data.transpose(2, 1, 0)))
    image.SetSpacing(volume.spacing.tolist())
    image.SetOrigin(volume.origin.tolist())
    image.SetDirection(volume.direction.ravel().tolist())
    with atomic_path(p, VolumeError) as tmp:
        try:
            sitk.WriteImage(image, str(tmp), compress)
        except RuntimeError as exc:
            raise VolumeError(f"{p}: cannot write it ({_sitk_message(exc)})") from None
    return p
