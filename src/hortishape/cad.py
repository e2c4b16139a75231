"""CAD description of a shape model: cylindrical parameterization, B-spline surfaces, STEP/IGES.

The paper (section 2.2.4, results in 3.3 and Fig. 9) parameterizes the
*mean* surface of a shape model on a cylinder, so that every vertex has
``(u, v)`` coordinates, and approximates surfaces by B-splines on that
domain. Because all instances of the model are in correspondence with the
mean, they share its ``(u, v)``; the control points of an instance are then
a *linear* function of its coordinates, and so of its shape coefficients
``b``: the fitting operator is computed once and any instance (the mean, a
random sample, mean +/- k SD along a mode, a fitted scan) is a CAD surface
without refitting.

The steps, and how they are done here
-------------------------------------
1. **Poles** (:func:`find_poles`): the stalk and the bottom point, given as
   landmarks or found automatically. The automatic search tries each of the
   three principal axes of the area-weighted surface: the point geodesically
   farthest from the half of the surface below the mid-plane is one end;
   then each pole is taken as the *centre* of the region nearest to being
   farthest from the other pole (the point of that region farthest from its
   edge), twice, so a stalk tip or the middle of a calyx basin is found
   rather than a basin's rim. Of the three pairs, the one farthest apart
   along the surface wins (a stalk and cavities lengthen the fruit's
   meridian, so even a round apple's stalk axis wins). The stalk is the
   thinner end: the one with less surface within a geodesic ball around its
   pole.
2. **Opening and parameterization** (:func:`parameterize`): the faces around
   both poles are removed, which leaves a cylinder (a mesh with two boundary
   loops). The shortest edge path between the loops is the seam. The mesh
   is mapped onto the cylinder ``[0, 1) x [0, 1]`` (``u`` periodic) by a
   periodic Tutte embedding with mean-value weights (Floater 2003): every
   vertex is the weighted mean of its neighbours, ``u`` jumps by 1 across
   the seam, the loops lie on ``v = 0`` and ``v = 1`` spaced by arc length.
   A convex-combination map onto a flat cylinder with straight boundaries is
   one-to-one (Gortler, Gotsman and Thurston 2006), so no triangle flips; the
   result is checked (:attr:`CylinderMap.n_flipped`, and the unrolled disc
   covers the unit square exactly once). The paper builds its map through a
   progressive mesh instead; any bijective low-distortion map serves.
   A harmonic ``v`` crowds a thin stalk: a tube of radius ``r`` and length
   ``L`` takes ``L / (2 pi r)`` of the conformal height, more than half of
   it for an apple's stalk. So ``v`` is then reparameterized monotonically
   (which cannot flip a triangle) to be proportional to the mean
   *meridian arc length*, with the poles' one-rings added at both ends:
   equal steps of ``v`` are equal millimetres along the fruit.
3. **B-spline approximation** (:class:`BSplineFitter`): bicubic, periodic
   in ``u`` (uniform knots), clamped in ``v`` (uniform knots), with a
   ``k x k`` control grid whose first and last rows are each collapsed to
   one point, so the surface closes at both poles. The control points
   minimise the area-weighted squared distance to the triangle surface,
   ``integral |S(u, v) - X(u, v)|^2 dA``, evaluated on a regular grid of
   samples in ``(u, v)`` (8 per knot span; points of the triangle surface
   found by barycentric interpolation), so every knot span has data even
   where the surface is thin. The operator from vertex coordinates to control
   points is linear and is factored once.
4. **Model instances** (:class:`BSplineModel`): the mean's control points
   and one set per mode; an instance's control points are ``P_mean + sum_i
   c_i sqrt(lambda_i) P_i`` (eq. 13 carried over to control points).
5. **Export** (:func:`write_cad`): JSON (control points and knots, no extra
   dependency), STEP and IGES through OpenCascade (``pip install
   'hortishape[cad]'``, imported only when used), as one closed face
   (periodic in ``u``, degenerate at both poles) bounding a solid.
   :func:`read_cad` reads any of the three back, :func:`cad_volume` gives
   the volume of a STEP or IGES solid as OpenCascade computes it.

Conventions: control points are ``(k_u, k_v, 3)`` arrays in millimetres,
index ``[i, j]`` with ``i`` along ``u`` (around the fruit) and ``j`` along
``v`` (``v = 0`` the bottom pole, ``v = 1`` the stalk). Knots are as in
OpenCascade and STEP: distinct values and multiplicities; ``u`` periodic with
``k_u + 1`` knots of multiplicity 1 on ``[0, 1]``; ``v`` with ``k_v - 2``
distinct knots, multiplicity 4 at both ends.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ._rng import RandomState
from .errors import HortishapeError, MeshError, NotFittedError
from .mesh import Mesh, check_mesh, unique_edges
from .surface import face_areas, vertex_areas

if TYPE_CHECKING:  # pragma: no cover
    from .model import ShapeModel

__all__ = [
    "BSplineFitter",
    "BSplineModel",
    "BSplineSurface",
    "CylinderMap",
    "Deviation",
    "Poles",
    "cad_formats",
    "cad_volume",
    "find_poles",
    "grid_map",
    "parameterize",
    "read_cad",
    "render_deviation",
    "surface_deviation",
    "write_cad",
]

DEGREE = 3
_JSON_FORMAT = "hortishape-bspline-surface"
_JSON_VERSION = 1
_CAD_SUFFIXES = {".step": "step", ".stp": "step", ".iges": "iges", ".igs": "iges", ".json": "json"}
_INSTALL_HINT = "pip install 'hortishape[cad]' (the cadquery-ocp-novtk package)"
# pole search: regions within this fraction of the equivalent-sphere radius
_POLE_REGION = 0.15
# stalk test: surface area within this fraction of the radius around each pole
_THIN_REGION = 0.25


# --------------------------------------------------------------------------
# poles
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Poles:
    """The two poles of a fruit surface, as vertex indices.

    Attributes
    ----------
    stalk : int
        Vertex at the stalk end (``v = 1`` of the parameterization).
    bottom : int
        Vertex at the other end (``v = 0``), e.g. the calyx of an apple.
    axis : (3,) float64 ndarray
        Unit vector from the bottom pole to the stalk pole.
    """

    stalk: int
    bottom: int
    axis: np.ndarray


def _edge_graph(v: np.ndarray, f: np.ndarray) -> sp.csr_matrix:
    """Symmetric sparse matrix of edge lengths."""
    e = unique_edges(f)
    w = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    w = np.maximum(w, 1e-12)  # csgraph treats explicit zeros as missing edges
    g = sp.coo_matrix((w, (e[:, 0], e[:, 1])), shape=(len(v), len(v))).tocsr()
    return (g + g.T).tocsr()


def _geodesic(graph: sp.csr_matrix, sources) -> np.ndarray:
    from scipy.sparse.csgraph import dijkstra

    return dijkstra(graph, directed=False, indices=np.atleast_1d(sources), min_only=True)


def _region_centre(graph: sp.csr_matrix, dist: np.ndarray, radius: float) -> int:
    """Centre of the region within ``radius`` of the largest ``dist``: its point farthest from its edge."""
    from scipy.sparse.csgraph import connected_components

    top = int(np.argmax(dist))
    inside = dist >= dist[top] - radius
    idx = np.flatnonzero(inside)
    sub = graph[idx][:, idx]
    _, labels = connected_components(sub, directed=False)
    keep = labels == labels[np.searchsorted(idx, top)]
    idx, sub = idx[keep], sub[keep][:, keep]
    inside = np.zeros(len(dist), dtype=bool)
    inside[idx] = True
    outside_nb = np.asarray(graph[idx][:, ~inside].getnnz(axis=1)).ravel() > 0
    if not outside_nb.any():
        return top
    d = _geodesic(sub, np.flatnonzero(outside_nb))
    return int(idx[np.argmax(d)])


def _nearest_vertex(vertices: np.ndarray, point, name: str) -> int:
    p = np.asarray(point, dtype=np.float64)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise ValueError(f"{name} must be a point (x, y, z) in mm, got {point!r}")
    return int(np.argmin(((vertices - p) ** 2).sum(axis=1)))


def _check_surface(vertices, faces, name: str) -> tuple[np.ndarray, np.ndarray]:
    from .surface import check_closed_surface

    v, f = check_mesh(vertices, faces, name=name)
    check_closed_surface(Mesh(v, f), name=name)
    return v, f


def find_poles(
    vertices: npt.ArrayLike,
    faces: npt.ArrayLike,
    *,
    stalk: npt.ArrayLike | None = None,
    bottom: npt.ArrayLike | None = None,
    axis: npt.ArrayLike | None = None,
) -> Poles:
    """Find the stalk and bottom poles of a closed fruit surface.

    With both landmarks the poles are the vertices nearest to them; with one,
    the other is the centre of the region farthest (geodesically) from it.
    Without landmarks the search is automatic (see the module docstring):
    from each principal axis of the surface, a first end (the point farthest
    from the half below the mid-plane) and two sweeps of "centre of the
    farthest region" give a pair of poles; the pair farthest apart along the
    surface wins, and its thinner end is the stalk.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        A closed, one-component surface (e.g. a model's mean), mm.
    faces : (m, 3) array_like of int
    stalk, bottom : (3,) array_like of float, optional
        Landmarks in the surface's coordinates, mm.
    axis : (3,) array_like of float, optional
        Direction from the bottom towards the stalk, when known (e.g.
        ``(0, 0, 1)`` for fruit scanned standing up). It replaces the
        principal-axis guess and decides which end is the stalk.

    Returns
    -------
    Poles

    Raises
    ------
    MeshError
        If the surface is not closed, has several components, or the poles
        coincide or are neighbours (their one-rings touch).
    ValueError
        If a landmark or the axis is not a finite 3-vector.

    Examples
    --------
    >>> import trimesh
    >>> capsule = trimesh.creation.capsule(height=60.0, radius=20.0, count=[32, 32])
    >>> poles = find_poles(capsule.vertices, capsule.faces, axis=(0, 0, 1))
    >>> capsule.vertices[poles.stalk].round(3).tolist(), capsule.vertices[poles.bottom].round(3).tolist()
    ([0.0, 0.0, 50.0], [0.0, 0.0, -50.0])
    """
    v, f = _check_surface(vertices, faces, "surface")
    graph = _edge_graph(v, f)
    radius = math.sqrt(float(face_areas(v, f).sum()) / (4.0 * math.pi))
    region = _POLE_REGION * radius

    if stalk is not None and bottom is not None:
        s, b = _nearest_vertex(v, stalk, "stalk"), _nearest_vertex(v, bottom, "bottom")
    elif stalk is not None:
        s = _nearest_vertex(v, stalk, "stalk")
        b = _region_centre(graph, _geodesic(graph, s), region)
    elif bottom is not None:
        b = _nearest_vertex(v, bottom, "bottom")
        s = _region_centre(graph, _geodesic(graph, b), region)
    else:
        weights = vertex_areas(v, f)
        centre = weights @ v / weights.sum()
        if axis is None:
            x = v - centre
            candidates = list(np.linalg.eigh((x * weights[:, None]).T @ x / weights.sum())[1].T)
        else:
            candidates = [_unit(axis, "axis")]
        best = None
        for direction in candidates:
            height = (v - centre) @ direction
            below = np.flatnonzero(height <= np.median(height))
            first = int(np.argmax(_geodesic(graph, below)))
            end_b = _region_centre(graph, _geodesic(graph, first), region)
            from_b = _geodesic(graph, end_b)
            end_a = _region_centre(graph, from_b, region)
            if best is None or from_b[end_a] > best[0]:
                best = (from_b[end_a], end_a, end_b, height)
        _, end_a, end_b, height = best
        if axis is not None:
            s, b = (end_a, end_b) if height[end_a] >= height[end_b] else (end_b, end_a)
        else:
            near_a = weights[_geodesic(graph, end_a) <= _THIN_REGION * radius].sum()
            near_b = weights[_geodesic(graph, end_b) <= _THIN_REGION * radius].sum()
            s, b = (end_a, end_b) if near_a <= near_b else (end_b, end_a)

    if s == b:
        raise MeshError("the stalk and bottom poles coincide (the same vertex): give two distinct poles")
    ring_s = set(f[(f == s).any(axis=1)].ravel().tolist())
    ring_b = set(f[(f == b).any(axis=1)].ravel().tolist())
    if ring_s & ring_b:
        raise MeshError(
            f"the stalk and bottom poles (vertices {s} and {b}) are neighbours: the surface cannot be "
            "opened at both; give poles at the two ends of the fruit"
        )
    d = v[s] - v[b]
    return Poles(stalk=int(s), bottom=int(b), axis=d / np.linalg.norm(d))


def _unit(vector, name: str) -> np.ndarray:
    a = np.asarray(vector, dtype=np.float64)
    if a.shape != (3,) or not np.isfinite(a).all() or not np.linalg.norm(a) > 0:
        raise ValueError(f"{name} must be a non-zero 3-vector, got {vector!r}")
    return a / np.linalg.norm(a)


# --------------------------------------------------------------------------
# cylindrical parameterization
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class CylinderMap:
    """A one-to-one map of a closed surface onto the cylinder ``[0, 1) x [0, 1]``.

    The surface is opened at both poles (their one-rings of faces removed)
    and cut along a seam; the resulting disc is the unit square, ``u``
    periodic. The pole vertices map to the whole rows ``v = 0`` (bottom) and
    ``v = 1`` (stalk) and their rings of neighbours to ``v = v_bottom`` and
    ``v = v_stalk``.

    Attributes
    ----------
    uv : (n, 2) float64 ndarray
        ``(u, v)`` of every vertex, ``u`` in ``[0, 1)``, ``v`` in ``[0, 1]``
        (poles: ``u = 0``).
    stalk, bottom : int
        The pole vertices.
    bottom_ring, stalk_ring : (r,) int64 ndarray
        The poles' neighbours, by increasing ``u``.
    seam : (s,) int64 ndarray
        The cut, a vertex path from a bottom-ring vertex to a stalk-ring vertex.
    faces : (m', 3) int64 ndarray
        The opened surface: the faces minus the poles' one-rings.
    disc_faces : (m', 3) int64 ndarray
        The same faces after the cut, as indices into ``disc_vertices``.
    disc_vertices : (n',) int64 ndarray
        Vertex of the surface of each disc vertex (seam vertices twice).
    disc_uv : (n', 2) float64 ndarray
        Unrolled coordinates of the disc vertices: a seam vertex's second copy
        has ``u + 1``; ``u`` is not wrapped, so every disc triangle is a proper
        triangle of the plane.
    """

    uv: np.ndarray
    stalk: int
    bottom: int
    bottom_ring: np.ndarray
    stalk_ring: np.ndarray
    seam: np.ndarray
    faces: np.ndarray
    disc_faces: np.ndarray
    disc_vertices: np.ndarray
    disc_uv: np.ndarray

    @property
    def n_vertices(self) -> int:
        return int(len(self.uv))

    def signed_areas(self) -> np.ndarray:
        """Signed area in ``(u, v)`` of every disc triangle (positive: not flipped)."""
        p = self.disc_uv[self.disc_faces]
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])

    @property
    def n_flipped(self) -> int:
        """Triangles with zero or negative area in ``(u, v)``."""
        return int((self.signed_areas() <= 0).sum())

    @property
    def covered_area(self) -> float:
        """Area the triangles and the two pole caps cover in ``(u, v)``: 1 when the map covers the cylinder once."""
        v_b = float(self.uv[self.bottom_ring, 1].mean())
        v_s = float(self.uv[self.stalk_ring, 1].mean())
        return float(self.signed_areas().sum()) + v_b + (1.0 - v_s)

    def distortion(self, vertices: npt.ArrayLike) -> np.ndarray:
        """Per-triangle conformal distortion ``sigma_max / sigma_min`` (1 = angle-preserving).

        The singular values are those of the Jacobian of the map from each
        triangle (in 3D) to ``(u, v)``, with ``v`` rescaled once, for the
        whole map, so that the median ratio of the gradients of ``u`` and
        ``v`` is 1 (a cylinder's circumference and height are unrelated).

        Parameters
        ----------
        vertices : (n, 3) array_like of float
            The surface's vertices, mm.

        Returns
        -------
        (m',) float64 ndarray
            One value per disc triangle.
        """
        x = np.asarray(vertices, dtype=np.float64)[self.disc_vertices]
        f = self.disc_faces
        p = self.disc_uv[f]
        e1, e2 = x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]
        # orthonormal frame of each 3D triangle
        t1 = e1 / np.linalg.norm(e1, axis=1)[:, None]
        nrm = np.cross(e1, e2)
        t2 = np.cross(nrm / np.linalg.norm(nrm, axis=1)[:, None], t1)
        q = np.stack([np.stack([np.einsum("ij,ij->i", e, t1), np.einsum("ij,ij->i", e, t2)], 1) for e in (e1, e2)], 2)
        d = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], 2)  # (m, 2, 2) columns: edges in uv
        jac = d @ np.linalg.inv(q)  # 3D frame -> uv
        ratio_uv = np.median(np.linalg.norm(jac[:, 0, :], axis=1) / np.linalg.norm(jac[:, 1, :], axis=1))
        jac = jac * np.array([1.0, ratio_uv])[None, :, None]
        s = np.linalg.svd(jac, compute_uv=False)
        return s[:, 0] / s[:, 1]


def _mean_value_laplacian(x: np.ndarray, f: np.ndarray) -> sp.csr_matrix:
    """Rows ``sum_j w_ij (x_j - x_i)`` with Floater's mean-value weights ``w_ij = (tan(a/2) + tan(b/2)) / |e_ij|``."""
    n = len(x)
    rows, cols, vals = [], [], []
    for c in range(3):
        i, j, k = f[:, c], f[:, (c + 1) % 3], f[:, (c + 2) % 3]
        eij, eik = x[j] - x[i], x[k] - x[i]
        lij, lik = np.linalg.norm(eij, axis=1), np.linalg.norm(eik, axis=1)
        cos = np.einsum("ij,ij->i", eij, eik) / (lij * lik)
        half = np.tan(0.5 * np.arccos(np.clip(cos, -1.0, 1.0)))
        rows += [i, i]
        cols += [j, k]
        vals += [half / lij, half / lik]
    w = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    return (w - sp.diags(np.asarray(w.sum(axis=1)).ravel())).tocsr()


def _ring(f: np.ndarray, pole: int) -> np.ndarray:
    r = np.unique(f[(f == pole).any(axis=1)])
    return r[r != pole]


def _seam_flags(faces: np.ndarray, path: np.ndarray, n: int) -> np.ndarray:
    """(m, 3) bool: face edge ``(c, c+1)`` lies on the path."""
    a, b = np.minimum(path[:-1], path[1:]), np.maximum(path[:-1], path[1:])
    keys = np.sort(a * n + b)
    flags = np.zeros(faces.shape, dtype=bool)
    for c in range(3):
        x, y = faces[:, c], faces[:, (c + 1) % 3]
        k = np.minimum(x, y) * n + np.maximum(x, y)
        pos = np.clip(np.searchsorted(keys, k), 0, len(keys) - 1)
        flags[:, c] = keys[pos] == k
    return flags


def _loop_fractions(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length along an open polyline, 0 to 1."""
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]
    return s / s[-1]


def _arclength_v(x: np.ndarray, f: np.ndarray, v: np.ndarray, n_bins: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Mean meridian arc length ``s(v)`` of a harmonic ``v`` on ``[0, 1]``, as a piecewise-linear table.

    By the coarea formula the mean length of the paths across a thin band of
    ``v`` is ``dv * sum(area) / sum(|grad v| area)`` over its triangles.
    """
    e1, e2 = x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]
    nrm = np.cross(e1, e2)
    area2 = np.linalg.norm(nrm, axis=1)
    nh = nrm / area2[:, None]
    dv1, dv2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    grad = (np.cross(nh, e1) * dv2[:, None] - np.cross(nh, e2) * dv1[:, None]) / area2[:, None]
    gnorm = np.linalg.norm(grad, axis=1)
    area = 0.5 * area2
    vm = v[f].mean(axis=1)
    order = np.argsort(vm, kind="stable")
    groups = np.array_split(order, min(n_bins, len(order)))
    edges = [0.0]
    lengths = []
    for g_i, grp in enumerate(groups):
        hi = 1.0 if g_i == len(groups) - 1 else 0.5 * (vm[grp[-1]] + vm[groups[g_i + 1][0]])
        if hi <= edges[-1]:
            continue
        lengths.append((hi - edges[-1]) * area[grp].sum() / max((gnorm[grp] * area[grp]).sum(), 1e-300))
        edges.append(hi)
    if edges[-1] < 1.0:  # pragma: no cover - the last group always ends at 1
        edges.append(1.0)
        lengths.append(lengths[-1] if lengths else 1.0)
    return np.asarray(edges), np.r_[0.0, np.cumsum(lengths)]


def parameterize(
    vertices: npt.ArrayLike,
    faces: npt.ArrayLike,
    *,
    poles: Poles | None = None,
    spacing: str = "arclength",
) -> CylinderMap:
    """Map a closed surface one-to-one onto the cylinder (paper section 2.2.4).

    The surface is opened at its poles and cut along the shortest seam
    between the two holes; ``(u, v)`` solve a periodic Tutte system with
    mean-value weights (``u`` jumps by 1 across the seam; the holes' rims
    are fixed on two circles of the cylinder, spaced by arc length), and
    ``v`` is then made proportional to the mean meridian arc length (see the
    module docstring).

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        A closed, one-component surface, mm (e.g. a model's mean).
    faces : (m, 3) array_like of int
    poles : Poles, optional
        Default: :func:`find_poles` (automatic).
    spacing : {"arclength", "harmonic"}, default: "arclength"
        ``"arclength"``: ``v`` proportional to the mean meridian length
        (equal resolution per millimetre along the fruit); ``"harmonic"``:
        the conformal ``v`` of the Tutte map (which gives a thin stalk most
        of the domain), only rescaled to make room for the pole caps.

    Returns
    -------
    CylinderMap

    Raises
    ------
    MeshError
        If the surface is not closed or not one component, the poles are
        unusable, or the opened surface is not a cylinder.
    ValueError
        If ``spacing`` is unknown.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    >>> cmap = parameterize(s.vertices, s.faces)
    >>> cmap.n_flipped, round(cmap.covered_area, 9)
    (0, 1.0)
    """
    from scipy.sparse.linalg import splu

    if spacing not in ("arclength", "harmonic"):
        raise ValueError(f"spacing must be 'arclength' or 'harmonic', got {spacing!r}")
    v3, f = _check_surface(vertices, faces, "surface")
    n = len(v3)
    if poles is None:
        poles = find_poles(v3, f)
    elif not isinstance(poles, Poles):
        raise TypeError(f"poles must be a Poles (from find_poles), got {type(poles).__name__}")
    s_pole, b_pole = int(poles.stalk), int(poles.bottom)
    if not (0 <= s_pole < n and 0 <= b_pole < n) or s_pole == b_pole:
        raise MeshError(f"poles must be two distinct vertices of the surface, got {s_pole} and {b_pole}")

    # 1. open both poles: drop their one-rings, keep the other vertices
    open_faces = f[~np.isin(f, [s_pole, b_pole]).any(axis=1)]
    ring_b, ring_s = _ring(f, b_pole), _ring(f, s_pole)
    if np.intersect1d(ring_b, ring_s).size:
        raise MeshError("the poles are neighbours: the surface cannot be opened at both")
    used = np.zeros(n, dtype=bool)
    used[open_faces.ravel()] = True
    kept = np.flatnonzero(used)
    if len(kept) != n - 2:
        raise MeshError("opening the surface at its poles isolated vertices: choose other poles")
    index = -np.ones(n, dtype=np.int64)
    index[kept] = np.arange(len(kept))
    x, fo = v3[kept], index[open_faces]
    rb, rs = index[ring_b], index[ring_s]
    n_edges = len(unique_edges(fo))
    if len(x) - n_edges + len(fo) != 0:
        raise MeshError(
            "the surface opened at its poles is not a cylinder (it has handles or holes): "
            "a fruit surface must be a sphere topologically"
        )

    # 2. seam: shortest edge path from the bottom rim to the stalk rim
    from scipy.sparse.csgraph import dijkstra

    graph = _edge_graph(x, fo)
    dist, pred, _ = dijkstra(graph, directed=False, indices=rb, min_only=True, return_predecessors=True)
    end = int(rs[np.argmin(dist[rs])])
    if not np.isfinite(dist[end]):  # pragma: no cover - the surface is connected
        raise MeshError("the two poles are not connected on the surface")
    in_rb = np.zeros(len(x), dtype=bool)
    in_rb[rb] = True
    path = [end]
    while not in_rb[path[-1]]:
        path.append(int(pred[path[-1]]))
    path = np.asarray(path[::-1], dtype=np.int64)

    # 3. cut along the seam: a disc; find its boundary in face orientation
    import igl

    dv, df, dmap = igl.cut_mesh(x, fo, _seam_flags(fo, path, len(x)))
    dmap = np.asarray(dmap, dtype=np.int64)
    df = np.asarray(df, dtype=np.int64)
    n_disc = len(dv)
    loop = np.asarray(igl.boundary_loop(df), dtype=np.int64)
    if len(loop) != len(rb) + len(rs) + 2 * len(path) - 2:
        raise MeshError("cutting the opened surface along its seam did not give a disc")
    nd = n_disc
    directed = np.sort(np.concatenate([df[:, c] * nd + df[:, (c + 1) % 3] for c in range(3)]))
    k01 = loop[0] * nd + loop[1]
    if directed[min(np.searchsorted(directed, k01), len(directed) - 1)] != k01:
        loop = loop[::-1]
    orig = dmap[loop]
    is_b, is_s = np.isin(orig, rb), np.isin(orig, rs)
    start = int(np.flatnonzero(is_b & ~np.roll(is_b, 1))[0])
    loop, is_b, is_s = np.roll(loop, -start), np.roll(is_b, -start), np.roll(is_s, -start)
    nb = int(np.flatnonzero(~is_b)[0])
    s0 = int(np.flatnonzero(is_s)[0])
    s1 = s0 + int(np.argmin(is_s[s0:])) if not is_s[s0:].all() else len(loop)
    b_seg, s_seg = loop[:nb], loop[s0:s1]
    if len(b_seg) != len(rb) + 1 or len(s_seg) != len(rs) + 1:
        raise MeshError("the seam does not join the two pole rims: cannot parameterize")

    # 4. periodic Tutte system: u_copy = u_vertex + offset, offset 1 on the seam's right side
    offset = np.zeros(n_disc)
    offset[loop[nb - 1 : s0 + 1]] = 1.0
    u_fixed = np.zeros(len(x))
    u_fixed[dmap[b_seg]] = _loop_fractions(dv[b_seg]) - offset[b_seg]
    u_fixed[dmap[s_seg]] = 1.0 - _loop_fractions(dv[s_seg]) - offset[s_seg]
    v_fixed = np.zeros(len(x))
    v_fixed[rs] = 1.0
    lap = _mean_value_laplacian(dv, df)
    p = sp.csr_matrix((np.ones(n_disc), (np.arange(n_disc), dmap)), shape=(n_disc, len(x)))
    a = (p.T @ lap @ p).tocsr()
    jump = p.T @ (lap @ offset)
    fixed = np.zeros(len(x), dtype=bool)
    fixed[rb] = fixed[rs] = True
    free, fix = np.flatnonzero(~fixed), np.flatnonzero(fixed)
    a_ff, a_fb = a[free][:, free].tocsc(), a[free][:, fix]
    try:
        lu = splu(a_ff)
    except RuntimeError as exc:  # pragma: no cover - the Tutte matrix is an M-matrix
        raise MeshError(f"the parameterization system is singular ({exc})") from None
    u = u_fixed.copy()
    v = v_fixed.copy()
    u[free] = lu.solve(-(a_fb @ u_fixed[fix]) - jump[free])
    v[free] = lu.solve(-(a_fb @ v_fixed[fix]))

    # 5. v spacing, with the pole caps: the rims sit at the mean distance of the poles
    rad_b = float(np.linalg.norm(v3[ring_b] - v3[b_pole], axis=1).mean())
    rad_s = float(np.linalg.norm(v3[ring_s] - v3[s_pole], axis=1).mean())
    edges, length = _arclength_v(x, fo, v)
    total = rad_b + length[-1] + rad_s
    if spacing == "arclength":
        v = (rad_b + np.interp(v, edges, length)) / total
    else:
        v = (rad_b + v * length[-1]) / total
    v[rb] = rad_b / total
    v[rs] = 1.0 - rad_s / total

    uv = np.zeros((n, 2))
    uv[kept, 0] = np.mod(u, 1.0)
    uv[kept, 1] = v
    uv[b_pole] = (0.0, 0.0)
    uv[s_pole] = (0.0, 1.0)
    disc_uv = np.column_stack([u[dmap] + offset, v[dmap]])
    return CylinderMap(
        uv=uv,
        stalk=s_pole,
        bottom=b_pole,
        bottom_ring=ring_b[np.argsort(uv[ring_b, 0], kind="stable")],
        stalk_ring=ring_s[np.argsort(uv[ring_s, 0], kind="stable")],
        seam=kept[path],
        faces=open_faces,
        disc_faces=df,
        disc_vertices=kept[dmap],
        disc_uv=disc_uv,
    )


def grid_map(n_u: int, n_v: int) -> CylinderMap:
    """The exact parameterization of :meth:`BSplineSurface.tessellate`'s grid meshes.

    Vertex 0 is the bottom pole, vertex 1 the stalk pole, and vertex ``2 +
    i * (n_v - 1) + (j - 1)`` lies at ``(u, v) = (i / n_u, j / n_v)``.

    Parameters
    ----------
    n_u, n_v : int
        Intervals around (``>= 3``) and along (``>= 2``) the cylinder.

    Returns
    -------
    CylinderMap

    Examples
    --------
    >>> grid_map(8, 4).n_vertices, grid_map(8, 4).n_flipped
    (26, 0)
    """
    if isinstance(n_u, bool) or not isinstance(n_u, (int, np.integer)) or n_u < 3:
        raise ValueError(f"n_u must be an integer >= 3, got {n_u!r}")
    if isinstance(n_v, bool) or not isinstance(n_v, (int, np.integer)) or n_v < 2:
        raise ValueError(f"n_v must be an integer >= 2, got {n_v!r}")
    n_u, n_v = int(n_u), int(n_v)
    rows = n_v - 1
    ids = 2 + np.arange(n_u * rows).reshape(n_u, rows)
    uv = np.zeros((2 + n_u * rows, 2))
    uv[1] = (0.0, 1.0)
    uu, vv = np.meshgrid(np.arange(n_u) / n_u, np.arange(1, n_v) / n_v, indexing="ij")
    uv[2:, 0], uv[2:, 1] = uu.ravel(), vv.ravel()
    # disc: the grid with column 0 repeated as column n_u
    disc_ids = np.arange((n_u + 1) * rows).reshape(n_u + 1, rows)
    disc_vertices = np.concatenate([ids.ravel(), ids[0]])
    du, dvv = np.meshgrid(np.arange(n_u + 1) / n_u, np.arange(1, n_v) / n_v, indexing="ij")
    disc_uv = np.column_stack([du.ravel(), dvv.ravel()])
    a, b = disc_ids[:-1, :-1].ravel(), disc_ids[1:, :-1].ravel()
    c, d = disc_ids[1:, 1:].ravel(), disc_ids[:-1, 1:].ravel()
    disc_faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return CylinderMap(
        uv=uv,
        stalk=1,
        bottom=0,
        bottom_ring=ids[:, 0].copy(),
        stalk_ring=ids[:, -1].copy(),
        seam=ids[0].copy(),
        faces=disc_vertices[disc_faces],
        disc_faces=disc_faces,
        disc_vertices=disc_vertices,
        disc_uv=disc_uv,
    )


def _grid_faces(n_u: int, n_v: int) -> np.ndarray:
    """Faces of the closed grid mesh of :func:`grid_map` (outward when u x v is outward)."""
    rows = n_v - 1
    ids = 2 + np.arange(n_u * rows).reshape(n_u, rows)
    nxt = np.roll(ids, -1, axis=0)
    a, b, c, d = ids[:, :-1].ravel(), nxt[:, :-1].ravel(), nxt[:, 1:].ravel(), ids[:, 1:].ravel()
    bottom = np.column_stack([np.zeros(n_u, dtype=np.int64), nxt[:, 0], ids[:, 0]])
    top = np.column_stack([np.ones(n_u, dtype=np.int64), ids[:, -1], nxt[:, -1]])
    return np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d]), bottom, top])


# --------------------------------------------------------------------------
# B-spline surfaces
# --------------------------------------------------------------------------


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
        from .surface import signed_volume

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


# --------------------------------------------------------------------------
# fitting
# --------------------------------------------------------------------------


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
        from .model import ShapeModel

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


# --------------------------------------------------------------------------
# deviation
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Deviation:
    """How far a B-spline approximation is from a triangle surface (paper Fig. 9).

    Attributes
    ----------
    distances : (n,) float64 ndarray
        Distance from each vertex of the triangle surface to the B-spline surface, mm.
    mean, max : float
        Mean and largest of ``distances``, mm.
    back_mean, back_max : float
        Mean and largest distance from points of the B-spline surface (a fine
        tessellation) back to the triangle surface, mm: what the approximation
        adds that the surface does not have.
    """

    distances: np.ndarray
    mean: float
    max: float
    back_mean: float
    back_max: float


def surface_deviation(surface: BSplineSurface, vertices: npt.ArrayLike, faces: npt.ArrayLike) -> Deviation:
    """Distances between a B-spline surface and a triangle surface, both ways.

    The B-spline is tessellated finely (:meth:`BSplineSurface.tessellate`'s
    default, 16 intervals per knot span, at least 128) and distances are
    exact point-to-triangle distances (libigl).

    Parameters
    ----------
    surface : BSplineSurface
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int

    Returns
    -------
    Deviation

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
    >>> fitter = BSplineFitter(grid=16).fit(s.vertices, s.faces)
    >>> d = surface_deviation(fitter.surface(s.vertices), s.vertices, s.faces)
    >>> d.max < 0.1
    True
    """
    import igl

    v, f = check_mesh(vertices, faces, name="surface")
    ku, kv = surface.grid
    tess = surface.tessellate(max(256, 16 * ku), max(256, 16 * (kv - 3)))
    d2, _, _ = igl.point_mesh_squared_distance(v, tess.vertices, tess.faces)
    back2, _, _ = igl.point_mesh_squared_distance(tess.vertices, v, f)
    d, back = np.sqrt(np.maximum(d2, 0.0)), np.sqrt(np.maximum(back2, 0.0))
    return Deviation(d, float(d.mean()), float(d.max()), float(back.mean()), float(back.max()))


def render_deviation(
    surface: BSplineSurface,
    vertices: npt.ArrayLike,
    faces: npt.ArrayLike,
    path: str | os.PathLike,
    *,
    views=("front", "top"),
    clim: tuple[float, float] | None = None,
    title: str | None = None,
    cell_size: tuple[int, int] = (420, 400),
    backend: str = "auto",
) -> Path:
    """Picture of a B-spline approximation coloured by its distance to the triangle surface (Fig. 9).

    The B-spline surface is tessellated (8 intervals per knot span, at least
    96) and each of its points is coloured by its distance to the triangle
    surface, in mm, with a colour bar; one panel per view, all at the same
    scale (:func:`hortishape.render.render_grid`).

    Parameters
    ----------
    surface : BSplineSurface
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int
        The triangle surface the B-spline approximates, mm.
    path : str or os.PathLike
        Output ``.png``, written atomically.
    views : sequence of str or (float, float), default: ("front", "top")
    clim : (float, float), optional
        Colour range in mm; default: 0 to the largest distance.
    title : str, optional
        Drawn above every panel.
    cell_size : (int, int), default: (420, 400)
    backend : {"auto", "vtk", "matplotlib"}, default: "auto"

    Returns
    -------
    pathlib.Path
    """
    import igl

    from .render import render_grid

    v, f = check_mesh(vertices, faces, name="surface")
    ku, kv = surface.grid
    tess = surface.tessellate(max(96, 8 * ku), max(96, 8 * (kv - 3)))
    d2, _, _ = igl.point_mesh_squared_distance(tess.vertices, v, f)
    d = np.sqrt(np.maximum(d2, 0.0))
    if clim is None:
        clim = (0.0, max(float(d.max()), 1e-6))
    return render_grid(
        [tess], path, titles=None if title is None else [title], views=views, scalars=[d], clim=clim,
        cmap="viridis", scalar_bar_title="distance to the triangle surface (mm)", cell_size=cell_size,
        backend=backend,
    )


# --------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------


def cad_formats() -> tuple[str, ...]:
    """File extensions :func:`write_cad` and :func:`read_cad` understand."""
    return tuple(_CAD_SUFFIXES)


def _cad_kind(path: Path) -> str:
    kind = _CAD_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise HortishapeError(
            f"{path}: unknown CAD file extension {path.suffix!r} (use one of {', '.join(_CAD_SUFFIXES)})"
        )
    return kind


def _occ() -> None:
    """Check that OpenCascade's Python bindings can be imported, or explain how to install them."""
    import importlib

    try:
        for name in ("BRep", "BRepBuilderAPI", "BRepGProp", "BRepLib", "Geom", "GProp", "IGESControl",
                     "STEPControl", "TopAbs", "TopExp", "TopoDS"):
            importlib.import_module(f"OCP.{name}")
    except ImportError as exc:
        raise HortishapeError(
            f"STEP and IGES need OpenCascade's Python bindings (OCP), which are not installed: {_INSTALL_HINT} "
            f"({exc})"
        ) from None


@contextlib.contextmanager
def _quiet_stdout():
    """Silence what OpenCascade's C++ code prints on file descriptor 1 (the writers' statistics)."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError, AttributeError):  # pragma: no cover - no real stdout
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(null)


def _occ_surface(surface: BSplineSurface):
    from OCP.collections import Array1_double, Array1_int, Array2_gp_Pnt
    from OCP.Geom import Geom_BSplineSurface
    from OCP.gp import gp_Pnt

    ku, kv = surface.grid
    poles = Array2_gp_Pnt(1, ku, 1, kv)
    cp = surface.control_points
    for i in range(ku):
        for j in range(kv):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*map(float, cp[i, j])))

    def array(values, kind):
        a = kind(1, len(values))
        for i, x in enumerate(values):
            a.SetValue(i + 1, x)
        return a

    return Geom_BSplineSurface(
        poles,
        array([float(x) for x in surface.knots_u], Array1_double),
        array([float(x) for x in surface.knots_v], Array1_double),
        array([int(x) for x in surface.multiplicities_u], Array1_int),
        array([int(x) for x in surface.multiplicities_v], Array1_int),
        DEGREE,
        DEGREE,
        True,
        False,
    )


def _occ_shape(surface: BSplineSurface):
    """A solid bounded by the closed face, or the face alone when the surface is not closed."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeSolid
    from OCP.BRepLib import BRepLib
    from OCP.TopoDS import TopoDS_Shell

    face = BRepBuilderAPI_MakeFace(_occ_surface(surface), 1e-7).Face()
    if not surface.is_closed:
        return face
    builder = BRep_Builder()
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    builder.Add(shell, face)
    shell.Closed(True)
    solid = BRepBuilderAPI_MakeSolid(shell).Solid()
    BRepLib.OrientClosedSolid_s(solid)
    return solid


def write_cad(path: str | os.PathLike, surface: BSplineSurface) -> Path:
    """Write a B-spline surface as STEP, IGES or JSON (by extension), atomically.

    STEP (``.step``, ``.stp``; AP214, millimetres) holds a solid bounded by
    the one closed face (a manifold solid B-rep); IGES (``.iges``, ``.igs``;
    millimetres) holds the face (rational B-spline surface entity 128).
    Both go through OpenCascade (``pip install 'hortishape[cad]'``). JSON
    holds :meth:`BSplineSurface.to_dict`. A surface that is not closed at its
    poles is written as a face in STEP too.

    Parameters
    ----------
    path : str or os.PathLike
    surface : BSplineSurface

    Returns
    -------
    pathlib.Path

    Raises
    ------
    HortishapeError
        Unknown extension, OpenCascade missing, or the writer failed.

    Examples
    --------
    >>> import tempfile
    >>> cp = np.zeros((4, 4, 3))
    >>> cp[..., 2] = [-30.0, -20.0, 20.0, 30.0]
    >>> cp[:, 1:3, :2] = 30.0 * np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])[:, None]
    >>> path = write_cad(tempfile.mkdtemp() + "/egg.json", BSplineSurface(cp))
    >>> bool(np.array_equal(read_cad(path).control_points, cp))
    True
    """
    from .io import atomic_path

    target = Path(path)
    if not isinstance(surface, BSplineSurface):
        raise TypeError(f"surface must be a BSplineSurface, got {type(surface).__name__}")
    kind = _cad_kind(target)
    if kind == "json":
        with atomic_path(target, HortishapeError) as tmp:
            tmp.write_text(json.dumps(surface.to_dict(), indent=1))
        return target
    _occ()
    shape = _occ_shape(surface)
    with atomic_path(target, HortishapeError) as tmp:
        with _quiet_stdout():
            if kind == "step":
                from OCP.Interface import Interface_Static
                from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

                writer = STEPControl_Writer()
                Interface_Static.SetCVal_s("write.step.unit", "MM")
                writer.Transfer(shape, STEPControl_AsIs)
                status = writer.Write(str(tmp))
            else:
                from OCP.IGESControl import IGESControl_Controller, IGESControl_Writer

                IGESControl_Controller.Init_s()
                writer = IGESControl_Writer("MM", 0)
                writer.AddShape(shape)
                writer.ComputeModel()
                status = writer.Write(str(tmp))
        ok = status if isinstance(status, bool) else int(status) == 1  # IFSelect_RetDone
        if not ok:
            raise HortishapeError(f"{target}: OpenCascade could not write the {kind.upper()} file ({status})")
    return target


def _read_occ_shape(path: Path, kind: str):
    _occ()
    with _quiet_stdout():
        if kind == "step":
            from OCP.STEPControl import STEPControl_Reader

            reader = STEPControl_Reader()
        else:
            from OCP.IGESControl import IGESControl_Reader

            reader = IGESControl_Reader()
        status = reader.ReadFile(str(path))
        if int(status) != 1:
            raise HortishapeError(f"{path}: OpenCascade cannot read this {kind.upper()} file ({status})")
        reader.TransferRoots()
        shape = reader.OneShape()
    if shape.IsNull():
        raise HortishapeError(f"{path}: the {kind.upper()} file holds no shape")
    return shape


def _faces(shape) -> list:
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    out = []
    explorer = TopExp_Explorer(shape, TopAbs_FACE)
    while explorer.More():
        out.append(TopoDS.Face(explorer.Current()))
        explorer.Next()
    return out


def _surface_from_occ(face, path: Path) -> BSplineSurface:
    from OCP.BRep import BRep_Tool
    from OCP.Geom import Geom_BSplineSurface

    geom = BRep_Tool.Surface_s(face)
    if not isinstance(geom, Geom_BSplineSurface):
        geom = Geom_BSplineSurface.DownCast(geom) if hasattr(Geom_BSplineSurface, "DownCast") else None
    if geom is None:
        raise HortishapeError(f"{path}: the face is not a B-spline surface")
    if geom.UDegree() != DEGREE or geom.VDegree() != DEGREE or geom.IsVPeriodic():
        raise HortishapeError(f"{path}: not a bicubic surface periodic in u only")
    ku, kv = geom.NbUPoles(), geom.NbVPoles()
    cp = np.array([[[geom.Pole(i, j).X(), geom.Pole(i, j).Y(), geom.Pole(i, j).Z()]
                    for j in range(1, kv + 1)] for i in range(1, ku + 1)])
    uk = np.array([geom.UKnot(i) for i in range(1, geom.NbUKnots() + 1)])
    vk = np.array([geom.VKnot(i) for i in range(1, geom.NbVKnots() + 1)])
    if not geom.IsUPeriodic():
        # a periodic surface written unperiodized: the last DEGREE columns repeat the first
        if ku > DEGREE and np.allclose(cp[-DEGREE:], cp[:DEGREE]):
            cp = cp[:-DEGREE]
            ku -= DEGREE
            uk = (uk - uk[DEGREE]) if len(uk) > ku + 1 else uk
        else:
            raise HortishapeError(f"{path}: the surface is not periodic in u")
    uk = uk[(uk >= -1e-12)]
    for name, knots, expected in (("u", uk, np.arange(ku + 1) / ku), ("v", vk, _knots_v(kv))):
        span = knots[-1] - knots[0] if len(knots) > 1 else 1.0
        if len(knots) < len(expected) or not np.allclose((knots[: len(expected)] - knots[0]) / span, expected,
                                                          atol=1e-9):
            raise HortishapeError(f"{path}: knots in {name} are not uniform")
    return BSplineSurface(cp)


def read_cad(path: str | os.PathLike) -> BSplineSurface:
    """Read a B-spline surface from STEP, IGES (through OpenCascade) or hortishape's JSON.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    BSplineSurface
        The first face's surface (files written by :func:`write_cad` hold one).

    Raises
    ------
    HortishapeError
        Missing or unreadable file, no B-spline face, a surface hortishape does
        not write (not bicubic, not periodic in ``u``, non-uniform knots), or
        OpenCascade missing.
    """
    from .io import _check_exists, _check_not_empty

    target = Path(path)
    kind = _cad_kind(target)
    _check_exists(target, HortishapeError)
    _check_not_empty(target, HortishapeError)
    if kind == "json":
        try:
            data = json.loads(target.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise HortishapeError(f"{target}: not a JSON file ({exc})") from None
        return BSplineSurface.from_dict(data, name=str(target))
    faces = _faces(_read_occ_shape(target, kind))
    if not faces:
        raise HortishapeError(f"{target}: the file holds no face")
    return _surface_from_occ(faces[0], target)


def cad_volume(path: str | os.PathLike) -> float:
    """Volume enclosed by the surface of a STEP or IGES file, as OpenCascade computes it (mm^3).

    The file's faces are made into a closed shell and a solid (as a CAD
    program would on import), oriented outward, and its volume integrated
    exactly on the B-spline geometry.

    Raises
    ------
    HortishapeError
        If the file cannot be read or its faces do not close a volume.
    """
    target = Path(path)
    kind = _cad_kind(target)
    if kind == "json":
        raise HortishapeError(f"{target}: cad_volume reads STEP or IGES; for JSON use read_cad(path).volume()")
    from .io import _check_exists

    _check_exists(target, HortishapeError)
    _occ()
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid
    from OCP.BRepGProp import BRepGProp
    from OCP.BRepLib import BRepLib
    from OCP.GProp import GProp_GProps
    from OCP.TopoDS import TopoDS_Shell

    shape = _read_occ_shape(target, kind)
    builder = BRep_Builder()
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    for face in _faces(shape):
        builder.Add(shell, face)
    shell.Closed(True)
    solid = BRepBuilderAPI_MakeSolid(shell).Solid()
    BRepLib.OrientClosedSolid_s(solid)
    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(solid, props)
    volume = float(props.Mass())
    if not volume > 0:
        raise HortishapeError(f"{target}: the faces do not enclose a volume")
    return volume
