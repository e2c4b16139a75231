"""Corresponded point sets: the input checks and the batched least-squares transforms.

Private to the package: shared by :mod:`hortishape.procrustes`,
:mod:`hortishape.model` and :mod:`hortishape.metrics`, which all take
corresponded shapes and move them rigidly onto one another.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .errors import MeshError
from .mesh import Mesh


# --------------------------------------------------------------------------
# input checks
# --------------------------------------------------------------------------


def as_shapes(shapes, *, name: str = "shapes", allow_single: bool = False,
              copy: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """``(N, n, 3)`` float64 copy of ``shapes`` and the common faces of Mesh input.

    With ``copy=False`` a float64 array is returned as it is (for callers
    that only read it: a copy of a thousand shapes is as large as they are).

    ``shapes`` is an ``(N, n, 3)`` array, a sequence of ``(n, 3)`` arrays or
    a sequence of :class:`Mesh` (which must all have the same faces). With
    ``allow_single`` a single ``(n, 3)`` array or Mesh is taken as ``N = 1``.
    """
    faces = None
    if isinstance(shapes, Mesh):
        if not allow_single:
            raise MeshError(f"{name} must be several shapes (N, n, 3), got a single Mesh")
        shapes = [shapes]
    if isinstance(shapes, Sequence) and not isinstance(shapes, (str, bytes)) and len(shapes) > 0 \
            and all(isinstance(s, Mesh) for s in shapes):
        faces = shapes[0].faces
        for i, s in enumerate(shapes[1:], start=1):
            if s.faces.shape != faces.shape or not np.array_equal(s.faces, faces):
                raise MeshError(
                    f"{name}[{i}] has other faces than {name}[0]: corresponded shapes share one triangulation"
                )
        arrays = [s.vertices for s in shapes]
        if len({a.shape for a in arrays}) > 1:
            raise MeshError(f"{name} have different numbers of vertices (unreferenced vertices?)")
        x = np.array(arrays, dtype=np.float64)
        return x, np.array(faces, dtype=np.int64)
    if isinstance(shapes, Sequence) and not isinstance(shapes, (str, bytes)) and len(shapes) > 0:
        try:
            sizes = {np.shape(s) for s in shapes}
        except Exception:  # pragma: no cover - exotic sequences
            sizes = set()
        if len(sizes) > 1:
            raise MeshError(
                f"{name} have different sizes {sorted(sizes, key=str)}: every shape needs the same "
                "number of corresponding points"
            )
    try:
        x = np.array(shapes, dtype=np.float64) if copy else np.asarray(shapes, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"{name} must be a numeric array of shape (N, n, 3) ({exc})") from None
    if allow_single and x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or x.shape[2] != 3:
        want = "(N, n, 3) or (n, 3)" if allow_single else "(N, n, 3)"
        raise MeshError(f"{name} must have shape {want}, got {x.shape}")
    if x.shape[0] == 0 or x.shape[1] == 0:
        raise MeshError(f"{name} is empty: shape {x.shape}")
    if not np.isfinite(x).all():
        bad = np.unique(np.nonzero(~np.isfinite(x))[0])
        raise MeshError(
            f"{name} contain NaN or infinite coordinates (shape{'s' if len(bad) > 1 else ''} "
            f"{', '.join(map(str, bad[:10]))}{', ...' if len(bad) > 10 else ''})"
        )
    return x, faces


def as_weights(weights, n: int) -> np.ndarray:
    """Normalised ``(n,)`` point weights (all equal when ``weights`` is None)."""
    if weights is None:
        return np.full(n, 1.0 / n)
    w = np.array(weights, dtype=np.float64)
    if w.shape != (n,):
        raise ValueError(f"weights must have shape ({n},), one per point, got {w.shape}")
    if not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
        raise ValueError("weights must be finite, non-negative and not all zero")
    return w / w.sum()


# --------------------------------------------------------------------------
# batched least-squares transforms (Kabsch / Umeyama)
# --------------------------------------------------------------------------


def fit_transforms(sources: np.ndarray, target: np.ndarray, w: np.ndarray, scaling: bool) -> np.ndarray:
    """``(N, 4, 4)`` transforms taking each of ``sources (N, n, 3)`` onto ``target (n, 3)``.

    Minimises ``sum_j w_j |s R p_ij + t - q_j|^2`` over rotations ``R`` (no
    reflections), translations ``t`` and, with ``scaling``, ``s > 0``
    (Kabsch; Umeyama 1991 for the scale). ``w`` sums to 1.
    """
    cs = w @ sources  # (N, 3) weighted centroids
    ct = w @ target
    a = sources - cs[:, None, :]
    b = target - ct
    h = np.swapaxes(a, 1, 2) @ (b * w[:, None])  # (N, 3, 3) cross-covariances
    u, sig, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, 1, 2)
    d = np.sign(np.linalg.det(v @ np.swapaxes(u, 1, 2)))
    d[d == 0] = 1.0
    dm = np.ones((len(sources), 3))
    dm[:, 2] = d
    r = (v * dm[:, None, :]) @ np.swapaxes(u, 1, 2)
    if scaling:
        var_src = (a * a).sum(axis=2) @ w
        s = (sig * dm).sum(axis=1) / np.where(var_src > 0, var_src, 1.0)
        s = np.where(var_src > 0, s, 1.0)
        r = r * s[:, None, None]
    t = np.empty((len(sources), 4, 4))
    t[:, :3, :3] = r
    t[:, :3, 3] = ct - np.einsum("ikl,il->ik", r, cs)
    t[:, 3] = [0.0, 0.0, 0.0, 1.0]
    return t


def apply_transforms(transforms: np.ndarray, shapes: np.ndarray) -> np.ndarray:
    """Apply ``(N, 4, 4)`` transforms to ``(N, n, 3)`` shapes."""
    out = shapes @ np.swapaxes(transforms[:, :3, :3], 1, 2)
    out += transforms[:, None, :3, 3]  # in place: one (N, n, 3) array, not two
    return out
