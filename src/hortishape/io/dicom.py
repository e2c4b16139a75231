"""DICOM series as scanners and PACS export them, through the optional pydicom package.

A series is found by content, not by file name: slice files often have no
extension (``IM0000``, ``00000001``), one folder can hold several series, and a
study folder or a DICOMDIR's tree holds them in nested folders. The series
(SeriesInstanceUID) of each slice is read from its header; the slices of one
series are put in order along the normal of their ImageOrientationPatient and
the slice spacing is taken from their ImagePositionPatient, not from
SliceThickness (which is the slab's width, not the step). A series whose
slices are not evenly spaced (a slice missing), are not stacked along their
normal (a gantry tilt), or differ in size or orientation, is refused with a
message saying what is wrong and where: a surface from it would be distorted.
"""

from __future__ import annotations

import importlib
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import VolumeError
from ._common import _first_line, _ParseError, _RawVolume

#: Extensions of files that may be DICOM slices without the 128-byte preamble
#: and "DICM" mark (old ACR-NEMA style exports); other files need the mark.
_MAYBE_DICOM = ("", ".dcm", ".dicom", ".dic", ".ima")

#: Relative spread of the steps between slices above which a series is refused
#: (a missing slice doubles one step; rounding of positions in headers is far smaller).
SLICE_STEP_TOLERANCE = 0.05

#: Largest angle (degrees) between the slices' stacking direction and their
#: normal that is not a gantry tilt (headers round positions to a few digits).
TILT_TOLERANCE_DEG = 0.5

_HEADER_TAGS = ("SeriesInstanceUID", "SeriesDescription", "SeriesNumber", "SOPClassUID", "Rows", "Columns",
                "ImagePositionPatient", "ImageOrientationPatient", "PixelSpacing", "InstanceNumber",
                "NumberOfFrames", "SliceThickness", "SpacingBetweenSlices", "Modality")

_DICOMDIR_CLASS = "1.2.840.10008.1.3.10"  # Media Storage Directory Storage


def _pydicom(path: Path):
    try:
        return importlib.import_module("pydicom")
    except ImportError:
        raise VolumeError(
            f"{path}: reading DICOM needs the optional dependency 'pydicom' (pip install \"hortishape[ct]\")"
        ) from None


@dataclass(frozen=True)
class DicomHeader:
    """What a slice's header says about the series it belongs to (read without its pixels)."""

    path: Path
    series_uid: str
    description: str
    number: str
    rows: int
    columns: int
    frames: int
    is_directory: bool = False  # a DICOMDIR


def has_dicom_mark(path: Path) -> bool:
    """Whether the file starts with the DICOM preamble and ``DICM`` mark."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(132)
    except OSError:
        return False
    return len(head) == 132 and head[128:132] == b"DICM"


def read_header(path: Path) -> DicomHeader | None:
    """The header of a DICOM file, or None when the file is not DICOM (or too broken to say)."""
    marked = has_dicom_mark(path)
    if not marked and path.suffix.lower() not in _MAYBE_DICOM:
        return None
    try:
        pydicom = importlib.import_module("pydicom")
    except ImportError:
        if marked:  # a DICOM file that cannot be read here: say what is missing
            raise
        return None
    try:
        with warnings.catch_warnings():  # pydicom's about odd values in a header; what matters is said later
            warnings.simplefilter("ignore")
            ds = pydicom.dcmread(path, stop_before_pixels=True, force=not marked, specific_tags=list(_HEADER_TAGS))
        if not marked and "SOPClassUID" not in ds and "Rows" not in ds:
            return None  # force=True reads anything; without these it was not DICOM
        sop = str(ds.get("SOPClassUID", "") or getattr(getattr(ds, "file_meta", None), "MediaStorageSOPClassUID", ""))
        if path.name.upper() == "DICOMDIR" or sop == _DICOMDIR_CLASS:
            return DicomHeader(path, "", "", "", 0, 0, 0, is_directory=True)
        return DicomHeader(
            path=path,
            series_uid=str(ds.get("SeriesInstanceUID", "") or ""),
            description=str(ds.get("SeriesDescription", "") or "").strip(),
            number=str(ds.get("SeriesNumber", "") or "").strip(),
            rows=int(ds.get("Rows", 0) or 0),
            columns=int(ds.get("Columns", 0) or 0),
            frames=int(ds.get("NumberOfFrames", 1) or 1),
        )
    except Exception:  # noqa: BLE001 - pydicom raises many kinds on a broken header; then it is not a slice
        return None


def _floats(ds, keyword: str, n: int, where: Path) -> np.ndarray | None:
    value = ds.get(keyword)
    if value is None:
        return None
    items = list(value) if hasattr(value, "__len__") and not isinstance(value, (str, bytes)) else [value]
    try:
        arr = np.array([float(v) for v in items], dtype=np.float64)
    except (TypeError, ValueError):
        raise _ParseError(f"slice {where.name}: {keyword} is not numeric ({value!r})") from None
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise _ParseError(f"slice {where.name}: {keyword} should hold {n} numbers, got {value!r}")
    return arr


def _multi_frame(path: Path, ds) -> tuple[_RawVolume, dict]:
    """A multi-frame (enhanced) DICOM file: one volume in one file, read with its geometry by SimpleITK."""
    try:
        sitk = importlib.import_module("SimpleITK")
    except ImportError:
        raise _ParseError(f"{path.name} is a multi-frame DICOM file: reading it needs SimpleITK "
                          '(pip install "hortishape[ct]")') from None
    try:
        image = sitk.ReadImage(str(path))  # GDCM applies the rescale
    except RuntimeError as exc:
        raise _ParseError(f"{path.name}: cannot read this multi-frame DICOM file ({exc})".splitlines()[0]) from None
    if image.GetDimension() != 3 or image.GetNumberOfComponentsPerPixel() != 1:
        raise _ParseError(f"{path.name}: not one grey-value 3D volume")
    data = sitk.GetArrayFromImage(image).transpose(2, 1, 0)
    info = {"spacing_source": "DICOM multi-frame header (SimpleITK)", "series_uid": str(ds.get("SeriesInstanceUID", "")),
            "series_description": str(ds.get("SeriesDescription", "") or ""), "n_slices": int(data.shape[2]),
            "modality": str(ds.get("Modality", "") or "")}
    return _RawVolume(np.ascontiguousarray(data), np.array(image.GetSpacing()), np.array(image.GetOrigin()),
                      np.array(image.GetDirection()).reshape(3, 3)), info


def _check_length(ds, path: Path) -> None:
    """Refuse uncompressed pixel data cut short (some pydicom versions pad it silently)."""
    meta = getattr(ds, "file_meta", None)
    syntax = getattr(meta, "TransferSyntaxUID", None)
    if "PixelData" not in ds or syntax is None or getattr(syntax, "is_compressed", True):
        return
    try:
        expected = (int(ds.Rows) * int(ds.Columns) * int(ds.get("NumberOfFrames", 1) or 1)
                    * int(ds.get("SamplesPerPixel", 1) or 1) * int(ds.BitsAllocated) // 8)
        got = len(ds.PixelData)
    except (AttributeError, TypeError, ValueError):
        return  # pydicom says what is missing when it decodes
    if got < expected:
        raise _ParseError(f"slice {path.name}: cannot decode its pixels (cut short: {got:,} of {expected:,} bytes)")


def _pixels(ds, path: Path) -> tuple[np.ndarray, bool]:
    """A slice's values (rows, columns) and whether they are rescaled already.

    Decoded by pydicom (stored values), or by SimpleITK where pydicom cannot
    (a compression it has no decoder for), which applies the rescale itself.
    """
    rescaled = False
    _check_length(ds, path)
    try:
        arr = ds.pixel_array
    except Exception as exc:  # noqa: BLE001 - truncated data, an unknown compression: say which slice
        try:
            sitk = importlib.import_module("SimpleITK")
            arr = sitk.GetArrayFromImage(sitk.ReadImage(str(path)))
            arr = arr.reshape(arr.shape[-2:]) if arr.ndim == 3 and arr.shape[0] == 1 else arr
            rescaled = True
        except Exception:  # noqa: BLE001
            raise _ParseError(f"slice {path.name}: cannot decode its pixels ({_first_line(exc)})") from None
    arr = np.asarray(arr)
    if arr.ndim != 2:
        what = "colour" if arr.ndim == 3 and arr.shape[-1] in (3, 4) else f"shape {arr.shape}"
        raise _ParseError(f"slice {path.name}: is not one grey-value image ({what})")
    return arr, rescaled


def read_series(files: list[Path], *, name: Path) -> tuple[_RawVolume, dict]:
    """Read one series' slices into a volume indexed ``[x, y, z]``.

    Parameters
    ----------
    files : list of Path
        The slices of one series (any order).
    name : Path
        What error messages start with (the folder).

    Returns
    -------
    raw : _RawVolume
        Values after the rescale slope and intercept (Hounsfield units in CT).
    info : dict
        ``spacing_source``, ``series_uid``, ``series_description``, ``n_slices``, ``modality``.
    """
    pydicom = _pydicom(name)
    with warnings.catch_warnings():  # pydicom warns of values scanners write a little off the standard
        warnings.simplefilter("ignore")
        return _read_series(pydicom, files, name)


def _read_series(pydicom, files: list[Path], name: Path) -> tuple[_RawVolume, dict]:
    slices = []
    for f in files:
        try:
            ds = pydicom.dcmread(f, force=not has_dicom_mark(f))
        except Exception as exc:  # noqa: BLE001 - a truncated or garbled header
            raise _ParseError(f"slice {f.name}: cannot read its header ({_first_line(exc)})") from None
        slices.append((f, ds))
    if len(slices) == 1 and int(slices[0][1].get("NumberOfFrames", 1) or 1) > 1:
        return _multi_frame(files[0], slices[0][1])
    if len(slices) < 2:
        raise _ParseError(f"the series has {len(slices)} slice; a volume needs at least 2")
    uids = {str(ds.get("SeriesInstanceUID", "")) for _, ds in slices}
    if len(uids) > 1:
        raise _ParseError(f"holds {len(uids)} DICOM series; read each on its own")
    sizes = {}
    for f, ds in slices:
        sizes.setdefault((int(ds.get("Rows", 0) or 0), int(ds.get("Columns", 0) or 0)), []).append(f.name)
    if len(sizes) > 1:
        (common, _), *others = sorted(sizes.items(), key=lambda kv: -len(kv[1]))
        odd = others[0][1][0]
        raise _ParseError(f"slice {odd} is {others[0][0][1]} x {others[0][0][0]} pixels, "
                          f"the others {common[1]} x {common[0]}")
    f0, ds0 = slices[0]
    orient = _floats(ds0, "ImageOrientationPatient", 6, f0)
    spacing_px = _floats(ds0, "PixelSpacing", 2, f0)
    if spacing_px is None:
        spacing_px = _floats(ds0, "ImagerPixelSpacing", 2, f0)
    if spacing_px is None or np.any(spacing_px <= 0):
        raise _ParseError(f"slice {f0.name}: no PixelSpacing, so no voxel size; give it with --spacing SX SY SZ")
    positions = [_floats(ds, "ImagePositionPatient", 3, f) for f, ds in slices]
    if orient is not None and all(p is not None for p in positions):
        for f, ds in slices[1:]:
            o = _floats(ds, "ImageOrientationPatient", 6, f)
            if o is None or np.abs(o - orient).max() > 1e-4:
                raise _ParseError(f"slice {f.name}: its orientation differs from slice {f0.name}'s")
        row, col = orient[:3], orient[3:]
        row, col = row / np.linalg.norm(row), col / np.linalg.norm(col)
        normal = np.cross(row, col)
        pos = np.array(positions)
        along = pos @ normal
        order = np.argsort(along, kind="stable")
        along, pos = along[order], pos[order]
        slices = [slices[k] for k in order]
        steps = np.diff(along)
        if np.any(steps <= 1e-6 * max(1.0, float(np.abs(along).max()))):
            k = int(np.argmin(steps))
            raise _ParseError(f"slices {slices[k][0].name} and {slices[k + 1][0].name} lie at the same place "
                              "(two acquisitions or echoes in one series?)")
        step = float(np.median(steps))
        bad = np.abs(steps - step) > SLICE_STEP_TOLERANCE * step
        if np.any(bad):
            k = int(np.flatnonzero(bad)[0])
            what = (f"about {round(steps[k] / step) - 1} slice(s) missing" if steps[k] > 1.5 * step
                    else "uneven slice spacing")
            raise _ParseError(
                f"{what}: {steps[k]:.4g} mm between slices {slices[k][0].name} and {slices[k + 1][0].name}, "
                f"{step:.4g} mm elsewhere; a surface from it would be distorted (export the whole series)")
        stack = pos[-1] - pos[0]
        cos = abs(float(stack @ normal)) / max(float(np.linalg.norm(stack)), 1e-12)
        tilt = float(np.degrees(np.arccos(min(1.0, cos))))
        if tilt > TILT_TOLERANCE_DEG:
            raise _ParseError(
                f"the slices are stacked {tilt:.1f} degrees off their normal (a gantry tilt); resample the series "
                "to an upright grid (e.g. in the scanner's software) before extracting a surface")
        direction = np.column_stack([row, col, normal])
        origin = pos[0]
        step = float((along[-1] - along[0]) / (len(along) - 1))
        for key in ("SpacingBetweenSlices", "SliceThickness"):
            # positions are written with a few digits each: a header's step that agrees is the exact one
            value = ds0.get(key)
            try:
                if value not in (None, "") and abs(float(value) - step) <= 1e-6 * step:
                    step = float(value)
                    break
            except (TypeError, ValueError):
                pass
        spacing = np.array([spacing_px[1], spacing_px[0], step])
        source = "DICOM PixelSpacing and ImagePositionPatient"
    else:
        # No geometry per slice: the order of InstanceNumber, the step from the header.
        numbers = [ds.get("InstanceNumber") for _, ds in slices]
        if any(n is None for n in numbers):
            raise _ParseError("the slices have neither ImagePositionPatient nor InstanceNumber: their order is unknown")
        slices = [slices[k] for k in np.argsort([int(n) for n in numbers], kind="stable")]
        step = None
        for key in ("SpacingBetweenSlices", "SliceThickness"):
            value = ds0.get(key)
            if value not in (None, "") and float(value) > 0:
                step, source = float(value), f"DICOM PixelSpacing and {key} (no ImagePositionPatient)"
                break
        if step is None:
            raise _ParseError("no slice positions and no SliceThickness: the slice step is unknown; "
                              "give it with --spacing SX SY SZ")
        direction, origin = np.eye(3), np.zeros(3)
        spacing = np.array([spacing_px[1], spacing_px[0], step])
    planes = []
    for f, ds in slices:
        values, rescaled = _pixels(ds, f)
        slope = 1.0 if rescaled else float(ds.get("RescaleSlope", 1) or 1)
        intercept = 0.0 if rescaled else float(ds.get("RescaleIntercept", 0) or 0)
        planes.append((values, slope, intercept))
    # the values in the smallest type that holds them: a CT's int16 stays int16 (a volume of a
    # thousand 512 x 512 slices is 0.5 GB so, 2 GB as float64)
    integral = all(s == 1.0 and float(i).is_integer() for _, s, i in planes)
    dtype = np.dtype(np.float32)
    if integral:
        lo = min(float(v.min()) + i for v, _, i in planes)
        hi = max(float(v.max()) + i for v, _, i in planes)
        dtype = next((np.dtype(t) for t in (np.int16, np.int32) if np.iinfo(t).min <= lo and hi <= np.iinfo(t).max),
                     np.dtype(np.float64))
    rows, columns = planes[0][0].shape
    data = np.empty((columns, rows, len(planes)), dtype=dtype)  # [x = column, y = row, z = slice]
    for k, (values, slope, intercept) in enumerate(planes):
        if integral:
            data[:, :, k] = (values.T.astype(np.int64) + int(intercept)).astype(dtype)
        else:
            data[:, :, k] = values.T.astype(np.float64) * slope + intercept
    info = {"spacing_source": source, "series_uid": str(ds0.get("SeriesInstanceUID", "")),
            "series_description": str(ds0.get("SeriesDescription", "") or ""), "n_slices": len(slices),
            "modality": str(ds0.get("Modality", "") or "")}
    return _RawVolume(data, spacing, origin, direction), info


_CT_IMAGE_STORAGE = "1.2.840.10008.5.1.4.1.1.2"


def _write_ct_slice(path: Path, pixels: np.ndarray, *, study_uid: str, series_uid: str, instance: int,
                    series_number: int, description: str, orientation, position, pixel_spacing,
                    thickness: float, slope: float, intercept: float) -> Path:
    """One slice of a CT series as a scanner writes it: ``pixels`` indexed [x, y], int16 or uint16.

    ``pixel_spacing`` is DICOM's (rows, then columns: y, then x); ``orientation`` the six direction
    cosines of a row and a column.
    """
    import pydicom
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian

    uid = f"{series_uid}.{instance}"[:64]
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = _CT_IMAGE_STORAGE
    meta.MediaStorageSOPInstanceUID = uid
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = FileDataset(str(path), {}, file_meta=meta, preamble=b"\0" * 128)
    ds.SOPClassUID = _CT_IMAGE_STORAGE
    ds.SOPInstanceUID = uid
    ds.StudyInstanceUID = study_uid
    ds.SeriesInstanceUID = series_uid
    ds.SeriesNumber = int(series_number)
    ds.InstanceNumber = int(instance)
    ds.Modality = "CT"
    if description:
        ds.SeriesDescription = description
    ds.ImageOrientationPatient = [float(c) for c in orientation]
    ds.ImagePositionPatient = [float(c) for c in position]
    ds.PixelSpacing = [float(c) for c in pixel_spacing]
    ds.SliceThickness = float(thickness)
    ds.RescaleSlope = f"{slope:.10g}"
    ds.RescaleIntercept = f"{intercept:.10g}"
    ds.Rows, ds.Columns = pixels.shape[1], pixels.shape[0]
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated = ds.BitsStored = 16
    ds.HighBit = 15
    ds.PixelRepresentation = 1 if pixels.dtype == np.int16 else 0
    ds.PixelData = np.ascontiguousarray(pixels.T).tobytes()  # a slice's rows run along y
    pydicom.dcmwrite(path, ds, enforce_file_format=True)
    return path


def write_dicom_series(folder, volume, *, description: str = "", series_number: int = 1) -> list[Path]:
    """Write a volume as a CT scanner exports it: one extensionless DICOM file per slice.

    The folder must not exist yet: the slices are written into a temporary folder beside it,
    which takes its name only once every slice is there. The values are stored as 16-bit
    integers with the rescale slope and intercept that keep their range (integer volumes within
    the 16-bit range are stored exactly); spacing, origin and direction go into PixelSpacing,
    ImagePositionPatient and ImageOrientationPatient.

    Parameters
    ----------
    folder : path
        The series' folder, created; its slices are ``IM0000``, ``IM0001``, ...
    volume : Volume
        Indexed ``[x, y, z]``; one slice per ``z``.
    description : str, default: ""
        SeriesDescription (``find_sources`` names series by it when all differ).
    series_number : int, default: 1

    Returns
    -------
    list of Path
        The slice files, in order.

    Examples
    --------
    >>> import tempfile
    >>> from hortishape.io import Volume, read_volume
    >>> data = np.zeros((8, 8, 5), np.int16); data[2:6, 2:6, 1:4] = 1000
    >>> folder = Path(tempfile.mkdtemp()) / "apple_01"
    >>> len(write_dicom_series(folder, Volume(data, spacing=(0.4, 0.4, 1.0)), description="apple 1"))
    5
    >>> v = read_volume(folder)
    >>> v.spacing.tolist(), bool((v.data == data).all())
    ([0.4, 0.4, 1.0], True)
    """
    import shutil
    import tempfile

    _pydicom(Path(folder))
    from pydicom.uid import generate_uid

    folder = Path(folder)
    if folder.exists():
        raise VolumeError(f"{folder}: already exists; a DICOM series is written into a new folder")
    folder.parent.mkdir(parents=True, exist_ok=True)
    data = np.asarray(volume.data)
    lo, hi = float(data.min()), float(data.max())
    if np.issubdtype(data.dtype, np.integer) and -32768 <= lo and hi <= 32767:
        slope, intercept, stored = 1.0, 0.0, data.astype(np.int16)
    else:  # the range over 65,535 steps, stored as uint16
        slope = (hi - lo) / 65535.0 or 1.0
        intercept = lo
        stored = np.round((data - intercept) / slope).astype(np.uint16)
    # the same volume and name give the same identifiers (reproducible files)
    seed = [folder.name, description, str(data.shape), str(volume.spacing.tolist())]
    study_uid = generate_uid(entropy_srcs=["study", *seed])
    series_uid = generate_uid(entropy_srcs=["series", *seed])
    direction = np.asarray(volume.direction, np.float64)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        for k in range(stored.shape[2]):
            _write_ct_slice(tmp / f"IM{k:04d}", stored[:, :, k], study_uid=study_uid, series_uid=series_uid,
                            instance=k + 1, series_number=series_number, description=description,
                            orientation=(*direction[:, 0], *direction[:, 1]),
                            position=volume.origin + direction[:, 2] * (k * volume.spacing[2]),
                            pixel_spacing=(volume.spacing[1], volume.spacing[0]), thickness=volume.spacing[2],
                            slope=slope, intercept=intercept)
        tmp.rename(folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [folder / f"IM{k:04d}" for k in range(stored.shape[2])]
