"""Rigid alignment: centroids and principal axes (paper eqs. 1-7), candidates, least squares.

The paper's initial alignment (section 2.2.1) moves the reference so that its
centroid and principal axes coincide with the target's. Eq. 7 alone does not
fix the signs of the axes (an eigenvector ``u`` and ``-u`` are equally valid)
nor, for a round fruit whose variances are nearly equal, their order, so it
can turn a fruit upside down or sideways. :func:`candidate_alignments`
therefore lists every proper rotation that maps the reference's principal
axes onto the target's (24 = 6 axis orders x 4 sign choices with determinant
+1); :mod:`hortishape.registration` chooses among them by the quality of a coarse
elastic registration.

That choice does not carry over to fruit the project did not generate: on
real scans the principal axes of a round fruit point anywhere, and a fit
cannot tell one kind of fruit's ends from another's. :func:`fruit_axis`
finds what a fruit has in common with any other instead: the axis it is most
nearly a body of revolution about, and the end of it that carries a cavity
(the stalk's); :func:`axis_alignments` lists the turns about that axis.

Transforms are ``(4, 4)`` homogeneous matrices acting on column vectors:
``p' = T[:3, :3] @ p + T[:3, 3]``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from ._rng import RandomState, as_generator
from .errors import MeshError
from .surface import vertex_areas

__all__ = [
    "FruitAxis",
    "PrincipalAxes",
    "apply_transform",
    "axis_alignments",
    "candidate_alignments",
    "fruit_axis",
    "pca_alignment",
    "principal_axes",
    "rigid_fit",
    "rigid_transform",
    "rotation_about",
    "rotation_angle",
]


@dataclass(frozen=True)
class PrincipalAxes:
    """Centroid and principal axes of a point set (eqs. 1-6).

    Attributes
    ----------
    centroid : (3,) float64 ndarray
        Mean of the points (eq. 1 / eq. 2).
    axes : (3, 3) float64 ndarray
        Unit principal axes as *columns*, by decreasing variance; a proper
        rotation (right-handed). Signs follow a deterministic convention: the
        first two axes point towards the side with the larger third moment
        (the heavier tail) of the points along them.
    variances : (3,) float64 ndarray
        Variance along each axis (eigenvalues of eq. 3 / eq. 4), decreasing.
    """

    centroid: np.ndarray
    axes: np.ndarray
    variances: np.ndarray


def _points(x, name: str) -> np.ndarray:
    p = np.asarray(x, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 4:
        raise MeshError(f"{name} must have shape (n, 3) with n >= 4, got {p.shape}")
    if not np.isfinite(p).all():
        raise MeshError(f"{name} contains NaN or infinite coordinates")
    return p


def principal_axes(vertices, faces=None) -> PrincipalAxes:
    """Centroid, covariance and principal axes of a vertex set or surface (eqs. 1-6).

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Points (mm), n >= 4.
    faces : (m, 3) array_like of int, optional
        Triangles over ``vertices``: the moments are then those of the
        surface (each point of it weighted by area; exact for the centroid
        and covariance, triangle centroids for the third moment that fixes
        the signs) instead of the vertices'. The vertices of a scan's
        marching-cubes surface are denser where the surface runs obliquely
        to the voxel grid, so their principal axes depend on how the fruit
        lay in the scanner (``docs/design-notes.md``).

    Returns
    -------
    PrincipalAxes

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> pts = rng.normal(size=(1000, 3)) * [10.0, 3.0, 1.0]
    >>> pa = principal_axes(pts)
    >>> np.abs(pa.axes[:, 0]).round(1).tolist()
    [1.0, 0.0, 0.0]

    A box surface 4 x 2 x 1: its longest axis comes first, whatever the
    triangulation.

    >>> import trimesh
    >>> box = trimesh.creation.box([4.0, 2.0, 1.0])
    >>> np.abs(principal_axes(box.vertices, box.faces).axes[:, 0]).round(3).tolist()
    [1.0, 0.0, 0.0]
    """
    p = _points(vertices, "vertices")
    if faces is None:
        c = p.mean(axis=0)  # eq. 1 / 2
        x = p - c
        cov = x.T @ x / (len(p) - 1)  # eq. 3 / 4
        pts, weights = x, None
    else:
        f = np.asarray(faces, dtype=np.int64)
        a, b, d = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, d - a), axis=1)
        total = area.sum()
        if not total > 0:
            raise MeshError("the surface has no area")
        c = area @ ((a + b + d) / 3.0) / total
        xa, xb, xd = a - c, b - c, d - c
        # the second moment of a triangle about c: (s s^T + sum x_i x_i^T) / 12
        # per unit area, with s the sum of its corners
        s3 = xa + xb + xd
        cov = (
            np.einsum("k,ki,kj->ij", area, s3, s3)
            + sum(np.einsum("k,ki,kj->ij", area, xi, xi) for xi in (xa, xb, xd))
        ) / (12.0 * total)
        pts, weights = s3 / 3.0, area / total
    w, u = np.linalg.eigh(cov)  # eq. 5 / 6 (symmetric: SVD == eigendecomposition)
    order = np.argsort(w)[::-1]
    w, u = w[order], u[:, order]
    # deterministic signs: the heavier tail of the distribution along an axis
    proj = pts @ u
    skew = np.average(proj**3, axis=0, weights=weights)
    s = np.where(skew < 0, -1.0, 1.0)
    u = u * s
    u[:, 2] = np.cross(u[:, 0], u[:, 1])  # right-handed, so R stays a rotation
    return PrincipalAxes(c, u, w)


def rigid_transform(rotation, translation) -> np.ndarray:
    """Assemble a ``(4, 4)`` transform from a rotation and a translation.

    Examples
    --------
    >>> rigid_transform(np.eye(3), [1.0, 2.0, 3.0])[:3, 3].tolist()
    [1.0, 2.0, 3.0]
    """
    t = np.eye(4)
    t[:3, :3] = np.asarray(rotation, dtype=np.float64)
    t[:3, 3] = np.asarray(translation, dtype=np.float64)
    return t


def apply_transform(transform, points) -> np.ndarray:
    """Apply a ``(4, 4)`` transform to ``(n, 3)`` points (returns a new array).

    Examples
    --------
    >>> apply_transform(rigid_transform(np.eye(3), [1.0, 0, 0]), [[0.0, 0, 0]]).tolist()
    [[1.0, 0.0, 0.0]]
    """
    t = np.asarray(transform, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ t[:3, :3].T + t[:3, 3]


def rotation_about(axis, angle: float) -> np.ndarray:
    """``(3, 3)`` rotation by ``angle`` radians about ``axis`` (Rodrigues).

    Examples
    --------
    >>> rotation_about([0, 0, 1], np.pi / 2).round(6) @ [1, 0, 0]
    array([0., 1., 0.])
    """
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def rotation_angle(rotation) -> float:
    """The angle in degrees of a ``(3, 3)`` rotation matrix (how far it turns about its axis).

    Examples
    --------
    >>> round(rotation_angle(rotation_about([1, 1, 0], np.radians(30))), 6)
    30.0
    """
    r = np.asarray(rotation, dtype=np.float64)
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def pca_alignment(source_vertices, target_vertices, *, source_faces=None, target_faces=None) -> np.ndarray:
    """The paper's initial alignment (eqs. 1-7) with deterministic axis signs.

    Eq. 7 is printed as ``R = U_S U_T^T``; for column vectors the rotation that
    takes the source's axes onto the target's is its transpose,
    ``R = U_T U_S^T``, applied after moving the source centroid to the origin,
    followed by a translation to the target centroid (steps 1-5 of 2.2.1).

    Parameters
    ----------
    source_vertices, target_vertices : (n, 3), (k, 3) array_like of float
    source_faces, target_faces : array_like of int, optional
        Triangles: use the surfaces' moments (see :func:`principal_axes`).

    Returns
    -------
    (4, 4) float64 ndarray
        Transform taking source coordinates to target coordinates.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> src = rng.normal(size=(2000, 3)) * [9.0, 4.0, 1.0] + rng.exponential(size=(2000, 3))
    >>> r = rotation_about([1, 2, 3], 0.7)
    >>> t = pca_alignment(src, src @ r.T + 5.0)
    >>> bool(np.allclose(t[:3, :3], r, atol=1e-6))
    True
    """
    ps = principal_axes(source_vertices, source_faces)
    pt = principal_axes(target_vertices, target_faces)
    r = pt.axes @ ps.axes.T
    return rigid_transform(r, pt.centroid - r @ ps.centroid)


def _signed_permutations() -> list[np.ndarray]:
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            q = np.zeros((3, 3))
            q[np.arange(3), perm] = signs
            if np.linalg.det(q) > 0:
                out.append(q)
    return out


def candidate_alignments(
    source_vertices,
    target_vertices,
    *,
    source_up=None,
    target_up=None,
    n_twists: int = 8,
    source_faces=None,
    target_faces=None,
) -> np.ndarray:
    """Initial rigid alignments to choose among (eq. 7 with all sign/order choices).

    Without hints: the 24 proper rotations ``R = U_T Q U_S^T`` (``Q`` a signed
    permutation with determinant +1), each with the centroid translation of
    eqs. 1-2, ordered so that the ones whose axis *order* agrees with the
    variances come first (the paper's eq. 7 choice is the first).

    With a known-axis hint (both ``source_up`` and ``target_up``, e.g. the
    stalk direction): rotations that map ``source_up`` onto ``target_up``,
    twisted about it by ``n_twists`` equal steps plus the twists that align
    the remaining principal axes (the axis itself is then never flipped).

    Parameters
    ----------
    source_vertices, target_vertices : (n, 3), (k, 3) array_like of float
    source_up, target_up : (3,) array_like of float, optional
        Direction of the same anatomical axis (e.g. towards the stalk) in
        source and target coordinates. Give both or neither.
    n_twists : int, default: 8
        Twist samples about the hinted axis.
    source_faces, target_faces : array_like of int, optional
        Triangles: use the surfaces' moments, which do not depend on how a
        scan's vertices are spread (see :func:`principal_axes`).

    Returns
    -------
    (k, 4, 4) float64 ndarray
        Candidate transforms from source to target coordinates.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> pts = rng.normal(size=(500, 3)) * [5.0, 2.0, 1.0]
    >>> candidate_alignments(pts, pts).shape
    (24, 4, 4)
    """
    ps = principal_axes(source_vertices, source_faces)
    pt = principal_axes(target_vertices, target_faces)
    if (source_up is None) != (target_up is None):
        raise ValueError("give both source_up and target_up, or neither")
    rots: list[np.ndarray] = []
    if source_up is None:
        qs = _signed_permutations()
        # axis-order mismatch of the variances: 0 for the diagonal sign choices
        cost = np.array([np.abs(q.T @ np.diag(pt.variances) @ q - np.diag(ps.variances)).sum() for q in qs])
        # Costs equal in exact arithmetic (the two 3-cycles) differ in their
        # last bits by summation order, which would make their order depend on
        # the machine: ties are decided at a precision far above rounding,
        # then by the fixed order of the signed permutations.
        scale = float(pt.variances.sum() + ps.variances.sum()) or 1.0
        first = np.argsort(np.round(cost / scale, 9), kind="stable")
        for i in first:
            rots.append(pt.axes @ qs[i] @ ps.axes.T)
    else:
        su = np.asarray(source_up, dtype=np.float64)
        tu = np.asarray(target_up, dtype=np.float64)
        su, tu = su / np.linalg.norm(su), tu / np.linalg.norm(tu)
        base = _rotation_between(su, tu)
        # twists that bring the source's principal axis most perpendicular to
        # `up` onto the target's (two signs), then uniform samples
        def perp_axis(pa: PrincipalAxes, up: np.ndarray) -> np.ndarray:
            a = pa.axes.T[np.argmin(np.abs(pa.axes.T @ up))]
            a = a - (a @ up) * up
            return a / np.linalg.norm(a)

        a_s = base @ perp_axis(ps, su)
        a_t = perp_axis(pt, tu)
        ang = np.arctan2(np.cross(a_s, a_t) @ tu, a_s @ a_t)
        angles = [ang, ang + np.pi] + [2 * np.pi * k / n_twists for k in range(n_twists)]
        for a in angles:
            rots.append(rotation_about(tu, a) @ base)
    out = np.empty((len(rots), 4, 4))
    for k, r in enumerate(rots):
        out[k] = rigid_transform(r, pt.centroid - r @ ps.centroid)
    return out


def _axis_frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``axis`` made unit, and two unit vectors across it: a right-handed frame ``(a, p1, p2)``."""
    a = axis / np.linalg.norm(axis)
    p1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    p1 /= np.linalg.norm(p1)
    return a, p1, np.cross(a, p1)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``a`` onto unit vector ``b``."""
    v = np.cross(a, b)
    s, c = np.linalg.norm(v), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # opposite: rotate by pi about any axis perpendicular to a
        perp = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(a, [0.0, 1.0, 0.0])
        return rotation_about(perp, np.pi)
    return rotation_about(v / s, np.arctan2(s, c))


def rigid_fit(source_points, target_points, *, weights=None) -> np.ndarray:
    """Least-squares rigid transform between paired points (Kabsch).

    Minimises ``sum_i w_i |R s_i + t - q_i|^2`` over rotations ``R`` (no
    reflection) and translations ``t``: the paper's "linear least squares
    alignment" on the kept correspondences (section 2.2.2).

    Parameters
    ----------
    source_points, target_points : (k, 3) array_like of float
        Paired points, k >= 3.
    weights : (k,) array_like of float, optional
        Non-negative weights (default: all 1).

    Returns
    -------
    (4, 4) float64 ndarray
        Transform taking source coordinates onto target coordinates.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> s = rng.normal(size=(50, 3))
    >>> r = rotation_about([0, 1, 1], 0.3)
    >>> t = rigid_fit(s, s @ r.T + [1.0, 2.0, 3.0])
    >>> bool(np.allclose(t[:3, :3], r)), t[:3, 3].round(6).tolist()
    (True, [1.0, 2.0, 3.0])
    """
    s = np.asarray(source_points, dtype=np.float64)
    q = np.asarray(target_points, dtype=np.float64)
    if s.shape != q.shape or s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"paired points must both be (k, 3), got {s.shape} and {q.shape}")
    w = np.ones(len(s)) if weights is None else np.asarray(weights, dtype=np.float64)
    if len(s) < 3 or w.sum() <= 0:
        return np.eye(4)
    w = w / w.sum()
    cs, cq = w @ s, w @ q
    h = (s - cs).T @ ((q - cq) * w[:, None])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d if d != 0 else 1.0]) @ u.T
    return rigid_transform(r, cq - r @ cs)


#: Turns of a surface about a trial axis that :func:`fruit_axis` compares
#: with the surface (radians): multiples of 2 pi / 7, which no lobe count
#: from 2 to 6 repeats, so that a 3-, 4- or 5-lobed fruit is not more
#: symmetric about a wrong axis than about its own.
SYMMETRY_TURNS = (2 * np.pi / 7, 4 * np.pi / 7, 6 * np.pi / 7)
#: Half-angle (degrees) of the cone about each end of the axis, seen from the
#: centroid, in which :func:`fruit_axis` looks for a cavity.
END_CONE = 30.0
#: On an elongated fruit (``ELONGATED_VARIANCE``) only the part of each end's
#: cone closer to the axis than this fraction of the cone's surface's median
#: distance from it counts (not the concave side of a bend).
END_RADIUS = 0.5
#: A surface point counts as lying in a cavity when it is this far below the
#: convex hull, in units of the surface's rms radius (2 mm on an 80 mm
#: apple: deeper than scanner noise, shallower than any stalk cavity).
CAVITY_DEPTH = 0.05
#: Vertices (at most) whose convex hull the cavity depths are measured from.
HULL_VERTICES = 5000
#: Surface samples (at most) that the turned surface is compared with.
TREE_POINTS = 20_000
#: The first sweep over trial axes reads distances off a grid of cells this
#: many to the fruit's RMS radius (the few best axes are then compared by
#: exact distances).
GRID_CELLS = 25
#: A cavity that covers less than this fraction of the surface does not make
#: an axis hypothesis of its own.
CAVITY_MIN_AREA = 0.005
#: Degrees between the axis of revolution and the direction to the largest
#: cavity beyond which the latter is kept as a second hypothesis.
AXIS_AGREEMENT = 30.0
#: A fruit whose largest principal variance exceeds this times the mean of
#: the other two (length 1.5 times its widths) is elongated: its axis is
#: its first principal axis, with no second hypothesis.
ELONGATED_VARIANCE = 2.25


@dataclass(frozen=True)
class FruitAxis:
    """A fruit's axis of near revolution and the end of it that has the cavity.

    Attributes
    ----------
    centre : (3,) float64 ndarray
        Centroid of the surface (area-weighted).
    direction : (3,) float64 ndarray
        Unit axis, pointing to the end with more cavity surface (the stalk's,
        on fruit that carry the stalk in a cavity), or, when neither end has
        one, an arbitrary one of the two.
    across : (3,) float64 ndarray
        Unit direction perpendicular to ``direction`` along which the surface
        is widest (its principal axis of largest variance across the axis),
        pointing to the heavier tail (as :func:`principal_axes` signs).
    symmetry : float
        Mean distance of the surface turned about the axis from itself, in
        units of its rms radius (0: a body of revolution).
    cavities : (2,) float64 ndarray
        Fraction of the surface that lies in a cavity (deeper than
        ``CAVITY_DEPTH`` below the convex hull) near the ``direction`` end and
        near the other end.
    contrast : float
        ``(c0 - c1) / (c0 + c1)`` of ``cavities``: 1 when one end alone has a
        cavity, 0 when the ends do not differ (or neither has one).
    alternative : FruitAxis or None
        A second hypothesis, the axis through the largest cavity, when that
        lies more than ``AXIS_AGREEMENT`` degrees from ``direction`` and the
        fruit is not elongated (``ELONGATED_VARIANCE``).
    hidden : (2,) float64 ndarray
        Fraction of the surface near each end (as ``cavities``) that closes a
        hole of the scan (not ``observed``): a cavity there would not be
        seen, so the ends' cavities say less than they seem.
    """

    centre: np.ndarray
    direction: np.ndarray
    across: np.ndarray
    symmetry: float
    cavities: np.ndarray
    contrast: float
    alternative: FruitAxis | None = None
    hidden: np.ndarray = field(default_factory=lambda: np.zeros(2))


def _fibonacci_hemisphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = i / n
    phi = np.pi * (1.0 + np.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _turned(points: np.ndarray, axes: np.ndarray, angles) -> np.ndarray:
    """``points`` turned about each of ``axes`` by each of ``angles``: ``(len(axes), len(angles) * n, 3)``."""
    out = []
    for t in angles:
        # Rodrigues' formula for all axes at once
        c, s = np.cos(t), np.sin(t)
        dot = points @ axes.T  # (n, k)
        cross = np.cross(axes[:, None, :], points[None, :, :])  # (k, n, 3)
        out.append(c * points[None] + s * cross + (1 - c) * dot.T[:, :, None] * axes[:, None, :])
    return np.concatenate(out, axis=1)


class _DistanceGrid:
    """Distances to a point set, capped at ``bound``, on a grid of ``cell``-sized voxels (trilinear between nodes).

    Within about a cell of the exact distance, at a hundredth of the cost of
    a k-d tree query per point once the grid is made.
    """

    def __init__(self, points: np.ndarray, bound: float, cell: float) -> None:
        from scipy.ndimage import distance_transform_edt

        self.origin = points.min(axis=0) - bound - cell
        shape = np.ceil((points.max(axis=0) + bound + cell - self.origin) / cell).astype(int) + 1
        occupied = np.ones(shape, dtype=bool)
        idx = np.rint((points - self.origin) / cell).astype(int)
        occupied[tuple(idx.T)] = False
        self.values = np.minimum(distance_transform_edt(occupied) * cell, bound)
        self.cell, self.bound = cell, bound

    def __call__(self, q: np.ndarray) -> np.ndarray:
        from scipy.ndimage import map_coordinates

        return map_coordinates(self.values, ((q - self.origin) / self.cell).T, order=1, mode="constant",
                               cval=self.bound)


def _hull_depth(vertices: np.ndarray, points: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Distance of each of ``points`` (inside) below the convex hull of ``vertices``."""
    try:
        eq = ConvexHull(vertices).equations
    except QhullError as exc:  # pragma: no cover - a closed surface has a hull
        raise MeshError(f"no convex hull: {exc}") from None
    # the depth is the smallest distance to a facet's plane: a product in
    # homogeneous coordinates, in single precision (a hundred-thousandth of a
    # millimetre on a fruit), in chunks whose products stay in the cache
    # (one product of all points took 20 times longer on fresh memory)
    h = np.hstack([points, np.ones((len(points), 1))]).astype(np.float32)
    e = np.ascontiguousarray(eq.T, dtype=np.float32)
    out = np.empty(len(points))
    for i in range(0, len(points), chunk):
        out[i : i + chunk] = -(h[i : i + chunk] @ e).max(axis=1)
    return out


def fruit_axis(
    vertices,
    faces,
    *,
    n_directions: int = 200,
    n_samples: int = 1000,
    n_end_samples: int = 4000,
    random_state: RandomState = 0,
    observed=None,
) -> FruitAxis:
    """The axis a fruit is most nearly a body of revolution about, and its cavity end.

    A fruit much longer than wide (``ELONGATED_VARIANCE``) has its length for
    an axis. Any other grows about its stalk-blossom axis: turned about it, the surface
    stays nearly where it was; turned about any other axis it moves, unless
    the fruit is a sphere, and then the poles' features (the stalk cavity,
    the calyx, a blossom nub) are what moves. The axis is the one of
    ``n_directions`` directions (then refined) that minimises the mean
    distance of surface samples turned by ``SYMMETRY_TURNS`` from the surface
    (a k-d tree). Unlike the principal axes, it does not depend on which of a
    round fruit's widths happens to be the largest. Its end with more surface
    in a cavity near the axis is taken for the stalk end: a stalk sits in a
    cavity on apples, peaches, plums, cherries, tomatoes and bell peppers;
    the blossom end is a point, a nub or a shallower basin.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int
        A closed surface.
    n_directions : int, default: 200
        Trial axes, spread evenly over a hemisphere (about 8 degrees apart).
    n_samples : int, default: 1000
        Surface samples (area-weighted) turned about each trial axis.
    n_end_samples : int, default: 4000
        Surface samples that measure the cavities at the ends.
    random_state : int, Generator or None, default: 0
        Seed of the surface samples.
    observed : (m,) array_like of bool, optional
        Which faces the scanner saw; the others close its holes
        (:func:`hortishape.surface.fill_holes`). Only seen faces are sampled,
        so that a guessed patch neither breaks the symmetry nor makes a
        cavity; the patches still count as surface to land on.

    Returns
    -------
    FruitAxis

    Examples
    --------
    An ellipsoid with a dimple at one end of its short axis:

    >>> import trimesh
    >>> s = trimesh.creation.icosphere(5, radius=40.0)
    >>> v = s.vertices * [1.0, 1.0, 0.8]
    >>> v[:, 2] -= 12.0 * np.exp(-((v[:, 0] ** 2 + v[:, 1] ** 2) / 120.0)) * (v[:, 2] > 0)
    >>> ax = fruit_axis(v, s.faces)
    >>> round(float(ax.direction[2]), 3), ax.contrast
    (1.0, 1.0)
    """
    v = _points(vertices, "vertices")
    f = np.asarray(faces, dtype=np.int64)
    rng = as_generator(random_state)
    w = vertex_areas(v, f)
    if not w.sum() > 0:
        raise MeshError("the surface has no area")
    centre = w @ v / w.sum()
    x = v - centre
    prob = w / w.sum()
    seen, known = prob, np.ones(len(v), dtype=bool)
    if observed is not None:
        observed = np.asarray(observed, dtype=bool)
        seen = vertex_areas(v, f[observed])
        seen = seen / seen.sum() if seen.sum() > 0 else prob
        known = np.zeros(len(v), dtype=bool)
        known[f[observed].ravel()] = True
    p = x[rng.choice(len(v), n_samples, p=seen)]
    scale = float(np.sqrt((p**2).sum(axis=1).mean()))
    # the surface as up to TREE_POINTS area-weighted samples: the distances
    # compare axes, a finer surface changes them all alike
    tree = cKDTree(x if len(x) <= TREE_POINTS else x[rng.choice(len(x), TREE_POINTS, replace=False, p=prob)])
    bound = 0.3 * scale  # farther misses all count the same; keeps far queries cheap

    def costs(axes: np.ndarray, pts: np.ndarray) -> np.ndarray:
        q = _turned(pts, axes, SYMMETRY_TURNS)
        d, _ = tree.query(q.reshape(-1, 3), distance_upper_bound=bound, workers=-1)
        return np.minimum(d, bound).reshape(len(axes), -1).mean(axis=1) / scale

    def refine(axis: np.ndarray, best: float) -> tuple[np.ndarray, float]:
        # pattern search about a direction, halving the step when no
        # neighbour improves, down to a degree (the registration's rigid
        # steps take it from there)
        step = np.radians(0.6 * np.degrees(np.arccos(1.0 - 1.0 / n_directions)) + 2.0)
        ring = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
        for _ in range(16):
            if step < np.radians(1.0):
                break
            _, e1, e2 = _axis_frame(axis)
            trial = axis + np.tan(step) * (np.cos(ring)[:, None] * e1 + np.sin(ring)[:, None] * e2)
            trial /= np.linalg.norm(trial, axis=1, keepdims=True)
            tc = costs(trial, p)
            if tc.min() < best:
                axis, best = trial[int(np.argmin(tc))], float(tc.min())
            else:
                step /= 2.0
        return axis / np.linalg.norm(axis), best

    # the surface's covariance from its vertices, each weighted by its area
    # (principal_axes integrates over the triangles, at ten times the cost)
    variances, vectors = np.linalg.eigh((x * prob[:, None]).T @ x)
    variances, vectors = variances[::-1], vectors[:, ::-1]
    elongated = variances[0] > ELONGATED_VARIANCE * 0.5 * (variances[1] + variances[2])
    if elongated:
        # a fruit much longer than wide: its length is its axis (a bent one
        # is no body of revolution, and its most symmetric axis strays: 13
        # degrees on a bent zucchini, which then fitted better end over end)
        axis = vectors[:, 0]
        best = float(costs(axis[None], p)[0])
    else:
        # all directions with a third of the samples (their distances read
        # off a grid: it only ranks them), then the best few with all
        dirs = _fibonacci_hemisphere(n_directions)
        grid = _DistanceGrid(tree.data, bound, scale / GRID_CELLS)
        sub = p[: max(n_samples // 3, 1)]
        c = grid(_turned(sub, dirs, SYMMETRY_TURNS).reshape(-1, 3)).reshape(len(dirs), -1).mean(axis=1)
        dirs = dirs[np.argsort(c)[:5]]
        c = costs(dirs, p)
        axis, best = refine(dirs[int(np.argmin(c))], float(c.min()))

    # cavities: surface samples deeper than CAVITY_DEPTH below the convex
    # hull (of a few thousand vertices: its facets lie within a hundredth of
    # a millimetre of the full hull's on a fruit, at a fraction of the cost)
    picked = rng.choice(len(v), n_end_samples, p=prob)
    q, guessed = x[picked], ~known[picked]
    hull_points = x if len(x) <= HULL_VERTICES else x[rng.choice(len(x), HULL_VERTICES, replace=False)]
    # a patch over a hole is no evidence of a cavity, nor of its absence
    deep = (_hull_depth(hull_points, q) / scale > CAVITY_DEPTH) & ~guessed

    def oriented(axis: np.ndarray, symmetry: float) -> FruitAxis:
        s = q @ axis
        # within END_CONE of each end, seen from the centroid
        along = s / np.maximum(np.linalg.norm(q, axis=1), 1e-12)
        cone = np.cos(np.radians(END_CONE))
        near = [along > cone, along < -cone]
        if elongated:
            # from the centroid of a long fruit the cone reaches back along
            # its sides, where the concave side of a bend lies below the
            # hull: only the part near the axis counts there
            off = np.linalg.norm(q - np.outer(s, axis), axis=1)
            near = [n & (off < END_RADIUS * np.median(off[n])) if n.any() else n for n in near]
        ends = np.array([np.mean(deep & near[0]), np.mean(deep & near[1])])
        hidden = np.array([np.mean(guessed & near[0]), np.mean(guessed & near[1])])
        if ends[1] > ends[0]:
            axis, ends, hidden = -axis, ends[::-1], hidden[::-1]
        total = ends.sum()
        contrast = float((ends[0] - ends[1]) / total) if total > 0 else 0.0
        return FruitAxis(centre, axis, _across(x, w, axis), symmetry, ends, contrast, hidden=hidden)

    found = oriented(axis, best)
    # A fruit flattened along its axis (a squat pepper) can be more nearly a
    # body of revolution about its short axis than about its own; its stalk
    # cavity still points along its own. The direction to the largest
    # cavity, when it is far from the axis found, is the other hypothesis.
    # An elongated fruit's axis is not in doubt, and the concave side of its
    # bend is a cavity beside the axis (a banana, a bent zucchini).
    toward = None if elongated else _largest_cavity(q[deep], scale, min_points=int(CAVITY_MIN_AREA * len(q)))
    if toward is not None and abs(toward @ axis) < np.cos(np.radians(AXIS_AGREEMENT)):
        other, c_other = refine(toward, float(costs(toward[None], p)[0]))
        if abs(other @ axis) < np.cos(np.radians(AXIS_AGREEMENT)):
            found = replace(found, alternative=oriented(other, c_other))
    return found


def _largest_cavity(points: np.ndarray, scale: float, *, min_points: int) -> np.ndarray | None:
    """Unit direction from the centre to the mean of the largest cluster of ``points`` (cavity samples)."""
    if len(points) < max(min_points, 1):
        return None
    pairs = cKDTree(points).query_pairs(0.15 * scale, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
    _, labels = connected_components(graph, directed=False)
    counts = np.bincount(labels)
    k = int(np.argmax(counts))
    if counts[k] < min_points:
        return None
    m = points[labels == k].mean(axis=0)
    n = np.linalg.norm(m)
    return m / n if n > 0 else None


def _across(x: np.ndarray, w: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The area-weighted principal direction of ``x`` perpendicular to ``axis``, signed by its third moment."""
    flat = x - np.outer(x @ axis, axis)
    cov = (flat * w[:, None]).T @ flat
    vals, vecs = np.linalg.eigh(cov)
    e = vecs[:, int(np.argmax(vals))]
    e = e - (e @ axis) * axis
    e /= np.linalg.norm(e)
    return -e if w @ (flat @ e) ** 3 < 0 else e


def axis_alignments(source: FruitAxis, target: FruitAxis, *, n_turns: int = 4, both_ends: bool = True) -> np.ndarray:
    """Rigid alignments that put one fruit's axis on another's, turned about it.

    Parameters
    ----------
    source, target : FruitAxis
        See :func:`fruit_axis`.
    n_turns : int, default: 4
        Equal turns about the target's axis, starting from the one that puts
        the source's widest direction across the axis (``across``) on the
        target's.
    both_ends : bool, default: True
        Also the alignments that put the source's ``direction`` end on the
        target's other end (when the cavities do not tell the ends apart).

    Returns
    -------
    (k, 4, 4) float64 ndarray
        Source -> target transforms, ``n_turns`` (or twice that), those that
        match the ``direction`` ends first.

    Examples
    --------
    >>> z, x, y = np.eye(3)[2], np.eye(3)[0], np.eye(3)[1]
    >>> a = FruitAxis(np.zeros(3), z, x, 0.0, np.array([0.1, 0.0]), 1.0)
    >>> b = FruitAxis(np.ones(3), x, y, 0.0, np.array([0.1, 0.0]), 1.0)
    >>> t = axis_alignments(a, b, n_turns=2)
    >>> (t[:, :3, :3] @ z).round(6)[:, 0].tolist(), (t[0, :3, :3] @ x).round(6).tolist() == [0, 1, 0]
    ([1.0, 1.0, -1.0, -1.0], True)
    """
    out = []
    for sign in (1.0, -1.0) if both_ends else (1.0,):
        base = _rotation_between(source.direction, sign * target.direction)
        a_s = base @ source.across
        start = np.arctan2(np.cross(a_s, target.across) @ target.direction, a_s @ target.across)
        for k in range(n_turns):
            r = rotation_about(target.direction, start + 2.0 * np.pi * k / n_turns) @ base
            out.append(rigid_transform(r, target.centre - r @ source.centre))
    return np.stack(out)
