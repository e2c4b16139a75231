"""Folded triangles: kept from folding during the closing step, and repaired at the end."""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from ..surface import face_normals
from .template import _face_pairs, _Level


def _unfold_step(faces: np.ndarray, old: np.ndarray, new: np.ndarray, *, max_rounds: int = 10) -> np.ndarray:
    """Undo the step for vertices of triangles whose normal turns by > 90 degrees."""
    n_old = face_normals(old, faces)
    out = new.copy()
    for _ in range(max_rounds):
        flipped = np.einsum("ij,ij->i", n_old, face_normals(out, faces)) <= 0
        if not flipped.any():
            break
        idx = np.unique(faces[flipped].ravel())
        out[idx] = old[idx]
    return out


def _folded_faces(faces: np.ndarray, placed: np.ndarray, positions: np.ndarray, pairs=None) -> np.ndarray:
    """Faces turned by more than 90 degrees from ``placed``, or from a neighbour across an edge.

    ``pairs``: :func:`_face_pairs` of ``faces``, if already known.
    """
    n = face_normals(positions, faces)
    bad = np.einsum("ij,ij->i", n, face_normals(placed, faces)) <= 0
    a, b = _face_pairs(faces) if pairs is None else pairs
    back = np.einsum("ij,ij->i", n[a], n[b]) <= 0
    bad[a[back]] = bad[b[back]] = True
    return bad


def _repair_folds(
    level: _Level, placed: np.ndarray, positions: np.ndarray, *, rings: int = 2, rounds: int = 8
) -> np.ndarray:
    """Replace the displacement around folded faces by its harmonic fill-in.

    Where a stalk of the reference meets a differently bent or placed stalk
    on the scan, the elastic steps can fold a few triangles over.
    The displacement from ``placed`` (the globally placed reference) of the
    folded faces' vertices and ``rings`` rings around them is replaced by
    the harmonic interpolation of the displacement around them (graph
    Laplacian, boundary fixed), which is smooth and does not fold; the patch
    grows by a ring per round while folds remain. It leaves the surface a
    little off the scan there.
    """
    faces = level.faces
    out = positions
    lap = level.laplacian
    pairs = level.face_pairs()
    adj = None
    for k in range(rounds):
        bad = _folded_faces(faces, placed, out, pairs)
        if not bad.any():
            break
        if adj is None:  # only once there is a fold, and once for all rounds
            adj = (lap != 0).astype(np.float64)
        region = np.zeros(len(out), dtype=bool)
        region[faces[bad].ravel()] = True
        for _ in range(rings + k):
            region |= (adj @ region.astype(np.float64)) > 0
        inner = np.flatnonzero(region)
        outer = np.flatnonzero(~region)
        if len(outer) == 0:  # folds everywhere: nothing to interpolate from
            break
        disp = out - placed
        a = lap[inner][:, inner].tocsc()
        rhs = -(lap[inner][:, outer] @ disp[outer])
        filled = np.asarray(spla.spsolve(a, rhs)).reshape(len(inner), 3)
        out = out.copy()
        out[inner] = placed[inner] + filled
    return out
