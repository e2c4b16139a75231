"""Elastic surface registration: RN-ICP-T (paper section 2.2.2, eq. 8).

One module per stage, :func:`register` (in ``core``) the coordinator that
runs them in order:

=====================  ===============================================================================================
``config``             :class:`RegistrationConfig` and every heuristic constant
``template``           the reference prepared once (:func:`prepare_reference`): fine, coarse and search levels
``orientation``        step 1: candidate orientations, the stiff search that scores them, hints
``warp``               step 1: the global polynomial warp ("initializing globally affine step")
``correspondences``    step 2: normal-ray correspondences and the paper's three filters
``elastic``            step 2: the rigid or affine step and the elastic step of eq. 8, its solvers
``folds``              the closing step's and the end's fold checks and repair
``result``             :class:`Registration`, its log and its :class:`RegistrationPlan`
``batch``              :func:`register_many`, in worker processes
=====================  ===============================================================================================

A reference (template) surface is deformed onto a target surface so that each
reference vertex lands on the anatomically corresponding place of the target.
One call of :func:`register` does:

1. **Initial alignment** (section 2.2.1, eqs. 1-7). The paper aligns the
   principal axes; they do not fix the signs and, for round fruit, point
   anywhere (on real scans they did). By default (``orientation="axis"``)
   each surface's axis of near revolution and its cavity end are found
   instead (:func:`hortishape.align.fruit_axis`), and the reference's axis is
   put on the target's, cavity end on cavity end (both ways when either
   scan's ends look alike), turned about it in ``axis_turns`` steps
   (:func:`hortishape.align.axis_alignments`); ``orientation="search"``
   takes every proper rotation between the two sets of surface principal
   axes (24, see :func:`hortishape.align.candidate_alignments`). Either
   way, each candidate is tried with a short, stiff
   elastic registration of a very coarse reference (800 vertices, with the
   stiffness of a ``SEARCH_VERTICES`` one; optionally, ``twists``, the
   winner is also tried turned about its stalk axis in equal steps); the
   best ``search_finalists`` are tried again on the coarse level, and the one
   with the lowest residual there is kept. The global steps
   of these short registrations are affine (``search_affine``): the width
   and depth of a fruit vary independently of its anatomy, and a rigid fit
   turns the reference to lay its wider side along the scan's; for a round
   reference they also fit a taper (``search_taper``), or a pepper wider at
   the top than the reference fits better upside down. The rotation
   of the winner's affine map is then refined by rigid point-to-plane ICP
   (see ``orientation`` in :class:`RegistrationConfig`), unless that turns
   it by more than ``MAX_REFINE_TURN`` (it has then slid onto a neighbouring
   lobe) or a short stiff registration started from the refined rotation
   scores worse than one started from the search's.
   Then the paper's "initializing globally affine step" (section 1): a
   two-sided point-to-plane ICP of a global affine map plus a taper (for
   elongated references, ``warp="auto"``, a quadratic map), kept only if it
   brings the surfaces clearly closer
   (``WARP_MIN_GAIN``).
   Known limitation: the twist about a fruit's (near-)symmetry axis is only
   weakly determined by the geometry (a cheek 2-5 % fuller on one side of an
   apple, the largest of 3-4 pepper lobes); for a round reference without
   lobes the warp is damped weakly enough to find it (``ROUND_RIDGE``). On a
   straight zucchini little but a slightly bent stalk fixes it, and the
   registration follows the stalk (``docs/design-notes.md``).
2. **RN-ICP-T iterations**: normal-ray correspondences with the three filters
   (:mod:`hortishape.registration.correspondences`; the crossing filter (c) on the fine level
   only), a least-squares rigid (or, see ``affine``, affine) step on the
   kept pairs, and the translation-only elastic step of eq. 8,
   ``(beta^2 M^T M + W) X = W (T - S)`` with ``M`` the edge-incidence matrix
   and ``W`` the 0/1 weights, so that vertices without a correspondence move
   with their neighbours. ``beta`` decreases linearly from 50 to 1 over 30
   iterations (section 3.1).
3. **Convergence** at the final stiffness: iterations continue at
   ``beta_end`` until ``|d_t - d_(t-1)| / d_t < 0.001``.
4. **Coverage check**: if the registered surface leaves part of the scan
   uncovered (more than ``UNCOVERED_MAX`` of its vertices farther than
   ``UNCOVERED_EDGES`` edge lengths from it: the scan's stalk, when the
   reference came out upside down), the registration is run again from the
   best search candidate end over end from the chosen one (where the
   cavities decided the ends: the best one turned well away from it), and
   that result is kept if it leaves at most ``UNCOVERED_GAIN`` (half) as
   much uncovered (``coverage_check``).

Design choices where the paper is silent or ambiguous
------------------------------------------------------
* *Stiffness schedule vs. convergence.* The paper gives both a fixed
  schedule (50 -> 1 over 30 iterations) and a convergence test. Stopping the
  schedule as soon as the test passes leaves a stiff, poorly fitted surface
  (``d_t`` changes little between stiff iterations), so the schedule always
  runs to the end and the test decides when to stop iterating at ``beta_end``
  (capped by ``max_iterations``; :class:`~hortishape.ConvergenceWarning` when
  the cap is hit).
* *d_t* is the mean distance of the kept correspondences of iteration t (the
  same number filter (b) uses).
* *Stiffness and resolution.* Eq. 8's energy ``beta^2 sum_edges |X_i - X_j|^2 +
  sum_i w_i |X_i - D_i|^2`` smooths the displacement over a length of about
  ``beta`` edge lengths, so ``beta`` is defined at the resolution of the
  reference given (the paper's 30k-vertex apple) and rescaled by the edge
  length ratio on coarser levels.
* *Multiresolution for speed.* Iterations whose smoothing length spans at
  least ``COARSE_MIN_BETA`` coarse edges run on a coarse version of the
  reference (about 2,500 vertices) whose displacement is carried to the full
  reference by barycentric interpolation; only the last, nearly elastic
  iterations run on the full-resolution mesh. Coarse systems are factorised
  by sparse LDL^T (QDLDL, whose symbolic analysis is reused across
  iterations); fine ones, which are well conditioned at low
  ``beta``, are solved by warm-started Jacobi-preconditioned conjugate
  gradients. Filter (a) allows ``COARSE_ANGLE_SLACK`` more degrees on the
  coarse level, whose normals stray from the surface's on a thin stalk.
* *Landing on the surface.* A last step with ``final_beta`` (default 0.1)
  moves every matched vertex (almost) onto its correspondence, which is
  needed for the paper's sub-0.1 mm geometric errors; any triangle that
  would fold (its normal turning by more than 90 degrees in the step) keeps
  its vertices' previous positions.
* *No folds.* Triangles still folded at the end (turned by more than 90
  degrees from the placed reference, or from a neighbour) get the harmonic
  fill-in of the displacement around them (``_repair_folds``).
"""

from .config import RegistrationConfig, heuristics
from .correspondences import TargetSurface, find_correspondences, prepare_target
from .core import plan_registration, register
from .batch import register_many
from .result import IterationRecord, Registration, RegistrationPlan
from .template import Template, close_scan, prepare_reference

__all__ = [
    "IterationRecord",
    "Registration",
    "RegistrationConfig",
    "RegistrationPlan",
    "TargetSurface",
    "Template",
    "close_scan",
    "find_correspondences",
    "heuristics",
    "plan_registration",
    "prepare_reference",
    "prepare_target",
    "register",
    "register_many",
]
