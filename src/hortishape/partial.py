"""Fitting a shape model to a partial scan: the whole shape, its volume, and how sure they are.

A depth camera sees one side of a fruit; a scan may miss what lay on the
table. :func:`fit_partial` finds the pose and the model coefficients that
explain the points that were seen, and the **posterior** model: the shape
model conditioned on those points. A PCA model is a Gaussian process with a
low-rank covariance (Scalismo's view of it), so conditioning on noisy
observations is closed-form linear algebra in the ``k`` coefficients:

- each kept point ``y_j`` is matched to the nearest vertex ``i(j)`` of the
  current shape, and observes that vertex along its normal ``n_i``:
  ``n_i . (C y_j) = n_i . (x_bar_i + Phi_i c) + e_j`` with ``e_j ~ N(0, s^2)``
  (a point on a surface says where the surface is, not which vertex it is);
- the coefficients ``c`` (in standard deviations) have the prior ``N(0, I)``;
- their posterior is ``N(c*, S)``, ``S = (A^T A / s^2 + I)^-1``, where ``A``
  stacks the rows ``n_i^T Phi_i``; ``c*`` is the maximum a posteriori fit,
  found jointly with the rigid pose ``C`` by Gauss-Newton;
- every vertex's posterior covariance is ``Phi_i S Phi_i^T`` (its standard
  deviation along the surface normal is reported); the volume is linearised
  about ``c*`` (its gradient with respect to a vertex is a sixth of the
  summed cross products of the opposite edges), so its variance is
  ``g^T S g``.

The pose is searched first. Most fruit are nearly bodies of revolution, and
every normal line of a body of revolution meets its axis: the line the
points' own normal lines meet best is the fruit's axis, found from one side
as well as from all round, whatever the fruit's proportions
(:func:`_revolution_axis`). When the points show such a line, the model's
axis is put on it, either end up, turned about it in ``AXIS_TURNS`` steps,
and each start is ranked by a few Gauss-Newton iterations with the modes.
When they do not (a sphere, a peach), the 60 rotations of the icosahedral
group are each refined by a trimmed rigid ICP of the points against the
model's mean; the best distinct ones are screened by a short fit with the
modes (the mean alone ranks them poorly), the best of those is also tried
turned about the fruit's axis in ``TWISTS`` steps (a view of one side of a
round fruit often leaves the turn open, and a wrong turn explains the
points with the wrong coefficients). Either way the best few are fitted in
full. Points far from the fitted surface (a table, a neighbouring fruit)
are trimmed at every step: farther than ``TRIM_MAD`` robust standard
deviations of the distances, and never closer than ``TRIM_FLOOR_MM``.

The result is a mixture: each pose fitted in full contributes its Laplace
approximation (coefficients and pose together; the pose's uncertainty is
marginalised: a larger fruit placed farther explains a cap seen from one
side almost as well as a smaller one nearer), weighted by its posterior
density. The completed surface is the best pose's; the volume and its SD
are the mixture's.

The noise ``s`` is, by default, estimated from the residuals of the kept
points; it then holds both the sensor's noise and what the model cannot
represent of this fruit. What the model cannot represent is smooth, so
neighbouring residuals are not independent: the distance at which their
correlation falls below 1/e is measured on the fit, and the points within it
of each other count together as one observation (each point weighs one over
the points around it). Without this, thousands of points would make the
posterior far too sure.

A model of 12 or 30 shapes knows its population only roughly. When it holds
its training shapes' coefficients (``scores_``, every mode kept), leaving
each out in turn calibrates it (``calibrate``): the prior of each mode is
widened to the spread of the left-out shapes' coefficients, the principal
components of what the others' model cannot represent of them become extra
modes, and each left-out shape, completed from the same view by the model of
the others, gives the error to expect for this view (the reported SD is the
larger of that and the posterior's). The models of the shapes but one, each
completing the same points with the pose free, differ: their spread (a
jackknife) is added, since another dozen shapes would have made another
completion. Last, the surface not seen may lie off
by the size of the residuals as a whole: that is added to every vertex's SD
and, over the unseen area, to the volume's.

None of this knows a fruit of another population than the model's: its
unseen side can be off by more than the model's own spread. What such a fit
shows is residuals far above the points' own noise (their spread about a
plane through each point's neighbours, which no model enters). What the
model misses of the points beyond that noise (``misfit_mm``), it may miss by
``MISFIT_REACH`` times as much, all one way, where it saw nothing: that is
added to the SD of the unseen vertices and, over their area, of the volume.
Beyond ``MISFIT_RATIO`` times the points' noise, the fit also warns
(:class:`~hortishape.errors.FitWarning` and :attr:`PartialFit.warnings`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from ._rng import RandomState, as_generator
from .align import _rotation_between, fruit_axis, rotation_about, rotation_angle
from .errors import FitWarning, HortishapeError
from .mesh import Mesh
from .surface import closest_points, signed_volume, vertex_areas, vertex_normals

__all__ = ["PartialFit", "PartialFitter", "fit_partial", "write_partial_fit"]

#: Robust standard deviations (1.4826 MAD) of the point distances beyond which a point is trimmed.
TRIM_MAD = 4.0
#: A point is never trimmed nearer the surface than this, mm.
TRIM_FLOOR_MM = 1.0
#: Points used to search the pose, and at most used to fit (a random subset of the cloud).
SEARCH_POINTS = 400
FIT_POINTS = 2500
#: Model vertices the correspondences are searched among while fitting (evenly spread).
FIT_VERTICES = 8000
#: Rigid ICP iterations per rotation of the pose search; the best distinct rotations screened with
#: the modes (a short fit on the search's points), and the best of those fitted in full.
SEARCH_ITERATIONS = 8
SCREENED = 8
SCREEN_ITERATIONS = 5
FINALISTS = 2
#: Turns about the fruit's axis tried from the best rotation (equally spaced); fits that end within
#: SAME_POSE degrees of each other are one pose.
TWISTS = 12
SAME_POSE = 10.0
#: The points' own axis of revolution (the line their normal lines meet best) gives the starts
#: instead of the search above when it is clearly the best line (its misfit below AXIS_GAP times
#: the next line's): the model's axis on it, either end up, turned about it in AXIS_TURNS steps.
#: Normals from the AXIS_NEIGHBOURS nearest points; lines fitted to at most AXIS_POINTS points.
AXIS_TURNS = 6
#: Gauss-Newton iterations that rank those starts (with the shape's own normals).
AXIS_ITERATIONS = 8
AXIS_GAP = 0.25
AXIS_NEIGHBOURS = 20
AXIS_POINTS = 4000
#: Poses whose share of the posterior mixture is below this are left out of it.
MIN_SHARE = 0.01
#: The calibration's misfit modes: the leading ones, holding this share of the misfits' variance.
MISFIT_SHARE = 0.95
#: Gauss-Newton iterations of the joint pose and shape fit; the surface normals are computed again
#: every this many.
FIT_ITERATIONS = 12
NORMALS_EVERY = 3
#: Residuals closer than the correlation length are not independent observations: the length is
#: where the residuals' correlation falls below 1/e, within these bounds (mm); before the first
#: fit, the start value.
CORRELATION_MM = (2.0, 30.0)
START_CORRELATION_MM = 10.0
#: The noise used until it is estimated from the residuals, mm (about twice the residuals of a fit in
#: the right pose, 0.2-0.35 mm: at 1 mm the prior outweighed the points and the pose search kept the
#: poses the mean fits; docs/design-notes.md); and its floor.
START_NOISE_MM = 0.5
MIN_NOISE_MM = 0.05
#: A surface point counts as observed when a kept point lies this many point spacings from it.
OBSERVED_SPACINGS = 2.0
#: Normals, when given, must agree within this angle (degrees) for a pair to count.
NORMAL_ANGLE = 60.0
#: Large planes among the points (a table, a wall) are dropped first: RANSAC trials, the distance
#: (mm) within which a point is on a plane, and the share of the points a plane must hold.
PLANE_TRIALS = 200
PLANE_MM = 1.0
PLANE_SHARE = 0.15
#: A fit whose residuals exceed MISFIT_RATIO times the points' own noise (the spread of each point's
#: MISFIT_NEIGHBOURS nearest about their plane) is warned about: the fruit may lie outside the
#: model's population.
MISFIT_RATIO = 2.0
MISFIT_NEIGHBOURS = 20
#: What the model misses of the points beyond their own noise (the residuals' RMS and the points'
#: noise, in quadrature), the surface not seen may miss by this many times, all of it one way: the
#: fit bends the modes to meet what was seen, and nothing meets what was not. Added to the SD of the
#: unseen vertices and, over their area, of the volume (tuned on one population's model completing
#: another's; docs/design-notes.md).
MISFIT_REACH = 2.0
#: Refusals: too few points, a cloud flatter than this ratio of its two widest extents, too small a cloud.
MIN_POINTS = 50
MIN_FLATNESS = 0.05
MIN_EXTENT_FRACTION = 0.2


@dataclass(frozen=True, eq=False)
class PartialFit:
    """The model fitted to a partial scan, and its posterior.

    Attributes
    ----------
    vertices : (n, 3) float64 ndarray
        The completed surface (the posterior mean), in the points' coordinates, in the model's vertex order.
    faces : (m, 3) int64 ndarray
        The model's triangles.
    sd : (n,) float64 ndarray
        Standard deviation of every vertex along the surface normal, mm: the
        larger of the posterior's and the leave-one-out's, with the residuals'
        size added, and where the surface was not seen the model's misfit
        (see the module notes).
    coefficients : (k,) float64 ndarray
        Posterior mean of the model's coefficients at the best pose, in its standard deviations.
    covariance : (k, k) float64 ndarray
        Their posterior covariance at that pose.
    pose : (4, 4) float64 ndarray
        Rigid transform from the model's frame to the points' coordinates.
    volume_ml, volume_sd_ml : float
        Enclosed volume and its standard deviation, mL: the mean and SD of
        the posterior mixture over the poses (see ``poses``).
    residual_mm : float
        Mean distance of the kept points to the completed surface, mm.
    noise_mm : float
        The observation noise ``s`` used, mm.
    observed_fraction : float
        Share of the completed surface's area within reach of a kept point.
    n_points, n_kept : int
        Points given, and points kept by the last fit (of those used).
    n_planar : int
        Points dropped as lying on a large plane (a table, a wall).
    correlation_mm : float
        Distance at which the fit's residuals stop being correlated (1/e):
        points closer than this count together as one observation.
    calibrated : bool
        Whether the prior was widened by the model's leave-one-out (see
        :func:`fit_partial`'s ``calibrate``).
    poses : tuple of (float, float)
        ``(share, angle)`` of every pose fitted in full, best first: its
        share of the posterior mixture the volume and the SD come from, and
        its rotation's angle in degrees from the best. A second pose with a
        large share means the points leave the pose open (a round fruit seen
        from one side: its turn about the axis).
    point_noise_mm : float
        The points' own noise, mm: the median spread of each point's
        neighbours about their plane, which no model enters.
    misfit_mm : float
        What the model misses of the points beyond their own noise, mm: the
        kept points' RMS residual and ``point_noise_mm`` in quadrature (0
        when the residuals are the points' noise). ``MISFIT_REACH`` times it
        is added to the SD where the surface was not seen.
    warnings : tuple of str
        What a person should know: residuals far above the points' own noise
        (``MISFIT_RATIO`` times) say the model cannot represent this fruit
        where it was seen, so the completion of the side not seen, and its
        SD, may be off (a fruit of another population than the model's).
        Checked only when the noise is estimated (``noise="auto"``).
    """

    vertices: np.ndarray
    faces: np.ndarray
    sd: np.ndarray
    coefficients: np.ndarray
    covariance: np.ndarray
    pose: np.ndarray
    volume_ml: float
    volume_sd_ml: float
    residual_mm: float
    noise_mm: float
    observed_fraction: float
    n_points: int
    n_kept: int
    correlation_mm: float = float("nan")
    n_planar: int = 0
    poses: tuple = ()
    calibrated: bool = False
    point_noise_mm: float = float("nan")
    misfit_mm: float = 0.0
    warnings: tuple = ()

    def as_dict(self) -> dict:
        """The figures as plain JSON-able values (no per-vertex arrays)."""
        return {
            "units": "mm",
            "volume_ml": self.volume_ml,
            "volume_sd_ml": self.volume_sd_ml,
            "residual_mm": self.residual_mm,
            "noise_mm": self.noise_mm,
            "observed_fraction": self.observed_fraction,
            "n_points": self.n_points,
            "n_kept": self.n_kept,
            "n_planar": self.n_planar,
            "correlation_mm": self.correlation_mm,
            "calibrated": self.calibrated,
            "pose": self.pose.tolist(),
            "coefficients_sd": self.coefficients.tolist(),
            "coefficient_sd": np.sqrt(np.diag(self.covariance)).tolist(),
            "sd_mm": {"mean": float(self.sd.mean()), "max": float(self.sd.max())},
            "poses": [{"share": p, "angle_deg": a} for p, a in self.poses],
            "point_noise_mm": self.point_noise_mm,
            "misfit_mm": self.misfit_mm,
            "warnings": list(self.warnings),
        }


def _volume_gradient(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(n, 3)`` derivative of the enclosed volume with respect to every vertex."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    out = np.zeros_like(vertices)
    for corner, g in enumerate((np.cross(b, c), np.cross(c, a), np.cross(a, b))):
        for k in range(3):
            out[:, k] += np.bincount(faces[:, corner], weights=g[:, k], minlength=len(vertices))
    return out / 6.0


def _trim(distances: np.ndarray) -> np.ndarray:
    """The points to keep: not farther than TRIM_MAD robust SDs of the distances (and never within the floor)."""
    med = float(np.median(distances))
    spread = 1.4826 * float(np.median(np.abs(distances - med)))
    return distances <= max(med + TRIM_MAD * spread, TRIM_FLOOR_MM)


def _check_points(points, normals, model_extent: float) -> tuple[np.ndarray, np.ndarray | None]:
    y = np.asarray(points, dtype=np.float64)
    if y.ndim != 2 or y.shape[1] != 3:
        raise HortishapeError(f"points must have shape (k, 3), got {y.shape}")
    if len(y) < MIN_POINTS:
        raise HortishapeError(f"{len(y)} points are too few to fit a shape model to (at least {MIN_POINTS})")
    if not np.isfinite(y).all():
        raise HortishapeError("the points hold NaN or infinite coordinates")
    nrm = None
    if normals is not None:
        nrm = np.asarray(normals, dtype=np.float64)
        if nrm.shape != y.shape or not np.isfinite(nrm).all():
            raise HortishapeError(f"normals must be finite and of the points' shape {y.shape}, got {nrm.shape}")
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.divide(nrm, length, out=np.zeros_like(nrm), where=length > 0)
    spread = np.linalg.svd(y - y.mean(axis=0), compute_uv=False) / np.sqrt(len(y))
    extent = float(np.ptp(y, axis=0).max())
    if extent < MIN_EXTENT_FRACTION * model_extent:
        hint = " (in metres? multiply by 1000)" if extent * 1000 < 10 * model_extent else ""
        raise HortishapeError(f"the points span {extent:.3g} mm, too little of a {model_extent:.0f} mm model "
                              f"to fit{hint}")
    if spread[2] < MIN_FLATNESS * spread[1]:
        raise HortishapeError(f"the points are too flat to fit a shape to: they lie within "
                              f"{spread[2] / spread[1]:.1%} of a plane (a table or a wall, not a fruit?)")
    return y, nrm


def _drop_planes(points: np.ndarray, normals, model_extent: float, rng) -> tuple[np.ndarray, object, int]:
    """The points without the large planes among them (a table, a wall behind the fruit).

    A plane is found by RANSAC on a subset; it is dropped when it holds at
    least ``PLANE_SHARE`` of the points within ``PLANE_MM`` and spans more
    than the model's size (no fruit has a flat patch that large). At most
    two planes. Returns the points, their normals and how many were dropped.
    """
    dropped = 0
    for _ in range(2):
        if len(points) < 4 * MIN_POINTS:
            break
        sample = points[rng.choice(len(points), min(len(points), 2000), replace=False)]
        best, best_count = None, 0
        for _ in range(PLANE_TRIALS):
            a, b, c = sample[rng.choice(len(sample), 3, replace=False)]
            n = np.cross(b - a, c - a)
            if not np.linalg.norm(n) > 1e-9:
                continue
            n /= np.linalg.norm(n)
            count = int((np.abs((sample - a) @ n) < PLANE_MM).sum())
            if count > best_count:
                best, best_count = (a, n), count
        if best is None or best_count < PLANE_SHARE * len(sample):
            break
        on = np.abs((points - best[0]) @ best[1]) < PLANE_MM
        flat = points[on] - points[on].mean(axis=0)
        if float(np.ptp(flat @ np.linalg.svd(flat, full_matrices=False)[2][0])) < model_extent:
            break
        points = points[~on]
        normals = None if normals is None else normals[~on]
        dropped += int(on.sum())
    return points, normals, dropped


def _neighbour_scatter(points: np.ndarray, query: np.ndarray, k: int) -> np.ndarray:
    """``(len(query), 3, 3)`` scatter matrices of each query point's ``k`` nearest ``points`` about their mean.

    Their least eigenvector is the local plane's normal, their least eigenvalue the spread across it.
    """
    _, near = cKDTree(points).query(query, k)
    hood = points[near] - points[near].mean(axis=1, keepdims=True)
    return np.einsum("nki,nkj->nij", hood, hood)


def _revolution_axis(points: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray] | None:
    """The line the points' normal lines meet best: ``(direction, a point on it)``, or None when unclear.

    Every normal line of a surface of revolution meets its axis (Pottmann and
    Randrup's linear line complex): with the normal line through ``p`` along
    ``n`` and the axis through ``c`` along ``a``, ``det(a, p - c, n) = 0``,
    which is linear in the axis's Pluecker coordinates ``(a, c x a)``. The
    least-squares line is the smallest generalised eigenvector of a 6 x 6
    matrix. A sphere's normals meet every line through its centre; the line
    counts only when its misfit is below ``AXIS_GAP`` of the next's (on a
    sphere seen from one side, the noise of the normals favours the line of
    sight, but not by that much; docs/design-notes.md). The normals are the
    points' own (their neighbourhoods' least spread), so given normals are
    not needed; a fifth of the points that miss the line most (stray points,
    a stalk) are dropped and the line fitted again.
    """
    from scipy.linalg import eigh

    if len(points) > AXIS_POINTS:
        points = points[rng.choice(len(points), AXIS_POINTS, replace=False)]
    if len(points) < 2 * AXIS_NEIGHBOURS:
        return None
    normals = np.linalg.eigh(_neighbour_scatter(points, points, AXIS_NEIGHBOURS))[1][:, :, 0]
    centre = points.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1))))
    x = (points - centre) / scale
    lines = np.concatenate([np.cross(x, normals), normals], axis=1)
    norm = np.diag([1.0, 1.0, 1.0, 1e-9, 1e-9, 1e-9])
    values, vectors = eigh(lines.T @ lines, norm)
    # the gap on all the points: dropping the ones that miss a line makes any line look clearer
    if not values[0] < AXIS_GAP * values[1]:
        return None
    miss = np.abs(lines @ vectors[:, 0])
    keep = miss <= np.quantile(miss, 0.8)
    vectors = eigh(lines[keep].T @ lines[keep], norm)[1]
    a, moment = vectors[:3, 0], vectors[3:, 0]
    length = float(np.linalg.norm(a))
    a, moment = a / length, moment / length
    # the moment is c x a for a point c on the line; the nearest such point to the centroid
    point = np.cross(a, moment) * scale + centre
    return a, point


def _point_noise(points: np.ndarray, rng) -> float:
    """The points' own noise, mm: the median RMS of each point's neighbours about their plane.

    Corrected for the plane's three fitted parameters; a fruit's curvature
    over a few neighbours adds little (an apple's 40 mm radius bends 20
    points 1 mm apart by a few hundredths of a millimetre).
    """
    k = MISFIT_NEIGHBOURS
    if len(points) <= k:
        return float("nan")
    # neighbours among all the points: a subset's are farther apart, and the surface bends between them
    query = points[rng.choice(len(points), AXIS_POINTS, replace=False)] if len(points) > AXIS_POINTS else points
    least = np.linalg.eigvalsh(_neighbour_scatter(points, query, k))[:, 0]
    return float(np.sqrt(np.median(np.maximum(least, 0.0) / (k - 3))))


def _rotations() -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.create_group("I").as_matrix()


def _holds_its_shapes(model) -> bool:
    """Whether the model's scores give back its training shapes: 4 or more, every mode kept."""
    scores = model.scores_
    return (scores is not None and len(scores) >= 4
            and float(model.explained_variance_ratio_.sum()) > 1.0 - 1e-9)


@dataclass(frozen=True, eq=False)
class _Calibration:
    """What leaving each training shape out tells about new shapes (see :func:`_calibration`)."""

    mode_scale: np.ndarray  # (k,) factor on each mode's variance
    misfit: np.ndarray  # (q, n, 3) modes of what the model cannot represent, scaled to their SD


def _training_shapes(model) -> np.ndarray:
    """(N, n, 3) the training shapes the model holds, minus its mean."""
    scores = model.scores_
    return ((scores * np.sqrt(model.explained_variance_)) @ model.components_).reshape(len(scores), -1, 3)


def _as_seen(shapes: np.ndarray, vertices: np.ndarray, normals: np.ndarray, volume_gradient: np.ndarray,
             surface_normals: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The training ``shapes`` (N, n, 3) as a fit sees them, for :func:`_loo_predictive` and :func:`_jackknife`.

    Each along ``normals`` at the fitting ``vertices`` (N, K), its linearised
    volume (N,), and along ``surface_normals`` at every vertex (N, n; None
    without them).
    """
    seen = np.einsum("kd,akd->ak", normals, shapes[:, vertices])
    vol = np.einsum("nd,and->a", volume_gradient, shapes)
    along = None if surface_normals is None else np.einsum("jnd,nd->jn", shapes, surface_normals)
    return seen, vol, along


def _calibration(model, k: int) -> _Calibration | None:
    """Leave-one-out on the training shapes the model holds (its ``scores_``).

    A model of N shapes underestimates how far a new shape lies: each
    training shape left out in turn is described by the model of the others,
    and (1) the variance of its coefficients per mode, over the N shapes, is
    how much wider the prior of that mode should be (mostly the last modes,
    whose variances N shapes estimate worst; never narrower); (2) what the
    others' model cannot represent of it is the model's misfit, and the
    principal components of the N misfits become extra modes of the prior.
    All of it in the N x N Gram matrix of the shapes. None when the model
    does not hold its training shapes' coefficients or has dropped modes.
    """
    if not _holds_its_shapes(model) or k == 0:
        return None
    x = _training_shapes(model).reshape(len(model.scores_), -1)  # (N, 3n)
    n_shapes = len(x)
    gram = x @ x.T
    eye = np.eye(n_shapes)
    coef_sq = np.zeros((n_shapes, n_shapes - 2))
    a = np.zeros((n_shapes, n_shapes))
    for i in range(n_shapes):
        others = np.delete(np.arange(n_shapes), i)
        m = eye[others] - eye[others].mean(axis=0)  # rows: the others, centred on their mean
        w = eye[i] - eye[others].mean(axis=0)  # the left-out shape minus the others' mean
        s, u = np.linalg.eigh(m @ gram @ m.T)
        keep = s > 1e-9 * s.max()
        s, u = s[keep][::-1], u[:, keep][:, ::-1]
        proj = u.T @ (m @ gram @ w)  # sqrt(s) * the coefficients in the orthonormal LOO basis
        q = min(len(s), n_shapes - 2)
        coef_sq[i, :q] = (proj[:q] ** 2 / s[:q]) * (n_shapes - 2) / s[:q]
        a[i] = w - m.T @ (u @ (proj / s))
    per_mode = coef_sq.mean(axis=0)
    scale = np.ones(k)
    scale[: min(k, len(per_mode))] = np.maximum(per_mode[: min(k, len(per_mode))], 1.0)
    if k > len(per_mode):
        scale[len(per_mode):] = scale[len(per_mode) - 1]
    # the misfits' principal components: R = A X, R R^T = A G A^T
    s, v = np.linalg.eigh(a @ gram @ a.T)
    s, v = s[::-1], v[:, ::-1]
    # the misfits' leading components, MISFIT_SHARE of their variance
    keep = np.arange(len(s)) < 1 + np.searchsorted(np.cumsum(np.maximum(s, 0)) / max(s.sum(), 1e-300), MISFIT_SHARE)
    keep &= s > 1e-9 * max(s.max(), 1e-300)
    s, v = s[keep], v[:, keep]
    fields = (v.T @ a @ x) / np.sqrt(s)[:, None]  # orthonormal rows
    misfit = fields * np.sqrt(s / n_shapes)[:, None]
    return _Calibration(scale, misfit.reshape(len(s), -1, 3))


def _loo_predictive(seen: np.ndarray, vol: np.ndarray, along: np.ndarray | None, weights: np.ndarray,
                    sigma: float) -> tuple[float, np.ndarray | None]:
    """Cross-validated errors of completing a shape seen as these points were seen.

    Each training shape in turn is left out, observed where the fitted points
    observed the surface (``seen``, :func:`_as_seen`, with the fit's weights
    and noise), and completed by the model of the others (the same
    Gaussian conditioning as the fit, in the Gram matrix of the shapes). What
    the completion gets wrong of the left-out shape, over the N shapes, is
    the error to expect for a new one seen the same way: its volume error's
    RMS (mm^3) and, per vertex, the RMS of the error along the surface normal
    (mm). Unlike the posterior, it does not trust correlations that N shapes
    only seem to show.
    """
    n_shapes = len(seen)
    eye = np.eye(n_shapes)
    a = np.zeros((n_shapes, n_shapes))
    for i in range(n_shapes):
        others = np.delete(np.arange(n_shapes), i)
        m = eye[others] - eye[others].mean(axis=0)  # the others centred on their mean: m @ x
        w = eye[i] - eye[others].mean(axis=0)  # the left-out shape minus the others' mean: w @ x
        y_seen = m @ seen  # (N-1, K)
        # shape = others' mean + (m x)^T beta, beta ~ N(0, I / (N - 2)): the others' sample covariance
        h = (y_seen * weights) @ y_seen.T / sigma**2 + (n_shapes - 2) * np.eye(n_shapes - 1)
        beta = np.linalg.solve(h, (y_seen * weights) @ (w @ seen) / sigma**2)
        a[i] = w - m.T @ beta  # the error of the completion, as a combination of the shapes
    volume_rms = float(np.sqrt(np.mean((a @ vol) ** 2)))
    if along is None:
        return volume_rms, None
    return volume_rms, np.sqrt(np.mean((a @ along) ** 2, axis=0))  # the errors along the normals


def _jackknife(gram: np.ndarray, k: int, seen: np.ndarray, vol: np.ndarray, along: np.ndarray | None,
               normals: np.ndarray, weights: np.ndarray, sigma: float, points: np.ndarray,
               distances: np.ndarray) -> tuple[float, np.ndarray | None]:
    """How much the completion rests on the few shapes the model was built from.

    The model of the training shapes but one (their mean and sample
    covariance, ``k`` modes at most), for each shape in turn, completes the
    same observations: the fitted ``points`` (in the model's frame), their
    signed ``distances`` from the model's mean along the surface ``normals``
    at the fitting vertices, with the fit's weights and noise, the pose
    free. The jackknife spread of the N completions' volume (mm^3) and, per
    vertex, of their position along the surface normals (mm; ``seen``,
    ``vol`` and ``along`` are the shapes as :func:`_as_seen` gives them). A
    model of a dozen shapes can complete the side no view reached quite
    otherwise without one of them, most of all by placing a larger or
    smaller fruit farther or nearer; the posterior, which trusts the model,
    does not see that. All in the N x N ``gram`` matrix of the shapes.
    """
    n_shapes = len(seen)
    pose = np.concatenate([np.cross(points, normals), normals], axis=1)  # (K, 6) moving the points
    eye = np.eye(n_shapes)
    completions = np.zeros((n_shapes, n_shapes))  # each completion as a combination of the shapes
    for i in range(n_shapes):
        others = np.delete(np.arange(n_shapes), i)
        centre = eye[others].mean(axis=0)
        m = eye[others] - centre  # the others centred on their mean: m @ x
        s, u = np.linalg.eigh(m @ gram @ m.T)
        k_i = min(k, int((s > 1e-9 * s.max()).sum()))
        rows = u[:, ::-1][:, :k_i].T @ m / np.sqrt(n_shapes - 2)  # the others' modes, each at its SD
        design = np.concatenate([(rows @ seen).T, -pose], axis=1)  # (K, k_i + 6)
        h = (design.T * weights) @ design / sigma**2
        h[:k_i, :k_i] += np.eye(k_i)
        h[k_i:, k_i:] += 1e-9 * np.eye(6)
        coef = np.linalg.solve(h, (design.T * weights) @ (distances - centre @ seen) / sigma**2)[:k_i]
        completions[i] = centre + coef @ rows
    spread = completions - completions.mean(axis=0)
    factor = (n_shapes - 1) / n_shapes
    volume_sd = float(np.sqrt(factor * np.sum((spread @ vol) ** 2)))
    if along is None:
        return volume_sd, None
    return volume_sd, np.sqrt(factor * np.sum((spread @ along) ** 2, axis=0))


class _Fitter:
    """The model's arrays restricted to the fitting vertices, and the Gauss-Newton steps."""

    def __init__(self, model, k: int, fit_idx: np.ndarray, calibration: _Calibration | None = None, *,
                 shapes: bool = False) -> None:
        n = model.n_points_
        self.mean = model.mean_
        self.faces = model.faces_
        variances = model.explained_variance_[:k]
        if calibration is not None:
            variances = variances * calibration.mode_scale
        basis = (model.components_[:k] * np.sqrt(variances)[:, None]).reshape(k, n, 3)
        if calibration is not None:
            basis = np.concatenate([basis, calibration.misfit])
        self.basis = basis
        self.k = len(basis)
        self.k_model = k  # the model's modes among them
        # with ``shapes``, the training shapes and their Gram matrix for the posterior's checks (None: not held)
        self.shapes = _training_shapes(model) if shapes and _holds_its_shapes(model) else None
        flat = None if self.shapes is None else self.shapes.reshape(len(self.shapes), -1)
        self.gram = None if flat is None else flat @ flat.T
        self.idx = fit_idx
        # the fitting vertices' rows, laid out for gathering: (n_fit, 3, K)
        self.mean_fit = self.mean[fit_idx]
        self.basis_fit = np.ascontiguousarray(basis[:, fit_idx].transpose(1, 2, 0))

    def jacobian(self, p: np.ndarray, rows: np.ndarray, nv: np.ndarray, basis_rows=None) -> np.ndarray:
        """Derivatives of the signed distances ``nv . (p - x)`` by the coefficients, then the pose.

        ``rows`` index the fitting vertices (``basis_rows`` None) or the rows of ``basis_rows`` (n', 3, K).
        """
        k = self.k
        jac = np.empty((len(p), k + 6))
        if k:
            b = (self.basis_fit if basis_rows is None else basis_rows)[rows]  # (K_points, 3, K)
            jac[:, :k] = -np.einsum("id,idj->ij", nv, b)
        jac[:, k:k + 3] = np.cross(p, nv)  # d r / d omega, for p -> p + omega x p
        jac[:, k + 3:] = nv
        return jac

    def shape(self, c: np.ndarray) -> np.ndarray:
        """The whole shape for coefficients ``c``, in the model's frame."""
        return self.mean + np.einsum("j,jnd->nd", c, self.basis) if self.k else self.mean.copy()

    def shape_fit(self, c: np.ndarray) -> np.ndarray:
        """The fitting vertices only."""
        return self.mean_fit + self.basis_fit @ c if self.k else self.mean_fit.copy()

    def fit(self, y, nrm, rotation, translation, c, noise, iterations, weights=None, normals=None):
        """Joint Gauss-Newton on pose (of the points, into the model's frame) and coefficients.

        ``weights`` (one per point of ``y``, default 1) count each residual as
        that share of an independent observation. ``normals`` (of the fitting
        vertices) are used throughout instead of the shape's own.
        """
        k = self.k
        weights = np.ones(len(y)) if weights is None else weights
        cos_max = np.cos(np.radians(NORMAL_ANGLE))
        for it in range(iterations):
            xs = self.shape_fit(c)
            if normals is not None:
                ns = normals
            elif it % NORMALS_EVERY == 0:  # the normals change slowly with the shape
                ns = vertex_normals(self.shape(c), self.faces)[self.idx]
            p = y @ rotation.T + translation
            dist, j = cKDTree(xs).query(p)
            keep = _trim(dist)
            if nrm is not None:
                keep &= np.einsum("ij,ij->i", nrm @ rotation.T, ns[j]) >= cos_max
            if keep.sum() < MIN_POINTS:
                break
            p, v, nv, wk = p[keep], j[keep], ns[j[keep]], weights[keep]
            r = np.einsum("ij,ij->i", nv, p - xs[v])  # signed distance along the surface normal
            jac = self.jacobian(p, v, nv)
            h = (jac * wk[:, None]).T @ jac / noise**2
            g = (jac * wk[:, None]).T @ r / noise**2
            h[:k, :k] += np.eye(k)
            g[:k] += c
            step = -np.linalg.solve(h + 1e-9 * np.eye(k + 6), g)
            c = c + step[:k]
            w = step[k:k + 3]
            angle = np.linalg.norm(w)
            if angle > 0:
                turn = rotation_about(w / angle, angle)
            else:
                turn = np.eye(3)
            rotation, translation = turn @ rotation, turn @ translation + step[k + 3:]
            if np.abs(step).max() < 1e-6:
                break
        return rotation, translation, c

    def objective(self, y, nrm, rotation, translation, c, noise, weights=None, normals=None):
        """Negative log posterior (up to a constant) and the kept pairs ``(keep, j, r)``, at a fit."""
        weights = np.ones(len(y)) if weights is None else weights
        xs = self.shape_fit(c)
        ns = vertex_normals(self.shape(c), self.faces)[self.idx] if normals is None else normals
        p = y @ rotation.T + translation
        dist, j = cKDTree(xs).query(p)
        keep = _trim(dist)
        if nrm is not None:
            keep &= np.einsum("ij,ij->i", nrm @ rotation.T, ns[j]) >= np.cos(np.radians(NORMAL_ANGLE))
        r = np.einsum("ij,ij->i", ns[j], p - xs[j])
        # the trimmed points count at the trimming distance, so trimming more cannot lower the objective
        cap = dist[keep].max() if keep.any() else 0.0
        data = (weights * np.where(keep, r, cap) ** 2).sum() / noise**2
        return float(0.5 * data + 0.5 * c @ c), keep, j, r

    def short_fit(self, y, nrm, rotation, translation, noise, iterations, weights=None, normals=None):
        """A few iterations from a start with the mean shape: ``(objective, rotation, translation, c)``."""
        rot, tr, c = self.fit(y, nrm, rotation, translation, np.zeros(self.k), noise, iterations, weights,
                              normals=normals)
        return self.objective(y, nrm, rot, tr, c, noise, weights, normals=normals)[0], rot, tr, c


def fit_partial(
    model,
    points: npt.ArrayLike,
    *,
    normals: npt.ArrayLike | None = None,
    modes: int | None = None,
    noise: float | str = "auto",
    calibrate: bool = True,
    random_state: RandomState = 0,
) -> PartialFit:
    """Fit a shape model to a partial point cloud, with the posterior (see the module notes).

    Parameters
    ----------
    model : ShapeModel
        A fitted model with triangles (``faces_``), in mm.
    points : (k, 3) array_like of float
        What was seen of one fruit, in any pose, mm: a depth camera's points,
        the vertices of an open mesh. Stray points (a table, a neighbour)
        are trimmed.
    normals : (k, 3) array_like of float, optional
        Outward normals of the points; pairs whose normals disagree by more
        than ``NORMAL_ANGLE`` degrees are not used.
    modes : int, optional
        Leading modes fitted (default: all of the model's).
    noise : float or "auto", default: "auto"
        Standard deviation of a point's distance to the true surface, mm.
        ``"auto"``: estimated from the fit's residuals.
    calibrate : bool, default: True
        Widen the prior by what leaving each training shape out shows (the
        model's own test of how far new shapes lie, and of what it cannot
        represent; see the module notes). Needs the model's ``scores_`` and
        all its modes; otherwise the prior is the model's as it is.
    random_state : int, Generator, SeedSequence or None, default: 0
        Chooses the subsets of the points used to search and to fit.

    Returns
    -------
    PartialFit

    Raises
    ------
    HortishapeError
        A model without triangles; too few points, points on a plane, points
        spanning too little of the model (in metres?), NaN.

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    >>> rng = np.random.default_rng(0)
    >>> shapes = s.vertices * (40.0 + rng.normal(0.0, 2.0, (8, 1, 3)))  # ellipsoids about 80 mm wide
    >>> model = ShapeModel().fit(shapes, s.faces)
    >>> truth = s.vertices * [42.0, 39.0, 41.0]
    >>> seen = truth[truth[:, 2] > 5.0]                                # the top half, seen from above
    >>> fit = fit_partial(model, seen + [100.0, 0.0, 0.0])
    >>> from scipy.spatial import cKDTree
    >>> float(cKDTree(truth + [100.0, 0.0, 0.0]).query(fit.vertices)[0].max()) < 0.1  # the hidden half too
    True
    >>> from hortishape.surface import signed_volume
    >>> volume = signed_volume(truth, s.faces) / 1000.0
    >>> error = abs(fit.volume_ml - volume)
    >>> round(volume, 1), bool(error < 0.005 * volume), bool(error < 2 * fit.volume_sd_ml)
    (278.9, True, True)
    """
    return PartialFitter(model, modes=modes, calibrate=calibrate).fit(
        points, normals=normals, noise=noise, random_state=random_state)


class PartialFitter:
    """A shape model made ready to complete partial scans, for :meth:`fit` to use on one scan after another.

    What depends on the model alone is done once, here: its leave-one-out
    calibration, the fitting vertices, the mean's normals and axis.
    :func:`fit_partial` is this for a single scan.

    Parameters
    ----------
    model : ShapeModel
        A fitted model with triangles (``faces_``), in mm.
    modes : int, optional
        Leading modes fitted (default: all of the model's).
    calibrate : bool, default: True
        See :func:`fit_partial`.

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    >>> rng = np.random.default_rng(0)
    >>> model = ShapeModel().fit(s.vertices * (40.0 + rng.normal(0.0, 2.0, (8, 1, 3))), s.faces)
    >>> from hortishape.surface import signed_volume
    >>> fitter = PartialFitter(model)
    >>> truths = [s.vertices * r for r in ([42.0, 39.0, 41.0], [38.0, 40.0, 44.0])]
    >>> fits = [fitter.fit(t[t[:, 2] > 0.1]) for t in truths]               # the top halves
    >>> [bool(abs(f.volume_ml - signed_volume(t, s.faces) / 1000.0) < 2 * f.volume_sd_ml) for f, t in zip(fits, truths)]
    [True, True]
    """

    def __init__(self, model, *, modes: int | None = None, calibrate: bool = True) -> None:
        model._check_fitted()
        if model.faces_ is None:
            raise HortishapeError("the model has no triangles (a point-set model): a partial fit needs its surface")
        k = model.n_components_ if modes is None else modes
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= model.n_components_:
            raise HortishapeError(f"modes must be in [0, {model.n_components_}], got {modes!r}")
        self.model = model
        self.k = int(k)
        self.calibrate = bool(calibrate)
        n = model.n_points_
        self.fit_idx = np.unique(np.linspace(0, n - 1, min(n, FIT_VERTICES)).astype(np.int64))
        self.calibration = _calibration(model, self.k) if calibrate else None
        self.fitter = _Fitter(model, self.k, self.fit_idx, self.calibration, shapes=self.calibrate)
        self.mean_normals = vertex_normals(model.mean_, model.faces_)[self.fit_idx]
        self.tree = cKDTree(model.mean_[self.fit_idx])
        self.axis = fruit_axis(model.mean_, model.faces_)
        self.extent = float(np.ptp(model.mean_, axis=0).max())

    def fit(self, points: npt.ArrayLike, *, normals: npt.ArrayLike | None = None, noise: float | str = "auto",
            random_state: RandomState = 0) -> PartialFit:
        """Fit the model to one partial point cloud; see :func:`fit_partial` for the parameters."""
        if noise != "auto" and not (isinstance(noise, (int, float)) and not isinstance(noise, bool) and noise > 0):
            raise HortishapeError(f"noise must be a positive number of mm or 'auto', got {noise!r}")
        y, nrm = _check_points(points, normals, self.extent)
        rng = as_generator(random_state)
        kept, kept_normals, dropped = _drop_planes(y, nrm, self.extent, rng)
        if dropped:
            y, nrm = _check_points(kept, kept_normals, self.extent)
        fit = replace(_fit(self, y, nrm, noise, rng), n_points=len(points), n_planar=dropped)
        for note in fit.warnings:
            warnings.warn(note, FitWarning, stacklevel=2)
        return fit


def _group_search(prep: PartialFitter, ys: np.ndarray, ns, start_noise: float, ws: np.ndarray) -> list:
    """Candidate poses when the points show no axis: ``(objective, rotation, translation, coefficients)``.

    Trimmed rigid ICP of the points ``ys`` against the mean from every
    rotation of the icosahedral group; the best distinct rotations screened
    by a short fit with the modes (the mean alone ranks them poorly); the
    best of those also turned about the fruit's axis, which a view of one
    side often leaves open. Sorted, best first.
    """
    fitter, mean, fit_idx = prep.fitter, prep.model.mean_, prep.fit_idx
    tree, mean_normals = prep.tree, prep.mean_normals
    cos_max = np.cos(np.radians(NORMAL_ANGLE))
    # every rotation at once: (R, m, 3) points, one query and one batch of 3 x 3 SVDs per iteration
    rotations = _rotations()
    translations = mean.mean(axis=0) - ys.mean(axis=0) @ rotations.transpose(0, 2, 1)
    target = mean[fit_idx]
    for _ in range(SEARCH_ITERATIONS):
        p = ys @ rotations.transpose(0, 2, 1) + translations[:, None, :]
        dist, j = tree.query(p)
        med = np.median(dist, axis=1, keepdims=True)
        spread = 1.4826 * np.median(np.abs(dist - med), axis=1, keepdims=True)
        keep = dist <= np.maximum(med + TRIM_MAD * spread, TRIM_FLOOR_MM)
        if ns is not None:
            agree = np.einsum("rij,rij->ri", ns @ rotations.transpose(0, 2, 1), mean_normals[j]) >= cos_max
            enough = (keep & agree).sum(axis=1, keepdims=True) >= 3
            keep = np.where(enough, keep & agree, keep)
        wk = keep / keep.sum(axis=1, keepdims=True)
        q = target[j]
        cp, cq = np.einsum("ri,rid->rd", wk, p), np.einsum("ri,rid->rd", wk, q)
        h = np.einsum("ri,rid,rie->rde", wk, p - cp[:, None], q - cq[:, None])
        u, _, vt = np.linalg.svd(h)
        d = np.sign(np.linalg.det(np.swapaxes(vt, 1, 2) @ np.swapaxes(u, 1, 2)))
        d[d == 0] = 1.0
        fix = np.ones((len(d), 3))
        fix[:, 2] = d
        dr = np.swapaxes(vt, 1, 2) @ (fix[:, :, None] * np.swapaxes(u, 1, 2))
        rotations = dr @ rotations
        translations = np.einsum("rde,re->rd", dr, translations - cp) + cq
    dist = tree.query(ys @ rotations.transpose(0, 2, 1) + translations[:, None, :])[0]
    dist.sort(axis=1)
    scores = np.mean(dist[:, : int(0.9 * dist.shape[1])] ** 2, axis=1)
    found = [(float(sc), r, t) for sc, r, t in zip(scores, rotations, translations)]
    found.sort(key=lambda t: t[0])
    screened = []
    for score, rotation, translation in found:  # distinct rotations only
        if all(rotation_angle(rotation @ r.T) > 20.0 for _, r, _ in screened):
            screened.append((score, rotation, translation))
        if len(screened) == SCREENED:
            break

    def screen(rotation, translation):  # short, with the mean's normals: the candidates alike
        return fitter.short_fit(ys, ns, rotation, translation, start_noise, SCREEN_ITERATIONS, ws,
                                normals=mean_normals)

    short = sorted((screen(rot, tr) for _, rot, tr in screened), key=lambda t: t[0])
    axis = prep.axis
    _, rot_b, tr_b, _ = short[0]
    for turn in np.arange(1, TWISTS) * (2.0 * np.pi / TWISTS):
        twist = rotation_about(axis.direction, turn)
        short.append(screen(twist @ rot_b, twist @ (tr_b - axis.centre) + axis.centre))
    short.sort(key=lambda t: t[0])
    return short


def _axis_starts(prep, y_all: np.ndarray, ys: np.ndarray, rng) -> list:
    """Starts with the model's axis on the points' axis of revolution (:func:`_revolution_axis`).

    Either end up, turned about the axis in ``AXIS_TURNS`` steps; each
    placed by a few translation-only ICP steps against the mean. Empty when
    the points show no clear axis.
    """
    found = _revolution_axis(y_all, rng) if AXIS_TURNS else None
    if found is None:
        return []
    direction, point = found
    axis = prep.axis
    target = prep.model.mean_[prep.fit_idx]
    starts = []
    for end in (1.0, -1.0):
        onto = _rotation_between(end * direction, axis.direction)
        for turn in np.arange(AXIS_TURNS) * (2.0 * np.pi / AXIS_TURNS):
            rotation = rotation_about(axis.direction, turn) @ onto
            # the points' axis on the model's; along it, centroid on centroid
            p = ys @ rotation.T
            shift = axis.centre - rotation @ point
            along = axis.direction @ (axis.centre - (p.mean(axis=0) + shift))
            translation = shift + along * axis.direction
            for _ in range(SEARCH_ITERATIONS):
                dist, j = prep.tree.query(p + translation)
                keep = _trim(dist)
                translation = translation + (target[j[keep]] - (p[keep] + translation)).mean(axis=0)
            starts.append((rotation, translation))
    return starts


def _fit(prep: PartialFitter, y_all: np.ndarray, n_all, noise, rng) -> PartialFit:
    model, k, fitter, calibrate = prep.model, prep.k, prep.fitter, prep.calibrate
    calibration = prep.calibration

    def subset(count: int) -> np.ndarray:
        return np.sort(rng.choice(len(y_all), count, replace=False)) if len(y_all) > count else np.arange(len(y_all))

    s_idx = subset(SEARCH_POINTS)
    ys = y_all[s_idx]
    ns = None if n_all is None else n_all[s_idx]
    start_noise = START_NOISE_MM if noise == "auto" else float(noise)
    ws = _weights(ys, START_CORRELATION_MM)
    starts = _axis_starts(prep, y_all, ys, rng)
    if starts:
        # a few iterations with the shape's own normals rank the starts as the full fit would
        # (with the mean's normals they turned away from the right axis; docs/design-notes.md)
        short = sorted((fitter.short_fit(ys, ns, rot, tr, start_noise, AXIS_ITERATIONS, ws) for rot, tr in starts),
                       key=lambda t: t[0])
    else:
        short = _group_search(prep, ys, ns, start_noise, ws)
    finalists = []
    for candidate in short:
        if all(rotation_angle(candidate[1] @ other[1].T) > 20.0 for other in finalists):
            finalists.append(candidate)
        if len(finalists) == FINALISTS:
            break

    # the finalists fitted in full; the noise and the residuals' correlation length from the best,
    # then every finalist again with them
    f_idx = subset(FIT_POINTS)
    y = y_all[f_idx]
    nrm = None if n_all is None else n_all[f_idx]
    w = _weights(y, START_CORRELATION_MM)
    fits = [fitter.fit(y, nrm, rot, tr, c, start_noise, FIT_ITERATIONS, w) for _, rot, tr, c in finalists]
    judged = sorted(((fitter.objective(y, nrm, *f, start_noise, w), f) for f in fits), key=lambda t: t[0][0])
    fits = [f for _, f in judged]
    _, keep, j, r = judged[0][0]
    length = _correlation_length(y[keep], r[keep], rng)
    w = _weights(y, length)
    sigma = float(noise) if noise != "auto" else max(_weighted_rms(r, keep, w), MIN_NOISE_MM)
    fits = [fitter.fit(y, nrm, *f, sigma, FIT_ITERATIONS // 2, w) for f in fits]
    scored = []
    for o, f in sorted(((fitter.objective(y, nrm, *f, sigma, w)[0], f) for f in fits), key=lambda t: t[0]):
        if all(rotation_angle(f[0] @ g[0].T) > SAME_POSE for _, g in scored):  # two finalists that met count once
            scored.append((o, f))

    # the posterior is a mixture over the poses that explain the points alike: each fit's Laplace
    # approximation, weighted by its posterior density
    objectives = np.array([o for o, _ in scored])
    share = np.exp(-(objectives - objectives[0]))
    share /= share.sum()
    parts = []
    for (_, f), p_m in zip(scored, share):
        if p_m < MIN_SHARE and parts:
            continue
        parts.append((p_m, f, _posterior(fitter, model, y, nrm, w, sigma, *f, calibrate=calibrate,
                                         per_vertex=not parts)))
    total = sum(p for p, _, _ in parts)
    _, (rotation, translation, c), best = parts[0]
    x, sd, cov, keep = best.shape, best.sd, best.cov, best.keep
    volume = sum(p * post.volume for p, _, post in parts) / total
    volume_sd = float(np.sqrt(sum(p * (post.volume_sd**2 + (post.volume - volume) ** 2)
                                  for p, _, post in parts) / total))
    if len(parts) > 1:  # where the other poses put the surface, along the best's normals
        spread = np.zeros(len(x))
        for p, _, post in parts[1:]:
            spread += p * cKDTree(post.shape).query(x)[0] ** 2
        sd = np.sqrt(sd**2 + spread / total)

    # back to the points' coordinates
    pose = np.eye(4)
    pose[:3, :3] = rotation.T
    pose[:3, 3] = -rotation.T @ translation
    completed = x @ pose[:3, :3].T + pose[:3, 3]
    kept_points = y[keep]
    spacing = float(np.median(cKDTree(kept_points).query(kept_points, k=2)[0][:, 1]))
    near = cKDTree(kept_points).query(completed, distance_upper_bound=OBSERVED_SPACINGS * max(spacing, 0.5))[0]
    areas = vertex_areas(x, model.faces_)
    seen = np.isfinite(near)
    observed = float(areas[seen].sum() / areas.sum())
    residual = float(closest_points(Mesh(completed, model.faces_), kept_points).distances.mean())
    point_noise = _point_noise(y_all, rng)
    # what the model misses of this fruit where it was seen; 0 when it is the points' own noise
    misfit = float(np.sqrt(max(best.residual**2 - point_noise**2, 0.0))) if np.isfinite(point_noise) else 0.0
    # What the model cannot represent of this fruit is, where it was seen, the size of the residuals;
    # where it was not seen nothing says it is smaller, nor that it averages out: the unseen surface
    # may lie that far off as a whole, and MISFIT_REACH times the misfit farther, all one way.
    sd = np.sqrt(sd**2 + sigma**2)
    sd[~seen] = np.hypot(sd[~seen], MISFIT_REACH * misfit)
    volume_sd = float(np.hypot(volume_sd, np.hypot(sigma, MISFIT_REACH * misfit) * areas[~seen].sum()))
    notes = []
    if noise == "auto" and sigma > MISFIT_RATIO * point_noise:
        notes.append(f"the model explains these points far worse than their own noise (residuals "
                     f"{sigma:.2f} mm against {point_noise:.2f} mm): this fruit may lie outside the model's "
                     "population, and the completion of the side not seen, and its SD, may be off")
    best = rotation
    # the model's own coefficients (in its SD) and their covariance
    to_model = np.sqrt(calibration.mode_scale) if calibration is not None else np.ones(k)
    coefficients = c[:k] * to_model
    covariance = cov[:k, :k] * np.outer(to_model, to_model)
    return PartialFit(
        vertices=completed, faces=model.faces_, sd=sd, coefficients=coefficients, covariance=covariance, pose=pose,
        volume_ml=float(volume) / 1000.0, volume_sd_ml=float(volume_sd) / 1000.0, residual_mm=residual, noise_mm=sigma,
        observed_fraction=observed, n_points=len(y_all), n_kept=int(keep.sum()), correlation_mm=length,
        poses=tuple((float(p_m), rotation_angle(best @ f[0].T)) for (_, f), p_m in zip(scored, share)),
        calibrated=calibration is not None, point_noise_mm=point_noise, misfit_mm=misfit, warnings=tuple(notes),
    )


@dataclass(frozen=True, eq=False)
class _Posterior:
    shape: np.ndarray  # (n, 3) the posterior mean, in the model's frame
    sd: np.ndarray  # (n,) SD along the normal
    cov: np.ndarray  # (K, K) of the fitter's coefficients
    volume: float  # mm^3
    volume_sd: float
    keep: np.ndarray  # the kept points
    residual: float  # RMS of the kept points' weighted residuals, mm


def _posterior(fitter, model, y, nrm, w, sigma, rotation, translation, c, *, calibrate: bool,
               per_vertex: bool = True) -> _Posterior:
    """The Laplace approximation at one fit: coefficients and pose together, the pose marginalised.

    The pose is estimated with the coefficients (a flat prior), and its
    uncertainty is theirs too: a larger fruit placed farther explains a cap
    seen from one side almost as well as a smaller one nearer.
    """
    _, keep, j, r = fitter.objective(y, nrm, rotation, translation, c, sigma, w)
    kk = fitter.k
    x = fitter.shape(c)
    normals_x = vertex_normals(x, model.faces_)
    v = fitter.idx[j[keep]]
    jac = fitter.jacobian(y[keep] @ rotation.T + translation, j[keep], normals_x[v])
    hessian = (jac * w[keep][:, None]).T @ jac / sigma**2
    hessian[:kk, :kk] += np.eye(kk)
    cov = np.linalg.inv(hessian + 1e-9 * np.eye(kk + 6))[:kk, :kk]
    along = np.einsum("nd,jnd->nj", normals_x, fitter.basis)
    sd = np.sqrt(np.maximum(np.einsum("nj,jk,nk->n", along, cov, along), 0.0))
    volume_gradient = _volume_gradient(x, model.faces_)
    grad = np.einsum("nd,jnd->j", volume_gradient, fitter.basis)
    volume = abs(signed_volume(x, model.faces_))
    volume_sd = float(np.sqrt(max(grad @ cov @ grad, 0.0)))
    # the posterior trusts the model's correlations; the training shapes, each completed from what
    # these points saw, show how far to trust them: the larger of the two is kept
    if calibrate and fitter.shapes is not None:
        seen, vol, along_shapes = _as_seen(fitter.shapes, v, normals_x[v], volume_gradient,
                                           normals_x if per_vertex else None)
        cv_volume, cv_sd = _loo_predictive(seen, vol, along_shapes, w[keep], sigma)
        volume_sd = max(volume_sd, cv_volume)
        if cv_sd is not None:
            sd = np.maximum(sd, cv_sd)
        # and a model of as many other shapes would have completed it otherwise
        points = y[keep] @ rotation.T + translation
        distances = np.einsum("kd,kd->k", normals_x[v], points - model.mean_[v])
        jk_volume, jk_sd = _jackknife(fitter.gram, fitter.k_model, seen, vol, along_shapes, normals_x[v], w[keep],
                                      sigma, points, distances)
        volume_sd = float(np.hypot(volume_sd, jk_volume))
        if jk_sd is not None:
            sd = np.hypot(sd, jk_sd)
    return _Posterior(x, sd, cov, volume, volume_sd, keep, _weighted_rms(r, keep, w))


def _weighted_rms(residuals: np.ndarray, keep: np.ndarray, weights: np.ndarray) -> float:
    """RMS of the kept ``residuals``, each counted by its weight (its share of an observation)."""
    return float(np.sqrt(np.average(residuals[keep] ** 2, weights=weights[keep])))


def _weights(points: np.ndarray, length: float) -> np.ndarray:
    """Each point's share of an independent observation: one over the points within ``length`` of it.

    A point with fewer neighbours than is typical weighs as a typical one: a surface gives dense
    points, and a lone point (a stray one that was not trimmed) must not outweigh them.
    """
    counts = cKDTree(points).query_ball_point(points, length, return_length=True)
    return 1.0 / np.maximum(counts, max(float(np.median(counts)), 1.0))


def _correlation_length(points: np.ndarray, residuals: np.ndarray, rng) -> float:
    """Distance at which the residuals' correlation falls below 1/e (within ``CORRELATION_MM``)."""
    lo, hi = CORRELATION_MM
    if len(points) < 20:
        return hi
    pick = rng.choice(len(points), min(len(points), 800), replace=False)
    p, r = points[pick], residuals[pick] - residuals[pick].mean()
    var = float(r @ r / len(r))
    if var <= 0:
        return lo
    pairs = cKDTree(p).query_pairs(hi, output_type="ndarray")
    if len(pairs) == 0:
        return hi
    d = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1)
    prod = r[pairs[:, 0]] * r[pairs[:, 1]] / var
    edges = np.arange(0.0, hi + 1.0, 1.0)
    sums = np.bincount(np.digitize(d, edges), weights=prod, minlength=len(edges) + 1)[1:len(edges)]
    counts = np.bincount(np.digitize(d, edges), minlength=len(edges) + 1)[1:len(edges)]
    corr = np.divide(sums, counts, out=np.ones_like(sums), where=counts >= 10)
    below = np.nonzero(corr < np.exp(-1.0))[0]
    return float(np.clip(edges[below[0]] if below.size else hi, lo, hi))


def write_partial_fit(fit: PartialFit, out_dir, stem: str, *, points: npt.ArrayLike | None = None,
                      source: str | None = None) -> dict:
    """Write a partial fit: the completed surface, its figures, its SD and a picture.

    Files in ``out_dir`` (created if needed), each written atomically:

    - ``<stem>.ply``: the completed surface in the points' coordinates, in the
      model's vertex order, with the per-vertex SD as the vertex property ``sd_mm``;
    - ``<stem>.json``: :meth:`PartialFit.as_dict` (volume and its SD, pose,
      coefficients, residual, observed fraction, ...);
    - ``<stem>.sd.npy``: the per-vertex SD, ``(n,) float64``;
    - ``<stem>.png``: the completed surface coloured by its SD, the points over
      it as grey dots, from the front and from the top.

    Parameters
    ----------
    fit : PartialFit
    out_dir : path
    stem : str
        File name stem (the scan's).
    points : (k, 3) array_like of float, optional
        The points that were fitted, for the picture.
    source : str, optional
        The scan's path, recorded in the JSON.

    Returns
    -------
    dict of str to Path
        ``"mesh"``, ``"json"``, ``"sd"``, ``"picture"``.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    >>> shapes = s.vertices * (40.0 + np.random.default_rng(0).normal(0.0, 2.0, (8, 1, 3)))
    >>> model = ShapeModel().fit(shapes, s.faces)
    >>> seen = (s.vertices * [42.0, 39.0, 41.0])[s.vertices[:, 2] > 0.1]
    >>> files = write_partial_fit(fit_partial(model, seen), tempfile.mkdtemp(), "ball", points=seen)
    >>> sorted(p.name for p in files.values())
    ['ball.json', 'ball.ply', 'ball.png', 'ball.sd.npy']
    """
    import json
    from pathlib import Path

    from ._files import atomic_path, atomic_text
    from .io import write_mesh
    from .report import render_partial_fit

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"mesh": write_mesh(out / f"{stem}.ply", fit.vertices, fit.faces, vertex_scalars={"sd_mm": fit.sd})}
    figures = {"scan": source, **fit.as_dict()}
    files["json"] = atomic_text(out / f"{stem}.json", json.dumps(figures, indent=1), HortishapeError)
    with atomic_path(out / f"{stem}.sd.npy", HortishapeError) as tmp, open(tmp, "wb") as fh:
        np.save(fh, fit.sd)
    files["sd"] = out / f"{stem}.sd.npy"
    files["picture"] = render_partial_fit(fit.vertices, fit.faces, fit.sd, out / f"{stem}.png", points=points)
    return files
