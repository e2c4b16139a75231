"""Units: hortishape works in millimetres, and checks that a product's size is one a fruit can have.

A scan exported in metres is a thousand times too small, and nothing else in
the pipeline notices: the registration fits it to a few thousandths of a
millimetre, and a model built from such scans varies by hundredths of one.
So every command that reads a product's surface (``register``, ``build``,
``fit``, ``extract``) measures its largest extent and refuses one outside
:data:`PLAUSIBLE_EXTENT_MM`, naming the file and the likely unit. A known
factor is applied with ``scale`` (the command line's ``--scale``), in memory:
input files are never changed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import MeshError
from .mesh import Mesh

__all__ = ["PLAUSIBLE_EXTENT_MM", "PRODUCT_EXTENT_MM", "PRODUCT_VOLUME_ML", "Scan", "SizeCheck", "check_size", "likely_unit", "read_scan", "scaled"]

#: The largest extent (bounding box, mm) a fruit or vegetable can have: from
#: a few millimetres (a currant, a caper) to about a metre (a large pumpkin).
PLAUSIBLE_EXTENT_MM = (3.0, 1500.0)

#: The sizes a product in a CT or MRI volume can have, as its largest extent
#: (mm) and its enclosed volume (mL): narrower than :data:`PLAUSIBLE_EXTENT_MM`,
#: because a volume's voxel size is easily wrong by a factor (a TIFF read at
#: 1 mm voxels, micrometres taken for millimetres) and the product's size then
#: is the only sign of it.
PRODUCT_EXTENT_MM = (10.0, 600.0)
PRODUCT_VOLUME_ML = (1.0, 10_000.0)

#: Units a scan is likely to be in when its extent is out of range, with the
#: factor that converts them to millimetres.
_LIKELY_UNITS = (("metres", 1000.0), ("centimetres", 10.0), ("micrometres", 0.001))


@dataclass(frozen=True)
class SizeCheck:
    """The size check of one product's surface.

    Attributes
    ----------
    extent_mm : float
        Largest extent of its bounding box after ``scale``, mm.
    scale : float
        The factor its coordinates were multiplied by to give mm.
    """

    extent_mm: float
    scale: float = 1.0

    def as_log(self) -> dict:
        """What a log's ``units`` records: the unit, the scale applied and the size checked."""
        return {"unit": "mm", "scale": self.scale, "extent_mm": self.extent_mm,
                "plausible_extent_mm": list(PLAUSIBLE_EXTENT_MM)}


def likely_unit(extent: float) -> tuple[str, float] | None:
    """The unit a product of this extent is most likely in, and its factor to mm.

    ``None`` when no usual unit makes it a fruit's size.

    Examples
    --------
    >>> likely_unit(0.08)
    ('metres', 1000.0)
    >>> likely_unit(80000.0)
    ('micrometres', 0.001)
    """
    lo, hi = PLAUSIBLE_EXTENT_MM
    centre = np.sqrt(lo * hi)
    fits = [(abs(np.log(extent * f / centre)), name, f) for name, f in _LIKELY_UNITS
            if extent > 0 and lo <= extent * f <= hi]
    return min(fits)[1:] if fits else None


def _likely_cause(size: float, scale: float, option: str) -> str:
    """Why a product measures ``size`` "mm" after ``scale``, and the scale that would fix it."""
    unit = likely_unit(size)
    if unit is None:
        return "not a fruit's size in any usual unit"
    return f"in {unit[0]}? use {option} {scale * unit[1]:g}"


def check_size(vertices, *, name: str = "surface", scale: float = 1.0, option: str = "--scale") -> SizeCheck:
    """Check that a product's size, in mm after ``scale``, is one a fruit can have.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        The product's surface points, in the file's units.
    name : str, default: "surface"
        What to call it in the error (the file's path).
    scale : float, default: 1.0
        The factor that converts the file's units to mm.
    option : str, default: "--scale"
        The option the error suggests to fix the unit with.

    Returns
    -------
    SizeCheck

    Raises
    ------
    MeshError
        If the largest extent times ``scale`` lies outside
        :data:`PLAUSIBLE_EXTENT_MM`, with the likely unit.

    Examples
    --------
    >>> box = np.array([[0, 0, 0], [0.08, 0.07, 0.09]])
    >>> check_size(box * 1000).extent_mm
    90.0
    >>> check_size(box, name="apple.ply")
    Traceback (most recent call last):
    ...
    hortishape.errors.MeshError: apple.ply: 0.09 across: in metres? use --scale 1000 (hortishape works in millimetres; a fruit is 3-1500 mm across)
    >>> check_size(box, scale=1000).scale
    1000.0
    """
    if not (np.isfinite(scale) and scale > 0):
        raise MeshError(f"the scale must be a positive number, got {scale}")
    v = np.asarray(vertices, dtype=np.float64)
    extent = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
    size = extent * scale
    lo, hi = PLAUSIBLE_EXTENT_MM
    if not lo <= size <= hi:
        raise MeshError(
            f"{name}: {size:.3g} across: {_likely_cause(size, scale, option)} "
            f"(hortishape works in millimetres; a fruit is {lo:g}-{hi:g} mm across)"
        )
    return SizeCheck(size, float(scale))


def scaled(mesh: Mesh, scale: float) -> Mesh:
    """``mesh`` with its vertices multiplied by ``scale`` (a new mesh; the same one for 1).

    Examples
    --------
    >>> from hortishape.mesh import Mesh
    >>> in_metres = Mesh([[0, 0, 0], [0.08, 0, 0], [0, 0.08, 0], [0, 0, 0.08]], [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> float(scaled(in_metres, 1000.0).vertices.max())
    80.0
    """
    return mesh if scale == 1.0 else mesh.with_vertices(mesh.vertices * scale)


@dataclass(frozen=True, eq=False)
class Scan:
    """A product's surface read from a file, in mm, with its size check."""

    mesh: Mesh
    units: SizeCheck


def read_scan(path, *, scale: float = 1.0) -> Scan:
    """Read a product's surface, convert it to mm with ``scale`` and check its size.

    Parameters
    ----------
    path : path
        Any mesh file :func:`hortishape.io.read_mesh` reads.
    scale : float, default: 1.0
        The factor that converts the file's units to mm (1000 for metres).

    Returns
    -------
    Scan
        The mesh in mm (vertex order unchanged) and its :class:`SizeCheck`.

    Raises
    ------
    MeshError
        If the file cannot be read, or the size is not a fruit's (naming the likely unit).

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.io import write_mesh
    >>> path = Path(tempfile.mkdtemp()) / "ball_in_metres.ply"
    >>> ball = trimesh.creation.icosphere(2, radius=0.04)
    >>> _ = write_mesh(path, ball.vertices, ball.faces)
    >>> scan = read_scan(path, scale=1000)
    >>> round(scan.units.extent_mm)
    80
    """
    from .io import read_mesh

    mesh = read_mesh(path)
    units = check_size(mesh.vertices, name=str(path), scale=scale)
    return Scan(scaled(mesh, scale), units)


def plausible_voxel_factors(extent_mm: float, volume_mm3: float) -> tuple[float, float]:
    """The range of factors on a voxel size that make a product of a fruit's size.

    A product ``extent_mm`` across holding ``volume_mm3``, measured with a
    voxel size ``s``, is a fruit's size (:data:`PRODUCT_EXTENT_MM`,
    :data:`PRODUCT_VOLUME_ML`) with a voxel size ``f * s`` for ``f`` in the
    returned range; it is empty (low > high) when no factor does (a shape no
    fruit has, such as a thin sheet).

    Examples
    --------
    >>> lo, hi = plausible_voxel_factors(200.0, 2_806_000.0)  # a ball read at 1 mm voxels, not 0.4
    >>> bool(lo <= 0.4 <= hi), round(lo, 3), round(hi, 3)
    (True, 0.071, 1.527)
    """
    (lo, hi), (vlo, vhi) = PRODUCT_EXTENT_MM, PRODUCT_VOLUME_ML
    if not (extent_mm > 0 and volume_mm3 > 0):
        return float("inf"), 0.0
    return (max(lo / extent_mm, (vlo * 1000.0 / volume_mm3) ** (1 / 3)),
            min(hi / extent_mm, (vhi * 1000.0 / volume_mm3) ** (1 / 3)))
