"""Volumes written the way scanners write them, for the tests: DICOM series through pydicom
(extensionless slice files, rescale slope and intercept, study folders of several series),
TIFF stacks with only a scanner's log beside them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROOT = "1.2.826.0.1.3680043.8.498."  # a UID prefix for examples


def ball_ct(n=40, radii=(14.0, 12.0, 15.0), *, noise=20.0, seed=0):
    """A CT-like ellipsoid in Hounsfield-like units: air -1000, flesh about 0, a partial-volume edge."""
    from scipy.special import erf

    x, y, z = np.mgrid[:n, :n, :n].astype(np.float64) - (n - 1) / 2
    q = np.sqrt((x / radii[0]) ** 2 + (y / radii[1]) ** 2 + (z / radii[2]) ** 2)
    d = (q - 1.0) * min(radii)
    values = -1000.0 + 1000.0 * 0.5 * (1.0 - erf(d / (0.7 * np.sqrt(2.0))))
    values += np.random.default_rng(seed).normal(0.0, noise, d.shape)
    return np.round(values).astype(np.int16)


def write_dicom_series(folder: Path, data: np.ndarray, *, spacing=(0.5, 0.5, 0.8), origin=(0.0, 0.0, 0.0),
                       series_uid: str, description: str = "", number: int = 1, slope: float = 1.0,
                       intercept: float = -1024.0, names: str = "IM{:04d}", skip=(), tilt_mm: float = 0.0,
                       thickness: float | None = None, study_uid: str = ROOT + "1") -> list[Path]:
    """Write ``data`` ([x, y, z], values after rescale) as one file per slice, as a CT scanner exports.

    Stored values are ``(data - intercept) / slope`` as uint16 / int16. ``skip`` leaves slices out (a
    missing slice); ``tilt_mm`` shifts each slice along y by that much per slice (a gantry tilt);
    ``thickness`` is the SliceThickness written (default: the step), which readers must not trust.
    """
    from hortishape.io.dicom import _write_ct_slice

    folder.mkdir(parents=True, exist_ok=True)
    stored = np.round((np.asarray(data, np.float64) - intercept) / slope)
    stored = stored.astype(np.int16 if stored.min() < 0 else np.uint16)
    paths = []
    for k in range(stored.shape[2]):
        if k in skip:
            continue
        position = (origin[0], origin[1] + k * tilt_mm, origin[2] + k * spacing[2])
        paths.append(_write_ct_slice(
            folder / names.format(k), stored[:, :, k], study_uid=study_uid, series_uid=series_uid, instance=k + 1,
            series_number=number, description=description, orientation=(1, 0, 0, 0, 1, 0), position=position,
            pixel_spacing=(spacing[1], spacing[0]), thickness=spacing[2] if thickness is None else thickness,
            slope=slope, intercept=intercept))
    return paths


def write_tiff_slices(folder: Path, data: np.ndarray, *, names: str = "slice_{:04d}.tif") -> list[Path]:
    """``data`` ([x, y, z]) as one 2D TIFF per slice without any voxel size, as micro-CT software exports."""
    import tifffile

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(data.shape[2]):
        path = folder / names.format(k)
        tifffile.imwrite(path, np.ascontiguousarray(data[:, :, k].T), photometric="minisblack")
        paths.append(path)
    return paths


def write_skyscan_log(path: Path, pixel_um: float) -> Path:
    """A Bruker SkyScan reconstruction log stating the voxel size, as NRecon writes it."""
    path.write_text(
        "[System]\nScanner=Skyscan1272\n[Acquisition]\nNumber of Rows=  2016\n"
        f"Image Pixel Size (um)={pixel_um * 2:.5f}\n"  # the acquisition's, before the reconstruction's binning
        "[Reconstruction]\nReconstruction Program=NRecon\n"
        f"Pixel Size (um)={pixel_um:.5f}\nResult File Type=TIF\n",
        encoding="utf-8",
    )
    return path
