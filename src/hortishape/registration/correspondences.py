"""Correspondences by normal-ray casting with the paper's three filters (section 2.2.2).

From each source (reference) vertex a ray is cast along its normal, in both
directions, onto the target surface. The first target hit in a direction is
the candidate there; it is kept only if

(a) the target's normal at the hit is within ``max_angle`` (30 degrees) of the
    source vertex normal,
(b) it is closer than ``max_distance`` (the registration passes 20 x the
    previous iteration's mean distance; infinite at first), and
(c) the ray crosses neither surface before reaching it. Taking the *first*
    target hit means the ray never crosses the target before it (a farther
    hit behind a rejected first hit is never used); a second ray query
    against the source itself rejects hits behind a fold of the source.

When both directions give a kept hit the nearer one wins. Ray casting uses
Embree (``embreex``) when available.
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..mesh import Mesh
from ..surface import barycentric_interpolate, vertex_normals
from ._embree import PacketScene
from ._embree import library as _embree_library
from .config import CROSSING_MIN_EDGES, RegistrationConfig
from .result import Registration
from .template import _Level, close_scan

__all__ = [
    "CROSSING",
    "DISTANCE",
    "KEPT",
    "NORMAL",
    "NO_HIT",
    "Correspondences",
    "RayScene",
    "TargetSurface",
    "correspond",
    "find_correspondences",
    "prepare_target",
]

#: status codes of :attr:`Correspondences.status`
KEPT, NO_HIT, NORMAL, DISTANCE, CROSSING = 0, 1, 2, 3, 4

#: A ray query is split over threads (up to ``RAY_THREADS``, at most the
#: cores this process may use) when each gets at least this many rays.
#: Embree traces each part without Python's lock, so the parts run at once;
#: the hits are the same as in one query. Fewer rays per thread gain less
#: than starting the threads costs.
RAY_THREAD_MIN = 8192
RAY_THREADS = 4


@functools.lru_cache(maxsize=4)
def _ray_pool(threads: int, pid: int) -> ThreadPoolExecutor:
    """Threads for split ray queries, kept for the process (``pid``: a forked child starts its own).

    Started once rather than for every query: starting them cost a measurable
    part of a fine iteration (docs/design-notes.md).
    """
    return ThreadPoolExecutor(threads, thread_name_prefix="hortishape-rays")


def _ray_threads(n_rays: int) -> int:
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(RAY_THREADS, cores, n_rays // RAY_THREAD_MIN))


class RayScene:
    """First-hit ray queries against a fixed triangle mesh.

    Uses Embree through ``embreex`` (float32 internally; hit points are
    recomputed in float64 from the barycentric coordinates). Where embreex
    has no wheel (macOS, ARM) libigl's AABB tree answers instead, several
    times slower.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int
    few_queries : bool, default: False
        The scene will be queried once or twice: Embree reads the arrays in
        place (``registration/_embree.py``), which builds it several times faster than
        ``embreex`` does but queries on one core. Same hits either way.

    Examples
    --------
    >>> scene = RayScene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> face, t, bary = scene.first_hit([[0.2, 0.2, 1.0]], [[0.0, 0.0, -1.0]])
    >>> face.tolist(), t.round(6).tolist()
    ([0], [1.0])
    """

    def __init__(self, vertices, faces, *, few_queries: bool = False) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        # shift to the centroid so float32 keeps precision far from the origin
        self._shift = self.vertices.mean(axis=0)
        self._packets = None
        if few_queries and _embree_library() is not None:
            scene = PacketScene(self.vertices - self._shift, self.faces)
            if scene.ok:
                self._packets = scene
                self._scene = None
                return
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
        except ImportError:  # pragma: no cover - depends on the platform (tests force it)
            import igl

            self._scene = None
            self._fallback = igl.AABB()
            self._fallback.init(self.vertices, self.faces)
        else:
            self._scene = rtcore_scene.EmbreeScene()
            # indexed geometry builds ~1.6x faster than a triangle soup
            TriangleMesh(
                self._scene,
                np.ascontiguousarray(self.vertices - self._shift, dtype=np.float32),
                np.ascontiguousarray(self.faces, dtype=np.int32),
            )
            # the first query builds the scene's tree: one ray now, so that
            # threads never query a scene still being built
            self._scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), output=1)

    def _run(self, o: np.ndarray, d: np.ndarray, dists) -> dict:
        """Embree's first hits of float32 rays, the rays split over threads when there are many."""
        if self._packets is not None:
            face, u, v = self._packets.hits(o, d, dists)
            return {"primID": face, "u": u, "v": v}
        n = _ray_threads(len(o))
        if n == 1:
            return self._scene.run(o, d, dists=dists, output=1)
        bounds = np.linspace(0, len(o), n + 1).astype(int)

        def part(i: int) -> dict:
            a, b = bounds[i], bounds[i + 1]
            return self._scene.run(o[a:b], d[a:b], dists=None if dists is None else dists[a:b], output=1)

        parts = list(_ray_pool(n, os.getpid()).map(part, range(n)))
        return {key: np.concatenate([p[key] for p in parts]) for key in ("primID", "u", "v")}

    def _igl_first_hit(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """libigl's first hits (its limit is one for all rays: the rays' own apply in :meth:`first_hit`).

        libigl's ray-triangle test is not watertight, as Embree's is: a ray
        through a vertex or along an edge can pass between the triangles that
        share it, and miss or find the surface behind (9 of 2,562 rays from
        the centre of an icosphere through another's vertices). The rays are
        cast from origins moved by ``NUDGE`` of the mesh's size in a direction
        no mesh is built along, and the face found is crossed by the ray
        itself (:func:`_crossing`).
        """
        shift = NUDGE * float(np.ptp(self.vertices, axis=0).max()) * _NUDGE_DIRECTION
        face, _, uv = self._fallback.intersect_ray_first(
            self.vertices, self.faces, np.ascontiguousarray(o + shift), np.ascontiguousarray(d))
        face = face.astype(np.int64)
        bary = np.zeros((len(o), 3))
        hit = face >= 0
        crossing = _crossing(self.vertices[self.faces[face[hit]]], o[hit], d[hit])
        # a ray in the face's plane crosses it nowhere: libigl's own point on it
        along = ~np.isfinite(crossing).all(axis=1)
        crossing[along] = np.column_stack([1.0 - uv[hit, 0] - uv[hit, 1], uv[hit, 0], uv[hit, 1]])[along]
        bary[hit] = crossing
        return face, bary

    def first_hit(self, origins, directions, max_distance=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest hit of each ray.

        Parameters
        ----------
        origins, directions : (k, 3) array_like of float
            Ray origins and unit directions.
        max_distance : (k,) array_like of float, optional
            Ignore hits farther than this along each ray (``inf``: no limit).
            A short limit makes a query cheaper.

        Returns
        -------
        face : (k,) int64 ndarray
            Face hit, -1 for a miss.
        t : (k,) float64 ndarray
            Distance along the ray (``inf`` for a miss).
        barycentric : (k, 3) float64 ndarray
            Barycentric coordinates of the hit in its face (zeros for a miss).
        """
        o = np.asarray(origins, dtype=np.float64)
        d = np.asarray(directions, dtype=np.float64)
        k = len(o)
        if k == 0:
            return np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3))
        if self._scene is not None or self._packets is not None:
            dists = None
            if max_distance is not None:
                lim = np.asarray(max_distance, dtype=np.float64)
                # float32 round-off must never cut a hit at the limit itself
                dists = np.minimum(lim * (1.0 + 1e-5) + 1e-4, 1e30).astype(np.float32)
            res = self._run((o - self._shift).astype(np.float32), d.astype(np.float32), dists)
            face = np.asarray(res["primID"], dtype=np.int64)
            u = np.asarray(res["u"], dtype=np.float64)
            v = np.asarray(res["v"], dtype=np.float64)
            bary = np.stack([1.0 - u - v, u, v], axis=1)
        else:  # pragma: no cover - without embreex (tests force it)
            face, bary = self._igl_first_hit(o, d)
        hit = face >= 0
        if not hit.all():
            bary[~hit] = 0.0
        p = barycentric_interpolate(self.vertices, self.faces, np.maximum(face, 0), bary)
        # distance along the ray, recomputed in float64
        t = np.einsum("kd,kd->k", p - o, d)
        t[~hit] = np.inf
        if max_distance is not None:
            beyond = t > np.asarray(max_distance, dtype=np.float64)
            face[beyond] = -1
            t[beyond] = np.inf
            bary[beyond] = 0.0
        return face, t, bary


#: How far libigl's rays start from their origins, as a share of the mesh's size, so that
#: none runs exactly through a vertex or along an edge of a mesh built on axes or a symmetry
#: (:meth:`RayScene._igl_first_hit`).
NUDGE = 1e-9
_NUDGE_DIRECTION = np.array([0.5377, -0.3089, 0.7845]) / np.linalg.norm([0.5377, -0.3089, 0.7845])


def _crossing(triangles: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(k, 3)`` where rays ``o + t d`` cross the planes of ``triangles``
    ``(k, 3, 3)``, clipped into the triangles: a ray through an edge or a vertex crosses there."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    n = np.cross(b - a, c - a)
    with np.errstate(divide="ignore", invalid="ignore"):  # a ray in the plane: NaN, see the caller
        t = np.einsum("kd,kd->k", a - o, n) / np.einsum("kd,kd->k", d, n)
        p = o + t[:, None] * d
        area = np.einsum("kd,kd->k", n, n)
        u = np.einsum("kd,kd->k", np.cross(c - b, p - b), n) / area
        v = np.einsum("kd,kd->k", np.cross(a - c, p - c), n) / area
        bary = np.clip(np.column_stack([u, v, 1.0 - u - v]), 0.0, None)
        return bary / bary.sum(axis=1, keepdims=True)


@dataclass(frozen=True, eq=False)
class TargetSurface:
    """A target surface prepared for repeated correspondence queries.

    Attributes
    ----------
    mesh : Mesh
        The target surface, its holes closed (:func:`hortishape.surface.fill_holes`).
    normals : (n, 3) float64 ndarray
        Outward unit vertex normals (orientation fixed by the enclosed volume).
    scene : RayScene
        Ray-query structure (built once).
    filled : (m,) bool ndarray or None
        Which faces of ``mesh`` close a hole of the scan (None: it had none).
        A ray that hits one finds no correspondence: the patch is not data.
    n_holes : int
        Holes the scan had.
    hole_share : float
        The patches' share of the closed surface's area.
    patch_data : bool, default: False
        Whether a ray that hits a patch finds its correspondence there, as
        on the scan: the orientation search judges whole surfaces.
    scan_vertices : int or None
        With holes: the first ``scan_vertices`` vertices of ``mesh`` are the
        scan's, the rest the patches'.
    """

    mesh: Mesh
    normals: np.ndarray
    scene: RayScene
    filled: np.ndarray | None = None
    n_holes: int = 0
    hole_share: float = 0.0
    patch_data: bool = False
    scan_vertices: int | None = None


def prepare_target(mesh: Mesh, *, name: str = "target") -> TargetSurface:
    """Check a target surface and build its ray-query structure.

    Parameters
    ----------
    mesh : Mesh
        Single-component surface. Degenerate (zero-area) triangles are
        tolerated (marching cubes makes a few; rays never hit them); inward
        winding is tolerated (normals are flipped to point outward); holes
        are closed by smooth patches (:func:`close_scan`), which the
        orientation search takes for surface and the elastic iterations
        ignore.
    name : str, default: "target"
        Name in error messages.

    Returns
    -------
    TargetSurface

    Raises
    ------
    MeshError
        If the surface is non-manifold, has several components or holes
        over ``MAX_HOLE_SHARE`` of it.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(2, radius=10.0)
    >>> prepare_target(Mesh(s.vertices, s.faces)).normals.shape
    (162, 3)
    """
    sign, closed = close_scan(mesh, name=name)
    m = mesh if closed is None else closed.mesh
    normals = sign * vertex_normals(m.vertices, m.faces)
    normals.flags.writeable = False
    if closed is None:
        return TargetSurface(m, normals, RayScene(m.vertices, m.faces))
    return TargetSurface(m, normals, RayScene(m.vertices, m.faces), closed.filled, closed.n_holes,
                         closed.hole_share, scan_vertices=closed.n_input_vertices)


@dataclass(frozen=True)
class Correspondences:
    """Result of :func:`correspond`: one candidate target point per source vertex.

    Attributes
    ----------
    points : (n, 3) float64 ndarray
        Corresponding target point of each source vertex (the source vertex
        itself where none was kept).
    found : (n,) bool ndarray
        Whether a correspondence was kept (the 0/1 weights of eq. 8).
    distances : (n,) float64 ndarray
        Distance to the kept point (``inf`` where none).
    target_normals : (n, 3) float64 ndarray
        Target normal at the kept point (zeros where none).
    status : (n,) int8 ndarray
        :data:`KEPT`, or why the vertex has none: :data:`NO_HIT` (no ray hits
        the target), :data:`NORMAL` (filter a), :data:`DISTANCE` (filter b),
        :data:`CROSSING` (filter c, the ray crosses the source first). When both
        directions fail, the reason for the nearer hit is given.
    """

    points: np.ndarray
    found: np.ndarray
    distances: np.ndarray
    target_normals: np.ndarray
    status: np.ndarray

    @property
    def kept_fraction(self) -> float:
        """Fraction of source vertices with a kept correspondence."""
        return float(self.found.mean()) if len(self.found) else 0.0

    @property
    def mean_distance(self) -> float:
        """Mean distance over kept correspondences (``inf`` if none)."""
        return float(self.distances[self.found].mean()) if self.found.any() else np.inf


def correspond(
    source: Mesh,
    target: Mesh | TargetSurface,
    *,
    max_angle: float = 30.0,
    max_distance: float = np.inf,
    check_crossings: bool = True,
    source_normals=None,
) -> Correspondences:
    """Normal-ray correspondences from each source vertex to the target (2.2.2).

    Parameters
    ----------
    source : Mesh
        The (deformed) reference surface; its faces wind outward.
    target : Mesh or TargetSurface
        The target; pass a :class:`TargetSurface` (see :func:`prepare_target`)
        to reuse its ray structure across calls.
    max_angle : float, default: 30.0
        Filter (a): largest angle in degrees between the source vertex normal
        and the target normal at the hit.
    max_distance : float, default: inf
        Filter (b): hits at this distance or farther are rejected.
    check_crossings : bool, default: True
        Filter (c) against the source: reject hits behind a crossing of the
        source surface (one more ray query against the source).
    source_normals : (n, 3) array_like of float, optional
        Unit normals of the source vertices (default: area-weighted normals of
        ``source``).

    Returns
    -------
    Correspondences

    Examples
    --------
    >>> import trimesh
    >>> small = trimesh.creation.icosphere(3, radius=10.0)
    >>> big = trimesh.creation.icosphere(4, radius=12.0)
    >>> c = correspond(Mesh(small.vertices, small.faces), Mesh(big.vertices, big.faces))
    >>> bool(c.found.all()), round(float(np.median(c.distances)), 1)
    (True, 2.0)
    """
    tgt = target if isinstance(target, TargetSurface) else prepare_target(target)
    sv = source.vertices
    sn = (
        vertex_normals(sv, source.faces)
        if source_normals is None
        else np.asarray(source_normals, dtype=np.float64)
    )
    return find_correspondences(
        sv,
        source.faces,
        sn,
        tgt,
        max_angle=max_angle,
        max_distance=max_distance,
        check_crossings=check_crossings,
    )


def find_correspondences(
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    target: TargetSurface,
    *,
    max_angle: float = 30.0,
    max_distance: float = np.inf,
    check_crossings: bool = True,
    crossing_min_distance: float = 0.0,
    sources: np.ndarray | None = None,
) -> Correspondences:
    """Array-level core of :func:`correspond` (no input validation; hot path).

    Parameters
    ----------
    vertices : (n, 3) float64 ndarray
        Source vertex positions.
    faces : (m, 3) int64 ndarray
        Source faces (only used by the crossing filter).
    normals : (n, 3) float64 ndarray
        Unit outward source vertex normals.
    target : TargetSurface
    max_angle, max_distance, check_crossings
        As in :func:`correspond`.
    crossing_min_distance : float, default: 0.0
        Filter (c) is skipped when no kept hit is farther than this. A ray
        shorter than the source's local feature size (about half an edge
        length) can cross the source only where it folds back on itself
        within that length; once a registration sits on its target every
        ray is that short, and skipping the test saves building the
        source's ray structure. When some hit is farther, every hit is
        tested (short rays do cross where a surface is crumpled).
    sources : (k,) int ndarray, optional
        Cast rays from these vertices only (``normals`` is still indexed by
        vertex); the correspondences are theirs, in this order. Filter (c)
        tests them against the whole surface.

    Returns
    -------
    Correspondences

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.surface import vertex_normals
    >>> small = trimesh.creation.icosphere(3, radius=10.0)
    >>> big = trimesh.creation.icosphere(4, radius=12.0)
    >>> target = prepare_target(Mesh(big.vertices, big.faces))
    >>> c = find_correspondences(small.vertices, small.faces, vertex_normals(small.vertices, small.faces), target)
    >>> bool(c.found.all()), round(float(np.median(c.distances)), 1)
    (True, 2.0)
    """
    tgt = target
    sv = vertices if sources is None else np.take(vertices, sources, axis=0)
    sn = normals if sources is None else np.take(normals, sources, axis=0)
    n = len(sv)
    cos_max = np.cos(np.radians(max_angle))

    origins = np.concatenate([sv, sv])  # rows [0, n) outward, [n, 2n) inward
    dirs = np.concatenate([sn, -sn])
    src_n2 = np.concatenate([sn, sn])
    t = np.full(2 * n, np.inf)
    tn = np.zeros((2 * n, 3))
    status = np.full(2 * n, NO_HIT, dtype=np.int8)

    def cast(rows, limit=None) -> None:
        """Rays ``rows`` (a slice or indices) against the target, filters (a) and (b)."""
        face, tr, bary = tgt.scene.first_hit(origins[rows], dirs[rows], max_distance=limit)
        hit = face >= 0
        if tgt.filled is not None and not tgt.patch_data:
            # a hole's patch is no data: the ray found nothing (it stops there, as at the scan's hole)
            patch = hit & tgt.filled[np.maximum(face, 0)]
            face = np.where(patch, -1, face)
            hit &= ~patch
        # a hit "behind" the origin by round-off counts as distance 0
        t[rows] = np.where(hit, np.maximum(tr, 0.0), np.inf)
        nn = barycentric_interpolate(tgt.normals, tgt.mesh.faces, np.maximum(face, 0), bary)
        if not hit.all():
            nn[~hit] = 0.0
        nrm = np.linalg.norm(nn, axis=1, keepdims=True)
        tnr = np.divide(nn, nrm, out=np.zeros_like(nn), where=nrm > 0)
        tn[rows] = tnr
        ok_normal = np.einsum("kd,kd->k", tnr, src_n2[rows]) >= cos_max
        ok_dist = t[rows] < max_distance
        status[rows] = np.where(~hit, NO_HIT, np.where(~ok_normal, NORMAL, np.where(~ok_dist, DISTANCE, KEPT)))

    def flag_crossings(scene: RayScene, rows: np.ndarray) -> None:
        """Filter (c): kept hits behind a crossing of the source."""
        cand = rows[status[rows] == KEPT]
        # start a little off the surface so the vertex's own faces are not hit
        eps = 1e-4 * _scale(vertices)
        d = np.take(dirs, cand, axis=0)
        # a source hit counts only before the target's: the rays stop there (a short query is cheaper)
        _, ts, _ = scene.first_hit(np.take(origins, cand, axis=0) + eps * d, d, max_distance=t[cand] - eps)
        status[cand[ts + eps < t[cand] - 1e-9]] = CROSSING

    cast(slice(0, n))
    # an inward ray matters only if it is nearer than a kept outward hit, so
    # it is cast no farther (a short query is cheaper)
    limit = np.where(status[:n] == KEPT, t[:n], np.inf)
    cast(slice(n, 2 * n), limit)
    cand = np.flatnonzero(status == KEPT)
    if check_crossings and len(cand) and t[cand].max() > crossing_min_distance:
        scene = RayScene(vertices, faces, few_queries=True)
        flag_crossings(scene, cand)
        # an outward hit rejected here cut its inward ray short: cast it in full
        redo = np.flatnonzero((status[:n] == CROSSING) & np.isfinite(limit)) + n
        if len(redo):
            cast(redo)
            flag_crossings(scene, redo)
    kept2 = status == KEPT
    t_kept = np.where(kept2, t, np.inf)
    # choose per vertex: the nearer kept direction
    use_in = t_kept[n:] < t_kept[:n]
    pick = np.where(use_in, np.arange(n) + n, np.arange(n))
    found = kept2[pick]
    # status where none kept: the reason of the nearer hit
    nearer = np.where(t[n:] < t[:n], np.arange(n) + n, np.arange(n))
    st = np.where(found, KEPT, status[nearer]).astype(np.int8)
    dist = np.where(found, t[pick], np.inf)
    pts = sv.copy()
    at = pick[found]
    pts[found] = np.take(origins, at, axis=0) + dist[found, None] * np.take(dirs, at, axis=0)
    tnorm = np.where(found[:, None], np.take(tn, pick, axis=0), 0.0)
    return Correspondences(pts, found, dist, tnorm, st)


def _scale(points: np.ndarray) -> float:
    ext = points.max(axis=0) - points.min(axis=0)
    return float(max(np.linalg.norm(ext), 1e-12))


# ----------------------------------------------------------------------------
# as the registration uses them
# ----------------------------------------------------------------------------


def _match(positions, faces, target: TargetSurface, cfg: RegistrationConfig, *,
           max_distance: float = np.inf, check_crossings: bool = False, edge_length: float = 0.0):
    """Normal-ray correspondences of the surface ``(positions, faces)`` on ``target``.

    Filter (c) is skipped if every kept ray is shorter than
    ``CROSSING_MIN_EDGES * edge_length``.
    """
    return find_correspondences(positions, faces, vertex_normals(positions, faces), target,
                                max_angle=cfg.max_angle, max_distance=max_distance,
                                check_crossings=check_crossings,
                                crossing_min_distance=CROSSING_MIN_EDGES * edge_length)


def _max_distance(cfg: RegistrationConfig, prev_distance: float, level: _Level) -> float:
    """Filter (b)'s threshold: ``distance_factor`` times d_(t-1), at least ``distance_floor`` edges."""
    return max(cfg.distance_factor * prev_distance, cfg.distance_floor * level.edge_length)


def _landmark_pairs(reference_landmarks, target_landmarks) -> tuple[np.ndarray, np.ndarray] | None:
    """The landmarks named on both sides, as (k, 3) reference and target points in name order, or None."""
    if reference_landmarks is None and target_landmarks is None:
        return None
    if reference_landmarks is None or target_landmarks is None:
        raise ValueError("give both reference_landmarks and target_landmarks, or neither")
    names = sorted(set(reference_landmarks) & set(target_landmarks))
    if not names:
        raise ValueError(
            f"no landmark is named on both the reference ({', '.join(sorted(reference_landmarks)) or 'none'}) "
            f"and the target ({', '.join(sorted(target_landmarks)) or 'none'})"
        )
    p = np.array([np.asarray(reference_landmarks[n], dtype=np.float64).reshape(3) for n in names])
    q = np.array([np.asarray(target_landmarks[n], dtype=np.float64).reshape(3) for n in names])
    if not (np.isfinite(p).all() and np.isfinite(q).all()):
        raise ValueError("landmarks must be finite points")
    return p, q


def _nearest_vertices(vertices: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Index of the vertex nearest each point."""
    from scipy.spatial import cKDTree

    return cKDTree(vertices).query(points)[1].astype(np.int64)


def _uncovered_fraction(reg: Registration, target: TargetSurface, distance: float, samples: int = 20_000) -> float:
    """Fraction of the target's vertices (up to ``samples``, evenly spread) farther than ``distance`` from every vertex of ``reg``.

    Distances to the nearest registered vertex (a k-d tree, far cheaper
    than the distance to the surface through an AABB tree of the registered
    faces); at twice the edge length the two tell the same places apart.
    """
    return _uncovered(reg, target, distance, samples)[0]


def _uncovered(reg: Registration, target: TargetSurface, distance: float,
               samples: int = 20_000) -> tuple[float, np.ndarray]:
    """:func:`_uncovered_fraction` and the uncovered vertices themselves."""
    from scipy.spatial import cKDTree

    v = target.mesh.vertices[:target.scan_vertices]  # a patch is no scan to cover
    idx = np.linspace(0, len(v) - 1, min(samples, len(v))).astype(np.int64)
    d, _ = cKDTree(reg.vertices).query(v[idx], distance_upper_bound=distance)
    far = np.isinf(d)
    return float(far.mean()), v[idx][far]
