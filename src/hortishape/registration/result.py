"""What a registration returns: :class:`Registration`, its :class:`IterationRecord` log and its :class:`RegistrationPlan`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..mesh import Mesh


@dataclass(frozen=True)
class IterationRecord:
    """One line of the registration log.

    Attributes
    ----------
    iteration : int
        0-based iteration number (orientation search not counted).
    level : str
        ``"coarse"``, ``"fine"``, ``"local"`` (``local_tail``: only the part of the
        fine level still moving) or ``"final"`` (the closing step).
    beta : float
        Stiffness, on the reference's scale.
    mean_distance : float
        Mean distance of the kept correspondences, mm (d_t).
    kept_fraction : float
        Fraction of vertices with a kept correspondence.
    seconds : float
        Wall time of the iteration.
    """

    iteration: int
    level: str
    beta: float
    mean_distance: float
    kept_fraction: float
    seconds: float


@dataclass(frozen=True)
class RegistrationPlan:
    """The choices a :class:`RegistrationConfig` leaves to the data, as made once for one reference.

    :func:`register` resolves every ``"auto"`` option from the reference
    before its first step and records the result here (in the
    :class:`Registration` and in ``hortishape build``'s logs).

    Attributes
    ----------
    orientation : str
        ``"axis"``, ``"search"``, ``"pca"``, ``"none"`` (the configured method),
        or ``"given"`` (an ``initial_transform``, or three landmarks or more).
    search_taper : bool
        Whether the orientation search's global steps fit a taper (``search_taper``).
    warp : str
        The global warp: ``"affine"``, ``"taper"``, ``"quadratic"`` or ``"none"`` (``warp``).
    warp_ridge : float
        The damping of the warp's Gauss-Newton steps (``warp_ridge``).

    Examples
    --------
    >>> RegistrationPlan("axis", True, "taper", 0.001).warp
    'taper'
    """

    orientation: str
    search_taper: bool
    warp: str
    warp_ridge: float


@dataclass(frozen=True, eq=False)
class Registration:
    """Result of :func:`register`.

    Attributes
    ----------
    vertices : (n, 3) float64 ndarray
        Deformed reference vertices, in the target's coordinates; vertex ``j``
        corresponds to reference vertex ``j``.
    faces : (m, 3) int64 ndarray
        The reference's faces.
    transform : (4, 4) float64 ndarray
        The rigid part, reference -> target coordinates: the rotation of
        ``affine`` (polar decomposition), moving the reference's centroid
        where ``affine`` does.
    affine : (4, 4) float64 ndarray
        The global part: initial alignment composed with all global (rigid or
        affine) steps and the affine approximation of the warp. Equal to
        ``transform`` when every global step was rigid and there was no warp.
    placed : (n, 3) float64 ndarray or None
        The reference placed globally (initial alignment, warp and global
        steps) before the elastic displacements: ``vertices - placed`` is
        the elastic displacement, and a triangle turned by more than 90
        degrees from its placed self is folded.
    log : tuple of IterationRecord
        Per-iteration log.
    converged : bool
        Whether the convergence test passed before ``max_iterations``.
    orientation_scores : (k,) float64 ndarray
        Score of each initial-alignment candidate, the twist candidates
        after the axis or principal-axis ones (lower is better; empty
        without a search): the coarse-level score of the finalists
        (``search_finalists``), ``inf`` for the others. With an axis hint,
        only the candidates that keep it.
    orientation_index : int
        The candidate chosen (-1 without a search).
    orientation_confidence : float
        The margin of the chosen orientation over the best distinct one (the
        best candidate turned more than ``ALTERNATIVE_TURN`` degrees from
        it), ``1 - score_chosen / score_distinct``, both judged at the same
        level: 0 is a tie, towards 1 the search was sure. Negative only when
        ``orientation_rank`` chose a worse candidate; ``nan`` without a
        search.
    orientation_ends : str
        How the ends were matched: ``"cavity"`` (``orientation="axis"``, both
        scans' cavity ends told apart: the other way was not tried),
        ``"searched"`` (both ways judged by the search), ``"pca"``, or ``""``
        (no search: ``initial_transform``, three landmarks or
        ``orientation="none"``).
    seconds : float
        Total wall time.
    plan : RegistrationPlan or None
        The choices made for this reference (see :class:`RegistrationPlan`).
    target_holes : int
        Holes the target had, closed by patches before it was registered
        (:func:`hortishape.registration.close_scan`).
    target_hole_share : float
        The patches' share of the closed target's surface.
    """

    vertices: np.ndarray
    faces: np.ndarray
    transform: np.ndarray
    log: tuple
    converged: bool
    orientation_scores: np.ndarray = field(default_factory=lambda: np.zeros(0))
    orientation_index: int = -1
    seconds: float = 0.0
    affine: np.ndarray = field(default_factory=lambda: np.eye(4))
    placed: np.ndarray | None = None
    orientation_confidence: float = float("nan")
    orientation_ends: str = ""
    plan: RegistrationPlan | None = None
    target_holes: int = 0
    target_hole_share: float = 0.0

    @property
    def mesh(self) -> Mesh:
        """The registered surface as a :class:`Mesh`."""
        return Mesh(self.vertices, self.faces)
