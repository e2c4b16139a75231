"""Pictures and files that show a shape model (the paper's Figs. 7 and 8).

:func:`render_modes` draws the paper's Fig. 7: one row per mode, the mean
moved -3 SD, the mean and the mean moved +3 SD, in a front and a top view,
all at the same scale. :func:`write_mode_meshes` writes the same surfaces as
mesh files for a viewer or a CAD tool.

Mode numbers in pictures and file names count from 1, as in the paper
("mode 1" is the largest); :meth:`ShapeModel.mode_shapes` indexes from 0.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .model import ShapeModel

__all__ = ["render_modes", "write_mode_meshes"]


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
