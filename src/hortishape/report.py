"""Pictures, plots and the HTML report that show a shape model and its quality.

:func:`render_modes` draws the paper's Fig. 7: one row per mode, the mean
moved -3 SD, the mean and the mean moved +3 SD, in a front and a top view,
all at the same scale. :func:`write_mode_meshes` writes the same surfaces as
mesh files for a viewer or a CAD tool. :func:`render_samples` pictures random
shapes of a model (Fig. 8).

The quality measures of :mod:`hortishape.evaluate` are drawn by
:func:`plot_compactness` (Fig. 10), :func:`plot_generalization` (Fig. 11),
:func:`plot_specificity` (Fig. 12), :func:`plot_landmark_errors` (Table 3)
and :func:`render_error_map` (Fig. 6); :func:`write_report` puts them all on
one self-contained HTML page (pictures embedded as data URIs, no network).
:func:`write_evaluation` writes everything of an evaluation: those pictures,
the error map as meshes, ``metrics.json`` and ``metrics.csv``
(:func:`metrics_dict`, :func:`metrics_csv`) and the page.
Plots are drawn with matplotlib's Agg canvas (no display, no pyplot state).

Mode numbers in pictures and file names count from 1, as in the paper
("mode 1" is the largest); :meth:`ShapeModel.mode_shapes` indexes from 0.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from ._files import atomic_text
from ._rng import RandomState
from .errors import HortishapeError
from .layout import ModelDir
from .metrics import Compactness, Evaluation, Generalization, LandmarkTransfer, Specificity

if TYPE_CHECKING:  # pragma: no cover
    from .mesh import Mesh
    from .model import ShapeModel

__all__ = [
    "error_colours",
    "metrics_csv",
    "metrics_dict",
    "plot_compactness",
    "plot_generalization",
    "plot_landmark_errors",
    "plot_specificity",
    "render_error_map",
    "render_modes",
    "render_partial_fit",
    "render_uncertain",
    "render_samples",
    "write_evaluation",
    "write_mode_meshes",
    "write_report",
]


def _check_modes(model: "ShapeModel", n_modes, sd) -> tuple[int, float]:
    model._check_fitted()
    if isinstance(n_modes, bool) or not isinstance(n_modes, (int, np.integer)) or n_modes < 1:
        raise ValueError(f"n_modes must be a positive integer, got {n_modes!r}")
    if n_modes > model.n_components_:
        raise ValueError(f"n_modes={n_modes}, but the model has only {model.n_components_} modes")
    if isinstance(sd, bool) or not isinstance(sd, (int, float, np.integer, np.floating)) or not (
        np.isfinite(sd) and sd > 0
    ):
        raise ValueError(f"sd must be a positive number of standard deviations, got {sd!r}")
    return int(n_modes), float(sd)


def _sd_label(sd: float) -> str:
    return f"{sd:g}"


def render_modes(
    model: "ShapeModel",
    path: str | os.PathLike,
    *,
    n_modes: int = 3,
    sd: float = 3.0,
    views=("front", "top"),
    cell_size: tuple[int, int] = (240, 240),
    color="#c8553d",
    backend: str = "auto",
) -> Path:
    """Picture of the first modes of a model: rows = modes, columns = -sd / mean / +sd (Fig. 7).

    Each row shows :meth:`ShapeModel.mode_shapes` of one mode around the mean,
    labelled with the mode's share of the variance, in every view of
    ``views`` (one block of three columns per view). All cells use the same
    millimetres per pixel (:func:`hortishape.render.render_grid`). The view
    convention has the stalk along +z: the model should be in that pose.

    Parameters
    ----------
    model : ShapeModel
        A fitted model with faces.
    path : str or os.PathLike
        Output ``.png``, written atomically.
    n_modes : int, default: 3
        Rows: modes 1 to ``n_modes``.
    sd : float, default: 3.0
        Standard deviations for the outer columns.
    views : sequence of str or (float, float), default: ("front", "top")
    cell_size : (int, int), default: (240, 240)
        Pixels per cell.
    color : colour, default: "#c8553d"
    backend : {"auto", "vtk", "matplotlib"}, default: "auto"

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    NotFittedError
        If the model is not fitted.
    MeshError
        If the model has no faces.
    ValueError
        If ``n_modes`` exceeds the model's modes or an option is unusable.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> rng = np.random.default_rng(0)
    >>> shapes = [s.vertices * rng.normal(1.0, 0.1, size=3) for _ in range(6)]
    >>> model = ShapeModel().fit(shapes, s.faces)
    >>> render_modes(model, tempfile.mkdtemp() + "/modes.png", n_modes=2, backend="matplotlib").name
    'modes.png'
    """
    from .render import render_grid

    n_modes, sd = _check_modes(model, n_modes, sd)
    label = _sd_label(sd)
    meshes, titles, rows = [], [], []
    mean = model.to_mesh(model.mean_)
    for k in range(n_modes):
        minus, plus = model.mode_shapes(k, sd=sd)
        meshes += [model.to_mesh(minus), mean, model.to_mesh(plus)]
        titles += [f"\u2212{label} SD", "mean", f"+{label} SD"]
        rows.append(f"mode {k + 1} ({100 * model.explained_variance_ratio_[k]:.1f}%)")
    return render_grid(
        meshes, path, titles=titles, n_cols=3, views=tuple(views), row_titles=rows,
        color=color, cell_size=cell_size, backend=backend,
    )


def write_mode_meshes(
    model: "ShapeModel",
    out_dir: str | os.PathLike,
    *,
    n_modes: int = 3,
    sd: float = 3.0,
    extension: str = ".ply",
) -> list[Path]:
    """Write the mean and the +/- ``sd`` shapes of the first modes as meshes.

    Files: ``mean.ply``, then for each mode ``k = 1 .. n_modes``
    ``mode<k>_minus<sd>sd.ply`` and ``mode<k>_plus<sd>sd.ply`` (e.g.
    ``mode1_minus3sd.ply``), in millimetres, vertex order of the model.

    Parameters
    ----------
    model : ShapeModel
        A fitted model with faces.
    out_dir : str or os.PathLike
        Folder (created if missing).
    n_modes : int, default: 3
    sd : float, default: 3.0
    extension : str, default: ".ply"
        Mesh format (see :func:`hortishape.io.mesh_formats`).

    Returns
    -------
    list of pathlib.Path
        The files written, mean first.

    Raises
    ------
    NotFittedError, MeshError, ValueError
        As :func:`render_modes`; ``MeshError`` also when a file cannot be written.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=1, radius=30.0)
    >>> rng = np.random.default_rng(0)
    >>> model = ShapeModel().fit([s.vertices * rng.normal(1.0, 0.1, size=3) for _ in range(5)], s.faces)
    >>> [p.name for p in write_mode_meshes(model, tempfile.mkdtemp(), n_modes=1)]
    ['mean.ply', 'mode1_minus3sd.ply', 'mode1_plus3sd.ply']
    """
    from .io import write_mesh

    n_modes, sd = _check_modes(model, n_modes, sd)
    ext = extension if extension.startswith(".") else "." + extension
    folder = Path(out_dir)
    folder.mkdir(parents=True, exist_ok=True)
    label = _sd_label(sd)
    written = [write_mesh(folder / f"mean{ext}", model.to_mesh(model.mean_))]
    for k in range(n_modes):
        minus, plus = model.mode_shapes(k, sd=sd)
        written.append(write_mesh(folder / f"mode{k + 1}_minus{label}sd{ext}", model.to_mesh(minus)))
        written.append(write_mesh(folder / f"mode{k + 1}_plus{label}sd{ext}", model.to_mesh(plus)))
    return written


def render_samples(
    model: "ShapeModel",
    path: str | os.PathLike,
    *,
    n: int = 5,
    modes: int = 5,
    truncate: float = 3.0,
    random_state=None,
    backend: str = "auto",
) -> Path:
    """Picture of ``n`` random shapes of a model, front and top view, same scale (Fig. 8).

    The shapes are :meth:`ShapeModel.sample` of the first ``modes`` modes
    (Gaussian truncated at ``+/- truncate`` SD, as the paper's section 3.2).

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> rng = np.random.default_rng(0)
    >>> model = ShapeModel().fit([s.vertices * rng.normal(1.0, 0.1, size=3) for _ in range(6)], s.faces)
    >>> render_samples(model, tempfile.mkdtemp() + "/s.png", n=2, random_state=0, backend="matplotlib").name
    's.png'
    """
    shapes = model.sample(n, modes=min(modes, model.n_components_), truncate=truncate, random_state=random_state)
    meshes = [model.to_mesh(s) for s in shapes]
    return _front_and_top(meshes, [f"sample {i + 1}" for i in range(n)], path, backend)


def _front_and_top(meshes, names, path, backend: str) -> Path:
    """One row of front views above one row of top views, all at one scale."""
    from .render import render_grid

    return render_grid([*meshes, *(_turned(m, "top") for m in meshes)], path,
                       titles=[f"{t}, {v}" for v in ("front", "top") for t in names],
                       n_cols=len(meshes), views=("front",), cell_size=(220, 240), backend=backend)


def render_uncertain(
    mean: Mesh,
    shapes: Sequence[np.ndarray],
    titles: Sequence[str],
    path: str | os.PathLike,
    *,
    backend: str = "auto",
) -> Path:
    """Picture of instances beside the mean, front and top view, in the model's frame.

    The instances are the Procrustes-aligned corresponded surfaces
    (``aligned/<stem>.ply``): one whose orientation went wrong shows its
    stalk or lobes where the mean has none, since its correspondence is
    turned with it.

    Parameters
    ----------
    mean : Mesh
        The model's mean shape.
    shapes : sequence of (n, 3) array_like of float
        The instances' aligned vertices (the mean's vertex order).
    titles : sequence of str
        One per instance.
    path : str or os.PathLike
        Output ``.png``.

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.mesh import Mesh
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> mean = Mesh(s.vertices, s.faces)
    >>> render_uncertain(mean, [s.vertices * [1.2, 1, 1]], ["a (0.010)"], tempfile.mkdtemp() + "/u.png",
    ...                  backend="matplotlib").name
    'u.png'
    """
    meshes = [mean, *(mean.with_vertices(v) for v in shapes)]
    return _front_and_top(meshes, ["mean", *titles], path, backend)


def render_partial_fit(vertices, faces, sd, path: str | os.PathLike, *, points=None, max_points: int = 2000,
                       backend: str = "auto") -> Path:
    """Picture of a completed surface coloured by its posterior SD, with the fitted points over it.

    Three views (front, side, top) of the surface in the points' coordinates;
    the points (at most ``max_points`` of them, evenly chosen) are drawn as
    small grey markers, so what was seen and what the model filled in can be
    told apart at a glance.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int
    sd : (n,) array_like of float
        Per-vertex standard deviation, mm.
    path : str or os.PathLike
        Output ``.png``.
    points : (k, 3) array_like of float, optional
        The observed points.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile, trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> top = s.vertices[s.vertices[:, 2] > 0]
    >>> render_partial_fit(s.vertices, s.faces, 1.0 - s.vertices[:, 2] / 30.0, tempfile.mkdtemp() + "/p.png",
    ...                    points=top, backend="matplotlib").name
    'p.png'
    """
    from .mesh import Mesh
    from .render import render_grid

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    values = np.asarray(sd, dtype=np.float64)
    if points is not None and len(points):
        p = np.asarray(points, dtype=np.float64)
        p = p[np.linspace(0, len(p) - 1, min(len(p), max_points)).astype(np.int64)]
        size = 0.006 * float(np.ptp(v, axis=0).max())
        tetra = size * np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])
        marks = (p[:, None, :] + tetra[None]).reshape(-1, 3)
        tf = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
        mf = (tf[None] + 4 * np.arange(len(p))[:, None, None]).reshape(-1, 3) + len(v)
        v, f = np.concatenate([v, marks]), np.concatenate([f, mf])
        values = np.concatenate([values, np.full(len(marks), np.nan)])  # NaN is drawn grey
    mesh = Mesh(v, f)
    return render_grid([mesh], path, views=("front", "side", "top"), scalars=[values], cmap="viridis",
                       scalar_bar_title="posterior SD (mm); grey: the points seen", backend=backend)


# Turns that make the "front" view of the turned copy show another view
# (front: looking along +y with x to the right and z up).
_TURNS = {
    "front": np.eye(3),
    "side": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),   # looking along -x
    "top": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),    # looking down -z
    "bottom": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),  # looking up +z
}


def _turned(mesh, view: str):
    """A copy of ``mesh`` whose front view is ``view`` of the original."""
    from .mesh import Mesh

    return Mesh(mesh.vertices @ _TURNS[view].T, mesh.faces)


# --------------------------------------------------------------------------
# plots of the quality measures (Figs. 10-12, Table 3)
# --------------------------------------------------------------------------

_BLUE = "#2a6f97"
_RED = "#c8553d"
_GREY = "#8d99ae"


def _figure(width_in: float, height_in: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=110, facecolor="white", layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path) -> Path:
    from ._files import atomic_path

    target = Path(path)
    if target.suffix.lower() != ".png":
        raise ValueError(f"{target}: pictures are written as .png")
    with atomic_path(target, HortishapeError) as tmp, open(tmp, "wb") as stream:
        fig.savefig(stream, format="png", facecolor="white")
    return target


def _mode_axis(ax, modes) -> None:
    from matplotlib.ticker import MaxNLocator

    ax.set_xlabel("number of modes m")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, nbins=12))
    ax.set_xlim(0.3, float(max(modes)) + 0.7)
    ax.grid(True, color="#e5e5e5", linewidth=0.8)
    ax.set_axisbelow(True)


def plot_compactness(c: "Compactness", path: str | os.PathLike) -> Path:
    """Plot the compactness (Fig. 10): cumulative variance in percent against m.

    Bars: each mode's share of the total variance; line: the cumulative share
    C(m) / total (eq. 14). Dashed lines mark 90% and 99%.

    Parameters
    ----------
    c : Compactness
    path : str or os.PathLike
        Output ``.png``, written atomically.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile
    >>> from hortishape.metrics import compactness
    >>> plot_compactness(compactness([50.0, 30.0, 15.0, 5.0]), tempfile.mkdtemp() + "/c.png").name
    'c.png'
    """
    fig = _figure(6.4, 4.2)
    ax = fig.add_subplot()
    m = np.asarray(c.modes)
    ax.bar(m, 100 * c.variance_mm2 / c.total_mm2, color=_GREY, alpha=0.55, width=0.7, label="variance of mode m")
    ax.plot(m, 100 * c.ratio, "-o", color=_BLUE, markersize=4, linewidth=1.8, label="cumulative, C(m)")
    for level in (90, 99):
        ax.axhline(level, color="#999999", linestyle="--", linewidth=0.8)
        hit = np.nonzero(100 * c.ratio >= level - 1e-9)[0]
        if hit.size:
            ax.annotate(f"{level}% at m = {int(m[hit[0]])}", (m[hit[0]], level), xytext=(6, -14),
                        textcoords="offset points", fontsize=9, color="#444444")
    ax.set_ylim(0, 104)
    ax.set_ylabel("variance described (% of total)")
    _mode_axis(ax, m)
    ax.set_title("Compactness (eq. 14, Fig. 10)")
    ax.legend(loc="center right", fontsize=9, frameon=False)
    return _save(fig, path)


def _plot_measure(modes, mean_mm, se_mm, mean_sq, se_sq, path, *, title: str, sq_label: str) -> Path:
    fig = _figure(10.0, 4.0)
    left, right = fig.subplots(1, 2)
    m = np.asarray(modes)
    left.errorbar(m, mean_mm, yerr=se_mm, fmt="-o", color=_BLUE, ecolor="#555555", elinewidth=1.0, capsize=3,
                  markersize=4, linewidth=1.8)
    left.set_ylabel("mean distance per vertex (mm)")
    left.set_title("per vertex, mm")
    right.errorbar(m, mean_sq, yerr=se_sq, fmt="-o", color=_RED, ecolor="#555555", elinewidth=1.0, capsize=3,
                   markersize=4, linewidth=1.8)
    right.set_ylabel(sq_label)
    right.set_title("as the paper defines it, mm\u00b2")
    if np.nanmax(mean_sq) >= 100:
        from matplotlib.ticker import StrMethodFormatter

        right.yaxis.set_major_formatter(StrMethodFormatter("{x:,.0f}"))
    for ax, values, err in ((left, mean_mm, se_mm), (right, mean_sq, se_sq)):
        _mode_axis(ax, m)
        top = np.nanmax(np.asarray(values) + np.nan_to_num(np.asarray(err)))
        ax.set_ylim(0, top * 1.08 if np.isfinite(top) and top > 0 else 1.0)
    fig.suptitle(title + "\nerror bars: standard error of the mean", fontsize=11)
    return _save(fig, path)


def plot_generalization(g: "Generalization", path: str | os.PathLike) -> Path:
    """Plot the leave-one-out generalization (Fig. 11), mm per vertex and eq. 15, with standard errors.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile
    >>> from hortishape.metrics import generalization
    >>> rng = np.random.default_rng(0)
    >>> g = generalization(rng.normal(size=(30, 3)) + 0.1 * rng.normal(size=(6, 30, 3)))
    >>> plot_generalization(g, tempfile.mkdtemp() + "/g.png").name
    'g.png'
    """
    n = g.per_shape_mm.shape[0]
    return _plot_measure(g.modes, g.mean_mm, g.se_mm, g.mean_sq, g.se_sq, path,
                         title=f"Generalization G(m): leave-one-out over {n} shapes (eq. 15, Fig. 11)",
                         sq_label="|x - x'(m)|\u00b2 over all coordinates (mm\u00b2)")


def plot_specificity(s: "Specificity", path: str | os.PathLike) -> Path:
    """Plot the specificity (Fig. 12), mm per vertex and eq. 16, with standard errors.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile
    >>> from hortishape.metrics import specificity
    >>> from hortishape.model import ShapeModel
    >>> rng = np.random.default_rng(0)
    >>> x = rng.normal(size=(30, 3)) + 0.1 * rng.normal(size=(6, 30, 3))
    >>> s = specificity(ShapeModel().fit(x), x, n_samples=20, random_state=0)
    >>> plot_specificity(s, tempfile.mkdtemp() + "/s.png").name
    's.png'
    """
    return _plot_measure(s.modes, s.mean_mm, s.se_mm, s.mean_sq, s.se_sq, path,
                         title=f"Specificity S(m): {s.n_samples} random shapes per m, each against its nearest "
                               "training shape (eq. 16, Fig. 12)",
                         sq_label="|y - y'(m)|\u00b2 over all coordinates (mm\u00b2)")


def plot_landmark_errors(t: "LandmarkTransfer", names, path: str | os.PathLike) -> Path:
    """Plot the landmark transfer errors (Table 3): every instance as a dot, mean +/- SD as a bar.

    Parameters
    ----------
    t : LandmarkTransfer
    names : sequence of str
        The instances (rows of ``t.errors_mm``); the worst is labelled.
    path : str or os.PathLike

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.metrics import transfer_landmarks
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.9, 1.1, (4, 1, 3))
    >>> tips = shapes[:, np.argmax(s.vertices[:, 2])][:, None]            # the top of each, marked by hand
    >>> t = transfer_landmarks(shapes, s.faces, tips, names=["top"])
    >>> plot_landmark_errors(t, [f"s{i}" for i in range(4)], tempfile.mkdtemp() + "/landmarks.png").suffix
    '.png'
    """
    errs = np.asarray(t.errors_mm, dtype=float)
    columns = [errs[:, j] for j in range(errs.shape[1])]
    labels = list(t.names)
    if errs.shape[1] > 1:
        columns.append(t.average_mm)
        labels.append("average")
    fig = _figure(max(4.8, 1.6 * len(labels) + 2.0), 4.2)
    ax = fig.add_subplot()
    rng = np.random.default_rng(0)
    for j, col in enumerate(columns):
        ok = np.isfinite(col)
        vals = col[ok]
        if not vals.size:
            continue
        x = j + rng.uniform(-0.18, 0.18, size=vals.size)
        ax.scatter(x, vals, s=16, color=_BLUE if labels[j] != "average" else _GREY, alpha=0.75, zorder=2)
        mean, sd = float(vals.mean()), float(vals.std(ddof=1)) if vals.size > 1 else 0.0
        ax.errorbar([j + 0.32], [mean], yerr=[sd], fmt="D", color=_RED, capsize=4, markersize=6, zorder=3)
        ax.annotate(f"{mean:.2f} \u00b1 {sd:.2f}", (j + 0.4, mean), fontsize=9, va="center", color="#333333")
        worst = int(np.nonzero(ok)[0][np.argmax(vals)])
        ax.annotate(str(names[worst]), (x[np.argmax(vals)], col[worst]), xytext=(4, 4), textcoords="offset points",
                    fontsize=7, color="#666666")
    ax.set_xticks(range(len(labels)), labels)
    ax.set_xlim(-0.6, len(labels) - 0.1 + 0.6)
    ax.set_ylim(bottom=0)
    ax.set_ylabel("transfer error: distance to the given landmark (mm)")
    ax.set_title("Landmark transfer error (Table 3): dots = instances, \u25c6 = mean \u00b1 SD", fontsize=10)
    ax.grid(True, axis="y", color="#e5e5e5")
    ax.set_axisbelow(True)
    return _save(fig, path)


# --------------------------------------------------------------------------
# the geometric error map (Fig. 6)
# --------------------------------------------------------------------------

_ERROR_CMAP = "viridis"


def _error_range(values) -> tuple[float, float]:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    hi = float(np.percentile(v, 99.5)) if v.size else 1.0
    return 0.0, max(hi, 1e-3)


def error_colours(values) -> np.ndarray:
    """RGB colours (uint8) of per-vertex errors, as in :func:`render_error_map`.

    The colour map is viridis from 0 to the 99.5th percentile of ``values``
    or 0.001 mm, whichever is larger (larger values get its end colour).

    Parameters
    ----------
    values : (n,) array_like of float
        Errors, mm.

    Returns
    -------
    (n, 3) uint8 ndarray

    Examples
    --------
    >>> error_colours([0.0, 1.0]).shape
    (2, 3)
    """
    import matplotlib

    lo, hi = _error_range(values)
    v = np.clip((np.asarray(values, dtype=float) - lo) / (hi - lo), 0.0, 1.0)
    rgba = matplotlib.colormaps[_ERROR_CMAP](np.nan_to_num(v))
    return np.round(255 * rgba[:, :3]).astype(np.uint8)


def render_error_map(mesh, values, path: str | os.PathLike, *, n_instances: int | None = None,
                     backend: str = "auto") -> Path:
    """Picture of a per-vertex error on a surface: front, side, top and bottom, with a colour bar (Fig. 6).

    The fruit's stalk axis is +z (see :mod:`hortishape.render`); the four
    views are drawn at the same scale. Colours: viridis from 0 to the 99.5th
    percentile of ``values`` or 0.001 mm, whichever is larger (an arrow on the
    colour bar when some values are larger).

    Parameters
    ----------
    mesh : Mesh
        The surface (e.g. the model's mean), mm.
    values : (n,) array_like of float
        One error per vertex, mm.
    path : str or os.PathLike
        Output ``.png``, written atomically.
    n_instances : int, optional
        Over how many instances the error was averaged (for the colour bar's label).
    backend : {"auto", "vtk", "matplotlib"}, default: "auto"

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.mesh import Mesh
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> m = Mesh(s.vertices, s.faces)
    >>> render_error_map(m, np.abs(s.vertices[:, 2]) / 30, tempfile.mkdtemp() + "/e.png",
    ...                  backend="matplotlib").name
    'e.png'
    """
    from .render import render_grid

    views = ("front", "side", "top", "bottom")
    meshes = [_turned(mesh, v) for v in views]
    vals = np.asarray(values, dtype=float)
    label = "distance to scan (mm)" if not n_instances else f"distance to scan, mean of {n_instances} (mm)"
    return render_grid(meshes, path, titles=list(views), n_cols=4, views=("front",), scalars=[vals] * 4,
                       cmap=_ERROR_CMAP, clim=_error_range(vals), scalar_bar_title=label, cell_size=(300, 320),
                       backend=backend)


# --------------------------------------------------------------------------
# the HTML report
# --------------------------------------------------------------------------

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif;color:#222;
 max-width:1120px;margin:2em auto;padding:0 1.2em;line-height:1.45}
h1{font-size:1.7em;margin-bottom:.2em}h2{font-size:1.3em;margin-top:2em;border-bottom:1px solid #ddd;
 padding-bottom:.2em}h3{font-size:1.05em}
.meta{color:#555;margin-top:0}nav{margin:1em 0;font-size:.95em}nav a{margin-right:1em}
table{border-collapse:collapse;margin:.6em 0 1em;font-size:.92em}
th,td{border:1px solid #d5d5d5;padding:.25em .6em;text-align:right}th{background:#f3f5f7}
td.l,th.l{text-align:left}img{max-width:100%;height:auto;border:1px solid #eee}
.note{background:#fff7e6;border:1px solid #f0c36d;padding:.5em .9em;margin:1em 0}
.key td:first-child{text-align:left}.small{font-size:.88em;color:#555}
details{margin:.5em 0 1em}summary{cursor:pointer;color:#2a6f97}
"""


def _img(path) -> str:
    import base64
    import html

    if path is None or not Path(path).is_file():
        return ""
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(Path(path).stem)}">'


def _pm(mean: float, sd: float, digits: int = 2) -> str:
    if not np.isfinite(sd):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} \u00b1 {sd:.{digits}f}"


def _g(x: float, digits: int = 3) -> str:
    """A number with ``digits`` significant figures, without exponent for everyday sizes."""
    if not np.isfinite(x):
        return "\u2013"
    if x != 0 and (abs(x) >= 1e6 or abs(x) < 1e-3):
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}" if abs(x) < 10 ** digits else f"{x:,.0f}"


def _table(header, rows, left: int = 1) -> str:
    import html

    head = "".join(f'<th class="{"l" if i < left else ""}">{html.escape(str(h))}</th>' for i, h in enumerate(header))
    body = "".join(
        "<tr>" + "".join(f'<td class="{"l" if i < left else ""}">{html.escape(str(v))}</td>'
                         for i, v in enumerate(r)) + "</tr>"
        for r in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _first_reaching(ratio, modes, level: float) -> str:
    hit = np.nonzero(np.asarray(ratio) >= level - 1e-12)[0]
    return str(int(modes[hit[0]])) if hit.size else f"more than {int(modes[-1])}"


def write_report(ev: "Evaluation", path: str | os.PathLike) -> Path:
    """Write the evaluation as one self-contained HTML page.

    The page holds the key figures, the population's dimensions (Table 1),
    compactness, generalization and specificity (Figs. 10-12) as plots and as
    a table per number of modes (mm per vertex and the paper's squared norms,
    each with its standard error), the geometric error map and its Table 2
    figures, the landmark errors (Table 3), the first shape modes (Fig. 7)
    and random samples (Fig. 8). Pictures listed in ``ev.files`` are embedded
    as data URIs; the page loads nothing from the network.

    Parameters
    ----------
    ev : Evaluation
        With ``files`` naming the pictures (as :func:`write_evaluation` fills it).
    path : str or os.PathLike
        Output ``.html``, written atomically.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.evaluate import evaluate_shapes
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> ev = evaluate_shapes(ShapeModel().fit(shapes, s.faces), shapes, shapes, s.faces, names=[f"s{i}" for i in range(6)], n_samples=20)
    >>> page = write_report(ev, tempfile.mkdtemp() + "/report.html")
    >>> page.read_text(encoding="utf-8").startswith("<!DOCTYPE html>")
    True
    """
    import datetime
    import html

    from ._version import __version__
    from ._files import atomic_path

    target = Path(path)
    files = dict(ev.files)
    c, g, s, d = ev.compactness, ev.generalization, ev.specificity, ev.dimensions
    n = len(ev.names)
    esc = html.escape
    parts: list[str] = []
    add = parts.append
    now = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    add(f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        f"<title>Shape model evaluation: {esc(str(ev.model_dir or 'shapes'))}</title><style>{_CSS}</style></head><body>")
    add("<h1>Shape model evaluation</h1>")
    model_file = ModelDir(ev.model_dir).model if ev.model_dir is not None else "(in memory)"
    add(f'<p class="meta">Model <code>{esc(str(model_file))}</code>: {n} instances, '
        f"{ev.n_points:,} vertices; measures for m = 1 .. {int(c.modes[-1])} modes. "
        f"hortishape {esc(__version__)}, {now}, evaluated in {ev.seconds:.0f} s. All lengths in mm. "
        "Method and figure numbers: Danckaers et al. (2017), Food Bioprocess Technol 10:2100-2112.</p>")
    add('<nav><a href="#summary">Summary</a><a href="#dimensions">Dimensions</a><a href="#compactness">Compactness</a>'
        '<a href="#generalization">Generalization</a><a href="#specificity">Specificity</a>'
        '<a href="#table">Table per m</a><a href="#error-map">Error map</a><a href="#landmarks">Landmarks</a>'
        '<a href="#modes">Modes and viewer</a><a href="#samples">Samples</a><a href="#files">Files</a></nav>')
    if ev.notes:
        add('<div class="note"><b>Notes</b><ul>' + "".join(f"<li>{esc(t)}</li>" for t in ev.notes) + "</ul></div>")

    # summary
    def at(values, m):
        idx = np.nonzero(np.asarray(c.modes) == m)[0]
        return float(values[idx[0]]) if idx.size else float("nan")

    m5 = 5 if 5 in c.modes else int(c.modes[-1])
    key = [
        ("modes for 90% / 95% / 99% of the variance",
         f"{_first_reaching(c.ratio, c.modes, 0.9)} / {_first_reaching(c.ratio, c.modes, 0.95)} / "
         f"{_first_reaching(c.ratio, c.modes, 0.99)}"),
        (f"variance described by {m5} modes", f"{100 * at(c.ratio, m5):.1f}%"),
        (f"generalization G({m5}), mean distance per vertex",
         f"{_pm(at(g.mean_mm, m5), at(g.se_mm, m5), 3)} mm (\u00b1 SE)"),
        (f"specificity S({m5}), mean distance per vertex",
         f"{_pm(at(s.mean_mm, m5), at(s.se_mm, m5), 3)} mm (\u00b1 SE)"),
    ]
    if ev.geometric_error is not None:
        ge = ev.geometric_error
        key.append(("geometric error, registered surface to scan (Table 2)",
                    f"{_pm(ge.mean_mm, ge.sd_mm, 4)} mm (mean \u00b1 SD over {len(ge.names)} instances)"))
    if ev.landmarks is not None:
        stats = ev.landmarks.summary()
        mean, sd, _, _ = stats.get("average", stats[ev.landmarks.names[0]])
        key.append(("landmark transfer error, average of " + ", ".join(ev.landmarks.names) + " (Table 3)",
                    f"{_pm(mean, sd)} mm (mean \u00b1 SD)"))
    add('<h2 id="summary">Summary</h2><table class="key"><tbody>'
        + "".join(f"<tr><td>{esc(k)}</td><td>{esc(v)}</td></tr>" for k, v in key) + "</tbody></table>")

    # Table 1
    add('<h2 id="dimensions">Population dimensions (Table 1)</h2>')
    oh = d.overall_height
    add(_table(["", "width", "depth", "height", "height with stalk"],
               [["mean \u00b1 SD (mm)", *(_pm(a, b, 1) for a, b in zip(d.mean, d.sd)),
                 _pm(float(oh.mean()), float(oh.std(ddof=1)) if len(oh) > 1 else float("nan"), 1)],
                ["range (mm)", *(f"{lo:.1f} \u2013 {hi:.1f}" for lo, hi in zip(d.per_shape.min(0), d.per_shape.max(0))),
                 f"{oh.min():.1f} \u2013 {oh.max():.1f}"]]))
    add('<p class="small">Extents of each corresponded surface in the model\'s frame: height along its z axis (the '
        "stalk axis when the scans stood upright) without thin ends such as the stalk (cross-sections narrower "
        "than 10% of the width), width and depth along the major and minor horizontal axes of the mean shape; "
        "the last column is the whole extent along z.</p>")

    # Figs. 10-12
    add('<h2 id="compactness">Compactness (Fig. 10)</h2>' + _img(files.get("compactness_png")))
    add('<p class="small">C(m) = &lambda;<sub>1</sub> + ... + &lambda;<sub>m</sub> (eq. 14), the variance of the first '
        f"m modes, as a share of the total variance of the training shapes ({_g(c.total_mm2)} mm\u00b2 summed over "
        "all coordinates). A compact model describes the population with few modes.</p>")
    add('<h2 id="generalization">Generalization (Fig. 11)</h2>' + _img(files.get("generalization_png")))
    add('<p class="small">Leave-one-out: for each instance, a model is built from the other '
        f"{n - 1} (Procrustes and PCA); the left-out shape, aligned onto that model's mean, is described by its "
        "first m modes. Left: the mean Euclidean distance per vertex between the shape and its description (mm). "
        "Right: the paper's eq. 15, G(m) = mean of |x<sub>i</sub> \u2212 x'<sub>i</sub>(m)|\u00b2, the squared norm "
        "over all 3n coordinates (mm\u00b2). Mean over the instances; error bars: standard error. Smaller is "
        "better: the model describes shapes it has not seen.</p>")
    add('<h2 id="specificity">Specificity (Fig. 12)</h2>' + _img(files.get("specificity_png")))
    trunc = ev.settings.get("truncate")
    truncated = f", truncated at \u00b1{trunc:g} SD" if trunc else ""
    add(f'<p class="small">{s.n_samples} random shapes per m, drawn from the model with m modes (coefficients '
        f"standard normal{truncated}), each compared with the nearest "
        "training shape (smallest squared norm), both in the model's frame. Left: mean distance per vertex (mm); "
        "right: the paper's eq. 16, S(m) = mean of |y<sub>i</sub> \u2212 y'<sub>i</sub>(m)|\u00b2 (mm\u00b2). "
        "Error bars: standard error. Smaller is better: the model makes shapes like those it was built from.</p>")

    rows = []
    for j, m in enumerate(c.modes):
        rows.append([int(m), f"{100 * c.ratio[j]:.2f}", _g(c.variance_mm2[j]),
                     _pm(g.mean_mm[j], g.se_mm[j], 3), f"{_g(g.mean_sq[j])} \u00b1 {_g(g.se_sq[j], 2)}",
                     _pm(s.mean_mm[j], s.se_mm[j], 3), f"{_g(s.mean_sq[j])} \u00b1 {_g(s.se_sq[j], 2)}"])
    add('<h2 id="table">The measures per number of modes</h2>')
    add(_table(["m", "C(m) (% of total)", "\u03bb_m (mm\u00b2)", "G(m) per vertex (mm) \u00b1 SE",
                "G(m) eq. 15 (mm\u00b2) \u00b1 SE", "S(m) per vertex (mm) \u00b1 SE",
                "S(m) eq. 16 (mm\u00b2) \u00b1 SE"], rows))
    add('<p class="small">The same numbers are in <code>metrics.json</code> and <code>metrics.csv</code>.</p>')

    # Fig. 6 / Table 2
    add('<h2 id="error-map">Geometric error (Fig. 6, Table 2)</h2>')
    ge = ev.geometric_error
    if ge is None:
        add("<p>Not measured: the scans were not found (see the notes above).</p>")
    else:
        add(_img(files.get("error_map_png")))
        add(f'<p class="small">For every vertex of the reference, the distance of the registered surface to the '
            f"scan it was registered to, averaged over {len(ge.names)} instances and drawn on the model's mean "
            "(front, side, top and bottom view). The map is also written as <code>error_map.ply</code> (colours, "
            "and the distance as the vertex property <code>error_mm</code>) and <code>error_map.vtk</code> "
            "(point data <code>error_mm</code>).</p>")
        add(_table(["", "mean \u00b1 SD over the instances (mm)", "largest instance mean (mm)",
                    "largest vertex distance (mm)", "map maximum (mm)"],
                   [["distance to the scan", _pm(ge.mean_mm, ge.sd_mm, 4), f"{ge.per_instance_mm.max():.4f}",
                     f"{ge.max_mm.max():.4f}", f"{ge.per_vertex_mm.max():.4f}"]]))
        add("<details><summary>per instance</summary>"
            + _table(["instance", "mean (mm)", "max (mm)"],
                     [[nm, f"{a:.4f}", f"{b:.4f}"] for nm, a, b in zip(ge.names, ge.per_instance_mm, ge.max_mm)])
            + "</details>")

    # Table 3
    add('<h2 id="landmarks">Landmarks (Table 3)</h2>')
    t = ev.landmarks
    if t is None:
        add("<p>Not measured: no landmark positions were given (<code>--landmarks</code>) or found beside "
            "the scans.</p>")
    else:
        errs = t.errors_mm
        stats = t.summary()
        add(_table(["", *stats], [["error, mean \u00b1 SD (mm)", *(_pm(m, sd) for m, sd, _, _ in stats.values())],
                                  ["largest (mm)", *(f"{mx:.2f}" for _, _, mx, _ in stats.values())],
                                  ["instances", *(str(k) for _, _, _, k in stats.values())]]))
        add(_img(files.get("landmarks_png")))
        add(f'<p class="small">Landmarks from {esc(str(ev.landmarks_source))}. Protocol (the paper\'s, with the '
            "manual marker on the mean replaced by a consensus): each given landmark is moved to the closest point "
            "of its instance's corresponded surface, a face and barycentric coordinates shared by all instances; "
            "those places, evaluated on the mean shape and averaged over the instances, give the landmark on the "
            "mean; carried back to every instance through the correspondence (same face, same barycentric "
            "coordinates), its distance to the given position is the error. With perfect correspondence it is "
            "zero.</p>")
        surf = t.surface_mm
        add("<details><summary>per instance</summary>"
            + _table(["instance", *(f"{k} error (mm)" for k in t.names), *(f"{k} off-surface (mm)" for k in t.names)],
                     [[nm, *(_g(v) for v in errs[i]), *(_g(v) for v in surf[i])] for i, nm in enumerate(ev.names)])
            + "</details>")

    if files.get("uncertain_png"):
        add('<h2 id="orientation">Orientation</h2>')
        add("<p>The build found the orientation of these instances uncertain: the orientation search's margin "
            "over a distinct orientation (turned more than 45 degrees away) was small. Below, each beside the "
            "mean in the model's frame: one whose orientation went wrong shows its stalk or lobes turned away "
            "from the mean's. Confidence in brackets (0: a tie).</p>" + _img(files.get("uncertain_png")))
    add('<h2 id="modes">Shape modes (Fig. 7)</h2>' + _img(files.get("modes_png")))
    add('<p class="small">The mean and the mean moved \u00b13 standard deviations along each of the first modes, '
        "front and top view, all at the same scale.</p>")
    if files.get("viewer"):
        add(f'<p><a href="{esc(Path(files["viewer"]).name)}"><b>Open the model in the browser</b></a>: the mean in 3D '
            "with a slider per mode acting together, random samples, colouring by the displacement from the mean, "
            "the model's SD or the error map. One self-contained page (it needs no network), to send to anyone; "
            "its address keeps the sliders (<code>viewer.html#b=0,3</code> is mode 2 at +3 SD).</p>")
    elif ev.model_dir is not None:
        add('<p class="small">No browser viewer: it needs plotly (<code>pip install "hortishape[view]"</code>).</p>')
    add('<h2 id="samples">Random samples (Fig. 8)</h2>' + _img(files.get("samples_png")))
    add('<p class="small">New shapes drawn from the first five modes (coefficients standard normal, truncated at '
        "\u00b13 SD).</p>")
    add('<h2 id="files">Files</h2><ul>')
    for k, p in files.items():
        if k == "report":
            continue
        add(f'<li><a href="{esc(Path(p).name)}">{esc(Path(p).name)}</a></li>')
    add("</ul>")
    if ev.timings:
        add('<p class="small">Seconds per stage: '
            + ", ".join(f"{esc(k.replace('_', ' '))} {v:.1f}" for k, v in ev.timings.items()) + ".</p>")
    add("</body></html>\n")
    with atomic_path(target, HortishapeError) as tmp:
        tmp.write_text("\n".join(parts), encoding="utf-8")
    return target


# --------------------------------------------------------------------------
# an evaluation's files
# --------------------------------------------------------------------------


def _finite(values) -> list:
    """A list with NaN and infinity as None (strict JSON)."""
    return [None if not math.isfinite(v) else float(v) for v in np.asarray(values, dtype=float).reshape(-1)]


def metrics_dict(ev: Evaluation) -> dict:
    """The JSON-able content of ``metrics.json``.

    Top-level lists aligned with ``modes``: ``compactness`` (cumulative
    fraction of the variance, 0..1), ``generalization_mm`` /
    ``generalization_se_mm`` and ``specificity_mm`` / ``specificity_se_mm``
    (mean Euclidean distance per vertex and its standard error, mm),
    ``generalization_sq`` / ``generalization_se_sq`` and ``specificity_sq`` /
    ``specificity_se_sq`` (the paper's eqs. 15-16, squared norms, mm^2) and
    ``variance_mm2`` (each mode's variance). Then the geometric error,
    landmarks, dimensions and settings.

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.evaluate import evaluate_shapes
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> d = metrics_dict(evaluate_shapes(ShapeModel().fit(shapes, s.faces), shapes, shapes, s.faces, names=[f"s{i}" for i in range(6)], n_samples=20))
    >>> d["modes"], d["n_instances"]
    ([1, 2, 3], 6)
    """
    c, g, s, d = ev.compactness, ev.generalization, ev.specificity, ev.dimensions
    out: dict = {
        "units": "mm",
        "model_dir": None if ev.model_dir is None else str(ev.model_dir),
        "n_instances": len(ev.names),
        "n_points": ev.n_points,
        "modes": [int(m) for m in c.modes],
        "compactness": _finite(c.ratio),
        "variance_mm2": _finite(c.variance_mm2),
        "generalization_mm": _finite(g.mean_mm),
        "generalization_se_mm": _finite(g.se_mm),
        "generalization_sq": _finite(g.mean_sq),
        "generalization_se_sq": _finite(g.se_sq),
        "specificity_mm": _finite(s.mean_mm),
        "specificity_se_mm": _finite(s.se_mm),
        "specificity_sq": _finite(s.mean_sq),
        "specificity_se_sq": _finite(s.se_sq),
        "definitions": {
            "compactness": "C(m) / total variance: sum of the first m mode variances (eq. 14) over the total",
            "generalization_mm": "leave-one-out: mean Euclidean distance per vertex between each left-out "
                                 "shape and its description by m modes, averaged over the shapes (mm)",
            "generalization_sq": "eq. 15: squared norm |x_i - x'_i(m)|^2 over all 3n coordinates, "
                                 "averaged over the shapes (mm^2)",
            "specificity_mm": "mean Euclidean distance per vertex between a random shape of the model with "
                              "m modes and its nearest training shape, averaged over the random shapes (mm)",
            "specificity_sq": "eq. 16: squared norm |y_i - y'_i(m)|^2, averaged over the random shapes (mm^2)",
            "se": "standard error of the mean (standard deviation / sqrt(count))",
        },
        "dimensions_mm": {
            "mean": dict(zip(("width", "depth", "height"), _finite(d.mean))),
            "sd": dict(zip(("width", "depth", "height"), _finite(d.sd))),
            "per_instance": {n: dict(zip(("width", "depth", "height"), _finite(row)))
                             for n, row in zip(ev.names, d.per_shape)},
            "overall_height": {"mean": float(d.overall_height.mean()),
                               "sd": _finite([d.overall_height.std(ddof=1)])[0]},
            "definition": "extents in the model's frame: height along z without thin ends (a stalk), width "
                          "and depth along the major and minor horizontal axes of the mean; overall_height "
                          "includes the stalk",
        },
        "instances": list(ev.names),
        "settings": dict(ev.settings),
        "notes": list(ev.notes),
        "seconds": ev.seconds,
        "timings_s": dict(ev.timings),
    }
    geo = ev.geometric_error
    if geo is not None:
        out["geometric_error_mm"] = {
            "mean": geo.mean_mm, "sd": _finite([geo.sd_mm])[0],
            "per_instance": dict(zip(geo.names, _finite(geo.per_instance_mm))),
            "max_per_instance": dict(zip(geo.names, _finite(geo.max_mm))),
            "map_max": float(geo.per_vertex_mm.max()),
            "missing": [{"instance": n, "reason": r} for n, r in geo.missing],
        }
    else:
        out["geometric_error_mm"] = None
    t = ev.landmarks
    if t is not None:
        errs = t.errors_mm
        stats = {k: dict(zip(("mean", "sd", "max"), _finite(v[:3])), n=v[3]) for k, v in t.summary().items()}
        out["landmarks"] = {
            "source": ev.landmarks_source,
            "names": list(t.names),
            "protocol": "each given landmark -> closest point of its corresponded surface (face, barycentric) "
                        "-> evaluated on the mean and averaged over the instances -> put on the mean's surface "
                        "-> carried to every instance through the correspondence; error = distance to the given "
                        "position",
            "on_mean_mm": {k: _finite(p) for k, p in zip(t.names, t.on_mean)},
            "error_mm": {k: stats[k] for k in t.names},
            "average_mm": stats.get("average", stats[t.names[0]]),
            "per_instance_mm": {n: dict(zip(t.names, _finite(row))) for n, row in zip(ev.names, errs)},
            "surface_distance_mm": {n: dict(zip(t.names, _finite(row))) for n, row in zip(ev.names, t.surface_mm)},
        }
    else:
        out["landmarks"] = None
    return out


def metrics_csv(ev: Evaluation) -> str:
    """The content of ``metrics.csv``: one row per m, the measures as columns.

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.evaluate import evaluate_shapes
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> ev = evaluate_shapes(ShapeModel().fit(shapes, s.faces), shapes, shapes, s.faces, names=[f"s{i}" for i in range(6)], n_samples=20)
    >>> metrics_csv(ev).splitlines()[0].split(",")[:3]
    ['modes', 'compactness', 'variance_mm2']
    """
    c, g, s = ev.compactness, ev.generalization, ev.specificity
    cols = {
        "modes": c.modes, "compactness": c.ratio, "variance_mm2": c.variance_mm2,
        "generalization_mm": g.mean_mm, "generalization_se_mm": g.se_mm,
        "generalization_sq": g.mean_sq, "generalization_se_sq": g.se_sq,
        "specificity_mm": s.mean_mm, "specificity_se_mm": s.se_mm,
        "specificity_sq": s.mean_sq, "specificity_se_sq": s.se_sq,
    }
    lines = [",".join(cols)]
    for j in range(len(c.modes)):
        lines.append(",".join(str(int(v[j])) if k == "modes" else f"{float(v[j]):.9g}" for k, v in cols.items()))
    return "\n".join(lines) + "\n"


def _write_viewer(model, path: Path, ev: Evaluation) -> dict:
    """The evaluation's viewer page, or nothing when plotly, which draws it, is not installed."""
    from importlib.util import find_spec

    from .view import write_viewer

    if find_spec("plotly") is None:
        return {}
    geo = ev.geometric_error
    marks = None if ev.landmarks is None else dict(zip(ev.landmarks.names, ev.landmarks.on_mean))
    marks = {k: p for k, p in (marks or {}).items() if np.all(np.isfinite(p))} or None
    title = f"Shape model: {Path(ev.model_dir).name}" if ev.model_dir is not None else "Shape model"
    provenance = {"model file": str(ModelDir(ev.model_dir).model)} if ev.model_dir is not None else None
    page = write_viewer(model, path, error_map=None if geo is None else geo.per_vertex_mm, landmarks=marks,
                        title=title, provenance=provenance)
    return {"viewer": page.path}


def write_evaluation(
    ev: Evaluation,
    model,
    faces,
    folder,
    *,
    aligned: Mapping | None = None,
    random_state: RandomState = 0,
    start: float | None = None,
    viewer: bool = True,
) -> Evaluation:
    """Write an evaluation: metrics, error map, plots, pictures and the HTML report.

    Files in ``folder`` (created if needed), all written atomically:

    - ``metrics.json``, ``metrics.csv`` (see :func:`metrics_dict`, :func:`metrics_csv`);
    - ``error_map.ply`` (the mean shape with a colour per vertex and the
      distance as the vertex property ``error_mm``), ``error_map.vtk`` (the
      distance as point data ``error_mm``) and ``error_map.png`` (four views
      with a colour bar), when there is a geometric error;
    - ``compactness.png``, ``generalization.png``, ``specificity.png``,
      ``landmarks.png`` (with landmarks), ``modes.png``, ``samples.png``;
    - ``viewer.html``: the model in a browser, with the error map and the
      landmarks (:func:`hortishape.view.write_viewer`; with ``viewer`` and
      plotly installed);
    - ``report.html``: all of it on one page, pictures embedded, linking to the viewer.

    Parameters
    ----------
    ev : Evaluation
        From :func:`hortishape.evaluate.evaluate_shapes` (or
        ``evaluate_model(..., write=False)``).
    model : ShapeModel
        The evaluated model (for the mean, the mode and sample pictures).
    faces : (m, 3) array_like of int
        Its triangles.
    folder : path
    aligned : mapping of str to (n, 3) array_like, optional
        The aligned surfaces of the instances of uncertain orientation, by
        name, for their picture. Default: read from the model directory.
    random_state : int, Generator, SeedSequence or None, default: 0
        For the random samples pictured.
    start : float, optional
        ``time.perf_counter()`` when the evaluation began (for ``seconds``).
    viewer : bool, default: True
        Write ``viewer.html``.

    Returns
    -------
    Evaluation
        ``ev`` with ``files``, ``seconds`` and ``timings`` filled in.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.evaluate import evaluate_shapes
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> model = ShapeModel().fit(shapes, s.faces)
    >>> ev = write_evaluation(evaluate_shapes(model, shapes, shapes, s.faces, names=[f"s{i}" for i in range(6)], n_samples=20), model, s.faces,
    ...                       tempfile.mkdtemp(), viewer=False)
    >>> sorted(ev.files)[:3], ev.files["report"].name
    (['compactness_png', 'generalization_png', 'metrics_csv'], 'report.html')
    """
    from dataclasses import replace

    from .io import read_mesh, write_mesh

    t0 = time.perf_counter()
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    mean_mesh = model.to_mesh(model.mean_) if model.faces_ is not None else None
    if mean_mesh is None:
        from .mesh import Mesh

        mean_mesh = Mesh(model.mean_, faces)

    files["compactness_png"] = plot_compactness(ev.compactness, out / "compactness.png")
    files["generalization_png"] = plot_generalization(ev.generalization, out / "generalization.png")
    files["specificity_png"] = plot_specificity(ev.specificity, out / "specificity.png")
    geo = ev.geometric_error
    if geo is not None:
        values = geo.per_vertex_mm
        files["error_map_ply"] = write_mesh(out / "error_map.ply", mean_mesh,
                                            vertex_colors=error_colours(values),
                                            vertex_scalars={"error_mm": values})
        files["error_map_vtk"] = write_mesh(out / "error_map.vtk", mean_mesh, vertex_scalars={"error_mm": values})
        files["error_map_png"] = render_error_map(mean_mesh, values, out / "error_map.png",
                                                         n_instances=len(geo.names))
    if ev.landmarks is not None:
        files["landmarks_png"] = plot_landmark_errors(ev.landmarks, ev.names, out / "landmarks.png")
    n_modes = min(3, model.n_components_)
    files["modes_png"] = render_modes(model, out / "modes.png", n_modes=n_modes)
    files["samples_png"] = render_samples(model, out / "samples.png", random_state=random_state)
    if viewer and model.faces_ is not None:
        files.update(_write_viewer(model, out / "viewer.html", ev))
    if ev.uncertain_orientation:
        if aligned is None:
            aligned = {n: read_mesh(ModelDir(ev.model_dir).aligned_mesh(n)).vertices for n, _ in ev.uncertain_orientation}
        files["uncertain_png"] = render_uncertain(
            mean_mesh, [np.asarray(aligned[n]) for n, _ in ev.uncertain_orientation],
            [f"{n} ({c:.3f})" for n, c in ev.uncertain_orientation], out / "uncertain_orientation.png")
    timings = dict(ev.timings)
    timings["pictures"] = time.perf_counter() - t0
    seconds = time.perf_counter() - start if start is not None else ev.seconds + timings["pictures"]
    ev = replace(ev, files=files, timings=timings, seconds=seconds)
    files["metrics_json"] = atomic_text(out / "metrics.json", json.dumps(metrics_dict(ev), indent=1), HortishapeError)
    files["metrics_csv"] = atomic_text(out / "metrics.csv", metrics_csv(ev), HortishapeError)
    files["report"] = write_report(ev, out / "report.html")
    # files an earlier evaluation wrote that this one did not (no scans, no landmarks now)
    for stale in ("error_map.ply", "error_map.vtk", "error_map.png", "landmarks.png", "uncertain_orientation.png",
                  "viewer.html"):
        if (out / stale) not in files.values():
            (out / stale).unlink(missing_ok=True)
    return replace(ev, files=dict(files))
