"""The triangle-mesh type shared by every stage, and its basic checks.

A :class:`Mesh` is a frozen pair of arrays: ``vertices (n, 3) float64`` in
millimetres and ``faces (m, 3) int64`` indexing them. Vertex order is part of
a mesh's meaning in hortishape (it *is* the correspondence), so nothing here
merges, drops or reorders vertices.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .errors import MeshError

if TYPE_CHECKING:  # pragma: no cover
    import trimesh


__all__ = ["Mesh", "check_mesh", "unique_edges"]


def check_mesh(vertices, faces, *, name: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert mesh arrays.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex coordinates in millimetres.
    faces : (m, 3) array_like of int
        Triangles as indices into ``vertices``.
    name : str, default: "mesh"
        What to call the mesh in error messages (usually its file name).

    Returns
    -------
    vertices : (n, 3) float64 ndarray
    faces : (m, 3) int64 ndarray
        New arrays; the inputs are never modified.

    Raises
    ------
    MeshError
        If the arrays have the wrong shape, the mesh has no vertices or no
        faces, a coordinate is not finite, or a face index is out of range.

    Examples
    --------
    >>> v, f = check_mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> v.dtype, f.dtype
    (dtype('float64'), dtype('int64'))
    """
    try:
        v = np.array(vertices, dtype=np.float64)
        f = np.array(faces, dtype=np.int64)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"{name}: vertices and faces must be numeric arrays ({exc})") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"{name}: vertices must have shape (n, 3), got {v.shape}")
    if v.shape[0] == 0:
        raise MeshError(f"{name}: the mesh has no vertices")
    if f.size == 0:
        raise MeshError(f"{name}: the mesh has no faces (a point cloud is not a surface)")
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"{name}: faces must be triangles of shape (m, 3), got {f.shape}")
    if not np.isfinite(v).all():
        bad = int((~np.isfinite(v).all(axis=1)).sum())
        raise MeshError(f"{name}: {bad} vertices have NaN or infinite coordinates")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise MeshError(
            f"{name}: face indices must lie in [0, {v.shape[0] - 1}], "
            f"found {int(f.min())}..{int(f.max())}"
        )
    return v, f


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh: read-only ``vertices (n, 3) float64`` and ``faces (m, 3) int64``.

    Construction validates the arrays (see :func:`check_mesh`) and stores
    read-only copies, so a ``Mesh`` can be shared freely without being changed.

    Examples
    --------
    >>> m = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> m.n_vertices, m.n_faces
    (3, 1)
    """

    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self) -> None:
        v, f = check_mesh(self.vertices, self.faces)
        v.flags.writeable = False
        f.flags.writeable = False
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    def edges(self) -> np.ndarray:
        """Unique undirected edges, ``(e, 2) int64`` with ``edges[:, 0] < edges[:, 1]``."""
        return unique_edges(self.faces)

    def with_vertices(self, vertices) -> "Mesh":
        """A new mesh with the same faces and other vertex positions (same count)."""
        v = np.asarray(vertices, dtype=np.float64)
        if v.shape != self.vertices.shape:
            raise MeshError(f"new vertices have shape {v.shape}, expected {self.vertices.shape}")
        return Mesh(v, self.faces)

    def to_trimesh(self) -> "trimesh.Trimesh":
        """A ``trimesh.Trimesh`` view with processing off (vertex order kept)."""
        import trimesh

        return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(), process=False, validate=False)


def unique_edges(faces) -> np.ndarray:
    """Unique undirected edges of a triangle list.

    Parameters
    ----------
    faces : (m, 3) array_like of int

    Returns
    -------
    (e, 2) int64 ndarray
        Sorted rows, smaller index first.

    Examples
    --------
    >>> unique_edges([[0, 1, 2], [2, 1, 3]]).tolist()
    [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]
    """
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    if len(e) == 0:
        return e
    # one int64 key per edge: np.unique on rows (axis=0) is 15x slower
    n = int(e.max()) + 1
    key = np.unique(e[:, 0] * n + e[:, 1])
    return np.column_stack([key // n, key % n])
