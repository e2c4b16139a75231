"""What the mesh and volume format modules share: parse errors, the raw mesh a reader returns, polygon and text helpers."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np



class _ParseError(Exception):
    """A format parser found broken content; the caller adds the file name."""


def _first_line(exc: BaseException) -> str:
    """The first line of a dependency's exception, for a one-line error (its type where it says nothing)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


class _MissingDependencyError(Exception):
    """An optional package is not installed; the message names it."""


class _RawVolume(NamedTuple):
    data: np.ndarray  # indexed [x, y, z]
    spacing: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    geometry_known: bool = True  # False: the file keeps no trustworthy spacing (TIFF)


class _RawMesh(NamedTuple):
    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None = None
    scalars: dict[str, np.ndarray] | None = None


_COLOR_NAMES = ("red", "green", "blue", "alpha")
# "colors" is the name of the colour array in VTK files; a scalar of that name would replace it.
_RESERVED_NAMES = frozenset(("x", "y", "z", *_COLOR_NAMES, "colors"))


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
