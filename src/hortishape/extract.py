"""From CT and MRI volumes to surfaces: segment the product and mesh its outer surface.

:func:`extract_surface` turns a volume (:class:`~hortishape.io.Volume`)
into one closed, outward-oriented triangle surface of genus 0 in world
millimetres, the kind of scan the rest of hortishape works on:

1. **The level** (:func:`intensity_levels`) lies on the boundary between air
   and the outermost tissue. A histogram of the voxel values, Otsu's
   threshold between product and background, and the peak of the histogram
   on either side of it give the background and the product intensity (a
   constant filling part of the volume, a CT's outside of its reconstructed
   circle, is left out: the air around the product is the background; the
   bins follow the values' own step, so the same values stored as floats or
   multiplied up give the same level). Rays
   along the volume's finest axes, entering the product from outside where
   they cross its surface nearly square, then see which tissue comes first.
   When it is the product's main tissue (CT of most fruit) the level is
   half-way between the two peaks: under the partial-volume model of a
   scanner the iso-surface at that level runs through the true edge, to a
   small fraction of a voxel. When the first tissue is of another
   brightness (MRI: a thin bright peel over a dark rind, brighter flesh
   inside, or a skin dimmer than the flesh, which shows in the rays' mean
   profile as a step that pauses before the flesh), the level is the value
   on the outer boundary of a model of the layers (blurred steps, and the
   noise floor of a magnitude image) fitted to the rays' profile across the
   edge: it holds on a peel too thin to reach its full brightness, and is
   not lifted by MRI's magnitude noise in the background. Across thick
   slices a peel thinner than a slice fills only a share of one and can
   stay below that level at the poles; rays along the slices' axis measure
   how bright it gets there (``slice_outer``), and a lower level half-way
   to it (``segment_level``) is kept in reserve for step 2.
2. **The product, by construction.** Outside is every voxel at or below the
   level that can be reached from the volume's border through such voxels;
   the solid is everything else, so a pepper's hollow, an apple's core and
   air pockets are inside. Where the outside gets in through an opening (an
   MRI orange's core opens to the top through its stalk channel, the gaps
   between its segments open into the core), the solid has tunnels (genus
   above 0) or is an open shell around the flesh: the outside is then
   reached by a box of 1, 2, 4, 8 mm (:data:`GAPS_MM`, a morphological
   opening of the free voxels), which cannot pass gaps narrower than it,
   until the product is one solid of genus 0 (its Euler number, counted
   slab by slab) around no other piece, nor inside other pieces that
   together lie beyond it on every side (a peel broken into pieces). Beyond
   the volume is air: a box may stand partly outside it, so a fruit that
   nearly fills the field of view gets no cap out to the border. If no box
   closes the product, the solid is found again at the lower level of step
   1 and kept when that closes it. The largest 6-connected piece of the
   solid is the product. When it touches the border of the volume (a
   scanner bed or a support does, the product normally does not), it is
   eroded by ``support_radius``: parts that then come apart from the product
   and reach the border are dropped as a support. A support thinner than
   the erosion (a tray, a plate) is what the product's opening leaves out and
   reaches the border; a product fused to its bed over a flat base is parted
   by a larger erosion (:data:`SUPPORT_RADIUS_STEPS`).
3. **Marching cubes** (Lewiner) on the *intensity*, not on the mask, which is
   what gives sub-voxel accuracy: inside the product the intensity is raised
   above the level where it is below, outside the product every voxel above
   the level is lowered below it, and every other voxel keeps its value
   (found at the lower level, the product's voxels between the two levels
   that face the outside with no voxel above the level beside them are
   stretched so that the surface crosses them where it would at the lower
   level). The surface is therefore exactly the outer boundary of the product, one
   closed component, in world coordinates (``origin + direction @ (spacing *
   index)``), with outward normals.
4. Optionally, **Taubin smoothing** (:func:`taubin_smooth`, a low-pass
   filter that does not shrink the shape) and **decimation** to a target
   vertex count (:func:`decimate`, quadric error edge collapses).

What a person should look at is said in :attr:`Extraction.warnings` (and as
:class:`~hortishape.errors.ExtractionWarning`): gaps that had to be closed
and what was filled, a genus that stays above 0, a product touching the
volume's border, a size far from a fruit's, a support that takes most of the
voxels.

Memory: a 512^3 ``int16`` volume is 256 MB, a 1000^3 one 2 GB. The work is
done in slabs of a few million voxels along the volume's last axis.
Connected components are labelled slab by slab and joined with a union-find
over the slab boundaries; each slab's labels are kept as runs along its rows
(a smooth mask has a few per row), the outside as one bit per voxel, and
meshing runs slab by slab on the object's bounding box.

:func:`extract_files` runs a batch of volume files (``hortishape extract``)
resumably; :func:`render_extraction` draws the surface beside two slices of
the volume with the surface's outline on them, for checking by eye.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
import time
import traceback
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from ._version import __version__
from ._batch import raise_failed, run_jobs
from .errors import ExtractionWarning, HortishapeError, MeshError, VolumeError
from ._files import Progress, atomic_path
from ._memory import give_back_freed_memory
from .io import Volume, VolumeSource, find_sources, read_volume, volume_formats, write_mesh
from .mesh import Mesh
from .units import PRODUCT_EXTENT_MM, PRODUCT_VOLUME_ML, SizeCheck, check_size, likely_unit, plausible_voxel_factors

__all__ = [
    "ExtractResult",
    "Extraction",
    "IntensityLevels",
    "collect_volumes",
    "decimate",
    "extract_file",
    "extract_files",
    "extract_products",
    "extract_surface",
    "find_volumes",
    "split_products",
    "Split",
    "intensity_levels",
    "is_volume_source",
    "render_extraction",
    "taubin_smooth",
    "volume_stem",
]


# Voxels per slab: labels (int32) and intensities (float32) of a slab take
# 16 MB each, small next to a CT volume.
_SLAB_VOXELS = 4_000_000
# Voxels sampled for the histogram, and voxels of the coarse grid on which a
# support is separated from the product.
_HISTOGRAM_SAMPLES = 4_000_000
_COARSE_VOXELS = 4_000_000
# Voxels of the coarse grid on which a channel's depth is measured (mm-scale).
_PIT_VOXELS = 1_000_000
# A product smaller than this many voxels is taken as no product at all.
_MIN_OBJECT_VOXELS = 27

#: Gap widths (mm) tried in turn when closing the product: 0 fills only
#: cavities that are sealed off; each next width also closes gaps and channels
#: narrower than it (a box of that size cannot pass), until the product is one
#: solid of genus 0 that encloses no other piece.
GAPS_MM = (0.0, 1.0, 2.0, 4.0, 8.0)
#: A channel: the outside reaches deeper into the product than ``PIT_DEPTH``
#: of its smallest extent beyond where a box ``PIT_BOX_MM`` wide (at most
#: ``PIT_BOX_SHARE`` of that extent) reaches.
PIT_BOX_MM = 8.0
PIT_BOX_SHARE = 0.25
PIT_DEPTH = 0.25
#: A solid piece at least this share of the product's voxels, lying inside
#: the product's bounding box, means the outside leaked in (an open shell).
ENCLOSED_MIN_SHARE = 0.01
#: How many of the largest other pieces are checked for that.
ENCLOSED_CHECKED = 4
#: Other solid pieces (each at least ``ENCLOSED_MIN_SHARE`` of the product)
#: whose bounding boxes overlap the product's and that together hold at least
#: this share of its voxels: the product broke up at the level (flesh segments
#: parted by dark gaps, under a peel too thin or dim to hold them together),
#: and a wider gap is tried, up to ``BESIDE_GAP_MM``: pieces still apart there are
#: separate objects (the largest is kept, with a warning). Up to ``BESIDE_CHECKED``
#: of the largest pieces are looked at.
BESIDE_SHARE = 0.5
BESIDE_GAP_MM = 2.0
BESIDE_CHECKED = 32
#: A support that takes more than this share of the voxels above the level
#: is warned about; one that would leave less than ``1 - SUPPORT_REFUSE_SHARE``
#: of them is the product itself: it is kept whole, with a warning.
SUPPORT_WARN_SHARE = 0.5
SUPPORT_REFUSE_SHARE = 0.95
#: Erosion radii tried in turn to part a support from the product, as
#: multiples of ``support_radius``: the first that parts them is used.
SUPPORT_RADIUS_STEPS = (1.0, 2.0, 4.0)
#: The outermost tissue: rays along the volume's two finest axes, from outside,
#: stop where two voxels in a row are above the background by ``OUTER_DETECT``
#: of the contrast (or ``OUTER_NOISE`` times the background's noise, if more);
#: only rays within ``OUTER_ANGLE`` degrees of the surface's normal count
#: (``OUTER_ROWS`` rows sampled per axis). The tissue's intensity is the
#: median over the rays of the brightest voxel within ``OUTER_WINDOW_MM``
#: beyond. When it differs from the histogram's product peak by more than
#: ``OUTER_DIFFERS`` of the contrast, or the rays' mean profile pauses on the
#: way up to that peak (a dimmer skin too thin to fill the window), the level
#: is fitted on its edge instead (:func:`_outer_layer`).
OUTER_DETECT = 0.15
OUTER_NOISE = 5.0
OUTER_WINDOW_MM = 2.0
OUTER_DIFFERS = 0.25
OUTER_ROWS = 8000
OUTER_ANGLE = 20.0
#: The rays' edge profile: from ``OUTER_BEFORE_MM`` outside the edge to
#: ``OUTER_AFTER_MM`` inside, in bins of ``OUTER_BIN_MM``.
OUTER_BEFORE_MM = 3.0
OUTER_AFTER_MM = 6.0
OUTER_BIN_MM = 0.05
#: A rays' mean profile (smoothed over ``OUTER_STEP_SMOOTH`` of the finest
#: voxel edge: less than a thin skin, more than the noise of the fewer rays
#: per bin of a coarse volume) that is one blurred step up to the product's
#: peak is the scanner's blur, not a tissue: no dip and no slope rising again
#: by more than ``OUTER_STEP_SLACK`` of the contrast or of the steepest slope.
OUTER_STEP_SMOOTH = 0.25
#: The outer edge's steepest point is sought within this distance of where
#: the rays cross its edge value.
OUTER_STEP_NEAR_MM = 1.0
OUTER_STEP_SLACK = 0.1
#: Where the rays' brightest voxel is near the product's peak, the profile is
#: read until it comes within this share of the contrast of the peak.
OUTER_STEP_TOP = 0.1
#: A magnitude image (MRI): its background within ``MAGNITUDE_NEAR`` of the contrast from its zero,
#: and, where its values run below 0, within ``MAGNITUDE_TAIL`` times the background's noise above
#: the smallest value (:func:`_magnitude_zero`).
MAGNITUDE_NEAR = 0.1
MAGNITUDE_TAIL = 3.0
#: A constant filling part of the volume (a CT's outside of the reconstructed circle: DICOM's
#: pixel padding value, -2000 or -3024 HU): the histogram's lowest value when it holds at least
#: ``PADDING_MIN_SHARE`` of the voxels, more than ``PADDING_SPIKE`` times any of the next
#: ``PADDING_NEXT`` values (no noise: not the scanner's air), and the rest of the background
#: (below Otsu's threshold without it) holds at least ``PADDING_REST`` times as many, in a peak at
#: least ``PADDING_GAP`` of the way from the constant to that threshold. It is left out of the
#: histogram: the air around the product is the background. (An air that is all one value, as in a
#: volume whose air was set to 0 or a noiseless one, has only the edge's partial volumes beside
#: it, most of them next to that value.)
PADDING_MIN_SHARE = 0.01
PADDING_SPIKE = 20.0
PADDING_NEXT = 3
PADDING_REST = 0.1
PADDING_GAP = 0.1
#: The fitted level is kept under this share of the way from the background
#: to the outer tissue's peak.
OUTER_MAX_SHARE = 0.75
#: Fewer rays than this reaching the product: the histogram's peaks are kept.
OUTER_MIN_RAYS = 50
#: A surface smaller or larger across than this (mm) is warned about
#: (:func:`extract_file` refuses it, see :data:`hortishape.units.PRODUCT_EXTENT_MM`).
FRUIT_EXTENT_MM = (10.0, 600.0)
#: Across the slices (the coarsest axis, at least ``SLICE_ANISOTROPY`` times the finest),
#: the ``SLICE_QUANTILE`` of the outermost tissue's peaks; where ``SLICE_SHARE`` of the way
#: to it from the background is below the level, what is inside is decided there instead
#: (no lower than the rays' detection level), when no gap width closes the product at the
#: level, or only the widest does and the lower level's product holds ``LOWER_GAIN`` more: a
#: thin peel stays whole at the poles.
SLICE_ANISOTROPY = 1.25
SLICE_QUANTILE = 0.1
SLICE_SHARE = 0.5
#: The lower level's product is kept over the level's, both whole, when it holds this share more:
#: the level's gaps closed over a pole that a peel thinner than a slice left open.
LOWER_GAIN = 0.01
#: The surface is meshed at least this share of a step from the values the voxels take (:func:`_value_grid`).
ISO_OFF_INTEGER = 0.05


# --------------------------------------------------------------------------
# Intensity levels
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class IntensityLevels:
    """The intensities that separate product from background.

    Attributes
    ----------
    background : float
        Intensity of the background: the histogram peak below ``threshold``.
    foreground : float
        Intensity of the product: the histogram peak above ``threshold``.
    threshold : float
        Otsu's threshold (or the given level) that splits the histogram.
    level : float
        The iso level of the surface, on the boundary between the background
        and the outermost tissue (see ``method``), or the given level.
        Voxels above it are inside.
    outer : float
        Intensity of the outermost tissue, seen by rays from outside (NaN
        when too few rays reach the product, or with a given level).
    method : str
        How the level was chosen: ``"peaks"`` (half-way between the
        histogram's peaks: the outermost tissue is the product's main one),
        ``"outer"`` (the outermost tissue differs from the main one, a peel
        in MRI: the value on its outer boundary, from a model of the layers
        fitted to the rays' profile across the edge) or ``"given"``.
    segment_level : float
        The level that decides what is inside (the product's voxels, the
        gaps to close): ``level``, or lower where the outermost tissue,
        seen along the volume's coarsest axis, stays below ``level`` (a
        peel thinner than a slice: ``slice_outer``). The surface is meshed
        at ``level`` wherever the voxels reach it, and between the two
        levels only where they do not. NaN: ``level``. In an
        :class:`Extraction`'s levels, the one that was used: ``level``
        unless no gap width closed the product there.
    slice_outer : float
        The outermost tissue's brightness along the coarsest axis (the 10th
        percentile of the rays' peaks), when it set ``segment_level``; NaN
        otherwise (and in an :class:`Extraction` whose product the level
        itself closed).
    padding : float
        A constant filling part of the volume (outside a CT's reconstructed
        circle), left out of the histogram so that the background is the air
        around the product; NaN when there is none.
    """

    background: float
    foreground: float
    threshold: float
    level: float
    outer: float = float("nan")
    method: str = "peaks"
    segment_level: float = float("nan")
    slice_outer: float = float("nan")
    padding: float = float("nan")

    @property
    def segment(self) -> float:
        """The level that decides what is inside: ``segment_level``, or ``level``."""
        return self.segment_level if math.isfinite(self.segment_level) else self.level

    def explain(self) -> str:
        """One sentence on how the level was chosen, for logs and pictures."""
        if self.method == "given":
            return f"level {self.level:g} (given)"
        if self.method == "outer":
            if abs(self.outer - self.foreground) > OUTER_DIFFERS * abs(self.foreground - self.background):
                tissue = (f"the outermost tissue ({self.outer:.4g}, which differs from the main tissue, "
                          f"{self.foreground:.4g})")
            else:
                tissue = (f"a skin dimmer than the main tissue ({self.foreground:.4g}), too thin to be read "
                          "on its own (the rays' profile pauses on it)")
            text = (f"level {self.level:.4g}: on the outer edge of {tissue}, fitted to rays from "
                    f"the background ({self.background:.4g})")
        else:
            text = (f"level {self.level:.4g}: half-way between the background ({self.background:.4g}) and "
                    f"the product ({self.foreground:.4g})")
        if self.segment < self.level:
            text += (f"; inside from {self.segment:.4g}: across the slices the outermost tissue "
                     f"reaches only {self.slice_outer:.4g} (thinner than a slice)")
        if math.isfinite(self.padding):
            text += (f"; the value {self.padding:.4g} filling part of the volume (outside the reconstructed "
                     "field of view?) left out")
        return text


def _as_volume(volume) -> Volume:
    if isinstance(volume, Volume):
        return volume
    return Volume(volume, spacing=1.0)


def _sample(data: np.ndarray) -> np.ndarray:
    """About ``_HISTOGRAM_SAMPLES`` voxels of ``data``, on a regular grid."""
    step = max(1, math.ceil((data.size / _HISTOGRAM_SAMPLES) ** (1.0 / 3.0)))
    return np.asarray(data[::step, ::step, ::step]).ravel()


def _value_grid(sample: np.ndarray) -> tuple[float, float] | None:
    """The grid ``(origin, step)`` that the voxel values lie on, or None.

    An 8-bit MRI keeps its 256 values when it is stored as float (a NIfTI's
    ``scl_slope``, a DICOM's rescale slope) or multiplied up: the histogram
    is then counted in bins of that step, and the level kept off its values,
    so the surface does not depend on how the same values are stored.
    Read from the histogram's subsample (:func:`_sample`); None when the
    values are not on a grid of at most 65,537 values (a continuous float
    volume).
    """
    sample = np.asarray(sample).ravel()
    lo, hi = sample.min(), sample.max()
    if sample.dtype.kind in "biu" and int(hi) - int(lo) <= 65_536:
        present = np.flatnonzero(np.bincount((sample.astype(np.int64) - int(lo))))
        step = int(np.gcd.reduce(np.diff(present))) if len(present) > 1 else 1
        return float(lo), float(step)
    if sample.dtype.kind not in "f":
        return None
    values = np.unique(sample.astype(np.float64))
    values = values[np.isfinite(values)]
    if len(values) < 2 or len(values) > 65_537:
        return None
    origin = float(values[0])
    offset = values - origin
    step = float(np.diff(values).min())
    # refined on the largest value: the smallest gap carries the float's rounding
    step = offset[-1] / max(1.0, round(offset[-1] / step))
    k = np.rint(offset / step)
    if k[-1] > 65_536 or np.max(np.abs(offset / step - k)) > 0.01:
        return None
    return origin, step


def _histogram(sample: np.ndarray, grid: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray, float]:
    """Counts, bin centres and bin width of the voxels' subsample (:func:`_sample`): one bin per
    value of their ``grid`` (:func:`_value_grid`), else 4096 bins."""
    if grid is not None:
        origin, step = grid
        k = np.rint((sample.astype(np.float64) - origin) / step).astype(np.int64)
        counts = np.bincount(k[k >= 0])
        return counts, origin + step * np.arange(len(counts), dtype=np.float64), step
    lo, hi = sample.min(), sample.max()
    counts, edges = np.histogram(sample.astype(np.float64), bins=4096, range=(float(lo), float(hi)))
    return counts, 0.5 * (edges[:-1] + edges[1:]), float(edges[1] - edges[0])


def _is_padding(counts: np.ndarray, centres: np.ndarray) -> bool:
    """Whether the histogram's lowest bin is a constant filling part of the volume (see
    ``PADDING_MIN_SHARE``), not the scanner's air."""
    if len(counts) < PADDING_NEXT + 2:
        return False
    first, total = float(counts[0]), float(counts.sum())
    if first < PADDING_MIN_SHARE * total or first <= PADDING_SPIKE * float(counts[1 : 1 + PADDING_NEXT].max()):
        return False
    from skimage.filters import threshold_otsu

    rest = counts.copy()
    rest[0] = 0
    threshold = float(threshold_otsu(hist=(rest, centres)))
    below = centres <= threshold
    if float(rest[below].sum()) < PADDING_REST * first:
        return False
    from scipy.ndimage import gaussian_filter1d

    # the rest's peak, smoothed over 1 % of the bins below the threshold
    sigma = max(1.0, 0.01 * float(np.count_nonzero(below)))
    air = float(centres[np.argmax(gaussian_filter1d(np.where(below, rest, 0).astype(np.float64), sigma))])
    return air - float(centres[0]) >= PADDING_GAP * (threshold - float(centres[0]))


def _peak(smooth: np.ndarray, centres: np.ndarray, width: float) -> float:
    """Position of the highest peak, refined by a parabola through three bins."""
    i = int(np.argmax(smooth))
    if 0 < i < len(smooth) - 1:
        a, b, c = smooth[i - 1], smooth[i], smooth[i + 1]
        den = a - 2.0 * b + c
        if den < 0:
            return float(centres[i] + width * 0.5 * (a - c) / den)
    return float(centres[i])


def intensity_levels(volume, *, level: float | None = None, name: str = "volume") -> IntensityLevels:
    """Background and product intensity, and the iso level of the product's surface.

    Parameters
    ----------
    volume : Volume or (nx, ny, nz) array_like
        The CT volume (an array is taken with 1 mm voxels).
    level : float, optional
        The iso level. Default: on the boundary between the background and
        the outermost tissue (see the module docstring): half-way between the
        histogram's peaks either side of Otsu's threshold, or, where rays
        from outside enter a first tissue of another brightness, the value on
        its outer boundary from a model of the layers fitted to the rays.
        With a given level the peaks are taken either side of it.
    name : str, default: "volume"
        What to call the volume in error messages (usually its file name).

    Returns
    -------
    IntensityLevels

    Raises
    ------
    VolumeError
        If every voxel has the same value, or no voxel (or every voxel) is
        above ``level``.

    Examples
    --------
    >>> data = np.zeros((20, 20, 20), np.int16)
    >>> data[5:15, 5:15, 5:15] = 1000
    >>> intensity_levels(data).level
    500.0
    """
    vol = _as_volume(volume)
    sample = _sample(vol.data)
    return _intensity_levels(vol, level, name, sample, _value_grid(sample))


def _intensity_levels(vol: Volume, level: float | None, name: str, sample, grid) -> IntensityLevels:
    counts, centres, width = _histogram(sample, grid)
    data = vol.data
    vmin, vmax = float(data.min()), float(data.max())
    padding = float("nan")
    if _is_padding(counts, centres):
        padding, counts = vmin, counts.copy()
        counts[0] = 0
    if vmin == vmax:
        raise VolumeError(f"{name}: every voxel has the same value ({vmin:g}); there is no object to extract")
    if level is not None:
        level = float(level)
        if not math.isfinite(level):
            raise VolumeError(f"{name}: the level must be a finite number, got {level}")
        if level >= vmax:
            raise VolumeError(
                f"{name}: no voxel is above the level {level:g} (the largest value is {vmax:g}); no object"
            )
        if level < vmin:
            raise VolumeError(
                f"{name}: every voxel is above the level {level:g} (the smallest value is {vmin:g}); "
                "no background around the object"
            )
        threshold = level
    else:
        from skimage.filters import threshold_otsu

        threshold = float(threshold_otsu(hist=(counts, centres)))
    below = centres <= threshold
    n_below, n_above = counts[below].sum(), counts[~below].sum()
    if n_below == 0 or n_above == 0:
        # the subsample missed one side (a speck in a large volume): the extremes
        bg, fg = vmin, vmax
    else:
        from scipy.ndimage import gaussian_filter1d

        m_bg = np.average(centres[below], weights=counts[below])
        m_fg = np.average(centres[~below], weights=counts[~below])
        # smooth over 1% of the contrast: a noisy peak keeps its place, its bins' noise goes
        sigma = max(1.0, 0.01 * abs(m_fg - m_bg) / width)
        # each side on its own: the tail of a tall peak must not make the other side's peak
        side = counts.astype(np.float64)
        bg = _peak(gaussian_filter1d(np.where(below, side, 0.0), sigma, mode="constant"), centres, width)
        fg = _peak(gaussian_filter1d(np.where(below, 0.0, side), sigma, mode="constant"), centres, width)
    if level is not None:
        return IntensityLevels(background=bg, foreground=fg, threshold=threshold, level=float(level),
                               method="given", padding=padding)
    below_bg = centres <= bg
    noise = (math.sqrt(np.average((centres[below_bg] - bg) ** 2, weights=counts[below_bg]))
             if counts[below_bg].sum() else 0.0)
    outer, edge, rays = _outer_intensity(vol, bg, fg, noise)
    level, method = 0.5 * (bg + fg), "peaks"
    # the rays' edge profile, once: both the layer test and the layer model read it
    profile = _edge_profile(rays, edge) if math.isfinite(outer) and edge > bg else None
    if profile is not None and _outer_layer(profile, outer, bg, fg, float(np.min(vol.spacing))):
        fitted = _edge_level(profile, bg, outer, _magnitude_zero(vmin, bg, fg, noise),
                             unit=grid[1] if grid else 1.0)
        # a blurred edge's middle lies below OUTER_MAX_SHARE of its peak when the peel
        # is at least twice as thick as the blur: a fit above that is one a coarse
        # profile could not fix (a thin peel's brightness and thickness trade off)
        top = bg + OUTER_MAX_SHARE * (outer - bg)
        fitted = min(fitted, top) if math.isfinite(fitted) else edge
        if fitted > bg:
            level, method = fitted, "outer"
    segment, across = level, float("nan")
    if fg > bg:
        detect = _detect_level(bg, fg, noise)
        peak = _slice_outer(vol, detect)
        lower = max(detect, bg + SLICE_SHARE * (peak - bg)) if math.isfinite(peak) else level
        if lower < level:
            segment, across = lower, peak
    return IntensityLevels(background=bg, foreground=fg, threshold=threshold, level=level, outer=outer,
                           method=method, segment_level=segment, slice_outer=across, padding=padding)


def _along_normal(data: np.ndarray, spacing: np.ndarray, place: np.ndarray, axis: int) -> np.ndarray:
    """Whether the intensity gradient at each voxel ``place`` (k, 3) is within
    ``OUTER_ANGLE`` degrees of the index axis ``axis`` (False at the border)."""
    shape = np.asarray(data.shape)
    inner = np.all((place >= 1) & (place <= shape - 2), axis=1)
    grad = np.zeros((len(place), 3))
    p = place[inner]
    for a in range(3):
        up, down = p.copy(), p.copy()
        up[:, a] += 1
        down[:, a] -= 1
        grad[inner, a] = (data[tuple(up.T)].astype(np.float64) - data[tuple(down.T)]) / spacing[a]
    norm = np.linalg.norm(grad, axis=1)
    return inner & (np.abs(grad[:, axis]) >= math.cos(math.radians(OUTER_ANGLE)) * norm) & (norm > 0)


def _sampled_rows(data: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """About ``OUTER_ROWS`` rows of voxels along ``axis`` (float32, one per row of the result) and
    each row's place along the other two axes."""
    n = data.shape[axis]
    others = [a for a in range(3) if a != axis]
    stride = max(1, math.ceil(math.sqrt(data.shape[others[0]] * data.shape[others[1]] / OUTER_ROWS)))
    index = [slice(None)] * 3
    for a in others:
        index[a] = slice(None, None, stride)
    rows = np.moveaxis(np.asarray(data[tuple(index)]), axis, -1).reshape(-1, n).astype(np.float32)
    across = np.stack(np.meshgrid(*(np.arange(0, data.shape[a], stride) for a in others), indexing="ij"),
                      axis=-1).reshape(-1, 2)
    return rows, across


def _outer_intensity(vol: Volume, background: float, foreground: float, noise: float):
    """Intensity of the outermost tissue and of its outer edge, from rays that enter the product.

    Rows of voxels along the volume's two finest axes (a subsample of them),
    read from both ends, stop at the first two voxels in a row above a
    detection threshold; only rays that cross the surface nearly square are
    kept. The ray's tissue intensity is its brightest voxel within
    ``OUTER_WINDOW_MM`` beyond; its edge intensity is the value where it
    rises most steeply there (a first estimate: on a thin peel it lies
    outside the boundary, see :func:`_edge_level`). Returns the medians over
    the rays and the rays themselves, ``(rows, first hit, spacing)`` per
    axis and direction (NaNs and no rays with fewer than ``OUTER_MIN_RAYS``).
    Assumes a product brighter than its background, as in CT and MRI.
    """
    if foreground <= background:
        return float("nan"), float("nan"), []
    data = vol.data
    detect = _detect_level(background, foreground, noise)
    # rises this close are equal: a float's rounding must not tell them apart, nor bend a straight run
    tie = 1e-5 * (foreground - background)
    maxima, edges, rays = [], [], []
    for axis in np.argsort(vol.spacing, kind="stable")[:2]:
        n = data.shape[axis]
        others = [a for a in range(3) if a != axis]
        rows, across = _sampled_rows(data, axis)
        window = max(3, math.ceil(OUTER_WINDOW_MM / float(vol.spacing[axis])))
        if n < window + 3:
            continue
        for backwards in (False, True):
            r = rows[:, ::-1] if backwards else rows
            high = r > detect
            pair = high[:, :-1] & high[:, 1:]
            first = pair.argmax(axis=1)
            # from outside: the ray starts in the background
            ok = pair.any(axis=1) & (first >= 2)
            if ok.any():
                place = np.full((len(r), 3), -1)
                place[:, axis] = np.where(backwards, n - 1 - first, first)
                place[:, others[0]], place[:, others[1]] = across[:, 0], across[:, 1]
                # rays that cross the surface within OUTER_ANGLE of its normal: a slanted
                # ray stretches the edge, and a thin peel's peak fades on it
                ok &= _along_normal(data, vol.spacing, place, axis)
            if ok.sum() < 2:
                continue
            r, first = r[ok], first[ok]
            rays.append((r, first, float(vol.spacing[axis])))
            at = np.clip(first[:, None] + np.arange(window)[None, :], 0, n - 1)
            maxima.append(np.take_along_axis(r, at, axis=1).max(axis=1))
            # the steepest point of the edge, from two voxels before the hit to the window's end
            at = np.clip(first[:, None] + np.arange(-1, window)[None, :], 1, n - 2)
            rise = np.take_along_axis(r, at + 1, axis=1) - np.take_along_axis(r, at - 1, axis=1)
            ray = np.arange(len(r))
            j = (rise >= rise.max(axis=1, keepdims=True) - tie).argmax(axis=1)  # the first of equal rises
            i = at[ray, j]
            # between voxels: the top of a parabola through the rises about the steepest
            g0, g1, g2 = (rise[ray, np.clip(j + d, 0, rise.shape[1] - 1)] for d in (-1, 0, 1))
            curve = g0 - 2.0 * g1 + g2
            # no peak where the rises run straight
            shift = np.clip(np.divide(0.5 * (g0 - g2), curve, out=np.zeros_like(curve), where=curve < -tie),
                            -0.5, 0.5)
            # within the two voxels either side: across a step sharper than a voxel the line
            # through the steepest point runs far beyond them (below the background)
            a, b = r[ray, i - 1], r[ray, i + 1]
            edges.append(np.clip(r[ray, i] + shift * 0.5 * g1, np.minimum(a, b), np.maximum(a, b)))
    if not maxima or sum(map(len, maxima)) < OUTER_MIN_RAYS:
        return float("nan"), float("nan"), []
    outer = float(np.median(np.concatenate(maxima)))
    # the edge from the rays that met the outermost tissue: where a thin or dim peel fills too
    # few voxels to be met, a ray's first voxels above the threshold are the flesh, and its
    # edge is another (mixed in, the rays' edge profile fits neither)
    met = [np.abs(m - outer) <= np.abs(m - foreground) for m in maxima]
    if sum(int(k.sum()) for k in met) >= OUTER_MIN_RAYS:
        rays = [(r[k], first[k], h) for (r, first, h), k in zip(rays, met) if k.any()]
        edges = [e[k] for e, k in zip(edges, met)]
    return outer, float(np.median(np.concatenate(edges))), rays


def _detect_level(background: float, foreground: float, noise: float) -> float:
    """The intensity above which a ray from outside has met the product, clear of the noise."""
    return background + max(OUTER_DETECT * (foreground - background), OUTER_NOISE * noise)


def _slice_outer(vol: Volume, detect: float) -> float:
    """The outermost tissue's brightness across the slices: the ``SLICE_QUANTILE`` of the peaks
    that rays along the volume's coarsest axis meet within ``OUTER_WINDOW_MM`` of the first voxel
    above ``detect``, over the rays that cross the surface nearly square. A peel thinner than a
    slice fills none of them: its peak there is a share of its brightness, and lower where it
    straddles two slices. NaN when the volume's voxels are cubes or too few rays are left.
    """
    spacing = np.asarray(vol.spacing, dtype=np.float64)
    axis = int(np.argmax(spacing))
    if spacing[axis] < SLICE_ANISOTROPY * spacing.min():
        return float("nan")
    data = vol.data
    n = data.shape[axis]
    others = [a for a in range(3) if a != axis]
    rows, across = _sampled_rows(data, axis)
    window = max(2, math.ceil(OUTER_WINDOW_MM / float(spacing[axis])))
    peaks = []
    for backwards in (False, True):
        r = rows[:, ::-1] if backwards else rows
        high = r > detect
        first = high.argmax(axis=1)  # one voxel: a thin peel may fill no two in a row
        ok = high.any(axis=1) & (first >= 2) & (first + window < n)
        if not ok.any():
            continue
        # the direction at the voxel before the hit: across a peel one voxel thick the
        # intensity falls again, and its own gradient points anywhere
        place = np.full((len(r), 3), -1)
        place[:, axis] = np.where(backwards, n - first, first - 1)
        place[:, others[0]], place[:, others[1]] = across[:, 0], across[:, 1]
        ok &= _along_normal(data, spacing, place, axis)
        at = first[ok, None] + np.arange(window)[None, :]
        peaks.append(np.take_along_axis(r[ok], at, axis=1).max(axis=1))
    if not peaks or sum(map(len, peaks)) < OUTER_MIN_RAYS:
        return float("nan")
    return float(np.quantile(np.concatenate(peaks), SLICE_QUANTILE))


def _edge_profile(rays, level: float):
    """The rays' mean profile across the outer edge, finely sampled: ``(u mm, mean, count)``.

    Each ray is placed by where it crosses ``level`` between voxels, so the
    rays' voxels fall at all offsets from the edge: together they sample the
    edge far finer than one voxel (as the slanted-edge method of measuring a
    scanner's blur does). Bins of ``OUTER_BIN_MM`` from ``-OUTER_BEFORE_MM``
    to ``OUTER_AFTER_MM`` about the crossing.
    """
    us, vs = [], []
    for r, first, spacing in rays:
        n = r.shape[1]
        rows = np.arange(len(r))
        reach = max(3, math.ceil(OUTER_WINDOW_MM / spacing))
        at = np.clip(first[:, None] + np.arange(-2, reach)[None, :], 0, n - 2)
        a, b = np.take_along_axis(r, at, axis=1), np.take_along_axis(r, at + 1, axis=1)
        cross = (a <= level) & (b > level)
        has = cross.any(axis=1)
        j = cross.argmax(axis=1)
        k = at[rows, j]
        lo, hi = a[rows, j], b[rows, j]
        x = k + (level - lo) / np.where(hi > lo, hi - lo, 1.0)
        before, after = math.ceil(OUTER_BEFORE_MM / spacing) + 1, math.ceil(OUTER_AFTER_MM / spacing) + 1
        pos = k[:, None] + np.arange(-before, after + 1)[None, :]
        inside = (pos >= 0) & (pos < n) & has[:, None]
        pos = np.clip(pos, 0, n - 1)
        us.append(((pos - x[:, None]) * spacing)[inside])
        vs.append(np.take_along_axis(r, pos, axis=1)[inside])
    u, v = np.concatenate(us), np.concatenate(vs).astype(np.float64)
    keep = (u >= -OUTER_BEFORE_MM) & (u < OUTER_AFTER_MM)
    b = ((u[keep] + OUTER_BEFORE_MM) / OUTER_BIN_MM).astype(np.int64)
    count = np.bincount(b)
    total = np.bincount(b, weights=v[keep])
    centre = -OUTER_BEFORE_MM + (np.arange(len(count)) + 0.5) * OUTER_BIN_MM
    full = count >= 5
    return centre[full], total[full] / count[full], count[full]


def _step_shape(profile, background: float, foreground: float, voxel: float, reach: float):
    """How the rays' mean profile (:func:`_edge_profile`) rises from the background to the
    product: ``(rises_again, dips)``, or None when it cannot tell.

    Along one blurred step the profile, past the outer edge's steepest point
    (within ``OUTER_STEP_NEAR_MM`` of where the rays cross the edge's value),
    rises ever more slowly until it reaches the product's peak (within
    ``reach`` of the contrast). A layer of its own shows a plateau whose
    slope rises again (a tissue dimmer than the flesh first) or a dip (a dark
    rind under a bright peel): by more than ``OUTER_STEP_SLACK`` of the
    steepest slope, or of the contrast for a dip. ``voxel`` is the finest
    voxel edge (mm): the profile is smoothed over ``OUTER_STEP_SMOOTH`` of it.
    """
    from scipy.ndimage import gaussian_filter1d

    u, mean, _ = profile
    if len(u) < 20:
        return None
    grid = np.arange(u[0], u[-1], OUTER_BIN_MM)
    v = gaussian_filter1d(np.interp(grid, u, mean), OUTER_STEP_SMOOTH * voxel / OUTER_BIN_MM)
    contrast = foreground - background
    top = np.flatnonzero((grid >= 0.0) & (v >= foreground - reach * contrast))
    if not len(top):
        return None
    slope = np.gradient(v, OUTER_BIN_MM)
    # the outer edge's steepest point: near where the rays cross its edge value (u = 0),
    # not a steeper edge further in
    near = np.flatnonzero(np.abs(grid[: top[0] + 1]) <= OUTER_STEP_NEAR_MM)
    if not len(near):
        return None
    steepest = int(near[np.argmax(slope[near])])
    after = slope[steepest : top[0] + 1]
    rises_again = bool(np.max(after - np.minimum.accumulate(after)) > OUTER_STEP_SLACK * slope[steepest])
    rest = v[steepest : top[0] + 1]
    dips = bool(np.max(np.maximum.accumulate(rest) - rest) > OUTER_STEP_SLACK * contrast)
    return rises_again, dips


def _outer_layer(profile, outer: float, background: float, foreground: float, voxel: float) -> bool:
    """Whether the rays meet a tissue of its own before the product's main one, so that the level
    is fitted on its edge (:func:`_edge_level`) rather than half-way between the histogram's peaks.

    Where the rays' brightest voxel differs from the product's peak by more
    than ``OUTER_DIFFERS`` of the contrast, it is a tissue unless the profile
    is one blurred step (:func:`_step_shape`): a scanner's blur wider than
    ``OUTER_WINDOW_MM`` keeps the brightest voxel within the window below the
    peak too. Where it is near the peak, a skin dimmer than the flesh but too
    thin to fill the window shows only as a plateau in the profile, whose
    slope rises again before the profile comes within ``OUTER_STEP_TOP`` of
    the peak; a thin peel near the flesh's brightness over a dark rind (a
    dip) is left to the peaks, which lie on its edge as well.
    """
    if abs(outer - foreground) > OUTER_DIFFERS * abs(foreground - background):
        shape = _step_shape(profile, background, foreground, voxel, OUTER_DIFFERS)
        return shape is None or any(shape)
    shape = _step_shape(profile, background, foreground, voxel, OUTER_STEP_TOP)
    return shape is not None and shape[0] and not shape[1]


def _magnitude_zero(vmin: float, background: float, foreground: float, noise: float) -> float | None:
    """The value of no signal in a magnitude image (MRI), or None for another kind of image.

    A magnitude image has no values below its zero and its background lies
    near it (within ``MAGNITUDE_NEAR`` of the contrast): 0 as scanners store
    it; the smallest value where the volume runs below 0 (stored with an
    offset, or z-scored) but the background's lower tail stops short, within
    ``MAGNITUDE_TAIL`` times its noise (a real-valued image's Gaussian noise
    reaches four or five times its noise below it over a volume's voxels).
    """
    near = MAGNITUDE_NEAR * (foreground - background)
    if vmin >= 0:
        return 0.0 if background < near else None
    return vmin if background - vmin < min(near, MAGNITUDE_TAIL * noise) else None


def _edge_level(profile, background: float, outer: float, zero: float | None, unit: float = 1.0) -> float:
    """The intensity on the outer boundary, from a model of the layers fitted to the rays' edge
    profile (:func:`_edge_profile`, placed at the edge's first estimate).

    Along the normal, the intensity steps from the background ``b`` to the
    outer tissue ``P`` at the boundary, then to a second layer ``R`` and a
    third ``F``, each step blurred by the same Gaussian (a scanner's point
    spread). A thin peel never reaches ``P`` once blurred, and its inner
    edge pulls the steepest point of its outer edge outwards; the model
    knows both, so the value it gives on the boundary holds for thick and
    thin peels alike. In a magnitude image (MRI) the background's noise
    lifts dark voxels: the model's intensity is ``sqrt(S^2 + c^2)``, with
    ``S`` the layers' and ``c`` the noise floor, both from the image's
    ``zero`` (:func:`_magnitude_zero`; None: not a magnitude image). NaN
    when the fit fails. The fit runs in ``unit`` steps of intensity (the
    step between the voxels' values): its finite differences are not
    scale-free, and the same values stored as floats or multiplied up must
    give the same level.
    """
    from scipy.optimize import least_squares
    from scipy.special import ndtr

    u, mean, count = profile
    if len(u) < 20:
        return float("nan")
    magnitude = zero is not None
    origin = zero if magnitude else 0.0
    mean, background, outer = (mean - origin) / unit, (background - origin) / unit, (outer - origin) / unit
    weight = np.sqrt(count)
    lo_v, hi_v = float(mean.min()), float(mean.max())
    span = max(hi_v - lo_v, 1e-9)

    def model(q, u):
        u0, s, t, t2, P, R, F, floor = q
        b = 0.0 if magnitude else floor
        layers = (b + (P - b) * ndtr((u - u0) / s) + (R - P) * ndtr((u - u0 - t) / s)
                  + (F - R) * ndtr((u - u0 - t - t2) / s))
        return np.sqrt(layers**2 + floor**2) if magnitude else layers

    def residual(q):
        return weight * (model(q, u) - mean) / span

    beyond = mean[u > 1.0]
    start = np.array([0.0, 0.3, 1.0, 2.0, outer, float(beyond.min()) if len(beyond) else outer,
                      hi_v, max(background, 0.0) if magnitude else background])
    lower = [-2.0, 0.02, 0.05, 0.05, lo_v - span, lo_v - span, lo_v - span, 0.0 if magnitude else lo_v - span]
    upper = [2.0, 3.0, 10.0, 20.0, hi_v + span, hi_v + span, hi_v + span, hi_v]
    start = np.clip(start, np.asarray(lower) + 1e-9, np.asarray(upper) - 1e-9)
    try:
        fit = least_squares(residual, start, bounds=(lower, upper), x_scale="jac", max_nfev=400)
    except (ValueError, np.linalg.LinAlgError):
        return float("nan")
    if not fit.success:
        return float("nan")
    return origin + unit * float(model(fit.x, np.array([fit.x[0]]))[0])


# --------------------------------------------------------------------------
# Connected components slab by slab
# --------------------------------------------------------------------------


def _grow_box(lo: np.ndarray, hi: np.ndarray, mask: np.ndarray, z_shift: int) -> None:
    """Grow the box ``[lo, hi)`` (z, y, x, in place) to hold ``mask``'s voxels, its planes from ``z_shift``."""
    for axis, others in ((0, (1, 2)), (1, (0, 2)), (2, (0, 1))):
        hit = np.flatnonzero(mask.any(axis=others))
        if len(hit):
            shift = z_shift if axis == 0 else 0
            lo[axis] = min(lo[axis], hit[0] + shift)
            hi[axis] = max(hi[axis], hit[-1] + 1 + shift)


def _slab_bounds(lo: int, hi: int, step: int) -> list[tuple[int, int]]:
    """Split ``[lo, hi)`` at the multiples of ``step``."""
    out = []
    z = lo
    while z < hi:
        end = min(hi, (z // step + 1) * step)
        out.append((z, end))
        z = end
    return out


class _Runs:
    """A slab's labels as runs of equal values along the flattened array.

    Kept as they are (in the smallest integer type) when runs would take more
    memory, as for a noisy mask.
    """

    def __init__(self, lab: np.ndarray, n_labels: int) -> None:
        dtype = np.min_scalar_type(n_labels)
        flat = lab.ravel()
        starts = np.flatnonzero(flat[1:] != flat[:-1]) + 1
        self.shape = lab.shape
        if (len(starts) + 1) * (4 + dtype.itemsize) >= flat.size * dtype.itemsize:
            self.plain, self.starts, self.values = lab.astype(dtype), None, None
        else:
            self.plain = None
            self.starts = starts.astype(np.int32 if flat.size < 2**31 else np.int64)
            self.values = flat[np.r_[0, starts]].astype(dtype)

    def array(self) -> np.ndarray:
        if self.plain is not None:
            return self.plain
        size = int(np.prod(self.shape))
        lengths = np.diff(np.r_[0, self.starts, size])
        return np.repeat(self.values, lengths).reshape(self.shape)


class _Components:
    """6-connected components of a mask, labelled slab by slab along axis 0.

    The mask is given by ``get_mask(z0, z1)`` for the planes ``[z0, z1)`` of a
    region of the volume (shape ``(Z, Y, X)`` in region coordinates). Each
    slab is labelled with :func:`scipy.ndimage.label`; labels that touch
    across a slab boundary are joined (union-find by a sparse graph). A slab's
    labels are kept as runs along the flattened slab (a smooth mask has a few
    runs per row: kilobytes where the labels themselves take megabytes), or
    as they are when runs would not save memory (:class:`_Runs`).

    Attributes per component (index ``c``): ``size[c]`` voxels and
    ``border[c]``, whether it touches the region's border.
    """

    def __init__(self, get_mask, slabs) -> None:
        from scipy import ndimage
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        self.slabs = slabs
        self.z_lo = slabs[0][0]
        self._structure = ndimage.generate_binary_structure(3, 1)
        offsets, counts, stored = [], [], []
        sizes, borders, pairs = [], [], []
        total = 0
        previous = None
        for k, (z0, z1) in enumerate(slabs):
            lab, n = ndimage.label(get_mask(z0, z1), structure=self._structure)
            offsets.append(total)
            counts.append(n)
            if n:
                sizes.append(np.bincount(lab.ravel(), minlength=n + 1)[1:])
                touch = np.zeros(n + 1, dtype=bool)
                for face in (lab[:, 0, :], lab[:, -1, :], lab[:, :, 0], lab[:, :, -1]):
                    touch[face.ravel()] = True
                if k == 0:
                    touch[lab[0].ravel()] = True
                if k == len(slabs) - 1:
                    touch[lab[-1].ravel()] = True
                borders.append(touch[1:])
                if previous is not None:
                    both = (previous > 0) & (lab[0] > 0)
                    if both.any():
                        # one key per touching pair of labels; runs of equal keys are
                        # dropped first, which leaves little to sort
                        key = (previous[both] << 32) | lab[0][both].astype(np.int64)
                        key = np.unique(key[np.r_[True, key[1:] != key[:-1]]])
                        pairs.append(np.stack([key >> 32, (key & 0xFFFFFFFF) + total], axis=1))
            previous = np.where(lab[-1] > 0, lab[-1].astype(np.int64) + total, 0) if n else None
            stored.append(_Runs(lab, n))
            total += n
            del lab
        self.offsets, self.counts, self.stored = offsets, counts, stored
        self.n_labels = total
        if total == 0:
            self.root = np.zeros(1, dtype=np.int64)
            self.size = np.zeros(0, dtype=np.int64)
            self.border = np.zeros(0, dtype=bool)
            return
        edges = np.concatenate(pairs) - 1 if pairs else np.zeros((0, 2), dtype=np.int64)
        graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(total, total))
        n_comp, comp = connected_components(graph, directed=False)
        self.root = np.concatenate([[-1], comp]).astype(np.int64)  # global label -> component
        self.size = np.bincount(comp, weights=np.concatenate(sizes), minlength=n_comp).astype(np.int64)
        self.border = np.bincount(comp, weights=np.concatenate(borders), minlength=n_comp) > 0

    def bounds(self, chosen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box ``(lo, hi)`` (z, y, x; ``hi`` exclusive) of the ``chosen`` components."""
        lo = np.array([np.iinfo(np.int64).max] * 3)
        hi = np.zeros(3, dtype=np.int64)
        for k, (z0, _) in enumerate(self.slabs):
            _grow_box(lo, hi, self.select(k, chosen), z0 - self.z_lo)
        return lo, hi

    def boxes(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounding boxes ``(lo, hi)``, each ``(len(ids), 3)``, of the components ``ids``, in one pass."""
        lo = np.full((len(ids), 3), np.iinfo(np.int64).max)
        hi = np.zeros((len(ids), 3), dtype=np.int64)
        chosen = [np.arange(len(self.size)) == c for c in ids]
        for k, (z0, _) in enumerate(self.slabs):
            labels = self.labels(k)
            for i, mask in enumerate(chosen):
                _grow_box(lo[i], hi[i], self.select(k, mask, labels=labels), z0 - self.z_lo)
        return lo, hi

    def labels(self, k: int) -> np.ndarray:
        """The local labels of slab ``k``."""
        return self.stored[k].array()

    def select(self, k: int, chosen: np.ndarray, *, labels: np.ndarray | None = None) -> np.ndarray:
        """Mask of slab ``k``: voxels whose component is ``chosen`` ((n_components,) bool)."""
        n, off = self.counts[k], self.offsets[k]
        lut = np.zeros(n + 1, dtype=bool)
        if n:
            lut[1:] = chosen[self.root[off + 1 : off + n + 1]]
        return lut[self.labels(k) if labels is None else labels]


# --------------------------------------------------------------------------
# Support removal
# --------------------------------------------------------------------------


def _support_region(product_slab, slabs, shape, spacing_zyx, radius: float, factor: int):
    """Coarse mask of a support touching the product, or None.

    ``product_slab(k)`` gives the product's mask on slab ``k``. The product is
    reduced to a coarse grid (blocks of ``factor``^3 voxels, inside when at
    least half full), eroded by ``radius`` mm (a Euclidean distance
    transform), and split into 6-connected pieces. Pieces that reach the
    border of the volume are a support when at least one other piece does
    not (the product). The support is the part of the product within
    ``radius`` (plus a block) of those pieces: the opening of the support.
    A support thinner than ``2 * radius`` (a plate, a tray) vanishes in the
    erosion: it is what the product's opening leaves out, reaches the border
    and reaches far from the product (see :func:`_separate`). Where every
    eroded piece reaches the border (a thin bed along the volume's edge, whose
    air below is lost on the coarse grid), the erosion is tried again with
    the outside of the volume counted as air. Where nothing comes apart, the
    radius grows (``SUPPORT_RADIUS_STEPS``): a product resting on a bed with a
    flat base is joined to it over an area wider than ``2 * radius``.
    """
    c = factor
    nz, ny, nx = shape
    cz, cy, cx = -(-nz // c), -(-ny // c), -(-nx // c)
    full = np.zeros((cz, cy, cx), dtype=np.uint16)
    for k, (z0, z1) in enumerate(slabs):
        m = product_slab(k)
        pad = ((0, (-m.shape[0]) % c), (0, (-ny) % c), (0, (-nx) % c))
        if any(p[1] for p in pad):
            m = np.pad(m, pad)
        blocks = m.reshape(m.shape[0] // c, c, m.shape[1] // c, c, m.shape[2] // c, c)
        full[z0 // c : z0 // c + blocks.shape[0]] += blocks.sum(axis=(1, 3, 5), dtype=np.uint16)
    half = full * 2 >= c**3
    any_ = full > 0
    del full
    sampling = np.asarray(spacing_zyx, dtype=np.float64) * c
    for r in radius * np.asarray(SUPPORT_RADIUS_STEPS):
        support, all_reach = _separate(half, any_, sampling, float(r), outside_is_air=False)
        if support is None and all_reach:
            support, _ = _separate(half, any_, sampling, float(r), outside_is_air=True)
        if support is not None:
            return support
    return None


def _separate(half, any_, sampling, radius: float, *, outside_is_air: bool):
    """One try of :func:`_support_region` on the coarse masks: (support or None,
    whether every eroded piece reached the border)."""
    from scipy import ndimage

    six = ndimage.generate_binary_structure(3, 1)
    block = float(sampling.max())
    if outside_is_air:
        depth = ndimage.distance_transform_edt(np.pad(half, 1), sampling=sampling)[1:-1, 1:-1, 1:-1]
    else:
        depth = ndimage.distance_transform_edt(half, sampling=sampling)
    core = depth > radius
    del depth
    lab, n = ndimage.label(core, structure=six)
    touch = _border_blocks(lab, n) > 0
    if n == 0 or touch[1:].all():
        return None, n > 0
    if touch.any():
        # a support at least 2 * radius thick: its own eroded pieces, grown back
        # through the support's outer layer and a block beyond
        reach = ndimage.distance_transform_edt(~touch[lab], sampling=sampling)
        return (reach <= radius + block) & any_, False
    # none of the eroded product reaches the border, yet the product does: a
    # support thinner than 2 * radius that the erosion took whole. It is what the
    # opening (the eroded product grown back by radius, half a block of slack for
    # the grid) leaves out, where it reaches the border and lies farther from the
    # eroded product than the rounded rim of a product cut by the border can
    # (2 * radius and a block); the product's opening itself is never cut
    del lab
    grown = ndimage.distance_transform_edt(~core, sampling=sampling)
    opened = grown <= radius
    rest = half & ~(grown <= radius + 0.5 * block)
    lab, n = ndimage.label(rest, structure=six)
    met = _border_blocks(lab, n) * block**2
    touch = met > 0
    far = np.zeros(n + 1, dtype=bool)
    far[np.unique(lab[grown > 2.0 * radius + block])] = True
    del grown
    # and meets the border over more than a disc of the erosion's diameter: a
    # plate's edges do, a stalk cut off by the border does not
    touch &= far & (met > math.pi * radius**2)
    if not touch.any():
        return None, False
    reach = ndimage.distance_transform_edt(~touch[lab], sampling=sampling)
    return (reach <= block) & any_ & ~opened, False


def _border_blocks(lab: np.ndarray, n: int) -> np.ndarray:
    """How many border cells of the array each label 0..n holds (label 0, the background: 0)."""
    faces = (lab[0], lab[-1], lab[:, 0], lab[:, -1], lab[:, :, 0], lab[:, :, -1])
    counts = sum(np.bincount(f.ravel(), minlength=n + 1) for f in faces)
    counts[0] = 0
    return counts


def _repeat_crop(block: np.ndarray, start, shape, factor: int) -> np.ndarray:
    """``block`` on a grid ``factor`` times finer, the part of ``shape`` from ``start`` (fine voxels)."""
    up = np.repeat(np.repeat(np.repeat(block, factor, axis=0), factor, axis=1), factor, axis=2)
    return up[start[0]:start[0] + shape[0], start[1]:start[1] + shape[1], start[2]:start[2] + shape[2]]


def _upsample(coarse: np.ndarray, z0: int, z1: int, shape_yx, factor: int) -> np.ndarray:
    c = factor
    return _repeat_crop(coarse[z0 // c : -(-z1 // c)], (z0 - (z0 // c) * c, 0, 0), (z1 - z0, *shape_yx), c)


# --------------------------------------------------------------------------
# Mesh post-processing
# --------------------------------------------------------------------------


def _adjacency(faces: np.ndarray, n: int, *, closed: bool = False):
    """Vertex adjacency (n, n) CSR with int8 ones, from the faces' directed edges.

    On a closed, consistently oriented surface every edge is in the faces once
    in each direction, so the directed edges alone are the whole (symmetric)
    matrix; otherwise the matrix is symmetrized (more memory).
    """
    import scipy.sparse as sp

    f = np.asarray(faces)
    index = np.int32 if n < 2**31 - 1 else np.int64
    # edges (0, 1), (1, 2), (2, 0) of every face; the rows are the faces themselves when they are int32
    rows = np.ascontiguousarray(f, dtype=index).ravel()
    cols = f[:, [1, 2, 0]].astype(index).ravel()
    a = sp.csr_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n, n))
    del rows, cols
    if not closed:
        a = a.maximum(a.T).tocsr()
    return a


_ROWS_PER_BLOCK = 1 << 16


def _neighbour_sum(a):
    """The product ``a @ v`` with an adjacency matrix ``a`` of ones, row block by row block.

    A product needs float64 values (any other type is copied to float64 at
    every product), but they are all ones: the blocks share one buffer of
    ones, as long as a block's edges, instead of one value per edge.
    """
    import scipy.sparse as sp

    n = a.shape[0]
    bounds = [(r, min(r + _ROWS_PER_BLOCK, n)) for r in range(0, n, _ROWS_PER_BLOCK)]
    ones = np.ones(max(int(a.indptr[r1] - a.indptr[r0]) for r0, r1 in bounds) if n else 0)
    blocks = []
    for r0, r1 in bounds:
        p0, p1 = int(a.indptr[r0]), int(a.indptr[r1])
        blocks.append(sp.csr_matrix((ones[: p1 - p0], a.indices[p0:p1], a.indptr[r0 : r1 + 1] - p0),
                                    shape=(r1 - r0, a.shape[1])))

    def product(v: np.ndarray) -> np.ndarray:
        out = np.empty_like(v)
        for (r0, r1), b in zip(bounds, blocks):
            out[r0:r1] = b @ v
        return out

    return product


def _taubin(v: np.ndarray, faces: np.ndarray, iterations: int, pass_band: float, lam: float,
            *, closed: bool) -> np.ndarray:
    """Taubin smoothing of ``v`` in place (see :func:`taubin_smooth`)."""
    mu = 1.0 / (pass_band - 1.0 / lam)
    a = _adjacency(faces, len(v), closed=closed)
    degree = np.diff(a.indptr).astype(np.float64)
    neighbours = _neighbour_sum(a)
    del a
    moving = (degree > 0)[:, None]
    inv = np.divide(1.0, degree, out=np.zeros_like(degree), where=degree > 0)[:, None]
    every = bool(moving.all())
    for _ in range(iterations):
        for step in (lam, mu):
            delta = neighbours(v)
            delta *= inv
            delta -= v if every else v * moving
            delta *= step
            v += delta
            del delta
    return v


def taubin_smooth(vertices, faces, *, iterations: int = 10, pass_band: float = 0.1,
                  lam: float = 0.5) -> np.ndarray:
    """Smooth a surface without shrinking it (Taubin's lambda|mu filter).

    Each iteration is a Laplacian step of ``lam`` followed by an inflating
    step of ``mu = 1 / (pass_band - 1 / lam)`` (Taubin 1995, *A signal
    processing approach to fair surface design*), with the uniform
    (umbrella) Laplacian. Noise (high frequencies) is removed; the shape
    (frequencies under ``pass_band``) keeps its size, unlike plain Laplacian
    smoothing.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int
    iterations : int, default: 10
        Number of lambda|mu pairs; 0 returns a copy.
    pass_band : float, default: 0.1
        Pass-band frequency k_PB, in (0, 1).
    lam : float, default: 0.5
        The shrinking step, in (0, 1).

    Returns
    -------
    (n, 3) float64 ndarray
        New vertex positions (same order); the inputs are not modified.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(3, radius=10.0)
    >>> rng = np.random.default_rng(0)
    >>> noisy = s.vertices * (1 + 0.01 * rng.standard_normal((len(s.vertices), 1)))
    >>> r = np.linalg.norm(taubin_smooth(noisy, s.faces), axis=1)
    >>> bool(abs(r.mean() - 10.0) < 0.05 and r.std() < 0.05)
    True
    """
    v = np.array(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    iterations = int(iterations)
    if iterations < 0:
        raise ValueError(f"iterations must be at least 0, got {iterations}")
    if not (0.0 < pass_band < 1.0 and 0.0 < lam < 1.0):
        raise ValueError(f"pass_band and lam must lie in (0, 1), got {pass_band} and {lam}")
    if iterations == 0:
        return v
    return _taubin(v, f, iterations, pass_band, lam, closed=False)


def decimate(mesh: Mesh, n_vertices: int) -> Mesh:
    """Reduce a closed surface to about ``n_vertices`` vertices.

    Quadric error edge collapses (Garland & Heckbert 1997, libigl's
    ``qslim``), which keep the shape and the enclosed volume well. The
    result is a new mesh (new vertices; the input is not modified); a mesh
    with no more than ``n_vertices`` vertices is returned as it is.

    Parameters
    ----------
    mesh : Mesh
        A closed, manifold surface.
    n_vertices : int
        Vertices wanted, at least 4. The result has this many within a few
        vertices (a closed surface of genus g has ``2 (V + 2g - 2)`` faces).

    Returns
    -------
    Mesh

    Raises
    ------
    MeshError
        If ``n_vertices`` is below 4.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(4, radius=10.0)
    >>> decimate(Mesh(s.vertices, s.faces), 500).n_vertices
    500
    """
    import igl

    n_vertices = int(n_vertices)
    if n_vertices < 4:
        raise MeshError(f"n_vertices must be at least 4, got {n_vertices}")
    if mesh.n_vertices <= n_vertices:
        return mesh
    euler = mesh.n_vertices - len(mesh.edges()) + mesh.n_faces
    target_faces = max(4, 2 * (n_vertices - euler))
    out = igl.qslim(mesh.vertices, np.ascontiguousarray(mesh.faces, dtype=np.int32), target_faces)
    return Mesh(np.asarray(out[0], dtype=np.float64), np.asarray(out[1], dtype=np.int64))


# --------------------------------------------------------------------------
# Extraction
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Extraction:
    """The outer surface of the product in a CT volume (result of :func:`extract_surface`).

    Attributes
    ----------
    mesh : Mesh
        One closed, consistently oriented surface with outward normals, in
        world coordinates (mm).
    levels : IntensityLevels
        Background and product intensity and the iso level used.
    bounds : (3, 2) int64 ndarray
        The product's bounding box in voxel indices along x, y, z: first and
        one-past-last index.
    n_object_voxels : int
        Voxels of the product above the level (cavities not counted).
    n_filled_voxels : int
        Voxels of interior cavities filled in.
    n_support_voxels : int
        Voxels above the level dropped as a support touching the product.
    n_marching_cubes_vertices : int
        Vertices of the surface straight from marching cubes, before
        decimation.
    gap_mm : float
        Width of the gaps that were closed (0: only sealed cavities were
        filled); see :data:`GAPS_MM`.
    attempts : tuple of dict
        Each gap width tried: ``gap_mm``, ``genus`` of the product's
        surface, ``enclosed`` (other pieces inside its box: an open shell),
        ``channel_mm`` (how deep a narrow channel reaches into it, see
        :data:`PIT_DEPTH`) and ``n_filled_voxels``.
    warnings : tuple of str
        What a person should look at (also issued as
        :class:`~hortishape.errors.ExtractionWarning`).
    """

    mesh: Mesh
    levels: IntensityLevels
    bounds: np.ndarray
    n_object_voxels: int
    n_filled_voxels: int
    n_support_voxels: int
    n_marching_cubes_vertices: int
    gap_mm: float = 0.0
    attempts: tuple = ()
    warnings: tuple = ()

    @property
    def genus(self) -> int:
        """Genus of the surface (0: a sphere's topology), from its Euler number."""
        return _surface_genus(self.mesh.n_vertices, len(self.mesh.faces))

    @property
    def volume(self) -> float:
        """Enclosed volume of the surface, mm^3."""
        from .surface import signed_volume

        return abs(signed_volume(self.mesh.vertices, self.mesh.faces))


def _surface_genus(n_vertices: int, n_faces: int) -> int:
    """Genus of one closed triangle surface, from its Euler number (it has 3 f / 2 edges)."""
    return (2 - (n_vertices - n_faces // 2)) // 2


def _off_grid(level: float, grid: tuple[float, float] | None) -> float:
    """``level`` kept at least ``ISO_OFF_INTEGER`` of a step from the values the voxels can take,
    ``grid = (origin, step)``: the grid of the volume's values (:func:`_value_grid`), whether
    stored as integers or as floats. Voxels equal to the level would put vertices on them
    (degenerate faces). The voxels above it stay the same, and the
    surface keeps the level's place between two values: in an 8-bit MRI volume, whose edge
    rises some 20 values, half a value moves the surface by a share of a pixel that matters
    (design notes)."""
    if grid is None:
        return level
    origin, step = grid
    at = (level - origin) / step
    whole = math.floor(at)
    return origin + step * (whole + min(max(at - whole, ISO_OFF_INTEGER), 1.0 - ISO_OFF_INTEGER))


def _check_options(smoothing, target_vertices, support_radius) -> None:
    if isinstance(smoothing, bool) or not isinstance(smoothing, (int, np.integer)) or smoothing < 0:
        raise ValueError(f"smoothing must be a whole number of iterations, 0 or more, got {smoothing!r}")
    if target_vertices is not None and (
        isinstance(target_vertices, bool) or not isinstance(target_vertices, (int, np.integer))
        or target_vertices < 4
    ):
        raise ValueError(f"target_vertices must be a whole number, at least 4, got {target_vertices!r}")
    if not (isinstance(support_radius, (int, float)) and 0 < support_radius < math.inf):
        raise ValueError(f"support_radius must be a positive number of mm, got {support_radius!r}")


def _fill_values(levels: IntensityLevels) -> tuple[float, float]:
    """Intensities given to filled cavities (inside) and to dropped objects (outside)."""
    contrast = abs(levels.foreground - levels.background) or 1.0
    inside = max(levels.foreground, levels.level + 0.25 * contrast)
    outside = min(levels.background, levels.level - 0.25 * contrast)
    return inside, outside


def _weld(chunks, boundaries) -> tuple[np.ndarray, np.ndarray]:
    """Join per-slab marching-cubes meshes: merge the copies of vertices on shared planes.

    Both slabs next to a shared plane interpolate the same edges of that plane
    from the same two values, so the copies are bit-identical. ``chunks`` holds
    ``[vertices (plane, y, x), faces, the chunk's origin (x, y, z)]``; the
    vertices come back in volume indices along x, y, z, and the faces as int32
    when the vertices allow (half the memory of a million-vertex surface's
    int64 faces). The pieces are freed as they are copied.
    """
    n_verts = sum(len(c[0]) for c in chunks)
    index_type = np.int32 if n_verts < 2**31 - 1 else np.int64
    verts = np.empty((n_verts, 3), dtype=np.float64)
    faces = np.empty((sum(len(c[1]) for c in chunks), 3), dtype=index_type)
    nv = nf = 0
    for c in chunks:
        v, f, origin = c
        c[:] = [None, None, None]
        part = verts[nv : nv + len(v)]
        part[...] = v[:, ::-1]
        part += np.asarray(origin, dtype=np.float64)
        np.add(f, nv, out=faces[nf : nf + len(f)], casting="unsafe")
        nv, nf = nv + len(v), nf + len(f)
        del v, f
    chunks.clear()  # the caller's list
    index = np.arange(n_verts, dtype=index_type)
    if len(boundaries):
        on_plane = np.flatnonzero(np.isin(verts[:, 2], np.asarray(boundaries, dtype=np.float64)))
        if len(on_plane):
            _, first, inverse = np.unique(verts[on_plane], axis=0, return_index=True, return_inverse=True)
            index[on_plane] = on_plane[first[np.ravel(inverse)]]
    # in place ("clip": the indices are in range, and "raise" would copy the faces first)
    np.take(index, faces, out=faces, mode="clip")
    used = np.zeros(n_verts, dtype=bool)
    used[faces.ravel()] = True
    renumber = np.cumsum(used, dtype=index_type) - 1
    np.take(renumber, faces, out=faces, mode="clip")
    return verts[used], faces


def _opened_free(data: np.ndarray, iso: float, z0: int, z1: int, box) -> np.ndarray:
    """Voxels at or below the level, of planes ``[z0, z1)``, that a box of ``box`` voxels fits around.

    A morphological opening of the free (below-level) voxels by a box of
    ``box`` = (bz, by, bx) voxels (odd sizes): an erosion then a dilation
    along each axis. Beyond the volume is air: a box may stand partly
    outside it, centred up to its half-width beyond the border, so that the
    outside reaches into a gap between the product and the border narrower
    than the box (a fruit that fills the field of view). ``box`` (1, 1, 1)
    gives the free voxels themselves.
    """
    if all(b == 1 for b in box):
        return data[z0:z1] <= iso
    rz, ry, rx = (b // 2 for b in box)
    halo = 2 * rz
    a0, a1 = max(0, z0 - halo), min(data.shape[0], z1 + halo)
    # air beyond the border, one half-width deep, where the volume ends
    below = rz if a0 == 0 else 0
    above = rz if a1 == data.shape[0] else 0
    m = _opened(data[a0:a1] <= iso, box, ((below, above), (ry, ry), (rx, rx)))
    return m[z0 - a0 : z1 - a0]


def _opened(m: np.ndarray, box, air) -> np.ndarray:
    """Morphological opening of ``m`` by a box of ``box`` voxels (odd sizes), with ``air``
    (``np.pad``'s widths) of True beyond it: a box may be centred there."""
    m = np.pad(m, air, constant_values=True)
    for axis, b in enumerate(box):
        m = _sweep(m, b // 2, axis, erode=True)
    for axis, b in enumerate(box):
        m = _sweep(m, b // 2, axis, erode=False)
    return m[tuple(slice(a, m.shape[i] - b) for i, (a, b) in enumerate(air))]


def _sweep(m: np.ndarray, radius: int, axis: int, *, erode: bool) -> np.ndarray:
    """Erosion (AND) or dilation (OR) of a boolean array over ``2 radius + 1`` voxels along ``axis``.

    By doubling: windows of 3, 5, 9, ... voxels from shifted copies, a few
    whole-array operations instead of a filter per line. Beyond the array
    counts as True for the erosion (air) and as False for the dilation (no
    box is centred outside the volume).
    """
    if radius <= 0:
        return m
    op = np.logical_and if erode else np.logical_or
    out = m.copy()
    reach = 0  # out[i] combines m over [i - reach, i + reach]
    while reach < radius:
        step = min(reach + 1, radius - reach)  # grow the window by `step` on each side
        prev = out.copy()
        lead = [slice(None)] * m.ndim
        tail = [slice(None)] * m.ndim
        lead[axis], tail[axis] = slice(step, None), slice(None, -step)
        op(out[tuple(lead)], prev[tuple(tail)], out=out[tuple(lead)])
        op(out[tuple(tail)], prev[tuple(lead)], out=out[tuple(tail)])
        reach += step
    return out


def _probe_box(gap_mm: float, spacing_zyx) -> tuple[int, int, int]:
    """Odd box sizes (voxels along z, y, x) about ``gap_mm`` wide: gaps narrower than it are closed."""
    if gap_mm <= 0:
        return (1, 1, 1)
    return tuple(max(1, int(round(gap_mm / float(s)))) | 1 for s in spacing_zyx)


def _euler_number(planes: np.ndarray, n_own: int) -> int:
    """Euler number (6-connected voxels) of the planes ``planes[:n_own]``, counting the
    edges, squares and cubes that reach into the next plane ``planes[n_own]`` when given.

    Summed over slabs that share no planes, it is the Euler number of the whole
    mask: for one solid piece without cavities, ``1 - genus`` of its surface.
    """
    own = planes[:n_own]
    count = int(own.sum())
    count -= int((own[:, 1:] & own[:, :-1]).sum()) + int((own[:, :, 1:] & own[:, :, :-1]).sum())
    count += int((own[:, 1:, 1:] & own[:, 1:, :-1] & own[:, :-1, 1:] & own[:, :-1, :-1]).sum())
    if len(planes) > 1:
        a, b = planes[: len(planes) - 1], planes[1:]
        both = a & b  # pairs along z
        count -= int(both.sum())
        sq_y = both[:, 1:] & both[:, :-1]
        sq_x = both[:, :, 1:] & both[:, :, :-1]
        count += int(sq_y.sum()) + int(sq_x.sum())
        count -= int((sq_y[:, :, 1:] & sq_y[:, :, :-1]).sum())
    return count


@dataclass
class _Segmentation:
    """The product of one gap width: what marching cubes needs, and what the checks found."""

    gap_mm: float
    fg: "_Components"
    product: np.ndarray
    slabs: list
    lo: np.ndarray
    hi: np.ndarray
    n_object: int
    n_filled: int
    n_support: int
    support_refused: int
    genus: int
    enclosed: int  # other solid pieces inside the product's box or around it: the outside leaked in
    beside: int = 0  # voxels of other pieces side by side with the product (BESIDE_SHARE): it broke up
    pit_mm: float = 0.0  # how deep the outside reaches beyond a big box's reach (NaN: not looked at)
    spacing_zyx: np.ndarray = None
    mesh_genus: int | None = None  # of the marched surface, when it was marched
    level: float = float("nan")  # that decided what is inside

    @property
    def n_solid(self) -> int:
        return self.n_object + self.n_filled

    def closed(self, *, alone: bool = True) -> bool:
        """One solid of genus 0, around no other piece, without a narrow channel deep into it,
        and (``alone``) with no pieces of its own size beside it that a gap up to
        ``BESIDE_GAP_MM`` might join."""
        extent = float(np.min((self.hi - self.lo) * self.spacing_zyx))
        return (self.genus == 0 and not self.enclosed and self.pit_mm <= PIT_DEPTH * extent
                and not (alone and self.beside and self.gap_mm < BESIDE_GAP_MM))

    def whole(self) -> bool:
        """Closed (:meth:`closed`) and, once marched, a surface of genus 0."""
        return self.mesh_genus == 0 and self.closed()


def _segment(data, iso: float, spacing_zyx, slabs, *, gap_mm: float, remove_support: bool,
             support_radius: float, coarse: int, name: str) -> _Segmentation:
    """The product for one gap width: the largest piece of what cannot be reached from outside.

    Outside is every voxel at or below the level that a box ``gap_mm`` wide
    reaches from the volume's border, moving through such voxels; the solid is
    everything else, so cavities and gaps narrower than the box are inside.
    Its largest 6-connected piece is the product (without a support that
    touches it, see :func:`_support_region`).
    """
    shape = data.shape
    box = _probe_box(gap_mm, spacing_zyx)
    slab_of = {z0: k for k, (z0, _) in enumerate(slabs)}
    # the outside is kept as one bit per voxel, its labels only for a moment
    outs = _Components(lambda z0, z1: _opened_free(data, iso, z0, z1, box), slabs)
    outside = [np.packbits(outs.select(k, outs.border), axis=-1) for k in range(len(slabs))]
    del outs

    def solid(z0: int, z1: int) -> np.ndarray:
        return ~np.unpackbits(outside[slab_of[z0]], axis=-1, count=shape[2]).view(bool)

    fg = _Components(solid, slabs)
    if fg.n_labels == 0:
        raise VolumeError(f"{name}: no voxel is above the level {iso:g}; no object")
    product = np.zeros(len(fg.size), dtype=bool)
    product[int(np.argmax(fg.size))] = True
    n_support = refused = 0
    if remove_support and fg.border[product][0]:
        support = _support_region(lambda k: fg.select(k, product), slabs, shape, spacing_zyx,
                                  support_radius, coarse)
        if support is not None:
            before = int(fg.size[product][0])
            whole = fg

            def solid_not_support(z0: int, z1: int) -> np.ndarray:
                return solid(z0, z1) & ~_upsample(support, z0, z1, shape[1:], coarse)

            fg = _Components(solid_not_support, slabs)
            free = np.flatnonzero(~fg.border)
            pool = free if len(free) else np.arange(len(fg.size))
            kept = np.zeros(len(fg.size), dtype=bool)
            kept[pool[int(np.argmax(fg.size[pool]))]] = True
            n_support = before - int(fg.size[kept][0])
            if n_support > SUPPORT_REFUSE_SHARE * before:
                # not a support: the product itself, but for a fragment; keep it whole
                refused, n_support = n_support, 0
                fg = whole
            else:
                product = kept
    n_solid = int(fg.size[product][0])
    # counts, box and Euler number of the product, slab by slab (with the next slab's first plane)
    n_object = 0
    euler = 0
    lo, hi = np.array([np.iinfo(np.int64).max] * 3), np.zeros(3, dtype=np.int64)
    nxt = fg.select(0, product)
    for k, (z0, z1) in enumerate(slabs):
        cur = nxt
        nxt = fg.select(k + 1, product) if k + 1 < len(slabs) else None
        if cur.any():
            n_object += int((cur & (data[z0:z1] > iso)).sum())
            planes = cur if nxt is None else np.concatenate([cur, nxt[:1]])
            euler += _euler_number(planes, len(cur))
            _grow_box(lo, hi, cur, z0)
    # another solid piece of some size inside the product's box, or around it: one
    # of them is an open shell around the other (a peel whose opening the box
    # passed through, over the flesh)
    others = np.flatnonzero(~product & (fg.size >= ENCLOSED_MIN_SHARE * n_solid))
    order = others[np.argsort(-fg.size[others])]
    # pieces side by side with the product that may hold as much as half of it (it broke up, below)
    # are looked at too: their boxes in the same pass
    broke = fg.size[order[:BESIDE_CHECKED]].sum() >= BESIDE_SHARE * n_solid
    looked = order[: max(ENCLOSED_CHECKED, BESIDE_CHECKED if broke else 0)]
    b_lo, b_hi = fg.boxes(looked)
    e_lo, e_hi = b_lo[:ENCLOSED_CHECKED], b_hi[:ENCLOSED_CHECKED]
    enclosed = int(np.sum((np.all(e_lo >= lo, axis=1) & np.all(e_hi <= hi, axis=1))
                          | (np.all(e_lo <= lo, axis=1) & np.all(e_hi >= hi, axis=1))))
    if not enclosed:
        # a shell broken into pieces (a thin peel at an MRI's slice thickness) around
        # one flesh segment: no piece is around the product, but together they are,
        # beyond it on every side
        rest = ~product & (fg.size >= _MIN_OBJECT_VOXELS)
        if fg.size[rest].sum() >= ENCLOSED_MIN_SHARE * n_solid:
            u_lo, u_hi = fg.bounds(rest)
            enclosed += bool(np.all(u_lo < lo) and np.all(u_hi > hi))
    beside = 0
    if broke:
        near = looked[np.all(b_lo < hi, axis=1) & np.all(b_hi > lo, axis=1)]
        if fg.size[near].sum() >= BESIDE_SHARE * n_solid:
            beside = int(fg.size[near].sum())
    genus = 1 - euler
    # only a product closed otherwise is looked at for a channel (it takes a while)
    pit = (_pit_depth(lambda k: ~fg.select(k, product), slabs, shape, spacing_zyx, lo, hi)
           if genus == 0 and not enclosed else float("nan"))
    return _Segmentation(gap_mm, fg, product, slabs, lo, hi, n_object, n_solid - n_object,
                         n_support, refused, genus, enclosed, beside, pit, np.asarray(spacing_zyx, dtype=float),
                         level=float(iso))


def _pit_depth(elsewhere, slabs, shape, spacing_zyx, lo, hi) -> float:
    """How deep (mm) the outside reaches into the product beyond where a box ``PIT_BOX_MM`` wide reaches.

    A fruit's own hollows (a stalk cavity, a calyx basin, the grooves between
    a pepper's lobes) are about as wide as they are deep: the big box enters
    them most of the way. A channel a few millimetres wide that leads to the
    core is not: what only the small box reaches lies deep inside. Worked out
    on a coarse grid of blocks, from ``elsewhere(k)``, slab ``k``'s voxels not
    in the product. The big box is at most ``PIT_BOX_SHARE`` of the product's
    smallest extent.
    """
    from scipy import ndimage

    c = max(1, math.ceil((np.prod(shape) / _PIT_VOXELS) ** (1.0 / 3.0)))
    nz, ny, nx = shape
    cz, cy, cx = -(-nz // c), -(-ny // c), -(-nx // c)
    some = np.zeros((cz, cy, cx), dtype=bool)
    every = np.ones((cz, cy, cx), dtype=bool)
    for k, (z0, z1) in enumerate(slabs):
        m = elsewhere(k)
        pad = ((0, 0), (0, (-ny) % c), (0, (-nx) % c))
        if any(p[1] for p in pad):
            m = np.pad(m, pad, constant_values=True)  # beyond the volume is air
        # across each plane first (the one full read), then the planes block by block
        a = m.reshape(m.shape[0], m.shape[1] // c, c, m.shape[2] // c, c)
        any_, all_ = a.any(axis=(2, 4)), a.all(axis=(2, 4))
        starts = np.r_[0, np.arange(-(-z0 // c) * c, z1, c) - z0]
        starts = np.unique(starts[starts < z1 - z0])
        block = (z0 + starts) // c
        some[block] |= np.logical_or.reduceat(any_, starts, axis=0)
        every[block] &= np.logical_and.reduceat(all_, starts, axis=0)
    sampling = np.asarray(spacing_zyx, dtype=np.float64) * c
    extent = float(np.min((np.asarray(hi) - np.asarray(lo)) * np.asarray(spacing_zyx)))
    width = min(PIT_BOX_MM, PIT_BOX_SHARE * extent)
    box = tuple(max(1, int(round(width / s))) | 1 for s in sampling)
    # as the gap closing's boxes, the big box may stand beyond the volume (air)
    big = _opened(every, box, [(b // 2, b // 2) for b in box])
    lab, n = ndimage.label(big)
    border = np.zeros(n + 1, dtype=bool)
    for face in (lab[0], lab[-1], lab[:, 0], lab[:, -1], lab[:, :, 0], lab[:, :, -1]):
        border[face.ravel()] = True
    border[0] = False
    big = border[lab]
    del lab
    deep = some & ~big
    clo, chi = np.asarray(lo) // c, -(-np.asarray(hi) // c)
    window = tuple(slice(int(a), int(b)) for a, b in zip(clo, chi))
    inside_box = np.zeros_like(deep)
    inside_box[window] = True
    deep &= inside_box
    if not deep.any():
        return 0.0
    return float(ndimage.distance_transform_edt(~big, sampling=sampling)[deep].max())


def _march(vol: Volume, data, iso: float, seg_iso: float, seg: _Segmentation, inside_value: float,
           outside_value: float, background: float, step: int):
    """Marching cubes of the product's outer surface, slab by slab, in voxel indices.

    Runs on the intensity (sub-voxel accuracy) with the product's below-level
    voxels raised to ``inside_value`` and every other voxel above the level
    lowered to ``outside_value``, on the product's box plus a background
    layer all around, so that the surface closes where the product touches
    the volume's border. In a product segmented at a lower ``seg_iso``, the
    voxels between the two levels that face the outside keep their values
    beside a voxel above ``iso`` (an edge the level finds); elsewhere (a
    thin peel's, across the slices) they are stretched from ``background``
    so that ``seg_iso`` becomes ``iso``: the surface crosses them where it
    would at the lower level, not behind them. Returns ``(index_vertices (n, 3) along x, y, z, faces (m, 3) int32)``
    (see :func:`_weld`).
    """
    from skimage.measure import marching_cubes

    shape = data.shape
    lo, hi, fg, product = seg.lo, seg.hi, seg.fg, seg.product
    r_lo = np.maximum(lo - 1, 0)
    r_hi = np.minimum(hi + 1, np.asarray(shape))
    ys, xs = slice(int(r_lo[1]), int(r_hi[1])), slice(int(r_lo[2]), int(r_hi[2]))
    box_slabs = _slab_bounds(int(r_lo[0]), int(r_hi[0]), step)
    fg_slab = {z0: k for k, (z0, _) in enumerate(seg.slabs)}

    def filled(k: int) -> np.ndarray:
        z0, z1 = box_slabs[k]
        kk = fg_slab[z0 - z0 % step]
        s0 = seg.slabs[kk][0]
        return fg.select(kk, product, labels=fg.labels(kk)[z0 - s0 : z1 - s0, ys, xs])

    level32 = np.float32(iso)
    # small integers are exact in float32, and an integer volume's level is a
    # half-integer: no voxel value can reach or cross the level
    exact = vol.data.dtype.kind in "biu" and vol.data.dtype.itemsize <= 2 and float(level32) == iso
    two_levels = seg_iso < iso
    stretch = (iso - background) / (seg_iso - background) if two_levels else 1.0
    chunks, boundaries = [], []
    nxt = filled(0)
    before = np.zeros_like(nxt[:1])  # the plane before the box: outside the product
    for k, (z0, z1) in enumerate(box_slabs):
        cur = nxt
        last = k == len(box_slabs) - 1
        nxt = None if last else filled(k + 1)
        inside = cur if last else np.concatenate([cur, nxt[:1]])
        if two_levels:
            # the planes either side, for whether each voxel faces the outside
            after = (np.zeros_like(cur[:1]) if last
                     else nxt[1:2] if len(nxt) > 1 or k + 2 >= len(box_slabs)
                     else filled(k + 2)[:1])
            if not len(after):
                after = np.zeros_like(cur[:1])
            walled = _all_neighbours(np.concatenate([before, inside, after]))
            before = cur[-1:]
        if not inside.any():
            continue
        first_plane = z0 - 1 if k == 0 else z0  # a background plane before the first slab
        j = np.full((z1 - first_plane + 1, inside.shape[1] + 2, inside.shape[2] + 2), outside_value,
                    dtype=np.float32)
        d = data[z0 : z1 + (0 if last else 1), ys, xs]
        p0 = z0 - first_plane
        core = j[p0 : p0 + d.shape[0], 1:-1, 1:-1]
        core[...] = d
        high = d > iso
        if not exact:
            # float32 rounding must not move a voxel across the level, nor onto it
            core[high & (core <= level32)] = np.nextafter(level32, np.float32(np.inf))
            core[~high & (core >= level32)] = np.nextafter(level32, np.float32(-np.inf))
        raised = inside & ~high
        if two_levels:
            # between the levels and facing the outside. Beside a voxel above the level (an
            # edge the level finds): kept as they are. Elsewhere (a peel thinner than the
            # voxel, whose inside the level misses): their values stretched from the
            # background's, so that the surface crosses them where it would at the lower level
            facing = raised & (d > seg_iso) & ~walled
            raised &= ~facing
            lo_plane, hi_plane = z0 - 1, z0 + len(inside)
            above = data[max(lo_plane, 0) : min(hi_plane + 1, shape[0]), ys, xs] > iso
            above = np.concatenate([np.zeros_like(above[:1])] * (lo_plane < 0) + [above]
                                   + [np.zeros_like(above[:1])] * (hi_plane >= shape[0]))
            thin = facing & ~_any_neighbour(above)
            core[thin] = background + (core[thin] - background) * stretch
            del walled, facing, above, thin
        core[raised] = inside_value
        core[~inside & high] = outside_value
        del d, high, inside, core
        verts, faces, _, _ = marching_cubes(j, level=float(level32), allow_degenerate=True)
        del j
        # the chunk's (plane, y, x) and where its origin lies in the volume's x, y, z
        chunks.append([verts, faces, (int(r_lo[2]) - 1, int(r_lo[1]) - 1, first_plane)])
        if not last:
            boundaries.append(float(z1))
        del verts, faces
    if not chunks:  # pragma: no cover - the product has voxels above the level
        raise VolumeError(f"no surface found at the level {iso:g}")
    give_back_freed_memory()
    verts, faces = _weld(chunks, boundaries)
    if two_levels:
        verts, faces = _largest_component(verts, faces)
    return verts, faces


def _largest_component(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's largest connected component. Meshed with two levels, the voxels kept below the
    level can leave a few voxels of the product (a speck of noise it took in) apart from it."""
    from .surface import component_labels

    n, labels = component_labels(faces, len(verts))
    if n <= 1:
        return verts, faces
    keep = labels == np.argmax(np.bincount(labels))
    renumber = np.cumsum(keep, dtype=faces.dtype) - 1
    return verts[keep], renumber[faces[keep[faces[:, 0]]]]


def _all_neighbours(m: np.ndarray) -> np.ndarray:
    """For planes ``m[1:-1]``: whether a voxel and its six neighbours are all set (none beyond y, x)."""
    c = m[1:-1] & ~_any_neighbour(~m)
    c[:, 0] = c[:, -1] = False
    c[:, :, 0] = c[:, :, -1] = False
    return c


def _any_neighbour(m: np.ndarray) -> np.ndarray:
    """For planes ``m[1:-1]``: whether any of a voxel's six neighbours is set (none beyond y, x)."""
    c = m[:-2] | m[2:]
    c[:, 1:] |= m[1:-1, :-1]
    c[:, :-1] |= m[1:-1, 1:]
    c[:, :, 1:] |= m[1:-1, :, :-1]
    c[:, :, :-1] |= m[1:-1, :, 1:]
    return c


def _mesh_product(vol: Volume, iso: float, seg_iso: float, inside_value: float, outside_value: float,
                  background: float, *, remove_support: bool, support_radius: float, gaps_mm: Sequence[float],
                  name: str):
    """Segment the product at ``seg_iso`` and mesh its outer surface at ``iso`` in voxel indices.

    The gap widths are tried in turn (:func:`_segment`) until the product is
    one solid of genus 0 that encloses no other piece; the last is kept
    otherwise. Returns ``(index_vertices (n, 3) float64 along x, y, z,
    faces (m, 3) int32 (int64 past 2^31 vertices), bounds, the segmentation,
    the attempts)``. Only the attempt at hand keeps its labels (as runs,
    :class:`_Runs`).
    """
    # (z, y, x) view: slabs along the volume's last axis are contiguous in memory
    # for volumes read from files (x varies fastest on disk).
    data = vol.data.transpose(2, 1, 0)
    shape = data.shape
    spacing_zyx = vol.spacing[::-1]
    coarse = max(1, math.ceil((data.size / _COARSE_VOXELS) ** (1.0 / 3.0)))
    step = max(1, _SLAB_VOXELS // (shape[1] * shape[2]))
    step = max(coarse, step - step % coarse)
    slabs = _slab_bounds(0, shape[0], step)
    def everywhere(s: _Segmentation) -> bool:
        return bool(np.all(s.lo == 0) and np.all(s.hi == np.asarray(shape)))

    attempts = []
    gaps = list(gaps_mm)
    i = -1
    while i + 1 < len(gaps):
        i += 1
        last = i == len(gaps) - 1
        for s in attempts:
            s.fg = None
        seg = _segment(data, seg_iso, spacing_zyx, slabs, gap_mm=float(gaps[i]), remove_support=remove_support,
                       support_radius=support_radius, coarse=coarse, name=name)
        attempts.append(seg)
        give_back_freed_memory()
        if everywhere(seg) and len(attempts) > 1 and not everywhere(attempts[-2]):
            # a box this wide fits nowhere in a noisy background: the narrower gap's product,
            # segmented again (its labels are gone), is the last
            gaps = gaps[: i + 1] + [gaps[i - 1]]
            continue
        if not (seg.closed() or last):
            continue
        if seg.n_object < _MIN_OBJECT_VOXELS:
            raise VolumeError(
                f"{name}: no object: the largest region above the level {seg_iso:g} has only {seg.n_object} voxels"
            )
        if everywhere(seg):
            raise VolumeError(
                f"{name}: the object above the level {seg_iso:g} touches all six faces of the volume: there is "
                "no background around it (is the whole volume object, or the level too low?)"
            )
        index_vertices, faces = _march(vol, data, iso, seg_iso, seg, inside_value, outside_value, background, step)
        # marching cubes may join voxels that touch only along an edge, which 6-connected
        # voxels do not: a handle the voxels' count did not see; a wider gap closes it
        seg.mesh_genus = _surface_genus(len(index_vertices), len(faces))
        if seg.mesh_genus == 0 or last:
            break
    for s in attempts:
        s.fg = None  # free the labels
    bounds = np.stack([seg.lo[::-1], seg.hi[::-1]], axis=1).astype(np.int64)
    return index_vertices, faces, bounds, seg, attempts


def _marched_volume(product) -> float:
    """The volume (voxel units) inside a :func:`_mesh_product` result's marched surface."""
    from .surface import signed_volume

    return abs(signed_volume(product[0], product[1]))


def extract_surface(
    volume,
    *,
    level: float | None = None,
    smoothing: int = 10,
    target_vertices: int | None = None,
    remove_support: bool = True,
    support_radius: float = 2.0,
    name: str = "volume",
) -> Extraction:
    """Extract the outer surface of the product in a CT or MRI volume.

    See the module docstring for the method: the level on the boundary
    between air and the outermost tissue, everything the outside cannot
    reach (gaps closed until the product is one solid of genus 0), the
    largest piece without a support touching it, marching cubes on the
    intensity in world coordinates, then optional smoothing and decimation.

    Parameters
    ----------
    volume : Volume or (nx, ny, nz) array_like
        The CT volume (from :func:`hortishape.io.read_volume`); an array is
        taken with 1 mm voxels at the origin. Not modified.
    level : float, optional
        Iso level in the volume's intensity units; voxels above it are
        inside. Default: on the boundary between the background and the
        outermost tissue (:func:`intensity_levels`). Where the voxels take
        values on a grid (the integers, or 8-bit values stored as float or
        multiplied up), the surface is meshed at the level kept
        ``ISO_OFF_INTEGER`` of a step from them, so that no vertex falls on a
        voxel and the same values give the same surface however stored.
    smoothing : int, default: 10
        Iterations of :func:`taubin_smooth` (0: none). Removes the scanner
        noise from the surface without shrinking it.
    target_vertices : int, optional
        Decimate the surface to about this many vertices (:func:`decimate`).
        Default: keep marching cubes' resolution (about 1.5 vertices per
        voxel face of surface area).
    remove_support : bool, default: True
        Drop a support or scanner bed touching the product (see the module
        docstring). Only tried when the product touches the volume's border.
    support_radius : float, default: 2.0
        Erosion radius (mm) that separates a support from the product: more
        than half the width of their contact, less than half the thickness
        of the support and of the product's walls.
    name : str, default: "volume"
        What to call the volume in error messages (usually its file name).

    Returns
    -------
    Extraction

    Raises
    ------
    VolumeError
        Every voxel the same, no voxel or every voxel above the level, no
        object (only specks above the level), or an object that touches all
        six faces of the volume (no background around it). Unusable arrays
        (2D, NaN, non-positive spacing) are refused by
        :class:`~hortishape.io.Volume`.
    ValueError
        If an option is out of range.

    Warns
    -----
    ExtractionWarning
        For each of :attr:`Extraction.warnings`: gaps closed (and what was
        filled), a genus above 0 that stays, a product touching the volume's
        border, a size far from a fruit's, a support taking most of the
        voxels or refused.

    Examples
    --------
    >>> x, y, z = np.mgrid[:40, :40, :40] - 19.5
    >>> r = np.sqrt(x**2 + y**2 + z**2)
    >>> data = (1000 * np.clip(12.5 - r, 0, 1)).astype(np.float32)  # radius 12 voxels
    >>> ext = extract_surface(data, smoothing=0)
    >>> round(ext.volume / (4 / 3 * np.pi * 12**3), 2)
    1.0
    """
    from .surface import _checked_arrays, check_closed_surface, signed_volume

    vol = _as_volume(volume)
    _check_options(smoothing, target_vertices, support_radius)
    sample = _sample(vol.data)
    grid = _value_grid(sample)
    levels = _intensity_levels(vol, level, name, sample, grid)
    del sample
    # the grid the values lie on, however they are stored (the integers where an integer
    # volume's values span too many to count)
    values = grid if grid is not None or vol.data.dtype.kind not in "biu" else (0.0, 1.0)
    iso, seg_iso = _off_grid(levels.level, values), _off_grid(levels.segment, values)
    inside_value, outside_value = _fill_values(levels)

    def mesh_product(at: float):
        return _mesh_product(vol, iso, at, inside_value, outside_value, levels.background,
                             remove_support=remove_support, support_radius=float(support_radius),
                             gaps_mm=GAPS_MM, name=name)

    # the level decides what is inside, unless the outermost tissue breaks up there (a peel
    # thinner than a slice, at the poles) and no gap width closes it, or the widest closed it
    # over a sunk pole: then the lower level
    result, attempts = None, []  # the attempts of every pass, in order
    try:
        result = mesh_product(iso)
        attempts += result[4]
    except VolumeError:
        if seg_iso >= iso:
            raise
    if seg_iso < iso and (result is None or result[3].gap_mm >= GAPS_MM[-1] or not result[3].whole()):
        # also where only the widest gaps made the level's product whole: a pole the peel left
        # open is about that wide, and they bridge it only partly: the surface sinks into the flesh
        try:
            again = mesh_product(seg_iso)
        except VolumeError:
            if result is None:
                raise
            # the lower level took in the background's noise: the level's product stays
        else:
            attempts += again[4]
            if result is None or (again[3].whole() and (
                    not result[3].whole() or _marched_volume(again) > (1 + LOWER_GAIN) * _marched_volume(result))):
                result = again
            del again
    if result[3].level >= iso:  # the lower level was not used: the levels say so
        levels = replace(levels, segment_level=levels.level, slice_outer=float("nan"))
    index_vertices, faces, bounds, seg, _ = result
    del result
    n_mc = len(index_vertices)
    index_vertices *= vol.spacing
    world = index_vertices @ vol.direction.T
    del index_vertices
    world += vol.origin
    if signed_volume(world, faces) < 0:  # outward normals
        faces[:, [0, 2]] = faces[:, [2, 0]]  # reversed in place: (a, b, c) -> (c, b, a)
    give_back_freed_memory()
    if smoothing:
        world = _taubin(world, faces, int(smoothing), 0.1, 0.5, closed=True)
        give_back_freed_memory()
    # marching cubes' degenerate slivers are harmless here; checked on the arrays,
    # before the Mesh's copies of them
    _checked_arrays(world, faces, name=name, allow_degenerate=True, allow_holes=False)
    mesh = Mesh(world, faces)
    del world, faces
    if target_vertices is not None:
        mesh = decimate(mesh, int(target_vertices))
        check_closed_surface(mesh, name=name, allow_degenerate=True)
    tried = tuple({"level": a.level, "gap_mm": a.gap_mm, "genus": a.genus, "mesh_genus": a.mesh_genus,
                   "enclosed": a.enclosed, "beside_voxels": a.beside,
                   "channel_mm": round(a.pit_mm, 2) if math.isfinite(a.pit_mm) else None,
                   "n_filled_voxels": a.n_filled} for a in attempts)
    ext = Extraction(mesh, levels, bounds, seg.n_object, seg.n_filled, seg.n_support, n_mc,
                     gap_mm=seg.gap_mm, attempts=tried)
    notes = _warnings(ext, seg, attempts, vol)
    for note in notes:
        warnings.warn(f"{name}: {note}", ExtractionWarning, stacklevel=2)
    return replace(ext, warnings=tuple(notes))


def _warnings(ext: Extraction, seg: "_Segmentation", attempts, vol: Volume) -> list[str]:
    """What a person should look at in an extraction, one sentence each."""
    notes = []
    first = attempts[0]
    # pieces beside that no gap joined are said once, below
    if len(attempts) > 1 and not (seg.beside and seg.closed() and first.closed(alone=False)):
        why = []
        if first.genus:
            why.append(f"genus {first.genus} (tunnels or openings into the inside)")
        if first.enclosed:
            why.append("an open shell (a peel or wall with an opening) around another piece")
        if first.beside:
            why.append(f"other pieces beside it holding {first.beside / first.n_solid:.1f} times its voxels "
                       "(it broke up at the level)")
        if not first.genus and not first.enclosed and not first.beside:
            why.append(f"a narrow channel {first.pit_mm:.0f} mm deep into it" if not first.closed()
                       else f"a handle where voxels touch along an edge (genus {first.mesh_genus} once meshed)")
        ml = float(np.prod(vol.spacing)) / 1000.0
        notes.append(
            f"the surface at the level had {' and '.join(why)}; gaps up to {seg.gap_mm:g} mm wide were closed "
            f"and {seg.n_filled:,} voxels ({seg.n_filled * ml:.1f} mL) inside filled"
        )
    if math.isfinite(ext.levels.slice_outer):  # the lower level decided what is inside
        notes.append(
            f"across the slices the outermost tissue reaches only {ext.levels.slice_outer:.4g} (thinner than a "
            f"slice) and broke up at the level {ext.levels.level:.4g}: what is inside was decided at "
            f"{ext.levels.segment:.4g}, the surface kept at the level where the voxels reach it"
        )
    if seg.beside:  # only a gap of BESIDE_GAP_MM or more ends with pieces beside
        notes.append(f"other pieces lie beside the product ({seg.beside:,} voxels, {seg.beside / seg.n_solid:.1f} "
                     f"times its own) and a gap of {seg.gap_mm:g} mm did not join them: separate objects? Only "
                     "the largest was kept; check the picture and the level (--level)")
    if not seg.closed():
        left = ([f"genus {seg.genus}"] if seg.genus else []) + (
            ["an open shell around another piece"] if seg.enclosed else []) + (
            [] if seg.genus or seg.enclosed else [f"a narrow channel {seg.pit_mm:.0f} mm deep into it"])
        notes.append(f"the surface still has {' and '.join(left)} with gaps up to {seg.gap_mm:g} mm closed: "
                     "check the level (--level)")
    if ext.genus and seg.closed():
        notes.append(f"the meshed surface has genus {ext.genus} where its voxels have {seg.genus}")
    if seg.support_refused:
        notes.append(
            f"no support was dropped: what came apart from the product as a support was {seg.support_refused:,} "
            f"voxels, more than {SUPPORT_REFUSE_SHARE:.0%} of it (the product itself?); check the level"
        )
    elif seg.n_support > SUPPORT_WARN_SHARE * (seg.n_support + seg.n_object + seg.n_filled):
        notes.append(
            f"the support dropped took {seg.n_support:,} voxels, most of what was above the level "
            "(a large scanner bed, or the product?); check the picture, or use --keep-support"
        )
    shape = np.asarray(vol.shape)
    lo, hi = ext.bounds[:, 0], ext.bounds[:, 1]
    cut = [f"{'-' if side == 0 else '+'}{'xyz'[a]}" for a in range(3) for side in (0, 1)
           if (lo[a] == 0 if side == 0 else hi[a] == shape[a])]
    if cut:
        notes.append(f"the product touches the volume's border ({', '.join(cut)}): it may be cut off there")
    extent = float(np.ptp(ext.mesh.vertices, axis=0).max())
    small, large = FRUIT_EXTENT_MM
    if not small <= extent <= large:
        notes.append(f"the product is {extent:.3g} mm across ({ext.volume / 1000:.3g} mL), far from a fruit's "
                     f"{small:g}-{large:g} mm: check the voxel size and the level")
    return notes


# --------------------------------------------------------------------------
# Picture
# --------------------------------------------------------------------------


def _slice_segments(index_vertices: np.ndarray, faces: np.ndarray, axis: int, position: float) -> np.ndarray:
    """Segments ``(s, 2, 3)`` where the plane ``index[axis] == position`` cuts the triangles."""
    # a hair off the plane, so that no vertex lies on it: every cut triangle has two cut edges
    side = index_vertices[:, axis] - (position + 1e-6) > 0
    s = side[faces]
    tri = faces[s.any(axis=1) & ~s.all(axis=1)]
    if not len(tri):
        return np.zeros((0, 2, 3))
    d = index_vertices[tri, axis] - (position + 1e-6)  # (t, 3)
    points, crosses = [], []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        da, db = d[:, a], d[:, b]
        cut = (da > 0) != (db > 0)
        t = np.divide(da, da - db, out=np.zeros_like(da), where=cut)
        pa, pb = index_vertices[tri[:, a]], index_vertices[tri[:, b]]
        points.append(pa + t[:, None] * (pb - pa))
        crosses.append(cut)
    points, crosses = np.stack(points, axis=1), np.stack(crosses, axis=1)  # (t, 3, 3), (t, 3)
    order = np.argsort(~crosses, axis=1, kind="stable")[:, :2]  # the two cut edges
    return np.take_along_axis(points, order[:, :, None], axis=1)


_PICTURE_VERTICES = 150_000  # more than a 520-pixel picture shows
_PICTURE_SIZE = (1500, 520)  # the picture's width and height in pixels


def _picture_surface(mesh: Mesh) -> Mesh:
    """``mesh``, or for a large one a coarser copy for the picture (vertex clustering).

    The vertices in each cell of a grid are merged into their mean, with the
    cells sized to leave about ``_PICTURE_VERTICES``. Faces that collapse,
    that the merge turned over, or that two sheets now share are dropped:
    drawn, they would show as dark seams. Fast and good enough to look at (not
    a surface to measure).
    """
    from .surface import _FACE_BLOCK as block
    from .surface import _face_cross, face_areas

    if mesh.n_vertices <= _PICTURE_VERTICES:
        return mesh
    v, f = mesh.vertices, mesh.faces
    area = sum(float(face_areas(v, f[i : i + block]).sum()) for i in range(0, len(f), block))
    cell = math.sqrt(area / _PICTURE_VERTICES)
    grid = np.floor((v - v.min(axis=0)) / cell).astype(np.int64)
    dims = grid.max(axis=0) + 1
    _, inverse = np.unique((grid[:, 0] * dims[1] + grid[:, 1]) * dims[2] + grid[:, 2], return_inverse=True)
    del grid
    n = int(inverse.max()) + 1
    inverse = inverse.ravel().astype(np.int32 if n < 2**31 - 1 else np.int64)
    count = np.bincount(inverse)
    merged = np.stack([np.bincount(inverse, weights=v[:, d]) for d in range(3)], axis=1) / count[:, None]
    tri = inverse[f]
    # each cell's outward direction: the area-weighted normals of the faces at its vertices
    outward = np.zeros((n, 3))
    for i in range(0, len(f), block):
        normal, corners = _face_cross(v, f[i : i + block]), tri[i : i + block]
        for d in range(3):
            outward[:, d] += sum(np.bincount(corners[:, k], weights=normal[:, d], minlength=n) for k in range(3))
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 2] != tri[:, 0])]
    # every copy of a face that two sheets now share (they face both ways), then the faces turned over
    corners = np.sort(tri, axis=1).astype(np.int64)
    if n < 2_000_000:  # one key per face: (a n + b) n + c fits in int64
        corners = (corners[:, 0] * n + corners[:, 1]) * n + corners[:, 2]
    _, first, copies = np.unique(corners, axis=0 if corners.ndim == 2 else None, return_index=True,
                                 return_counts=True)
    del corners
    tri = tri[np.sort(first[copies == 1])]
    return Mesh(merged, tri[np.einsum("ij,ij->i", _face_cross(merged, tri), outward[tri].sum(axis=1)) > 0])


def render_extraction(volume, extraction: Extraction, path, *, title: str | None = None,
                      size: tuple[int, int] = _PICTURE_SIZE, backend: str = "auto") -> Path:
    """Picture of an extracted surface beside two slices of its volume, for checking by eye.

    Left: the surface (iso view). Middle and right: the slices of the volume
    through the centre of the product across its last index axis (z) and its
    second (y), in millimetres along the volume's index axes, with the
    surface's outline in those planes drawn over them. A good extraction
    follows the product's outer edge and ignores its cavities and supports.

    Parameters
    ----------
    volume : Volume or array_like
        The volume the surface came from.
    extraction : Extraction
    path : str or os.PathLike
        A ``.png`` file; written atomically.
    title : str, optional
        Drawn above the picture.
    size : (int, int), default: (1500, 520)
        Width and height in pixels.
    backend : {"auto", "vtk", "matplotlib"}, default: "auto"
        How the surface is drawn (see :func:`hortishape.render.render_mesh`).

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import tempfile
    >>> x, y, z = np.mgrid[:30, :30, :30] - 14.5
    >>> data = (1000 * np.clip(9.5 - np.sqrt(x**2 + y**2 + z**2), 0, 1)).astype(np.float32)
    >>> ext = extract_surface(data)
    >>> render_extraction(data, ext, tempfile.mkdtemp() + "/sphere.png", backend="matplotlib").suffix
    '.png'
    """
    target = Path(os.fspath(path))
    if target.suffix.lower() != ".png":
        raise ValueError(f"{target}: pictures are written as PNG, so the path must end in .png")
    width, height = (int(s) for s in size)
    if width < 300 or height < 150:
        raise ValueError(f"size must be at least 300 x 150 pixels, got {size!r}")
    return _draw_extraction(_ExtractionSlices.of(_as_volume(volume), extraction), extraction, target,
                            title=title, width=width, height=height, backend=backend)


@dataclass(frozen=True)
class _ExtractionSlices:
    """What the picture needs of the volume: two slices through the product's centre, and the voxel size.

    Taken before the picture is drawn, so that a batch can let the volume go
    first (its renderer's libraries take a few hundred megabytes of their own).
    """

    panels: tuple  # (axis, index, picture (along the other two axes) float32)
    index_vertices: np.ndarray  # the surface's vertices in voxel indices
    spacing: np.ndarray

    @classmethod
    def of(cls, vol: Volume, extraction: Extraction) -> "_ExtractionSlices":
        centre = extraction.bounds.mean(axis=1)
        panels = []
        for axis in (2, 1):  # across the last index axis, then the second
            k = int(np.clip(int(round(centre[axis])), 0, vol.shape[axis] - 1))
            # indexing, a view: np.take copies element by element along a strided axis (3 s on 512^3)
            panels.append((axis, k, vol.data[(slice(None),) * axis + (k,)].astype(np.float32)))
        return cls(tuple(panels), vol.world_to_index(extraction.mesh.vertices), np.asarray(vol.spacing, float))


def _draw_extraction(slices: _ExtractionSlices, extraction: Extraction, target: Path, *, title, width: int,
                     height: int, backend: str) -> Path:
    """:func:`render_extraction` from the slices it needs."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure
    from PIL import Image

    from .render import render_mesh

    mesh = extraction.mesh
    with tempfile.TemporaryDirectory() as tmp:
        render_mesh(_picture_surface(mesh), Path(tmp) / "surface.png", view="iso", size=(height, height),
                    backend=backend)
        surface = np.asarray(Image.open(Path(tmp) / "surface.png").convert("RGB"))
    index = slices.index_vertices
    lv = extraction.levels
    contrast = lv.foreground - lv.background
    vmin, vmax = lv.background - 0.2 * contrast, lv.foreground + 0.2 * contrast
    if vmin > vmax:
        vmin, vmax = vmax, vmin
    sx, sy, sz = slices.spacing
    dpi = 100.0
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    lines = [extraction.levels.explain()
             + (f"; gaps up to {extraction.gap_mm:g} mm closed" if extraction.gap_mm else "")]
    lines += [f"warning: {w}" for w in extraction.warnings]
    foot = 0.035 * len(lines)  # the level's explanation and the warnings, under the panels
    top = 0.86 if title else 0.92
    ax = fig.add_axes((0.0, 0.02 + foot, height / width, top - 0.02 - foot))
    ax.imshow(surface)
    ax.set_axis_off()
    ax.set_title(f"surface: {mesh.n_vertices:,} vertices, {extraction.volume / 1000:.1f} mL", fontsize=10)
    panels = (((0, 1), (sx, sy), "x", "y"), ((0, 2), (sx, sz), "x", "z"))
    room = 1.0 - height / width
    for i, ((axis, k, picture), ((a0, a1), (s0, s1), n0, n1)) in enumerate(zip(slices.panels, panels)):
        left = height / width + room * (0.08 + 0.5 * i)
        ax = fig.add_axes((left, 0.1 + foot, room * 0.4, top - 0.14 - foot))
        extent = (-0.5 * s0, (picture.shape[0] - 0.5) * s0, -0.5 * s1, (picture.shape[1] - 0.5) * s1)
        ax.imshow(picture.T, cmap="gray", vmin=vmin, vmax=vmax, origin="lower", extent=extent,
                  interpolation="nearest")
        segs = _slice_segments(index, mesh.faces, axis, float(k))
        if len(segs):
            xy = np.stack([segs[:, :, a0] * s0, segs[:, :, a1] * s1], axis=-1)
            ax.add_collection(LineCollection(xy, colors="#ff3b30", linewidths=0.9))
        ax.set_xlabel(f"{n0} (mm, index axis {a0})", fontsize=8)
        ax.set_ylabel(f"{n1} (mm, index axis {a1})", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_title(f"slice {'xyz'[axis]} = {k} (red: the surface)", fontsize=10)
    if title:
        fig.text(0.5, 0.96, title, ha="center", va="center", fontsize=12)
    fig.text(0.5, 0.012, "\n".join(lines), ha="center", va="bottom", fontsize=8,
             color="#b00020" if extraction.warnings else "#333333")
    canvas.draw()
    with atomic_path(target, VolumeError) as tmp_path:
        fig.savefig(tmp_path, format="png", dpi=dpi, facecolor="white")
    return target


# --------------------------------------------------------------------------
# Several products in one volume
# --------------------------------------------------------------------------

#: Radius (mm) of the opening that takes thin things (a tray, a plate, stalks)
#: off the products before they are told apart: less than half the thickness
#: of a product, more than half that of a tray.
SPLIT_OPENING_MM = 3.0
#: Two touching pieces are one product when the distance map's pass between
#: them is at least this share of the lower of their two peaks. Measured on
#: synthetic CT at 1 mm (2026-12-07): the peaks along one banana, zucchini or
#: pepper join at 0.81 or more, two apples touching on a tray at 0.06-0.11...
SPLIT_SADDLE_SHARE = 0.6
#: ... and the lower peak is at least this share of the higher (a plate
#: thicker than the opening is not merged into the fruit standing on it).
SPLIT_PEAK_SHARE = 0.3
#: A piece holding less than this share of the largest product's voxels is
#: not a product (a broken-off stalk, a label, a speck).
SPLIT_MIN_SHARE = 0.1
#: Voxels added around the products' bounding boxes when they are cut out.
SPLIT_MARGIN_VOXELS = 4
#: Volumes with more voxels than this are told apart on a grid twice as coarse.
SPLIT_COARSE_VOXELS = 40_000_000


@dataclass(frozen=True)
class Split:
    """The products found in one volume (:func:`split_products`).

    Attributes
    ----------
    products : tuple of Volume
        One volume per product, in order of position (rows along y, then x,
        in world coordinates): the product's bounding box with a margin, the
        other products' voxels set to the background. Extract each with
        :func:`extract_surface`.
    centres : (k, 3) float64 ndarray
        World position (mm) of each product's centre of mass.
    left_out : tuple of str
        What was left out, and why, one sentence each: a piece touching the
        volume's edge (cut off), a piece too small to be a product.
    level : float
        The level the products were told apart at.
    """

    products: tuple
    centres: np.ndarray
    left_out: tuple
    level: float


def _pass_values(labels: np.ndarray, dist: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs of touching regions and the highest distance at which they touch (their pass)."""
    keys, values = [], []
    for axis in range(3):
        a = np.moveaxis(labels, axis, 0)
        d = np.moveaxis(dist, axis, 0)
        la, lb = a[:-1], a[1:]
        touch = (la != lb) & (la > 0) & (lb > 0)
        if not touch.any():
            continue
        x, y = la[touch].astype(np.int64), lb[touch].astype(np.int64)
        v = np.minimum(d[:-1][touch], d[1:][touch])
        keys.append(np.minimum(x, y) * (n + 1) + np.maximum(x, y))
        values.append(v)
    if not keys:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    key, val = np.concatenate(keys), np.concatenate(values)
    order = np.lexsort((-val, key))
    key, val = key[order], val[order]
    first = np.r_[True, key[1:] != key[:-1]]
    key, val = key[first], val[first]
    return key // (n + 1), key % (n + 1), val


def _merge_regions(labels: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Regions of a watershed joined where the distance map's pass between them is high: one product each."""
    from scipy import ndimage

    n = int(labels.max())
    if n <= 1:
        return labels
    peaks = np.zeros(n + 1)
    peaks[1:] = ndimage.maximum(dist, labels, index=np.arange(1, n + 1))
    a, b, val = _pass_values(labels, dist, n)
    parent = np.arange(n + 1)

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for k in np.argsort(-val, kind="stable"):  # over the pairs of regions, a few dozen
        ra, rb = root(int(a[k])), root(int(b[k]))
        if ra == rb:
            continue
        low, high = sorted((peaks[ra], peaks[rb]))
        if val[k] >= SPLIT_SADDLE_SHARE * low and low >= SPLIT_PEAK_SHARE * high:
            parent[rb] = ra
            peaks[ra] = high
    roots = np.array([root(i) for i in range(n + 1)])
    _, relabel = np.unique(roots, return_inverse=True)
    return relabel[labels]


def _attach_small(regions: np.ndarray, dist: np.ndarray, n: int, counts: np.ndarray, edge: np.ndarray,
                  largest: int) -> np.ndarray:
    """A piece too small to be a product that touches one is part of it (a pepper's thick stalk)."""
    small = (counts < SPLIT_MIN_SHARE * largest) & ~edge
    small[0] = False
    if not small.any():
        return regions
    a, b, passes = _pass_values(regions, dist, n)
    target = np.arange(n + 1)
    best = np.full(n + 1, -1.0)
    for x, y, v in zip(a, b, passes):  # over the pairs of touching regions, a few dozen
        for piece, other in ((x, y), (y, x)):
            if small[piece] and not small[other] and not edge[other] and v > best[piece]:
                target[piece], best[piece] = other, v
    return target[regions]


def _others_fine(crop: np.ndarray, coarse: np.ndarray, offset: np.ndarray, i: int, masked_ids: np.ndarray,
                 level: float, spacing: np.ndarray, factor: int) -> np.ndarray:
    """In one product's box, the voxels of the others and their rims, on the volume's own grid.

    The products were told apart on a grid ``factor`` times coarser
    (``coarse``: their labels over the box); where two meet, the boundary is
    found again at full resolution: the labels a coarse voxel away from any
    other seed a watershed of the box's own distance map.
    """
    from scipy import ndimage
    from skimage.segmentation import watershed

    up = _repeat_crop(coarse, offset, crop.shape, factor)
    size = 2 * factor + 1
    seeds = np.where(ndimage.maximum_filter(up, size=size) == ndimage.minimum_filter(up, size=size), up, 0)
    solid = ndimage.binary_fill_holes(crop > level)
    dist = ndimage.distance_transform_edt(solid, sampling=spacing)
    labels = watershed(-dist, seeds, mask=solid & ndimage.binary_dilation(up > 0, iterations=factor))
    own = labels == i
    others = np.isin(labels, masked_ids) & ~own
    rim = ndimage.binary_dilation(others, iterations=2) & ~solid
    return others | (rim & ~ndimage.binary_dilation(own, iterations=3))


def _reading_order(centres: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Rows along y (a new row where y jumps by more than half a product), then along x."""
    if len(centres) == 0:
        return np.zeros(0, np.int64)
    by_y = np.argsort(centres[:, 1], kind="stable")
    step = 0.5 * float(np.median(sizes))
    row = np.r_[0, np.cumsum(np.diff(centres[by_y, 1]) > step)]
    rows = np.empty(len(centres), np.int64)
    rows[by_y] = row
    return np.lexsort((centres[:, 0], rows))


def split_products(volume, *, level: float | None = None, name: str = "volume") -> Split:
    """Find every product in a volume of several (a tray of fruit) and cut each out.

    What is above the level (:func:`intensity_levels`), with its enclosed
    cavities, is opened by a ball of :data:`SPLIT_OPENING_MM` (a tray or plate
    and stalks come off). Its distance map's peaks seed a watershed; regions
    whose pass is high against their peaks (:data:`SPLIT_SADDLE_SHARE`,
    :data:`SPLIT_PEAK_SHARE`) are one product, so touching fruit come apart
    at their contact and a pear at its neck does not; a small piece touching
    a product (a thick stalk) is part of it. A piece that touches the
    volume's edge or holds less than :data:`SPLIT_MIN_SHARE` of the largest
    product's voxels is left out, and said so. The products are grown back
    over what the opening took (stalks, thin tips) by the same watershed, a
    thin piece reaching the volume's edge (a tray) excepted. Each product is
    cut out with a margin, the other products' voxels (and their
    partial-volume rims) set to the background; a tray in its box stays, for
    :func:`extract_surface` to drop as a support.

    Parameters
    ----------
    volume : Volume or (nx, ny, nz) array_like
    level : float, optional
        Voxels above it are product; default as :func:`extract_surface`.
    name : str, default: "volume"
        What to call the volume in messages.

    Returns
    -------
    Split

    Raises
    ------
    VolumeError
        No product in the volume (every piece touches its edge or none is
        above the level).

    Examples
    --------
    >>> x, y, z = np.mgrid[:60, :36, :36] - np.array([[[[0]]], [[[17.5]]], [[[17.5]]]])
    >>> balls = [np.sqrt((x - c) ** 2 + y**2 + z**2) for c in (17.5, 41.0)]  # radius 12, touching
    >>> data = (1000 * np.clip(12.5 - np.minimum(*balls), 0, 1)).astype(np.float32)
    >>> split = split_products(data)
    >>> len(split.products), [round(float(c)) for c in split.centres[:, 0]]
    (2, [18, 41])
    """
    from scipy import ndimage
    from skimage.segmentation import watershed

    vol = _as_volume(volume)
    levels = intensity_levels(vol, level=level, name=name)
    factor = 2 if int(np.prod(vol.shape)) > SPLIT_COARSE_VOXELS else 1
    data = vol.data[::factor, ::factor, ::factor]
    spacing = vol.spacing * factor
    solid = ndimage.binary_fill_holes(data > levels.level)
    dist = ndimage.distance_transform_edt(solid, sampling=spacing).astype(np.float32)
    core = dist > SPLIT_OPENING_MM
    opened = ndimage.distance_transform_edt(~core, sampling=spacing) <= SPLIT_OPENING_MM
    opened &= solid
    del core
    if not opened.any():
        raise VolumeError(f"{name}: nothing above the level {levels.level:.6g} is thicker than "
                          f"{2 * SPLIT_OPENING_MM:g} mm: no product in it")
    # seeds: the distance map's peaks, one per plateau
    size = max(3, int(round(2 * SPLIT_OPENING_MM / spacing.min())) | 1)
    peaks = (dist == ndimage.maximum_filter(dist, size=size)) & opened
    seeds, _ = ndimage.label(peaks, structure=np.ones((3, 3, 3)))
    regions = watershed(-dist, seeds, mask=opened)
    del seeds, peaks
    regions = _merge_regions(regions, dist)
    n = int(regions.max())
    counts = np.bincount(regions.ravel(), minlength=n + 1)
    edge = _border_blocks(regions, n) > 0
    largest = max((counts[i] for i in range(1, n + 1) if not edge[i]), default=0)
    if largest == 0:
        raise VolumeError(f"{name}: every piece above the level touches the volume's edge: no whole product in it")
    # thin things: a stalk goes with the product it hangs from, a tray or plate reaching the edge with none
    thin, n_thin = ndimage.label(solid & ~opened, structure=np.ones((3, 3, 3)))
    thin_edge = _border_blocks(thin, n_thin) > 0
    loose = thin_edge[thin]
    del thin
    regions = _attach_small(regions, dist, n, counts, edge, largest)
    counts = np.bincount(regions.ravel(), minlength=n + 1)
    # the thick parts by nearest core; thin parts (a stalk, a banana's tip) along the solid from them
    # the products grown back over what the opening took (stalks, tips), along the solid
    grown = watershed(-dist, regions, mask=solid & ~loose)
    voxel_ml = float(np.prod(spacing)) / 1000.0
    keep, left_out = [], []
    boxes = ndimage.find_objects(grown)
    for i in range(1, n + 1):
        if counts[i] == 0:
            continue  # part of a product now
        box = boxes[i - 1]
        where = vol.index_to_world([[factor * (s.start + s.stop - 1) / 2 for s in box]])[0]
        at = ", ".join(f"{c:.0f}" for c in where)
        if edge[i]:
            left_out.append(f"a piece of {counts[i] * voxel_ml:.3g} mL at ({at}) mm touches the volume's edge "
                            "(cut off, or a tray or holder)")
        elif counts[i] < SPLIT_MIN_SHARE * largest:
            left_out.append(f"a piece of {counts[i] * voxel_ml:.3g} mL at ({at}) mm is too small to be a product "
                            f"(under {SPLIT_MIN_SHARE:.0%} of the largest)")
        else:
            keep.append(i)
    centres = np.array(ndimage.center_of_mass(opened, regions, keep)) * factor if keep else np.zeros((0, 3))
    centres = vol.index_to_world(centres) if len(keep) else centres
    sizes = np.cbrt(counts[keep] * np.prod(spacing))
    order = _reading_order(centres, sizes)
    keep = [keep[k] for k in order]
    centres = centres[order]
    # the others' voxels and their rims (below the level, beside them) go to the background; a tray stays,
    # for extract_surface to drop as a support (the surface meets it where the product stands on it)
    masked_ids = np.array(keep + [i for i in range(1, n + 1) if edge[i]])
    if factor == 1:  # on a coarse grid each box finds its boundaries again at full resolution instead
        masked = np.isin(grown, masked_ids)
        rim = ndimage.binary_dilation(masked, iterations=2) & ~solid
    background = levels.background
    products = []
    for i in keep:
        box = boxes[i - 1]
        lo = np.array([max(0, factor * (s.start - SPLIT_MARGIN_VOXELS)) for s in box])
        hi = np.array([min(vol.shape[a], factor * (s.stop + SPLIT_MARGIN_VOXELS)) for a, s in enumerate(box)])
        crop = np.array(vol.data[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]])
        sub = tuple(slice(a // factor, -(-b // factor)) for a, b in zip(lo, hi))
        if factor == 1:
            own = grown[sub] == i
            others = (masked[sub] & ~own) | (rim[sub] & ~ndimage.binary_dilation(own, iterations=3))
        else:
            others = _others_fine(crop, grown[sub], lo - factor * np.array([s.start for s in sub]), i, masked_ids,
                                  levels.level, vol.spacing, factor)
        fill = np.array(background).astype(crop.dtype) if crop.dtype.kind != "f" else background
        crop[others] = fill
        products.append(Volume(crop, vol.spacing, vol.index_to_world([lo])[0], vol.direction,
                               spacing_source=vol.spacing_source))
    return Split(tuple(products), centres, tuple(left_out), float(levels.level))


# --------------------------------------------------------------------------
# Files and batches
# --------------------------------------------------------------------------


def volume_stem(path) -> str:
    """The name of a volume's outputs: the file name without its extension.

    ``.nii.gz`` counts as one extension; a DICOM or TIFF-slice folder gives
    its own name, a :class:`hortishape.io.VolumeSource` its ``name``.

    Examples
    --------
    >>> volume_stem("scans/apple_001.nii.gz"), volume_stem("scans/pear.mha")
    ('apple_001', 'pear')
    """
    if isinstance(path, VolumeSource):
        return path.name
    p = Path(path)
    name = p.name
    for ext in sorted(volume_formats(), key=len, reverse=True):
        if name.lower().endswith(ext) and len(name) > len(ext) and not p.is_dir():
            return name[: -len(ext)]
    return name


def is_volume_source(path) -> bool:
    """Whether ``path`` is one volume :func:`hortishape.io.read_volume` reads.

    A file with a volume extension (``.mha``, ``.mhd``, ``.nrrd``, ``.nhdr``,
    ``.nii``, ``.nii.gz``, ``.tif``, ``.tiff``), or a folder holding one DICOM
    series (found by content, whatever its files are called) or at least two
    ``.tif`` slices. Hidden names (starting with a dot) are not volumes.

    Examples
    --------
    >>> is_volume_source("no/such/apple.mha")
    False
    """
    p = Path(path)
    if p.name.startswith(".") or not p.exists():
        return False
    if p.is_file():
        return any(p.name.lower().endswith(ext) for ext in volume_formats())
    found = find_sources(p, meshes=False).volumes
    return len(found) == 1 and found[0].path == p


def find_volumes(folder) -> list[VolumeSource]:
    """The volumes in ``folder`` and its subfolders (:func:`hortishape.io.find_sources`), sorted by name.

    Raises
    ------
    HortishapeError
        If ``folder`` is not a folder.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape.io import Volume, write_volume
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = write_volume(folder / "b.mha", Volume(np.zeros((4, 4, 4)), spacing=0.5))
    >>> (folder / "study").mkdir()
    >>> _ = write_volume(folder / "study" / "a.mha", Volume(np.zeros((4, 4, 4)), spacing=0.5))
    >>> _ = (folder / "notes.txt").write_text("not a scan")
    >>> [v.name for v in find_volumes(folder)]
    ['a', 'b']
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise HortishapeError(f"{folder}: not a folder")
    return list(find_sources(folder, meshes=False).volumes)


def collect_volumes(paths, *, exclude=()) -> tuple[list, list[tuple[str, str]]]:
    """The volumes to extract from files and folders, as ``extract`` and ``build`` take them.

    A file is taken as it is (:func:`hortishape.io.read_volume` says what is
    wrong with it); a folder is searched with its subfolders
    (:func:`hortishape.io.find_sources`): each DICOM series, TIFF stack and
    volume file in it is a volume. A folder without any is kept, for the
    reader to say why.

    Returns
    -------
    volumes : list of Path or VolumeSource
    passed_over : list of (str, str)
        Files and folders in the folders that are not volumes, with why.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape.io import Volume, write_volume
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = write_volume(folder / "apple.mha", Volume(np.zeros((4, 4, 4)), spacing=0.5))
    >>> _ = (folder / "notes.txt").write_text("120 kV")
    >>> volumes, passed_over = collect_volumes([folder])
    >>> [v.name for v in volumes], [Path(p).name for p, why in passed_over]
    (['apple'], ['notes.txt'])
    """
    volumes: list = []
    passed: list[tuple[str, str]] = []
    for p in (Path(x) for x in paths):
        if p.is_dir():
            found = find_sources(p, meshes=False, exclude=exclude)
            volumes += list(found.volumes) or [p]
            passed += list(found.skipped) if found.volumes else []
        else:
            volumes.append(p)
    return volumes, passed


@dataclass(frozen=True)
class ExtractResult:
    """What happened to one volume of a batch (:func:`extract_files`).

    Attributes
    ----------
    name : str
        The volume's stem: its outputs are ``<name>.ply``, ``.json``, ``.png``.
    source : str
        The volume's path.
    ok : bool
    error : str or None
        Why it failed, in one line naming the file.
    resumed : bool
        Taken from an earlier run instead of redone.
    mesh : str or None
        Path of the surface.
    picture : str or None
        Path of the picture, when one was made.
    seconds : float
        Time of the extraction (of the earlier run when resumed).
    n_vertices : int
    volume_mm3 : float
        Enclosed volume of the surface.
    level, background, foreground : float
        Iso level and intensities (:class:`IntensityLevels`).
    n_filled_voxels, n_support_voxels : int
    warnings : tuple of str
        What a person should look at (:attr:`Extraction.warnings`).
    left_out : tuple of str
        With ``split``, on a volume's first product: what was left out of
        the volume, and why (:attr:`Split.left_out`).
    """

    name: str
    source: str
    ok: bool
    error: str | None = None
    resumed: bool = False
    mesh: str | None = None
    picture: str | None = None
    seconds: float = 0.0
    n_vertices: int = 0
    volume_mm3: float = float("nan")
    level: float = float("nan")
    background: float = float("nan")
    foreground: float = float("nan")
    n_filled_voxels: int = 0
    n_support_voxels: int = 0
    warnings: tuple = ()
    left_out: tuple = ()


def _source_digest(source) -> str:
    """SHA-256 of a volume's bytes (with an .mhd's data file, or a folder's or series' files)."""
    h = hashlib.sha256()
    src = source if isinstance(source, VolumeSource) else VolumeSource(volume_stem(source), Path(source))
    for f in src.all_files():
        h.update(f.name.encode() + b"\0")
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _settings(options: dict) -> str:
    """A digest of the options, hortishape's version and the method's constants: a change of any
    re-extracts."""
    constants = {name: globals()[name] for name in sorted(globals()) if name.startswith(_CONSTANT_PREFIXES)}
    return hashlib.sha256(json.dumps({"version": __version__, "constants": constants, **options},
                                     sort_keys=True, default=list).encode()).hexdigest()


_CONSTANT_PREFIXES = ("GAPS_", "ENCLOSED_", "SUPPORT_", "OUTER_", "PIT_", "SLICE_", "ISO_", "SPLIT_")


def _failure(stem: str, source, exc: BaseException) -> ExtractResult:
    """What a failed volume reports: one line naming it (a bug too, so that a batch goes on)."""
    if isinstance(exc, HortishapeError):
        msg = str(exc)
        if not msg.startswith(str(source)):
            msg = f"{source}: {msg}"
    elif isinstance(exc, MemoryError):
        msg = f"{source}: not enough memory to extract this volume"
    elif isinstance(exc, OSError):
        msg = f"{source}: {exc.strerror or exc}"
    else:
        where = traceback.extract_tb(exc.__traceback__)[-1]
        msg = (f"{source}: internal error {type(exc).__name__}: {exc} "
               f"(at {Path(where.filename).name}:{where.lineno}; please report it)")
    return ExtractResult(name=stem, source=str(source), ok=False, error=msg)


def _done_before(log_path: Path, digest: str, fingerprint: str, needed: Sequence[Path]) -> dict | None:
    """The log of an earlier run of the same bytes and options whose outputs are all there, or None."""
    if not (log_path.is_file() and all(p.is_file() for p in needed)):
        return None
    try:
        log = json.loads(log_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return log if log.get("source_sha256") == digest and log.get("fingerprint") == fingerprint else None


def _extract_and_write(vol: Volume, source, stem: str, out: Path, options: dict, picture: bool,
                       extra: dict) -> tuple[dict, Path, Path | None]:
    """Extract one product's surface from ``vol`` and write its PLY, picture and, last, its JSON log."""
    ply, log_path, png = out / f"{stem}.ply", out / f"{stem}.json", out / f"{stem}.png"
    start = time.perf_counter()
    surface_options = {k: options[k] for k in ("level", "smoothing", "target_vertices", "remove_support",
                                               "support_radius")}
    with warnings.catch_warnings():
        # said in the log and the result instead (batches run in other processes)
        warnings.simplefilter("ignore", ExtractionWarning)
        ext = extract_surface(vol, name=str(source), **surface_options)
    units = {**_check_extent(ext.mesh.vertices, vol.spacing, source, ext.volume).as_log(),
             "spacing_mm": vol.spacing.tolist(), "spacing_source": vol.spacing_source}
    seconds = time.perf_counter() - start
    slices = _ExtractionSlices.of(vol, ext) if picture else None
    write_mesh(ply, ext.mesh)
    if picture:
        _draw_extraction(slices, ext, png, title=stem, width=_PICTURE_SIZE[0], height=_PICTURE_SIZE[1],
                         backend="auto")
    log = {
        "source": str(source),
        **extra,
        "options": options,
        "units": units,
        "seconds": seconds,
        "levels": asdict(ext.levels),
        "level_choice": ext.levels.explain(),
        "gap_mm": ext.gap_mm,
        "genus": ext.genus,
        "attempts": list(ext.attempts),
        "warnings": list(ext.warnings),
        "bounds_index_xyz": ext.bounds.tolist(),
        "n_vertices": ext.mesh.n_vertices,
        "n_marching_cubes_vertices": ext.n_marching_cubes_vertices,
        "volume_mm3": ext.volume,
        "n_object_voxels": ext.n_object_voxels,
        "n_filled_voxels": ext.n_filled_voxels,
        "n_support_voxels": ext.n_support_voxels,
    }
    # the log last: with the right fingerprint it marks the product done
    with atomic_path(log_path, VolumeError) as tmp:
        tmp.write_text(json.dumps(log, indent=1), encoding="utf-8")
    return log, ply, png if picture else None


def _options(level, smoothing, target_vertices, remove_support, support_radius, spacing, split=False) -> dict:
    options = {"level": level, "smoothing": smoothing, "target_vertices": target_vertices,
               "remove_support": remove_support, "support_radius": support_radius}
    if spacing is not None:  # absent otherwise, so earlier runs' fingerprints still hold
        options["spacing"] = [float(x) for x in spacing]
    if split:
        options["split"] = True
    return options


def extract_file(source, out_dir, *, level: float | None = None, smoothing: int = 10,
                 target_vertices: int | None = None, remove_support: bool = True,
                 support_radius: float = 2.0, picture: bool = True,
                 spacing: Sequence[float] | None = None) -> ExtractResult:
    """Extract the surface of one volume file into ``out_dir``, unless already done.

    Writes ``out_dir/<stem>.ply`` (the surface, mm), ``out_dir/<stem>.json``
    (levels, counts, seconds, where the voxel size came from, and a
    fingerprint of the source's bytes and the options) and, with
    ``picture``, ``out_dir/<stem>.png`` (:func:`render_extraction`). When the
    JSON shows that the same file was extracted with the same options,
    nothing is redone.

    Parameters
    ----------
    source : path or VolumeSource
        A volume file, a DICOM / TIFF-slice folder (:func:`hortishape.io.read_volume`)
        or one volume :func:`hortishape.io.find_sources` found.
    out_dir : path
        Created if needed.
    level, smoothing, target_vertices, remove_support, support_radius
        See :func:`extract_surface`.
    picture : bool, default: True
        Also write the picture.
    spacing : (3,) sequence of float, optional
        Voxel size along x, y, z (mm), in place of what the file says (a
        TIFF stack without a voxel size in its metadata or a scanner log
        beside it needs it).

    Returns
    -------
    ExtractResult
        Never raises for a bad volume: ``ok`` is False and ``error`` says why,
        also when the surface is not a fruit's size
        (:data:`hortishape.units.PRODUCT_EXTENT_MM`,
        :data:`hortishape.units.PRODUCT_VOLUME_ML`), with the voxel size
        that would make it one.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> from hortishape.io import write_volume
    >>> folder = Path(tempfile.mkdtemp())
    >>> apple = synth.make_instance("apple", random_state=1, volume=True, n_vertices=20000)
    >>> _ = write_volume(folder / "apple.mha", apple.volume)
    >>> r = extract_file(folder / "apple.mha", folder / "surfaces", picture=False)
    >>> r.ok, Path(r.mesh).name
    (True, 'apple.ply')
    """
    source = source if isinstance(source, VolumeSource) else Path(source)
    location = source.path if isinstance(source, VolumeSource) else source
    out = Path(out_dir)
    stem = volume_stem(source)
    options = _options(level, smoothing, target_vertices, remove_support, support_radius, spacing)
    ply, png = out / f"{stem}.ply", out / f"{stem}.png"
    try:
        if not location.exists():
            raise VolumeError(f"{source}: no such file or folder")
        digest = _source_digest(source)
        fingerprint = _settings(options)
        log = _done_before(out / f"{stem}.json", digest, fingerprint, [ply] + ([png] if picture else []))
        if log is not None:
            return _result(stem, source, log, ply, png if png.is_file() else None, resumed=True)
        out.mkdir(parents=True, exist_ok=True)
        vol = read_volume(source, spacing=spacing)
        log, ply, png = _extract_and_write(vol, source, stem, out, options, picture,
                                           {"source_sha256": digest, "fingerprint": fingerprint})
        return _result(stem, source, log, ply, png, resumed=False)
    except Exception as exc:  # noqa: BLE001 - a bad volume or a bug must not lose the rest of the batch
        return _failure(stem, source, exc)


def extract_products(source, out_dir, *, level: float | None = None, smoothing: int = 10,
                     target_vertices: int | None = None, remove_support: bool = True,
                     support_radius: float = 2.0, picture: bool = True,
                     spacing: Sequence[float] | None = None) -> list[ExtractResult]:
    """Extract every product in one volume of several (a tray of fruit) into ``out_dir``, unless done.

    The products are found and cut out by :func:`split_products` and each
    extracted as :func:`extract_file` extracts a volume, into
    ``out_dir/<stem>_1.ply``, ``<stem>_2.ply``, ... (with their JSON and
    pictures) in the order of their positions (rows along y, then x).
    ``out_dir/<stem>.split.json`` says how many were found, where, and what
    was left out and why (a piece touching the volume's edge, too small to
    be a product); with the same bytes and options nothing is redone.

    Parameters
    ----------
    source, out_dir, level, smoothing, target_vertices, remove_support, support_radius, picture, spacing
        As :func:`extract_file`.

    Returns
    -------
    list of ExtractResult
        One per product, in order; the first carries ``left_out``. Never
        raises for a bad volume: one result with ``ok`` False says why.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> from hortishape.io import write_volume
    >>> folder = Path(tempfile.mkdtemp())
    >>> tray = synth.make_tray("apple", 2, random_state=3)
    >>> _ = write_volume(folder / "tray.mha", tray.volume)
    >>> [Path(r.mesh).name for r in extract_products(folder / "tray.mha", folder / "surfaces", picture=False)]
    ['tray_1.ply', 'tray_2.ply']
    """
    source = source if isinstance(source, VolumeSource) else Path(source)
    location = source.path if isinstance(source, VolumeSource) else source
    out = Path(out_dir)
    stem = volume_stem(source)
    options = _options(level, smoothing, target_vertices, remove_support, support_radius, spacing, split=True)
    summary_path = out / f"{stem}.split.json"
    try:
        if not location.exists():
            raise VolumeError(f"{source}: no such file or folder")
        digest = _source_digest(source)
        fingerprint = _settings(options)
        summary = _done_before(summary_path, digest, fingerprint, [])
        if summary is not None:
            names = summary["products"]
            logs = [_done_before(out / f"{n}.json", digest, fingerprint,
                                 [out / f"{n}.ply"] + ([out / f"{n}.png"] if picture else [])) for n in names]
            if all(log is not None for log in logs):
                return [replace(_result(n, source, log, out / f"{n}.ply",
                                        out / f"{n}.png" if (out / f"{n}.png").is_file() else None, resumed=True),
                                left_out=tuple(summary["left_out"]) if k == 0 else ())
                        for k, (n, log) in enumerate(zip(names, logs))]
        out.mkdir(parents=True, exist_ok=True)
        vol = read_volume(source, spacing=spacing)
        split = split_products(vol, level=level, name=str(source))
        del vol
        names = [f"{stem}_{k + 1}" for k in range(len(split.products))]
        results = []
        for k, (name, product) in enumerate(zip(names, split.products)):
            extra = {"source_sha256": digest, "fingerprint": fingerprint, "split_from": stem, "product": k + 1,
                     "centre_mm": split.centres[k].tolist()}
            try:
                log, ply, png = _extract_and_write(product, source, name, out, options, picture, extra)
                results.append(_result(name, source, log, ply, png, resumed=False))
            except Exception as exc:  # noqa: BLE001 - one product's failure does not lose the others
                results.append(_failure(name, f"{source} (product {k + 1})", exc))
        with atomic_path(summary_path, VolumeError) as tmp:
            tmp.write_text(json.dumps({"source": str(source), "source_sha256": digest, "fingerprint": fingerprint,
                                       "products": names, "centres_mm": split.centres.tolist(),
                                       "left_out": list(split.left_out), "level": split.level}, indent=1),
                           encoding="utf-8")
        if results:
            results[0] = replace(results[0], left_out=split.left_out)
        return results
    except Exception as exc:  # noqa: BLE001
        return [_failure(stem, source, exc)]


def _check_extent(vertices: np.ndarray, spacing: np.ndarray, source, volume_mm3: float) -> SizeCheck:
    """The size check of an extracted surface, whose unit is set by the voxel size.

    Stricter than a mesh's (:data:`hortishape.units.PRODUCT_EXTENT_MM` and
    :data:`hortishape.units.PRODUCT_VOLUME_ML`): a wrong voxel size is the
    likely cause, and the error names the voxel sizes that would make it a
    fruit's size.
    """
    extent = float(np.ptp(vertices, axis=0).max())
    ml = volume_mm3 / 1000.0
    (lo, hi), (vlo, vhi) = PRODUCT_EXTENT_MM, PRODUCT_VOLUME_ML
    if lo <= extent <= hi and vlo <= ml <= vhi:
        return check_size(vertices, name=str(source))
    f_lo, f_hi = plausible_voxel_factors(extent, volume_mm3)
    given = " ".join(f"{x:g}" for x in spacing)
    unit = likely_unit(extent)
    if unit is not None and f_lo <= unit[1] <= f_hi:
        fix = f"; if the voxel size is in {unit[0]}, use --spacing {' '.join(f'{x * unit[1]:g}' for x in spacing)}"
    elif f_lo <= f_hi:
        fix = (f"; a voxel size {f_lo:.3g} to {f_hi:.3g} times this one would make it one "
               f"(--spacing SX SY SZ, e.g. {' '.join(f'{x * math.sqrt(f_lo * f_hi):.3g}' for x in spacing)})")
    else:
        fix = "; no voxel size makes it one (is this a fruit or vegetable?)"
    raise VolumeError(
        f"{source}: the product is {extent:.3g} mm across and holds {ml:.3g} mL with voxels of {given} mm, "
        f"not a fruit's size ({lo:g}-{hi:g} mm, {vlo:g} mL-{vhi / 1000:g} L){fix}"
    )


def _result(stem: str, source: Path, log: dict, ply: Path, png: Path | None, *, resumed: bool) -> ExtractResult:
    lv = log["levels"]
    return ExtractResult(
        name=stem, source=str(source), ok=True, resumed=resumed, mesh=str(ply),
        picture=str(png) if png is not None else None, seconds=float(log["seconds"]),
        n_vertices=int(log["n_vertices"]), volume_mm3=float(log["volume_mm3"]), level=float(lv["level"]),
        background=float(lv["background"]), foreground=float(lv["foreground"]),
        n_filled_voxels=int(log["n_filled_voxels"]), n_support_voxels=int(log["n_support_voxels"]),
        warnings=tuple(log.get("warnings", ())),
    )


def _extract_job(job) -> ExtractResult | list[ExtractResult]:
    source, out_dir, options = job
    options = dict(options)
    if options.pop("split", False):
        return extract_products(source, out_dir, **options)
    return extract_file(source, out_dir, **options)


def _raise_failed_any(results) -> None:
    """``stop`` with ``strict`` for results that may be lists (a split volume's products)."""
    for r in results if isinstance(results, list) else [results]:
        raise_failed(r)


def extract_files(
    sources: Sequence,
    out_dir,
    *,
    level: float | None = None,
    smoothing: int = 10,
    target_vertices: int | None = None,
    remove_support: bool = True,
    support_radius: float = 2.0,
    picture: bool = True,
    n_jobs: int | None = 1,
    strict: bool = False,
    progress: Progress | None = None,
    spacing: Sequence[float] | None = None,
    scheduler=None,
    split: bool = False,
) -> list[ExtractResult]:
    """Extract the surface of every volume into ``out_dir`` (see :func:`extract_file`).

    Parameters
    ----------
    sources : sequence of path or VolumeSource
        Volume files, folders (each volume in them and their subfolders,
        :func:`collect_volumes`), or what :func:`hortishape.io.find_sources`
        found.
    out_dir : path
    level, smoothing, target_vertices, remove_support, support_radius, picture, spacing
        See :func:`extract_file`.
    n_jobs : int or None, default: 1
        Worker processes; None: all cores. Each holds one volume and about
        1.5 times its size besides.
    strict : bool, default: False
        Stop at the first volume that fails instead of going on.
    progress : callable, optional
        Wraps the iterator of finished volumes (e.g. ``tqdm``).
    scheduler : str or distributed.Client, optional
        Run the extractions as tasks on this Dask cluster; its workers read
        the volumes and write ``out_dir`` themselves, so they must see both.
    split : bool, default: False
        Each volume holds several products: extract every one
        (:func:`extract_products`).

    Returns
    -------
    list of ExtractResult
        In the order of ``sources`` (with ``split``, each volume's products
        in their order).

    Raises
    ------
    HortishapeError
        With ``strict``, for the first volume that fails; or if two volumes
        share a stem (their outputs would collide).
    ValueError
        If an option is out of range.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> from hortishape.io import write_volume
    >>> folder = Path(tempfile.mkdtemp())
    >>> for seed in (1, 2):
    ...     pear = synth.make_instance("pear", random_state=seed, volume=True, n_vertices=20000)
    ...     _ = write_volume(folder / f"pear_{seed}.mha", pear.volume)
    >>> results = extract_files(find_volumes(folder), folder / "surfaces", picture=False)
    >>> [(r.ok, Path(r.mesh).name) for r in results]
    [(True, 'pear_1.ply'), (True, 'pear_2.ply')]
    """
    _check_options(smoothing, target_vertices, support_radius)
    out = Path(out_dir)
    paths = []
    for s in sources:  # a folder is searched as the command line searches it (collect_volumes)
        paths += [s] if isinstance(s, VolumeSource) or not Path(s).is_dir() else collect_volumes([s])[0]
    stems = [volume_stem(p) for p in paths]
    dup = sorted({s for s in stems if stems.count(s) > 1})
    if dup:
        raise HortishapeError(f"several volumes share the name {dup[0]!r}: their outputs would collide")
    out.mkdir(parents=True, exist_ok=True)
    options = {"level": level, "smoothing": smoothing, "target_vertices": target_vertices,
               "remove_support": remove_support, "support_radius": support_radius, "picture": picture,
               "spacing": spacing, "split": split}
    def where(q):  # a worker has its own working folder
        if isinstance(q, VolumeSource):
            return q.resolved() if scheduler is not None else q
        return str(q.resolve()) if scheduler is not None else str(q)

    jobs = [(where(p), str(out.resolve()) if scheduler is not None else str(out), options) for p in paths]
    results = run_jobs(_extract_job, jobs, n_jobs=n_jobs, progress=progress,
                       stop=_raise_failed_any if strict else None, scheduler=scheduler)
    return [r for item in results for r in (item if isinstance(item, list) else [item])]
