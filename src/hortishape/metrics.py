"""How good is a shape model: quality measures of the paper's section 3.4.

Each measure is reported two ways: as the paper defines it (a mean squared
norm, eqs. 15-16) and as the mean Euclidean distance per vertex in
millimetres, which is what a person can picture.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .errors import HortishapeError

__all__ = ["Generalization", "generalization"]


@dataclass(frozen=True)
class Generalization:
    """Leave-one-out generalization G(m) for m = 1 .. M (paper eq. 15).

    Attributes
    ----------
    modes : (M,) int64 ndarray
        The numbers of modes m.
    mean_mm, se_mm : (M,) float64 ndarray
        Mean Euclidean distance per vertex between each left-out shape and its
        description by the first m modes of a model built without it, averaged
        over the shapes; and its standard error over the shapes. mm.
    mean_sq, se_sq : (M,) float64 ndarray
        The paper's eq. 15: the squared norm ``|x_i - x'_i(m)|^2`` averaged over
        the shapes, and its standard error. mm^2.
    per_shape_mm : (N, M) float64 ndarray
        The per-vertex mean distance of every left-out shape.
    """

    modes: np.ndarray
    mean_mm: np.ndarray
    se_mm: np.ndarray
    mean_sq: np.ndarray
    se_sq: np.ndarray
    per_shape_mm: np.ndarray


def generalization(shapes, *, modes: int | Sequence[int] | None = None, scaling: bool = False) -> Generalization:
    """Leave-one-out generalization of a PCA shape model (paper eq. 15).

    For each shape, a model is built from all the others (generalized
    Procrustes and PCA); the left-out shape is aligned onto that model's mean
    (rigid least squares, or similarity with ``scaling``) and described by the
    model's first m modes (orthogonal projection); the error is the distance
    between the aligned shape and its description.

    Parameters
    ----------
    shapes : (N, n, 3) array_like of float
        Corresponded shapes, N >= 4 (a model of the other N - 1 needs 3).
    modes : int or sequence of int, optional
        The m to evaluate; an int M means 1 .. M. Default: 1 .. N - 2 (all a
        model of N - 1 shapes has).
    scaling : bool, default: False

    Returns
    -------
    Generalization

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> shapes = rng.normal(size=(50, 3)) + 0.1 * rng.normal(size=(8, 50, 3))
    >>> g = generalization(shapes, modes=3)
    >>> g.modes.tolist(), bool(np.all(np.diff(g.mean_mm) <= 0))  # more modes, smaller error
    ([1, 2, 3], True)
    """
    from .model import ShapeModel
    from .procrustes import procrustes_align

    x = np.asarray(shapes, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise HortishapeError(f"shapes must be (N, n, 3), got {x.shape}")
    n_shapes = len(x)
    if n_shapes < 4:
        raise HortishapeError(f"leave-one-out needs at least 4 shapes, got {n_shapes}")
    if modes is None:
        ms = np.arange(1, n_shapes - 1)
    elif np.isscalar(modes):
        ms = np.arange(1, int(modes) + 1)
    else:
        ms = np.asarray(sorted(set(int(m) for m in modes)))
    if ms.min() < 1 or ms.max() > n_shapes - 2:
        raise HortishapeError(f"modes must lie in 1..{n_shapes - 2} for {n_shapes} shapes, got {ms.tolist()}")
    per_mm = np.empty((n_shapes, len(ms)))
    per_sq = np.empty((n_shapes, len(ms)))
    for i in range(n_shapes):
        others = np.delete(x, i, axis=0)
        model = ShapeModel(procrustes=True).fit(others)
        aligned, _ = procrustes_align(x[i], model.mean_, scaling=scaling)
        residual = (aligned - model.mean_).reshape(-1)
        proj = model.components_ @ residual  # coordinates along each mode (mm)
        for j, m in enumerate(ms):
            diff = (residual - proj[:m] @ model.components_[:m]).reshape(-1, 3)
            per_mm[i, j] = np.linalg.norm(diff, axis=1).mean()
            per_sq[i, j] = float((diff**2).sum())
    se = np.sqrt(n_shapes)
    return Generalization(
        modes=ms, mean_mm=per_mm.mean(0), se_mm=per_mm.std(0, ddof=1) / se,
        mean_sq=per_sq.mean(0), se_sq=per_sq.std(0, ddof=1) / se, per_shape_mm=per_mm,
    )
