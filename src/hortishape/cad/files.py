"""CAD files: JSON (no extra dependency), STEP and IGES through OpenCascade (step 5)."""

from __future__ import annotations

import contextlib
import json
import os
import sys
from pathlib import Path

import numpy as np

from ..errors import HortishapeError
from .bspline import DEGREE, BSplineSurface, _knots_v


_CAD_SUFFIXES = {".step": "step", ".stp": "step", ".iges": "iges", ".igs": "iges", ".json": "json"}
_INSTALL_HINT = "pip install 'hortishape[cad]' (the cadquery-ocp-novtk package)"


def cad_formats() -> tuple[str, ...]:
    """File extensions :func:`write_cad` and :func:`read_cad` understand.

    Examples
    --------
    >>> cad_formats()
    ('.step', '.stp', '.iges', '.igs', '.json')
    """
    return tuple(_CAD_SUFFIXES)


def _cad_kind(path: Path) -> str:
    kind = _CAD_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise HortishapeError(
            f"{path}: unknown CAD file extension {path.suffix!r} (use one of {', '.join(_CAD_SUFFIXES)})"
        )
    return kind


def _occ() -> None:
    """Check that OpenCascade's Python bindings can be imported, or explain how to install them."""
    import importlib

    try:
        for name in ("BRep", "BRepBuilderAPI", "BRepGProp", "BRepLib", "Geom", "GProp", "IGESControl",
                     "STEPControl", "TopAbs", "TopExp", "TopoDS"):
            importlib.import_module(f"OCP.{name}")
    except ImportError as exc:
        raise HortishapeError(
            f"STEP and IGES need OpenCascade's Python bindings (OCP), which are not installed: {_INSTALL_HINT} "
            f"({exc})"
        ) from None


@contextlib.contextmanager
def _quiet_stdout():
    """Silence what OpenCascade's C++ code prints on file descriptor 1 (the writers' statistics)."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError, AttributeError):  # pragma: no cover - no real stdout
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(null)


def _occ_surface(surface: BSplineSurface):
    from OCP.collections import Array1_double, Array1_int, Array2_gp_Pnt
    from OCP.Geom import Geom_BSplineSurface
    from OCP.gp import gp_Pnt

    ku, kv = surface.grid
    poles = Array2_gp_Pnt(1, ku, 1, kv)
    cp = surface.control_points
    for i in range(ku):
        for j in range(kv):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*map(float, cp[i, j])))

    def array(values, kind):
        a = kind(1, len(values))
        for i, x in enumerate(values):
            a.SetValue(i + 1, x)
        return a

    return Geom_BSplineSurface(
        poles,
        array([float(x) for x in surface.knots_u], Array1_double),
        array([float(x) for x in surface.knots_v], Array1_double),
        array([int(x) for x in surface.multiplicities_u], Array1_int),
        array([int(x) for x in surface.multiplicities_v], Array1_int),
        DEGREE,
        DEGREE,
        True,
        False,
    )


def _occ_shape(surface: BSplineSurface):
    """A solid bounded by the closed face, or the face alone when the surface is not closed."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeSolid
    from OCP.BRepLib import BRepLib
    from OCP.TopoDS import TopoDS_Shell

    face = BRepBuilderAPI_MakeFace(_occ_surface(surface), 1e-7).Face()
    if not surface.is_closed:
        return face
    builder = BRep_Builder()
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    builder.Add(shell, face)
    shell.Closed(True)
    solid = BRepBuilderAPI_MakeSolid(shell).Solid()
    BRepLib.OrientClosedSolid_s(solid)
    return solid


def write_cad(path: str | os.PathLike, surface: BSplineSurface) -> Path:
    """Write a B-spline surface as STEP, IGES or JSON (by extension), atomically.

    STEP (``.step``, ``.stp``; AP214, millimetres) holds a solid bounded by
    the one closed face (a manifold solid B-rep); IGES (``.iges``, ``.igs``;
    millimetres) holds the face (rational B-spline surface entity 128).
    Both go through OpenCascade (``pip install 'hortishape[cad]'``). JSON
    holds :meth:`BSplineSurface.to_dict`. A surface that is not closed at its
    poles is written as a face in STEP too.

    Parameters
    ----------
    path : str or os.PathLike
    surface : BSplineSurface

    Returns
    -------
    pathlib.Path

    Raises
    ------
    HortishapeError
        Unknown extension, OpenCascade missing, or the writer failed.

    Examples
    --------
    >>> import tempfile
    >>> cp = np.zeros((4, 4, 3))
    >>> cp[..., 2] = [-30.0, -20.0, 20.0, 30.0]
    >>> cp[:, 1:3, :2] = 30.0 * np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])[:, None]
    >>> path = write_cad(tempfile.mkdtemp() + "/egg.json", BSplineSurface(cp))
    >>> bool(np.array_equal(read_cad(path).control_points, cp))
    True
    """
    from .._files import atomic_path

    target = Path(path)
    if not isinstance(surface, BSplineSurface):
        raise TypeError(f"surface must be a BSplineSurface, got {type(surface).__name__}")
    kind = _cad_kind(target)
    if kind == "json":
        with atomic_path(target, HortishapeError) as tmp:
            tmp.write_text(json.dumps(surface.to_dict(), indent=1), encoding="utf-8")
        return target
    _occ()
    shape = _occ_shape(surface)
    with atomic_path(target, HortishapeError) as tmp:
        with _quiet_stdout():
            if kind == "step":
                from OCP.Interface import Interface_Static
                from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

                writer = STEPControl_Writer()
                Interface_Static.SetCVal_s("write.step.unit", "MM")
                writer.Transfer(shape, STEPControl_AsIs)
                status = writer.Write(str(tmp))
            else:
                from OCP.IGESControl import IGESControl_Controller, IGESControl_Writer

                IGESControl_Controller.Init_s()
                writer = IGESControl_Writer("MM", 0)
                writer.AddShape(shape)
                writer.ComputeModel()
                status = writer.Write(str(tmp))
        ok = status if isinstance(status, bool) else int(status) == 1  # IFSelect_RetDone
        if not ok:
            raise HortishapeError(f"{target}: OpenCascade could not write the {kind.upper()} file ({status})")
    return target


def _read_occ_shape(path: Path, kind: str):
    _occ()
    with _quiet_stdout():
        if kind == "step":
            from OCP.STEPControl import STEPControl_Reader

            reader = STEPControl_Reader()
        else:
            from OCP.IGESControl import IGESControl_Reader

            reader = IGESControl_Reader()
        status = reader.ReadFile(str(path))
        if int(status) != 1:
            raise HortishapeError(f"{path}: OpenCascade cannot read this {kind.upper()} file ({status})")
        reader.TransferRoots()
        shape = reader.OneShape()
    if shape.IsNull():
        raise HortishapeError(f"{path}: the {kind.upper()} file holds no shape")
    return shape


def _faces(shape) -> list:
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    out = []
    explorer = TopExp_Explorer(shape, TopAbs_FACE)
    while explorer.More():
        out.append(TopoDS.Face(explorer.Current()))
        explorer.Next()
    return out


def _surface_from_occ(face, path: Path) -> BSplineSurface:
    from OCP.BRep import BRep_Tool
    from OCP.Geom import Geom_BSplineSurface

    geom = BRep_Tool.Surface_s(face)
    if not isinstance(geom, Geom_BSplineSurface):
        geom = Geom_BSplineSurface.DownCast(geom) if hasattr(Geom_BSplineSurface, "DownCast") else None
    if geom is None:
        raise HortishapeError(f"{path}: the face is not a B-spline surface")
    if geom.UDegree() != DEGREE or geom.VDegree() != DEGREE or geom.IsVPeriodic():
        raise HortishapeError(f"{path}: not a bicubic surface periodic in u only")
    ku, kv = geom.NbUPoles(), geom.NbVPoles()
    cp = np.array([[[geom.Pole(i, j).X(), geom.Pole(i, j).Y(), geom.Pole(i, j).Z()]
                    for j in range(1, kv + 1)] for i in range(1, ku + 1)])
    uk = np.array([geom.UKnot(i) for i in range(1, geom.NbUKnots() + 1)])
    vk = np.array([geom.VKnot(i) for i in range(1, geom.NbVKnots() + 1)])
    if not geom.IsUPeriodic():
        # a periodic surface written unperiodized: the last DEGREE columns repeat the first
        if ku > DEGREE and np.allclose(cp[-DEGREE:], cp[:DEGREE]):
            cp = cp[:-DEGREE]
            ku -= DEGREE
            uk = (uk - uk[DEGREE]) if len(uk) > ku + 1 else uk
        else:
            raise HortishapeError(f"{path}: the surface is not periodic in u")
    uk = uk[(uk >= -1e-12)]
    for name, knots, expected in (("u", uk, np.arange(ku + 1) / ku), ("v", vk, _knots_v(kv))):
        span = knots[-1] - knots[0] if len(knots) > 1 else 1.0
        if len(knots) < len(expected) or not np.allclose((knots[: len(expected)] - knots[0]) / span, expected,
                                                          atol=1e-9):
            raise HortishapeError(f"{path}: knots in {name} are not uniform")
    return BSplineSurface(cp)


def read_cad(path: str | os.PathLike) -> BSplineSurface:
    """Read a B-spline surface from STEP, IGES (through OpenCascade) or hortishape's JSON.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    BSplineSurface
        The first face's surface (files written by :func:`write_cad` hold one).

    Raises
    ------
    HortishapeError
        Missing or unreadable file, no B-spline face, a surface hortishape does
        not write (not bicubic, not periodic in ``u``, non-uniform knots), or
        OpenCascade missing.

    Examples
    --------
    >>> import tempfile
    >>> cp = np.zeros((4, 4, 3))
    >>> cp[..., 2] = [-30.0, -20.0, 20.0, 30.0]
    >>> cp[:, 1:3, :2] = 30.0 * np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])[:, None]
    >>> surface = read_cad(write_cad(tempfile.mkdtemp() + "/egg.step", BSplineSurface(cp)))
    >>> surface.control_points.shape, bool(np.allclose(surface.control_points, cp))
    ((4, 4, 3), True)
    """
    from .._files import check_exists, check_not_empty

    target = Path(path)
    kind = _cad_kind(target)
    check_exists(target, HortishapeError)
    check_not_empty(target, HortishapeError)
    if kind == "json":
        try:
            data = json.loads(target.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise HortishapeError(f"{target}: not a JSON file ({exc})") from None
        return BSplineSurface.from_dict(data, name=str(target))
    faces = _faces(_read_occ_shape(target, kind))
    if not faces:
        raise HortishapeError(f"{target}: the file holds no face")
    return _surface_from_occ(faces[0], target)


def cad_volume(path: str | os.PathLike) -> float:
    """Volume enclosed by the surface of a STEP or IGES file, as OpenCascade computes it (mm^3).

    The file's faces are made into a closed shell and a solid (as a CAD
    program would on import), oriented outward, and its volume integrated
    exactly on the B-spline geometry.

    Raises
    ------
    HortishapeError
        If the file cannot be read or its faces do not close a volume.

    Examples
    --------
    >>> import tempfile
    >>> from hortishape.cad import BSplineFitter
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
    >>> path = write_cad(tempfile.mkdtemp() + "/ball.step", BSplineFitter(grid=16).fit(s.vertices, s.faces).surface(s.vertices))
    >>> ml = cad_volume(path) / 1000.0
    >>> bool(abs(ml - 4.0 / 3.0 * np.pi * 40.0**3 / 1000.0) < 0.01 * ml)   # a 40 mm ball, within 1 %
    True
    """
    target = Path(path)
    kind = _cad_kind(target)
    if kind == "json":
        raise HortishapeError(f"{target}: cad_volume reads STEP or IGES; for JSON use read_cad(path).volume()")
    from .._files import check_exists

    check_exists(target, HortishapeError)
    _occ()
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid
    from OCP.BRepGProp import BRepGProp
    from OCP.BRepLib import BRepLib
    from OCP.GProp import GProp_GProps
    from OCP.TopoDS import TopoDS_Shell

    shape = _read_occ_shape(target, kind)
    builder = BRep_Builder()
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    for face in _faces(shape):
        builder.Add(shell, face)
    shell.Closed(True)
    solid = BRepBuilderAPI_MakeSolid(shell).Solid()
    BRepLib.OrientClosedSolid_s(solid)
    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(solid, props)
    volume = float(props.Mass())
    if not volume > 0:
        raise HortishapeError(f"{target}: the faces do not enclose a volume")
    return volume
