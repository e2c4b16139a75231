"""From CT volumes to surfaces: segment the product and mesh its outer surface.

:func:`extract_surface` turns a CT volume (:class:`~hortishape.io.Volume`)
into one closed, outward-oriented triangle surface in world millimetres, the
kind of scan the rest of hortishape works on:

1. **Intensities** (:func:`intensity_levels`). A histogram of the voxel
   values, Otsu's threshold between product and background, and the peak of
   the histogram on either side of it: the background and the product
   intensity. The iso level is half-way between the two peaks. Under the
   partial-volume model of a CT scanner (a voxel half air and half flesh has
   the half-way value) the iso-surface at that level runs through the true
   edge, to a small fraction of a voxel. The peaks, not the class means, are
   used: partial-volume voxels, a low-density core or a support would pull a
   mean away.
2. **The product.** Voxels above the level, in 6-connected components; the
   largest is the product. When it touches the border of the volume (a
   scanner bed or a support does, the product normally does not), it is
   eroded by ``support_radius``: parts that then come apart from the product
   and reach the border are dropped as a support. Interior cavities (the
   hollow of a pepper, the low-density core of an apple, air pockets) are
   filled: every region below the level that does not reach the border of
   the volume becomes part of the product.
3. **Marching cubes** (Lewiner) on the *intensity*, not on the mask, which is
   what gives sub-voxel accuracy: inside filled cavities the intensity is
   raised to the product's, voxels above the level that are not the product
   (other objects, a support) are lowered to the background's, and every
   other voxel keeps its value. The surface is therefore exactly the outer
   boundary of the product, one closed component, in world coordinates
   (``origin + direction @ (spacing * index)``), with outward normals.
4. Optionally, **Taubin smoothing** (:func:`taubin_smooth`, a low-pass
   filter that does not shrink the shape) and **decimation** to a target
   vertex count (:func:`decimate`, quadric error edge collapses).

Memory: a 512^3 ``int16`` volume is 256 MB, a 1000^3 one 2 GB. The work is
done in slabs of a few million voxels along the volume's last axis.
Connected components are labelled slab by slab and joined with a union-find
over the slab boundaries; the only whole-volume array besides the volume is
one byte per voxel (each slab's labels), and meshing runs slab by slab on the
object's bounding box. Peak memory is about 1.5 times the size of an
``int16`` volume on top of the volume itself.

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
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ._version import __version__
from ._batch import raise_failed, run_jobs
from .errors import HortishapeError, MeshError, VolumeError
from ._files import Progress, atomic_path
from .io import Volume, read_volume, volume_formats, write_mesh
from .mesh import Mesh
from .units import PLAUSIBLE_EXTENT_MM, SizeCheck, check_size, likely_unit

__all__ = [
    "ExtractResult",
    "Extraction",
    "IntensityLevels",
    "decimate",
    "extract_file",
    "extract_files",
    "extract_surface",
    "find_volumes",
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
# A product smaller than this many voxels is taken as no product at all.
_MIN_OBJECT_VOXELS = 27


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
        The iso level of the surface: half-way between ``background`` and
        ``foreground``, or the given level. Voxels above it are inside.
    """

    background: float
    foreground: float
    threshold: float
    level: float


def _as_volume(volume) -> Volume:
    if isinstance(volume, Volume):
        return volume
    return Volume(volume, spacing=1.0)


def _histogram(data: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Counts, bin centres and bin width of a subsample of ``data``."""
    n = data.size
    step = max(1, math.ceil((n / _HISTOGRAM_SAMPLES) ** (1.0 / 3.0)))
    sample = np.asarray(data[::step, ::step, ::step]).ravel()
    lo, hi = sample.min(), sample.max()
    if sample.dtype.kind in "biu" and int(hi) - int(lo) <= 65_536:
        values = sample.astype(np.int64) - int(lo)
        counts = np.bincount(values, minlength=int(hi) - int(lo) + 1)
        return counts, np.arange(int(lo), int(hi) + 1, dtype=np.float64), 1.0
    counts, edges = np.histogram(sample.astype(np.float64), bins=4096, range=(float(lo), float(hi)))
    return counts, 0.5 * (edges[:-1] + edges[1:]), float(edges[1] - edges[0])


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
        The iso level. Default: half-way between the background and product
        intensities, which are the histogram's peaks either side of Otsu's
        threshold. With a given level the peaks are taken either side of it.
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
    counts, centres, width = _histogram(vol.data)
    data = vol.data
    vmin, vmax = float(data.min()), float(data.max())
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
    iso = 0.5 * (bg + fg) if level is None else level
    return IntensityLevels(background=bg, foreground=fg, threshold=threshold, level=float(iso))


# --------------------------------------------------------------------------
# Connected components slab by slab
# --------------------------------------------------------------------------


def _slab_bounds(lo: int, hi: int, step: int) -> list[tuple[int, int]]:
    """Split ``[lo, hi)`` at the multiples of ``step``."""
    out = []
    z = lo
    while z < hi:
        end = min(hi, (z // step + 1) * step)
        out.append((z, end))
        z = end
    return out


class _Components:
    """6-connected components of a mask, labelled slab by slab along axis 0.

    The mask is given by ``get_mask(z0, z1)`` for the planes ``[z0, z1)`` of a
    region of the volume (shape ``(Z, Y, X)`` in region coordinates). Each
    slab is labelled with :func:`scipy.ndimage.label`; labels that touch
    across a slab boundary are joined (union-find by a sparse graph). A slab's
    labels are kept in ``work`` (one byte per voxel) when they fit, otherwise
    they are computed again when needed (labelling is deterministic).

    Attributes per component (index ``c``): ``size[c]`` voxels and
    ``border[c]``, whether it touches the region's border.
    """

    def __init__(self, get_mask, slabs, work) -> None:
        from scipy import ndimage
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        self.get_mask = get_mask
        self.slabs = slabs
        self.work = work
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
            keep = work is not None and n <= 255
            if keep:
                work[z0 - self.z_lo : z1 - self.z_lo] = lab
            stored.append(keep)
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
            m = self.select(k, chosen)
            for axis, others in ((0, (1, 2)), (1, (0, 2)), (2, (0, 1))):
                hit = np.flatnonzero(m.any(axis=others))
                if len(hit):
                    shift = z0 - self.z_lo if axis == 0 else 0
                    lo[axis] = min(lo[axis], hit[0] + shift)
                    hi[axis] = max(hi[axis], hit[-1] + 1 + shift)
        return lo, hi

    def labels(self, k: int) -> np.ndarray:
        """The local labels of slab ``k`` (stored, or computed again)."""
        from scipy import ndimage

        z0, z1 = self.slabs[k]
        if self.stored[k]:
            return self.work[z0 - self.z_lo : z1 - self.z_lo]
        return ndimage.label(self.get_mask(z0, z1), structure=self._structure)[0]

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
    """
    from scipy import ndimage

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
    depth = ndimage.distance_transform_edt(half, sampling=sampling)
    core = depth > radius
    del depth
    lab, n = ndimage.label(core, structure=ndimage.generate_binary_structure(3, 1))
    if n < 2:
        return None
    touch = np.zeros(n + 1, dtype=bool)
    for face in (lab[0], lab[-1], lab[:, 0], lab[:, -1], lab[:, :, 0], lab[:, :, -1]):
        touch[face.ravel()] = True
    touch[0] = False
    if not touch.any() or touch[1:].all():
        return None
    seeds = touch[lab]
    del lab
    reach = ndimage.distance_transform_edt(~seeds, sampling=sampling)
    return (reach <= radius + float(sampling.max())) & any_


def _upsample(coarse: np.ndarray, z0: int, z1: int, shape_yx, factor: int) -> np.ndarray:
    c = factor
    block = coarse[z0 // c : -(-z1 // c)]
    up = np.repeat(np.repeat(np.repeat(block, c, axis=0), c, axis=1), c, axis=2)
    start = z0 - (z0 // c) * c
    return up[start : start + (z1 - z0), : shape_yx[0], : shape_yx[1]]


# --------------------------------------------------------------------------
# Mesh post-processing
# --------------------------------------------------------------------------


def _adjacency(faces: np.ndarray, n: int, *, closed: bool = False):
    """Vertex adjacency (n, n) CSR with ones, from the faces' directed edges.

    On a closed, consistently oriented surface every edge is in the faces once
    in each direction, so the directed edges alone are the whole (symmetric)
    matrix; otherwise the matrix is symmetrized (more memory).
    """
    import scipy.sparse as sp

    f = np.asarray(faces)
    index = np.int32 if n < 2**31 - 1 else np.int64
    rows = f.astype(index).ravel()  # edges (0, 1), (1, 2), (2, 0) of every face
    cols = f[:, [1, 2, 0]].astype(index).ravel()
    a = sp.csr_matrix((np.ones(len(rows), dtype=np.float32), (rows, cols)), shape=(n, n))
    del rows, cols
    if not closed:
        a = a.maximum(a.T).tocsr()
    a.data[:] = 1.0
    return a


def _taubin(v: np.ndarray, faces: np.ndarray, iterations: int, pass_band: float, lam: float,
            *, closed: bool) -> np.ndarray:
    """Taubin smoothing of ``v`` in place (see :func:`taubin_smooth`)."""
    mu = 1.0 / (pass_band - 1.0 / lam)
    a = _adjacency(faces, len(v), closed=closed)
    degree = np.asarray(a.sum(axis=1)).ravel()
    moving = (degree > 0)[:, None]
    inv = np.divide(1.0, degree, out=np.zeros_like(degree), where=degree > 0)[:, None]
    for _ in range(iterations):
        for step in (lam, mu):
            delta = a @ v
            delta *= inv
            delta -= v * moving
            delta *= step
            v += delta
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
    """

    mesh: Mesh
    levels: IntensityLevels
    bounds: np.ndarray
    n_object_voxels: int
    n_filled_voxels: int
    n_support_voxels: int
    n_marching_cubes_vertices: int

    @property
    def volume(self) -> float:
        """Enclosed volume of the surface, mm^3."""
        from .surface import signed_volume

        return abs(signed_volume(self.mesh.vertices, self.mesh.faces))


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
    from the same two values, so the copies are bit-identical.
    """
    offsets = np.cumsum([0] + [len(c[0]) for c in chunks[:-1]])
    faces = np.concatenate([c[1].astype(np.int64) + o for c, o in zip(chunks, offsets)])
    for c in chunks:
        c[1] = None
    verts = np.concatenate([c[0] for c in chunks])
    chunks.clear()  # the caller's list: free the pieces
    index = np.arange(len(verts))
    if len(boundaries):
        on_plane = np.flatnonzero(np.isin(verts[:, 2], np.asarray(boundaries, dtype=np.float64)))
        if len(on_plane):
            _, first, inverse = np.unique(verts[on_plane], axis=0, return_index=True, return_inverse=True)
            index[on_plane] = on_plane[first[np.ravel(inverse)]]
    faces = index[faces]
    used = np.zeros(len(verts), dtype=bool)
    used[faces.ravel()] = True
    renumber = np.cumsum(used) - 1
    return verts[used], renumber[faces]


def _mesh_product(vol: Volume, iso: float, inside_value: float, outside_value: float, *,
                  remove_support: bool, support_radius: float, name: str):
    """Segment the product and mesh its outer surface in voxel indices.

    Returns ``(index_vertices (n, 3) float64 along x, y, z, faces (m, 3) int64,
    bounds, n_object, n_filled, n_support)``. Every whole-volume work array
    lives only inside this function.
    """
    from skimage.measure import marching_cubes

    # (z, y, x) view: slabs along the volume's last axis are contiguous in memory
    # for volumes read from files (x varies fastest on disk).
    data = vol.data.transpose(2, 1, 0)
    shape = data.shape
    coarse = max(1, math.ceil((data.size / _COARSE_VOXELS) ** (1.0 / 3.0)))
    step = max(1, _SLAB_VOXELS // (shape[1] * shape[2]))
    step = max(coarse, step - step % coarse)
    slabs = _slab_bounds(0, shape[0], step)
    work = np.empty(shape, dtype=np.uint8)  # each slab's labels: one byte per voxel

    def above(z0: int, z1: int) -> np.ndarray:
        return data[z0:z1] > iso

    fg = _Components(above, slabs, work)
    if fg.n_labels == 0:
        raise VolumeError(f"{name}: no voxel is above the level {iso:g}; no object")
    product = np.zeros(len(fg.size), dtype=bool)
    product[int(np.argmax(fg.size))] = True
    n_support = 0
    if remove_support and fg.border[product][0]:
        support = _support_region(lambda k: fg.select(k, product), slabs, shape, vol.spacing[::-1],
                                  support_radius, coarse)
        if support is not None:
            before = int(fg.size[product][0])

            def above_not_support(z0: int, z1: int) -> np.ndarray:
                return (data[z0:z1] > iso) & ~_upsample(support, z0, z1, shape[1:], coarse)

            fg = _Components(above_not_support, slabs, work)
            free = np.flatnonzero(~fg.border)
            pool = free if len(free) else np.arange(len(fg.size))
            product = np.zeros(len(fg.size), dtype=bool)
            product[pool[int(np.argmax(fg.size[pool]))]] = True
            n_support = before - int(fg.size[product][0])
    c = int(np.flatnonzero(product)[0])
    n_object = int(fg.size[c])
    if n_object < _MIN_OBJECT_VOXELS:
        raise VolumeError(
            f"{name}: no object: the largest region above the level {iso:g} has only {n_object} voxels"
        )
    lo, hi = fg.bounds(product)
    if np.all(lo == 0) and np.all(hi == np.asarray(shape)):
        raise VolumeError(
            f"{name}: the object above the level {iso:g} touches all six faces of the volume: there is "
            "no background around it (is the whole volume object, or the level too low?)"
        )

    # Cavities: components of the rest of the product's box (grown by a voxel)
    # that do not reach the box's border. Their labels overwrite the product's
    # in `work`, slab by slab; a slab's product mask is read just before.
    r_lo = np.maximum(lo - 1, 0)
    r_hi = np.minimum(hi + 1, np.asarray(shape))
    ys, xs = slice(int(r_lo[1]), int(r_hi[1])), slice(int(r_lo[2]), int(r_hi[2]))
    region_shape = tuple(int(v) for v in r_hi - r_lo)
    bg_slabs = _slab_bounds(int(r_lo[0]), int(r_hi[0]), step)
    fg_slab = {z0: k for k, (z0, _) in enumerate(slabs)}

    def not_product(z0: int, z1: int) -> np.ndarray:
        k = fg_slab[z0 - z0 % step]
        s0 = slabs[k][0]
        return ~fg.select(k, product, labels=fg.labels(k)[z0 - s0 : z1 - s0, ys, xs])

    region_work = work[int(r_lo[0]) : int(r_hi[0]), ys, xs]
    bg = _Components(not_product, bg_slabs, region_work)
    outside = bg.border
    n_filled = int(bg.size[~outside].sum())

    def filled(k: int) -> np.ndarray:
        """Product or cavity, on slab ``k`` of the box (label 0 is the product)."""
        return ~bg.select(k, outside)

    # Marching cubes slab by slab on the box plus a background layer all
    # around, so that the surface closes where the product touches the
    # volume's border. Slab k covers its planes and the next slab's first.
    level32 = np.float32(iso)
    # small integers are exact in float32, and an integer volume's level is a
    # half-integer: no voxel value can reach or cross the level
    exact = vol.data.dtype.kind in "biu" and vol.data.dtype.itemsize <= 2 and float(level32) == iso
    chunks, boundaries = [], []
    nxt = filled(0)
    for k, (z0, z1) in enumerate(bg_slabs):
        cur = nxt
        last = k == len(bg_slabs) - 1
        nxt = None if last else filled(k + 1)
        inside = cur if last else np.concatenate([cur, nxt[:1]])
        if not inside.any():
            continue
        first_plane = z0 - 1 if k == 0 else z0  # a background plane before the first slab
        j = np.full((z1 - first_plane + 1, region_shape[1] + 2, region_shape[2] + 2), outside_value,
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
        core[inside & ~high] = inside_value
        core[~inside & high] = outside_value
        del d, high, inside, core
        verts, faces, _, _ = marching_cubes(j, level=float(level32), allow_degenerate=True)
        del j
        # (plane, y, x) of the chunk -> volume indices along x, y, z
        idx = np.empty((len(verts), 3), dtype=np.float64)
        idx[:, 0] = verts[:, 2] + (int(r_lo[2]) - 1)
        idx[:, 1] = verts[:, 1] + (int(r_lo[1]) - 1)
        idx[:, 2] = verts[:, 0] + first_plane
        chunks.append([idx, faces])
        if not last:
            boundaries.append(float(z1))
        del verts
    fg.work = bg.work = None  # free the labels (a byte per voxel) before the mesh is joined
    del work, region_work, nxt, cur
    if not chunks:  # pragma: no cover - the product has voxels above the level
        raise VolumeError(f"{name}: no surface found at the level {iso:g}")
    index_vertices, faces = _weld(chunks, boundaries)
    bounds = np.stack([lo[::-1], hi[::-1]], axis=1).astype(np.int64)
    return index_vertices, faces, bounds, n_object, n_filled, n_support


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
    """Extract the outer surface of the product in a CT volume.

    See the module docstring for the method: intensity levels, the largest
    object above the level without a support touching it and with its
    cavities filled, marching cubes on the intensity in world coordinates,
    then optional smoothing and decimation.

    Parameters
    ----------
    volume : Volume or (nx, ny, nz) array_like
        The CT volume (from :func:`hortishape.io.read_volume`); an array is
        taken with 1 mm voxels at the origin. Not modified.
    level : float, optional
        Iso level in the volume's intensity units; voxels above it are
        inside. Default: half-way between the background and product
        intensities (:func:`intensity_levels`). For integer voxels the
        surface is meshed at ``floor(level) + 0.5``, which leaves every voxel
        on its side (a shift of at most 0.5 intensity units, about a
        thousandth of a voxel for CT contrasts) and puts no vertex on a voxel.
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

    Examples
    --------
    >>> x, y, z = np.mgrid[:40, :40, :40] - 19.5
    >>> r = np.sqrt(x**2 + y**2 + z**2)
    >>> data = (1000 * np.clip(12.5 - r, 0, 1)).astype(np.float32)  # radius 12 voxels
    >>> ext = extract_surface(data, smoothing=0)
    >>> round(ext.volume / (4 / 3 * np.pi * 12**3), 2)
    1.0
    """
    from .surface import check_closed_surface, signed_volume

    vol = _as_volume(volume)
    _check_options(smoothing, target_vertices, support_radius)
    levels = intensity_levels(vol, level=level, name=name)
    iso = levels.level
    if vol.data.dtype.kind in "biu":
        iso = math.floor(iso) + 0.5  # the same voxels above it; no vertex on a voxel
    inside_value, outside_value = _fill_values(levels)
    index_vertices, faces, bounds, n_object, n_filled, n_support = _mesh_product(
        vol, iso, inside_value, outside_value, remove_support=remove_support,
        support_radius=float(support_radius), name=name)
    n_mc = len(index_vertices)
    world = vol.origin + (index_vertices * vol.spacing) @ vol.direction.T
    del index_vertices
    if signed_volume(world, faces) < 0:  # outward normals
        faces = faces[:, ::-1]
    if smoothing:
        world = _taubin(world, faces, int(smoothing), 0.1, 0.5, closed=True)
    mesh = Mesh(world, np.ascontiguousarray(faces))
    del world, faces
    if target_vertices is not None:
        mesh = decimate(mesh, int(target_vertices))
    # marching cubes' degenerate slivers (allow_degenerate above) are harmless here
    check_closed_surface(mesh, name=name, allow_degenerate=True)
    return Extraction(mesh, levels, bounds, n_object, n_filled, n_support, n_mc)


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


def render_extraction(volume, extraction: Extraction, path, *, title: str | None = None,
                      size: tuple[int, int] = (1500, 520), backend: str = "auto") -> Path:
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
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure
    from PIL import Image

    from .render import render_mesh

    vol = _as_volume(volume)
    target = Path(os.fspath(path))
    if target.suffix.lower() != ".png":
        raise ValueError(f"{target}: pictures are written as PNG, so the path must end in .png")
    width, height = (int(s) for s in size)
    if width < 300 or height < 150:
        raise ValueError(f"size must be at least 300 x 150 pixels, got {size!r}")
    mesh = extraction.mesh
    with tempfile.TemporaryDirectory() as tmp:
        render_mesh(mesh, Path(tmp) / "surface.png", view="iso", size=(height, height), backend=backend)
        surface = np.asarray(Image.open(Path(tmp) / "surface.png").convert("RGB"))
    index = vol.world_to_index(mesh.vertices)
    centre = extraction.bounds.mean(axis=1)
    lv = extraction.levels
    contrast = lv.foreground - lv.background
    vmin, vmax = lv.background - 0.2 * contrast, lv.foreground + 0.2 * contrast
    if vmin > vmax:
        vmin, vmax = vmax, vmin
    sx, sy, sz = vol.spacing
    dpi = 100.0
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    top = 0.86 if title else 0.92
    ax = fig.add_axes((0.0, 0.02, height / width, top - 0.02))
    ax.imshow(surface)
    ax.set_axis_off()
    ax.set_title(f"surface: {mesh.n_vertices:,} vertices, {extraction.volume / 1000:.1f} mL", fontsize=10)
    panels = (
        (2, int(round(centre[2])), (0, 1), (sx, sy), "x", "y"),
        (1, int(round(centre[1])), (0, 2), (sx, sz), "x", "z"),
    )
    room = 1.0 - height / width
    for i, (axis, k, (a0, a1), (s0, s1), n0, n1) in enumerate(panels):
        k = int(np.clip(k, 0, vol.shape[axis] - 1))
        picture = np.take(vol.data, k, axis=axis).astype(np.float32)  # [a0, a1]
        left = height / width + room * (0.08 + 0.5 * i)
        ax = fig.add_axes((left, 0.1, room * 0.4, top - 0.14))
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
    canvas.draw()
    with atomic_path(target, VolumeError) as tmp_path:
        fig.savefig(tmp_path, format="png", dpi=dpi, facecolor="white")
    return target


# --------------------------------------------------------------------------
# Files and batches
# --------------------------------------------------------------------------


def volume_stem(path) -> str:
    """The name of a volume's outputs: the file name without its extension.

    ``.nii.gz`` counts as one extension; a DICOM or TIFF-slice folder gives
    its own name.

    Examples
    --------
    >>> volume_stem("scans/apple_001.nii.gz"), volume_stem("scans/pear.mha")
    ('apple_001', 'pear')
    """
    p = Path(path)
    name = p.name
    for ext in sorted(volume_formats(), key=len, reverse=True):
        if name.lower().endswith(ext) and len(name) > len(ext) and not p.is_dir():
            return name[: -len(ext)]
    return name


def is_volume_source(path) -> bool:
    """Whether ``path`` is a volume :func:`hortishape.io.read_volume` reads.

    A file with a volume extension (``.mha``, ``.mhd``, ``.nrrd``, ``.nhdr``,
    ``.nii``, ``.nii.gz``, ``.tif``, ``.tiff``), or a folder of ``.dcm`` files
    or of at least two ``.tif`` slices. Hidden names (starting with a dot) are
    not volumes.

    Examples
    --------
    >>> is_volume_source("no/such/apple.mha")
    False
    """
    p = Path(path)
    if p.name.startswith("."):
        return False
    if p.is_file():
        return any(p.name.lower().endswith(ext) for ext in volume_formats())
    if p.is_dir():
        names = [f.name.lower() for f in p.iterdir() if f.is_file() and not f.name.startswith(".")]
        return any(n.endswith(".dcm") for n in names) or sum(n.endswith((".tif", ".tiff")) for n in names) >= 2
    return False


def find_volumes(folder) -> list[Path]:
    """The volumes in ``folder`` (see :func:`is_volume_source`), sorted by name.

    Raises
    ------
    HortishapeError
        If ``folder`` is not a folder.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise HortishapeError(f"{folder}: not a folder")
    return sorted(p for p in folder.iterdir() if is_volume_source(p))


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


def _source_digest(path: Path) -> str:
    """SHA-256 of a volume's bytes (with an .mhd's data file, or a folder's files)."""
    h = hashlib.sha256()
    if path.is_dir():
        files = sorted(f for f in path.iterdir() if f.is_file() and not f.name.startswith("."))
    else:
        files = [path]
        if path.suffix.lower() in (".mhd", ".nhdr"):
            files += sorted(f for f in path.parent.glob(path.stem + ".*")
                            if f != path and f.suffix.lower() in (".raw", ".zraw", ".gz", ".raw.gz"))
    for f in files:
        h.update(f.name.encode() + b"\0")
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _settings(options: dict) -> str:
    return hashlib.sha256(json.dumps({"version": __version__, **options}, sort_keys=True).encode()).hexdigest()


def extract_file(source, out_dir, *, level: float | None = None, smoothing: int = 10,
                 target_vertices: int | None = None, remove_support: bool = True,
                 support_radius: float = 2.0, picture: bool = True,
                 spacing: Sequence[float] | None = None) -> ExtractResult:
    """Extract the surface of one volume file into ``out_dir``, unless already done.

    Writes ``out_dir/<stem>.ply`` (the surface, mm), ``out_dir/<stem>.json``
    (levels, counts, seconds, and a fingerprint of the source's bytes and the
    options) and, with ``picture``, ``out_dir/<stem>.png``
    (:func:`render_extraction`). When the JSON shows that the same file was
    extracted with the same options, nothing is redone.

    Parameters
    ----------
    source : path
        A volume file or a DICOM / TIFF-slice folder (:func:`hortishape.io.read_volume`).
    out_dir : path
        Created if needed.
    level, smoothing, target_vertices, remove_support, support_radius
        See :func:`extract_surface`.
    picture : bool, default: True
        Also write the picture.
    spacing : (3,) sequence of float, optional
        Voxel size along x, y, z (mm), in place of what the file says (TIFF
        stores none: 1 mm is assumed with a warning).

    Returns
    -------
    ExtractResult
        Never raises for a bad volume: ``ok`` is False and ``error`` says why,
        also when the surface is not a fruit's size
        (:data:`hortishape.units.PLAUSIBLE_EXTENT_MM`), with the voxel size
        that would make it one.
    """
    source, out = Path(source), Path(out_dir)
    stem = volume_stem(source)
    options = {"level": level, "smoothing": smoothing, "target_vertices": target_vertices,
               "remove_support": remove_support, "support_radius": support_radius}
    if spacing is not None:  # absent otherwise, so earlier runs' fingerprints still hold
        options["spacing"] = [float(x) for x in spacing]
    ply, log_path, png = out / f"{stem}.ply", out / f"{stem}.json", out / f"{stem}.png"
    try:
        if not source.exists():
            raise VolumeError(f"{source}: no such file or folder")
        digest = _source_digest(source)
        fingerprint = _settings(options)
        if ply.is_file() and log_path.is_file() and (png.is_file() or not picture):
            try:
                log = json.loads(log_path.read_text())
            except (OSError, ValueError):
                log = {}
            if log.get("source_sha256") == digest and log.get("fingerprint") == fingerprint:
                return _result(stem, source, log, ply, png if png.is_file() else None, resumed=True)
        out.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        vol = read_volume(source, spacing=spacing)
        ext = extract_surface(vol, level=level, smoothing=smoothing, target_vertices=target_vertices,
                              remove_support=remove_support, support_radius=support_radius, name=str(source))
        units = {**_check_extent(ext.mesh.vertices, vol.spacing, source).as_log(), "spacing_mm": vol.spacing.tolist()}
        seconds = time.perf_counter() - start
        write_mesh(ply, ext.mesh)
        if picture:
            render_extraction(vol, ext, png, title=f"{source.name}: level {ext.levels.level:g}")
        del vol
        log = {
            "source": str(source),
            "source_sha256": digest,
            "fingerprint": fingerprint,
            "options": options,
            "units": units,
            "seconds": seconds,
            "levels": asdict(ext.levels),
            "bounds_index_xyz": ext.bounds.tolist(),
            "n_vertices": ext.mesh.n_vertices,
            "n_marching_cubes_vertices": ext.n_marching_cubes_vertices,
            "volume_mm3": ext.volume,
            "n_object_voxels": ext.n_object_voxels,
            "n_filled_voxels": ext.n_filled_voxels,
            "n_support_voxels": ext.n_support_voxels,
        }
        # the log last: with the right fingerprint it marks the volume done
        with atomic_path(log_path, VolumeError) as tmp:
            tmp.write_text(json.dumps(log, indent=1))
        return _result(stem, source, log, ply, png if picture else None, resumed=False)
    except HortishapeError as exc:
        msg = str(exc)
        if not msg.startswith(str(source)):
            msg = f"{source}: {msg}"
        return ExtractResult(name=stem, source=str(source), ok=False, error=msg)
    except MemoryError:
        return ExtractResult(name=stem, source=str(source), ok=False,
                             error=f"{source}: not enough memory to extract this volume")
    except OSError as exc:
        return ExtractResult(name=stem, source=str(source), ok=False, error=f"{source}: {exc.strerror or exc}")
    except Exception as exc:  # a bug must not lose the rest of the batch; say what it was
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return ExtractResult(
            name=stem, source=str(source), ok=False,
            error=f"{source}: internal error {type(exc).__name__}: {exc} "
                  f"(at {Path(where.filename).name}:{where.lineno}; please report it)",
        )


def _check_extent(vertices: np.ndarray, spacing: np.ndarray, source: Path) -> SizeCheck:
    """The size check of an extracted surface, whose unit is set by the voxel size."""
    try:
        return check_size(vertices, name=str(source))
    except MeshError:
        extent = float(np.ptp(vertices, axis=0).max())
        unit = likely_unit(extent)
        given = " ".join(f"{x:g}" for x in spacing)
        fix = ("" if unit is None else
               f"; if the voxel size is in {unit[0]}, use --spacing {' '.join(f'{x * unit[1]:g}' for x in spacing)}")
        lo, hi = PLAUSIBLE_EXTENT_MM
        raise VolumeError(
            f"{source}: the product is {extent:.3g} mm across with voxels of {given} mm, not a fruit's size "
            f"({lo:g}-{hi:g} mm){fix}"
        ) from None


def _result(stem: str, source: Path, log: dict, ply: Path, png: Path | None, *, resumed: bool) -> ExtractResult:
    lv = log["levels"]
    return ExtractResult(
        name=stem, source=str(source), ok=True, resumed=resumed, mesh=str(ply),
        picture=str(png) if png is not None else None, seconds=float(log["seconds"]),
        n_vertices=int(log["n_vertices"]), volume_mm3=float(log["volume_mm3"]), level=float(lv["level"]),
        background=float(lv["background"]), foreground=float(lv["foreground"]),
        n_filled_voxels=int(log["n_filled_voxels"]), n_support_voxels=int(log["n_support_voxels"]),
    )


def _extract_job(job) -> ExtractResult:
    source, out_dir, options = job
    return extract_file(source, out_dir, **options)


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
) -> list[ExtractResult]:
    """Extract the surface of every volume into ``out_dir`` (see :func:`extract_file`).

    Parameters
    ----------
    sources : sequence of path
        Volume files or DICOM / TIFF-slice folders.
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

    Returns
    -------
    list of ExtractResult
        In the order of ``sources``.

    Raises
    ------
    HortishapeError
        With ``strict``, for the first volume that fails; or if two volumes
        share a stem (their outputs would collide).
    ValueError
        If an option is out of range.
    """
    _check_options(smoothing, target_vertices, support_radius)
    out = Path(out_dir)
    paths = [Path(s) for s in sources]
    stems = [volume_stem(p) for p in paths]
    dup = sorted({s for s in stems if stems.count(s) > 1})
    if dup:
        raise HortishapeError(f"several volumes share the name {dup[0]!r}: their outputs would collide")
    out.mkdir(parents=True, exist_ok=True)
    options = {"level": level, "smoothing": smoothing, "target_vertices": target_vertices,
               "remove_support": remove_support, "support_radius": support_radius, "picture": picture,
               "spacing": spacing}
    jobs = [(str(p), str(out), options) for p in paths]
    return run_jobs(_extract_job, jobs, n_jobs=n_jobs, progress=progress, stop=raise_failed if strict else None)
