"""Fitting B-spline surfaces to the mean and to every instance of a model (steps 3 and 4)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from .._rng import RandomState
from ..errors import MeshError, NotFittedError
from ..mesh import check_mesh
from .bspline import BSplineSurface, _basis_u, _basis_v
from .parameterize import CylinderMap, parameterize
from .poles import Poles

if TYPE_CHECKING:  # pragma: no cover
    from ..model import ShapeModel


def _unknown_index(k: int) -> np.ndarray:
    """``(k, k)`` map from control point ``[i, j]`` to unknown: 0 bottom pole, 1 stalk pole, then the rows between."""
    idx = np.empty((k, k), dtype=np.int64)
    idx[:, 0], idx[:, -1] = 0, 1
    idx[:, 1:-1] = 2 + np.arange(k * (k - 2)).reshape(k, k - 2)
    return idx


def _design(u: np.ndarray, v: np.ndarray, k: int) -> sp.csr_matrix:
    """Sparse ``(n, 2 + k (k - 2))`` matrix of basis values on the unknown control points."""
    iu, wu = _basis_u(u, k)
    iv, wv = _basis_v(v, k)
    unknown = _unknown_index(k)
    cols = unknown[iu[:, :, None], iv[:, None, :]].reshape(len(u), 16)
    vals = (wu[:, :, None] * wv[:, None, :]).reshape(len(u), 16)
    rows = np.repeat(np.arange(len(u)), 16)
    return sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(len(u), 2 + k * (k - 2)))


def _surface_samples(cmap: CylinderMap, vertices: np.ndarray, n_u: int, n_v: int):
    """A regular ``n_u x n_v`` grid of ``(u, v)`` cell centres, each a point of the triangle surface.

    Returns ``u, v, interpolation (s, n) sparse, weight (s,)`` where the
    weight is the surface area the cell stands for (mm^2).
    """
    import matplotlib.tri as mtri

    n = len(vertices)
    uu, vv = np.meshgrid((np.arange(n_u) + 0.5) / n_u, (np.arange(n_v) + 0.5) / n_v, indexing="ij")
    uu, vv = uu.ravel(), vv.ravel()
    cell = 1.0 / (n_u * n_v)
    v_b = float(cmap.uv[cmap.bottom_ring, 1].mean())
    v_s = float(cmap.uv[cmap.stalk_ring, 1].mean())
    rows, cols, vals, weights, keep_u, keep_v = [], [], [], [], [], []

    # strip between the rims: locate in the unrolled disc
    strip = (vv > v_b) & (vv < v_s)
    su, sv = uu[strip], vv[strip]
    tri = mtri.Triangulation(cmap.disc_uv[:, 0], cmap.disc_uv[:, 1], cmap.disc_faces)
    finder = tri.get_trifinder()
    where = finder(su, sv)
    shifted = su.copy()
    for shift in (1.0, -1.0):
        miss = where < 0
        if not miss.any():
            break
        w2 = finder(su[miss] + shift, sv[miss])
        hit = np.flatnonzero(miss)[w2 >= 0]
        where[hit] = w2[w2 >= 0]
        shifted[hit] = su[hit] + shift
    ok = where >= 0
    if (~ok).sum() > 0.01 * len(ok):  # a few may fall on the disc's outline; more means a broken map
        raise MeshError(f"{int((~ok).sum())} of {len(ok)} (u, v) samples lie outside the parameterization's disc")
    su, sv, shifted, where = su[ok], sv[ok], shifted[ok], where[ok]
    fd = cmap.disc_faces[where]
    p0, p1, p2 = (cmap.disc_uv[fd[:, c]] for c in range(3))
    den = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0])
    l1 = ((shifted - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (sv - p0[:, 1]) * (p2[:, 0] - p0[:, 0])) / den
    l2 = ((p1[:, 0] - p0[:, 0]) * (sv - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (shifted - p0[:, 0])) / den
    bary = np.clip(np.column_stack([1.0 - l1 - l2, l1, l2]), 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    corner = cmap.disc_vertices[fd]
    x = vertices[corner]
    area3 = 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
    start = 0
    rows.append(np.repeat(np.arange(len(su)), 3))
    cols.append(corner.ravel())
    vals.append(bary.ravel())
    weights.append(area3 / (0.5 * np.abs(den)) * cell)
    keep_u.append(su)
    keep_v.append(sv)
    start += len(su)

    # pole caps: ruled between the pole and its rim
    for ring, pole, cap, rim_v in (
        (cmap.bottom_ring, cmap.bottom, vv <= v_b, v_b),
        (cmap.stalk_ring, cmap.stalk, vv >= v_s, v_s),
    ):
        cu, cv = uu[cap], vv[cap]
        ru = cmap.uv[ring, 0]
        seg = (np.searchsorted(ru, cu, side="right") - 1) % len(ring)
        a, b = ring[seg], ring[(seg + 1) % len(ring)]
        width = np.mod(cmap.uv[b, 0] - cmap.uv[a, 0], 1.0)
        width[width == 0] = 1.0
        t = np.clip(np.mod(cu - cmap.uv[a, 0], 1.0) / width, 0.0, 1.0)
        s = cv / rim_v if pole == cmap.bottom else (1.0 - cv) / (1.0 - rim_v)
        s = np.clip(s, 0.0, 1.0)
        r = start + np.arange(len(cu))
        rows.append(np.repeat(r, 3))
        cols.append(np.column_stack([np.full(len(cu), pole), a, b]).ravel())
        vals.append(np.column_stack([1.0 - s, s * (1.0 - t), s * t]).ravel())
        area3 = 0.5 * np.linalg.norm(np.cross(vertices[a] - vertices[pole], vertices[b] - vertices[pole]), axis=1)
        weights.append(area3 / (width * (rim_v if pole == cmap.bottom else 1.0 - rim_v)) * cell)
        keep_u.append(cu)
        keep_v.append(cv)
        start += len(cu)

    interp = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(start, n)
    )
    return np.concatenate(keep_u), np.concatenate(keep_v), interp, np.concatenate(weights)


def _check_grid(grid) -> int:
    if isinstance(grid, bool) or not isinstance(grid, (int, np.integer)) or grid < 4:
        raise ValueError(f"grid must be an integer of at least 4 (control points per direction), got {grid!r}")
    return int(grid)


class BSplineFitter:
    """Least-squares B-spline approximation on a fixed cylindrical parameterization.

    ``fit`` takes the surface that defines the parameterization (a model's
    mean) and computes the linear operator from vertex coordinates to control
    points once; :meth:`control_points` and :meth:`surface` then apply it to
    any shape in correspondence with that surface (same vertex count and
    order), e.g. every instance of a shape model.

    The control points minimise the area-weighted squared distance between
    the B-spline and the triangle surface, sampled on a regular ``(u, v)``
    grid of ``samples_per_span`` points per knot span in each direction (the
    weights, the areas the samples stand for, come from the surface given to
    ``fit``).

    Parameters
    ----------
    grid : int, default: 32
        Control points per direction, ``k`` (a ``k x k`` grid, first and last
        rows collapsed to the poles; the paper shows 4, 8, 16, 32).
    samples_per_span : int, default: 8
        Samples per knot span and direction.

    Attributes
    ----------
    parameterization_ : CylinderMap
    n_vertices_ : int
    residual_ : float
        Root-mean-square distance (area-weighted over the samples) between the
        fitted surface of ``fit``'s vertices and their triangle surface, mm.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    >>> fitter = BSplineFitter(grid=8).fit(s.vertices, s.faces)
    >>> surface = fitter.surface(s.vertices * 1.5)   # any shape with the same vertices
    >>> surface.grid, surface.is_closed
    ((8, 8), True)
    """

    def __init__(self, grid: int = 32, *, samples_per_span: int = 8) -> None:
        self.grid = grid
        self.samples_per_span = samples_per_span

    def __repr__(self) -> str:
        return f"BSplineFitter(grid={self.grid!r}, samples_per_span={self.samples_per_span!r})"

    def fit(
        self,
        vertices: npt.ArrayLike,
        faces: npt.ArrayLike,
        *,
        parameterization: CylinderMap | None = None,
        poles: Poles | None = None,
    ) -> "BSplineFitter":
        """Parameterize the surface (unless given) and factor the least-squares operator.

        Parameters
        ----------
        vertices : (n, 3) array_like of float
            The surface defining the parameterization and the area weights, mm.
        faces : (m, 3) array_like of int
        parameterization : CylinderMap, optional
            Default: :func:`parameterize` with ``poles``.
        poles : Poles, optional
            Default: found automatically.

        Returns
        -------
        BSplineFitter
            ``self``.
        """
        import scipy.linalg as sla

        k = _check_grid(self.grid)
        sps = self.samples_per_span
        if isinstance(sps, bool) or not isinstance(sps, (int, np.integer)) or sps < 1:
            raise ValueError(f"samples_per_span must be a positive integer, got {sps!r}")
        v, f = check_mesh(vertices, faces, name="surface")
        cmap = parameterization if parameterization is not None else parameterize(v, f, poles=poles)
        if not isinstance(cmap, CylinderMap):
            raise TypeError(f"parameterization must be a CylinderMap, got {type(cmap).__name__}")
        if cmap.n_vertices != len(v):
            raise MeshError(f"the parameterization has {cmap.n_vertices} vertices, the surface {len(v)}")
        su, sv, interp, w = _surface_samples(cmap, v, int(sps) * k, int(sps) * k)
        design = _design(su, sv, k)
        wd = design.multiply(w[:, None]).tocsr()
        normal = (wd.T @ design).toarray()
        try:
            factor = sla.cho_factor(normal)
        except np.linalg.LinAlgError:  # pragma: no cover - every span holds samples
            raise MeshError("the B-spline least-squares system is singular") from None
        self.parameterization_ = cmap
        self.n_vertices_ = len(v)
        self._rhs = (wd.T @ interp).tocsr()  # (unknowns, n): the sampled right-hand side
        self._factor = factor
        self._k = k
        fitted = design @ self._solve(v)
        target = interp @ v
        self.residual_ = float(np.sqrt(w @ ((fitted - target) ** 2).sum(axis=1) / w.sum()))
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "_factor"):
            raise NotFittedError("this BSplineFitter is not fitted yet: call fit(vertices, faces) first")

    def _solve(self, x: np.ndarray) -> np.ndarray:
        import scipy.linalg as sla

        return sla.cho_solve(self._factor, self._rhs @ x)

    def _expand(self, unknowns: np.ndarray) -> np.ndarray:
        """Unknowns ``(..., u, 3)`` to control grids ``(..., k, k, 3)``."""
        return unknowns[..., _unknown_index(self._k), :]

    def control_points(self, vertices: npt.ArrayLike) -> np.ndarray:
        """Control points of the approximation of shapes in correspondence with the fitted surface.

        Parameters
        ----------
        vertices : (n, 3) or (N, n, 3) array_like of float

        Returns
        -------
        (k, k, 3) or (N, k, k, 3) float64 ndarray
        """
        self._check_fitted()
        x = np.asarray(vertices, dtype=np.float64)
        if x.shape[-2:] != (self.n_vertices_, 3) or x.ndim not in (2, 3):
            raise MeshError(
                f"vertices must have shape ({self.n_vertices_}, 3) or (N, {self.n_vertices_}, 3) "
                f"(in correspondence with the fitted surface), got {x.shape}"
            )
        if not np.isfinite(x).all():
            raise MeshError("vertices contain NaN or infinite values")
        if x.ndim == 2:
            return self._expand(self._solve(x))
        sol = self._solve(np.moveaxis(x, 0, 1).reshape(self.n_vertices_, -1))  # (u, N * 3)
        return self._expand(np.moveaxis(sol.reshape(-1, len(x), 3), 1, 0))

    def surface(self, vertices: npt.ArrayLike) -> BSplineSurface:
        """The B-spline approximation of one shape (see :meth:`control_points`)."""
        x = np.asarray(vertices, dtype=np.float64)
        if x.ndim != 2:
            raise MeshError(f"vertices of one shape must have shape (n, 3), got {x.shape}")
        return BSplineSurface(self.control_points(x))


class BSplineModel:
    """A shape model whose instances are B-spline surfaces (paper section 2.2.4).

    ``fit`` parameterizes the model's mean once, fits the mean and every
    mode, and stores their control points; an instance's control points are
    then ``mean_control_points_ + sum_i c_i sqrt(lambda_i)
    components_[i]`` with coefficients ``c`` in standard deviations, as in
    :class:`~hortishape.model.ShapeModel`: no refitting.

    Parameters
    ----------
    grid : int, default: 32
        Control points per direction.
    poles : Poles, optional
        Default: found on the mean automatically (:func:`find_poles`).
    spacing : {"arclength", "harmonic"}, default: "arclength"
        See :func:`parameterize`.
    parameterization : CylinderMap, optional
        A parameterization of the model's mean computed before (then
        ``poles`` and ``spacing`` are not used).

    Attributes
    ----------
    fitter_ : BSplineFitter
        The operator, usable for any shape in correspondence with the model.
    parameterization_ : CylinderMap
    mean_control_points_ : (k, k, 3) float64 ndarray
    components_ : (n_modes, k, k, 3) float64 ndarray
        Control-point displacement of each unit mode vector ``Phi_i`` (the
        approximation of ``Phi_i`` reshaped to ``(n, 3)``; the operator is linear).
    explained_variance_ : (n_modes,) float64 ndarray
        The model's ``lambda_i``, mm^2.
    faces_ : (m, 3) int64 ndarray
        The model's triangles.

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    >>> rng = np.random.default_rng(0)
    >>> model = ShapeModel().fit([s.vertices * rng.normal(1, 0.05, 3) for _ in range(6)], s.faces)
    >>> cad = BSplineModel(grid=8).fit(model)
    >>> cad.instance([2.0, -1.0]).grid
    (8, 8)
    """

    def __init__(self, grid: int = 32, *, poles: Poles | None = None, spacing: str = "arclength",
                 parameterization: CylinderMap | None = None) -> None:
        self.grid = grid
        self.poles = poles
        self.spacing = spacing
        self.parameterization = parameterization

    def __repr__(self) -> str:
        return f"BSplineModel(grid={self.grid!r})"

    def fit(self, model: "ShapeModel") -> "BSplineModel":
        """Parameterize the model's mean and fit the control points of the mean and of every mode.

        Parameters
        ----------
        model : ShapeModel
            A fitted model with faces.

        Returns
        -------
        BSplineModel
            ``self``.

        Raises
        ------
        NotFittedError
            If ``model`` is not fitted.
        MeshError
            If the model has no faces or its mean is not a closed one-component surface.
        """
        from ..model import ShapeModel

        if not isinstance(model, ShapeModel):
            raise TypeError(f"model must be a ShapeModel, got {type(model).__name__}")
        model._check_fitted()
        if model.faces_ is None:
            raise MeshError("the model has no faces: a CAD surface needs the mean's triangles")
        _check_grid(self.grid)
        mean = model.mean_
        cmap = self.parameterization
        if cmap is None:
            cmap = parameterize(mean, model.faces_, poles=self.poles, spacing=self.spacing)
        fitter = BSplineFitter(self.grid).fit(mean, model.faces_, parameterization=cmap)
        self.fitter_ = fitter
        self.parameterization_ = cmap
        self.mean_control_points_ = fitter.control_points(mean)
        # modes: the operator is linear, so fit the unit mode vectors (no mean added)
        phi = model.components_.reshape(model.n_components_, -1, 3)
        self.components_ = fitter.control_points(phi) if len(phi) else np.zeros((0, *self.mean_control_points_.shape))
        self.explained_variance_ = model.explained_variance_.copy()
        self.faces_ = model.faces_.copy()
        self.n_components_ = int(model.n_components_)
        self._model = model
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "fitter_"):
            raise NotFittedError("this BSplineModel is not fitted yet: call fit(model) first")

    @property
    def mean_(self) -> BSplineSurface:
        """The mean shape as a B-spline surface."""
        self._check_fitted()
        return BSplineSurface(self.mean_control_points_)

    def instance(self, coefficients: npt.ArrayLike) -> BSplineSurface:
        """The B-spline surface of one model instance (eq. 13 on control points).

        Parameters
        ----------
        coefficients : (k',) array_like of float
            Standard deviations along the first ``k' <= n_components_`` modes.

        Returns
        -------
        BSplineSurface
        """
        self._check_fitted()
        c = self._model._one_instance(coefficients)
        b = c * np.sqrt(self.explained_variance_[: c.size])
        return BSplineSurface(self.mean_control_points_ + np.tensordot(b, self.components_[: c.size], axes=1))

    def sample(self, *, modes: int | None = 5, truncate: float | None = 3.0,
               random_state: RandomState = None) -> BSplineSurface:
        """A random instance: coefficients from :meth:`ShapeModel.sample_coefficients` (paper section 3.2)."""
        self._check_fitted()
        c = self._model.sample_coefficients(1, modes=modes, truncate=truncate, random_state=random_state)[0]
        return self.instance(c)

    def mode_shapes(self, mode: int, *, sd: float = 3.0) -> tuple[BSplineSurface, BSplineSurface]:
        """The mean moved ``-sd`` and ``+sd`` standard deviations along one mode (index from 0)."""
        self._check_fitted()
        self._model._check_mode(mode, sd)
        c = np.zeros(int(mode) + 1)
        c[mode] = sd
        return self.instance(-c), self.instance(c)

    def surface(self, vertices: npt.ArrayLike) -> BSplineSurface:
        """The approximation of any shape in correspondence with the model (e.g. a registered scan)."""
        self._check_fitted()
        return self.fitter_.surface(vertices)
