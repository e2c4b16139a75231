"""The RN-ICP-T iteration: a global (rigid or affine) step and the translation-only elastic step of eq. 8.

Eq. 8, ``(beta^2 M^T M + W) X = W (T - S)``, is solved by a sparse LDL^T
factorisation on the coarse level and by warm-started, Jacobi-preconditioned
conjugate gradients (with a coarse-grid correction while ``beta`` is high)
on the fine one. After the schedule, once few vertices still move, the
iterations go on round those alone (``local_tail``, :func:`_iterate_local`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from ..align import apply_transform, rigid_fit, rigid_transform, rotation_about
from ..errors import MeshError
from ..surface import barycentric_interpolate, vertex_normals
from .config import (
    COARSE_ANGLE_SLACK,
    COARSE_MIN_BETA,
    CROSSING_MIN_EDGES,
    LOCAL_RINGS,
    LOCAL_SHARE,
    RegistrationConfig,
)
from .correspondences import TargetSurface, _match, _max_distance, find_correspondences
from .folds import _unfold_step
from .template import Template, _Level


def _solve_direct(level: _Level, beta: float, w: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve (beta^2 L + W) X = rhs by a sparse LDL^T factorisation (see :class:`_Factor`)."""
    # without any weight the system is singular (free translation) and X = 0
    if not (w > 0).any():
        return np.zeros_like(rhs)
    return level.factor().solve(beta, w, rhs)


def _solve_pcg(
    lap: sp.csr_matrix,
    beta: float,
    w: np.ndarray,
    rhs: np.ndarray,
    x0: np.ndarray,
    *,
    tol: float = 1e-6,
    prolong: sp.csr_matrix | None = None,
) -> np.ndarray:
    """Solve (beta^2 L + W) X = rhs by preconditioned conjugate gradients, warm-started at x0.

    The three columns of X are solved as one vector of the block-diagonal
    system ``I_3 (x) A``: one step length for all three, so that every
    vector update runs over one contiguous array (a step length per column
    broadcasts over rows of three, which is slow; see the design notes).
    The iterations stop when ``|rhs - A X| <= tol |rhs|`` over all columns.

    The preconditioner is Jacobi plus, when ``prolong`` (fine <- coarse
    barycentric interpolation) is given, an exact coarse-grid correction with
    the Galerkin matrix ``P^T A P`` (two-level additive Schwarz). Jacobi alone
    needs ~170 iterations at beta = 8 on 30k vertices; the coarse correction
    removes the smooth error components that make it slow at high beta.
    """
    a = _system(lap, beta, w)
    dinv = np.repeat(1.0 / a.diagonal(), rhs.shape[1]).reshape(rhs.shape)
    coarse_solve = None
    if prolong is not None:
        from cholespy import CholeskySolverD, MatrixType

        ac = (prolong.T @ a @ prolong).tocoo()
        solver = CholeskySolverD(
            ac.shape[0], ac.row.astype(np.int32), ac.col.astype(np.int32), ac.data, MatrixType.COO
        )
        pt = prolong.T.tocsr()

        def coarse_solve(r: np.ndarray) -> np.ndarray:
            xc = np.zeros((ac.shape[0], r.shape[1]))
            solver.solve(np.ascontiguousarray(pt @ r), xc)
            return prolong @ xc

    def precondition(r: np.ndarray, out: np.ndarray) -> np.ndarray:
        np.multiply(r, dinv, out=out)
        if coarse_solve is not None:
            out += coarse_solve(r)
        return out

    x = np.array(x0, dtype=np.float64, order="C")
    r = rhs - a @ x
    z = precondition(r, np.empty_like(r))
    p = z.copy()
    rz = float(np.vdot(r, z))
    stop = (tol * max(float(np.linalg.norm(rhs)), 1e-300)) ** 2
    for _ in range(5000):
        if float(np.vdot(r, r)) <= stop:
            break
        ap = a @ p
        alpha = rz / max(float(np.vdot(p, ap)), 1e-300)
        x += alpha * p
        r -= alpha * ap
        precondition(r, z)
        rz_new = float(np.vdot(r, z))
        p *= rz_new / max(rz, 1e-300)
        p += z
        rz = rz_new
    return x


def _system(lap: sp.csr_matrix, beta: float, w: np.ndarray) -> sp.csr_matrix:
    """``beta^2 L + diag(w)``, in ``L``'s sparsity pattern when it holds the whole diagonal (it does for a mesh's Laplacian)."""
    rows = np.repeat(np.arange(lap.shape[0]), np.diff(lap.indptr))
    diag = np.flatnonzero(lap.indices == rows)
    if len(diag) != lap.shape[0]:
        return ((beta * beta) * lap + sp.diags(w)).tocsr()
    data = (beta * beta) * lap.data
    data[diag] += w
    return sp.csr_matrix((data, lap.indices, lap.indptr), shape=lap.shape)


@dataclass
class _State:
    positions: np.ndarray  # current deformed vertices of the active level
    transform: np.ndarray  # accumulated global (rigid or affine) transform, reference -> target
    prev_distance: float = np.inf


def _iterate(
    level: _Level,
    state: _State,
    target: TargetSurface,
    beta_level: float,
    cfg: RegistrationConfig,
    *,
    use_pcg: bool,
    rigid: bool,
    affine: bool = False,
    taper_axis: np.ndarray | None = None,
    prolong: sp.csr_matrix | None = None,
    anchors: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[float, float]:
    """One RN-ICP-T iteration in place on ``state``; returns (d_t, kept fraction).

    ``anchors`` (vertex indices of the level, (k, 3) target points): landmark
    pairs, kept as correspondences whatever the rays found there.

    ``taper_axis`` (a unit vector of the level in its undeformed pose): the
    global step also fits a taper about that axis as carried by
    ``state.transform`` (see :func:`_taper_step`); it moves ``positions``
    only, ``state.transform`` stays the affine part.
    """
    pos = state.positions
    corr = _match(pos, level.faces, target, cfg, max_distance=_max_distance(cfg, state.prev_distance, level),
                  check_crossings=cfg.check_crossings, edge_length=level.edge_length)
    found, points = _anchored(corr.found, corr.points, anchors)
    kept = corr.kept_fraction
    if found.sum() < 3:
        return np.inf, kept
    d_t = corr.mean_distance
    if rigid:
        step = _affine_fit(pos[found], points[found]) if affine else None
        if step is None:
            step = rigid_fit(pos[found], points[found])
        pos = apply_transform(step, pos)
        state.transform = step @ state.transform
        if taper_axis is not None:
            axis = state.transform[:3, :3] @ taper_axis
            pos = _taper_step(pos, found, points[found], axis / np.linalg.norm(axis))
    w = found.astype(np.float64)
    rhs = np.where(found[:, None], points - pos, 0.0)
    if use_pcg:
        # the coarse-grid correction pays off only while beta is high
        x = _solve_pcg(
            level.laplacian, beta_level, w, rhs, rhs, tol=1e-4, prolong=prolong if beta_level >= 3 else None
        )
    else:
        x = _solve_direct(level, beta_level, w, rhs)
    state.positions = pos + x
    state.prev_distance = d_t
    return d_t, kept


def _iterate_local(level: _Level, state: _State, target: TargetSurface, beta: float, cfg: RegistrationConfig,
                   active: np.ndarray) -> tuple[float, float]:
    """One RN-ICP-T iteration that moves only the vertices ``active`` (indices), in place on ``state``.

    The rest of the surface holds still: it is eq. 8 restricted to
    ``active`` with zero displacement around it. Rays, filters (a)-(c) as
    in :func:`_iterate` (filter (c) against the whole surface); no global
    step. Returns (mean distance of the active vertices' correspondences,
    their kept fraction); ``state.prev_distance`` (filter (b)) stays the
    whole surface's.
    """
    pos = state.positions
    inside = np.zeros(len(pos), dtype=bool)
    inside[active] = True
    touching = level.faces[inside[level.faces].any(axis=1)]
    normals = vertex_normals(pos, touching)  # exact at the active vertices: all their faces are there
    corr = find_correspondences(
        pos, level.faces, normals, target, max_angle=cfg.max_angle,
        max_distance=_max_distance(cfg, state.prev_distance, level), check_crossings=cfg.check_crossings,
        crossing_min_distance=CROSSING_MIN_EDGES * level.edge_length, sources=active,
    )
    found = corr.found
    if not found.any():
        return np.inf, 0.0
    sub = level.laplacian[active][:, active]
    rhs = np.where(found[:, None], corr.points - pos[active], 0.0)
    x = _solve_pcg(sub.tocsr(), beta, found.astype(np.float64), rhs, rhs, tol=1e-4)
    moved = pos.copy()
    moved[active] += x
    state.positions = moved
    return corr.mean_distance, corr.kept_fraction


def _grown(level: _Level, seeds: np.ndarray, rings: int) -> np.ndarray:
    """The vertices within ``rings`` edges of the boolean mask ``seeds`` (indices, sorted)."""
    lap = level.laplacian  # its pattern is the vertex adjacency (and the diagonal)
    mask = seeds.copy()
    for _ in range(rings):
        mask = ((lap @ mask.astype(np.float64)) != 0) | mask
    return np.flatnonzero(mask)


def _anchored(found: np.ndarray, points: np.ndarray, anchors) -> tuple[np.ndarray, np.ndarray]:
    """Correspondences with the landmark pairs put in (copies; the same arrays without anchors)."""
    if anchors is None:
        return found, points
    idx, q = anchors
    found, points = found.copy(), points.copy()
    found[idx] = True
    points[idx] = q
    return found, points


def _taper_step(positions: np.ndarray, found: np.ndarray, points: np.ndarray, axis: np.ndarray,
                *, max_taper: float = 0.5) -> np.ndarray:
    """``positions`` tapered about ``axis`` by the least-squares rate for the pairs ``positions[found] -> points``.

    The taper widens the cross-sections linearly along the axis through the
    centroid: ``x -> x + t h(x) r(x)``, ``h`` the (RMS-normalised) height along
    ``axis`` and ``r`` the offset across it. ``t`` is limited to
    ``max_taper`` either way.
    """
    c = positions.mean(axis=0)
    x = positions - c
    height = x @ axis
    g = (height / np.sqrt((height**2).mean()))[:, None] * (x - np.outer(height, axis))
    gf = g[found]
    den = float((gf * gf).sum())
    if den <= 0.0:
        return positions
    t = float(np.clip((gf * (points - positions[found])).sum() / den, -max_taper, max_taper))
    return positions + t * g


def _point_to_plane_step(p: np.ndarray, q: np.ndarray, n: np.ndarray) -> np.ndarray:
    """One Gauss-Newton step of point-to-plane ICP: min sum(((R p + t - q) . n)^2).

    Unlike Kabsch on the ray pairs, it uses the target normals, so shape
    asymmetry pulls tangentially (a twist about a near-symmetry axis) too.
    """
    c = p.mean(axis=0)
    pc = p - c
    a = np.hstack([np.cross(pc, n), n])  # d/d(omega, t) of the residual
    b = np.einsum("ij,ij->i", q - p, n)
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    omega, tr = x[:3], x[3:]
    angle = float(np.linalg.norm(omega))
    r = rotation_about(omega, angle) if angle > 1e-15 else np.eye(3)
    # rotate about the centroid c, then translate
    return rigid_transform(r, c - r @ c + tr)


def _affine_fit(p: np.ndarray, q: np.ndarray, *, max_stretch: float = 3.0) -> np.ndarray | None:
    """Least-squares affine transform ``min sum |A p + t - q|^2`` on paired points.

    Returns ``None`` when the fit is not trustworthy: fewer than 12 pairs,
    a reflection (``det A <= 0``) or a singular value of ``A`` outside
    ``[1 / max_stretch, max_stretch]`` (pairs on one side of the surface,
    e.g. early rays that only reach a flat face, can make the fit
    degenerate); the caller then takes a rigid step.
    """
    if len(p) < 12:
        return None
    c = p.mean(axis=0)
    pc = p - c
    h = pc.T @ pc
    if np.linalg.cond(h) > 1e8:
        return None
    # A = (Q^T P) (P^T P)^-1 with centred P and Q; t from the centroids
    a = np.linalg.solve(h, pc.T @ (q - q.mean(axis=0))).T
    sv = np.linalg.svd(a, compute_uv=False)
    if np.linalg.det(a) <= 0 or sv.min() < 1.0 / max_stretch or sv.max() > max_stretch:
        return None
    out = np.eye(4)
    out[:3, :3] = a
    out[:3, 3] = q.mean(axis=0) - a @ c
    return out


def _rigid_part(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The rotation of ``affine`` (polar decomposition) about the centroid of ``points``.

    The rigid transform that moves the centroid of ``points`` where
    ``affine`` does and turns it by the rotation closest to the linear part.
    """
    u, _, vt = np.linalg.svd(affine[:3, :3])
    r = u @ vt
    if np.linalg.det(r) < 0:  # cannot happen for an accepted affine step; be safe
        r = u @ np.diag([1.0, 1.0, -1.0]) @ vt
    c = points.mean(axis=0)
    return rigid_transform(r, apply_transform(affine, c[None])[0] - r @ c)


def _coarse_to_fine(template: Template, coarse_state: _State, base_c: np.ndarray, base_f: np.ndarray) -> np.ndarray:
    """Fine vertex positions from the coarse displacement (barycentric transfer).

    ``base_c`` and ``base_f`` are the undeformed coarse and fine levels where
    the loop started; the state's transform has moved them since.
    """
    t = coarse_state.transform
    disp = coarse_state.positions - apply_transform(t, base_c)
    disp_f = barycentric_interpolate(
        disp, template.coarse.faces, template.coarse_face_index, template.coarse_barycentric
    )
    return apply_transform(t, base_f) + disp_f


def _deform(template: Template, target: TargetSurface, base_c: np.ndarray, base_f: np.ndarray,
            cfg: RegistrationConfig, anchors: dict, record) -> tuple[_State, bool, int]:
    """RN-ICP-T iterations from the placed reference (``base_c``, ``base_f``) along the stiffness schedule.

    Stiff iterations run on the coarse level, the rest on the fine one, the
    last of them only where the surface still moves (``local_tail``);
    ``record(iteration, level, beta, d_t, kept, start_time)`` logs each.
    Returns the fine level's state, whether the convergence test passed, and
    the number of iterations.
    """
    fine = template.level("fine")
    coarse = template.level("coarse")
    betas = cfg.betas()
    ratio = fine.edge_length / coarse.edge_length
    on_coarse = cfg.multiresolution and template.coarse is not template.mesh
    state = _State((base_c if on_coarse else base_f).copy(), np.eye(4))
    level_name = "coarse" if on_coarse else "fine"
    # filter (c) only on the fine level: a stiff coarse surface does not fold
    # back on itself, and the filter costs a ray scene of the source per step
    cfg_coarse = replace(cfg, check_crossings=False, max_angle=min(cfg.max_angle + COARSE_ANGLE_SLACK, 90.0))
    converged = False
    it = 0
    prev_d = np.inf
    still = 0  # successive fine iterations in which no vertex moved more than move_tolerance edges
    moving_at = cfg.move_tolerance * fine.edge_length
    local = cfg.local_tail and cfg.move_tolerance > 0 and anchors.get("fine") is None
    active = None  # the vertices the local tail moves, once it has begun
    while it < cfg.max_iterations:
        t_it = time.perf_counter()
        beta = betas[it] if it < len(betas) else cfg.beta_end
        if active is not None:
            before = state.positions
            d_t, kept = _iterate_local(fine, state, target, beta, cfg, active)
            record(it, "local", beta, d_t, kept, t_it)
            it += 1
            moving = np.zeros(len(before), dtype=bool)
            moving[active] = np.linalg.norm(state.positions[active] - before[active], axis=1) >= moving_at
            if moving.any():
                still = 0
                active = _grown(fine, moving, LOCAL_RINGS)
            else:
                still += 1
                if still >= 2:
                    converged = True
                    break
            continue
        if level_name == "coarse" and beta * ratio < COARSE_MIN_BETA:
            # switch to the full-resolution reference for the elastic end game
            state = _State(_coarse_to_fine(template, state, base_c, base_f), state.transform, state.prev_distance)
            level_name = "fine"
        lev = coarse if level_name == "coarse" else fine
        beta_level = beta * (ratio if level_name == "coarse" else 1.0)
        before = state.positions if level_name == "fine" and cfg.move_tolerance > 0 else None
        d_t, kept = _iterate(
            lev,
            state,
            target,
            beta_level,
            cfg if level_name == "fine" else cfg_coarse,
            use_pcg=level_name == "fine",
            rigid=cfg.rigid_steps,
            affine=cfg.affine == "all" or (cfg.affine == "stiff" and beta * ratio >= COARSE_MIN_BETA),
            prolong=template.prolongation() if on_coarse else None,
            anchors=anchors.get(level_name),
        )
        record(it, level_name, beta, d_t, kept, t_it)
        if not np.isfinite(d_t):
            raise MeshError(
                "registration lost the target: fewer than 3 correspondences "
                "(are the surfaces far apart or in different units?)"
            )
        it += 1
        moving = None
        if before is not None:
            moving = np.einsum("ij,ij->i", state.positions - before, state.positions - before) >= moving_at**2
            still = 0 if moving.any() else still + 1
        if it >= len(betas) and np.isfinite(prev_d):
            change = abs(d_t - prev_d)
            # the paper's relative test, or a change below `edge_tolerance`
            # edge lengths: once the surface sits on the target d_t keeps halving
            # and the relative test alone would never pass; or the surface
            # has stopped (`move_tolerance`)
            if change < cfg.tolerance * d_t or change < cfg.edge_tolerance * fine.edge_length or still >= 2:
                converged = True
                break
            if local and moving is not None and moving.any() and moving.mean() <= LOCAL_SHARE:
                # the rest has stopped: go on only where the surface still moves (`local_tail`)
                active = _grown(fine, moving, LOCAL_RINGS)
        prev_d = d_t
    if level_name == "coarse":  # only if the schedule never reached fine stiffness
        state = _State(_coarse_to_fine(template, state, base_c, base_f), state.transform, state.prev_distance)
    return state, converged, it


def _land(fine: _Level, state: _State, target: TargetSurface, cfg: RegistrationConfig, anchors=None):
    """The closing step: matched vertices moved (almost) onto the target with ``final_beta``, in place.

    A triangle that would fold in the step keeps its vertices' previous
    positions. Returns the step's correspondences (for the log).
    """
    old = state.positions
    corr = _match(old, fine.faces, target, cfg, max_distance=_max_distance(cfg, state.prev_distance, fine),
                  check_crossings=cfg.check_crossings, edge_length=fine.edge_length)
    found, points = _anchored(corr.found, corr.points, anchors)
    w = found.astype(np.float64)
    rhs = np.where(found[:, None], points - old, 0.0)
    x = _solve_pcg(fine.laplacian, cfg.final_beta, w, rhs, rhs, tol=1e-8)
    state.positions = _unfold_step(fine.faces, old, old + x)
    return corr
