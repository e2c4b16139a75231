"""MetaImage (``.mha``, ``.mhd`` with its ``.raw`` / ``.zraw``), read and written natively with numpy."""

from __future__ import annotations

import re
import zlib
from pathlib import Path
from types import MappingProxyType

import numpy as np

from .._files import atomic_path, full_suffix
from ..errors import VolumeError
from ._common import _ParseError, _RawVolume
from .volume import Volume


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


def _read_metaimage(path: Path) -> _RawVolume:
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
    return _RawVolume(data, spacing, origin, direction)


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
    if full_suffix(path) == ".mha":
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
