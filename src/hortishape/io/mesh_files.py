"""Meshes: :class:`MeshData`, the registry of formats by extension, and the public readers and writers."""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from .._files import PathLike, atomic_path, check_exists, check_not_empty
from ..errors import MeshError
from ..mesh import Mesh, check_mesh
from ._common import _RESERVED_NAMES, _MissingDependencyError, _ParseError, _RawMesh
from .ply import _read_ply, _write_ply
from .stl import _read_stl, _write_stl, _stl_keeps_order
from .obj_off import _read_obj, _write_obj, _read_off, _write_off
from .vtk_files import _read_vtk_file, _write_vtk, _write_vtp


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


class _MeshFormat(NamedTuple):
    name: str
    read: Callable[[Path], _RawMesh]
    write: Callable[..., None]
    binary: tuple[bool, ...]  # allowed values of ``binary``; the first is the default
    attributes: bool  # can store vertex colours and scalars


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
    raw = _read_raw(p, _checked_format(p))
    vertices, faces = check_mesh(raw.vertices, raw.faces, name=str(p))
    return MeshData(Mesh(vertices, faces), raw.colors, raw.scalars or {})


def _checked_format(p: Path) -> _MeshFormat:
    """The format of an existing, non-empty mesh file (MeshError naming the file otherwise)."""
    check_exists(p, MeshError)
    fmt = _mesh_format(p)
    check_not_empty(p, MeshError)
    return fmt


def _read_raw(p: Path, fmt: _MeshFormat) -> _RawMesh:
    """The file's content as its format's reader gives it; every failure a MeshError naming the file."""
    try:
        return fmt.read(p)
    except MeshError:
        raise
    except (_ParseError, _MissingDependencyError) as exc:
        raise MeshError(f"{p}: {exc}") from None
    except OSError as exc:
        raise MeshError(f"{p}: cannot read the file ({exc.strerror or exc})") from None
    except (ValueError, IndexError, TypeError, OverflowError) as exc:
        raise MeshError(f"{p}: not a valid {fmt.name} file ({exc})") from exc


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
