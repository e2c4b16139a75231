"""How good is a shape model: quality measures of the paper's section 3.4 and Tables 1-3.

- :func:`compactness`: cumulative variance of the first m modes, C(m) (eq. 14, Fig. 10).
- :func:`generalization`: leave-one-out description of unseen shapes, G(m) (eq. 15, Fig. 11).
- :func:`specificity`: random model shapes against their nearest training shape, S(m) (eq. 16, Fig. 12).
- :func:`transfer_landmarks`: landmarks marked on the mean and carried to every
  instance through the correspondence (the protocol of Table 3).
- :func:`dimensions`: width, depth and height of every shape (Table 1).
- :func:`geometric_error`: distance of the registered surfaces to their scans
  (section 3.1, Fig. 6, Table 2).
- :class:`Evaluation`: all of them for one model, as
  :func:`hortishape.evaluate.evaluate_shapes` measures them and
  :func:`hortishape.report.write_evaluation` writes them.

Generalization and specificity are reported two ways: as the paper defines
them (a mean squared norm ``|x - x'|^2`` summed over all 3n coordinates,
eqs. 15-16, in mm^2) and as the mean Euclidean distance per vertex in
millimetres, which is what a person can picture. The two are different
numbers: for n vertices with errors of about e mm each, the first is about
``n * e^2`` and the second ``e``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from collections.abc import Mapping
from dataclasses import field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable, Sequence

import numpy as np

from ._rng import RandomState, as_generator
from .errors import HortishapeError, MeshError

if TYPE_CHECKING:  # pragma: no cover
    from .model import ShapeModel

__all__ = [
    "Compactness",
    "Dimensions",
    "Evaluation",
    "Generalization",
    "GeometricError",
    "LandmarkTransfer",
    "Specificity",
    "compactness",
    "dimensions",
    "generalization",
    "geometric_error",
    "specificity",
    "transfer_landmarks",
]

# Eigenvalues of a Gram matrix below this fraction of the largest are rounding
# noise (the same threshold as ShapeModel.fit).
_RANK_RTOL = 1e-10


def _modes_list(modes, largest: int, what: str) -> np.ndarray:
    """``modes`` (None, an int M or a sequence) as a sorted int64 array within 1..largest."""
    if largest < 1:
        raise HortishapeError(f"{what}: there are no modes to evaluate")
    if modes is None:
        ms = np.arange(1, largest + 1)
    elif np.isscalar(modes):
        if isinstance(modes, bool) or int(modes) != modes:
            raise ValueError(f"modes must be a whole number or a sequence of them, got {modes!r}")
        ms = np.arange(1, int(modes) + 1)
    else:
        ms = np.asarray(sorted(set(int(m) for m in modes)), dtype=np.int64)
    if ms.size == 0 or ms.min() < 1 or ms.max() > largest:
        raise HortishapeError(f"{what}: modes must lie in 1..{largest}, got {ms.tolist()}")
    return ms.astype(np.int64)


def _se(values: np.ndarray) -> np.ndarray:
    """Standard error of the mean over axis 0 (NaN for a single value)."""
    n = values.shape[0]
    if n < 2:
        return np.full(values.shape[1:], np.nan)
    return values.std(axis=0, ddof=1) / np.sqrt(n)


# --------------------------------------------------------------------------
# compactness (eq. 14)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Compactness:
    """Compactness C(m) for m = 1 .. M (paper eq. 14, Fig. 10).

    Attributes
    ----------
    modes : (M,) int64 ndarray
        The numbers of modes m.
    variance_mm2 : (M,) float64 ndarray
        Variance ``lambda_m`` of mode m, mm^2 (summed over the 3n coordinates).
    cumulative_mm2 : (M,) float64 ndarray
        ``C(m) = lambda_1 + ... + lambda_m`` (eq. 14), mm^2.
    ratio : (M,) float64 ndarray
        ``C(m)`` over the total variance of the training shapes: the fraction
        of the shape variation the first m modes describe, 0..1 (Fig. 10
        shows it in percent).
    total_mm2 : float
        The total variance the ratio is relative to, mm^2.
    """

    modes: np.ndarray
    variance_mm2: np.ndarray
    cumulative_mm2: np.ndarray
    ratio: np.ndarray
    total_mm2: float


def compactness(variances, *, total: float | None = None, modes: int | Sequence[int] | None = None) -> Compactness:
    """Cumulative variance of the first m modes, C(m) (paper eq. 14, Fig. 10).

    Parameters
    ----------
    variances : (k,) array_like of float, or ShapeModel
        The mode variances ``lambda_i`` in mm^2, largest first; or a fitted
        :class:`~hortishape.model.ShapeModel` (its ``explained_variance_``,
        and the total variance of its training shapes as ``total``).
    total : float, optional
        Total variance of the population, mm^2. Default: the sum of
        ``variances`` (all modes given), or the model's total variance.
    modes : int or sequence of int, optional
        The m to report; an int M means 1 .. M. Default: 1 .. k.

    Returns
    -------
    Compactness

    Examples
    --------
    >>> c = compactness([6.0, 3.0, 1.0])
    >>> c.cumulative_mm2.tolist(), c.ratio.tolist()
    ([6.0, 9.0, 10.0], [0.6, 0.9, 1.0])
    """
    if hasattr(variances, "explained_variance_"):
        model = variances
        model._check_fitted()
        lam = np.array(model.explained_variance_, dtype=np.float64)
        if total is None:
            ratio = np.asarray(model.explained_variance_ratio_, dtype=np.float64)
            total = float(lam[0] / ratio[0]) if ratio.size and ratio[0] > 0 else float(lam.sum())
    else:
        lam = np.array(variances, dtype=np.float64).reshape(-1)
    if lam.size == 0 or not np.isfinite(lam).all() or (lam < 0).any():
        raise ValueError("variances must be a non-empty sequence of finite, non-negative numbers")
    if np.any(np.diff(lam) > 1e-12 * lam.max()):
        raise ValueError("variances must be sorted largest first, as a PCA gives them")
    total = float(lam.sum()) if total is None else float(total)
    if not (np.isfinite(total) and total > 0) or total < lam.sum() * (1 - 1e-9):
        raise ValueError(f"total must be positive and at least the sum of the variances, got {total!r}")
    ms = _modes_list(modes, lam.size, "compactness")
    cumulative = np.cumsum(lam)[ms - 1]
    return Compactness(ms, lam[ms - 1], cumulative, cumulative / total, total)


# --------------------------------------------------------------------------
# generalization (eq. 15)
# --------------------------------------------------------------------------


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


def _check_shapes(shapes, name: str = "shapes") -> np.ndarray:
    x = np.array(shapes, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise HortishapeError(f"{name} must be (N, n, 3), got {x.shape}")
    if not np.isfinite(x).all():
        raise HortishapeError(f"{name} contain NaN or infinite coordinates")
    return x


def generalization(
    shapes,
    *,
    modes: int | Sequence[int] | None = None,
    scaling: bool = False,
    progress: Callable[[Iterable], Iterable] | None = None,
) -> Generalization:
    """Leave-one-out generalization of a PCA shape model (paper eq. 15).

    For each shape, a model is built from all the others: generalized
    Procrustes of the others (rigid, or similarity with ``scaling``) and PCA
    of the aligned others. The left-out shape is aligned onto that model's
    mean by the same kind of least-squares transform and described by the
    model's first m modes (orthogonal projection onto them); the error is
    the distance between the aligned shape and its description.

    The PCA of each leave-one-out model is computed from the ``(N-1) x
    (N-1)`` Gram matrix of its shapes (as in eqs. 10-12), and the
    descriptions for all m at once as combinations of the training shapes,
    so the ``3n x 3n`` covariance and the modes themselves are never formed.
    Every Procrustes starts from a global alignment of all shapes and so
    converges in a few iterations.

    The squared norm (eq. 15) never increases with m: the description is an
    orthogonal projection onto more and more modes. The mean distance per
    vertex is not bound to, but on fruit populations it decreases as well.

    Parameters
    ----------
    shapes : (N, n, 3) array_like of float
        Corresponded shapes, N >= 4 (a model of the other N - 1 needs 3).
    modes : int or sequence of int, optional
        The m to evaluate; an int M means 1 .. M. Default: 1 .. N - 2 (all a
        model of N - 1 shapes has). An m above the rank of a leave-one-out
        model uses all its modes.
    scaling : bool, default: False
        Remove size too in every alignment (as a model built with scaling).
    progress : callable, optional
        Wraps the iterator over the left-out shapes (e.g. ``tqdm``).

    Returns
    -------
    Generalization

    Raises
    ------
    HortishapeError
        Fewer than 4 shapes, shapes not ``(N, n, 3)`` or not finite, or modes
        outside 1 .. N - 2.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> shapes = rng.normal(size=(50, 3)) + 0.1 * rng.normal(size=(8, 50, 3))
    >>> g = generalization(shapes, modes=3)
    >>> g.modes.tolist(), bool(np.all(np.diff(g.mean_mm) <= 0))  # more modes, smaller error
    ([1, 2, 3], True)
    """
    from .procrustes import generalized_procrustes, procrustes_align

    x = _check_shapes(shapes)
    n_shapes, n_points = x.shape[:2]
    if n_shapes < 4:
        raise HortishapeError(f"leave-one-out needs at least 4 shapes, got {n_shapes}")
    ms = _modes_list(modes, n_shapes - 2, f"generalization of {n_shapes} shapes")
    start = generalized_procrustes(x, scaling=scaling).aligned
    per_mm = np.empty((n_shapes, len(ms)))
    per_sq = np.empty((n_shapes, len(ms)))
    folds = range(n_shapes) if progress is None else progress(range(n_shapes))
    for i in folds:
        gpa = generalized_procrustes(np.delete(start, i, axis=0), scaling=scaling)
        mean = gpa.mean.reshape(-1)
        xc = gpa.aligned.reshape(n_shapes - 1, -1) - mean
        aligned, _ = procrustes_align(start[i], gpa.mean, scaling=scaling)
        r = aligned.reshape(-1) - mean
        lam, u = np.linalg.eigh(xc @ xc.T)  # (N-1) x (N-1) Gram matrix, eqs. 10-11
        lam, u = lam[::-1], u[:, ::-1]
        rank = min(int(np.count_nonzero(lam > _RANK_RTOL * lam[0])), n_shapes - 2) if lam[0] > 0 else 0
        lam, u = lam[:rank], u[:, :rank]
        # Mode j is Phi_j = xc^T u_j / sqrt(lam_j); r's coordinate along it is
        # u_j . (xc r) / sqrt(lam_j); the description by the first m modes is
        # xc^T w_m with w_m = sum_{j<m} u_j (u_j . xc r) / lam_j.
        terms = u * ((u.T @ (xc @ r)) / lam)[None, :]  # (N-1, rank)
        w = np.cumsum(terms, axis=1)[:, np.minimum(ms, rank) - 1].T if rank else np.zeros((len(ms), n_shapes - 1))
        diff = r[None, :] - w @ xc  # (M, 3n)
        per_sq[i] = np.einsum("ij,ij->i", diff, diff)
        d3 = diff.reshape(len(ms), n_points, 3)
        per_mm[i] = np.sqrt(np.einsum("ijk,ijk->ij", d3, d3)).mean(axis=1)
    return Generalization(
        modes=ms, mean_mm=per_mm.mean(0), se_mm=_se(per_mm),
        mean_sq=per_sq.mean(0), se_sq=_se(per_sq), per_shape_mm=per_mm,
    )


# --------------------------------------------------------------------------
# specificity (eq. 16)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Specificity:
    """Specificity S(m) for m = 1 .. M (paper eq. 16, Fig. 12).

    Attributes
    ----------
    modes : (M,) int64 ndarray
        The numbers of modes m.
    mean_mm, se_mm : (M,) float64 ndarray
        Mean Euclidean distance per vertex between each random shape of the
        model with m modes and its nearest training shape, averaged over the
        random shapes; and its standard error. mm.
    mean_sq, se_sq : (M,) float64 ndarray
        The paper's eq. 16: the squared norm ``|y_i - y'_i(m)|^2`` averaged
        over the random shapes, and its standard error. mm^2.
    nearest : (M, n_samples) int64 ndarray
        Index of the nearest training shape of every random shape.
    n_samples : int
        Random shapes per m.
    """

    modes: np.ndarray
    mean_mm: np.ndarray
    se_mm: np.ndarray
    mean_sq: np.ndarray
    se_sq: np.ndarray
    nearest: np.ndarray
    n_samples: int


def specificity(
    model: "ShapeModel",
    shapes,
    *,
    modes: int | Sequence[int] | None = None,
    n_samples: int = 200,
    truncate: float | None = 3.0,
    random_state: RandomState = None,
) -> Specificity:
    """Random shapes of the model against their nearest training shape (paper eq. 16).

    For every m, ``n_samples`` shapes are drawn from the model with m modes
    (:meth:`ShapeModel.sample`: standard normal coefficients truncated at
    ``+/- truncate`` SD, as the paper's section 3.2) and each is compared with
    the training shape nearest to it, both in the model's frame (no further
    alignment). "Nearest" is in the sense of eq. 16, the smallest squared
    norm; the mm figure is the mean per-vertex distance to that same shape.

    The squared norms to all training shapes are computed exactly in the
    model's coefficient space (a training shape's part outside the model's
    modes adds a constant), so only one full shape difference per sample is
    formed.

    Parameters
    ----------
    model : ShapeModel
        A fitted model.
    shapes : (N, n, 3) array_like of float
        The training shapes in the model's frame (the shapes the model was
        fitted on; a model with ``procrustes=True`` aligns them onto its
        mean first).
    modes : int or sequence of int, optional
        The m to evaluate; an int M means 1 .. M. Default: all the model's modes.
    n_samples : int, default: 200
        Random shapes per m.
    truncate : float or None, default: 3.0
        Truncation of the coefficients, in standard deviations (None: none).
    random_state : int, Generator, SeedSequence or None, default: None
        The samples for m = modes[0], modes[1], ... are drawn in turn from one
        generator, as ``model.sample(n_samples, modes=m, ...)`` would.

    Returns
    -------
    Specificity

    Raises
    ------
    HortishapeError
        If the shapes do not correspond with the model, or modes exceed its modes.

    Examples
    --------
    >>> from hortishape.model import ShapeModel
    >>> rng = np.random.default_rng(0)
    >>> shapes = rng.normal(size=(40, 3)) + 0.5 * rng.normal(size=(10, 40, 3))
    >>> model = ShapeModel().fit(shapes)
    >>> s = specificity(model, shapes, modes=2, n_samples=50, random_state=0)
    >>> s.modes.tolist(), s.nearest.shape
    ([1, 2], (2, 50))
    """
    model._check_fitted()
    x = _check_shapes(shapes)
    if x.shape[1] != model.n_points_:
        raise HortishapeError(
            f"the training shapes have {x.shape[1]} points, the model {model.n_points_}: they must correspond"
        )
    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)) or n_samples < 2:
        raise ValueError(f"n_samples must be an integer of at least 2, got {n_samples!r}")
    ms = _modes_list(modes, model.n_components_, "specificity")
    if model.procrustes:
        from ._shapes import apply_transforms, fit_transforms

        x = apply_transforms(fit_transforms(x, model.mean_, np.full(x.shape[1], 1.0 / x.shape[1]), False), x)
    n_points = x.shape[1]
    phi = model.components_
    sd = np.sqrt(model.explained_variance_)
    t = x.reshape(len(x), -1) - model.mean_.reshape(-1)
    coords = t @ phi.T  # (N, k) training shapes along the modes, mm
    outside = t - coords @ phi  # (N, 3n) their parts outside the modes
    outside2 = np.einsum("ij,ij->i", outside, outside)
    # The per-vertex distances need whole shape differences: formed in float32
    # (differences of about a millimetre, so ~1e-7 mm rounding), 64 at a time.
    phi32 = phi.astype(np.float32)
    has_outside = bool(outside2.max() > 1e-18 * max(float(np.einsum("ij,ij->", t, t)), 1e-300))
    outside32 = outside.astype(np.float32) if has_outside else None
    rng = as_generator(random_state)
    nearest = np.empty((len(ms), n_samples), dtype=np.int64)
    per_mm = np.empty((n_samples, len(ms)))
    per_sq = np.empty((n_samples, len(ms)))
    for j, m in enumerate(ms):
        b = model.sample_coefficients(n_samples, modes=int(m), truncate=truncate, random_state=rng) * sd
        d2 = ((b[:, None, :] - coords[None, :, :]) ** 2).sum(axis=2) + outside2[None, :]  # (S, N)
        near = np.argmin(d2, axis=1)
        nearest[j] = near
        per_sq[:, j] = d2[np.arange(n_samples), near]
        for lo in range(0, n_samples, 64):
            sl = slice(lo, min(lo + 64, n_samples))
            diff = (b[sl] - coords[near[sl]]).astype(np.float32) @ phi32
            if outside32 is not None:
                diff -= outside32[near[sl]]
            diff = diff.reshape(len(diff), n_points, 3)
            per_mm[sl, j] = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff)).mean(axis=1, dtype=np.float64)
    return Specificity(ms, per_mm.mean(0), _se(per_mm), per_sq.mean(0), _se(per_sq), nearest, int(n_samples))


# --------------------------------------------------------------------------
# landmarks (Table 3)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class LandmarkTransfer:
    """Landmarks marked on the mean and carried to every instance (Table 3).

    Attributes
    ----------
    names : tuple of str
        The L landmarks.
    face_index : (L,) int64 ndarray
        Face of the shared triangulation holding each landmark on the mean.
    barycentric : (L, 3) float64 ndarray
        Its barycentric coordinates in that face.
    on_mean : (L, 3) float64 ndarray
        The landmarks on the mean shape, mm.
    transferred : (N, L, 3) float64 ndarray
        The mean's landmarks carried to every instance through the
        correspondence (same face, same barycentric coordinates), in the
        instance's coordinates, mm.
    errors_mm : (N, L) float64 ndarray
        Distance between the carried and the given landmark (NaN where none
        was given), mm.
    surface_mm : (N, L) float64 ndarray
        Distance of each given landmark to the instance's corresponded
        surface, mm (how far off the surface it was marked).
    """

    names: tuple
    face_index: np.ndarray
    barycentric: np.ndarray
    on_mean: np.ndarray
    transferred: np.ndarray
    errors_mm: np.ndarray
    surface_mm: np.ndarray

    @property
    def average_mm(self) -> np.ndarray:
        """(N,) each instance's error averaged over the landmarks given on it (NaN where none), mm."""
        ok = np.isfinite(self.errors_mm)
        count = ok.sum(axis=1)
        total = np.where(ok, self.errors_mm, 0.0).sum(axis=1)
        return np.divide(total, count, out=np.full(len(count), np.nan), where=count > 0)

    def summary(self) -> dict:
        """Table 3: for each landmark, and their ``"average"`` when there are several,
        ``(mean, sd, max, count)`` of the errors over the instances where it was given, mm."""
        columns = {k: self.errors_mm[:, j] for j, k in enumerate(self.names)}
        if len(self.names) > 1:
            columns["average"] = self.average_mm
        return {k: _finite_stats(v) for k, v in columns.items()}


def _finite_stats(values) -> tuple[float, float, float, int]:
    """(mean, sample SD, max, count) of the finite values; NaN where undefined."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan, math.nan, 0
    sd = float(v.std(ddof=1)) if v.size > 1 else math.nan
    return float(v.mean()), sd, float(v.max()), int(v.size)


def transfer_landmarks(
    shapes,
    faces,
    landmarks,
    *,
    names: Sequence[str] | None = None,
    mean=None,
) -> LandmarkTransfer:
    """Mark landmarks on the mean shape, carry them to every instance, measure the error (Table 3).

    The paper marks each landmark by hand on every input surface and on the
    average surface, loads the average's marker on every instance through
    the correspondence and measures the distance to the hand-placed marker.
    Here the marker on the mean is the consensus of the given markers:

    1. each given landmark is moved to the closest point of its instance's
       corresponded surface, which is a face and barycentric coordinates of
       the shared triangulation;
    2. those places are evaluated on the mean shape and averaged over the
       instances, and the average is put on the mean's surface (closest
       point): the landmark on the mean;
    3. that face and those barycentric coordinates, evaluated on every
       instance, carry it to the instance; the error is the distance to the
       given landmark.

    With perfect correspondence every instance marks the same place, so the
    error is zero (plus any distance of the given marker from the surface).

    Parameters
    ----------
    shapes : (N, n, 3) array_like of float
        Corresponded surfaces, each in the coordinates its landmarks are given
        in (e.g. the registered surfaces in scan coordinates), mm.
    faces : (m, 3) array_like of int
        Their shared triangles.
    landmarks : (N, L, 3) array_like of float
        The given landmark positions; NaN where an instance lacks one.
    names : sequence of str, optional
        L landmark names (default ``landmark_0``, ...).
    mean : (n, 3) array_like of float, optional
        The mean shape to mark them on (default: the mean of the shapes after
        generalized Procrustes).

    Returns
    -------
    LandmarkTransfer

    Raises
    ------
    HortishapeError
        Shapes and landmarks do not match, or a landmark is given on no instance.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=40.0)
    >>> shapes = [s.vertices * [1.0, 1.0, h] for h in (0.9, 1.0, 1.1)]
    >>> top = [[v[np.argmax(v[:, 2])]] for v in shapes]  # the top vertex of each
    >>> t = transfer_landmarks(shapes, s.faces, top, names=["top"])
    >>> t.errors_mm.round(9).tolist()
    [[0.0], [0.0], [0.0]]
    """
    from .mesh import Mesh
    from .surface import barycentric_interpolate, closest_points

    x = _check_shapes(shapes)
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or f.size == 0 or f.min() < 0 or f.max() >= x.shape[1]:
        raise MeshError(f"faces must be (m, 3) indices into the {x.shape[1]} vertices")
    lm = np.array(landmarks, dtype=np.float64)
    if lm.ndim != 3 or lm.shape[0] != len(x) or lm.shape[2] != 3:
        raise HortishapeError(f"landmarks must be (N, L, 3) with N = {len(x)} shapes, got {lm.shape}")
    n_lm = lm.shape[1]
    names = tuple(f"landmark_{k}" for k in range(n_lm)) if names is None else tuple(str(s) for s in names)
    if len(names) != n_lm:
        raise HortishapeError(f"got {len(names)} names for {n_lm} landmarks")
    given = np.isfinite(lm).all(axis=2)
    for k in np.nonzero(~given.any(axis=0))[0]:
        raise HortishapeError(f"landmark {names[k]!r} is given on no instance")
    if mean is None:
        from .procrustes import generalized_procrustes

        mean_shape = generalized_procrustes(x).mean
    else:
        mean_shape = np.asarray(mean, dtype=np.float64)
        if mean_shape.shape != x.shape[1:]:
            raise HortishapeError(f"mean must be ({x.shape[1]}, 3), got {mean_shape.shape}")

    surface = np.full(given.shape, np.nan)
    marks = np.full(lm.shape, np.nan)  # the given landmarks' places, evaluated on the mean
    for i in range(len(x)):
        ks = np.nonzero(given[i])[0]
        if ks.size == 0:
            continue
        cp = closest_points(Mesh(x[i], f), lm[i, ks])
        surface[i, ks] = cp.distances
        marks[i, ks] = barycentric_interpolate(mean_shape, f, cp.face_index, cp.barycentric)
    consensus = np.nanmean(marks, axis=0)  # (L, 3)
    cp = closest_points(Mesh(mean_shape, f), consensus)
    transferred = np.stack([barycentric_interpolate(xi, f, cp.face_index, cp.barycentric) for xi in x])
    errors = np.linalg.norm(transferred - lm, axis=2)  # NaN where not given
    return LandmarkTransfer(names, cp.face_index, cp.barycentric, cp.points, transferred, errors, surface)


# --------------------------------------------------------------------------
# dimensions (Table 1)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Dimensions:
    """Width, depth and height of every shape (Table 1).

    Attributes
    ----------
    per_shape : (N, 3) float64 ndarray
        Width, depth and height of each shape, mm; the height is that of the
        body, without thin protrusions at its ends such as a stalk.
    overall_height : (N,) float64 ndarray
        The whole extent along the height axis, stalk included, mm.
    mean, sd : (3,) float64 ndarray
        Mean and standard deviation of ``per_shape`` over the shapes, mm.
    axes : (3, 3) float64 ndarray
        Rows: the width, depth and height directions, unit vectors in the
        shapes' frame.
    """

    per_shape: np.ndarray
    overall_height: np.ndarray
    mean: np.ndarray
    sd: np.ndarray
    axes: np.ndarray


def _slice_extents(points: np.ndarray, edges: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Largest horizontal extent (along the first two axes) of a surface's cross-section at each level.

    ``points (n, 3)`` are in the (width, depth, height) frame; a cross-section
    at height ``h`` is where the mesh edges cross it. Levels no edge crosses
    get 0.
    """
    z0, z1 = points[edges[:, 0], 2], points[edges[:, 1], 2]
    lo, hi = np.minimum(z0, z1), np.maximum(z0, z1)
    first = np.searchsorted(levels, lo, side="left")
    last = np.searchsorted(levels, hi, side="right")  # levels[first:last] lie in [lo, hi]
    count = np.maximum(last - first, 0)
    rep = np.repeat(np.arange(len(edges)), count)
    offsets = np.cumsum(count) - count
    k = first[rep] + (np.arange(rep.size) - offsets[rep])
    a, b = points[edges[rep, 0]], points[edges[rep, 1]]
    dz = b[:, 2] - a[:, 2]
    t = np.divide(levels[k] - a[:, 2], dz, out=np.zeros_like(dz), where=dz != 0)
    xy = a[:, :2] + t[:, None] * (b[:, :2] - a[:, :2])
    big, small = np.full((len(levels), 2), -np.inf), np.full((len(levels), 2), np.inf)
    np.maximum.at(big, k, xy)
    np.minimum.at(small, k, xy)
    extent = (big - small).max(axis=1)
    return np.where(np.isfinite(extent), extent, 0.0)


def dimensions(shapes, faces=None, *, up=(0.0, 0.0, 1.0), min_width_fraction: float = 0.1) -> Dimensions:
    """Width, depth and height of corresponded shapes in a common frame (Table 1).

    Height is measured along ``up`` (the stalk axis; a model's frame has it
    along +z when the scans stood upright); width and depth are the extents
    along the major and minor principal axes of the mean shape seen from
    above (its vertices projected on the plane normal to ``up``).

    The height is that of the body, as calipers would measure it: the
    horizontal cross-sections of the surface are taken every 0.2% of the
    height, and those at the ends narrower than ``min_width_fraction`` of the
    shape's width (a stalk, a thin tip) are left out. A smooth rounded end
    of radius R loses about 0.005 R this way (a coarse mesh a little more).
    ``overall_height`` keeps everything. Without ``faces`` the height is the
    overall one.

    Parameters
    ----------
    shapes : (N, n, 3) array_like of float
        Shapes in a common frame (e.g. Procrustes-aligned), mm.
    faces : (m, 3) array_like of int, optional
        Their shared triangles (needed for the cross-sections).
    up : (3,) array_like of float, default: (0, 0, 1)
    min_width_fraction : float, default: 0.1
        Cross-sections narrower than this fraction of the width do not count
        as body at the top and bottom ends; 0 keeps everything.

    Returns
    -------
    Dimensions

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    >>> d = dimensions([s.vertices * [40.0, 35.0, 42.0], s.vertices * [42.0, 37.0, 44.0]], s.faces)
    >>> d.mean.round(1).tolist(), round(float(d.overall_height.mean()), 1)
    ([82.0, 72.0, 85.3], 86.0)
    """
    x = _check_shapes(shapes)
    if len(x) < 1:
        raise HortishapeError("dimensions need at least one shape")
    z = np.asarray(up, dtype=np.float64).reshape(-1)
    if z.shape != (3,) or not np.isfinite(z).all() or np.linalg.norm(z) == 0:
        raise ValueError(f"up must be a non-zero 3-vector, got {up!r}")
    if not (0.0 <= min_width_fraction < 1.0):
        raise ValueError(f"min_width_fraction must lie in [0, 1), got {min_width_fraction!r}")
    z = z / np.linalg.norm(z)
    mean = x.mean(axis=0)
    flat = mean - mean.mean(axis=0)
    flat = flat - np.outer(flat @ z, z)  # seen from above
    _, v = np.linalg.eigh(flat.T @ flat)
    width = v[:, 2] - (v[:, 2] @ z) * z
    width /= np.linalg.norm(width)
    depth = np.cross(z, width)
    axes = np.stack([width, depth, z])
    proj = x @ axes.T  # (N, n, 3) in the (width, depth, height) frame
    per = proj.max(axis=1) - proj.min(axis=1)
    overall = per[:, 2].copy()
    if faces is not None and min_width_fraction > 0:
        from .mesh import unique_edges

        edges = unique_edges(faces)
        if edges.size == 0 or edges.min() < 0 or edges.max() >= x.shape[1]:
            raise MeshError(f"faces must index the {x.shape[1]} points of the shapes")
        for i, p in enumerate(proj):
            lo, hi = float(p[:, 2].min()), float(p[:, 2].max())
            step = (hi - lo) / 500.0
            if step <= 0:
                continue
            levels = lo + step * (np.arange(500) + 0.5)
            wide = np.nonzero(_slice_extents(p, edges, levels) >= min_width_fraction * per[i, :2].max())[0]
            if wide.size:
                bottom = lo if wide[0] == 0 else levels[wide[0]] - step / 2
                top = hi if wide[-1] == len(levels) - 1 else levels[wide[-1]] + step / 2
                per[i, 2] = top - bottom
    sd = per.std(axis=0, ddof=1) if len(per) > 1 else np.full(3, np.nan)
    return Dimensions(per, overall, per.mean(axis=0), sd, axes)


@dataclass(frozen=True)
class GeometricError:
    """Distance of the registered surfaces to their scans (paper Fig. 6, Table 2).

    Attributes
    ----------
    names : tuple of str
        The instances measured (those whose scan was found).
    per_instance_mm : (N,) float64 ndarray
        Mean distance of each registered surface's vertices to its scan, mm.
    max_mm : (N,) float64 ndarray
        The largest of those distances per instance, mm.
    per_vertex_mm : (n,) float64 ndarray
        For every reference vertex, its distance to the scan averaged over the
        instances: the error map, mm.
    missing : tuple of (str, str)
        ``(instance, reason)`` for every instance left out.
    """

    names: tuple
    per_instance_mm: np.ndarray
    max_mm: np.ndarray
    per_vertex_mm: np.ndarray
    missing: tuple = ()

    @property
    def mean_mm(self) -> float:
        """Mean over the instances of their mean distance (Table 2), mm."""
        return float(self.per_instance_mm.mean())

    @property
    def sd_mm(self) -> float:
        """Standard deviation over the instances of their mean distance (Table 2), mm."""
        return float(self.per_instance_mm.std(ddof=1)) if len(self.per_instance_mm) > 1 else math.nan


def geometric_error(
    registered: np.ndarray,
    faces: np.ndarray,
    names,
    scan_paths,
    *,
    progress: Callable[[Iterable], Iterable] | None = None,
) -> GeometricError | None:
    """Distance of each registered surface's vertices to its scan, and their average per vertex.

    Parameters
    ----------
    registered : (N, n, 3) float64 ndarray
        Registered surfaces, each in its scan's coordinates, mm.
    faces : (m, 3) int64 ndarray
    names : sequence of str
        The N instances.
    scan_paths : sequence of (path or None)
        The scan of each instance; None where it was not found.
    progress : callable, optional
        Wraps the iterator over the instances.

    Returns
    -------
    GeometricError or None
        None when no scan could be read.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from pathlib import Path
    >>> from hortishape.io import write_mesh
    >>> from hortishape.mesh import Mesh
    >>> ball = trimesh.creation.icosphere(subdivisions=4, radius=30.0)
    >>> scan = write_mesh(Path(tempfile.mkdtemp()) / "ball.ply", Mesh(ball.vertices, ball.faces))
    >>> coarse = trimesh.creation.icosphere(subdivisions=2, radius=30.5)   # registered 0.5 mm outside
    >>> g = geometric_error(coarse.vertices[None], coarse.faces, ["ball"], [scan])
    >>> round(float(g.mean_mm), 2)
    0.5
    """
    from .io import read_mesh
    from .surface import closest_points

    kept, dists, missing = [], [], []
    items = list(zip(names, registered, scan_paths))
    for name, vertices, path in (progress(items) if progress else items):
        if path is None:
            missing.append((name, "scan not found"))
            continue
        try:
            scan = read_mesh(path)
        except HortishapeError as exc:
            missing.append((name, str(exc)))
            continue
        kept.append(name)
        dists.append(closest_points(scan, vertices).distances)
    if not kept:
        return None
    d = np.stack(dists)
    return GeometricError(tuple(kept), d.mean(axis=1), d.max(axis=1), d.mean(axis=0), tuple(missing))


@dataclass(frozen=True)
class Evaluation:
    """Everything :func:`hortishape.evaluate.evaluate_shapes` measured, and where it was written.

    Attributes
    ----------
    model_dir : Path or None
        The built model directory (None for shapes evaluated in memory).
    names : tuple of str
        The model's instances, in order.
    n_points : int
        Vertices of the model's shapes.
    compactness : Compactness
    generalization : Generalization
    specificity : Specificity
    dimensions : Dimensions
        Width, depth and height of every instance, in the model's frame.
    geometric_error : GeometricError or None
        None when no scan was found (see ``notes``).
    landmarks : LandmarkTransfer or None
        Rows in the order of ``names``; None without landmarks.
    landmarks_source : str or None
        Where the landmarks came from.
    notes : tuple of str
        What was skipped and why, in plain words.
    uncertain_orientation : tuple of (str, float)
        ``(name, confidence)`` of the instances the build named as of
        uncertain orientation (``summary.json``), pictured in the report.
    files : Mapping of str to Path
        What was written: ``"report"``, ``"metrics_json"``, ``"metrics_csv"``,
        ``"error_map_ply"``, ... (empty when nothing was written).
    seconds : float
        Wall time of the measures (and of the writing, when written).
    timings : Mapping of str to float
        Seconds per stage.
    settings : Mapping of str to object
        The options used (``n_samples``, ``truncate``, ``random_state``, ``scaling``).
    """

    model_dir: Path | None
    names: tuple
    n_points: int
    compactness: Compactness
    generalization: Generalization
    specificity: Specificity
    dimensions: Dimensions
    geometric_error: GeometricError | None
    landmarks: LandmarkTransfer | None
    landmarks_source: str | None
    notes: tuple
    uncertain_orientation: tuple = ()
    files: Mapping = field(default_factory=dict)
    seconds: float = 0.0
    timings: Mapping = field(default_factory=dict)
    settings: Mapping = field(default_factory=dict)

    @property
    def modes(self) -> np.ndarray:
        """The numbers of modes m every measure was evaluated at."""
        return self.compactness.modes
