"""Statistical shape models: PCA of corresponded shapes (paper section 2.2.3, eqs. 9-13).

:class:`ShapeModel` behaves like scikit-learn's ``PCA`` (arguments stored in
``__init__``, all work in :meth:`~ShapeModel.fit`, fitted attributes ending
in ``_``) and speaks scalismo's words (``instance``, ``project``, ``sample``,
``truncate``). :func:`fit_pose_and_shape` fits eq. 13, ``y = C(x_bar + Phi b)``,
to the corresponding points of a new shape.

Coefficients are in standard deviations
---------------------------------------
Everywhere in this module (``transform``, ``inverse_transform``,
``instance``, ``sample``, ``scores_``, ``ShapeFit.coefficients``) the shape
coefficients are in units of each mode's standard deviation, as in scalismo
and Statismo: coefficient ``c_i`` stands for the paper's ``b_i = c_i *
sqrt(lambda_i)`` millimetres along the unit mode ``Phi_i``. So coefficients of
the training population, and of samples of the model, are distributed as
``N(0, I)``; ``c_i = 3`` is "+3 SD" (the paper's Figs. 7 and 8); the
Mahalanobis distance is simply ``|c|``. (scikit-learn's ``transform`` returns
the raw projections ``b``; multiply by ``sqrt(explained_variance_)`` to get them.)

Flattened coordinates are interleaved per point, ``(x0, y0, z0, x1, ...)``,
as the rows of the paper's matrix ``X`` and Statismo's vectors.

Model files
-----------
:meth:`ShapeModel.save` writes an HDF5 file in the Statismo 0.9 layout that
Statismo and scalismo read (``/version``, ``/representer``, ``/model``,
``/modelinfo``; float32 as Statismo stores it), plus a ``/hortishape`` group
with float64 copies and hortishape's metadata. :meth:`ShapeModel.load`
reads both its own files and plain Statismo/scalismo files.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from ._rng import RandomState, as_generator
from ._shapes import apply_transforms, as_shapes, as_weights, fit_transforms
from .errors import HortishapeError, MeshError, NotFittedError
from .mesh import Mesh, check_mesh
from .procrustes import generalized_procrustes
from .statismo import ModelData, read_model, write_model

__all__ = ["ShapeFit", "ShapeModel", "fit_pose_and_shape"]

#: Shapes: an ``(N, n, 3)`` array (or ``(n, 3)`` where one shape is allowed), or meshes.
Shapes = npt.ArrayLike | Mesh | Sequence[Mesh]

# Eigenvalues of the Gram matrix below this fraction of the largest are
# rounding noise (its absolute error is about N * eps * lambda_max).
_RANK_RTOL = 1e-10
# A mode whose cosine with uniform growth of the mean is below this gets its
# sign from its largest entry instead (see ShapeModel.fit).
_GROWTH_COS_MIN = 1e-6
# Columns of the data centred at a time in the PCA: an N x 4096 block (33 MB
# for 1,000 shapes) keeps the products at full BLAS speed.
_BLOCK_COLUMNS = 4096

# --------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------


class ShapeModel:
    """A point distribution model: mean shape and principal modes (eqs. 9-12).

    Parameters
    ----------
    n_components : int, float or None, default: None
        Modes to keep. ``None``: every mode with non-zero variance (at most
        ``N - 1`` for ``N`` training shapes). An int ``k >= 1``: the first
        ``k``. A float in ``(0, 1]``: the fewest modes whose variances add up
        to at least that fraction of the total variance (e.g. ``0.95``).
    procrustes : bool, default: False
        Rigidly align the training shapes with generalized Procrustes
        (:func:`~hortishape.procrustes.generalized_procrustes`, no scaling)
        before the PCA, and align new shapes onto ``mean_`` in
        :meth:`transform` (and so in :meth:`project` and :meth:`mahalanobis`).
        Leave it off when the shapes are already in a common pose (e.g. all
        registered into the reference's frame).

    Attributes
    ----------
    mean_ : (n, 3) float64 ndarray
        Mean shape ``x_bar`` (eq. 9), mm.
    components_ : (k, 3n) float64 ndarray
        Orthonormal modes ``Phi`` as rows (eqs. 11-12), interleaved
        ``(x0, y0, z0, x1, ...)``, by decreasing variance. Signs: see :meth:`fit`.
    explained_variance_ : (k,) float64 ndarray
        Variance ``lambda_i`` of each mode, mm^2, decreasing (eq. 11, with the
        ``1 / (N - 1)`` of eq. 10).
    explained_variance_ratio_ : (k,) float64 ndarray
        ``lambda_i`` over the total variance of the training shapes.
    singular_values_ : (k,) float64 ndarray
        ``sqrt((N - 1) * lambda_i)``.
    noise_variance_ : float
        Variance per coordinate left outside the kept modes, mm^2:
        ``(total - sum(lambda)) / (3n - k)`` (the probabilistic-PCA estimate;
        0 when every mode is kept). Written as Statismo's ``noiseVariance``.
    n_components_ : int
        ``k``.
    n_samples_ : int or None
        ``N`` (None for a loaded Statismo file that does not say).
    n_points_ : int
        ``n``.
    faces_ : (m, 3) int64 ndarray or None
        Triangles of the shapes (from ``fit``'s ``faces`` or meshes).
    names_ : tuple of str
        Names of the training shapes (default ``shape_000``, ...).
    scores_ : (N, k) float64 ndarray or None
        Coefficients of the training shapes, in standard deviations.
    procrustes_transforms_ : (N, 4, 4) float64 ndarray or None
        With ``procrustes=True``: the transforms from each training shape to
        its aligned pose.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> base = rng.normal(size=(200, 3)) * [40.0, 40.0, 42.0]
    >>> shapes = base * rng.normal(1.0, 0.05, size=(20, 1, 1))  # size varies
    >>> model = ShapeModel(n_components=0.99).fit(shapes)
    >>> model.n_components_, model.components_.shape
    (1, (1, 600))
    >>> c = model.transform(shapes)  # coefficients in standard deviations
    >>> round(float(c.std(ddof=1)), 6)
    1.0
    """

    def __init__(self, n_components: int | float | None = None, *, procrustes: bool = False) -> None:
        self.n_components = n_components
        self.procrustes = procrustes

    def __repr__(self) -> str:
        args = []
        if self.n_components is not None:
            args.append(f"n_components={self.n_components!r}")
        if self.procrustes:
            args.append(f"procrustes={self.procrustes!r}")
        return f"ShapeModel({', '.join(args)})"

    # ------------------------------------------------------------------ fit

    def fit(self, shapes: Shapes, faces: npt.ArrayLike | None = None, *,
            names: Sequence[str] | None = None) -> "ShapeModel":
        """Build the model from ``N >= 3`` corresponded shapes (eqs. 9-12).

        The ``N x 3n`` matrix ``X`` of eq. 9 is centred, its ``N x N`` Gram
        matrix ``D = X_hat X_hat^T / (N - 1)`` (eq. 10) is decomposed (eq. 11)
        and the modes are ``Phi = X_hat^T U_D`` (eq. 12), normalised. The
        ``3n x 3n`` covariance is never formed, nor is ``X_hat``: the data
        are centred a block of columns at a time, so the memory beyond the
        shapes is that of the modes kept (only ``n_components`` of them are
        formed when it is an integer) and the Gram matrix. One Rayleigh-Ritz step
        (symmetric orthogonalisation of ``Phi`` and an SVD of the small ``N x
        k`` matrix ``X_hat Phi``) then makes the modes orthonormal to rounding
        error and the small variances accurate, which squaring the data in
        eq. 10 alone would not.

        Signs are deterministic: ``+`` is the direction in which the mode grows
        the mean shape about its centroid (so mode 1 at +3 SD is the larger
        fruit when mode 1 is size); a mode orthogonal to growth (cosine below
        1e-6) has its largest-magnitude entry positive (scikit-learn's rule).

        Parameters
        ----------
        shapes : (N, n, 3) array_like of float, or sequence of Mesh
            Corresponded shapes, mm. Meshes must all have the same faces.
        faces : (m, 3) array_like of int, optional
            The shared triangles (needed to save a mesh model, render or write
            meshes). Taken from the meshes when ``shapes`` are meshes.
        names : sequence of str, optional
            One name per shape (stored in the model file).

        Returns
        -------
        ShapeModel
            ``self``, fitted.

        Raises
        ------
        MeshError
            Fewer than 3 shapes, wrong array shape, shapes of different sizes,
            NaN or infinite coordinates, bad faces, or shapes that do not vary.
        ValueError
            ``n_components`` or ``names`` unusable.
        HortishapeError
            ``n_components`` asks for more modes than the data have.
        """
        n_comp = _check_n_components(self.n_components)
        x, mesh_faces = as_shapes(shapes, copy=False)  # only read: Procrustes below aligns a copy
        n_shapes, n_points = x.shape[:2]
        if n_shapes < 3:
            raise MeshError(f"a shape model needs at least 3 training shapes, got {n_shapes}")
        the_faces = _resolve_faces(x[0], faces, mesh_faces)
        the_names = _check_names(names, n_shapes)

        transforms = None
        if self.procrustes:
            gpa = generalized_procrustes(x)
            x, transforms = gpa.aligned, gpa.transforms

        flat = x.reshape(n_shapes, -1)
        mean = flat.mean(axis=0)  # eq. 9
        # an integer asks for that many modes: only they are formed
        max_modes = n_comp if isinstance(n_comp, int) else None
        components, variances, total, projections = _pca(flat, mean, max_modes=max_modes)
        scale2 = float(np.einsum("i,i->", mean, mean)) / mean.size + 1.0
        if total <= 1e-24 * scale2:
            raise MeshError("the training shapes are all the same: there is no variation to model")
        if len(variances) == 0:  # pragma: no cover - total > 0 implies one mode
            raise MeshError("the training shapes do not vary")
        signs = _flip_signs(components, mean.reshape(-1, 3))

        rank = len(variances)
        if n_comp is None:
            k = rank
        elif isinstance(n_comp, float):
            ratio = np.cumsum(variances) / total
            k = min(int(np.searchsorted(ratio, n_comp * (1 - 1e-12), side="left")) + 1, rank)
        else:
            if n_comp > rank:
                raise HortishapeError(
                    f"n_components={n_comp}, but the {n_shapes} training shapes have only {rank} "
                    f"mode{'s' if rank != 1 else ''} of variation (at most N - 1 = {n_shapes - 1})"
                )
            k = n_comp

        self._set_fitted(
            mean=mean.reshape(n_points, 3),
            components=components[:k],
            variances=variances[:k],
            total_variance=total,
            n_samples=n_shapes,
            faces=the_faces,
            names=the_names,
            scores=None,
            procrustes_transforms=transforms,
        )
        self.scores_ = projections[:, :k] * signs[:k] / np.sqrt(self.explained_variance_)
        return self

    def _set_fitted(self, *, mean, components, variances, total_variance, n_samples, faces, names, scores,
                    procrustes_transforms, noise_variance=None) -> None:
        k, d = components.shape
        self.mean_ = np.ascontiguousarray(mean, dtype=np.float64)
        self.components_ = np.ascontiguousarray(components, dtype=np.float64)
        self.explained_variance_ = np.array(variances, dtype=np.float64)
        self._total_variance = float(total_variance)
        self.explained_variance_ratio_ = self.explained_variance_ / self._total_variance
        self.n_components_ = int(k)
        self.n_samples_ = None if n_samples is None else int(n_samples)
        self.singular_values_ = (
            np.sqrt(self.explained_variance_ * (self.n_samples_ - 1)) if self.n_samples_ else None
        )
        if noise_variance is None:
            rest = max(self._total_variance - float(self.explained_variance_.sum()), 0.0)
            noise_variance = rest / (d - k) if d > k else 0.0
        self.noise_variance_ = float(noise_variance)
        self.faces_ = None if faces is None else np.array(faces, dtype=np.int64)
        self.names_ = tuple(names) if names is not None else None
        self.scores_ = None if scores is None else np.array(scores, dtype=np.float64)
        self.procrustes_transforms_ = (
            None if procrustes_transforms is None else np.array(procrustes_transforms, dtype=np.float64)
        )

    # ---------------------------------------------------------- properties

    @property
    def n_points_(self) -> int:
        """Number of points ``n`` of every shape."""
        self._check_fitted()
        return int(self.mean_.shape[0])

    def _check_fitted(self) -> None:
        if not hasattr(self, "components_"):
            raise NotFittedError(
                "this ShapeModel is not fitted yet: call fit(shapes) or ShapeModel.load(path) first"
            )

    def _shapes(self, shapes, name: str = "shapes") -> np.ndarray:
        x, _ = as_shapes(shapes, name=name, allow_single=True)
        if x.shape[1] != self.n_points_:
            raise MeshError(
                f"{name} have {x.shape[1]} points, the model has {self.n_points_}: "
                "shapes must be in correspondence with the model"
            )
        return x

    def _coefficients(self, coefficients, *, name: str = "coefficients") -> np.ndarray:
        """``(N, k')`` float64 coefficients, ``k' <= n_components_`` (1-D input: N = 1)."""
        c = np.array(coefficients, dtype=np.float64)
        if c.ndim == 1:
            c = c[None]
        if c.ndim != 2 or c.shape[1] == 0:
            raise ValueError(f"{name} must have shape (N, k) or (k,), got {c.shape}")
        if c.shape[1] > self.n_components_:
            raise ValueError(f"{name} have {c.shape[1]} columns, the model has {self.n_components_} modes")
        if not np.isfinite(c).all():
            raise ValueError(f"{name} contain NaN or infinite values")
        return c

    def _one_instance(self, coefficients) -> np.ndarray:
        """``(k',)`` float64 coefficients of one instance, checked as :meth:`_coefficients` does."""
        c = np.asarray(coefficients, dtype=np.float64)
        if c.ndim != 1:
            raise ValueError(f"coefficients of one instance must have shape (k,), got {c.shape}")
        return self._coefficients(c)[0]

    def _check_mode(self, mode, sd: float) -> None:
        """Raise ``ValueError`` unless ``mode`` indexes a mode and ``sd`` is finite."""
        if isinstance(mode, bool) or not isinstance(mode, (int, np.integer)) or not 0 <= mode < self.n_components_:
            raise ValueError(f"mode must be an integer in [0, {self.n_components_ - 1}], got {mode!r}")
        if not np.isfinite(sd):
            raise ValueError(f"sd must be a finite number, got {sd!r}")

    # ------------------------------------------------------- transform etc.

    def transform(self, shapes: Shapes) -> np.ndarray:
        """Shape coefficients in standard deviations: ``Phi^T (x - x_bar) / sqrt(lambda)``.

        With ``procrustes=True`` every shape is first rigidly aligned onto
        ``mean_`` (least squares over all points).

        Parameters
        ----------
        shapes : (N, n, 3) or (n, 3) array_like of float, Mesh or sequence of Mesh
            Shapes in correspondence with the model (a single shape is ``N = 1``).

        Returns
        -------
        (N, k) float64 ndarray
            Coefficients ``c``; the paper's ``b = c * sqrt(explained_variance_)`` (eq. 13).

        Examples
        --------
        >>> rng = np.random.default_rng(0)
        >>> shapes = rng.normal(size=(6, 10, 3))
        >>> model = ShapeModel().fit(shapes)
        >>> bool(np.allclose(model.inverse_transform(model.transform(shapes)), shapes))
        True
        """
        self._check_fitted()
        x = self._shapes(shapes)
        if self.procrustes:
            w = np.full(x.shape[1], 1.0 / x.shape[1])
            x = apply_transforms(fit_transforms(x, self.mean_, w, False), x)
        b = (x.reshape(len(x), -1) - self.mean_.reshape(-1)) @ self.components_.T
        return b / np.sqrt(self.explained_variance_)

    def inverse_transform(self, coefficients: npt.ArrayLike) -> np.ndarray:
        """Shapes from coefficients: ``x_bar + Phi (c * sqrt(lambda))`` (eq. 13 without ``C``).

        Parameters
        ----------
        coefficients : (N, k') or (k',) array_like of float
            Coefficients in standard deviations of the first ``k' <=
            n_components_`` modes (the others are 0).

        Returns
        -------
        (N, n, 3) float64 ndarray
        """
        self._check_fitted()
        c = self._coefficients(coefficients)
        k = c.shape[1]
        b = c * np.sqrt(self.explained_variance_[:k])
        flat = self.mean_.reshape(-1) + b @ self.components_[:k]
        return flat.reshape(len(c), -1, 3)

    def project(self, shapes: Shapes) -> np.ndarray:
        """The closest model shapes: ``inverse_transform(transform(shapes))``.

        Returns
        -------
        (N, n, 3) float64 ndarray
            In the model's frame (with ``procrustes=True``: aligned onto
            ``mean_``; use :func:`fit_pose_and_shape` to keep a shape's pose).
        """
        return self.inverse_transform(self.transform(shapes))

    def mahalanobis(self, shapes: Shapes) -> np.ndarray:
        """Mahalanobis distance of shapes from the mean within the model, ``|transform(shapes)|``.

        Returns
        -------
        (N,) float64 ndarray
            In standard deviations; the residual outside the model's modes is
            not counted.
        """
        return np.linalg.norm(self.transform(shapes), axis=1)

    def instance(self, coefficients: npt.ArrayLike) -> np.ndarray:
        """One model shape from coefficients (scalismo's ``instance``).

        Parameters
        ----------
        coefficients : (k',) array_like of float
            Standard deviations along the first ``k' <= n_components_`` modes.

        Returns
        -------
        (n, 3) float64 ndarray
        """
        self._check_fitted()
        return self.inverse_transform(self._one_instance(coefficients))[0]

    def mode_shapes(self, mode: int, *, sd: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
        """The mean moved ``-sd`` and ``+sd`` standard deviations along one mode (paper Fig. 7).

        Parameters
        ----------
        mode : int
            Index of the mode, from 0 (the paper's "mode 1").
        sd : float, default: 3.0
            Standard deviations.

        Returns
        -------
        minus, plus : (n, 3) float64 ndarray
        """
        self._check_fitted()
        self._check_mode(mode, sd)
        step = (sd * math.sqrt(self.explained_variance_[mode]) * self.components_[mode]).reshape(-1, 3)
        return self.mean_ - step, self.mean_ + step

    # --------------------------------------------------------------- sampling

    def sample_coefficients(self, n: int, *, modes: int | None = 5, truncate: float | None = 3.0,
                            random_state: RandomState = None) -> np.ndarray:
        """Random coefficients: standard normal, truncated at ``+/- truncate`` (paper 3.2).

        Each coefficient of the first ``modes`` modes is drawn independently
        from the standard normal distribution restricted to ``[-truncate,
        truncate]`` (exactly, by the inverse CDF); the other modes are 0.

        Parameters
        ----------
        n : int
            Number of samples.
        modes : int or None, default: 5
            Leading modes to vary (the paper uses 5); at most ``n_components_``
            are used; None: all.
        truncate : float or None, default: 3.0
            Truncation in standard deviations; None: no truncation.
        random_state : int, Generator, SeedSequence or None, default: None

        Returns
        -------
        (n, k) float64 ndarray, k = ``n_components_``
        """
        self._check_fitted()
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"n must be a non-negative integer, got {n!r}")
        if modes is None:
            m = self.n_components_
        elif isinstance(modes, bool) or not isinstance(modes, (int, np.integer)) or modes < 1:
            raise ValueError(f"modes must be a positive integer or None, got {modes!r}")
        else:
            m = min(int(modes), self.n_components_)
        rng = as_generator(random_state)
        out = np.zeros((int(n), self.n_components_))
        if truncate is None or truncate == math.inf:
            out[:, :m] = rng.standard_normal((int(n), m))
            return out
        if not (isinstance(truncate, (int, float, np.floating, np.integer)) and truncate > 0):
            raise ValueError(f"truncate must be a positive number of standard deviations or None, got {truncate!r}")
        from scipy.special import ndtr, ndtri

        lo = float(ndtr(-float(truncate)))
        u = rng.uniform(lo, 1.0 - lo, size=(int(n), m))
        out[:, :m] = np.clip(ndtri(u), -truncate, truncate)
        return out

    def sample(self, n: int, *, modes: int | None = 5, truncate: float | None = 3.0,
               random_state: RandomState = None) -> np.ndarray:
        """Random shapes of the model (paper section 3.2, Fig. 8).

        Coefficients from :meth:`sample_coefficients` (Gaussian truncated at
        ``+/- truncate`` SD on the first ``modes`` modes), turned into shapes
        by :meth:`inverse_transform`.

        Parameters
        ----------
        n : int
            Number of shapes.
        modes : int or None, default: 5
        truncate : float or None, default: 3.0
        random_state : int, Generator, SeedSequence or None, default: None

        Returns
        -------
        (n, p, 3) float64 ndarray, p = ``n_points_``

        Examples
        --------
        >>> rng = np.random.default_rng(0)
        >>> model = ShapeModel().fit(rng.normal(size=(8, 30, 3)))
        >>> model.sample(4, random_state=1).shape
        (4, 30, 3)
        """
        c = self.sample_coefficients(n, modes=modes, truncate=truncate, random_state=random_state)
        if len(c) == 0:
            return np.empty((0, self.n_points_, 3))
        return self.inverse_transform(c)

    # ------------------------------------------------------------ new models

    def truncate(self, n_components: int) -> "ShapeModel":
        """A new model with only the first ``n_components`` modes (scalismo's ``truncate``).

        The total variance is kept, so ``explained_variance_ratio_`` of the
        kept modes is unchanged and ``noise_variance_`` grows.

        Returns
        -------
        ShapeModel
        """
        self._check_fitted()
        k = n_components
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= self.n_components_:
            raise ValueError(f"n_components must be an integer in [1, {self.n_components_}], got {k!r}")
        new = ShapeModel(n_components=int(k), procrustes=self.procrustes)
        new._set_fitted(
            mean=self.mean_.copy(),
            components=self.components_[:k].copy(),
            variances=self.explained_variance_[:k].copy(),
            total_variance=self._total_variance,
            n_samples=self.n_samples_,
            faces=self.faces_,
            names=self.names_,
            scores=None if self.scores_ is None else self.scores_[:, :k],
            procrustes_transforms=self.procrustes_transforms_,
        )
        return new

    def to_mesh(self, vertices: npt.ArrayLike) -> Mesh:
        """A :class:`Mesh` of ``vertices (n, 3)`` (e.g. an instance) with the model's faces.

        Raises
        ------
        MeshError
            If the model has no faces or ``vertices`` has the wrong shape.
        """
        self._check_fitted()
        if self.faces_ is None:
            raise MeshError("the model has no faces (fit it with faces= or meshes to get surfaces)")
        v = np.asarray(vertices, dtype=np.float64)
        if v.shape != self.mean_.shape:
            raise MeshError(f"vertices must have shape {self.mean_.shape}, got {v.shape}")
        return Mesh(v, self.faces_)

    # ------------------------------------------------------------------ files

    def save(self, path: str | os.PathLike, *, format: str | None = None) -> Path:
        """Write the model to a Statismo v0.9 file (plus ``/hortishape``), HDF5 or HDF5-JSON, atomically.

        Layout (``n`` points, ``m`` triangles, ``k`` modes, ``N`` training shapes):

        * ``/version/majorVersion = 0``, ``/version/minorVersion = 9`` (int32 scalars)
        * ``/representer``: string attributes ``name = "vtkStandardMeshRepresenter"``,
          ``version = "1.0"``, ``datasetType = "POLYGON_MESH"`` (``"POINT_SET"``
          without faces); ``points`` float32 ``(3, n)`` (the mean shape, the
          model's reference), ``cells`` int32 ``(3, m)`` (Statismo writes
          uint32 and reads any integer type; scalismo reads only int32), empty
          groups ``pointData`` and ``cellData``
        * ``/model``: ``mean`` float32 ``(3n,)`` (absolute, interleaved
          coordinates), ``pcaBasis`` float32 ``(3n, k)`` (orthonormal columns),
          ``pcaVariance`` float32 ``(k,)``, ``noiseVariance`` float32 scalar
        * ``/modelinfo``: ``build-time`` (string), ``scores`` float32 ``(k, N)``
          (column ``j``: coefficients of training shape ``j``, in SD);
          ``modelBuilder-0/{builderName, buildTime, dataInfo/URI_<j>, parameters/*}``
        * ``/hortishape``: float64 ``mean (n, 3)``, ``components (k, 3n)``,
          ``explained_variance``, ``total_variance``, ``noise_variance``,
          ``scores (N, k)``, int64 ``faces (m, 3)``, ``names``,
          ``procrustes_transforms (N, 4, 4)``; attributes ``format``,
          ``format_version``, ``hortishape_version``, ``units = "mm"``,
          ``procrustes``, ``n_components`` (JSON), ``build_time``.

        Strings in the Statismo part are fixed-length, null-terminated ASCII,
        as Statismo's ``HDF5Utils`` writes them. The same layout as HDF5-JSON
        (``format="json"``) is what Scalismo 0.92 and later read and write;
        Scalismo tells the two apart by the name, so give such a file a name
        ending in ``.json``. See :mod:`hortishape.statismo`.

        Parameters
        ----------
        path : str or os.PathLike
            Target file (conventionally ``model.h5``); its folder must exist.
        format : {"hdf5", "json"}, optional
            Default: ``"json"`` for a name ending in ``.json``, else ``"hdf5"``.

        Returns
        -------
        pathlib.Path
            ``path``.

        Raises
        ------
        NotFittedError
            If the model is not fitted.
        HortishapeError
            If the file cannot be written.
        """
        self._check_fitted()
        return write_model(self._data(), path, format)

    def _data(self) -> ModelData:
        return ModelData(
            mean=self.mean_,
            components=self.components_,
            variances=self.explained_variance_,
            total_variance=self._total_variance,
            noise_variance=self.noise_variance_,
            n_samples=self.n_samples_,
            faces=self.faces_,
            names=self.names_,
            scores=self.scores_,
            procrustes_transforms=self.procrustes_transforms_,
            n_components=self.n_components,
            procrustes=self.procrustes,
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> "ShapeModel":
        """Read a model file written by :meth:`save`, Statismo or Scalismo: HDF5 or HDF5-JSON (told by its content).

        Files with a ``/hortishape`` group are read from its float64 copies;
        plain Statismo files (0.9 or 0.8 layout, standard mesh or point-set
        representer) from the float32 datasets: ``/model/mean``, ``pcaBasis``,
        ``pcaVariance``, ``noiseVariance``, the representer's ``cells`` as
        faces and ``/modelinfo/scores`` as ``scores_``. Such files do not record
        the total variance of the training shapes; it is taken as
        ``sum(pcaVariance) + noiseVariance * (3n - k)``, on which
        ``explained_variance_ratio_`` is then based.

        Returns
        -------
        ShapeModel
            Fitted.

        Raises
        ------
        HortishapeError
            If the file is missing, neither HDF5 nor HDF5-JSON, or not a usable model file.

        Examples
        --------
        >>> import tempfile
        >>> rng = np.random.default_rng(0)
        >>> model = ShapeModel().fit(rng.normal(size=(5, 12, 3)))
        >>> path = model.save(tempfile.mkdtemp() + "/model.h5")
        >>> bool(np.array_equal(ShapeModel.load(path).components_, model.components_))
        True
        """
        return cls._from_data(read_model(path))

    @classmethod
    def _from_data(cls, data: ModelData) -> "ShapeModel":
        """A fitted model from what a model file holds (:func:`hortishape.statismo.read_model`)."""
        model = cls(n_components=data.n_components, procrustes=data.procrustes)
        model._set_fitted(
            mean=data.mean,
            components=data.components,
            variances=data.variances,
            total_variance=data.total_variance,
            n_samples=data.n_samples,
            faces=data.faces,
            names=data.names,
            scores=data.scores,
            procrustes_transforms=data.procrustes_transforms,
            noise_variance=data.noise_variance,
        )
        return model


# --------------------------------------------------------------------------
# eq. 13: pose and shape of a new instance
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ShapeFit:
    """Result of :func:`fit_pose_and_shape` (eq. 13, ``y = C(x_bar + Phi b)``).

    Attributes
    ----------
    coefficients : (k,) float64 ndarray
        Shape coefficients in standard deviations (0 beyond the fitted modes);
        the paper's ``b = coefficients * sqrt(model.explained_variance_)``.
    pose : (4, 4) float64 ndarray
        Rigid transform ``C`` from the model's frame to the points' frame.
    reconstruction : (n, 3) float64 ndarray
        ``C(x_bar + Phi b)`` in the points' frame (mm).
    residual_mean, residual_max : float
        Mean and largest distance between ``reconstruction`` and the points, mm.
    mahalanobis : float
        ``|coefficients|``, standard deviations.
    n_iter : int
        Levenberg-Marquardt iterations done (0 when the first alternation fits exactly).
    converged : bool
    """

    coefficients: np.ndarray
    pose: np.ndarray
    reconstruction: np.ndarray
    residual_mean: float
    residual_max: float
    mahalanobis: float
    n_iter: int
    converged: bool


def fit_pose_and_shape(
    model: ShapeModel,
    points: npt.ArrayLike | Mesh,
    *,
    modes: int | None = None,
    weights: npt.ArrayLike | None = None,
    max_iter: int = 100,
    tol: float = 1e-10,
) -> ShapeFit:
    """Fit the model's pose and shape to the corresponding points of a new shape (eq. 13).

    Minimises ``sum_j w_j |C(x_bar + Phi b)_j - y_j|^2`` over a rigid ``C``
    and the coefficients ``b`` of the first ``modes`` modes. It starts with
    one alternation of the two exact sub-problems (``C`` by Kabsch for the
    mean, then ``b`` by least squares after moving ``y`` into the model's
    frame with ``C^-1``, then ``C`` again), and then solves for pose and
    shape jointly by Levenberg-Marquardt (rotation increments about the
    current centroid). Alternation alone stalls when a mode resembles a
    rigid motion (a model built without Procrustes from shapes in different
    poses); the joint steps do not.

    Parameters
    ----------
    model : ShapeModel
        A fitted model.
    points : (n, 3) array_like of float or Mesh
        The new shape's points, in correspondence with the model's (e.g. a
        registered reference), in any rigid pose, mm.
    modes : int, optional
        Leading modes to fit (default: all of the model's; 0: pose only).
    weights : (n,) array_like of float, optional
        Non-negative point weights (default: all equal).
    max_iter : int, default: 100
        Maximum Levenberg-Marquardt iterations.
    tol : float, default: 1e-10
        Stop when an iteration lowers the weighted mean squared residual by
        less than this fraction.

    Returns
    -------
    ShapeFit

    Raises
    ------
    NotFittedError
        If ``model`` is not fitted.
    MeshError
        If ``points`` is not ``(n, 3)`` with the model's ``n`` or holds NaN.

    Examples
    --------
    >>> from hortishape.align import apply_transform, rigid_transform, rotation_about
    >>> rng = np.random.default_rng(0)
    >>> model = ShapeModel().fit(rng.normal(size=(10, 40, 3)) + [0.0, 0.0, 5.0])
    >>> truth = model.instance([1.0, -0.5, 0.3])
    >>> pose = rigid_transform(rotation_about([1, 2, 3], 0.8), [10.0, -4.0, 2.0])
    >>> fit = fit_pose_and_shape(model, apply_transform(pose, truth))
    >>> bool(np.allclose(fit.coefficients[:3], [1.0, -0.5, 0.3], atol=1e-6)), fit.residual_max < 1e-6
    (True, True)
    """
    from .align import rotation_about

    if not isinstance(model, ShapeModel):
        raise TypeError(f"model must be a ShapeModel, got {type(model).__name__}")
    model._check_fitted()
    y = model._shapes(points, name="points")
    if len(y) != 1:
        raise MeshError(f"points must be one shape (n, 3), got {len(y)} shapes")
    y = y[0]
    n = len(y)
    if modes is None:
        m = model.n_components_
    elif isinstance(modes, bool) or not isinstance(modes, (int, np.integer)) or not 0 <= modes <= model.n_components_:
        raise ValueError(f"modes must be an integer in [0, {model.n_components_}] or None, got {modes!r}")
    else:
        m = int(modes)
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
        raise ValueError(f"max_iter must be a non-negative integer, got {max_iter!r}")
    if not (np.isfinite(tol) and tol >= 0):
        raise ValueError(f"tol must be a non-negative number, got {tol!r}")
    w = as_weights(weights, n)
    sw = np.sqrt(w)
    mean = model.mean_
    phi = model.components_[:m].reshape(m, n, 3)
    size2 = float(w @ ((y - w @ y) ** 2).sum(axis=1))
    tiny = 1e-26 * max(size2, float(w @ (y**2).sum(axis=1)), 1e-300)

    def kabsch(src: np.ndarray) -> np.ndarray:
        return fit_transforms(src[None], y, w, False)[0]

    def shape_of(b: np.ndarray) -> np.ndarray:
        return mean + np.einsum("k,knd->nd", b, phi) if m else mean

    def error(pose: np.ndarray, shape: np.ndarray) -> float:
        p = shape @ pose[:3, :3].T + pose[:3, 3]
        return float(w @ ((p - y) ** 2).sum(axis=1))

    # one alternation: pose of the mean, shape in the model's frame, pose again
    pose = kabsch(mean)
    b = np.zeros(m)
    if m:
        y_model = (y - pose[:3, 3]) @ pose[:3, :3]
        if weights is None:
            b = np.einsum("knd,nd->k", phi, y_model - mean)
        else:
            a = (phi * sw[None, :, None]).reshape(m, -1)
            b = np.linalg.lstsq(a.T, ((y_model - mean) * sw[:, None]).reshape(-1), rcond=None)[0]
        pose = kabsch(shape_of(b))
    err = error(pose, shape_of(b))

    # Levenberg-Marquardt on (rotation increment, translation, b)
    lam = 1e-3
    converged = err <= tiny
    n_iter = 0
    eye = np.eye(3)
    while not converged and n_iter < max_iter:
        n_iter += 1
        r, t = pose[:3, :3], pose[:3, 3]
        shape = shape_of(b)
        p = shape @ r.T + t
        c = w @ p
        q = p - c
        jac = np.empty((n, 3, 6 + m))
        jac[:, 0, 0:3] = np.column_stack([np.zeros(n), q[:, 2], -q[:, 1]])  # -[q]x
        jac[:, 1, 0:3] = np.column_stack([-q[:, 2], np.zeros(n), q[:, 0]])
        jac[:, 2, 0:3] = np.column_stack([q[:, 1], -q[:, 0], np.zeros(n)])
        jac[:, :, 3:6] = eye
        if m:
            jac[:, :, 6:] = np.einsum("de,kne->ndk", r, phi)
        a = (jac * sw[:, None, None]).reshape(3 * n, 6 + m)
        res = ((p - y) * sw[:, None]).reshape(-1)
        jtj = a.T @ a
        g = a.T @ res
        diag = np.diag(jtj).copy()
        diag[diag <= 0] = 1.0
        improved = False
        for _ in range(30):
            try:
                step = -np.linalg.solve(jtj + lam * np.diag(diag), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            omega, dt, db = step[:3], step[3:6], step[6:]
            angle = float(np.linalg.norm(omega))
            rot = rotation_about(omega, angle) if angle > 0 else eye
            new_pose = np.eye(4)
            new_pose[:3, :3] = rot @ r
            new_pose[:3, 3] = rot @ (t - c) + c + dt
            new_b = b + db
            new_err = error(new_pose, shape_of(new_b))
            if new_err < err:
                improved = True
                break
            lam *= 10.0
        if not improved:
            converged = True  # no descent step left: a minimum to working precision
            break
        decrease = err - new_err
        pose, b, err = new_pose, new_b, new_err
        lam = max(lam / 10.0, 1e-12)
        if err <= tiny or decrease <= tol * (err + decrease):
            converged = True

    shape = shape_of(b)
    rec = shape @ pose[:3, :3].T + pose[:3, 3]
    dist = np.linalg.norm(rec - y, axis=1)
    coefficients = np.zeros(model.n_components_)
    coefficients[:m] = b / np.sqrt(model.explained_variance_[:m])
    return ShapeFit(
        coefficients=coefficients,
        pose=pose,
        reconstruction=rec,
        residual_mean=float(dist.mean()),
        residual_max=float(dist.max()),
        mahalanobis=float(np.linalg.norm(coefficients)),
        n_iter=n_iter,
        converged=bool(converged),
    )


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------


def _check_n_components(n_components):
    if n_components is None:
        return None
    if isinstance(n_components, bool):
        raise ValueError(f"n_components must be an int, a float in (0, 1] or None, got {n_components!r}")
    if isinstance(n_components, (int, np.integer)):
        if n_components < 1:
            raise ValueError(f"n_components must be at least 1, got {n_components}")
        return int(n_components)
    if isinstance(n_components, (float, np.floating)):
        if not 0.0 < n_components <= 1.0:
            raise ValueError(
                f"a float n_components is a fraction of the variance in (0, 1], got {n_components}"
            )
        return float(n_components)
    raise ValueError(f"n_components must be an int, a float in (0, 1] or None, got {n_components!r}")


def _resolve_faces(vertices: np.ndarray, faces, mesh_faces) -> np.ndarray | None:
    if faces is None:
        return mesh_faces
    _, f = check_mesh(vertices, faces, name="faces")
    if mesh_faces is not None and not np.array_equal(f, mesh_faces):
        raise MeshError("faces differ from the faces of the meshes given as shapes")
    return f


def _check_names(names, n: int) -> tuple[str, ...]:
    if names is None:
        return tuple(f"shape_{i:03d}" for i in range(n))
    if isinstance(names, str) or not isinstance(names, Sequence):
        raise ValueError("names must be a sequence of strings, one per shape")
    if len(names) != n:
        raise ValueError(f"got {len(names)} names for {n} shapes")
    return tuple(str(s) for s in names)


def _column_slices(d: int):
    """Slices of ``_BLOCK_COLUMNS`` columns covering ``d``."""
    for j in range(0, d, _BLOCK_COLUMNS):
        yield slice(j, j + _BLOCK_COLUMNS)


def _column_blocks(x: np.ndarray, mean: np.ndarray):
    """``(columns, x[:, columns] - mean[columns])`` for blocks of ``_BLOCK_COLUMNS`` columns.

    The data are centred a block at a time, so that no ``N x 3n`` centred copy
    is ever held: the products below stay exact (no cancellation against a
    large mean) at the cost of one ``N x _BLOCK_COLUMNS`` block.
    """
    for cols in _column_slices(x.shape[1]):
        yield cols, x[:, cols] - mean[cols]


def _pca(x: np.ndarray, mean: np.ndarray, *,
         max_modes: int | None = None) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Modes ``(r, d)``, variances ``(r,)``, total variance and projections ``(N, r)`` of the rows of ``x`` about ``mean``.

    The projections are the centred rows' coordinates along the modes (mm),
    a by-product of the last step: the scores need no further pass over the
    data.

    Eqs. 10-12 without the centred ``N x d`` matrix: the Gram matrix is
    accumulated over column blocks, the modes are formed directly as rows,
    and the Rayleigh-Ritz steps update them a block of columns at a time. The
    memory is the data, the modes kept (``max_modes``, all ``N - 1`` if None)
    and ``O(N^2)``. ``max_modes`` is the number of modes wanted: fewer leave
    the leading ones as they would be with all.
    """
    n, d = x.shape
    gram = np.zeros((n, n))
    for _, xb in _column_blocks(x, mean):
        gram += xb @ xb.T
    gram /= n - 1  # eq. 10, N x N
    total = float(np.trace(gram))
    lam, u = np.linalg.eigh(gram)  # eq. 11 (symmetric: SVD == eigendecomposition)
    lam, u = lam[::-1], u[:, ::-1]
    if lam[0] <= 0:
        return np.zeros((0, d)), np.zeros(0), total, np.zeros((n, 0))
    rank = min(int(np.count_nonzero(lam > _RANK_RTOL * lam[0])), n - 1)
    r = rank if max_modes is None else min(rank, max_modes)
    a = u[:, :r] / np.sqrt((n - 1) * lam[:r])
    phi = np.empty((r, d))  # eq. 12, normalised, one mode per row
    for cols, xb in _column_blocks(x, mean):
        phi[:, cols] = a.T @ xb

    def left_multiply(m: np.ndarray) -> None:
        for cols in _column_slices(d):
            phi[:, cols] = m @ phi[:, cols]

    # Rayleigh-Ritz refinement inside span(phi): an orthonormal basis by
    # symmetric orthogonalisation (phi is already nearly orthonormal, so this
    # is stable and, unlike a Householder QR of the tall matrix, all BLAS-3),
    # then the exact SVD of the data restricted to it (N x r, cheap).
    for _ in range(3):
        g = phi @ phi.T
        if np.abs(g - np.eye(r)).max() < 1e-13:
            break
        w, v = np.linalg.eigh(g)
        left_multiply((v / np.sqrt(w)) @ v.T)
    p = np.zeros((n, r))
    for cols, xb in _column_blocks(x, mean):
        p += xb @ phi[:, cols].T
    u_p, s, vt = np.linalg.svd(p, full_matrices=False)
    lam = s**2 / (n - 1)
    keep = int(np.count_nonzero(lam > _RANK_RTOL * lam[0]))
    left_multiply(vt)  # the modes: vt @ phi, so the rows' projections onto them are p @ vt.T = u_p * s
    return (phi if keep == r else phi[:keep].copy()), lam[:keep], total, (u_p * s)[:, :keep]


def _flip_signs(components: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Deterministic signs, set in place: + grows the mean about its centroid, else largest entry positive.

    Returns the signs applied (one per mode).
    """
    growth = (mean - mean.mean(axis=0)).reshape(-1)
    norm = np.linalg.norm(growth)
    cos = components @ growth / norm if norm > 0 else np.zeros(len(components))
    # the entry of largest magnitude is the row's largest or its smallest
    # (np.abs would copy all the modes); on a tie the first, as argmax of abs
    rows = np.arange(len(components))
    hi, lo = components.argmax(axis=1), components.argmin(axis=1)
    a, b = components[rows, hi], -components[rows, lo]
    big = np.where((a > b) | ((a == b) & (hi < lo)), a, -b)
    sign = np.where(np.abs(cos) >= _GROWTH_COS_MIN, np.sign(cos), np.sign(big))
    sign[sign == 0] = 1.0
    components *= sign[:, None]  # in place: with every mode kept they are as large as the data
    return sign
