"""STL, ASCII and binary: a triangle soup, welded on reading (vertex order is kept only as first use)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._common import _ParseError, _RawMesh


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
