"""Finding the scans in what a user points at: files, folders, study folders, DICOMDIR trees.

One function, :func:`find_sources`, decides what is a scan, so ``hortishape
extract`` and ``hortishape build`` find exactly the same ones, and everything
it does not take is listed with the reason.
"""

from __future__ import annotations

import os
import re
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from .._files import PathLike, full_suffix
from .dicom import DicomHeader, read_header
from .tiff import LOG_EXTENSIONS, TIFF_EXTENSIONS, find_scanner_log
from .mesh_files import is_mesh_file

#: Volume file extensions (besides TIFF) read as one volume each.
_VOLUME_FILES = (".mha", ".mhd", ".nrrd", ".nhdr", ".nii", ".nii.gz")
#: Data files that belong to a header next to them.
_DATA_FILES = (".raw", ".zraw", ".raw.gz", ".img", ".gz")


@dataclass(frozen=True)
class VolumeSource:
    """One volume to read: a file, a folder of TIFF slices, or one DICOM series.

    Attributes
    ----------
    name : str
        The scan's name: its outputs are ``<name>.ply`` etc. A file's name
        without its extension; a folder's name; a DICOM series'
        SeriesDescription where the series found all have distinct ones,
        else its folder's name (or its description, where its folder holds
        several series). Names that would clash get their folders' names in
        front.
    path : Path
        The file, or the folder holding the slices.
    kind : {"file", "tiff-slices", "dicom"}
    files : tuple of Path
        The slices of a DICOM series.
    series_uid, description : str
        Of a DICOM series.
    """

    name: str
    path: Path
    kind: str = "file"
    files: tuple = field(default=(), repr=False)
    series_uid: str = ""
    description: str = ""

    def resolved(self) -> "VolumeSource":
        """The same source with absolute paths (for workers in other folders)."""
        return VolumeSource(self.name, self.path.resolve(), self.kind, tuple(f.resolve() for f in self.files),
                            self.series_uid, self.description)

    def __str__(self) -> str:
        if self.kind == "dicom" and self.description and self.name != self.path.name:
            return f"{self.path} (series {self.description!r})"
        return str(self.path)

    def all_files(self) -> list[Path]:
        """Every file whose bytes make the volume (for fingerprints)."""
        if self.kind == "dicom":
            return sorted(self.files)
        if self.path.is_dir():
            return sorted(f for f in self.path.iterdir() if f.is_file() and not f.name.startswith("."))
        files = [self.path]
        if self.path.suffix.lower() in (".mhd", ".nhdr"):
            files += sorted(f for f in self.path.parent.glob(self.path.stem + ".*")
                            if f != self.path and f.suffix.lower() in (".raw", ".zraw", ".gz", ".raw.gz"))
        return files


@dataclass(frozen=True)
class Sources:
    """What :func:`find_sources` found.

    Attributes
    ----------
    volumes : tuple of VolumeSource
        In order of name.
    meshes : tuple of Path
        Mesh files, in order of name.
    skipped : tuple of (str, str)
        Every file or folder not taken, with why.
    """

    volumes: tuple = ()
    meshes: tuple = ()
    skipped: tuple = field(default=())


def _stem(path: Path) -> str:
    name, ext = path.name, full_suffix(path)
    return name[: -len(ext)] if ext and len(name) > len(ext) else name


def _safe(text: str) -> str:
    return re.sub(r"[^\w.+-]+", "_", text.strip()).strip("._") or "series"


def find_sources(paths: PathLike | Iterable[PathLike], *, meshes: bool = True,
                 exclude: Iterable[PathLike] = ()) -> Sources:
    """The scans in files and folders, found by content, with what was passed over and why.

    A folder is searched with its subfolders: volume files (MHA/MHD, NRRD,
    NIfTI, TIFF stacks), folders of 2D TIFF slices, DICOM series (found by
    their headers whatever the files are called, grouped by
    SeriesInstanceUID, wherever in the tree their slices lie; a DICOMDIR is
    an index of them) and, with ``meshes``, mesh files.

    Parameters
    ----------
    paths : path or iterable of paths
        Files and folders.
    meshes : bool, default: True
        Take mesh files (those named and those in the folders themselves, not
        in their subfolders, which may hold earlier outputs); otherwise they
        are listed as skipped.
    exclude : iterable of paths
        Folders not to look into (an output folder inside the input).

    Returns
    -------
    Sources

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from hortishape.io import Volume, write_volume
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = write_volume(folder / "apple_1.mha", Volume(np.zeros((3, 3, 3), np.int16), spacing=0.5))
    >>> _ = (folder / "notes.txt").write_text("scanned on Monday")
    >>> found = find_sources(folder)
    >>> [v.name for v in found.volumes], [why for _, why in found.skipped]
    (['apple_1'], ['not a mesh, a volume or a DICOM file'])
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    excluded = {Path(p).resolve() for p in exclude}
    volumes: list[VolumeSource] = []
    mesh_files: list[Path] = []
    skipped: list[tuple[str, str]] = []
    series: dict[str, list[DicomHeader]] = {}
    logs: list[Path] = []

    def take_file(f: Path, tiffs_are_slices: bool, nested: bool = False) -> str | None:
        """Take a file; the reason when it is not taken."""
        ext = full_suffix(f)
        if ext in _VOLUME_FILES:
            volumes.append(VolumeSource(_stem(f), f))
        elif ext in TIFF_EXTENSIONS:
            if not tiffs_are_slices:
                volumes.append(VolumeSource(_stem(f), f))
        elif is_mesh_file(f):
            if not meshes:
                return "a mesh, not a volume"
            if nested:
                return "a mesh in a subfolder (meshes are taken from the folder itself)"
            mesh_files.append(f)
        elif ext in _DATA_FILES and any(f.with_name(f.name[: -len(ext)] + h).exists() for h in (".mhd", ".nhdr")):
            pass  # the data of a header beside it
        elif ext in LOG_EXTENSIONS:
            logs.append(f)
        elif f.name.endswith((".truth.json", ".truth.npz")):
            return "the ground truth of a synthetic scan (hortishape synth)"
        else:
            try:
                header = read_header(f)
            except ImportError:
                return 'a DICOM file; reading DICOM needs the optional dependency pydicom (pip install "hortishape[ct]")'
            if header is None:
                return "not a mesh, a volume or a DICOM file"
            if not header.is_directory:
                if not header.series_uid:
                    return "a DICOM file without a SeriesInstanceUID"
                if header.rows == 0:
                    return "a DICOM file without an image (a report, a structured set?)"
                series.setdefault(header.series_uid, []).append(header)
        return None

    def take_folder(folder: Path) -> None:
        for root, dirs, files in os.walk(folder):
            here = Path(root)
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and (here / d).resolve() not in excluded)
            files = sorted(f for f in files if not f.startswith("."))
            tifs = [f for f in files if full_suffix(Path(f)) in TIFF_EXTENSIONS]
            slices = len(tifs) >= 2 and _single_page(here / tifs[0])
            if slices:
                volumes.append(VolumeSource(here.name, here, "tiff-slices"))
            passed = []
            for name in files:
                reason = take_file(here / name, slices, nested=here != folder)
                if reason:
                    passed.append((here / name, reason))
            if passed and len(passed) == len(files) and len(files) > 3:
                skipped.append((str(here), f"none of its {len(files)} files is a scan ({passed[0][1]}, ...)"))
            else:
                skipped.extend((str(p), r) for p, r in passed)

    for p in (Path(x) for x in paths):
        if not p.exists():
            skipped.append((str(p), "no such file or folder"))
        elif p.is_dir():
            take_folder(p)
        else:
            reason = take_file(p, False)
            if reason:
                skipped.append((str(p), reason))
    volumes += _name_series(series, skipped)
    _add_log_reasons(logs, volumes, skipped)
    volumes = _unique_names(volumes, mesh_files)
    return Sources(tuple(sorted(volumes, key=lambda v: (v.name, str(v.path)))),
                   tuple(sorted(mesh_files, key=lambda f: (f.name, str(f)))), tuple(skipped))


def _single_page(path: Path) -> bool:
    try:
        import tifffile

        with tifffile.TiffFile(path) as tf:
            return len(tf.pages) == 1
    except Exception:  # noqa: BLE001 - a broken file: the reader will say what is wrong
        return True


def _name_series(series: dict, skipped: list) -> list[VolumeSource]:
    """One source per series of two slices or more, named after its SeriesDescription where several
    series all have distinct ones (an operator's names for the fruit), else after its folder."""
    per_folder: dict[Path, set] = {}
    for uid, headers in series.items():
        for h in headers:
            per_folder.setdefault(h.path.parent, set()).add(uid)
    kept = []
    for uid, headers in series.items():
        headers = sorted(headers, key=lambda h: h.path)
        first = headers[0]
        if len(headers) < 2 and first.frames < 2:
            label = first.description or (f"series {first.number}" if first.number else uid)
            skipped.append((str(first.path), f"a DICOM series of one slice ({label}), not a volume"))
            continue
        kept.append((uid, headers))
    described = [_safe(h[0].description) for _, h in kept if h[0].description]
    by_description = len(kept) > 1 and len(described) == len(kept) and len(set(described)) == len(kept)
    found = []
    for uid, headers in kept:
        first = headers[0]
        folders = sorted({h.path.parent for h in headers})
        folder = folders[0] if len(folders) == 1 else Path(os.path.commonpath([str(f) for f in folders]))
        alone = len(folders) == 1 and per_folder[folder] == {uid}
        if by_description:
            name = _safe(first.description)
        elif alone:
            name = folder.name
        else:
            name = _safe(first.description or f"series_{first.number or uid[-8:]}")
        found.append(VolumeSource(name, folder, "dicom", tuple(h.path for h in headers), uid, first.description))
    return found


def _add_log_reasons(logs: list[Path], volumes: list[VolumeSource], skipped: list) -> None:
    stacks = [v.path for v in volumes if full_suffix(v.path) in TIFF_EXTENSIONS or v.kind == "tiff-slices"]
    used = {found[0] for s in stacks if (found := find_scanner_log(s)) is not None}
    skipped.extend((str(f), "a log beside no TIFF stack") for f in logs if f not in used)


def _unique_names(volumes: list[VolumeSource], meshes: list[Path]) -> list[VolumeSource]:
    """Names made unique (outputs are named after them): clashing ones get their folders' names in front."""
    names = [v.name for v in volumes]
    parents = [v.path if v.kind == "dicom" and v.name != v.path.name else v.path.parent for v in volumes]
    stems = [_stem(m) for m in meshes]
    for _ in range(8):
        counts = Counter(names + stems)
        clashing = [i for i, n in enumerate(names) if counts[n] > 1 and parents[i] != parents[i].parent]
        if not clashing:
            break
        for i in clashing:
            names[i], parents[i] = f"{_safe(parents[i].name)}_{names[i]}", parents[i].parent
    seen = Counter(stems)
    for i, n in enumerate(names):
        seen[n] += 1
        if seen[n] > 1:
            names[i] = f"{n}_{seen[n]}"
    return [VolumeSource(n, v.path, v.kind, v.files, v.series_uid, v.description) for n, v in zip(names, volumes)]
