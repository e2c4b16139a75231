"""Point clouds: what a depth camera or a partial scan gives, read from PLY or from any mesh file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from .._files import PathLike, atomic_path
from ..errors import MeshError
from .mesh_files import _checked_format, _read_raw, read_mesh_data
from .ply import _write_ply

_NORMAL_NAMES = ("nx", "ny", "nz")


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Points, their outward normals when the file has them, and the triangles of a mesh file.

    Attributes
    ----------
    points : (k, 3) float64 ndarray
        Coordinates in the file's units.
    normals : (k, 3) float64 ndarray or None
        The ``nx``, ``ny``, ``nz`` vertex properties, when the file has all three.
    faces : (m, 3) int64 ndarray
        Triangles over the points; empty for a point cloud.
    """

    points: np.ndarray
    normals: np.ndarray | None
    faces: np.ndarray


def read_points(path: PathLike) -> PointCloud:
    """Read a point cloud: a PLY file with no faces, or the vertices of any mesh file (an open scan).

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply`` file (with or without a face element), or any mesh file
        :func:`read_mesh` reads.

    Returns
    -------
    PointCloud

    Raises
    ------
    MeshError
        The message starts with the path: missing, empty or unreadable file,
        no points, NaN or infinite coordinates.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = write_points(pathlib.Path(tempfile.mkdtemp()) / "seen.ply", [[0, 0, 1], [1, 0, 1]],
    ...                     normals=[[0, 0, 1], [0, 0, 1]])
    >>> cloud = read_points(path)
    >>> cloud.points.shape, cloud.normals[1].tolist(), cloud.faces.shape
    ((2, 3), [0.0, 0.0, 1.0], (0, 3))
    """
    p = Path(path)
    fmt = _checked_format(p)
    if fmt.name != "PLY":
        data = read_mesh_data(p)
        return PointCloud(data.mesh.vertices, None, data.mesh.faces)
    raw = _read_raw(p, fmt)
    points = np.asarray(raw.vertices, dtype=np.float64)
    if points.ndim != 2 or len(points) == 0:
        raise MeshError(f"{p}: the file holds no points")
    if not np.isfinite(points).all():
        raise MeshError(f"{p}: {int((~np.isfinite(points).all(axis=1)).sum())} points have NaN or infinite coordinates")
    scalars = raw.scalars or {}
    normals = None
    if all(name in scalars for name in _NORMAL_NAMES):
        normals = np.stack([np.asarray(scalars[name], dtype=np.float64) for name in _NORMAL_NAMES], axis=1)
    faces = np.asarray(raw.faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) and (faces.min() < 0 or faces.max() >= len(points)):
        raise MeshError(f"{p}: a face refers to a vertex that does not exist")
    return PointCloud(points, normals, faces)


def write_points(path: PathLike, points: npt.ArrayLike, *, normals: npt.ArrayLike | None = None) -> Path:
    """Write a point cloud as a binary PLY (no faces), atomically; normals as ``nx``, ``ny``, ``nz``.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.ply`` file; the folder must exist.
    points : (k, 3) array_like of float
    normals : (k, 3) array_like of float, optional

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        Not ``.ply``, arrays of the wrong shape or not finite, or the file cannot be written.

    Examples
    --------
    >>> import tempfile
    >>> points = np.random.default_rng(0).normal(size=(100, 3)) * 30.0
    >>> cloud = read_points(write_points(tempfile.mkdtemp() + "/seen.ply", points))
    >>> cloud.points.shape, cloud.normals is None, cloud.faces.shape
    ((100, 3), True, (0, 3))
    """
    p = Path(path)
    if p.suffix.lower() != ".ply":
        raise MeshError(f"{p}: point clouds are written as .ply")
    v = np.asarray(points, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.isfinite(v).all():
        raise MeshError(f"{p}: points must be a finite (k, 3) array with k >= 1, got shape {v.shape}")
    scalars = {}
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)
        if n.shape != v.shape or not np.isfinite(n).all():
            raise MeshError(f"{p}: normals must be finite and of the points' shape {v.shape}, got {n.shape}")
        scalars = dict(zip(_NORMAL_NAMES, n.T))
    with atomic_path(p, MeshError) as tmp:
        _write_ply(tmp, v, np.zeros((0, 3), dtype=np.int64), None, scalars, True)
    return p
