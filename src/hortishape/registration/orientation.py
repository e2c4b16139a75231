"""The initial alignment: candidate orientations, the stiff search that scores them, hints.

See the package notes (:mod:`hortishape.registration`), step 1.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..align import (
    FruitAxis,
    apply_transform,
    axis_alignments,
    candidate_alignments,
    fruit_axis,
    principal_axes,
    rigid_transform,
    rotation_about,
    rotation_angle,
)
from .config import ALTERNATIVE_TURN, MAX_REFINE_TURN, SEARCH_VERTICES, UP_TOLERANCE, RegistrationConfig
from .correspondences import TargetSurface, _match
from .elastic import _iterate, _point_to_plane_step, _rigid_part, _State
from .result import RegistrationPlan
from .template import Template, _Level
from .warp import _warp_kind


def _target_axis(target: TargetSurface) -> FruitAxis:
    """The target's :func:`hortishape.align.fruit_axis`."""
    observed = None if target.filled is None else ~target.filled
    return fruit_axis(target.mesh.vertices, target.mesh.faces, observed=observed)


def _axis_candidates(ref: FruitAxis, tgt: FruitAxis, cfg: RegistrationConfig) -> tuple[np.ndarray, str]:
    """The candidates of ``orientation="axis"`` and how their ends were matched (``"cavity"`` or ``"searched"``).

    Each scan's axis, and its second hypothesis if it has one (see
    :attr:`hortishape.align.FruitAxis.alternative`) against the other's axis:
    cavity end on cavity end when both scans' ends are told apart
    (:func:`_ends_told`), else both ways.
    """
    pairs = [(ref, tgt)]
    if tgt.alternative is not None:
        pairs.append((ref, tgt.alternative))
    if ref.alternative is not None:
        pairs.append((ref.alternative, tgt))
    both = [not (_ends_told(a, cfg) and _ends_told(b, cfg)) for a, b in pairs]
    cands = np.concatenate([axis_alignments(a, b, n_turns=cfg.axis_turns, both_ends=e) for (a, b), e in zip(pairs, both)])
    return cands, "searched" if any(both) else "cavity"


def _ends_told(axis: FruitAxis, cfg: RegistrationConfig) -> bool:
    """Whether a scan's cavities tell its ends apart: ``end_contrast`` between them, ``end_cavity`` at one.

    Not where a patch over a hole near an end holds ``end_cavity`` of the
    surface: as much cavity could hide under it.
    """
    return (axis.contrast >= cfg.end_contrast and axis.cavities[0] >= cfg.end_cavity
            and float(np.max(axis.hidden)) < cfg.end_cavity)


def _search_orientation(
    template: Template,
    target: TargetSurface,
    candidates: np.ndarray,
    cfg: RegistrationConfig,
    plan: RegistrationPlan,
    *,
    level: str = "search",
) -> tuple[np.ndarray, np.ndarray]:
    """Short, stiff registration of the search (or another) level from each candidate.

    Returns the score of each candidate (lower is better) and its refined
    transform. On a round fruit the rigid fit cannot tell the stalk end from
    a side (``docs/design-notes.md``), but after a stiff elastic registration the residual can: the elastic
    step absorbs size and aspect differences, and what remains is the
    mismatch of features such as the stalk cavity, the calyx basin or the
    necks, which a stiff surface cannot absorb. The score is the mean ray
    distance, with vertices without a correspondence counted at a cap.
    """
    lev = template.level(level)
    fine = template.level("fine")
    # the stiff part of the schedule (beta 50 -> 12), at the edge length the
    # reference would have with SEARCH_VERTICES vertices (see there)
    nominal_h = fine.edge_length * np.sqrt(len(fine.vertices) / SEARCH_VERTICES)
    betas = np.linspace(cfg.beta_start, 0.25 * cfg.beta_start, cfg.search_iterations)
    betas = betas * nominal_h / lev.edge_length
    # the crossing filter rarely matters this early and costs a ray scene per step
    scfg = replace(cfg, check_crossings=False)
    v = target.mesh.vertices
    cap = 0.1 * float(np.sqrt(((v - v.mean(axis=0)) ** 2).sum(axis=1).mean()))
    affine = cfg.search_affine or cfg.affine in ("stiff", "all")
    taper_axis = _symmetry_axis(lev.vertices) if plan.search_taper else None

    def score(st: _State) -> float:
        # a one-sided score: a two-sided one (target -> reference distances
        # too) and one adding the deformation energy of eq. 8 were measured
        # and told the right candidate apart no better
        corr = _match(st.positions, lev.faces, target, cfg)
        return float(np.where(corr.found, np.minimum(corr.distances, cap), cap).mean())

    states = [_State(apply_transform(c, lev.vertices), c.copy()) for c in candidates]
    for st in states:
        # no early pruning: halfway through the schedule the right candidate
        # often still scores worse than wrong ones (measured on apples)
        for b in betas:
            _iterate(lev, st, target, b, scfg, use_pcg=False, rigid=True, affine=affine, taper_axis=taper_axis)
    scores = np.array([score(st) for st in states])
    transforms = np.stack([st.transform for st in states])
    return scores, transforms


def _search_taper(cfg: RegistrationConfig, vertices: np.ndarray) -> bool:
    """Whether the search's global steps fit a taper: ``cfg.search_taper``, for ``"auto"`` only on a round reference.

    On an elongated fruit the taper is part of what tells the ends apart (a
    zucchini's club): a taper in the global step takes it out of the score.
    """
    if cfg.search_taper == "auto":
        return _warp_kind("auto", vertices) == "taper"
    return bool(cfg.search_taper)


def _symmetry_axis(vertices: np.ndarray) -> np.ndarray:
    """The principal axis whose variance stands most apart from the other two.

    A fruit is roughly a body of revolution about its stalk axis: the two
    variances across it are close, the one along it differs (larger for a
    pepper or zucchini, smaller for a flattened apple).
    """
    pa = principal_axes(vertices)
    lv = np.log(pa.variances)
    gap = [min(abs(lv[i] - lv[j]) for j in range(3) if j != i) for i in range(3)]
    return pa.axes[:, int(np.argmax(gap))]


def _twist_candidates(transform: np.ndarray, axis: np.ndarray, centre: np.ndarray, n: int) -> np.ndarray:
    """``transform`` followed by ``n`` equal turns about ``axis`` through ``centre``."""
    out = np.empty((n, 4, 4))
    for k in range(n):
        r = rotation_about(axis, 2.0 * np.pi * k / n)
        out[k] = rigid_transform(r, centre - r @ centre) @ transform
    return out


def _refine_rigid(
    lev: _Level, transform: np.ndarray, target: TargetSurface, cfg: RegistrationConfig, *, iterations: int = 15
) -> np.ndarray:
    """Rigid-only ICP of the undeformed level from ``transform``.

    The search's elastic steps absorb part of any small residual rotation
    (a smooth displacement field can mimic a rotation cheaply), and normal
    rays exert no tangential pull to undo it later; a purely rigid fit of the
    undeformed reference removes that drift before the main loop starts.
    """
    t = transform.copy()
    prev = np.inf
    for _ in range(iterations):
        pos = apply_transform(t, lev.vertices)
        corr = _match(pos, lev.faces, target, cfg, max_distance=cfg.distance_factor * prev)
        if corr.found.sum() < 3:
            break
        prev = corr.mean_distance
        step = _point_to_plane_step(pos[corr.found], corr.points[corr.found], corr.target_normals[corr.found])
        t = step @ t
        if np.abs(step - np.eye(4)).max() < 1e-9:
            break
    # A refinement that turns far has slid onto a neighbouring lobe or rib
    # (measured on peppers: a candidate 2 degrees from the truth ended 88
    # degrees off): the search's elastic fit judged that candidate, keep it.
    r = _rigid_part(t, lev.vertices)[:3, :3] @ _rigid_part(transform, lev.vertices)[:3, :3].T
    if rotation_angle(r) > MAX_REFINE_TURN:
        return transform
    return t


def _refined_start(template: Template, target: TargetSurface, candidate: np.ndarray,
                   cfg: RegistrationConfig, plan: RegistrationPlan) -> np.ndarray:
    """The rigid placement a search candidate starts the registration from.

    The rotation of the candidate's affine map only (the search's affine
    part has served to judge the candidates; the warp fits size and shape),
    refined by :func:`_refine_rigid` if the refinement scores better.
    """
    coarse = template.level("coarse")
    t0 = _rigid_part(candidate, coarse.vertices)
    refined = _refine_rigid(coarse, t0, target, cfg)
    if not np.array_equal(refined, t0):
        # the refinement is judged as the candidates were. Measured
        # (benchmarks/registration.py, 4 targets x 2 poses x 5
        # classes, and a 30-apple build): the stiff search leaves
        # apples tilted 15-22 degrees, which the refinement undoes
        # (coarse score 0.62 -> 0.24); but a rigid fit of a bent
        # zucchini or banana tilts the reference 3-15 degrees, and
        # it twisted three right apple orientations 8-26 degrees;
        # the score said so each time (it missed one pepper's
        # 2-degree twist)
        judged, _ = _search_orientation(template, target, np.stack([t0, refined]), cfg, plan, level="coarse")
        if judged[1] < judged[0]:
            t0 = refined
    return t0


def _up_hint(reference_up, target_up) -> tuple[np.ndarray, np.ndarray] | None:
    """The hinted axis as unit vectors in reference and target coordinates, or None."""
    if reference_up is None and target_up is None:
        return None
    if (reference_up is None) != (target_up is None):
        raise ValueError("give both reference_up and target_up, or neither")
    su = np.asarray(reference_up, dtype=np.float64)
    tu = np.asarray(target_up, dtype=np.float64)
    return su / np.linalg.norm(su), tu / np.linalg.norm(tu)


def _keep_hinted(template: Template, target: TargetSurface, cands: np.ndarray, scores: np.ndarray,
                 transforms: np.ndarray, hint, cfg: RegistrationConfig, plan: RegistrationPlan):
    """The searched candidates that keep the hinted axis within ``UP_TOLERANCE``, or the hint's own turns.

    The hint is applied to the search's results, whose stiff fits have turned
    each candidate towards the scan, not to the principal-axis candidates
    themselves: on a round fruit those lie up to about 40 degrees from the
    stalk axis. Nor does it replace them by turns about the hinted axis
    alone: a scan leans on the bed, and with every candidate off by the lean
    the stiff search no longer tells the turns apart. The
    turns are searched only when no candidate keeps the hint.
    """
    su, tu = hint
    coarse = template.level("coarse").vertices
    ups = np.array([_rigid_part(t, coarse)[:3, :3] @ su for t in transforms])
    keep = np.degrees(np.arccos(np.clip(ups @ tu, -1.0, 1.0))) <= UP_TOLERANCE
    if keep.any():
        return cands[keep], scores[keep], transforms[keep]
    turns = _hint_turns(template, target, hint)
    return (turns, *_search_orientation(template, target, turns, cfg, plan))


def _hint_turns(template: Template, target: TargetSurface, hint) -> np.ndarray:
    """Rotations putting the hinted reference axis on the target's, turned about it (see :func:`candidate_alignments`)."""
    su, tu = hint
    return candidate_alignments(
        template.mesh.vertices, target.mesh.vertices, source_up=su, target_up=tu,
        source_faces=template.mesh.faces, target_faces=target.mesh.faces,
    )


def _alternative_rank(order: np.ndarray, chosen: int, transforms: np.ndarray, points: np.ndarray) -> int | None:
    """Rank in ``order`` of the best candidate turned more than ``ALTERNATIVE_TURN`` from ``chosen``."""
    r0 = _rigid_part(transforms[chosen], points)[:3, :3]
    for rank, k in enumerate(order):
        if rotation_angle(_rigid_part(transforms[k], points)[:3, :3] @ r0.T) > ALTERNATIVE_TURN:
            return rank
    return None


def _opposite_rank(order: np.ndarray, chosen: int, transforms: np.ndarray, points: np.ndarray,
                   axis: np.ndarray) -> int | None:
    """Rank in ``order`` of the best candidate that puts the reference's ``axis`` the other way from ``chosen``.

    The candidate turned end over end: what the coverage check tries first,
    since a registration that leaves part of the scan uncovered has most
    often put the reference's stalk on the scan's blossom end.
    """
    a0 = _rigid_part(transforms[chosen], points)[:3, :3] @ axis
    for rank, k in enumerate(order):
        if (_rigid_part(transforms[k], points)[:3, :3] @ axis) @ a0 < 0:
            return rank
    return None


@dataclass(frozen=True, eq=False)
class _Orientation:
    """The initial alignment :func:`_choose_orientation` found.

    ``transform`` is the rigid start of the registration; ``scores``,
    ``chosen``, ``ends`` and ``confidence`` go to the
    :class:`~hortishape.registration.Registration`; ``alternative`` is the
    search's transform of the candidate the coverage check tries (the best
    one end over end from the chosen one, or, where every candidate keeps
    the chosen end, the best one turned more than ``ALTERNATIVE_TURN``
    from it; ``None`` if there is none), and ``alternative_index`` its index.
    """

    transform: np.ndarray
    scores: np.ndarray
    chosen: int
    ends: str
    confidence: float
    alternative: np.ndarray | None = None
    alternative_index: int = -1


def _choose_orientation(template: Template, target: TargetSurface, cfg: RegistrationConfig,
                        plan: RegistrationPlan, hint) -> _Orientation:
    """Step 1's search: candidates (``cfg.orientation``), each scored by a short stiff registration, the best kept.

    ``hint`` is ``None`` or a pair of axes (reference, target) the stalk
    keeps (see :func:`_up_hint`).
    """
    coarse = template.level("coarse")
    if cfg.orientation == "axis":
        cands, ends = _axis_candidates(template.axis(), _target_axis(target), cfg)
    else:
        ends = "searched"
        cands = candidate_alignments(
            template.mesh.vertices,
            target.mesh.vertices,
            source_faces=template.mesh.faces,
            target_faces=target.mesh.faces,
        )
    if cfg.orientation == "pca":
        t0 = cands[0] if hint is None else _hint_turns(template, target, hint)[0]
        return _Orientation(t0, np.zeros(0), -1, "pca", float("nan"))
    scores, transforms = _search_orientation(template, target, cands, cfg, plan)
    if hint is not None:
        cands, scores, transforms = _keep_hinted(template, target, cands, scores, transforms, hint, cfg, plan)
    if cfg.twists > 0 and hint is None:  # a hint's candidates are turns about it already
        # the 24 principal-axis candidates fix the stalk axis but only
        # sample the turn about it in 90-degree steps (and not at all
        # well when the two cross-axis variances are nearly equal)
        best = int(np.argmin(scores))
        base = _rigid_part(cands[best], template.mesh.vertices)
        own = template.axis().direction if cfg.orientation == "axis" else _symmetry_axis(template.mesh.vertices)
        axis = base[:3, :3] @ own
        centre = target.mesh.vertices.mean(axis=0)
        tw = _twist_candidates(cands[best], axis, centre, cfg.twists)[1:]
        tw_scores, tw_transforms = _search_orientation(template, target, tw, cfg, plan)
        cands = np.concatenate([cands, tw])
        scores = np.concatenate([scores, tw_scores])
        transforms = np.concatenate([transforms, tw_transforms])
    order = np.argsort(scores, kind="stable")
    if cfg.search_finalists > 1:
        # the final round: the best few judged again on the coarse level,
        # and the best candidate turned well away from the best, so that
        # the winner's margin is measured against a distinct orientation
        finalists = order[: cfg.search_finalists]
        distinct = _alternative_rank(order, int(order[0]), transforms, coarse.vertices)
        if distinct is not None and distinct >= cfg.search_finalists:
            finalists = np.append(finalists, order[distinct])
        f_scores, f_transforms = _search_orientation(template, target, cands[finalists], cfg, plan, level="coarse")
        search_scores = scores
        scores = np.full(len(scores), np.inf)
        scores[finalists] = f_scores
        transforms = transforms.copy()
        transforms[finalists] = f_transforms
        order = np.lexsort((search_scores, scores))
    chosen = int(order[min(cfg.orientation_rank, len(order) - 1)])
    rank = _alternative_rank(order, chosen, transforms, coarse.vertices)
    confidence = float("nan")
    if rank is None:
        return _Orientation(_refined_start(template, target, transforms[chosen], cfg, plan), scores, chosen, ends,
                            confidence)
    k = int(order[rank])
    if not np.isfinite(scores[k]):  # not a finalist: judge it as they were
        level = "coarse" if cfg.search_finalists > 1 else "search"
        scores = scores.copy()
        scores[k] = _search_orientation(template, target, cands[k : k + 1], cfg, plan, level=level)[0][0]
    confidence = 1.0 - scores[chosen] / scores[k] if scores[k] > 0 else 0.0
    flip = _opposite_rank(order, chosen, transforms, coarse.vertices, template.axis().direction)
    if flip is not None:
        k = int(order[flip])
    return _Orientation(_refined_start(template, target, transforms[chosen], cfg, plan), scores, chosen, ends,
                        float(confidence), transforms[k], k)
