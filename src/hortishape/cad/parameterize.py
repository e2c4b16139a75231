"""Cylindrical parameterization: the surface opened at its poles and mapped onto ``[0, 1) x [0, 1]`` (step 2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ..errors import MeshError
from ..mesh import unique_edges
from .poles import Poles, _check_surface, _edge_graph, find_poles


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
