"""OBJ (Wavefront) and OFF: plain-text polygon files."""

from __future__ import annotations

import re
from itertools import chain
from pathlib import Path

import numpy as np

from ._common import _ParseError, _RawMesh, _fan, _segments, _floats_text, _ints_text


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
