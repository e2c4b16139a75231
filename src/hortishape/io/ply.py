"""PLY (Stanford polygon file), ASCII and binary of either byte order, with vertex colours and scalars."""

from __future__ import annotations

import re
from itertools import chain
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np

from ._common import _COLOR_NAMES, _ParseError, _RawMesh, _fan, _segments, _ints_text


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


_WRITE_BLOCK = 1 << 16  # vertices or faces per block of a binary file


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
            # in blocks: a million-vertex surface (a large CT volume's) without a copy of itself
            vertex_type = np.dtype([(name, "<" + code) for name, code, _ in columns])
            for i in range(0, n, _WRITE_BLOCK):
                records = np.empty(min(_WRITE_BLOCK, n - i), dtype=vertex_type)
                for name, _, values in columns:
                    records[name] = values[i : i + len(records)]
                fh.write(records.view(np.uint8))
            face_type = np.dtype([("n", "u1"), ("i", "<i4" if index == "int" else "<u4", (3,))])
            for i in range(0, m, _WRITE_BLOCK):
                tris = np.empty(min(_WRITE_BLOCK, m - i), dtype=face_type)
                tris["n"] = 3
                tris["i"] = faces[i : i + len(tris)]
                fh.write(tris.view(np.uint8))
        else:
            line = " ".join("%r" if code == "f8" else "%d" for _, code, _ in columns) + "\n"
            cols = [
                values.tolist() if code == "u1" else np.asarray(values, np.float64).tolist()
                for _, code, values in columns
            ]
            fh.write(((line * n) % tuple(chain.from_iterable(zip(*cols, strict=True)))).encode())
            fh.write(_ints_text(faces, 3, prefix="3 ").encode())
