"""The coordinator: :func:`register` runs the stages of :mod:`hortishape.registration` in order."""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from typing import Callable

import numpy as np

from ..align import apply_transform, rigid_fit
from ..errors import ConvergenceWarning, MeshError
from ..mesh import Mesh
from .config import (
    LANDMARK_SPREAD,
    SEARCH_PATCH_DATA,
    UNCOVERED_AT_STALK,
    UNCOVERED_EDGES,
    UNCOVERED_GAIN,
    UNCOVERED_MAX,
    RegistrationConfig,
)
from .correspondences import (
    TargetSurface,
    _landmark_pairs,
    _nearest_vertices,
    _uncovered,
    _uncovered_fraction,
    prepare_target,
)
from .elastic import _deform, _land, _rigid_part
from .folds import _repair_folds
from .orientation import _choose_orientation, _ends_told, _Orientation, _refined_start, _search_taper, _up_hint
from .result import IterationRecord, Registration, RegistrationPlan
from .template import Template, prepare_reference
from .warp import _placed, _warp_kind, _warp_ridge


def _check_units(reference: np.ndarray, target: np.ndarray) -> None:
    def size(v: np.ndarray) -> float:
        return float(np.sqrt(((v - v.mean(axis=0)) ** 2).sum(axis=1).mean()))

    ratio = size(target) / max(size(reference), 1e-300)
    if not 0.2 <= ratio <= 5.0:
        hint = " (is one of them in metres? hortishape works in millimetres)" if (
            ratio < 0.01 or ratio > 100
        ) else ""
        raise MeshError(
            f"target is {ratio:.3g} times the size of the reference{hint}; "
            "scale it before registering"
        )


def register(
    reference: Mesh | Template,
    target: Mesh | TargetSurface,
    config: RegistrationConfig | None = None,
    *,
    initial_transform=None,
    reference_up=None,
    target_up=None,
    reference_landmarks=None,
    target_landmarks=None,
    callback: Callable[[IterationRecord], None] | None = None,
) -> Registration:
    """Register a reference surface elastically onto a target (RN-ICP-T, eq. 8).

    Parameters
    ----------
    reference : Mesh or Template
        The reference (template) surface, uniformly sampled (see
        :func:`prepare_reference`; a ``Mesh`` is prepared on each call, which
        costs a coarse remesh, a few seconds for 30k vertices).
    target : Mesh or TargetSurface
        Closed single-component target surface in mm (e.g. a marching-cubes
        surface of a CT scan), in any pose.
    config : RegistrationConfig, optional
        Parameters; default: the paper's.
    initial_transform : (4, 4) array_like, optional
        Start from this reference -> target transform instead of searching
        (the orientation search is skipped).
    reference_up, target_up : (3,) array_like, optional
        A known anatomical axis (e.g. towards the stalk) in reference and
        target coordinates: orientations that put the reference's one more
        than ``UP_TOLERANCE`` degrees from the target's are excluded (see
        ``up`` in :class:`RegistrationConfig`, the default for both). Give
        both or neither.
    reference_landmarks, target_landmarks : mapping of str to (3,) array_like, optional
        Named points (e.g. ``"stalk"``, ``"calyx"``) on the reference, in its
        coordinates, and on the target, in the target's; the names in both
        are used. Three or more not on one line fix the orientation (their
        rigid fit; no search), two fix the axis through them as ``up``
        does; and the reference vertex nearest each is pulled onto the
        target's point in every iteration, whatever the rays find there.
    callback : callable, optional
        Called with each :class:`IterationRecord` as it is logged (progress).
        When ``coverage_check`` registers again, the second registration's
        records follow the first's (its ``iteration`` starts from 0 again).

    Returns
    -------
    Registration

    Raises
    ------
    MeshError
        If either surface is open, non-manifold or has several components,
        the reference has degenerate triangles, or their sizes differ by more
        than 5x (e.g. a target in metres against a reference in mm).

    Warns
    -----
    ConvergenceWarning
        If ``max_iterations`` is reached before the convergence test passes.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(4, radius=40.0)
    >>> ref = prepare_reference(Mesh(s.vertices, s.faces), coarse_vertices=600)
    >>> tgt = Mesh(s.vertices * [1.1, 1.0, 0.9] + [5.0, 0.0, 0.0], s.faces)
    >>> reg = register(ref, tgt, RegistrationConfig(orientation="pca"))
    >>> bool(np.abs(np.linalg.norm((reg.vertices - [5, 0, 0]) / [44, 40, 36], axis=1) - 1).max() < 0.01)
    True
    """
    t_start = time.perf_counter()
    cfg = config if config is not None else RegistrationConfig()
    template = reference if isinstance(reference, Template) else prepare_reference(reference)
    tgt = target if isinstance(target, TargetSurface) else prepare_target(target)
    _check_units(template.mesh.vertices, tgt.mesh.vertices)
    fine = template.level("fine")
    coarse = template.level("coarse")

    # --- initial alignment ---------------------------------------------------
    pairs = _landmark_pairs(reference_landmarks, target_landmarks)
    if pairs is not None and initial_transform is None and cfg.orientation != "none":
        p, q = pairs
        centred = p - p.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False) if len(p) >= 3 else np.zeros(2)
        if len(p) >= 3 and sv[1] > LANDMARK_SPREAD * sv[0]:
            initial_transform = rigid_fit(p, q)
        elif len(p) >= 2 and reference_up is None:
            reference_up, target_up = p[0] - p[-1], q[0] - q[-1]
    if reference_up is None and target_up is None and cfg.up is not None:
        reference_up = target_up = cfg.up
    plan = plan_registration(template, cfg, given=initial_transform is not None)
    # the search judges whole surfaces: a hole's patch counts as the scan's
    searched = tgt if tgt.filled is None else replace(tgt, patch_data=SEARCH_PATCH_DATA)
    if initial_transform is not None:
        orient = _Orientation(np.asarray(initial_transform, dtype=np.float64).reshape(4, 4), np.zeros(0), -1, "",
                             float("nan"))
    elif cfg.orientation == "none":
        orient = _Orientation(np.eye(4), np.zeros(0), -1, "", float("nan"))
    else:
        orient = _choose_orientation(template, searched, cfg, plan, _up_hint(reference_up, target_up))

    # --- elastic registration from there ------------------------------------
    anchors = {} if pairs is None else {
        name: (_nearest_vertices(lev.vertices, pairs[0]), pairs[1]) for name, lev in (("coarse", coarse), ("fine", fine))
    }

    def run(t0: np.ndarray, chosen: int) -> Registration:
        """The registration from the rigid placement ``t0`` (search candidate ``chosen``)."""
        log: list[IterationRecord] = []

        def record(it: int, level: str, beta: float, d: float, kept: float, since: float) -> None:
            rec = IterationRecord(it, level, float(beta), float(d), float(kept), time.perf_counter() - since)
            log.append(rec)
            if callback is not None:
                callback(rec)

        base_c, base_f, warp_affine = _placed(template, tgt, t0, cfg, plan)
        state, converged, it = _deform(template, tgt, base_c, base_f, cfg, anchors, record)
        if not converged:
            warnings.warn(
                f"registration stopped at max_iterations={cfg.max_iterations} before "
                f"|d_t - d_t-1| / d_t < {cfg.tolerance}",
                ConvergenceWarning,
                stacklevel=3,
            )
        if cfg.final_beta is not None:
            t_it = time.perf_counter()
            corr = _land(fine, state, tgt, cfg, anchors.get("fine"))
            record(it, "final", cfg.final_beta, corr.mean_distance, corr.kept_fraction, t_it)
        placed = apply_transform(state.transform, base_f)
        verts = _repair_folds(fine, placed, state.positions)
        verts.flags.writeable = False
        placed.flags.writeable = False
        total = state.transform @ warp_affine @ t0
        return Registration(
            verts,
            template.mesh.faces,
            _rigid_part(total, template.mesh.vertices),
            tuple(log),
            converged,
            orient.scores,
            chosen,
            time.perf_counter() - t_start,
            affine=total,
            placed=placed,
            orientation_confidence=orient.confidence,
            orientation_ends=orient.ends,
            plan=plan,
            target_holes=tgt.n_holes,
            target_hole_share=tgt.hole_share,
        )

    reg = run(orient.transform, orient.chosen)
    if cfg.coverage_check and orient.alternative is not None:
        uncovered, points = _uncovered(reg, tgt, UNCOVERED_EDGES * fine.edge_length)
        if uncovered > UNCOVERED_MAX and not _beyond_stalk(template, reg, points, cfg):
            # a part of the scan the registered surface does not reach (its
            # stalk, when the reference came out upside down): try the best
            # candidate end over end (or turned well away) and keep it if it
            # covers clearly more (see ``coverage_check``)
            alt = run(_refined_start(template, searched, orient.alternative, cfg, plan), orient.alternative_index)
            if _uncovered_fraction(alt, tgt, UNCOVERED_EDGES * fine.edge_length) <= UNCOVERED_GAIN * uncovered:
                reg = alt
            reg = replace(reg, seconds=time.perf_counter() - t_start)
    return reg


def _beyond_stalk(template: Template, reg: Registration, points: np.ndarray, cfg: RegistrationConfig) -> bool:
    """Whether ``points`` of the scan lie at the registered reference's stalk end (see ``UNCOVERED_AT_STALK``).

    False when the reference's cavities do not tell its ends apart
    (``end_contrast``, ``end_cavity``): it then has no stalk end to go by.
    """
    ax = template.axis()
    if not _ends_told(ax, cfg) or not len(points):
        return False
    along = (template.mesh.vertices - ax.centre) @ ax.direction
    stalk, blossom = reg.vertices[int(np.argmax(along))], reg.vertices[int(np.argmin(along))]
    to_stalk = float(np.linalg.norm(points - stalk, axis=1).mean())
    to_blossom = float(np.linalg.norm(points - blossom, axis=1).mean())
    return to_stalk <= UNCOVERED_AT_STALK * to_blossom


def plan_registration(template: Template, config: RegistrationConfig | None = None, *,
                      given: bool = False) -> RegistrationPlan:
    """Resolve the ``"auto"`` options of ``config`` for the reference ``template`` (see :class:`RegistrationPlan`).

    Parameters
    ----------
    template : Template
        The prepared reference (:func:`prepare_reference`).
    config : RegistrationConfig, optional
        Default: the paper's.
    given : bool, default: False
        The orientation is given (an ``initial_transform`` or three landmarks).

    Returns
    -------
    RegistrationPlan

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(3, radius=40.0)
    >>> t = prepare_reference(Mesh(s.vertices * [1.0, 1.0, 2.0], s.faces), coarse_vertices=300)
    >>> plan_registration(t).warp
    'quadratic'
    """
    cfg = config if config is not None else RegistrationConfig()
    warp = _warp_kind(cfg.warp, template.mesh.vertices)
    return RegistrationPlan(
        orientation="given" if given else cfg.orientation,
        search_taper=_search_taper(cfg, template.level("search").vertices),
        warp=warp,
        warp_ridge=_warp_ridge(cfg, warp, template.level("coarse")),
    )
