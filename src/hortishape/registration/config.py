"""The registration's parameters: :class:`RegistrationConfig` and the heuristic constants.

Every constant the registration's heuristics use lives here, with the
measurement that set it, so that :func:`heuristics` can hand them all to a
build's resume fingerprint: a build made with other constants is not resumed.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np


#: Iterations run on the coarse level while beta (rescaled to the coarse
#: edge length) is at least this: the displacement field is then smooth over
#: at least about a coarse edge and barycentric interpolation loses little
#: (measured: 2.0 gave the same errors and cost two more fine iterations).
COARSE_MIN_BETA = 1.0

#: The global warp is used only if it brings the surfaces closer by more than
#: this fraction of the reference's RMS radius (0.2 mm on an apple) in mean
#: point-to-plane distance. A warp taken up for less mostly moves vertices
#: tangentially to fit small bumps: on a target made by a smooth 0.2 mm
#: deformation it moved the correspondence 0.32 mm off the truth, against
#: 0.06 mm without it.
WARP_MIN_GAIN = 0.005
#: The warp's Gauss-Newton steps stop when one takes less than this fraction
#: off the mean point-to-plane residual. Damped towards the current map, the
#: steps of a weakly seen coefficient (a pepper's quadratic terms) keep
#: creeping at about the same size, so a test on the step size alone ran all
#: 20 steps on most peppers and zucchini. Measured on the tuning set in random
#: poses (``benchmarks/registration.py --products pepper zucchini apple
#: --poses random --n 9``), before / after: dense error pepper 1.19 / 0.95 mm,
#: zucchini after the best turn 2.96 / 2.77, apple after it 0.64 / 0.64;
#: seconds per registration 2.90 / 2.83, 2.06 / 1.44, 2.84 / 2.23 (separate
#: runs on a machine otherwise idle).
WARP_STEP_GAIN = 0.01

#: ``warp="auto"`` takes the quadratic warp for a reference whose longest
#: principal axis is at least this many times the next (standard deviations).
#: Measured with ``benchmarks/registration.py`` (4 upright targets per class),
#: quadratic against affine: zucchini 49 -> 24 mm dense error, banana 3.0 ->
#: 1.8 mm, pear median 3.9 -> 1.3 mm; but pepper median 1.9 -> 5.3 mm (on a
#: round fruit the second-order terms are barely seen and slide the surface).
ELONGATED = 1.5

#: Damping of the warp's Gauss-Newton steps (``warp_ridge="auto"``): for a
#: round reference without lobes, and for every other one. On a round fruit
#: the residual barely sees the turn about the stalk axis: an apple's twist
#: shows only in a cheek 2-5 % fuller on one side. The stronger damping kept
#: the search's twist (1-4 degrees off on the benchmark's apples, about 0.7 mm
#: of dense error per degree); the weaker one lets the two-sided fit find it
#: (measured, the warp alone from the true pose turned 4 degrees: back to
#: within 0.1-1.6 degrees, against 3.1-3.7 with 0.05). Benchmark apples,
#: dense error upright / random: 0.83 / 1.33 mm with 0.05, 0.63 / 0.90 with
#: 0.01, 0.52 / 0.55 with 0.001. On a lobed reference the free twist turns
#: the lobes onto those of a target with another lobe count (peppers, random
#: pose: 1.47 -> 2.76 mm, one turned 14 degrees), and with the quadratic warp
#: of elongated ones the other terms wander (zucchini 6.9 -> 10.3 mm): those
#: keep 0.05, and so does the affine warp, not measured with the weak one.
ROUND_RIDGE = 0.001
LOBED_RIDGE = 0.05

#: A reference is lobed if an angular harmonic of order 3 or more of its
#: radius about the stalk axis (relative to the mean radius, over the middle
#: 60 % of its height; :func:`_lobes`) is at least this. Measured on the
#: 2,500-vertex coarse level: ten synthetic apples 0.001-0.003 (their five
#: ribs), ten peppers 0.034-0.059; the real scans in the YCB set: orange
#: 0.003, lemon 0.006, apple 0.010 and pear 0.012 below, peach 0.017 (its
#: suture), plum and strawberry 0.020 above.
LOBED = 0.015

#: Filter (c) (rays crossing the reference) is skipped in an iteration whose
#: kept hits are all nearer than this many edge lengths of the level: a
#: shorter ray can cross the reference only where it folds back within half
#: an edge. Once the surface sits on the target every ray is that short
#: (measured on peppers: 0-46 of 40,000 kept rays are longer after the first
#: fine iteration, none after the third, and no ray crossed in any
#: iteration), and the ray structure of the deforming reference (40 ms at
#: 40k vertices) is not built. Testing only the longer rays instead changed
#: the result of one badly registered zucchini, where short rays do cross.
CROSSING_MIN_EDGES = 0.5

#: Once the stiffness schedule has ended and at most this share of the fine
#: level's vertices moved more than ``move_tolerance`` edge lengths in an
#: iteration, the iterations go on only round those vertices (``local_tail``):
#: the rest of the surface has stopped, bar its approach to a noisy scan's
#: noise, which the closing step makes anyway.
LOCAL_SHARE = 0.01
#: The vertices still moving, grown by this many rings of neighbours, are
#: the ones a local iteration moves; the rest hold still. At the last
#: stiffness (beta = 1 edge) a step spreads over about two rings.
LOCAL_RINGS = 4

#: A scan with holes (a structured-light scan where the scanner did not see)
#: is registered onto its holes closed by smooth patches
#: (:func:`hortishape.surface.fill_holes`); patches larger than this share
#: of the closed surface are refused: too much of it would be guessed.
MAX_HOLE_SHARE = 0.25
#: Whether the orientation search takes a ray's hit on a patch for a
#: correspondence (the elastic iterations never do: the patch is no data).
SEARCH_PATCH_DATA = True

#: The orientation search's stiffness is that of the schedule's start on a
#: reference of this many vertices (the paper's apple), whatever the
#: reference's own count. Eq. 8's beta is a smoothing length in edges, so
#: a search defined at the reference's resolution was stiffer in
#: millimetres on a coarse reference, and its choice depended on the vertex
#: count asked for: one pepper came out upside down with a 3,000-20,000
#: vertex reference and right with 40,000. Measured with the search alone on
#: the pairs of ``benchmarks/registration.py`` (4 targets x 2 poses x 5
#: classes, references of 5,000 vertices and of the paper's count), wrong
#: orientations (more than 45 degrees): 4 of 80 at the reference's
#: resolution, 0 of 80 at 30,000 vertices; with 0.7, 0.5 or 0.35 times
#: that stiffness 5, 7 and 14 of 80.
SEARCH_VERTICES = 30_000

#: Largest turn (degrees) the rigid refinement after the orientation search
#: may make; the search's candidates lie within about 25 degrees of the truth
#: when right (measured on apples and peppers), neighbouring lobes 90 apart.
MAX_REFINE_TURN = 35.0

#: Degrees filter (a) allows on the coarse level beyond ``max_angle``. Its
#: vertex normals stray from the full reference's where the surface bends
#: within a few coarse edges (measured, 2,500 vertices: up to 15 degrees on
#: a pepper's stalk, 33 on a pear's, 49 on an apple's; median 0.3-1.1). With
#: the paper's 30 degrees there, a pepper's stalk that overshoots the scan's
#: found no correspondence and stayed in the air (stalk tip error 7.6 mm on
#: one pepper in a random pose, 1.1 mm upright); with 45: benchmark stalk
#: tip, pepper random pose 4.0 -> 1.2 mm, upright 1.4 -> 1.1, other classes
#: within 0.6 mm, dense error unchanged.
COARSE_ANGLE_SLACK = 15.0

#: ``coverage_check``: a registration leaves the scan uncovered if more than
#: this fraction of the scan's vertices lie farther than ``UNCOVERED_EDGES``
#: edge lengths of the reference from the registered surface.
UNCOVERED_MAX = 0.01
UNCOVERED_EDGES = 2.0
#: The alternative registration is kept only if it leaves at most this
#: fraction of what the first left uncovered. When both leave about as much
#: (a scan whose stalk is longer than the reference's: 3.52 and 3.53 % on a
#: synthetic pepper, seed 6002), the difference is a tie that says nothing
#: about the orientation, and the search's choice stands.
UNCOVERED_GAIN = 0.5
#: The check does not fire when the uncovered vertices lie, on average, at
#: most this fraction as far from the registered reference's stalk pole as
#: from its blossom pole (the poles of its ``fruit_axis``, when the cavities
#: tell its ends apart): the scan's stalk is longer than the reference's
#: and sits where the reference's does, so the ends are right. Upside down,
#: the scan's stalk lies at the reference's blossom end. On the second
#: generator's apples and peppers (development seeds 1-7 onto seed 0) the
#: check fired on 3 of 14 scans, each time with the uncovered part 6-19 mm
#: from the stalk pole and 70-80 mm from the blossom pole, and each time
#: kept the first registration after a second one (3.5 -> 6.9 s).
UNCOVERED_AT_STALK = 0.5

#: Three landmarks or more fix the orientation by their rigid fit unless they
#: lie nearly on a line: their spread across the line (second singular value)
#: must be at least this fraction of the spread along it.
LANDMARK_SPREAD = 0.05

#: With a hint of the stalk's direction (``up``, ``reference_up`` and
#: ``target_up``), orientations found by the search that put the reference's
#: stalk more than this many degrees from it are excluded: upside-down and
#: sideways ones. Wider than the lean of a scan on the bed, since the stiff
#: search leaves a candidate tilted by up to about 20 degrees more.
UP_TOLERANCE = 60.0

#: The chosen orientation's confidence is measured against the best-scored
#: search candidate turned from the chosen one by more than this (degrees);
#: ``coverage_check`` tries it when no candidate turns the reference end
#: over end (the cavities decided the ends).
ALTERNATIVE_TURN = 45.0


@dataclass(frozen=True)
class RegistrationConfig:
    """Parameters of :func:`register`; the defaults are the paper's.

    Attributes
    ----------
    n_iterations : int, default: 30
        Length of the linear stiffness schedule (section 3.1).
    beta_start, beta_end : float, default: 50.0, 1.0
        Stiffness at the first and last scheduled iteration (section 3.1),
        defined at the resolution of the reference.
    max_angle : float, default: 30.0
        Correspondence filter (a): normal tolerance in degrees (on the
        coarse level of ``multiresolution``, ``COARSE_ANGLE_SLACK`` more).
    distance_factor : float, default: 20.0
        Correspondence filter (b): hits farther than this times the previous
        iteration's mean distance are rejected (no limit in the first).
    distance_floor : float, default: 5.0
        Filter (b) never rejects a hit closer than this many edge lengths of
        the current level. Once the surface sits on the scan, d_t falls to
        thousandths of a millimetre and 20 d_t to a tenth: a part still
        millimetres off, such as a stalk tip overshooting the scan's, loses
        its last correspondences and stays in the air (measurements:
        ``docs/design-notes.md``). ``0`` is the paper's filter.
    check_crossings : bool, default: True
        Correspondence filter (c) against the reference itself.
    tolerance : float, default: 0.001
        Convergence: ``|d_t - d_(t-1)| / d_t < tolerance`` at ``beta_end``.
    edge_tolerance : float, default: 0.001
        Convergence also when ``|d_t - d_(t-1)|`` is below this many edge
        lengths of the reference: once the surface sits on the target, d_t
        keeps falling and the relative test alone may never pass. On a scan
        with noise it falls by about a tenth per iteration as the surface
        fits the noise, so the iterations run on to ``max_iterations``;
        0.005 ends them sooner at the cost of a little of the stalk tip's
        landing (measurements: ``docs/design-notes.md``).
    move_tolerance : float, default: 0.05
        Convergence also when no vertex of the reference moved more than
        this many edge lengths in each of the last two iterations: the
        surface has stopped, bar the uniform approach to a noisy scan that
        keeps d_t falling (the closing step ``final_beta`` lands it). A stalk
        tip still reaching for the scan's moves more, and keeps the
        iterations going. ``0`` turns the test off.
    local_tail : bool, default: True
        After the schedule, once no more than ``LOCAL_SHARE`` of the
        vertices still move (see ``move_tolerance``), iterate only round
        them (``LOCAL_RINGS``): rays, filters and eq. 8 on that part, the
        rest held still, until it stops too. On a noisy scan the whole
        surface would otherwise go on fitting the noise for ten or more
        iterations while a stalk tip finishes its way (measurements:
        ``docs/design-notes.md``). ``False``: every iteration moves the
        whole surface, as in the paper. Landmarks turn it off.
    max_iterations : int, default: 50
        Cap on the total number of iterations (schedule + convergence).
    orientation : {"axis", "search", "pca", "none"}, default: "axis"
        Initial alignment. ``"axis"``: the reference's axis of near
        revolution put on the target's (:func:`hortishape.align.fruit_axis`),
        cavity end on cavity end when both scans' ends differ by at least
        ``end_contrast`` (else both ways), turned about it in ``axis_turns``
        steps, each candidate judged by a short coarse elastic
        registration. ``"search"``: the same judgement of all 24
        principal-axis rotations (the previous default; on
        real round fruit the principal axes point anywhere). With a hint
        (``up``, landmarks) both search the hint's turns. ``"pca"``: the
        paper's eq. 7 with deterministic axis signs. ``"none"``: the
        reference is used where it is (or where ``initial_transform`` puts
        it). How the choices compare on real scans: the README.
    end_contrast : float, default: 0.15
        ``orientation="axis"`` puts the cavity end on the cavity end, without
        trying the other way, when :attr:`hortishape.align.FruitAxis.contrast`
        of both scans is at least this (why 0.15: ``docs/design-notes.md``)
        and the cavity end of each has at least ``end_cavity`` of its surface
        in a cavity.
    end_cavity : float, default: 0.005
        The least share of a scan's surface in the cavity at its cavity end
        (:attr:`hortishape.align.FruitAxis.cavities`) for ``end_contrast`` to
        decide its ends: a dent of a few square millimetres is no stalk
        cavity (``docs/design-notes.md``).
    axis_turns : int, default: 4
        Turns about the axis that ``orientation="axis"`` tries, equally
        spaced from the one that puts the reference's widest direction
        across the axis on the target's (:func:`hortishape.align.axis_alignments`);
        the refinement after the search closes the rest. The search's
        residual tells turns apart poorly, so more turns do not help
        (``docs/design-notes.md``).
    search_iterations : int, default: 6
        Iterations of each orientation candidate's coarse registration.
    search_finalists : int, default: 3
        The best this many candidates of the search are judged again by the
        same short registration on the coarse level (2,500 vertices instead
        of 800), which decides (1: the search level decides). On the search
        level a candidate's score moves by about 5 % with the scan's
        triangulation alone (``docs/design-notes.md``).
    orientation_rank : int, default: 0
        Start from the candidate with this rank (0: the best score; the
        finalists first, by their coarse-level score).
        :func:`hortishape.pipeline.build_model` registers a scan again from
        the runner-up when the search's choice was close or the result is an
        outlier among the population, and keeps the one that agrees with the
        others.
    search_affine : bool, default: True
        The global step of the orientation search's short registrations is
        an affine least-squares fit of the kept pairs instead of a rigid one
        (falling back to rigid as for ``affine``), and the refinement starts
        from the rotation of the winner's affine map. Width and depth vary
        independently of a fruit's anatomy (Table 1: 82 +/- 4 and
        82 +/- 4 mm for apples); a rigid fit turns a reference to lay its
        wider side along the scan's wider side (``docs/design-notes.md``).
    search_taper : {"auto", True, False}, default: "auto"
        The global step of the search's short registrations also fits a
        taper about the reference's symmetry axis (cross-sections widening
        linearly along it; :func:`_taper_step`), so that a scan whose top is
        wider than the reference's bottom is not fitted better upside down.
        ``"auto"``: for a round reference only (one that ``warp="auto"``
        tapers); on an elongated one the taper is part of what tells the
        ends apart (a zucchini's club; ``docs/design-notes.md``).
    coverage_check : bool, default: True
        After the registration, the fraction of the scan's vertices (20,000
        of them, evenly spread) farther than ``UNCOVERED_EDGES`` (2) edge
        lengths of the reference from the registered surface is measured;
        above ``UNCOVERED_MAX`` (1 %) part of the scan was not reached (its
        stalk, when the reference came out upside down; not when that part
        lies at the reference's own stalk end, ``UNCOVERED_AT_STALK``), and the
        registration is run again from the best search candidate that turns
        the reference end over end from the chosen one (or, when the
        cavities decided the ends, from the best one turned by more than
        ``ALTERNATIVE_TURN`` (45) degrees), and kept if it leaves at most
        ``UNCOVERED_GAIN`` (half) as much uncovered. Costs a nearest-vertex
        query, and a second registration when it fires.
    up : (3,) tuple of float, optional
        The reference and every target stand with the stalk towards this
        direction (e.g. ``(0, 0, 1)``: scanned upright on the scanner's bed):
        the orientations the search finds that put the reference's stalk
        more than ``UP_TOLERANCE`` degrees from it are excluded, and turns
        about it are searched if none is left (``reference_up`` and
        ``target_up`` of :func:`register`, for both). Default: no hint.
    twists : int, default: 0
        After the principal-axis candidates, the best one is also tried
        turned about its stalk axis (the principal axis whose variance
        stands apart) in this many equal steps (0: not at all). Off by
        default: the search residual does not tell twists apart reliably
        (``docs/design-notes.md``).
    rigid_steps : bool, default: True
        The global least-squares step (rigid or affine, see ``affine``) in
        every iteration.
    affine : {"none", "stiff", "all"}, default: "none"
        A globally affine step inside the loop: ``"stiff"``: the global step
        of the search (whatever ``search_affine``) and of the coarse-level
        iterations is an affine
        least-squares fit of the kept pairs instead of a rigid one;
        ``"all"``: in every iteration; ``"none"``: rigid steps only. Affine
        fits that would reflect or squash the surface (a singular value
        outside [1/3, 3]) fall back to rigid (why rigid by default:
        ``docs/design-notes.md``).
    warp : {"auto", "affine", "taper", "quadratic", "none"}, default: "auto"
        The paper's initializing globally affine step (section 1: "an
        initializing globally affine step is added. Therefore, using only
        translation of the vertices is sufficient"): after the orientation
        search, a two-sided point-to-plane ICP of a global map of the
        undeformed coarse level (:func:`_fit_warp`), so that size and
        proportion differences are taken up before the translation-only
        elastic steps, which move vertices along their normals only and
        cannot stretch a surface along itself. ``"quadratic"`` adds the
        second-order terms (taper, bend); ``"taper"`` adds only a taper
        about the reference's stalk axis (:func:`_taper_basis` about
        :func:`_concavity_axis`: the
        cross-sections widen or narrow along the axis), which fruit vary by
        and an affine map cannot take up; ``"auto"`` takes the quadratic map
        for elongated references (``ELONGATED``) and the taper for round
        ones (how they compare: ``docs/design-notes.md``).
    warp_ridge : float or "auto", default: "auto"
        Damping of the warp's Gauss-Newton steps, relative to the mean
        diagonal of the normal equations. ``"auto"``: ``ROUND_RIDGE`` (weak)
        for a round reference without lobes, whose warp then also finds the
        turn about the stalk axis, ``LOBED_RIDGE`` otherwise (see there).
    warp_prior : float, default: 0.01
        Weight, relative to the same diagonal, of a penalty pulling the
        quadratic terms of the warp towards zero. The sides of an elongated
        fruit barely constrain sliding along its length, and a free quadratic
        slides the middle of a zucchini to match a different neck or club
        (``docs/design-notes.md``).
    final_beta : float or None, default: 0.1
        Stiffness of the closing step that lands matched vertices on the
        target (``None``: no closing step).
    multiresolution : bool, default: True
        Run stiff iterations on the coarse level (much faster; see the
        package notes). ``False`` runs every iteration on the full reference.
    """

    n_iterations: int = 30
    beta_start: float = 50.0
    beta_end: float = 1.0
    max_angle: float = 30.0
    distance_factor: float = 20.0
    distance_floor: float = 5.0
    check_crossings: bool = True
    tolerance: float = 1e-3
    edge_tolerance: float = 1e-3
    move_tolerance: float = 0.05
    local_tail: bool = True
    max_iterations: int = 50
    orientation: str = "axis"
    end_contrast: float = 0.15
    end_cavity: float = 0.005
    axis_turns: int = 4
    search_iterations: int = 6
    search_finalists: int = 3
    orientation_rank: int = 0
    twists: int = 0
    search_affine: bool = True
    search_taper: bool | str = "auto"
    coverage_check: bool = True
    rigid_steps: bool = True
    affine: str = "none"
    warp: str = "auto"
    warp_ridge: float | str = "auto"
    warp_prior: float = 0.01
    final_beta: float | None = 0.1
    multiresolution: bool = True
    up: tuple | None = None

    def __post_init__(self) -> None:
        if self.n_iterations < 1:
            raise ValueError(f"n_iterations must be >= 1, got {self.n_iterations}")
        if not (self.beta_start > 0 and self.beta_end > 0):
            raise ValueError("beta_start and beta_end must be positive")
        if not 0 < self.max_angle <= 180:
            raise ValueError(f"max_angle must lie in (0, 180] degrees, got {self.max_angle}")
        if self.distance_factor <= 0:
            raise ValueError("distance_factor must be positive")
        if self.distance_floor < 0:
            raise ValueError("distance_floor must be >= 0")
        if self.move_tolerance < 0:
            raise ValueError("move_tolerance must be >= 0")
        if self.max_iterations < self.n_iterations:
            raise ValueError("max_iterations must be at least n_iterations")
        if self.orientation not in ("axis", "search", "pca", "none"):
            raise ValueError(f"orientation must be 'axis', 'search', 'pca' or 'none', got {self.orientation!r}")
        if not 0 <= self.end_contrast <= 1:
            raise ValueError(f"end_contrast must lie in [0, 1], got {self.end_contrast}")
        if not 0 <= self.end_cavity <= 1:
            raise ValueError(f"end_cavity must lie in [0, 1], got {self.end_cavity}")
        if self.axis_turns < 1:
            raise ValueError(f"axis_turns must be >= 1, got {self.axis_turns}")
        if self.affine not in ("stiff", "all", "none"):
            raise ValueError(f"affine must be 'stiff', 'all' or 'none', got {self.affine!r}")
        if self.warp not in ("auto", "none", "affine", "taper", "quadratic"):
            raise ValueError(f"warp must be 'auto', 'affine', 'taper', 'quadratic' or 'none', got {self.warp!r}")
        if self.search_finalists < 1:
            raise ValueError(f"search_finalists must be >= 1, got {self.search_finalists}")
        if self.orientation_rank < 0:
            raise ValueError(f"orientation_rank must be >= 0, got {self.orientation_rank}")
        if self.twists < 0:
            raise ValueError(f"twists must be >= 0, got {self.twists}")
        if self.search_taper not in ("auto", True, False):
            raise ValueError(f"search_taper must be 'auto', True or False, got {self.search_taper!r}")
        if self.warp_ridge != "auto" and not (isinstance(self.warp_ridge, (int, float)) and self.warp_ridge >= 0):
            raise ValueError(f"warp_ridge must be 'auto' or a number >= 0, got {self.warp_ridge!r}")
        if self.warp_prior < 0:
            raise ValueError("warp_prior must be >= 0")
        if self.final_beta is not None and self.final_beta <= 0:
            raise ValueError("final_beta must be positive or None")
        if self.up is not None:
            u = np.asarray(self.up, dtype=np.float64).reshape(-1)
            if u.shape != (3,) or not np.isfinite(u).all() or not np.linalg.norm(u) > 0:
                raise ValueError(f"up must be 3 finite numbers, not all zero, got {self.up!r}")
            # a plain tuple of unit length: the same hint always reads (and fingerprints) the same
            object.__setattr__(self, "up", tuple(float(x) for x in u / np.linalg.norm(u)))

    def betas(self) -> np.ndarray:
        """The linear stiffness schedule, ``(n_iterations,)``."""
        return np.linspace(self.beta_start, self.beta_end, self.n_iterations)


def heuristics() -> dict:
    """Every heuristic constant of the registration and of :func:`hortishape.align.fruit_axis`, by name.

    A build's resume fingerprint holds them, so that work done with other
    constants is not taken for this one's.

    Returns
    -------
    dict of str to int, float or tuple

    Examples
    --------
    >>> h = heuristics()
    >>> h["SEARCH_VERTICES"], h["align.END_CONE"]
    (30000, 30.0)
    """
    from .. import align

    def constants(module) -> dict:
        return {k: v for k, v in vars(module).items()
                if k.isupper() and not k.startswith("_") and isinstance(v, (int, float, tuple))}

    out = constants(sys.modules[__name__])
    out.update({f"align.{k}": v for k, v in constants(align).items()})
    return dict(sorted(out.items()))
