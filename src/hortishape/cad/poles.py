"""Poles: the stalk and the bottom point of a closed surface, given or found (step 1 of :mod:`hortishape.cad`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ..errors import MeshError
from ..mesh import Mesh, check_mesh, unique_edges
from ..surface import face_areas, vertex_areas


# pole search: regions within this fraction of the equivalent-sphere radius
_POLE_REGION = 0.15
# stalk test: surface area within this fraction of the radius around each pole
_THIN_REGION = 0.25


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
    from ..surface import check_closed_surface

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
