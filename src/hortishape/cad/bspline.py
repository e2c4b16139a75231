"""Bicubic B-spline surfaces on the cylinder: periodic in ``u``, clamped in ``v``, closed at both poles."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..errors import HortishapeError
from ..mesh import Mesh
from .parameterize import _grid_faces, grid_map


DEGREE = 3
_JSON_FORMAT = "hortishape-bspline-surface"
_JSON_VERSION = 1


def _knots_v(k: int) -> np.ndarray:
    return np.linspace(0.0, 1.0, k - 2)


def _flat_knots_v(k: int) -> np.ndarray:
    return np.r_[[0.0] * DEGREE, _knots_v(k), [1.0] * DEGREE]


def _basis_u(u: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Periodic uniform cubic basis: ``(n, 4)`` control indices and values."""
    t = np.mod(u, 1.0) * k
    span = np.minimum(np.floor(t).astype(np.int64), k - 1)
    s = t - span
    vals = np.column_stack([(1 - s) ** 3 / 6, (3 * s**3 - 6 * s**2 + 4) / 6, (-3 * s**3 + 3 * s**2 + 3 * s + 1) / 6, s**3 / 6])
    idx = (span[:, None] + np.arange(4)[None, :]) % k
    return idx, vals


def _basis_v(v: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Clamped uniform cubic basis: ``(n, 4)`` control indices and values."""
    from scipy.interpolate import BSpline

    m = BSpline.design_matrix(np.clip(v, 0.0, 1.0), _flat_knots_v(k), DEGREE).tocsr()
    m.sort_indices()
    if m.nnz != 4 * len(v):  # pragma: no cover - scipy stores degree + 1 values per row
        raise RuntimeError("unexpected B-spline design matrix layout")
    return m.indices.reshape(-1, 4).astype(np.int64), m.data.reshape(-1, 4)


@dataclass(frozen=True, eq=False)
class BSplineSurface:
    """A bicubic B-spline surface, periodic in ``u``, clamped in ``v`` (uniform knots).

    With its first and last rows of control points each collapsed to one
    point (as every surface hortishape fits), it is a closed surface: a
    fruit with its bottom at ``v = 0`` and its stalk at ``v = 1``.

    Parameters
    ----------
    control_points : (k_u, k_v, 3) array_like of float
        Control points in mm, ``[i, j]``: ``i`` around (``u``), ``j`` along
        (``v``); ``k_u, k_v >= 4``. Stored read-only.

    Examples
    --------
    >>> k = 6
    >>> angle = 2 * np.pi * np.arange(k) / k
    >>> ring = np.column_stack([np.cos(angle), np.sin(angle), np.zeros(k)])
    >>> cp = np.stack([ring * r + [0, 0, z] for r, z in
    ...                zip([0, 30, 40, 40, 30, 0], [-40, -38, -15, 15, 38, 40])], axis=1)
    >>> s = BSplineSurface(cp)
    >>> s.grid, s.is_closed
    ((6, 6), True)
    >>> s.evaluate([0.3], [1.0]).round(6).tolist()
    [[0.0, 0.0, 40.0]]
    """

    control_points: np.ndarray

    def __post_init__(self) -> None:
        cp = np.array(self.control_points, dtype=np.float64)
        if cp.ndim != 3 or cp.shape[2] != 3 or cp.shape[0] < 4 or cp.shape[1] < 4:
            raise ValueError(f"control_points must have shape (k_u, k_v, 3) with k_u, k_v >= 4, got {cp.shape}")
        if not np.isfinite(cp).all():
            raise ValueError("control_points contain NaN or infinite values")
        cp.flags.writeable = False
        object.__setattr__(self, "control_points", cp)

    @property
    def grid(self) -> tuple[int, int]:
        """``(k_u, k_v)``."""
        return int(self.control_points.shape[0]), int(self.control_points.shape[1])

    @property
    def knots_u(self) -> np.ndarray:
        """Distinct knots in ``u`` (periodic, each of multiplicity 1): ``k_u + 1`` values on [0, 1]."""
        return np.arange(self.grid[0] + 1) / self.grid[0]

    @property
    def knots_v(self) -> np.ndarray:
        """Distinct knots in ``v`` (multiplicity 4 at the ends, 1 inside): ``k_v - 2`` values on [0, 1]."""
        return _knots_v(self.grid[1])

    @property
    def multiplicities_u(self) -> np.ndarray:
        return np.ones(self.grid[0] + 1, dtype=np.int64)

    @property
    def multiplicities_v(self) -> np.ndarray:
        m = np.ones(self.grid[1] - 2, dtype=np.int64)
        m[0] = m[-1] = DEGREE + 1
        return m

    @property
    def is_closed(self) -> bool:
        """True when the first and last rows of control points are each one point (closed at both poles)."""
        cp = self.control_points
        scale = max(float(np.abs(cp).max()), 1.0)
        return bool(np.ptp(cp[:, 0], axis=0).max() <= 1e-9 * scale and np.ptp(cp[:, -1], axis=0).max() <= 1e-9 * scale)

    @property
    def nbytes(self) -> int:
        """Storage of the control points as float64: ``k_u * k_v * 3 * 8`` bytes (the knots are implicit)."""
        return int(self.control_points.size * 8)

    def evaluate(self, u: npt.ArrayLike, v: npt.ArrayLike) -> np.ndarray:
        """Points of the surface at parameters ``(u, v)``.

        Parameters
        ----------
        u, v : (n,) array_like of float
            ``u`` is taken modulo 1, ``v`` clipped to ``[0, 1]``.

        Returns
        -------
        (n, 3) float64 ndarray
        """
        uu = np.atleast_1d(np.asarray(u, dtype=np.float64)).ravel()
        vv = np.atleast_1d(np.asarray(v, dtype=np.float64)).ravel()
        if uu.shape != vv.shape:
            raise ValueError(f"u and v must have the same length, got {uu.size} and {vv.size}")
        ku, kv = self.grid
        iu, wu = _basis_u(uu, ku)
        iv, wv = _basis_v(vv, kv)
        cp = self.control_points
        out = np.zeros((len(uu), 3))
        for a in range(4):
            for b in range(4):
                out += (wu[:, a] * wv[:, b])[:, None] * cp[iu[:, a], iv[:, b]]
        return out

    def tessellate(self, n_u: int | None = None, n_v: int | None = None) -> Mesh:
        """A closed triangle mesh of the surface on a regular ``(u, v)`` grid.

        Vertex layout and exact parameters: :func:`grid_map`. Faces are
        oriented like ``dS/du x dS/dv``.

        Parameters
        ----------
        n_u, n_v : int, optional
            Intervals around and along; default: 16 per knot span, at least 128.

        Returns
        -------
        Mesh
        """
        ku, kv = self.grid
        n_u = max(128, 16 * ku) if n_u is None else n_u
        n_v = max(128, 16 * (kv - 3)) if n_v is None else n_v
        gm = grid_map(n_u, n_v)
        pts = self.evaluate(gm.uv[:, 0], gm.uv[:, 1])
        return Mesh(pts, _grid_faces(int(n_u), int(n_v)))

    def volume(self) -> float:
        """Enclosed volume, mm^3, from a fine tessellation (positive whatever the orientation)."""
        from ..surface import signed_volume

        m = self.tessellate(max(256, 16 * self.grid[0]), max(256, 16 * self.grid[1]))
        return abs(signed_volume(m.vertices, m.faces))

    def transformed(self, matrix: npt.ArrayLike) -> "BSplineSurface":
        """The surface moved by an affine ``(4, 4)`` transform (B-splines are affine-invariant)."""
        t = np.asarray(matrix, dtype=np.float64)
        if t.shape != (4, 4) or not np.isfinite(t).all():
            raise ValueError(f"matrix must be a finite (4, 4) transform, got shape {t.shape}")
        return BSplineSurface(self.control_points @ t[:3, :3].T + t[:3, 3])

    def to_dict(self) -> dict:
        """A JSON-ready description: degrees, knots with multiplicities, control points (mm)."""
        return {
            "format": _JSON_FORMAT,
            "version": _JSON_VERSION,
            "units": "mm",
            "degree": [DEGREE, DEGREE],
            "periodic": [True, False],
            "grid": list(self.grid),
            "knots_u": self.knots_u.tolist(),
            "multiplicities_u": self.multiplicities_u.tolist(),
            "knots_v": self.knots_v.tolist(),
            "multiplicities_v": self.multiplicities_v.tolist(),
            "control_points": self.control_points.tolist(),
            "layout": "control_points[i][j]: i around the fruit (u, periodic), j from bottom (v = 0) to stalk (v = 1)",
        }

    @classmethod
    def from_dict(cls, data: dict, *, name: str = "surface") -> "BSplineSurface":
        """Read :meth:`to_dict`'s description back."""
        if not isinstance(data, dict) or data.get("format") != _JSON_FORMAT:
            raise HortishapeError(f"{name}: not a hortishape B-spline surface (format {_JSON_FORMAT!r} expected)")
        if data.get("version") != _JSON_VERSION:
            raise HortishapeError(f"{name}: unsupported version {data.get('version')!r}")
        try:
            surface = cls(np.asarray(data["control_points"], dtype=np.float64))
        except (KeyError, TypeError, ValueError) as exc:
            raise HortishapeError(f"{name}: bad control points ({exc})") from None
        if list(data.get("degree", [])) != [DEGREE, DEGREE] or list(data.get("periodic", [])) != [True, False]:
            raise HortishapeError(f"{name}: only bicubic surfaces periodic in u and clamped in v are supported")
        if not np.allclose(data.get("knots_u", []), surface.knots_u) or not np.allclose(
            data.get("knots_v", []), surface.knots_v
        ):
            raise HortishapeError(f"{name}: only uniform knots are supported")
        return surface
