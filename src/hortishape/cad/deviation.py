"""How far a B-spline surface lies from the triangle surface it approximates, and its picture."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..mesh import check_mesh
from .bspline import BSplineSurface


@dataclass(frozen=True, eq=False)
class Deviation:
    """How far a B-spline approximation is from a triangle surface (paper Fig. 9).

    Attributes
    ----------
    distances : (n,) float64 ndarray
        Distance from each vertex of the triangle surface to the B-spline surface, mm.
    mean, max : float
        Mean and largest of ``distances``, mm.
    back_mean, back_max : float
        Mean and largest distance from points of the B-spline surface (a fine
        tessellation) back to the triangle surface, mm: what the approximation
        adds that the surface does not have.
    """

    distances: np.ndarray
    mean: float
    max: float
    back_mean: float
    back_max: float


def surface_deviation(surface: BSplineSurface, vertices: npt.ArrayLike, faces: npt.ArrayLike) -> Deviation:
    """Distances between a B-spline surface and a triangle surface, both ways.

    The B-spline is tessellated finely (:meth:`BSplineSurface.tessellate`'s
    default, 16 intervals per knot span, at least 128) and distances are
    exact point-to-triangle distances (libigl).

    Parameters
    ----------
    surface : BSplineSurface
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int

    Returns
    -------
    Deviation

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.cad import BSplineFitter
    >>> s = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
    >>> fitter = BSplineFitter(grid=16).fit(s.vertices, s.faces)
    >>> d = surface_deviation(fitter.surface(s.vertices), s.vertices, s.faces)
    >>> d.max < 0.1
    True
    """
    import igl

    v, f = check_mesh(vertices, faces, name="surface")
    ku, kv = surface.grid
    tess = surface.tessellate(max(256, 16 * ku), max(256, 16 * (kv - 3)))
    d2, _, _ = igl.point_mesh_squared_distance(v, tess.vertices, tess.faces)
    back2, _, _ = igl.point_mesh_squared_distance(tess.vertices, v, f)
    d, back = np.sqrt(np.maximum(d2, 0.0)), np.sqrt(np.maximum(back2, 0.0))
    return Deviation(d, float(d.mean()), float(d.max()), float(back.mean()), float(back.max()))


def render_deviation(
    surface: BSplineSurface,
    vertices: npt.ArrayLike,
    faces: npt.ArrayLike,
    path: str | os.PathLike,
    *,
    views=("front", "top"),
    clim: tuple[float, float] | None = None,
    title: str | None = None,
    cell_size: tuple[int, int] = (420, 400),
    backend: str = "auto",
) -> Path:
    """Picture of a B-spline approximation coloured by its distance to the triangle surface (Fig. 9).

    The B-spline surface is tessellated (8 intervals per knot span, at least
    96) and each of its points is coloured by its distance to the triangle
    surface, in mm, with a colour bar; one panel per view, all at the same
    scale (:func:`hortishape.render.render_grid`).

    Parameters
    ----------
    surface : BSplineSurface
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int
        The triangle surface the B-spline approximates, mm.
    path : str or os.PathLike
        Output ``.png``, written atomically.
    views : sequence of str or (float, float), default: ("front", "top")
    clim : (float, float), optional
        Colour range in mm; default: 0 to the largest distance.
    title : str, optional
        Drawn above every panel.
    cell_size : (int, int), default: (420, 400)
    backend : {"auto", "vtk", "matplotlib"}, default: "auto"

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.cad import BSplineFitter
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    >>> surface = BSplineFitter(grid=8).fit(s.vertices, s.faces).surface(s.vertices)
    >>> render_deviation(surface, s.vertices, s.faces, tempfile.mkdtemp() + "/ball.png").suffix
    '.png'
    """
    import igl

    from ..render import render_grid

    v, f = check_mesh(vertices, faces, name="surface")
    ku, kv = surface.grid
    tess = surface.tessellate(max(96, 8 * ku), max(96, 8 * (kv - 3)))
    d2, _, _ = igl.point_mesh_squared_distance(tess.vertices, v, f)
    d = np.sqrt(np.maximum(d2, 0.0))
    if clim is None:
        clim = (0.0, max(float(d.max()), 1e-6))
    return render_grid(
        [tess], path, titles=None if title is None else [title], views=views, scalars=[d], clim=clim,
        cmap="viridis", scalar_bar_title="distance to the triangle surface (mm)", cell_size=cell_size,
        backend=backend,
    )
