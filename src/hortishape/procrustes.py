"""Generalized Procrustes alignment of corresponded shapes (paper section 2.2.3).

Before the PCA of eqs. 9-12 the corresponded surfaces are "superimposed by
optimally translating and rotating" them (Gower 1975; Dryden and Mardia
1998). :func:`generalized_procrustes` does this for ``N`` shapes of ``n``
corresponding points each; :func:`procrustes_align` aligns one shape onto a
reference.

Scaling is optional and **off by default**: the size of a fruit is its most
important shape variable (it is the first mode of the paper's models), so
removing it would remove what the model is meant to describe.

Gauge
-----
Generalized Procrustes determines the shapes only up to one common rigid
(or similarity) transform: rotating every aligned shape and the mean by the
same rotation gives an equally good solution. hortishape fixes this freedom
deterministically: in every iteration the new mean is moved onto the
**first input shape** by the same kind of transform that aligns the shapes
(rigid, or similarity with ``scaling=True``), and the shapes are then aligned
to that mean. So the result sits in the pose (and, with scaling, the size) of
``shapes[0]``: a population already in a common upright pose stays upright
(stalk along +z), results do not drift from one iteration or run to the
next, and they do not depend on the order of the other shapes.

Transforms are ``(4, 4)`` homogeneous matrices acting on column vectors,
``p' = T[:3, :3] @ p + T[:3, 3]``, as everywhere in hortishape; with
scaling the scale factor is folded into the ``3 x 3`` block (``s R``).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ._shapes import apply_transforms, as_shapes, as_weights, fit_transforms
from .errors import ConvergenceWarning, MeshError
from .mesh import Mesh

__all__ = ["Procrustes", "generalized_procrustes", "procrustes_align"]


@dataclass(frozen=True, eq=False)
class Procrustes:
    """Result of :func:`generalized_procrustes`.

    Attributes
    ----------
    aligned : (N, n, 3) float64 ndarray
        The shapes after alignment (mm).
    transforms : (N, 4, 4) float64 ndarray
        ``transforms[i]`` maps ``shapes[i]`` onto ``aligned[i]``. Rigid, or a
        similarity (scale folded into the ``3 x 3`` block) with ``scaling=True``.
    mean : (n, 3) float64 ndarray
        The Procrustes mean: the mean of ``aligned`` (in the pose of the first
        shape, see the module's *Gauge*).
    n_iter : int
        Alignment iterations done.
    converged : bool
        Whether the mean changed by less than ``tol`` in the last iteration.
    """

    aligned: np.ndarray
    transforms: np.ndarray
    mean: np.ndarray
    n_iter: int
    converged: bool = True


def _rms_size(points: np.ndarray, w: np.ndarray) -> float:
    """Weighted RMS distance of ``points (n, 3)`` from their weighted centroid."""
    c = w @ points
    return float(np.sqrt(w @ ((points - c) ** 2).sum(axis=1)))


# --------------------------------------------------------------------------
# public functions
# --------------------------------------------------------------------------


def generalized_procrustes(
    shapes: npt.ArrayLike | Sequence[Mesh],
    *,
    scaling: bool = False,
    tol: float = 1e-8,
    max_iter: int = 100,
    weights: npt.ArrayLike | None = None,
) -> Procrustes:
    """Align corresponded shapes to their common mean (generalized Procrustes).

    Each iteration aligns every shape onto the current mean by least squares
    (Kabsch; Umeyama with ``scaling``), averages the aligned shapes into a new
    mean and moves that mean onto the first shape (the gauge, see the module
    docstring). It stops when the mean moves by less than ``tol`` times its
    size (both weighted RMS over the points). Used before the PCA of the
    paper's eqs. 9-12 (section 2.2.3).

    Parameters
    ----------
    shapes : (N, n, 3) array_like of float, or sequence of Mesh
        ``N`` shapes of ``n`` corresponding points (mm). Meshes must share faces.
    scaling : bool, default: False
        Also remove size (similarity instead of rigid transforms). Off by
        default: size is the first mode of a fruit population.
    tol : float, default: 1e-8
        Convergence threshold on the relative RMS change of the mean.
    max_iter : int, default: 100
        Maximum number of iterations; a :class:`~hortishape.ConvergenceWarning`
        is issued when it is reached without convergence.
    weights : (n,) array_like of float, optional
        Non-negative weights of the points in the least-squares fits (default:
        all equal), e.g. to ignore a stalk.

    Returns
    -------
    Procrustes
        ``aligned (N, n, 3)``, ``transforms (N, 4, 4)`` (input to aligned),
        ``mean (n, 3)``, ``n_iter``, ``converged``.

    Raises
    ------
    MeshError
        If ``shapes`` is not ``(N, n, 3)`` with ``n >= 3``, holds NaN or
        infinite values, or the meshes do not share faces.
    ValueError
        If an option is out of range.

    Examples
    --------
    >>> from hortishape.align import rotation_about
    >>> rng = np.random.default_rng(0)
    >>> base = rng.normal(size=(100, 3)) * [30.0, 20.0, 10.0]
    >>> moved = [base @ rotation_about(rng.normal(size=3), a).T + 5.0 * a for a in (0.0, 0.5, 1.0)]
    >>> gpa = generalized_procrustes(moved)
    >>> bool(np.allclose(gpa.aligned, base, atol=1e-9)), gpa.transforms.shape
    (True, (3, 4, 4))
    """
    x, _ = as_shapes(shapes)
    n_shapes, n = x.shape[:2]
    if n < 3:
        raise MeshError(f"shapes need at least 3 corresponding points each, got {n}")
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    w = as_weights(weights, n)
    first = x[0]
    # the points themselves, not their spread: a centroid of equal points can come out a last
    # digit off them (BLAS sums in an order of its CPU's), and the spread not 0
    if np.ptp(first[w > 0], axis=0).max() == 0:
        raise MeshError("shapes[0] has all its (weighted) points at one place: its pose is undefined")

    reference = first
    converged = False
    n_iter = 0
    for n_iter in range(1, int(max_iter) + 1):
        mean = _aligned_mean(x, reference, w, scaling)
        # gauge: the mean in the pose (and size) of the first shape
        gauge = fit_transforms(mean[None], first, w, scaling)[0]
        new_reference = mean @ gauge[:3, :3].T + gauge[:3, 3]
        size = _rms_size(new_reference, w)
        change = float(np.sqrt(w @ ((new_reference - reference) ** 2).sum(axis=1)))
        reference = new_reference
        if change <= tol * size:
            converged = True
            break
    if not converged:
        warnings.warn(
            f"generalized Procrustes did not converge in {max_iter} iterations "
            f"(relative change of the mean {change / size:.2e} > tol = {tol:g})",
            ConvergenceWarning,
            stacklevel=2,
        )
    transforms = np.concatenate([fit_transforms(x[c], reference, w, scaling) for c in _chunks(n_shapes)])
    aligned = apply_transforms(transforms, x)
    return Procrustes(aligned, transforms, aligned.mean(axis=0), n_iter, converged)


#: Shapes aligned at a time inside an iteration: the memory an iteration
#: needs beyond the shapes themselves stays that many shapes' worth, however
#: many there are.
CHUNK = 64


def _chunks(n_shapes: int):
    return (slice(s, min(s + CHUNK, n_shapes)) for s in range(0, n_shapes, CHUNK))


def _aligned_mean(x: np.ndarray, reference: np.ndarray, w: np.ndarray, scaling: bool) -> np.ndarray:
    """The mean of the shapes aligned onto ``reference``, a chunk of shapes at a time."""
    total = np.zeros(x.shape[1:])
    for c in _chunks(len(x)):
        total += apply_transforms(fit_transforms(x[c], reference, w, scaling), x[c]).sum(axis=0)
    return total / len(x)


def procrustes_align(
    shape: npt.ArrayLike | Mesh,
    reference: npt.ArrayLike | Mesh,
    *,
    scaling: bool = False,
    weights: npt.ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Align one shape onto a reference with corresponding points (least squares).

    Parameters
    ----------
    shape, reference : (n, 3) array_like of float or Mesh
        Corresponding points (mm), ``n >= 3``.
    scaling : bool, default: False
        Also fit a scale factor (similarity transform).
    weights : (n,) array_like of float, optional
        Non-negative point weights (default: all equal).

    Returns
    -------
    aligned : (n, 3) float64 ndarray
        ``shape`` moved onto ``reference``.
    transform : (4, 4) float64 ndarray
        The transform from ``shape`` to ``aligned`` (scale folded into the
        ``3 x 3`` block with ``scaling``).

    Raises
    ------
    MeshError
        If the arrays are not ``(n, 3)`` of equal size with ``n >= 3``, or hold
        NaN or infinite values.

    Examples
    --------
    >>> from hortishape.align import rotation_about
    >>> ref = np.random.default_rng(1).normal(size=(50, 3))
    >>> moved = 2.0 * ref @ rotation_about([1, 0, 0], 0.4).T + [3.0, 0.0, 0.0]
    >>> aligned, t = procrustes_align(moved, ref, scaling=True)
    >>> bool(np.allclose(aligned, ref)), round(float(np.linalg.det(t[:3, :3])) ** (1 / 3), 6)
    (True, 0.5)
    """
    s, _ = as_shapes(shape, name="shape", allow_single=True)
    r, _ = as_shapes(reference, name="reference", allow_single=True)
    if s.shape[0] != 1 or r.shape[0] != 1:
        raise MeshError(f"shape and reference must each be one (n, 3) array, got {s.shape} and {r.shape}")
    if s.shape != r.shape:
        raise MeshError(f"shape and reference must have the same number of points, got {s.shape[1]} and {r.shape[1]}")
    if s.shape[1] < 3:
        raise MeshError(f"at least 3 corresponding points are needed, got {s.shape[1]}")
    w = as_weights(weights, s.shape[1])
    t = fit_transforms(s, r[0], w, scaling)
    return apply_transforms(t, s)[0], t[0]
