"""Volumes: the registry of formats by extension and the public readers and writers."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from types import MappingProxyType
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from .._files import PathLike, check_not_empty, full_suffix
from ..errors import VolumeError
from ._common import _ParseError, _RawVolume
from .metaimage import _read_metaimage, _write_metaimage
from .dicom import read_header, read_series
from .simpleitk import _read_sitk, _sitk_message, _write_sitk
from .sources import VolumeSource, find_sources
from .tiff import LOG_EXTENSIONS, TIFF_EXTENSIONS, _write_tiff, read_tiff
from .volume import Volume, _check_volume


class _VolumeFormat(NamedTuple):
    name: str
    read: Callable[[Path], _RawVolume]
    write: Callable[[Path, Volume, bool], None] | None  # None: read only


_METAIMAGE = _VolumeFormat("MetaImage", _read_metaimage, _write_metaimage)
_NIFTI = _VolumeFormat("NIfTI", _read_sitk, _write_sitk)
_TIFF = _VolumeFormat("TIFF", lambda path: read_tiff(path)[0], _write_tiff)

_VOLUME_FORMATS: Mapping[str, _VolumeFormat] = MappingProxyType(
    {
        ".mha": _METAIMAGE,
        ".mhd": _METAIMAGE,
        ".nrrd": _VolumeFormat("NRRD", _read_sitk, _write_sitk),
        ".nhdr": _VolumeFormat("NRRD (detached header)", _read_sitk, None),
        ".nii": _NIFTI,
        ".nii.gz": _NIFTI,
        ".tif": _TIFF,
        ".tiff": _TIFF,
    }
)


def volume_formats() -> tuple[str, ...]:
    """The volume file extensions :func:`read_volume` supports.

    Folders of DICOM files or of 2D TIFF slices are read as well.

    Returns
    -------
    tuple of str

    Examples
    --------
    >>> ".mha" in volume_formats()
    True
    """
    return tuple(sorted(_VOLUME_FORMATS))


def read_volume(path: PathLike, *, spacing: npt.ArrayLike | None = None) -> Volume:
    """Read a CT volume.

    Parameters
    ----------
    path : str, os.PathLike or VolumeSource
        A ``.mha`` / ``.mhd`` MetaImage (read natively), a ``.nrrd`` /
        ``.nhdr``, ``.nii`` / ``.nii.gz`` (through ``SimpleITK``), a
        multi-page ``.tif`` / ``.tiff`` or a folder of 2D ``.tif`` slices (in
        natural name order: ``s2`` before ``s10``; through ``tifffile``), a
        folder holding one DICOM series whatever its files are called
        (through ``pydicom``), or one :class:`VolumeSource` of
        :func:`find_sources` (a series of a folder holding several).
    spacing : (3,) array_like of float or float, optional
        Voxel size (mm) along x, y, z replacing the file's. A TIFF's comes
        from its OME or ImageJ metadata or the scanner's log beside it
        (SkyScan ``.log``, Nikon ``.xtekct``); a TIFF with none of them
        needs ``spacing``.

    Returns
    -------
    Volume
        ``data`` indexed ``[x, y, z]``, spacing and origin in mm, direction,
        and where the voxel size came from (``spacing_source``). DICOM values
        have the rescale slope and intercept applied (Hounsfield units in
        CT); their slice step is taken from the slices' positions. NIfTI units
        (``xyzt_units``) are converted to mm by SimpleITK; unknown units are
        taken as mm.

    Raises
    ------
    VolumeError
        The message starts with the path and names the problem: missing,
        empty, unknown format, not 3D, several channels, NaN voxels, zero or
        negative spacing, no voxel size anywhere, truncated or corrupt data,
        a DICOM series with a slice missing, uneven slice steps, a gantry
        tilt or slices of several sizes, a folder of several series, a
        missing optional dependency.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = pathlib.Path(tmp.name)
    >>> path = write_volume(folder / "ct.mha", Volume(np.zeros((2, 3, 4), np.int16), spacing=0.5))
    >>> read_volume(path).shape
    (2, 3, 4)
    """
    source = path if isinstance(path, VolumeSource) else None
    p = source.path if source is not None else Path(path)
    if not p.exists():
        raise VolumeError(f"{p}: no such file or folder")
    extension = full_suffix(p)
    if source is None and p.is_dir():  # a DICOM series or TIFF slices
        found = find_sources(p, meshes=False)
        if not found.volumes:
            why = f" ({found.skipped[0][0]}: {found.skipped[0][1]})" if found.skipped else ""
            raise VolumeError(f"{p}: the folder holds no DICOM series and no .tif slices{why}")
        if len(found.volumes) > 1:
            kinds = "DICOM series" if all(v.kind == "dicom" for v in found.volumes) else "volumes"
            raise VolumeError(
                f"{p}: the folder holds {len(found.volumes)} {kinds} ({', '.join(v.name for v in found.volumes)}); "
                "read them one by one (hortishape.io.find_sources lists them; 'hortishape extract' takes them all)"
            )
        source = found.volumes[0]
    info: dict = {}
    try:
        if source is not None and source.kind == "dicom":
            raw, info = read_series(list(source.files), name=p)
        elif (source is not None and source.kind == "tiff-slices") or extension in TIFF_EXTENSIONS:
            if p.is_file():
                check_not_empty(p, VolumeError)
            raw, info = read_tiff(p)
        else:
            header = read_header(p) if extension not in _VOLUME_FORMATS else None
            if header is not None and header.is_directory:
                raise VolumeError(f"{p}: a DICOMDIR, the index of a DICOM tree: pass the folder that holds it")
            if header is not None and header.frames > 1:  # a multi-frame file: a volume of its own
                raw, info = read_series([p], name=p)
            elif extension == ".dcm" or header is not None:
                raise VolumeError(
                    f"{p}: a single DICOM file holds one slice; pass the folder of the series"
                )
            elif extension not in _VOLUME_FORMATS:
                shown = extension or "(none)"
                raise VolumeError(
                    f"{p}: unknown volume format {shown!r}; supported: {', '.join(volume_formats())}, "
                    "or a folder of DICOM files or of .tif slices"
                )
            else:
                check_not_empty(p, VolumeError)
                raw = _VOLUME_FORMATS[extension].read(p)
                info = {"spacing_source": f"the {_VOLUME_FORMATS[extension].name} header"}
    except VolumeError:
        raise
    except _ParseError as exc:
        raise VolumeError(f"{p}: {exc}") from None
    except OSError as exc:
        raise VolumeError(f"{p}: cannot read ({exc.strerror or exc})") from None
    except RuntimeError as exc:  # SimpleITK reports every failure as RuntimeError
        raise VolumeError(f"{p}: cannot read it ({_sitk_message(exc)})") from None
    except ValueError as exc:
        raise VolumeError(f"{p}: cannot read it ({exc})") from exc
    file_spacing = raw.spacing
    where = info.get("spacing_source", "")
    if spacing is not None:
        file_spacing, where = np.asarray(spacing, dtype=np.float64), "given (spacing=, --spacing)"
    elif not raw.geometry_known:
        raise VolumeError(
            f"{p}: no voxel size: the TIFF holds no OME or ImageJ voxel size and no scanner log beside it "
            f"({', '.join(LOG_EXTENSIONS)}) states one; give it with --spacing SX SY SZ (mm)"
        )
    arr, s, o, d = _check_volume(raw.data, file_spacing, raw.origin, raw.direction, name=str(p))
    return Volume(arr, s, o, d, spacing_source=where)


def write_volume(path: PathLike, volume: Volume, *, compress: bool = True) -> Path:
    """Write a volume atomically, in the format given by the extension.

    Parameters
    ----------
    path : str or os.PathLike
        ``.mha`` (one file) or ``.mhd`` (header plus ``.raw`` / ``.zraw`` data
        file next to it), written natively; ``.nrrd``, ``.nii``, ``.nii.gz``,
        ``.tif`` / ``.tiff`` through SimpleITK. TIFF keeps no spacing, origin
        or direction.
    volume : Volume
    compress : bool, default: True
        zlib-compress the voxel data (MetaImage, NRRD; NIfTI by extension).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    VolumeError
        Unknown extension, not a :class:`Volume`, missing folder or the file
        cannot be written; the target is then left as it was.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = pathlib.Path(tmp.name)
    >>> v = Volume(np.arange(24, dtype=np.uint8).reshape(2, 3, 4), spacing=(1, 1, 2))
    >>> int(read_volume(write_volume(folder / "ct.mha", v)).data[1, 2, 3])
    23
    """
    p = Path(path)
    if not isinstance(volume, Volume):
        raise VolumeError(f"{p}: expected a Volume, got {type(volume).__name__}")
    extension = full_suffix(p)
    fmt = _VOLUME_FORMATS.get(extension)
    if fmt is None or fmt.write is None:
        writable = sorted(k for k, f in _VOLUME_FORMATS.items() if f.write is not None)
        raise VolumeError(
            f"{p}: cannot write volume format {extension or '(none)'!r}; "
            f"supported: {', '.join(writable)}"
        )
    try:
        fmt.write(p, volume, compress)
    except KeyError:  # MetaImage's element types
        raise VolumeError(f"{p}: {fmt.name} cannot store {volume.data.dtype} voxels") from None
    return p
