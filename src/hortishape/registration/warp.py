"""The global polynomial warp (the paper's "initializing globally affine step"), its kind and damping."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..align import _axis_frame, apply_transform, principal_axes
from ..mesh import Mesh
from ..surface import barycentric_interpolate, closest_points, face_normals, vertex_normals
from .config import ELONGATED, LOBED, LOBED_RIDGE, ROUND_RIDGE, WARP_MIN_GAIN, WARP_STEP_GAIN, RegistrationConfig
from .correspondences import TargetSurface, _match
from .result import RegistrationPlan
from .template import Template, _Level


@dataclass(frozen=True)
class _Warp:
    """A global polynomial map ``x -> x + scale * m(u) @ coef``, ``u = (x - centre) / scale``.

    ``m(u)`` are the monomials of ``u`` up to ``degree`` (1: affine; 2: also
    the squares and products, which take up taper (a top wider than the
    bottom) and gentle bends, deformations a translation-only elastic step
    can only follow along the normals, sliding the correspondence up or
    down the sides).
    """

    coef: np.ndarray  # (k, 3)
    centre: np.ndarray  # (3,)
    scale: float
    degree: int

    def basis(self, x: np.ndarray) -> np.ndarray:
        return _monomials((x - self.centre) / self.scale, self.degree)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return x + self.scale * (self.basis(x) @ self.coef)

    def jacobian_det(self, x: np.ndarray) -> np.ndarray:
        """Determinant of the map's Jacobian at each point (positive: no fold)."""
        u = (x - self.centre) / self.scale
        j = np.broadcast_to(np.eye(3), (len(x), 3, 3)).copy()
        j += self.coef[1:4].T[None]  # linear terms
        if self.degree >= 2:
            c = self.coef
            for a in range(3):  # d(u_a^2)/du_a = 2 u_a
                j[:, :, a] += 2.0 * u[:, a, None] * c[4 + a][None]
            for k, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
                j[:, :, a] += u[:, b, None] * c[7 + k][None]
                j[:, :, b] += u[:, a, None] * c[7 + k][None]
        return np.linalg.det(j)

    def affine(self, x: np.ndarray) -> np.ndarray:
        """The least-squares affine approximation ``(4, 4)`` of the map over points ``x``."""
        xh = np.c_[x, np.ones(len(x))]
        sol, *_ = np.linalg.lstsq(xh, self(x), rcond=None)
        out = np.eye(4)
        out[:3, :] = sol.T
        return out


def _warp_kind(warp: str, vertices: np.ndarray) -> str:
    """The initializing warp to fit: ``"none"``, ``"affine"``, ``"taper"`` or ``"quadratic"``.

    ``"auto"``: quadratic for an elongated reference (its longest principal
    axis at least ``ELONGATED`` times the next, as the standard deviations:
    zucchini 3.7, banana 2.6, pear 1.7), taper for a round one (apple 1.0,
    pepper 1.3).
    """
    if warp == "auto":
        var = np.sort(principal_axes(vertices).variances)[::-1]
        return "quadratic" if np.sqrt(var[0] / var[1]) >= ELONGATED else "taper"
    return warp


def _warp_ridge(cfg: RegistrationConfig, kind: str, lev: _Level) -> float:
    """``cfg.warp_ridge``, or for ``"auto"`` the one for the reference level ``lev`` (see ``ROUND_RIDGE``)."""
    if cfg.warp_ridge != "auto":
        return float(cfg.warp_ridge)
    if kind == "taper" and _lobes(lev.vertices, _concavity_axis(lev, lev.vertices)) < LOBED:
        return ROUND_RIDGE
    return LOBED_RIDGE


def _product_terms(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Coefficients of ``(p.u)(q.u)`` on ``u_x^2, u_y^2, u_z^2, u_x u_y, u_x u_z, u_y u_z`` (see :func:`_monomials`)."""
    return np.array([
        p[0] * q[0], p[1] * q[1], p[2] * q[2],
        p[0] * q[1] + p[1] * q[0], p[0] * q[2] + p[2] * q[0], p[1] * q[2] + p[2] * q[1],
    ])


def _concavity_axis(lev: _Level, positions: np.ndarray, fraction: float = 0.1) -> np.ndarray:
    """The line through the centroid nearest the most concave ``fraction`` of the vertices.

    A fruit's pits lie on its stalk axis: the stalk cavity and the calyx
    basin of an apple, the stalk cavity and blossom end of a pepper (whose
    creases between the lobes run along the axis), where the principal
    axis whose variance stands apart (:func:`_symmetry_axis`) can lie far
    off on a near-spherical fruit (``docs/design-notes.md``). Concavity is the umbrella
    operator along the normal: how far outward the neighbours' mean lies.
    """
    lap = lev.laplacian
    deg = lap.diagonal()
    pull = -(lap @ positions) / deg[:, None]  # to the neighbours' mean
    depth = np.einsum("ij,ij->i", pull, vertex_normals(positions, lev.faces))
    cut = np.quantile(depth, 1.0 - fraction)
    pit = depth >= cut
    w = depth[pit] - cut + 1e-12
    x = positions[pit] - positions.mean(axis=0)
    _, vec = np.linalg.eigh((x * w[:, None]).T @ x)
    return vec[:, -1]


def _lobes(vertices: np.ndarray, axis: np.ndarray, orders: range = range(3, 9), bands: int = 8) -> float:
    """The largest angular harmonic of order in ``orders`` of the radius about ``axis``.

    ``vertices`` spread over a surface (a remeshed level); ``axis`` through
    their centroid. In each of ``bands`` slices across the middle 60 % of
    the height, the radius relative to the slice's mean is fitted by least
    squares with ``cos(k phi)``, ``sin(k phi)`` for every order up to the
    largest (a fit, not a projection: an oval section spreads the vertices
    unevenly in ``phi``, which a projection would read as a fourth order);
    the complex amplitudes are averaged over the slices (lobes run from top
    to bottom) and the largest modulus is returned: lobes 10 % deeper than
    the valleys between them give 0.05.
    """
    a, p1, p2 = _axis_frame(axis)
    x = vertices - vertices.mean(axis=0)
    h, u, w = x @ a, x @ p1, x @ p2
    radius, phi = np.hypot(u, w), np.arctan2(w, u)
    k = np.arange(1, max(orders) + 1)[None, :]
    amp = np.zeros(k.shape[1], dtype=complex)
    edges = np.linspace(*np.quantile(h, [0.2, 0.8]), bands + 1)
    band = np.searchsorted(edges, h, side="right") - 1
    for b in range(bands):
        m = band == b
        if m.sum() <= 2 * k.shape[1]:  # too few vertices in the slice to fit its harmonics
            continue
        design = np.hstack([np.ones((m.sum(), 1)), np.cos(k * phi[m, None]), np.sin(k * phi[m, None])])
        coef, *_ = np.linalg.lstsq(design, radius[m], rcond=None)
        amp += (coef[1 : 1 + k.shape[1]] + 1j * coef[1 + k.shape[1] :]) / coef[0] / bands
    return float(np.abs(amp[np.asarray(orders) - 1]).max())


def _taper_basis(axis: np.ndarray) -> np.ndarray:
    """Basis ``(30, 15)`` of the quadratic warp's coefficients that make an affine map plus a taper.

    A taper about ``axis`` (unit, through the warp's centre) widens or
    narrows the cross-sections linearly along it, in each transverse
    direction by its own rate, plus a shear of the cross-section growing
    along the axis: across-axis outputs get the terms ``(a.u)(p.u)`` for
    ``p`` across the axis, without the torsion ``(a.u)`` x (a quarter turn
    of ``u``) (a turn of the cross-section growing along the axis, which
    the residual of a round fruit barely sees). Outputs along the axis and
    all other second-order terms stay zero.
    """
    a, p1, p2 = _axis_frame(axis)

    def term(out: np.ndarray, form: np.ndarray) -> np.ndarray:
        c = np.zeros((10, 3))
        c[4:] = form[:, None] * out[None, :]
        return c.ravel()

    w1, w2 = _product_terms(a, p1), _product_terms(a, p2)
    cols = list(np.eye(12, 30))  # the affine part, free
    cols += [term(p1, w1), term(p2, w2), term(p1, w2) + term(p2, w1)]
    return np.column_stack(cols)


def _monomials(u: np.ndarray, degree: int) -> np.ndarray:
    """``1, u_x, u_y, u_z`` and, for degree 2, ``u_x^2, u_y^2, u_z^2, u_x u_y, u_x u_z, u_y u_z``."""
    cols = [np.ones(len(u)), u[:, 0], u[:, 1], u[:, 2]]
    if degree >= 2:
        cols += [u[:, 0] ** 2, u[:, 1] ** 2, u[:, 2] ** 2, u[:, 0] * u[:, 1], u[:, 0] * u[:, 2], u[:, 1] * u[:, 2]]
    return np.column_stack(cols)


def _fit_warp(
    lev: _Level,
    placed: np.ndarray,
    target: TargetSurface,
    cfg: RegistrationConfig,
    kind: str,
    *,
    iterations: int = 20,
    min_jacobian: float = 0.3,
    ridge: float = LOBED_RIDGE,
) -> _Warp | None:
    """Two-sided point-to-plane ICP of a global polynomial map of the undeformed level.

    The paper's "initializing globally affine step" (section 1), optionally
    quadratic: size, proportion and taper differences are taken up by one
    smooth global map before the translation-only elastic steps, which move
    vertices along their normals only and so cannot stretch a surface along
    itself. Pairs in both directions: the reference's normal rays, and
    sampled target vertices with their closest points on the reference
    (rays from a part of the reference that overhangs the target, the end of
    a zucchini longer than the scan, hit nothing; the target's own points
    there pull it in). Point-to-plane residuals let the surface slide
    tangentially. Each iteration is a damped Gauss-Newton step (``ridge``
    relative to the mean diagonal), which keeps still what the residual
    barely sees (shear and twist of a round fruit; see ``ROUND_RIDGE``), with the
    quadratic terms pulled towards zero (``warp_prior``); a map whose Jacobian
    determinant would fall below ``min_jacobian`` anywhere on the surface
    (a fold or squash) is not taken. The steps stop when one takes less
    than ``WARP_STEP_GAIN`` off the mean residual. ``kind`` is ``"affine"``, ``"taper"``
    (the quadratic map restricted to :func:`_taper_basis` about the level's
    :func:`_concavity_axis`) or ``"quadratic"``.

    ``placed`` are the level's vertices after the rigid initial alignment.
    """
    centre = placed.mean(axis=0)
    scale = float(np.sqrt(((placed - centre) ** 2).sum(axis=1).mean()))
    degree = 1 if kind == "affine" else 2
    k = 4 if degree == 1 else 10
    # the coefficients move in this subspace (None: all of them)
    basis = _taper_basis(_concavity_axis(lev, placed)) if kind == "taper" else None
    v = target.mesh.vertices
    coef = np.zeros((k, 3))
    # start from matched centroids: a rigid fit of a reference longer than the
    # scan slides it towards one end (measured on zucchini: 41 mm dense error
    # after the rigid refinement against 26 mm before it, 2.7 mm after this
    # warp), and from there the two-sided pairs cannot pull it back
    coef[0] = (v.mean(axis=0) - centre) / scale
    warp = _Warp(coef, centre, scale, degree)
    idx = np.linspace(0, len(v) - 1, min(2 * len(placed), len(v))).astype(np.int64)
    q_b, n_b = v[idx], target.normals[idx]
    cos_max = np.cos(np.radians(cfg.max_angle))
    prev = np.inf
    start = end = np.nan  # mean point-to-plane residual of the identity and of the map
    for _ in range(iterations):
        pos = warp(placed)
        corr = _match(pos, lev.faces, target, cfg, max_distance=cfg.distance_factor * prev)
        if corr.found.sum() < 3 * k:
            break
        prev = corr.mean_distance
        cp = closest_points(Mesh(pos, lev.faces), q_b)
        ok = (np.einsum("ij,ij->i", face_normals(pos, lev.faces)[cp.face_index], n_b) >= cos_max) & (
            cp.distances < cfg.distance_factor * prev
        )
        f = corr.found
        x = np.concatenate(
            [placed[f], barycentric_interpolate(placed, lev.faces, cp.face_index[ok], cp.barycentric[ok])]
        )
        q = np.concatenate([corr.points[f], q_b[ok]])
        n = np.concatenate([corr.target_normals[f], n_b[ok]])
        # residual (x + scale * m(u) @ coef - q) . n, linear in coef (k x 3, row-major)
        a = scale * (warp.basis(x)[:, :, None] * n[:, None, :]).reshape(len(x), 3 * k)
        b = np.einsum("ij,ij->i", q - x, n)
        ata = a.T @ a
        damping = np.full(3 * k, ridge * np.trace(ata) / (3 * k))
        damping[:3] = 0.0  # translation is free
        # damped towards the current map, not towards the identity: a step
        # the residual barely sees stays small, while a well-seen stretch is
        # reached in full over the iterations
        theta = warp.coef.ravel()
        prior = np.zeros(3 * k)
        prior[12:] = cfg.warp_prior * np.trace(ata) / (3 * k)
        lhs = ata + np.diag(damping + prior)
        rhs = a.T @ (b - a @ theta) - prior * theta
        if basis is None:
            delta = np.linalg.solve(lhs, rhs)
        else:
            delta = basis @ np.linalg.solve(basis.T @ lhs @ basis, basis.T @ rhs)
        coef = (theta + delta).reshape(k, 3)
        new = _Warp(coef, centre, scale, degree)
        if new.jacobian_det(placed).min() < min_jacobian:
            break
        if np.isnan(start):
            start = float(np.abs(b).mean())
        before = float(np.abs(b - a @ theta).mean())
        end = float(np.abs(b - a @ coef.ravel()).mean())
        change = np.abs(coef - warp.coef).max()
        warp = new
        # 1e-4 of the size: well under a voxel
        if change < 1e-4 or before - end < WARP_STEP_GAIN * before:
            break
    if not start - end > WARP_MIN_GAIN * scale:
        return None  # not worth it (see WARP_MIN_GAIN)
    return warp


def _placed(template: Template, target: TargetSurface, t0: np.ndarray, cfg: RegistrationConfig,
            plan: RegistrationPlan) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The undeformed reference in the target's frame: coarse and fine levels, and the warp's affine part.

    Rigidly placed by ``t0``, then through the global polynomial warp of
    ``plan.warp`` if one fits (the loop's global steps and elastic
    displacements start from here).
    """
    coarse, fine = template.level("coarse"), template.level("fine")
    base_c = apply_transform(t0, coarse.vertices)
    base_f = apply_transform(t0, fine.vertices)
    warp = None if plan.warp == "none" else _fit_warp(coarse, base_c, target, cfg, plan.warp, ridge=plan.warp_ridge)
    if warp is None:
        return base_c, base_f, np.eye(4)
    return warp(base_c), warp(base_f), warp.affine(base_f)
