"""NRRD and NIfTI files, through the optional SimpleITK package."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import numpy as np

from .._files import atomic_path, full_suffix
from ..errors import VolumeError
from ._common import _ParseError, _RawVolume
from .volume import Volume

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


def _read_sitk(path: Path) -> _RawVolume:
    """A volume from an NRRD or NIfTI file."""
    sitk = _import_sitk(path, "reading", f"{full_suffix(path)} files")
    image = sitk.ReadImage(str(path))
    if image.GetNumberOfComponentsPerPixel() != 1:
        raise _ParseError(
            f"has {image.GetNumberOfComponentsPerPixel()} values per voxel (colour?); "
            "only scalar volumes are supported"
        )
    if image.GetDimension() != 3:
        raise _ParseError(f"is a {image.GetDimension()}D image, not a 3D volume")
    data = sitk.GetArrayFromImage(image).transpose(2, 1, 0)  # (z, y, x) -> [x, y, z]
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
