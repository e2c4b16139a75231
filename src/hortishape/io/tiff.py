"""TIFF stacks and folders of TIFF slices with their voxel size, through tifffile.

A TIFF file has no reliable voxel size of its own: its resolution tags are
usually a screen's dots per inch. The voxel size is taken from where scanners
and image software put it, in this order:

1. OME-TIFF metadata (``PhysicalSizeX/Y/Z`` with their units);
2. ImageJ metadata (the resolution tags in its ``unit``, and ``spacing``
   between slices);
3. the scanner's log or project file beside the stack: Bruker SkyScan's
   ``.log`` (``Pixel Size (um)`` of the reconstruction, else ``Image Pixel
   Size (um)``) and Nikon's ``.xtekct`` / ``.xtekVolume`` (``VoxelSizeX/Y/Z``,
   mm).

Where it came from is recorded (``spacing_source``); a stack with none of
these has no voxel size and is refused unless one is given.
"""

from __future__ import annotations

import configparser
import importlib
import re
from pathlib import Path

import numpy as np

from ..errors import VolumeError
from ._common import _first_line, _ParseError, _RawVolume

TIFF_EXTENSIONS = (".tif", ".tiff")
#: Files beside a stack that may hold its voxel size.
LOG_EXTENSIONS = (".log", ".xtekct", ".xtekvolume")

#: Length units in metadata and logs, in mm.
_UNITS_MM = {"mm": 1.0, "millimeter": 1.0, "millimetre": 1.0, "um": 1e-3, "\u00b5m": 1e-3,
             "micron": 1e-3, "microns": 1e-3, "micrometer": 1e-3, "micrometre": 1e-3, "nm": 1e-6,
             "cm": 10.0, "centimeter": 10.0, "m": 1000.0, "meter": 1000.0, "metre": 1000.0}


def _natural_key(path: Path) -> list:
    """Slices in natural name order: ``s2`` before ``s10``."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def _tifffile(path: Path):
    try:
        return importlib.import_module("tifffile")
    except ImportError:
        raise VolumeError(f"{path}: reading TIFF needs the optional dependency 'tifffile' "
                          '(pip install "hortishape[ct]")') from None


def _unit_mm(unit) -> float | None:
    if unit is None:
        return None
    text = str(unit).strip().replace("\\u00B5", "\u00b5").replace("\\u00b5", "\u00b5").lower()
    return _UNITS_MM.get(text)


def _ome_spacing(xml: str) -> tuple[np.ndarray, str] | None:
    m = re.search(r"<(?:\w+:)?Pixels\b([^>]*)>", xml)
    if not m:
        return None
    attrs = dict(re.findall(r'(\w+)="([^"]*)"', m.group(1)))
    sizes = []
    for axis in "XYZ":
        value = attrs.get(f"PhysicalSize{axis}")
        factor = _unit_mm(attrs.get(f"PhysicalSize{axis}Unit", "\u00b5m"))  # the OME schema's default unit
        if value is None or factor is None:
            return None
        sizes.append(float(value) * factor)
    return np.array(sizes), "OME-TIFF PhysicalSizeX/Y/Z"


def _imagej_spacing(tf) -> tuple[np.ndarray, str] | None:
    meta = tf.imagej_metadata or {}
    factor = _unit_mm(meta.get("unit"))
    if factor is None:
        return None
    page = tf.pages[0]
    sizes = []
    for tag in ("XResolution", "YResolution"):
        t = page.tags.get(tag)
        if t is None:
            return None
        num, den = t.value
        if num <= 0 or den <= 0:
            return None
        sizes.append(den / num * factor)  # the tag is pixels per unit
    z = meta.get("spacing")
    if z is None:
        return None
    sizes.append(float(z) * factor)
    return np.array(sizes), "ImageJ metadata (resolution, unit and spacing)"


def parse_scanner_log(path: Path) -> np.ndarray | None:
    """The voxel size (mm, x y z) a SkyScan ``.log`` or Nikon ``.xtekct`` file states, or None.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> log = pathlib.Path(tempfile.mkdtemp()) / "apple_rec.log"
    >>> _ = log.write_text("[Reconstruction]\\nPixel Size (um)=40.0\\n")
    >>> parse_scanner_log(log).tolist()
    [0.04, 0.04, 0.04]
    """
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    if path.suffix.lower() == ".log":
        # the reconstruction's pixel size (binning included) before the acquisition's
        section = re.search(r"^\s*\[Reconstruction\](.*?)(?=^\s*\[|\Z)", text, re.M | re.S)
        for where, pattern in ((section.group(1) if section else "", r"Pixel Size \(um\)\s*=\s*([0-9.eE+-]+)"),
                               (text, r"Image Pixel Size \(um\)\s*=\s*([0-9.eE+-]+)")):
            m = re.search(r"^\s*" + pattern, where, re.M)
            if m:
                try:
                    size = float(m.group(1)) * 1e-3
                except ValueError:
                    return None
                return np.full(3, size) if size > 0 and np.isfinite(size) else None
        return None
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    try:
        parser.read_string("[top]\n" + text if not text.lstrip().startswith("[") else text)
    except configparser.Error:
        return None
    for section in parser.sections():
        s = parser[section]
        keys = {k.lower(): v for k, v in s.items()}
        if all(f"voxelsize{a}" in keys for a in "xyz"):
            factor = _unit_mm(keys.get("units", "mm")) or 1.0
            try:
                sizes = np.array([float(keys[f"voxelsize{a}"]) for a in "xyz"]) * factor
            except ValueError:
                return None
            return sizes if np.all(sizes > 0) and np.all(np.isfinite(sizes)) else None
    return None


def find_scanner_log(stack: Path) -> tuple[Path, np.ndarray] | None:
    """The scanner log beside ``stack`` (a TIFF file or a folder of slices) and the voxel size it states.

    Looked for in the stack's folder (for a folder of slices: in it, then
    beside it). A log whose name starts like the stack's is taken first;
    otherwise the only log there that states a voxel size.
    """
    places = [stack, stack.parent] if stack.is_dir() else [stack.parent]
    stem = stack.name.lower().split(".")[0]
    for place in places:
        try:
            logs = sorted(f for f in place.iterdir() if f.is_file() and f.suffix.lower() in LOG_EXTENSIONS)
        except OSError:
            continue
        found = [(f, s) for f in logs if (s := parse_scanner_log(f)) is not None]
        named = [(f, s) for f, s in found
                 if f.stem.lower().startswith(stem) or stem.startswith(f.stem.lower())]
        if named:
            return named[0]
        if len(found) == 1:
            return found[0]
    return None


def _check_pages(shapes: list[tuple], names: list[str], what: str) -> None:
    counts: dict[tuple, int] = {}
    for s in shapes:
        counts[s] = counts.get(s, 0) + 1
    if len(counts) > 1:
        common = max(counts, key=counts.get)
        k = next(i for i, s in enumerate(shapes) if s != common)
        size = " x ".join(str(v) for v in shapes[k][::-1])
        raise _ParseError(f"{what} {names[k]} is {size} pixels, the others "
                          f"{' x '.join(str(v) for v in common[::-1])}")
    shape = shapes[0]
    if len(shape) == 3 and shape[-1] in (3, 4):
        raise _ParseError(f"has {shape[-1]} values per pixel (colour?); only grey-value stacks are supported")
    if len(shape) != 2:
        raise _ParseError(f"{what}s of shape {shape} are not 2D grey-value images")


def read_tiff(path: Path) -> tuple[_RawVolume, dict]:
    """A multi-page TIFF or a folder of 2D TIFF slices (natural name order) as a volume ``[x, y, z]``.

    ``geometry_known`` is False when no voxel size was found (spacing 1 is a placeholder).
    """
    tifffile = _tifffile(path)
    try:
        if path.is_dir():
            files = sorted((f for f in path.iterdir() if f.is_file() and not f.name.startswith(".")
                            and f.suffix.lower() in TIFF_EXTENSIONS), key=_natural_key)
            if len(files) < 2:
                raise VolumeError(f"{path}: holds {len(files)} TIFF slice, need at least 2 for a volume")
            planes, shapes = [], []
            for f in files:
                with tifffile.TiffFile(f) as tf:
                    if len(tf.pages) != 1:
                        raise _ParseError(f"slice {f.name} holds {len(tf.pages)} images, not one")
                    shapes.append(tuple(tf.pages[0].shape))
                    if len(set(shapes)) > 1:
                        _check_pages(shapes, [g.name for g in files], "slice")
                    planes.append(tf.pages[0].asarray())
                    if f is files[0]:
                        found = _ome_spacing(tf.ome_metadata) if tf.ome_metadata else None
                        found = found or _imagej_spacing(tf)
            _check_pages(shapes, [f.name for f in files], "slice")
            data = np.stack(planes, axis=0)
        else:
            with tifffile.TiffFile(path) as tf:
                shapes = [tuple(p.shape) for p in tf.pages]
                _check_pages(shapes, [f"page {k + 1}" for k in range(len(shapes))], "page")
                if len(shapes) < 2:
                    raise _ParseError("is a 2D image, not a 3D volume (one page)")
                data = np.stack([p.asarray() for p in tf.pages], axis=0)
                found = _ome_spacing(tf.ome_metadata) if tf.ome_metadata else None
                found = found or _imagej_spacing(tf)
    except (VolumeError, _ParseError):
        raise
    except Exception as exc:  # noqa: BLE001 - tifffile's many errors on a broken file
        raise _ParseError(f"cannot read it as TIFF ({_first_line(exc)})") from None
    data = data.transpose(2, 1, 0)  # (z, y, x) -> [x, y, z]
    if data.dtype.kind not in "biuf":
        raise _ParseError(f"voxel values of type {data.dtype} are not numbers")
    if found is None:
        log = find_scanner_log(path)
        if log is not None:
            found = (log[1], f"scanner log {log[0]}")
    if found is None:
        return _RawVolume(np.ascontiguousarray(data), np.ones(3), np.zeros(3), np.eye(3),
                          geometry_known=False), {"spacing_source": ""}
    return (_RawVolume(np.ascontiguousarray(data), found[0], np.zeros(3), np.eye(3)),
            {"spacing_source": found[1]})


def _write_tiff(path: Path, volume, compress: bool) -> None:
    """An OME-TIFF stack with the voxel size in mm (no origin or direction: TIFF keeps none)."""
    from .._files import atomic_path

    tifffile = _tifffile(path)
    data = volume.data.astype(np.uint8) if volume.data.dtype == bool else volume.data
    sx, sy, sz = (float(v) for v in volume.spacing)
    meta = {"axes": "ZYX", "PhysicalSizeX": sx, "PhysicalSizeXUnit": "mm", "PhysicalSizeY": sy,
            "PhysicalSizeYUnit": "mm", "PhysicalSizeZ": sz, "PhysicalSizeZUnit": "mm"}
    with atomic_path(path, VolumeError) as tmp:
        tifffile.imwrite(tmp, np.ascontiguousarray(data.transpose(2, 1, 0)), ome=True, metadata=meta, photometric="minisblack",
                         compression="zlib" if compress else None)
