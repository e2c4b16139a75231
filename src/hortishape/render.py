"""Off-screen pictures of meshes: single views, grids and colour-mapped error maps.

Two functions write PNG files: :func:`render_mesh` (one mesh, one view) and
:func:`render_grid` (many meshes, one or more views each, all at the same
scale, with optional row titles and one shared colour bar). They serve the
README pictures of synthetic fruit, the shape-mode grids of the paper's
Fig. 7 (mean -3 SD / mean / +3 SD per mode, front and top view), the error
maps of Fig. 6 and grids of random samples.

View convention
---------------
The fruit's long (stalk) axis is +z. ``"front"`` looks along +y with z up
and x to the right; ``"top"`` looks down -z with x to the right and y up;
``"side"`` looks along -x with z up and y to the right; ``"iso"`` is
``(azimuth, elevation) = (-30, 20)``. A view may also be an ``(azimuth,
elevation)`` pair in degrees: azimuth turns the camera counter-clockwise
about +z starting from the front view, elevation lifts it towards +z. All
pictures use a parallel (orthographic) projection, so sizes in a picture are
proportional to millimetres.

Backends
--------
The 3D part is drawn with VTK through pyvista (``backend="vtk"``): smooth
shading with vertex normals computed by pyvista, three lights that move
with the camera (key light from the upper left, fill light, head light) and
super-sampling anti-aliasing. On a headless Linux machine VTK (9.4 or newer)
renders through EGL with Mesa's software rasteriser, which needs Debian's
``libegl1 libgl1-mesa-dri`` (or, instead, ``libosmesa6``). This module sets
``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` (unless it is already set)
when it first renders, never at import. Because a VTK that cannot open a
window may crash the whole Python process, the first rendering probes VTK
in a subprocess; when that probe fails, ``backend="auto"`` warns
(``RuntimeWarning``) and draws with matplotlib instead: an orthographic
projection of the faces, shaded with the same lights, painted back to
front, and decimated by vertex clustering when the mesh is large. Titles
and colour bars are always drawn with matplotlib, so both backends give the
same layout.
"""

from __future__ import annotations

import functools
import math
import os
import re
import signal
import subprocess
import sys
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import MeshError
from .mesh import Mesh, check_mesh

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.colors import Colormap

__all__ = ["VIEWS", "render_grid", "render_mesh"]

View = str | tuple[float, float]
MeshLike = Mesh | tuple[Any, Any]

#: Named views as (azimuth, elevation) in degrees (read-only); see the module docstring.
VIEWS: Mapping[str, tuple[float, float]] = MappingProxyType(
    {"front": (0.0, 0.0), "side": (90.0, 0.0), "top": (0.0, 90.0), "iso": (-30.0, 20.0)}
)

_BACKENDS = ("auto", "vtk", "matplotlib")
_BACKGROUND = (1.0, 1.0, 1.0)
_NAN_COLOR = "#b4b4b4"
_MARGIN = 1.1  # the largest object fills 1 / 1.1 of its picture
_DPI = 100.0
# Lights that move with the camera, as ((x right, y up, z towards the viewer),
# intensity): a key light from the upper left, a weak fill light from the
# right, and a head light.
_LIGHTS = (((-1.0, 1.2, 1.4), 0.75), ((1.2, -0.3, 0.6), 0.3), ((0.0, 0.0, 1.0), 0.45))
# Surface materials: a little gloss for fruit; more ambient light and almost
# no gloss for colour-mapped values, so that colours match the colour bar.
_PLAIN = {"ambient": 0.12, "diffuse": 0.85, "specular": 0.22, "specular_power": 18.0}
_MAPPED = {"ambient": 0.25, "diffuse": 0.75, "specular": 0.08, "specular_power": 18.0}
_MPL_MAX_FACES = 30_000  # the matplotlib backend decimates meshes above this
_PROBE_TIMEOUT = 120.0  # seconds
_PROBE_OK = "HORTISHAPE-VTK-OK"
_WINDOW_VARIABLE = "VTK_DEFAULT_OPENGL_WINDOW"
_APT_HINT = "on Debian or Ubuntu: apt-get install libegl1 libgl1-mesa-dri"

_PROBE_SCRIPT = f"""
import vtkmodules.vtkRenderingOpenGL2  # registers the OpenGL window classes
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkFiltersSources import vtkSphereSource
from vtkmodules.vtkRenderingCore import (
    vtkActor, vtkPolyDataMapper, vtkRenderWindow, vtkRenderer, vtkWindowToImageFilter)

source = vtkSphereSource()
mapper = vtkPolyDataMapper()
mapper.SetInputConnection(source.GetOutputPort())
actor = vtkActor()
actor.SetMapper(mapper)
renderer = vtkRenderer()
renderer.AddActor(actor)
renderer.SetBackground(1.0, 1.0, 1.0)
window = vtkRenderWindow()
window.SetOffScreenRendering(1)
window.SetSize(48, 48)
window.AddRenderer(renderer)
window.Render()
grab = vtkWindowToImageFilter()
grab.SetInput(window)
grab.Update()
pixels = vtk_to_numpy(grab.GetOutput().GetPointData().GetScalars())
print("{_PROBE_OK}", window.GetClassName()) if pixels.min() != pixels.max() else print("blank picture")
"""


# --------------------------------------------------------------------------- #
# public functions
# --------------------------------------------------------------------------- #


def render_mesh(
    mesh: MeshLike,
    path: str | os.PathLike,
    *,
    view: View = "front",
    scalars=None,
    cmap: str | Colormap = "viridis",
    clim: tuple[float, float] | None = None,
    scalar_bar_title: str | None = None,
    color: str | tuple[float, float, float] = "#c8553d",
    size: tuple[int, int] = (640, 480),
    title: str | None = None,
    backend: str = "auto",
) -> Path:
    """Render one mesh off-screen to a PNG file.

    Parameters
    ----------
    mesh : Mesh or (vertices, faces)
        The surface: a :class:`~hortishape.mesh.Mesh`, a ``(vertices (n, 3),
        faces (m, 3))`` pair, or any object with ``vertices`` and ``faces``
        attributes (a ``trimesh.Trimesh``). Lengths in millimetres.
    path : str or os.PathLike
        Where to write the picture; must end in ``.png``. Written atomically
        (a temporary file in the same folder, then renamed).
    view : str or (float, float), default: "front"
        ``"front"``, ``"top"``, ``"side"``, ``"iso"`` or ``(azimuth,
        elevation)`` in degrees; see the module docstring for the convention.
    scalars : (n,) or (m,) array_like of float, optional
        One value per vertex (or per face) shown with ``cmap`` and a colour
        bar, e.g. a registration error in mm. NaN values are drawn grey.
    cmap : str or matplotlib.colors.Colormap, default: "viridis"
        Colour map for ``scalars``.
    clim : (float, float), optional
        Colour range ``(low, high)``; default: the range of ``scalars``.
        Values outside are drawn in the end colours and the colour bar gets
        an arrow at that end.
    scalar_bar_title : str, optional
        Label of the colour bar, e.g. ``"error (mm)"``.
    color : str or (float, float, float), default: "#c8553d"
        Surface colour when there are no ``scalars`` (any matplotlib colour).
    size : (int, int), default: (640, 480)
        Width and height of the picture in pixels (title and colour bar
        included).
    title : str, optional
        Drawn centred above the mesh.
    backend : {"auto", "vtk", "matplotlib"}, default: "auto"
        ``"auto"`` uses VTK when a subprocess probe shows that off-screen
        rendering works, matplotlib otherwise (with a ``RuntimeWarning``).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    MeshError
        If the mesh arrays are unusable.
    ValueError
        If an option is unusable (unknown view, wrong number of scalars,
        ``clim`` not increasing, a size under 32 pixels, a path without
        ``.png``).
    RuntimeError
        If ``backend="vtk"`` and VTK cannot render off-screen here.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> sphere = trimesh.creation.icosphere(subdivisions=3, radius=30.0)
    >>> out = render_mesh((sphere.vertices, sphere.faces),
    ...                   tempfile.mkdtemp() + "/sphere.png", view="iso")
    >>> out.suffix
    '.png'
    """
    target = _check_path(path)
    the_mesh = _as_mesh(mesh, "mesh")
    width, height = _check_size(size, "size")
    angles = _view_angles(view)
    values = _check_scalars(scalars, the_mesh, "scalars")
    colormap = _colormap(cmap)
    rgb = _rgb(color, "color")
    norm_range, extend = _colour_range([values], clim)
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS}, got {backend!r}")

    font = float(np.clip(0.034 * height, 10.0, 20.0))
    title_h = round(2.0 * font) if title else 0
    bar_w = round(max(0.17 * width, 7.0 * font)) if values is not None else 0
    viewport = (width - bar_w, height - title_h)
    if min(viewport) < 32:
        raise ValueError(
            f"size {width}x{height} leaves no room for the mesh next to the title and colour bar"
        )

    backend = _choose_backend(backend)
    camera = _fit_cameras([the_mesh], [angles], viewport)[0][0]
    cell = _Cell(the_mesh, values, rgb, camera)
    (image,) = _render_cells([cell], viewport, colormap, norm_range, backend)

    layout = _Layout(width=width, height=height, font=font)
    layout.images.append((image, 0, title_h))
    if title:
        layout.texts.append((title, viewport[0] / 2.0, title_h / 2.0, 1.1, 0, "normal"))
    if values is not None:
        layout.colour_bar = (width - bar_w, 0, bar_w, height)
    _write_png(_compose(layout, colormap, norm_range, extend, scalar_bar_title), target)
    return target


def render_grid(
    meshes: Sequence[MeshLike],
    path: str | os.PathLike,
    *,
    titles: Sequence[str] | None = None,
    n_cols: int | None = None,
    views: Sequence[View] = ("front",),
    scalars=None,
    cmap: str | Colormap = "viridis",
    clim: tuple[float, float] | None = None,
    scalar_bar_title: str | None = None,
    color: str | tuple[float, float, float] | Sequence = "#c8553d",
    cell_size: tuple[int, int] = (320, 320),
    row_titles: Sequence[str] | None = None,
    backend: str = "auto",
) -> Path:
    """Render many meshes into one PNG grid, all at the same scale.

    The meshes fill the grid row by row, ``n_cols`` per row. With several
    ``views`` the grid gets one block of ``n_cols`` columns per view, side by
    side (for Fig. 7 of the paper: rows are modes, columns -3 SD / mean /
    +3 SD, ``views=("front", "top")``). Every cell uses the same millimetres
    per pixel (fitted to the largest mesh over all views), so sizes can be
    compared across the whole picture; each mesh is centred in its cell.

    Parameters
    ----------
    meshes : sequence of Mesh or (vertices, faces)
        The surfaces (see :func:`render_mesh`). Lengths in millimetres.
    path : str or os.PathLike
        Where to write the picture; must end in ``.png``. Written atomically.
    titles : sequence of str, optional
        One title per mesh, drawn above its cell in every view block. With
        more than one view, each block also gets the view's name as a header.
    n_cols : int, optional
        Meshes per row; default: ``min(len(meshes), 4)``.
    views : sequence of str or (float, float), default: ("front",)
        Views drawn for every mesh (see :func:`render_mesh`).
    scalars : sequence of ((n_i,) array_like or None), optional
        Values per vertex (or per face) of each mesh, or None for a mesh drawn
        in plain ``color``. One colour bar is shared by the whole grid.
    cmap : str or matplotlib.colors.Colormap, default: "viridis"
        Colour map for ``scalars``.
    clim : (float, float), optional
        Shared colour range; default: the range of all ``scalars``.
    scalar_bar_title : str, optional
        Label of the colour bar.
    color : colour or sequence of colours, default: "#c8553d"
        Surface colour, one for all meshes or one per mesh.
    cell_size : (int, int), default: (320, 320)
        Width and height of one cell in pixels, its title included.
    row_titles : sequence of str, optional
        One label per row, written vertically left of the row.
    backend : {"auto", "vtk", "matplotlib"}, default: "auto"
        See :func:`render_mesh`.

    Returns
    -------
    pathlib.Path
        ``path``. The picture is ``n_cols * len(views) * cell_w`` pixels wide
        plus ``round(0.15 * cell_h)`` when ``row_titles`` are given and
        ``round(0.45 * cell_h)`` for a colour bar, and ``n_rows * cell_h``
        pixels high plus a header of ``round(2.2 * font)`` pixels naming the
        views when there is more than one, where ``font = clip(0.05 * cell_h,
        10, 20)``.

    Raises
    ------
    MeshError
        If a mesh is unusable.
    ValueError
        If the number of titles, row titles, colours or scalars does not
        match, or an option is unusable (see :func:`render_mesh`).

    Examples
    --------
    >>> import tempfile, trimesh
    >>> small = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    >>> large = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> out = render_grid([(small.vertices, small.faces), (large.vertices, large.faces)],
    ...                   tempfile.mkdtemp() + "/grid.png", titles=["r = 20", "r = 30"],
    ...                   views=("front", "top"), cell_size=(200, 200))
    >>> out.name
    'grid.png'
    """
    target = _check_path(path)
    if isinstance(meshes, (Mesh, str)) or not isinstance(meshes, Sequence):
        raise TypeError("meshes must be a sequence of meshes (a list or tuple)")
    if len(meshes) == 0:
        raise ValueError("meshes is empty: nothing to render")
    the_meshes = [_as_mesh(m, f"meshes[{i}]") for i, m in enumerate(meshes)]
    n = len(the_meshes)
    cell_w, cell_h = _check_size(cell_size, "cell_size")
    if isinstance(views, str) or len(views) == 0:
        raise ValueError("views must be a non-empty sequence, e.g. ('front', 'top')")
    angles = [_view_angles(v) for v in views]
    if n_cols is None:
        n_cols = min(n, 4)
    if isinstance(n_cols, bool) or not isinstance(n_cols, (int, np.integer)) or n_cols < 1:
        raise ValueError(f"n_cols must be a positive integer, got {n_cols!r}")
    n_cols = int(min(n_cols, n))
    n_rows = math.ceil(n / n_cols)
    titles = _check_labels(titles, n, "titles", "meshes")
    row_titles = _check_labels(row_titles, n_rows, "row_titles", "rows")
    colormap = _colormap(cmap)
    colours = _grid_colours(color, n)
    if scalars is None:
        values = [None] * n
    else:
        if isinstance(scalars, np.ndarray) and scalars.ndim == 1:
            raise ValueError("scalars for a grid must be a sequence with one array (or None) per mesh")
        if len(scalars) != n:
            raise ValueError(f"got {len(scalars)} scalar arrays for {n} meshes")
        values = [_check_scalars(s, m, f"scalars[{i}]") for i, (s, m) in enumerate(zip(scalars, the_meshes))]
    have_scalars = any(v is not None for v in values)
    norm_range, extend = _colour_range(values, clim)
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS}, got {backend!r}")

    font = float(np.clip(0.05 * cell_h, 10.0, 20.0))
    title_h = round(2.0 * font) if titles is not None else 0
    header_h = round(2.2 * font) if len(views) > 1 else 0
    viewport = (cell_w, cell_h - title_h)
    if viewport[1] < 32:
        raise ValueError(f"cell_size {cell_w}x{cell_h} leaves no room for the mesh under its title")
    gutter = round(0.15 * cell_h) if row_titles is not None else 0
    bar_w = round(0.45 * cell_h) if have_scalars else 0
    block_w = n_cols * cell_w
    width = gutter + len(views) * block_w + bar_w
    height = header_h + n_rows * cell_h

    backend = _choose_backend(backend)
    cameras = _fit_cameras(the_meshes, angles, viewport)  # cameras[view][mesh]
    cells = [
        _Cell(the_meshes[i], values[i], colours[i], cameras[k][i])
        for k in range(len(views))
        for i in range(n)
    ]
    images = _render_cells(cells, viewport, colormap, norm_range, backend)

    layout = _Layout(width=width, height=height, font=font)
    for k, view in enumerate(views):
        x_block = gutter + k * block_w
        if header_h:
            layout.texts.append((_view_name(view), x_block + block_w / 2.0, header_h / 2.0, 1.15, 0, "bold"))
        if k > 0:
            layout.lines.append((x_block, 0, x_block, height))
        for i in range(n):
            row, col = divmod(i, n_cols)
            x0 = x_block + col * cell_w
            y0 = header_h + row * cell_h
            layout.images.append((images[k * n + i], x0, y0 + title_h))
            if titles is not None:
                layout.texts.append((titles[i], x0 + cell_w / 2.0, y0 + title_h / 2.0, 1.0, 0, "normal"))
    if row_titles is not None:
        for r, label in enumerate(row_titles):
            centre_y = header_h + r * cell_h + title_h + (cell_h - title_h) / 2.0
            layout.texts.append((label, gutter / 2.0, centre_y, 1.0, 90, "normal"))
    if have_scalars:
        layout.colour_bar = (width - bar_w, header_h, bar_w, height - header_h)
    _write_png(_compose(layout, colormap, norm_range, extend, scalar_bar_title), target)
    return target


# --------------------------------------------------------------------------- #
# input checks
# --------------------------------------------------------------------------- #


def _check_path(path) -> Path:
    target = Path(os.fspath(path))
    if target.suffix.lower() != ".png":
        raise ValueError(f"{target}: pictures are written as PNG, so the path must end in .png")
    return target


def _as_mesh(obj, name: str) -> Mesh:
    if isinstance(obj, Mesh):
        return obj
    if hasattr(obj, "vertices") and hasattr(obj, "faces"):  # trimesh.Trimesh and the like
        return Mesh(*check_mesh(obj.vertices, obj.faces, name=name))
    if isinstance(obj, (tuple, list)) and len(obj) == 2:
        return Mesh(*check_mesh(obj[0], obj[1], name=name))
    raise MeshError(f"{name} must be a Mesh or a (vertices, faces) pair, got {type(obj).__name__}")


def _check_size(size, name: str) -> tuple[int, int]:
    try:
        w, h = (int(s) for s in size)
        ok = all(float(s) == int(s) for s in size)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be (width, height) in pixels, got {size!r}") from None
    if not ok or w < 32 or h < 32:
        raise ValueError(f"{name} must be two whole numbers of pixels, each at least 32, got {size!r}")
    if w * h > 64_000_000:
        raise ValueError(f"{name} {w}x{h} is too large (more than 64 megapixels)")
    return w, h


def _view_angles(view) -> tuple[float, float]:
    if isinstance(view, str):
        if view not in VIEWS:
            raise ValueError(f"unknown view {view!r}; use one of {sorted(VIEWS)} or (azimuth, elevation)")
        return VIEWS[view]
    try:
        azimuth, elevation = (float(a) for a in view)
    except (TypeError, ValueError):
        raise ValueError(f"a view is a name or (azimuth, elevation) in degrees, got {view!r}") from None
    if not (math.isfinite(azimuth) and -90.0 <= elevation <= 90.0):
        raise ValueError(f"view {view!r}: azimuth must be finite and elevation within [-90, 90] degrees")
    return azimuth, elevation


def _view_name(view) -> str:
    if isinstance(view, str):
        return view
    azimuth, elevation = _view_angles(view)
    return f"az {azimuth:g}\N{DEGREE SIGN}, el {elevation:g}\N{DEGREE SIGN}"


def _check_scalars(scalars, mesh: Mesh, name: str):
    if scalars is None:
        return None
    try:
        values = np.array(scalars, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of numbers") from None
    if values.ndim != 1 or values.shape[0] not in (mesh.n_vertices, mesh.n_faces):
        raise ValueError(
            f"{name} must have one value per vertex ({mesh.n_vertices}) or per face "
            f"({mesh.n_faces}), got shape {values.shape}"
        )
    return values


def _colormap(cmap) -> Colormap:
    try:
        import matplotlib
    except ImportError:
        raise ImportError(
            "hortishape.render needs matplotlib for titles, colour bars and colour maps: "
            "pip install matplotlib"
        ) from None
    from matplotlib.colors import Colormap

    if isinstance(cmap, Colormap):
        return cmap
    try:
        return matplotlib.colormaps[cmap]
    except (KeyError, TypeError):
        raise ValueError(f"unknown colour map {cmap!r} (use a matplotlib colour map name)") from None


def _rgb(color, name: str) -> tuple[float, float, float]:
    from matplotlib.colors import to_rgb

    try:
        return tuple(float(c) for c in to_rgb(color))
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {color!r} is not a colour") from None


def _grid_colours(color, n: int) -> list[tuple[float, float, float]]:
    from matplotlib.colors import is_color_like

    if is_color_like(color):
        return [_rgb(color, "color")] * n
    if not isinstance(color, Sequence) or len(color) != n:
        raise ValueError(f"color must be one colour or one colour per mesh ({n})")
    return [_rgb(c, f"color[{i}]") for i, c in enumerate(color)]


def _check_labels(labels, n: int, name: str, what: str):
    if labels is None:
        return None
    if isinstance(labels, str) or len(labels) != n:
        raise ValueError(f"{name} must be a sequence of {n} strings, one per {what[:-1]}")
    return [str(s) for s in labels]


def _colour_range(values, clim) -> tuple[tuple[float, float], str]:
    """Colour range and the colour bar's ``extend`` (which ends have values beyond it)."""
    finite = [v[np.isfinite(v)] for v in values if v is not None]
    finite = [v for v in finite if v.size]
    lo_data = min(float(v.min()) for v in finite) if finite else None
    hi_data = max(float(v.max()) for v in finite) if finite else None
    if clim is not None:
        try:
            lo, hi = (float(c) for c in clim)
        except (TypeError, ValueError):
            raise ValueError(f"clim must be (low, high), got {clim!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"clim must be two finite numbers with low < high, got {clim!r}")
    elif lo_data is None:
        lo, hi = 0.0, 1.0
    else:
        lo, hi = lo_data, hi_data
        if hi <= lo:
            pad = 0.05 * abs(lo) if lo != 0 else 0.5
            lo, hi = lo - pad, hi + pad
    below = lo_data is not None and lo_data < lo
    above = hi_data is not None and hi_data > hi
    extend = {(False, False): "neither", (True, False): "min", (False, True): "max"}.get(
        (below, above), "both"
    )
    return (lo, hi), extend


def _choose_backend(backend: str) -> str:
    """``"vtk"`` or ``"matplotlib"``; probes VTK (once per process) unless told matplotlib."""
    if backend == "matplotlib":
        return backend
    ok, reason = _vtk_offscreen_status()
    if ok:
        return "vtk"
    if backend == "vtk":
        raise RuntimeError(f"VTK cannot render off-screen here: {reason} ({_APT_HINT})")
    warnings.warn(
        f"VTK cannot render off-screen here ({reason}); drawing with matplotlib instead, "
        f"which is slower and shades flat faces ({_APT_HINT})",
        RuntimeWarning,
        stacklevel=3,
    )
    return "matplotlib"


# --------------------------------------------------------------------------- #
# VTK availability
# --------------------------------------------------------------------------- #


def _prepare_vtk_environment() -> None:
    """Ask VTK for an EGL (headless) window unless the user chose one already.

    VTK reads ``VTK_DEFAULT_OPENGL_WINDOW`` when it creates a render window,
    so this must run before the first one; it is called when rendering
    starts, never at import.
    """
    if sys.platform.startswith("linux"):
        os.environ.setdefault(_WINDOW_VARIABLE, "vtkEGLRenderWindow")


@functools.cache
def _vtk_offscreen_status() -> tuple[bool, str]:
    """Whether VTK renders off-screen here, probed once per process in a subprocess.

    A VTK without a usable OpenGL (no EGL, no OSMesa, no X server) can crash
    the interpreter with a segmentation fault, so the first window is opened
    in a throw-away Python process. When VTK had to fall back from the EGL
    window this module asked for to another one (OSMesa, when only
    ``libosmesa6`` is installed), the variable is set to the class that
    worked, so that later windows open without warnings.

    Returns
    -------
    ok : bool
    reason : str
        Why not, when ``ok`` is False.
    """
    import importlib.util

    for module in ("vtkmodules", "pyvista"):
        if importlib.util.find_spec(module) is None:
            name = "vtk" if module == "vtkmodules" else module
            return False, f"{name} is not installed (pip install 'hortishape[vtk]')"
    chosen_by_user = _WINDOW_VARIABLE in os.environ
    _prepare_vtk_environment()
    ok, detail = _run_probe(_PROBE_SCRIPT)
    if not ok:
        return False, detail
    if not chosen_by_user and detail.startswith("vtk") and sys.platform.startswith("linux"):
        os.environ[_WINDOW_VARIABLE] = detail
    return True, ""


def _run_probe(script: str) -> tuple[bool, str]:
    """Run ``script`` in a fresh Python.

    Returns ``(True, what the script printed after the OK mark)`` when it
    exits cleanly and prints the mark, else ``(False, why)``.
    """
    try:
        done = subprocess.run(
            [sys.executable, "-c", script],
            check=False,
            capture_output=True,
            text=True,
            timeout=_PROBE_TIMEOUT,
            env=dict(os.environ),
        )
    except subprocess.TimeoutExpired:
        return False, f"a test render did not finish within {_PROBE_TIMEOUT:g} s"
    except OSError as exc:
        return False, f"could not start a test render ({exc})"
    marked = [ln for ln in done.stdout.splitlines() if ln.startswith(_PROBE_OK)]
    if done.returncode == 0 and marked:
        return True, marked[-1][len(_PROBE_OK) :].strip()
    if done.returncode < 0:
        try:
            what = f"a test render was killed by {signal.Signals(-done.returncode).name}"
        except ValueError:
            what = f"a test render was killed by signal {-done.returncode}"
    elif done.returncode == 0:
        what = f"a test render gave {done.stdout.strip()[-200:]!r}"
    else:
        what = f"a test render failed with exit status {done.returncode}"
    message = _first_message(done.stderr)
    if message:
        what += f"; first message: {message}"
    return False, what


def _first_message(stderr: str) -> str:
    """The first line of ``stderr`` without colour codes and VTK's log prefix."""
    for line in stderr.splitlines():
        line = re.sub(r"\x1b\[[0-9;]*m", "", line).strip()
        line = re.sub(r"^\d{4}-\d\d-\d\d .*?\|\s*", "", line)  # "date (time) [thread] file:line WARN| "
        if line:
            return line[:240]
    return ""


# --------------------------------------------------------------------------- #
# cameras
# --------------------------------------------------------------------------- #


@dataclass(frozen=True)
class _Camera:
    """An orthographic camera: unit vectors and a half-height in mm."""

    focal: np.ndarray  # (3,) the point in the middle of the picture
    toward: np.ndarray  # (3,) unit vector from the focal point to the camera
    up: np.ndarray  # (3,) unit vector pointing up in the picture
    right: np.ndarray  # (3,) unit vector pointing right in the picture
    half_height: float  # mm from the middle to the top edge of the picture
    half_depth: float  # mm from the focal point to the nearest and farthest vertex along ``toward``


def _camera_axes(azimuth: float, elevation: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``toward``, ``up`` and ``right`` unit vectors of a view (see the module docstring)."""
    a, e = math.radians(azimuth), math.radians(elevation)
    toward = np.array([math.cos(e) * math.sin(a), -math.cos(e) * math.cos(a), math.sin(e)])
    # d(toward)/d(elevation): z-up at the horizon, and still defined at the poles
    up = np.array([-math.sin(e) * math.sin(a), math.sin(e) * math.cos(a), math.cos(e)])
    right = np.cross(up, toward)
    return toward, up, right


def _fit_cameras(meshes, angles, viewport) -> list[list[_Camera]]:
    """One camera per view and mesh, all with the same scale (mm per pixel).

    Each mesh is centred in its picture; the scale fits the largest projected
    extent over all meshes and views, plus a small margin. Returns
    ``cameras[view][mesh]``.
    """
    aspect = viewport[0] / viewport[1]
    half = 0.0
    placed = []
    for azimuth, elevation in angles:
        toward, up, right = _camera_axes(azimuth, elevation)
        per_mesh = []
        for mesh in meshes:
            v = mesh.vertices
            x, y, d = v @ right, v @ up, v @ toward
            half = max(half, (y.max() - y.min()) / 2.0, (x.max() - x.min()) / (2.0 * aspect))
            focal = (
                (x.max() + x.min()) / 2.0 * right
                + (y.max() + y.min()) / 2.0 * up
                + (d.max() + d.min()) / 2.0 * toward
            )
            per_mesh.append((focal, toward, up, right, (d.max() - d.min()) / 2.0))
        placed.append(per_mesh)
    if half <= 0.0:
        half = 1.0  # every mesh is a single point in every view
    half *= _MARGIN
    return [[_Camera(f, t, u, r, half, h) for f, t, u, r, h in per_mesh] for per_mesh in placed]


# --------------------------------------------------------------------------- #
# drawing the 3D part of a cell
# --------------------------------------------------------------------------- #


@dataclass(frozen=True)
class _Cell:
    mesh: Mesh
    scalars: np.ndarray | None
    color: tuple[float, float, float]
    camera: _Camera


def _render_cells(cells, viewport, colormap, norm_range, backend) -> list[np.ndarray]:
    """``(h, w, 3) uint8`` pictures of the cells' meshes on a white background."""
    if backend == "vtk":
        return _render_vtk(cells, viewport, colormap, norm_range)
    return [_render_matplotlib(cell, viewport, colormap, norm_range) for cell in cells]


def _render_vtk(cells, viewport, colormap, norm_range) -> list[np.ndarray]:
    _prepare_vtk_environment()
    import pyvista as pv

    width, height = viewport
    plotter = pv.Plotter(
        off_screen=True,
        window_size=[width, height],
        lighting="none",
        theme=pv.themes.DocumentTheme(),
    )
    # cells showing the same mesh (in several views) are drawn one after the
    # other, so that each mesh is uploaded and its normals computed only once
    first_seen: dict = {}
    keys = [first_seen.setdefault((id(c.mesh), id(c.scalars), c.color), j) for j, c in enumerate(cells)]
    order = sorted(range(len(cells)), key=lambda j: (keys[j], j))
    images: list = [None] * len(cells)
    shown = None
    try:
        plotter.set_background(_BACKGROUND)
        plotter.enable_anti_aliasing("ssaa")
        for (lx, ly, lz), intensity in _LIGHTS:
            if (lx, ly) == (0.0, 0.0):
                light = pv.Light(light_type="headlight", intensity=intensity)
            else:
                light = pv.Light(
                    position=(lx, ly, lz),
                    focal_point=(0, 0, 0),
                    light_type="camera light",
                    intensity=intensity,
                )
            plotter.add_light(light)
        for j in order:
            cell = cells[j]
            if keys[j] != shown:
                _add_surface(plotter, cell, colormap, norm_range)
                shown = keys[j]
            cam = cell.camera
            distance = 2.0 * (cam.half_depth + cam.half_height) + 1.0  # well outside the mesh
            plotter.camera_position = [
                tuple(cam.focal + distance * cam.toward),
                tuple(cam.focal),
                tuple(cam.up),
            ]
            plotter.camera.parallel_projection = True
            plotter.camera.parallel_scale = cam.half_height
            plotter.renderer.reset_camera_clipping_range()
            plotter.render()  # screenshot() alone may return the previous camera's picture
            image = np.array(plotter.screenshot(return_img=True))[..., :3]
            if image.shape != (height, width, 3):  # pragma: no cover - a VTK quirk
                raise RuntimeError(f"VTK returned a {image.shape} picture for a {width}x{height} window")
            images[j] = image
    finally:
        plotter.close()
    return images


def _add_surface(plotter, cell: _Cell, colormap, norm_range) -> None:
    """Show ``cell.mesh`` in ``plotter``, replacing the mesh shown before."""
    import pyvista as pv

    surface = pv.PolyData.from_regular_faces(
        np.array(cell.mesh.vertices), np.array(cell.mesh.faces)
    )
    style = {
        "smooth_shading": True,
        "split_sharp_edges": False,
        "show_scalar_bar": False,
        "name": "mesh",
        "reset_camera": False,
        "render": False,
    }
    if cell.scalars is None:
        plotter.add_mesh(surface, color=cell.color, **_PLAIN, **style)
    else:
        on_points = cell.scalars.shape[0] == cell.mesh.n_vertices
        data = surface.point_data if on_points else surface.cell_data
        data["values"] = cell.scalars
        plotter.add_mesh(
            surface,
            scalars="values",
            preference="point" if on_points else "cell",
            cmap=colormap,
            clim=list(norm_range),
            nan_color=_NAN_COLOR,
            interpolate_before_map=True,
            **_MAPPED,
            **style,
        )


def _cluster(vertices, faces, values, on_points, max_faces):
    """Decimate by vertex clustering until at most about ``max_faces`` faces remain.

    Returns new ``vertices``, ``faces`` and ``values`` (averaged per cluster for
    vertex values, kept per surviving face for face values). Drawing only:
    vertex order is not preserved.
    """
    if faces.shape[0] <= max_faces:
        return vertices, faces, values
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    # a closed surface has about twice as many faces as vertices
    voxel = math.sqrt(max(area, 1e-12) / (0.5 * max_faces))
    for _ in range(8):
        keys = np.floor((vertices - vertices.min(axis=0)) / voxel).astype(np.int64)
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        new_faces = inverse[faces]
        keep = (
            (new_faces[:, 0] != new_faces[:, 1])
            & (new_faces[:, 1] != new_faces[:, 2])
            & (new_faces[:, 0] != new_faces[:, 2])
        )
        if keep.sum() <= 1.3 * max_faces:
            break
        voxel *= 1.3
    count = np.bincount(inverse).astype(np.float64)
    new_vertices = np.stack(
        [np.bincount(inverse, weights=vertices[:, k]) / count for k in range(3)], axis=1
    )
    new_values = values
    if values is not None:
        if on_points:
            finite = np.isfinite(values)
            total = np.bincount(inverse, weights=np.where(finite, values, 0.0))
            n_finite = np.bincount(inverse, weights=finite.astype(np.float64))
            new_values = np.divide(total, n_finite, out=np.full(total.shape, np.nan), where=n_finite > 0)
        else:
            new_values = values[keep]
    return new_vertices, new_faces[keep], new_values


def _render_matplotlib(cell: _Cell, viewport, colormap, norm_range) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import Normalize, to_rgb
    from matplotlib.figure import Figure

    width, height = viewport
    cam = cell.camera
    values = cell.scalars
    on_points = values is not None and values.shape[0] == cell.mesh.n_vertices
    vertices, faces, values = _cluster(
        cell.mesh.vertices, cell.mesh.faces, values, on_points, _MPL_MAX_FACES
    )
    from .surface import vertex_normals

    normals = vertex_normals(vertices, faces)

    # the lights and materials of the VTK backend, evaluated per vertex
    # (two-sided: normals turned towards the camera) and averaged per face
    facing = np.sign(normals @ cam.toward)
    facing[facing == 0] = 1.0
    n = normals * facing[:, None]
    material = _PLAIN if values is None else _MAPPED
    brightness = np.full(vertices.shape[0], material["ambient"])
    highlight = np.zeros(vertices.shape[0])
    for (lx, ly, lz), intensity in _LIGHTS:
        light = lx * cam.right + ly * cam.up + lz * cam.toward
        light /= np.linalg.norm(light)
        half_vector = light + cam.toward
        half_vector /= np.linalg.norm(half_vector)
        brightness += material["diffuse"] * intensity * np.clip(n @ light, 0.0, None)
        gloss = np.clip(n @ half_vector, 0.0, None) ** material["specular_power"]
        highlight += material["specular"] * intensity * gloss

    norm = Normalize(*norm_range)
    nan_rgb = np.array(to_rgb(_NAN_COLOR))
    if values is None:
        base = np.broadcast_to(np.array(cell.color), (faces.shape[0], 3))
    elif on_points:
        vertex_rgb = colormap(norm(np.clip(values, *norm_range)))[:, :3]
        vertex_rgb[~np.isfinite(values)] = nan_rgb
        base = vertex_rgb[faces].mean(axis=1)
    else:
        base = colormap(norm(np.clip(values, *norm_range)))[:, :3]
        base[~np.isfinite(values)] = nan_rgb
    shade = brightness[faces].mean(axis=1)
    shine = highlight[faces].mean(axis=1)
    rgb = np.clip(base * shade[:, None] + shine[:, None], 0.0, 1.0)

    relative = vertices - cam.focal
    x, y, depth = relative @ cam.right, relative @ cam.up, relative @ cam.toward
    order = np.argsort(depth[faces].mean(axis=1))  # far faces first (painter's algorithm)
    polygons = np.stack([x[faces], y[faces]], axis=-1)[order]
    colours = rgb[order]

    fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor=_BACKGROUND)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    half_h = cam.half_height
    half_w = half_h * width / height
    ax.set_xlim(-half_w, half_w)
    ax.set_ylim(-half_h, half_h)
    ax.add_collection(
        PolyCollection(polygons, facecolors=colours, edgecolors=colours, linewidths=0.4, antialiased=True)
    )
    canvas.draw()
    image = np.asarray(canvas.buffer_rgba())[..., :3].copy()
    return _fit_image(image, width, height)


def _fit_image(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Crop or pad (white) to exactly ``(height, width, 3)``: Agg rounds figure sizes."""
    out = np.full((height, width, 3), 255, dtype=np.uint8)
    h, w = min(height, image.shape[0]), min(width, image.shape[1])
    out[:h, :w] = image[:h, :w, :3]
    return out


# --------------------------------------------------------------------------- #
# layout: images, titles and colour bar on one matplotlib figure
# --------------------------------------------------------------------------- #


@dataclass
class _Layout:
    """What goes on the final picture, in pixels from the top left corner."""

    width: int
    height: int
    font: float  # pixels
    images: list = field(default_factory=list)  # (image, x0, y0)
    texts: list = field(default_factory=list)  # (text, x_centre, y_centre, size_factor, rotation, weight)
    lines: list = field(default_factory=list)  # (x0, y0, x1, y1)
    colour_bar: tuple | None = None  # (x0, y0, width, height) of its strip


def _compose(layout: _Layout, colormap, norm_range, extend, bar_title) -> np.ndarray:
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    W, H = layout.width, layout.height
    points = layout.font * 72.0 / _DPI
    with matplotlib.rc_context({"text.usetex": False, "font.family": "sans-serif"}):
        fig = Figure(figsize=(W / _DPI, H / _DPI), dpi=_DPI, facecolor=_BACKGROUND)
        canvas = FigureCanvasAgg(fig)
        for image, x0, y0 in layout.images:
            fig.figimage(image, xo=x0, yo=H - y0 - image.shape[0], origin="upper", zorder=1)
        for text, xc, yc, factor, rotation, weight in layout.texts:
            fig.text(
                xc / W,
                1.0 - yc / H,
                text,
                ha="center",
                va="center",
                rotation=rotation,
                fontsize=points * factor,
                fontweight=weight,
                color="#222222",
                zorder=3,
            )
        for x0, y0, x1, y1 in layout.lines:
            fig.add_artist(
                Line2D(
                    [x0 / W, x1 / W], [1.0 - y0 / H, 1.0 - y1 / H], color="#cccccc", linewidth=1.0, zorder=2
                )
            )
        if layout.colour_bar is not None:
            bx, by, bw, bh = layout.colour_bar
            bar_len = min(0.72 * bh, max(0.5 * bh, 360.0))
            bar_thick = max(10.0, 0.9 * layout.font)
            left = bx + 0.14 * bw
            bottom = by + (bh - bar_len) / 2.0
            cax = fig.add_axes((left / W, 1.0 - (bottom + bar_len) / H, bar_thick / W, bar_len / H))
            mappable = ScalarMappable(norm=Normalize(*norm_range), cmap=colormap)
            bar = fig.colorbar(mappable, cax=cax, extend=extend, extendfrac=0.06)
            bar.outline.set_linewidth(0.6)
            bar.ax.tick_params(labelsize=0.85 * points, width=0.6, length=3)
            if bar_title:
                bar.set_label(bar_title, fontsize=0.9 * points, labelpad=0.4 * layout.font)
        canvas.draw()
        image = np.asarray(canvas.buffer_rgba())[..., :3].copy()
    return _fit_image(image, W, H)


def _write_png(image: np.ndarray, target: Path) -> None:
    """Write ``image`` to ``target`` atomically (temporary file, then ``os.replace``)."""
    from PIL import Image

    from ._files import atomic_path

    with atomic_path(target, MeshError) as tmp, open(tmp, "wb") as stream:
        Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8)).save(stream, format="PNG")
