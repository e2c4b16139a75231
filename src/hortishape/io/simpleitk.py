"""NRRD, NIfTI, TIFF stacks and DICOM series folders, through the optional SimpleITK package."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import numpy as np

from .._files import atomic_path, full_suffix
from ..errors import VolumeError
from ._common import _ParseError, _RawVolume
from .volume import Volume

_TIFF = (".tif", ".tiff")


def _import_sitk(path: Path, action: str, what: str):
    try:
        return importlib.import_module("SimpleITK")
    except ImportError:
        raise VolumeError(
            f"{path}: {action} {what} needs the optional dependency 'SimpleITK' "
            '(pip install "hortishape[ct]")'
        ) from None


def _sitk_message(exc: Exception) -> str:
    """The useful last line of a SimpleITK exception (which starts with C++ source paths)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return re.sub(r"^sitk::ERROR:\s*", "", lines[-1]) if lines else type(exc).__name__


def _natural_key(path: Path) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def _sitk_image(path: Path):
    """A SimpleITK image from a file, a DICOM series folder or a folder of TIFF slices."""
    if path.is_dir():
        files = sorted(
            (f for f in path.iterdir() if f.is_file() and not f.name.startswith(".")),
            key=_natural_key,
        )
        slices = [f for f in files if f.suffix.lower() in _TIFF]
        what = "TIFF slices" if slices else "DICOM series"
        sitk = _import_sitk(path, "reading", what)
        if slices:
            if len(slices) < 2:
                raise VolumeError(
                    f"{path}: holds a single TIFF slice, need at least 2 for a volume"
                )
            return sitk.ReadImage([str(f) for f in slices]), True
        series = sitk.ImageSeriesReader.GetGDCMSeriesIDs(str(path))
        if not series:
            raise VolumeError(f"{path}: the folder holds no DICOM series and no .tif slices")
        if len(series) > 1:
            raise VolumeError(
                f"{path}: the folder holds {len(series)} DICOM series ({', '.join(series)}); "
                "put each series in its own folder"
            )
        names = sitk.ImageSeriesReader.GetGDCMSeriesFileNames(str(path), series[0])
        reader = sitk.ImageSeriesReader()
        reader.SetFileNames(names)
        return reader.Execute(), False
    extension = full_suffix(path)
    sitk = _import_sitk(path, "reading", f"{extension} files")
    return sitk.ReadImage(str(path)), extension in _TIFF


def _read_sitk(path: Path) -> _RawVolume:
    """A volume from a file, a DICOM series folder or a folder of TIFF slices."""
    image, is_tiff = _sitk_image(path)
    if image.GetNumberOfComponentsPerPixel() != 1:
        raise _ParseError(
            f"has {image.GetNumberOfComponentsPerPixel()} values per voxel (colour?); "
            "only scalar volumes are supported"
        )
    if image.GetDimension() != 3:
        raise _ParseError(f"is a {image.GetDimension()}D image, not a 3D volume")
    sitk = importlib.import_module("SimpleITK")
    data = sitk.GetArrayFromImage(image).transpose(2, 1, 0)  # (z, y, x) -> [x, y, z]
    if is_tiff:
        # TIFF resolution tags are usually screen DPI, not voxel size.
        return _RawVolume(data, np.ones(3), np.zeros(3), np.eye(3), geometry_known=False)
    return _RawVolume(data, np.array(image.GetSpacing()), np.array(image.GetOrigin()),
                      np.array(image.GetDirection()).reshape(3, 3))


def _write_sitk(path: Path, volume: Volume, compress: bool) -> None:
    sitk = _import_sitk(path, "writing", f"{full_suffix(path)} files")
    data = volume.data.astype(np.uint8) if volume.data.dtype == bool else volume.data
    image = sitk.GetImageFromArray(np.ascontiguousarray(data.transpose(2, 1, 0)))
    image.SetSpacing(volume.spacing.tolist())
    image.SetOrigin(volume.origin.tolist())
    image.SetDirection(volume.direction.ravel().tolist())
    with atomic_path(path, VolumeError) as tmp:
        try:
            sitk.WriteImage(image, str(tmp), compress)
        except RuntimeError as exc:
            raise VolumeError(f"{path}: cannot write it ({_sitk_message(exc)})") from None
