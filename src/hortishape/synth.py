"""Synthetic fruit and vegetable populations with known correspondence.

Real scans come without ground truth, so hortishape makes its own: every
instance is a smooth, invertible deformation of one *canonical* shape per
product, surfaced the way a CT scan would be (marching cubes on a voxel grid,
50k-150k vertices) and placed in a random scanner pose.

How an instance is made
-----------------------
1. A canonical shape per product is an implicit function ``F(c) < 0`` inside,
   built from smooth signed-distance primitives in *canonical coordinates*:
   millimetres on an average-sized, upright fruit, stalk along ``+z``. A few
   instance features live here (stalk length and bend, cavity depth, number and
   depth of pepper lobes, ribs).
2. A chain of closed-form invertible maps takes canonical coordinates to the
   scanner: taper (top wider or narrower), lean (lopsidedness), per-axis scale
   (the instance's dimensions, spread as in the paper's Table 1), bend (an arc,
   for zucchini, banana and pear necks) and the scanner pose.
3. The scanner-space volume ``F(psi(x))`` is sampled on a voxel grid aligned
   with the scanner axes and surfaced by marching cubes, so the triangulation
   looks like a CT surface and not like the canonical shape's.

The canonical frame is anatomical: ``z`` runs from the blossom end to the
stalk, and ``x`` points to the side every instance leans, bends and bulges to
(its stalk's bend, the fuller cheek of an apple, the largest lobe of a pepper,
the curve of a zucchini, pear neck or banana), each by a random amount. So the
shape itself fixes the turn about the stalk axis, as it must for a
correspondence to be measurable.

Because ``psi`` (scanner to canonical) is exact, every vertex knows its
canonical coordinates: the same canonical point is the same anatomical place
on every instance. :func:`true_correspondence` carries canonical points to any
instance, which is how registration accuracy is measured.

Products: ``apple``, ``pepper`` (bell pepper), ``zucchini`` (dimension means
and spreads from the paper's Table 1), ``pear`` and ``banana`` (curved and not
star-shaped).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ._batch import run_jobs
from ._rng import RandomState, as_generator, spawn_seeds
from .errors import HortishapeError
from .mesh import Mesh
from .surface import (
    barycentric_interpolate,
    closest_points,
    component_labels,
    face_areas,
    rim_edges,
    signed_volume,
    vertex_normals,
)

__all__ = [
    "PRODUCTS",
    "ProductSpec",
    "Deformation",
    "SyntheticInstance",
    "make_instance",
    "make_population",
    "true_correspondence",
    "write_instance",
    "read_truth",
    "write_population",
    "DepthView",
    "depth_view",
    "write_views",
    "Tray",
    "make_tray",
]


# --------------------------------------------------------------------------
# Smooth signed-distance primitives (vectorised over points)
# --------------------------------------------------------------------------


def _smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum: a union with a fillet of size ``k`` mm."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def _smax(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    return -_smin(-a, -b, k)


def _round_cone(p: np.ndarray, a, b, ra: float, rb: float) -> np.ndarray:
    """Exact distance to the convex hull of two spheres (centres a, b; radii ra, rb).

    Works in any dimension: ``p`` is ``(n, d)``.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    ba = b - a
    l2 = float(ba @ ba)
    rr = ra - rb
    a2 = l2 - rr * rr
    il2 = 1.0 / l2
    pa = p - a
    y = pa @ ba
    z = y - l2
    q = pa * l2 - y[:, None] * ba
    x2 = np.einsum("ij,ij->i", q, q)
    y2 = y * y * l2
    z2 = z * z * l2
    k = math.copysign(1.0, rr) * rr * rr * x2
    d_mid = (np.sqrt(np.maximum(x2 * a2 * il2, 0.0)) + y * rr) * il2 - ra
    d_b = np.sqrt(x2 + z2) * il2 - rb
    d_a = np.sqrt(x2 + y2) * il2 - ra
    return np.where(np.sign(z) * a2 * z2 > k, d_b, np.where(np.sign(y) * a2 * y2 < k, d_a, d_mid))


def _chain(p: np.ndarray, centres, radii) -> np.ndarray:
    """Distance to a chain of round cones through ``centres`` with ``radii``."""
    d = None
    for i in range(len(centres) - 1):
        di = _round_cone(p, centres[i], centres[i + 1], radii[i], radii[i + 1])
        d = di if d is None else np.minimum(d, di)
    return d


def _sphere(p: np.ndarray, centre, r: float) -> np.ndarray:
    return np.linalg.norm(p - np.asarray(centre, dtype=float), axis=1) - r


def _ellipsoid(p: np.ndarray, centre, radii) -> np.ndarray:
    """Approximate (bound-corrected) distance to an axis-aligned ellipsoid."""
    q = (p - np.asarray(centre, dtype=float)) / np.asarray(radii, dtype=float)
    k0 = np.linalg.norm(q, axis=1)
    k1 = np.linalg.norm(q / np.asarray(radii, dtype=float), axis=1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def _revolution(p: np.ndarray, modulation: np.ndarray) -> np.ndarray:
    """(rho, z) coordinates with the radius divided by ``1 + modulation``.

    Shapes of revolution are built as 2D profiles; the modulation adds lobes
    and ribs as a function of azimuth and height.
    """
    rho = np.hypot(p[:, 0], p[:, 1]) / (1.0 + modulation)
    return np.column_stack([rho, p[:, 2]])


def _azimuth(p: np.ndarray) -> np.ndarray:
    return np.arctan2(p[:, 1], p[:, 0])


# --------------------------------------------------------------------------
# Canonical shapes
# --------------------------------------------------------------------------

# A canonical shape: parts (name -> implicit function) and a combiner giving
# the whole surface; landmarks are found on the surface along given rays.


@dataclass(frozen=True)
class _Canonical:
    parts: dict[str, Callable[[np.ndarray], np.ndarray]]
    combine: Callable[[dict[str, np.ndarray]], np.ndarray]
    # landmark name -> (ray origin inside the shape, ray direction)
    landmark_rays: dict[str, tuple[np.ndarray, np.ndarray]]
    # parts that belong to the body when measuring dimensions
    body_parts: tuple[str, ...]

    def __call__(self, c: np.ndarray) -> np.ndarray:
        return self.combine({name: f(c) for name, f in self.parts.items()})

    def part_labels(self, c: np.ndarray) -> np.ndarray:
        """Index (into ``parts``) of the part nearest to each point."""
        values = np.stack([f(c) for f in self.parts.values()])
        return np.argmin(values, axis=0).astype(np.uint8)


def _stalk_path(rng: np.random.Generator, base, length: float, bend: float, n: int = 4):
    """Points along a gently bent stalk from ``base`` upwards.

    The stalk bends towards +x (give or take 20 degrees): the canonical frame
    is anatomical, its x axis the side the fruit leans and its stalk bends to.
    """
    az = rng.normal(0.0, math.radians(20.0))
    t = np.linspace(0.0, 1.0, n)
    off = bend * t**2
    return np.column_stack(
        [base[0] + off * math.cos(az), base[1] + off * math.sin(az), base[2] + length * t]
    )


def _calyx(ring: float, z: float, radius: float, phase: float = 0.0):
    """Five sepals: small spheres on a ring about the axis at height ``z``."""
    angles = np.linspace(0, 2 * math.pi, 6)[:5] + phase
    sepals = np.column_stack([ring * np.cos(angles), ring * np.sin(angles), np.full(5, z)])

    def calyx(c):
        return np.min(np.stack([_sphere(c, s, radius) for s in sepals]), axis=0)

    return calyx


def _end_rays(path: np.ndarray, bottom_origin: float, *, tip_back: float = 0.0) -> dict:
    """Landmark rays: along the stalk's last segment, and down the axis at the bottom.

    ``tip_back`` starts the stalk ray that fraction of the last segment
    before its end, inside the stalk.
    """
    direction = path[-1] - path[-2]
    return {
        "stalk_tip": (path[-1] - direction * tip_back, direction / np.linalg.norm(direction)),
        "bottom": (np.array([0.0, 0.0, bottom_origin]), np.array([0.0, 0.0, -1.0])),
    }


def _cavity_floor(shape_parts: Callable[[np.ndarray], np.ndarray], z_hi: float, z_lo: float) -> float:
    """Height where the axis first enters the shape going down from ``z_hi``."""
    z = np.linspace(z_hi, z_lo, 4001)
    p = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    inside = shape_parts(p) < 0
    if not inside.any():  # pragma: no cover - the shapes below always hit
        raise RuntimeError("canonical shape does not cross its axis")
    return float(z[np.argmax(inside)])


def _apple(rng: np.random.Generator, family: str = "standard") -> _Canonical:
    ribs = rng.uniform(0.004, 0.02)
    cheek = rng.uniform(0.02, 0.05)  # the +x cheek is the fuller one
    top_r = rng.uniform(19.0, 24.0)
    top_depth = rng.uniform(10.0, 14.0)
    bot_r = rng.uniform(8.0, 11.0)
    bot_depth = rng.uniform(4.0, 6.5)

    # held-out families: a conical apple narrows to its blossom end; a
    # five-ribbed one (Red Delicious) has strong ribs and five crown bumps
    z_bottom, r_bottom = (-26.0, 18.0) if family == "conical" else (-10.0, 31.0)
    if family == "ribbed":
        ribs = rng.uniform(0.04, 0.07)

    def body(c):
        az = _azimuth(c)
        mod = ribs * np.cos(5 * az) * np.clip((10.0 - c[:, 2]) / 50.0, 0.0, 1.0)
        mod = mod + cheek * np.cos(az) * np.clip((c[:, 2] + 20.0) / 50.0, 0.0, 1.0)
        d = _round_cone(_revolution(c, mod), (0.0, z_bottom), (0.0, 4.0), r_bottom, 39.0)
        d = _smax(d, -_sphere(c, (0, 0, 43.0 + top_r - top_depth), top_r), 9.0)
        return _smax(d, -_sphere(c, (0, 0, -41.0 - bot_r + bot_depth), bot_r), 4.0)

    z_top = _cavity_floor(body, 60.0, 0.0)
    z_bot = -_cavity_floor(lambda c: body(c * np.array([1, 1, -1])), 60.0, 0.0)
    calyx = _calyx(3.2, z_bot + 1.0, 1.6, phase=rng.uniform(0, 1))
    length = rng.uniform(14.0, 22.0)
    if family == "sunk":  # the stalk ends inside its cavity
        length = rng.uniform(0.1, 0.3) * top_depth
    path = _stalk_path(rng, (0.0, 0.0, z_top - 2.5), length + 2.5, rng.uniform(1.0, 4.0))
    if family == "tilted":  # a stalk leaning 25-45 degrees from the axis, towards any side
        tilt, az = rng.uniform(math.radians(25.0), math.radians(45.0)), rng.uniform(0.0, 2.0 * math.pi)
        direction = np.array([math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), math.cos(tilt)])
        path = path[0] + np.linspace(0.0, length + 2.5, len(path))[:, None] * direction
    radii = np.linspace(1.7, 1.35, len(path))

    def stalk(c):
        if family == "stalkless":  # picked off: nothing above the cavity floor
            return np.full(len(c), 1e3)
        d = _chain(c, path, radii)
        return np.minimum(d, _sphere(c, path[-1], 1.75))

    def combine(v):
        return _smin(_smin(v["body"], v["stalk"], 1.5), v["calyx"], 1.0)

    if family == "stalkless":  # the stalk mark is the cavity floor
        path = np.array([[0.0, 0.0, z_top - 6.0], [0.0, 0.0, z_top - 3.0]])

    return _Canonical(
        parts={"body": body, "stalk": stalk, "calyx": calyx},
        combine=combine,
        landmark_rays=_end_rays(path, z_bot + 8.0),
        body_parts=("body", "calyx"),
    )


def _pepper(rng: np.random.Generator, family: str = "standard") -> _Canonical:
    lobes = int(rng.choice([3, 4]))
    lobe_depth = rng.uniform(0.05, 0.10)
    big_lobe = rng.uniform(0.03, 0.06)  # the lobe on +x is the largest
    blockiness = rng.uniform(2.6, 3.4)
    r0, hz = 34.0, 40.0
    top_r, top_depth = rng.uniform(11.0, 15.0), rng.uniform(8.0, 12.0)
    bot_r, bot_depth = rng.uniform(12.0, 16.0), rng.uniform(4.0, 8.0)
    # held-out families: five lobes, or 3-5 lobes of unequal size (two more
    # harmonics at random phases); a conical pepper without its blossom-end
    # dent, narrowing downwards
    uneven, phases = np.zeros(2), np.zeros(2)
    if family == "five-lobed":
        lobes = 5
    elif family == "unequal":
        lobes = int(rng.choice([3, 4, 5]))
        uneven, phases = rng.uniform(0.03, 0.06, 2), rng.uniform(0.0, 2.0 * math.pi, 2)
    if family == "conical":
        bot_depth = -20.0  # the bottom cut sphere clears the body

    def body(c):
        z = c[:, 2]
        # lobe valleys run top to bottom and deepen towards the blossom end
        weight = 0.6 + 0.4 * np.clip(-z / hz, 0.0, 1.0)
        az = _azimuth(c)
        mod = lobe_depth * weight * np.cos(lobes * az) + big_lobe * np.cos(az)
        mod = mod + weight * (uneven[0] * np.cos(2 * az + phases[0]) + uneven[1] * np.cos(3 * az + phases[1]))
        if family == "conical":
            mod = mod - 0.35 * np.clip(-z / hz, 0.0, 1.0) ** 1.5
        rho = np.hypot(c[:, 0], c[:, 1]) / (1.0 + mod)
        n = blockiness
        d = r0 * ((rho / r0) ** n + (np.abs(z) / hz) ** n) ** (1.0 / n) - r0
        d = _smax(d, -_sphere(c, (0, 0, hz + top_r - top_depth), top_r), 6.0)
        return _smax(d, -_sphere(c, (0, 0, -hz - bot_r + bot_depth), bot_r), 6.0)

    z_top = _cavity_floor(body, 60.0, 0.0)
    length = rng.uniform(14.0, 26.0)
    path = _stalk_path(rng, (0.0, 0.0, z_top - 3.0), length + 3.0, rng.uniform(2.0, 8.0))
    r_stalk = rng.uniform(3.3, 4.5)
    radii = np.linspace(r_stalk * 1.15, r_stalk, len(path))

    def stalk(c):
        return _chain(c, path, radii)

    def calyx(c):
        return _ellipsoid(c, (0, 0, z_top + 0.5), (12.0, 12.0, 3.0))

    def combine(v):
        return _smin(_smin(v["body"], v["calyx"], 2.0), v["stalk"], 2.0)

    z_bot = -_cavity_floor(lambda c: body(c * np.array([1, 1, -1])), 60.0, 0.0)
    return _Canonical(
        parts={"body": body, "calyx": calyx, "stalk": stalk},
        combine=combine,
        landmark_rays=_end_rays(path, z_bot + 8.0, tip_back=0.1),
        body_parts=("body", "calyx"),
    )


def _zucchini(rng: np.random.Generator) -> _Canonical:
    ribs = rng.uniform(0.005, 0.02)
    n_ribs = int(rng.choice([5, 6, 8]))
    club = rng.uniform(1.5, 5.0)  # the blossom end is the thicker one
    neck = rng.uniform(24.0, 29.0)
    # the blossom end stays at z = -142 whatever the club: only the width changes
    centres = np.array([[0.0, -107.0 + club], [0.0, 20.0], [0.0, 112.0]])
    radii = np.array([35.0 + club, 33.0, neck])

    def body(c):
        mod = ribs * np.cos(n_ribs * _azimuth(c))
        d = _chain(_revolution(c, mod), centres, radii)
        return np.minimum(d, _sphere(c, (0.0, 0.0, -142.0), 3.5))

    length = rng.uniform(16.0, 30.0)
    r_stalk = rng.uniform(6.5, 8.5)
    path = _stalk_path(rng, (0.0, 0.0, 126.0), length + 13.0, rng.uniform(1.0, 6.0), n=3)

    def stalk(c):
        return _chain(c, path, [r_stalk * 1.5, r_stalk * 1.1, r_stalk])

    def combine(v):
        return _smin(v["body"], v["stalk"], 5.0)

    return _Canonical(
        parts={"body": body, "stalk": stalk},
        combine=combine,
        landmark_rays=_end_rays(path, -120.0, tip_back=0.2),
        body_parts=("body",),
    )


def _pear(rng: np.random.Generator) -> _Canonical:
    neck_shift = rng.uniform(2.0, 7.0)
    neck_r = rng.uniform(10.0, 14.0)
    centres = np.array([[0.0, 0.0, -22.0], [neck_shift * 0.3, 0.0, 10.0], [neck_shift, 0.0, 34.0]])
    radii = np.array([32.0, 22.0, neck_r])
    bot_depth = rng.uniform(2.0, 4.0)

    def body(c):
        d = _chain(c, centres, radii)
        return _smax(d, -_sphere(c, (0, 0, -54.0 - 7.0 + bot_depth), 7.0), 3.0)

    top = centres[-1] + np.array([0.0, 0.0, neck_r])
    length = rng.uniform(22.0, 34.0)
    path = _stalk_path(rng, top - np.array([0.0, 0.0, 3.0]), length + 3.0, rng.uniform(3.0, 9.0))
    radii_s = np.linspace(1.9, 1.4, len(path))

    def stalk(c):
        return np.minimum(_chain(c, path, radii_s), _sphere(c, path[-1], 1.6))

    z_bot = -_cavity_floor(lambda c: body(c * np.array([1, 1, -1])), 70.0, 0.0)
    calyx = _calyx(2.2, z_bot + 0.6, 1.3)

    def combine(v):
        return _smin(_smin(v["body"], v["stalk"], 2.5), v["calyx"], 0.8)

    return _Canonical(
        parts={"body": body, "stalk": stalk, "calyx": calyx},
        combine=combine,
        landmark_rays=_end_rays(path, z_bot + 8.0),
        body_parts=("body", "calyx"),
    )


def _banana(rng: np.random.Generator) -> _Canonical:
    edges = rng.uniform(0.03, 0.07)  # the angular ridges of the peel
    n_edges = int(rng.choice([4, 5]))
    centres = np.array([[0.0, -96.0], [0.0, -72.0], [0.0, 25.0], [0.0, 72.0], [0.0, 92.0]])
    radii = np.array([5.0, 16.0, 18.5, 13.0, 6.5])
    length = rng.uniform(18.0, 30.0)
    r_stalk = rng.uniform(4.5, 6.0)

    def body(c):
        mod = edges * np.cos(n_edges * _azimuth(c))
        return _chain(_revolution(c, mod), centres, radii)

    path = np.array([[0.0, 0.0, 86.0], [0.0, 0.0, 92.0 + length * 0.5], [0.0, 0.0, 92.0 + length]])

    def stalk(c):
        return _chain(c, path, [r_stalk * 1.3, r_stalk, r_stalk * 1.15])

    def combine(v):
        return _smin(v["body"], v["stalk"], 4.0)

    return _Canonical(
        parts={"body": body, "stalk": stalk},
        combine=combine,
        landmark_rays={
            "stalk_tip": (path[-1] - np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, 1.0])),
            "bottom": (np.array([0.0, 0.0, -85.0]), np.array([0.0, 0.0, -1.0])),
        },
        body_parts=("body",),
    )


# --------------------------------------------------------------------------
# Products: dimensions and deformation spreads
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ProductSpec:
    """What a synthetic product looks like and how its instances vary.

    ``dimensions_mm`` and ``dimensions_sd_mm`` are the mean and standard
    deviation of (width, depth, height) of the body (stalk excluded); for the
    apple, pepper and zucchini they are the paper's Table 1. ``correlation``
    couples the three dimensions (size is the main mode of a real population).
    ``bend_mm`` is the mean and spread of the sagitta of the bend over the
    body length (0 for straight products); with ``width_from_bend`` the bend
    is instead solved so the bent body has the sampled width.
    """

    name: str
    description: str
    dimensions_mm: tuple[float, float, float]
    dimensions_sd_mm: tuple[float, float, float]
    correlation: float
    taper_sd: float
    lean_sd: float
    bend_mm: tuple[float, float]
    width_from_bend: bool
    canonical: Callable[..., _Canonical] = field(repr=False)
    families: tuple[str, ...] = ("standard",)


PRODUCTS: dict[str, ProductSpec] = {
    "apple": ProductSpec(
        "apple", "Jonagold-like apple: stalk in its cavity, calyx at the bottom",
        (82.28, 81.81, 84.50), (3.66, 4.18, 4.74), 0.6, 0.06, 0.03, (0.0, 0.0), False, _apple,
        ("standard", "stalkless", "sunk", "tilted", "conical", "ribbed"),
    ),
    "pepper": ProductSpec(
        "pepper", "bell pepper: blocky, 3 or 4 lobes, thick bent stalk on a calyx",
        (69.30, 68.07, 84.23), (11.41, 11.81, 9.72), 0.7, 0.08, 0.03, (0.0, 0.0), False, _pepper,
        ("standard", "five-lobed", "unequal", "conical"),
    ),
    "zucchini": ProductSpec(
        # Table 1's width (83 +/- 13 mm) exceeds the depth (70 +/- 2 mm): the
        # curvature of the fruit adds to the width, so the bend carries it.
        "zucchini", "zucchini: long, slightly curved, club-shaped, with a stalk",
        (83.36, 70.17, 284.04), (13.30, 1.97, 38.71), 0.3, 0.05, 0.0, (0.0, 0.0), True, _zucchini,
    ),
    "pear": ProductSpec(
        "pear", "pear: round bottom, bent neck, long thin stalk (not star-shaped)",
        (64.0, 63.0, 100.0), (4.5, 4.5, 8.0), 0.6, 0.05, 0.04, (4.0, 2.5), False, _pear,
    ),
    "banana": ProductSpec(
        "banana", "banana: strongly curved, angular section, stalk (not star-shaped)",
        (72.0, 36.0, 180.0), (8.0, 3.0, 12.0), 0.5, 0.03, 0.0, (0.0, 0.0), True, _banana,
    ),
}


# --------------------------------------------------------------------------
# The deformation chain: canonical <-> body <-> scanner
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Deformation:
    """Closed-form invertible map from canonical to scanner coordinates.

    ``forward`` applies, in order: taper ``(x, y) *= 1 + taper * z / half_height``,
    lean ``x += lean * z``, scale ``*= scale``, bend (an arc of curvature
    ``curvature`` 1/mm in the x-z plane) and the scanner pose ``pose``
    (4x4, body to scanner). ``inverse`` undoes them exactly.
    """

    taper: float
    half_height: float
    lean: float
    scale: np.ndarray
    curvature: float
    pose: np.ndarray

    def to_body(self, c: np.ndarray) -> np.ndarray:
        c = np.asarray(c, dtype=float)
        x, y, z = c[:, 0], c[:, 1], c[:, 2]
        t = 1.0 + self.taper * z / self.half_height
        x = x * t + self.lean * z
        y = y * t
        p = np.column_stack([x, y, z]) * self.scale
        k = self.curvature
        if abs(k) > 1e-12:
            r = 1.0 / k
            theta = p[:, 2] * k
            px = r - (r - p[:, 0]) * np.cos(theta)
            pz = (r - p[:, 0]) * np.sin(theta)
            p = np.column_stack([px, p[:, 1], pz])
        return p

    def from_body(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        k = self.curvature
        if abs(k) > 1e-12:
            r = 1.0 / k
            u = r - p[:, 0]
            s = math.copysign(1.0, r)
            rho = s * np.hypot(u, p[:, 2])
            theta = np.arctan2(p[:, 2] / rho, u / rho)
            p = np.column_stack([r - rho, p[:, 1], r * theta])
        c = p / self.scale
        z = c[:, 2]
        x = c[:, 0] - self.lean * z
        t = 1.0 + self.taper * z / self.half_height
        return np.column_stack([x / t, c[:, 1] / t, z])

    def forward(self, c: np.ndarray) -> np.ndarray:
        """Canonical ``(n, 3)`` -> scanner ``(n, 3)`` millimetres."""
        b = self.to_body(c)
        return b @ self.pose[:3, :3].T + self.pose[:3, 3]

    def inverse(self, x: np.ndarray) -> np.ndarray:
        """Scanner ``(n, 3)`` millimetres -> canonical ``(n, 3)``."""
        b = (np.asarray(x, dtype=float) - self.pose[:3, 3]) @ self.pose[:3, :3]
        return self.from_body(b)


def _random_pose(rng: np.random.Generator, pose: str) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    if pose == "upright":
        # standing on the scanner bed: any turn about the vertical, a small tilt
        tilt = Rotation.from_rotvec(
            np.array([*rng.normal(size=2), 0.0]) / math.sqrt(2) * np.deg2rad(rng.uniform(0, 8))
        )
        rot = tilt * Rotation.from_euler("z", rng.uniform(-math.pi, math.pi))
    elif pose == "random":
        rot = Rotation.random(random_state=rng)
    elif pose == "canonical":
        rot = Rotation.identity()
    else:
        raise HortishapeError(f"unknown pose {pose!r}: use 'upright', 'random' or 'canonical'")
    m = np.eye(4)
    m[:3, :3] = rot.as_matrix()
    if pose != "canonical":
        m[:3, 3] = rng.uniform(-25.0, 25.0, size=3)
    return m


# --------------------------------------------------------------------------
# Instances
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SyntheticInstance:
    """One synthetic scan with its ground truth.

    Attributes
    ----------
    name : str
        ``"<product>_<index>"``, e.g. ``"apple_007"``.
    product : str
    mesh : Mesh
        The scan surface in scanner coordinates (mm).
    canonical : (n, 3) float64 ndarray
        Canonical coordinates (mm, average upright fruit) of every vertex.
    parts : (n,) uint8 ndarray
        Index into ``part_names`` of every vertex (body, stalk, calyx).
    part_names : tuple of str
    landmarks : dict of str to (3,) ndarray
        ``"stalk_tip"`` and ``"bottom"`` in scanner coordinates (mm).
    landmarks_canonical : dict of str to (3,) ndarray
    pose : (4, 4) float64 ndarray
        Rigid transform from the body frame (stalk along +z) to the scanner.
    dimensions : (3,) float64 ndarray
        Width, depth and height of the body (stalk excluded) in its frame, mm.
    deformation : Deformation
        The exact canonical -> scanner map.
    voxel_size : float
        Edge of the voxel grid the surface was extracted from, mm.
    volume : Volume or None
        A CT-like intensity volume (``make_instance(..., volume=True)``).
    mri_volume : Volume or None
        An MRI-like intensity volume of the same instance (also with
        ``volume=True``): see :func:`make_instance`.
    """

    name: str
    product: str
    mesh: Mesh
    canonical: np.ndarray
    parts: np.ndarray
    part_names: tuple[str, ...]
    landmarks: dict
    landmarks_canonical: dict
    pose: np.ndarray
    dimensions: np.ndarray
    deformation: Deformation
    voxel_size: float
    volume: object = None
    mri_volume: object = None


def _surface_point_on_ray(f, origin: np.ndarray, direction: np.ndarray, length: float = 80.0) -> np.ndarray:
    """First point where ``f`` turns positive along a ray from an inside point."""
    t = np.linspace(0.0, length, 8001)
    p = origin[None, :] + t[:, None] * direction[None, :]
    v = f(p)
    if v[0] >= 0:  # pragma: no cover - the rays above start inside
        raise RuntimeError("landmark ray does not start inside the shape")
    i = int(np.argmax(v >= 0))
    lo, hi = t[i - 1], t[i]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if f((origin + mid * direction)[None, :])[0] < 0:
            lo = mid
        else:
            hi = mid
    return origin + 0.5 * (lo + hi) * direction


def _coarse_surface(f, lo, hi, step: float):
    from skimage.measure import marching_cubes

    axes = [np.arange(lo[i], hi[i] + step, step) for i in range(3)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    vol = f(g).reshape(tuple(len(a) for a in axes))
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(step, step, step))
    return verts + np.asarray(lo), faces


def _canonical_surface(canon: _Canonical) -> tuple[np.ndarray, np.ndarray]:
    """A coarse (2 mm) mesh of the canonical shape, for sizes and bounds."""
    verts, _ = _coarse_surface(canon, (-160.0,) * 3, (160.0,) * 3, 6.0)
    return _coarse_surface(canon, verts.min(axis=0) - 8.0, verts.max(axis=0) + 8.0, 2.0)


def _fit_size(body_points, taper, half_height, lean, target, sagitta, *, width_from_bend):
    """Per-axis scale and bend curvature that give the body the target dimensions.

    For products whose width comes from their curvature (zucchini, banana) the
    cross-section keeps its canonical proportions and the bend is solved so the
    bent body is as wide as the target; otherwise ``sagitta`` (mm over the body
    length) sets the bend and the scale fits all three dimensions.
    """

    # extents only need the outline: a few thousand points keep the many
    # evaluations of the bisection cheap
    body_points = body_points[:: max(1, len(body_points) // 4000)]

    def extent(scale, curvature):
        d = Deformation(taper, half_height, lean, scale, curvature, np.eye(4))
        return np.ptp(d.to_body(body_points), axis=0)

    straight = extent(np.ones(3), 0.0)
    scale = target / straight
    if width_from_bend:
        scale[0] = scale[1]  # a round cross-section; the bend makes the width
    side = math.copysign(1.0, sagitta) if sagitta else 1.0
    # a sagitta s over the chord c is a curvature 8 s / (c^2 + 4 s^2)
    curvature = side * 8.0 * abs(sagitta) / (target[2] ** 2 + 4 * sagitta**2)
    for _ in range(8):  # the bend shortens the chord: refit the height
        if width_from_bend and extent(scale, 0.0)[0] < target[0]:
            # the width grows with the curvature up to a half circle of the body length
            lo, hi = 0.0, math.pi / (straight[2] * scale[2])
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if extent(scale, side * mid)[0] < target[0] else (lo, mid)
            curvature = side * lo
        ext = extent(scale, curvature)
        if np.abs(ext - target).max() < 0.01:
            break
        scale[2] *= target[2] / ext[2]
        if not width_from_bend:
            scale[:2] *= target[:2] / ext[:2]
    return scale, curvature


#: Products whose two equal-variance axes of the dimensions come in the other order (see
#: :func:`_sample_dimensions`).
_SWAPPED_SHAPE_AXES = frozenset({"pepper"})


def _sample_dimensions(spec: ProductSpec, rng: np.random.Generator) -> np.ndarray:
    # Correlated normal dimensions, z = L e with L L^T = (1 - rho) I + rho 11^T. That matrix has a
    # repeated eigenvalue: numpy's multivariate_normal took L from an SVD, whose basis of the
    # repeated eigenspace is whatever LAPACK's kernel for the CPU returns (another on an AMD EPYC
    # than on an AVX-512 Xeon), so the same seed gave other fruit on another CPU. The basis is
    # written out instead: the common size (1, 1, 1) and two shape axes, in the order (and with
    # the signs) that the populations hortishape was tuned and measured on were drawn with.
    rho = spec.correlation
    common = -np.ones(3) / math.sqrt(3.0)
    across = np.array([0.0, -1.0, 1.0]) / math.sqrt(2.0)
    along = np.array([2.0, -1.0, -1.0]) / math.sqrt(6.0)
    shape_axes = [along, across] if spec.name in _SWAPPED_SHAPE_AXES else [across, along]
    factor = np.column_stack([common, *shape_axes]) * np.sqrt([1.0 + 2.0 * rho, 1.0 - rho, 1.0 - rho])
    z = factor @ rng.standard_normal(3)
    z = np.clip(z, -2.5, 2.5)  # no freaks: real populations are graded
    return np.asarray(spec.dimensions_mm) + z * np.asarray(spec.dimensions_sd_mm)


def _band_volume(f, origin: np.ndarray, shape: tuple[int, int, int], h: float, full: bool) -> np.ndarray:
    """Sample ``f`` on a grid, exactly only near its zero level set.

    The grid is first sampled every 4th voxel; blocks whose corners are all far
    from the surface (farther than ``f`` can change inside a block) take the
    sign of their corners, the others are sampled exactly. Marching cubes only
    needs exact values on edges that cross the surface, so the result is the
    same as a full sampling at a quarter of the cost.
    """

    def sample(idx: np.ndarray) -> np.ndarray:
        return f(origin + idx * h)

    nx, ny, nz = shape
    if full:
        ii = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1)
        return sample(ii.reshape(-1, 3).astype(float)).reshape(shape)
    b = 4
    m = [(n - 1) // b for n in shape]
    ci = np.stack(np.meshgrid(*[np.arange(k + 1) * b for k in m], indexing="ij"), -1)
    coarse = sample(ci.reshape(-1, 3).astype(float)).reshape(tuple(k + 1 for k in m))
    corners = np.stack(
        [coarse[i : i + m[0], j : j + m[1], k : k + m[2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    )
    # |grad f| <= ~1.6 in scanner mm (distance-like primitives under mild scaling)
    margin = 1.6 * b * h * math.sqrt(3.0) + 2 * h
    near = (np.abs(corners).min(axis=0) < margin) | (np.sign(corners).min(axis=0) != np.sign(corners).max(axis=0))
    fill = np.where(corners.mean(axis=0) < 0, -margin, margin)
    grid = np.repeat(np.repeat(np.repeat(fill, b, 0), b, 1), b, 2)
    mask = np.repeat(np.repeat(np.repeat(near, b, 0), b, 1), b, 2)
    # the grid is (b*m + 1) long: the last layer belongs to the last block
    grid = np.pad(grid, [(0, 1)] * 3, mode="edge")
    mask = np.pad(mask, [(0, 1)] * 3, mode="edge")
    idx = np.argwhere(mask)
    grid[mask] = sample(idx.astype(float))
    return grid


#: Folder of the MRI-like volumes beside ``volumes/`` (their own, so that
#: ``build`` on ``volumes/`` takes each instance once).
MRI_FOLDER = "volumes-mri"

#: The fewest vertices :func:`make_instance` makes a scan of.
MIN_VERTICES = 1000

#: A thin part (a stalk at a coarse voxel size) can fall apart into pieces
#: in marching cubes: the grid is made finer by this factor, up to
#: ``REFINE_STEPS`` times, until the surface is one piece; if it never is,
#: the largest piece is kept.
REFINE_FACTOR = 0.75
REFINE_STEPS = 4


def _one_surface(field_at, points, h: float, *, full: bool):
    """Marching cubes of ``field_at`` around ``points``: one closed component, always.

    Returns the grid, its origin and voxel size, and the surface's vertices
    (scanner mm) and faces.
    """
    from skimage.measure import marching_cubes

    from .surface import component_labels

    for step in range(REFINE_STEPS + 1):
        lo = points.min(axis=0) - 4 * h - 3.0
        hi = points.max(axis=0) + 4 * h + 3.0
        shape = tuple(int(4 * math.ceil((hi[i] - lo[i]) / h / 4)) + 1 for i in range(3))
        grid = _band_volume(field_at, lo, shape, h, full=full)
        verts, faces, _, _ = marching_cubes(grid, 0.0, spacing=(h, h, h), allow_degenerate=True)
        faces = faces.astype(np.int64)
        n_comp, labels = component_labels(faces, len(verts))
        if n_comp == 1:
            break
        if step < REFINE_STEPS:
            h *= REFINE_FACTOR
    if n_comp > 1:
        keep = labels == np.argmax(np.bincount(labels))
        new_index = np.cumsum(keep) - 1
        faces = new_index[faces[keep[faces[:, 0]]]]
        verts = verts[keep]
    return grid, lo, h, verts + lo, faces


def make_instance(
    product: str,
    *,
    random_state: RandomState = None,
    pose: str = "upright",
    noise: float = 0.0,
    n_vertices: int | None = None,
    volume: bool = False,
    name: str | None = None,
    family: str = "standard",
    holes: float = 0.0,
) -> SyntheticInstance:
    """Make one synthetic scan of ``product`` with its ground truth.

    Parameters
    ----------
    product : {"apple", "pepper", "zucchini", "pear", "banana"}
    random_state : int, Generator, SeedSequence or None, default: None
        Seed; the same seed gives the same instance.
    pose : {"upright", "random", "canonical"}, default: "upright"
        Scanner pose: standing (random turn about the vertical, tilt up to 8
        degrees), any rotation, or none (body frame = scanner frame).
    noise : float, default: 0.0
        Standard deviation (mm) of Gaussian scanner noise added to the vertices
        along their normals. Ground truth is that of the noise-free surface.
    n_vertices : int, optional
        About how many vertices the scan should have (the voxel size is chosen
        for it), at least ``MIN_VERTICES``. Default: drawn between 70,000 and
        130,000. The surface is always one closed piece: where a thin stalk
        would come apart at that voxel size, the grid is made finer, so a
        small count can come out larger (up to about 6 times at 1,000).
    volume : bool, default: False
        Also return a CT-like intensity volume (``instance.volume``: flesh
        brighter than air, hollow peppers, apples with a darker core) and an
        MRI-like one (``instance.mri_volume``: a thin bright peel over a dark
        rind, flesh in segments with dark gaps, a core open to the blossom
        end, slices twice as thick as the pixels, 8-bit). Their outer
        surface is the instance's surface.
    name : str, optional
        Default ``"<product>"``.
    family : str, default: "standard"
        A shape family of the product (``PRODUCTS[product].families``). The
        standard ones are what hortishape was tuned on; the others are held
        out for testing it: apples ``"stalkless"`` (picked off; the stalk
        mark is the cavity floor), ``"sunk"`` (a stalk ending inside its
        cavity), ``"tilted"`` (leaning 25-45 degrees to any side),
        ``"conical"`` (narrowing to the blossom end), ``"ribbed"`` (five
        strong ribs); peppers ``"five-lobed"``, ``"unequal"`` (3-5 lobes of
        unequal size), ``"conical"`` (pointed, without the blossom-end dent).
    holes : float, default: 0.0
        Share of the surface cut away in one to three round holes at random
        places, as a structured-light scan misses where the scanner did not
        see (0: a closed surface). The truth (``canonical``, the landmarks)
        is that of the surface that is left; the volumes are of the whole
        fruit.

    Returns
    -------
    SyntheticInstance

    Examples
    --------
    >>> inst = make_instance("apple", random_state=0, n_vertices=20000)
    >>> inst.mesh.n_vertices > 10000, sorted(inst.landmarks)
    (True, ['bottom', 'stalk_tip'])
    """
    if product not in PRODUCTS:
        raise HortishapeError(f"unknown product {product!r}: choose from {', '.join(PRODUCTS)}")
    if noise < 0 or not math.isfinite(noise):
        raise HortishapeError(f"noise must be a non-negative number of millimetres, got {noise}")
    if not 0.0 <= holes < 0.5:
        raise HortishapeError(f"holes must be a share of the surface from 0 to 0.5, got {holes}")
    if n_vertices is not None and not n_vertices >= MIN_VERTICES:
        raise HortishapeError(f"n_vertices must be at least {MIN_VERTICES:,}, got {n_vertices}")
    spec = PRODUCTS[product]
    if family not in spec.families:
        raise HortishapeError(f"{product} has no family {family!r}: choose from {', '.join(spec.families)}")
    rng = as_generator(random_state)
    canon = spec.canonical(rng) if family == "standard" else spec.canonical(rng, family)

    # Canonical extent of the body (stalk excluded), to scale to the sampled size.
    c_verts, c_faces = _canonical_surface(canon)
    labels = canon.part_labels(c_verts)
    body_idx = [list(canon.parts).index(p) for p in canon.body_parts]
    body = np.isin(labels, body_idx)
    body_z = c_verts[body, 2]
    half_height = 0.5 * float(body_z.max() - body_z.min())

    target = _sample_dimensions(spec, rng)
    taper = float(np.clip(rng.normal(0.0, spec.taper_sd), -2.5 * spec.taper_sd, 2.5 * spec.taper_sd))
    lean = abs(float(rng.normal(0.0, spec.lean_sd))) if spec.lean_sd else 0.0  # towards +x
    # bends curve the body's ends towards +x, like the lean and the stalk
    sagitta = max(float(rng.normal(*spec.bend_mm)), 0.0) if spec.bend_mm[0] > 0 else 0.0
    scale, curvature = _fit_size(c_verts[body], taper, half_height, lean, target, sagitta,
                                 width_from_bend=spec.width_from_bend)
    pose_m = _random_pose(rng, pose)
    deform = Deformation(taper, half_height, lean, scale, curvature, pose_m)

    # Voxel size from the surface area (of the coarse mesh, which cuts corners):
    # marching cubes gives about 1.48 vertices per h^2 of it (measured over the
    # five products: 0.96-1.03 times the count asked for).
    scan_area = float(face_areas(deform.to_body(c_verts), c_faces).sum())
    n_target = int(n_vertices) if n_vertices else int(rng.uniform(70_000, 130_000))
    h = math.sqrt(1.48 * scan_area / n_target)

    # Scanner grid around the instance. The coarse canonical mesh can miss the
    # tip of a thin stalk, so the landmarks and a few millimetres are added.
    lm_canon = {k: _surface_point_on_ray(canon, o, d) for k, (o, d) in canon.landmark_rays.items()}
    s_verts = deform.forward(np.vstack([c_verts, *lm_canon.values()]))

    def field_at(x):
        return canon(deform.inverse(x))

    grid, lo, h, verts, faces = _one_surface(field_at, s_verts, h, full=volume)
    if signed_volume(verts, faces) < 0:  # outward normals
        faces = faces[:, ::-1].copy()

    canonical = deform.inverse(verts)
    parts = canon.part_labels(canonical)
    if noise > 0:
        normals = vertex_normals(verts, faces)
        verts = verts + normals * rng.normal(0.0, noise, size=(len(verts), 1))

    lm = {k: deform.forward(v[None, :])[0] for k, v in lm_canon.items()}
    body_v = np.isin(parts, body_idx)
    dims = np.ptp(deform.to_body(canonical[body_v]), axis=0)

    vol = _ct_volume(grid, lo, h, canon, deform, product, rng) if volume else None
    # after the CT volume, so that the CT volume and everything before are as without it
    mri = _mri_volume(grid, lo, h, deform, lm_canon["bottom"], rng) if volume else None
    if holes > 0:  # last, so that everything before is as without holes
        kept, faces = _cut_holes(verts, faces, holes, rng)
        verts, canonical, parts = verts[kept], canonical[kept], parts[kept]
    return SyntheticInstance(
        name=name or product,
        product=product,
        mesh=Mesh(verts, faces),
        canonical=canonical,
        parts=parts,
        part_names=tuple(canon.parts),
        landmarks=lm,
        landmarks_canonical=lm_canon,
        pose=pose_m,
        dimensions=dims,
        deformation=deform,
        voxel_size=h,
        volume=vol,
        mri_volume=mri,
    )


def _cut_holes(verts: np.ndarray, faces: np.ndarray, share: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Cut ``share`` of the surface away in 1-3 round holes; returns the vertices kept and the new faces.

    Each hole takes the faces nearest a random point of the surface until it
    holds its part of the share. The largest piece left is kept (a hole can
    cut a stalk off), and faces at a vertex where two holes touch go too, so
    that every rim is a simple loop.
    """
    area = face_areas(verts, faces)
    centres = verts[faces].mean(axis=1)
    n_holes = int(rng.integers(1, 4))
    drop = np.zeros(len(faces), dtype=bool)
    for point in centres[rng.choice(len(faces), n_holes, p=area / area.sum())]:
        order = np.argsort(np.linalg.norm(centres - point, axis=1))
        drop[order[: int(np.searchsorted(np.cumsum(area[order]), share / n_holes * area.sum())) + 1]] = True
    f = faces[~drop]
    n = len(verts)
    for _ in range(20):
        starts, counts = np.unique(rim_edges(f, n)[0], return_counts=True)
        touching = starts[counts > 1]
        if len(touching) == 0:
            break
        f = f[~np.isin(f, touching).any(axis=1)]
    # the vertices the holes took count as components of their own: the largest among the used ones
    _, labels = component_labels(f, n)
    f = f[labels[f[:, 0]] == np.bincount(labels[np.unique(f)]).argmax()]
    used = np.zeros(n, dtype=bool)
    used[f.ravel()] = True
    index = np.full(n, -1, dtype=np.int64)
    index[used] = np.arange(int(used.sum()))
    return used, index[f]


def _ct_volume(grid, origin, h, canon, deform, product, rng):
    """A CT-like volume: flesh, air, blur and noise on the scan grid.

    The intensity is an analytic partial-volume edge (an error function of the
    distance to the surface, 0.7 voxel wide), so the half-way iso-level lies on
    the true surface; peppers are hollow (6 mm wall) and apples have a
    lower-density core.
    """
    from scipy.special import erf

    from .io import Volume

    g = np.gradient(grid, h)
    gn = np.sqrt(g[0] ** 2 + g[1] ** 2 + g[2] ** 2)
    dist = grid / np.maximum(gn, 1e-6)  # signed distance (mm), negative inside
    sigma = 0.7 * h
    flesh = 0.5 * (1.0 - erf(dist / (sigma * math.sqrt(2.0))))
    density = np.full(grid.shape, 1000.0)
    if product in ("pepper", "apple"):
        idx = np.argwhere(grid < -3.0)
        c = deform.inverse(origin + idx * h)
        if product == "pepper":
            # hollow: air wherever the body is more than the wall thickness deep,
            # with the same partial-volume edge as the outside
            body = canon.part_labels(c) == list(canon.parts).index("body")
            deep = dist[tuple(idx.T)] + 6.0
            air = 0.5 * (1.0 - erf(deep / (sigma * math.sqrt(2.0))))
            density[tuple(idx[body].T)] = 1000.0 * (1.0 - air[body])
        else:
            core = np.hypot(c[:, 0], c[:, 1]) ** 2 / 12.0**2 + c[:, 2] ** 2 / 22.0**2 < 1.0
            density[tuple(idx[core].T)] = 700.0
    values = flesh * density + rng.normal(0.0, 25.0, size=grid.shape)
    values = np.clip(values, -1000, 3000).astype(np.int16)
    return Volume(values, spacing=np.full(3, h), origin=origin, direction=np.eye(3))


def _smooth_step(x: np.ndarray, sigma: float) -> np.ndarray:
    """1 where ``x`` is well below 0, 0 well above: a partial-volume edge of width ``sigma``."""
    from scipy.special import erf

    return 0.5 * (1.0 - erf(x / (sigma * math.sqrt(2.0))))


def _mri_volume(grid, origin, h, deform, bottom, rng):
    """An MRI-like volume: a bright peel over a dark rind, bright flesh in segments, an open core.

    What makes real MRI of fruit hard for an iso-surface, on the instance's
    shape (the outer surface is the instance's surface):

    - a thin bright **peel** (1-2 mm) that is darker than the flesh, over a
      dark **rind** (2.5-4.5 mm), so the strongest edge is the flesh's, inside;
    - **flesh in segments** (8-12 wedges about the fruit's axis) with dark
      gaps between them;
    - a dark **central cavity** that opens to the outside through a channel
      (1.6-3 mm wide) to the blossom end, through rind and peel;
    - 8-bit intensities with Rician noise (background about 2), and slices
      twice as thick as the in-plane pixels, averaged over their thickness.

    Intensities are drawn per instance: peel 30-50, rind 6-14, flesh 65-95.
    """
    from .io import Volume

    g = np.gradient(grid, h)
    gn = np.sqrt(g[0] ** 2 + g[1] ** 2 + g[2] ** 2)
    dist = grid / np.maximum(gn, 1e-6)  # signed distance (mm), negative inside
    del g, gn
    sigma = 0.7 * h
    peel_mm, rind_mm = rng.uniform(1.0, 2.0), rng.uniform(2.5, 4.5)
    peel, rind, flesh = rng.uniform(30, 50), rng.uniform(6, 14), rng.uniform(65, 95)
    n_segments = int(rng.integers(8, 13))
    phase = rng.uniform(0.0, 2.0 * math.pi)
    gap_mm = rng.uniform(0.3, 0.6)  # half-width of the dark gaps between segments
    cavity_mm = rng.uniform(3.0, 5.0)
    channel_mm = rng.uniform(0.8, 1.5)  # radius
    cavity_value = 4.0

    values = np.zeros(grid.shape)
    near = dist < 2.0
    idx = np.argwhere(near)
    d = dist[near]
    c = deform.inverse(origin + idx * h)  # canonical: the fruit's axis is z
    layered = (peel * _smooth_step(d, sigma) + (rind - peel) * _smooth_step(d + peel_mm, sigma))
    # segments: wedges about the axis, dark within gap_mm of the planes between them
    r_axis = np.hypot(c[:, 0], c[:, 1])
    theta = np.arctan2(c[:, 1], c[:, 0]) - phase
    period = 2.0 * math.pi / n_segments
    across = r_axis * np.abs((theta + 0.5 * period) % period - 0.5 * period)  # mm to the nearest gap plane
    segmented = rind + (flesh - rind) * (1.0 - _smooth_step(across - gap_mm, sigma))
    layered += (segmented - rind) * _smooth_step(d + peel_mm + rind_mm, sigma)
    # the core and its channel towards the blossom end, open through rind and peel
    axis = np.asarray(bottom, dtype=float) / max(float(np.linalg.norm(bottom)), 1e-9)
    t = c @ axis
    off_axis = np.linalg.norm(c - t[:, None] * axis, axis=1)
    core = np.sqrt(off_axis**2 + (t / 2.5) ** 2) - cavity_mm
    channel = np.where(t > 0, off_axis - channel_mm, np.inf)
    dark = np.maximum(_smooth_step(core, sigma), _smooth_step(channel, sigma))
    values[near] = layered * (1.0 - dark) + cavity_value * dark * (d < 0)
    del idx, d, c, layered, segmented, near
    # slices of two pixels' thickness along the last axis, averaged
    nz = values.shape[2] // 2 * 2
    values = 0.5 * (values[:, :, 0:nz:2] + values[:, :, 1:nz:2])
    noise = 2.0
    values = np.hypot(values + rng.normal(0.0, noise, values.shape), rng.normal(0.0, noise, values.shape))
    data = np.clip(np.rint(values), 0, 255).astype(np.uint8)
    spacing = np.array([h, h, 2.0 * h])
    return Volume(data, spacing=spacing, origin=np.asarray(origin) + np.array([0.0, 0.0, 0.5 * h]),
                  direction=np.eye(3))


# --------------------------------------------------------------------------
# Ground-truth correspondence
# --------------------------------------------------------------------------


def true_correspondence(canonical_points, instance: SyntheticInstance) -> np.ndarray:
    """Where canonical points lie on ``instance``, in its scanner coordinates (mm).

    Each canonical point is matched to the closest point of the instance's
    surface in canonical space; its barycentric coordinates then give the
    position on the scan. Where the instance has the point's canonical shape
    exactly, this is the exact ground truth; where instance features differ
    (a longer stalk, four lobes instead of three) it is the nearest anatomical
    place.

    Parameters
    ----------
    canonical_points : (k, 3) array_like of float
    instance : SyntheticInstance

    Returns
    -------
    (k, 3) float64 ndarray

    Examples
    --------
    >>> a = make_instance("apple", random_state=1, n_vertices=20000)
    >>> b = make_instance("apple", random_state=2, n_vertices=20000)
    >>> true_correspondence(a.landmarks_canonical["bottom"][None], b).shape
    (1, 3)
    """
    faces = instance.mesh.faces
    cp = closest_points(Mesh(instance.canonical, faces), np.asarray(canonical_points, dtype=float).reshape(-1, 3))
    return barycentric_interpolate(instance.mesh.vertices, faces, cp.face_index, cp.barycentric)


# --------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------


def _truth_paths(mesh_path: Path) -> tuple[Path, Path]:
    stem = mesh_path.with_suffix("")
    return stem.with_name(stem.name + ".truth.json"), stem.with_name(stem.name + ".truth.npz")


def write_instance(instance: SyntheticInstance, out_dir, *, random_seed: int | None = None) -> Path:
    """Write an instance: ``<name>.ply`` and its ground truth beside it.

    Files: ``<name>.ply`` (binary PLY, scanner coordinates, mm),
    ``<name>.truth.json`` (product, pose, landmarks in scanner and canonical
    coordinates, dimensions, voxel size, deformation parameters),
    ``<name>.truth.npz`` (``canonical`` (n, 3) float32 and ``parts`` (n,)
    uint8, in vertex order) and, if the instance has them,
    ``volumes/<name>.mha`` (CT-like) and ``volumes-mri/<name>.mha``
    (MRI-like). Every file is written atomically.

    Returns
    -------
    pathlib.Path
        The mesh file.

    Examples
    --------
    >>> import tempfile
    >>> apple = make_instance("apple", random_state=1, n_vertices=3000)
    >>> path = write_instance(apple, tempfile.mkdtemp())
    >>> path.name, sorted(p.name for p in path.parent.iterdir())
    ('apple.ply', ['apple.ply', 'apple.truth.json', 'apple.truth.npz'])
    """
    from ._files import atomic_path
    from .io import write_mesh, write_volume

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mesh_path = out / f"{instance.name}.ply"
    json_path, npz_path = _truth_paths(mesh_path)
    write_mesh(mesh_path, instance.mesh)
    d = instance.deformation
    truth = {
        "product": instance.product,
        "name": instance.name,
        "seed": random_seed,
        "units": "mm",
        "n_vertices": instance.mesh.n_vertices,
        "voxel_size_mm": instance.voxel_size,
        "dimensions_mm": {"width": float(instance.dimensions[0]), "depth": float(instance.dimensions[1]),
                          "height": float(instance.dimensions[2])},
        "pose": instance.pose.tolist(),
        "landmarks": {k: v.tolist() for k, v in instance.landmarks.items()},
        "landmarks_canonical": {k: v.tolist() for k, v in instance.landmarks_canonical.items()},
        "part_names": list(instance.part_names),
        "deformation": {"taper": d.taper, "half_height_mm": d.half_height, "lean": d.lean,
                        "scale": d.scale.tolist(), "curvature_per_mm": d.curvature},
        "arrays": npz_path.name,
    }
    with atomic_path(json_path, HortishapeError) as tmp:
        tmp.write_text(json.dumps(truth, indent=2), encoding="utf-8")
    with atomic_path(npz_path, HortishapeError) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, canonical=instance.canonical.astype(np.float32), parts=instance.parts)
    for folder, vol in (("volumes", instance.volume), (MRI_FOLDER, instance.mri_volume)):
        if vol is not None:
            (out / folder).mkdir(exist_ok=True)
            write_volume(out / folder / f"{instance.name}.mha", vol)
    return mesh_path


@dataclass(frozen=True, eq=False)
class DepthView:
    """What a depth camera sees of a surface: the visible points, their normals, the viewing direction.

    Attributes
    ----------
    points : (k, 3) float64 ndarray
        First hits of a square grid of parallel rays, with depth noise, mm.
    normals : (k, 3) float64 ndarray
        Outward normals of the surface at the hits (without noise).
    direction : (3,) float64 ndarray
        Where the camera looks (from the camera towards the fruit), unit length.
    """

    points: np.ndarray
    normals: np.ndarray
    direction: np.ndarray


def depth_view(mesh: Mesh, direction, *, pitch: float = 1.0, noise: float = 0.2,
               random_state: RandomState = None) -> DepthView:
    """The points a depth camera looking along ``direction`` sees of a closed surface.

    An orthographic camera: a square grid of parallel rays ``pitch`` mm
    apart covers the surface's outline; each ray's first hit is a point
    (the surface behind it is hidden, as a camera sees it), moved along the
    ray by normal noise of standard deviation ``noise`` mm (a depth
    sensor's error is in depth).

    Parameters
    ----------
    mesh : Mesh
        A closed surface, mm.
    direction : (3,) array_like of float
        Viewing direction, from the camera towards the surface.
    pitch : float, default: 1.0
        Spacing of the rays, mm.
    noise : float, default: 0.2
        Depth noise, standard deviation in mm.
    random_state : int, Generator, SeedSequence or None
        For the noise.

    Returns
    -------
    DepthView

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
    >>> view = depth_view(Mesh(s.vertices, s.faces), [0, 0, -1], noise=0.0)   # seen from above
    >>> bool(view.points[:, 2].min() > -1e-6)                  # the top half only
    True
    >>> bool(abs(len(view.points) - np.pi * 40.0**2) < 50)    # one point per mm^2 of the outline
    True
    """
    from .registration.correspondences import RayScene

    d = np.asarray(direction, dtype=np.float64)
    if d.shape != (3,) or not np.isfinite(d).all() or not np.linalg.norm(d) > 0:
        raise HortishapeError(f"direction must be a non-zero 3-vector, got {direction!r}")
    if not pitch > 0 or not noise >= 0:
        raise HortishapeError(f"pitch must be positive and noise non-negative, got {pitch!r} and {noise!r}")
    d = d / np.linalg.norm(d)
    u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(d, u)
    v = mesh.vertices
    centre = v.mean(axis=0)
    a, b, depth = (v - centre) @ u, (v - centre) @ w, (v - centre) @ d
    ga = np.arange(a.min() - pitch, a.max() + pitch, pitch)
    gb = np.arange(b.min() - pitch, b.max() + pitch, pitch)
    aa, bb = (g.ravel() for g in np.meshgrid(ga, gb, indexing="ij"))
    origins = centre + (depth.min() - 10.0) * d + aa[:, None] * u + bb[:, None] * w
    face, t, _ = RayScene(v, mesh.faces).first_hit(origins, np.broadcast_to(d, origins.shape))
    hit = face >= 0
    rng = as_generator(random_state)
    points = origins[hit] + (t[hit] + rng.normal(0.0, noise, hit.sum()) if noise > 0 else t[hit])[:, None] * d
    from .surface import face_normals

    normals = face_normals(v, mesh.faces)[face[hit]]
    return DepthView(points, normals, d)


def write_views(mesh_path, n_views: int, *, pitch: float = 1.0, noise: float = 0.2,
                random_state: RandomState = None) -> list[Path]:
    """Write ``n_views`` depth views of a synthetic scan: ``views/<name>.view<j>.ply`` beside it.

    Each view looks at the fruit from a random direction (uniform on the
    sphere); the points carry their normals (``nx``, ``ny``, ``nz``), and
    ``views/<name>.views.json`` lists the directions, the pitch and the
    noise. (In a folder of their own, as the volumes are, so that ``build``
    on the scans' folder does not take them for scans.)

    Returns
    -------
    list of pathlib.Path
        The point-cloud files.

    Examples
    --------
    >>> import tempfile
    >>> path = write_instance(make_instance("apple", random_state=1, n_vertices=3000), tempfile.mkdtemp())
    >>> [p.name for p in write_views(path, 2, random_state=0)]
    ['apple.view0.ply', 'apple.view1.ply']
    """
    from ._files import atomic_text
    from .io import read_mesh, write_points

    mesh_path = Path(mesh_path)
    mesh = read_mesh(mesh_path)
    rng = as_generator(random_state)
    stem = mesh_path.name[: -len(mesh_path.suffix)]
    folder = mesh_path.parent / "views"
    folder.mkdir(exist_ok=True)
    paths, directions = [], []
    for j in range(n_views):
        direction = rng.normal(size=3)
        view = depth_view(mesh, direction, pitch=pitch, noise=noise, random_state=rng)
        paths.append(write_points(folder / f"{stem}.view{j}.ply", view.points, normals=view.normals))
        directions.append(view.direction.tolist())
    atomic_text(folder / f"{stem}.views.json", json.dumps(
        {"scan": mesh_path.name, "pitch_mm": pitch, "noise_mm": noise, "directions": directions,
         "files": [p.name for p in paths]}, indent=1), HortishapeError)
    return paths


def read_truth(mesh_path) -> dict:
    """Read the ground truth written beside a synthetic mesh.

    Returns the JSON content with ``canonical`` ((n, 3) float64) and ``parts``
    added, and ``landmarks`` as arrays.

    Raises
    ------
    HortishapeError
        If the ground-truth files are missing.

    Examples
    --------
    >>> import tempfile
    >>> apple = make_instance("apple", random_state=1, n_vertices=3000)
    >>> truth = read_truth(write_instance(apple, tempfile.mkdtemp()))
    >>> sorted(truth["landmarks"]), truth["canonical"].shape == apple.mesh.vertices.shape
    (['bottom', 'stalk_tip'], True)
    """
    json_path, npz_path = _truth_paths(Path(mesh_path))
    if not json_path.is_file() or not npz_path.is_file():
        raise HortishapeError(f"{mesh_path}: no ground truth beside it ({json_path.name}, {npz_path.name})")
    truth = json.loads(json_path.read_text(encoding="utf-8"))
    with np.load(npz_path) as z:
        truth["canonical"] = z["canonical"].astype(np.float64)
        truth["parts"] = z["parts"]
    truth["landmarks"] = {k: np.asarray(v) for k, v in truth["landmarks"].items()}
    truth["landmarks_canonical"] = {k: np.asarray(v) for k, v in truth["landmarks_canonical"].items()}
    truth["pose"] = np.asarray(truth["pose"])
    return truth


def _make_and_write(args) -> tuple[str, int, list[float]]:
    product, seed, index, out_dir, pose, noise, n_vertices, volume, entropy, family, holes = args
    inst = make_instance(product, random_state=seed, pose=pose, noise=noise, n_vertices=n_vertices,
                         volume=volume, name=f"{product}_{index:03d}", family=family, holes=holes)
    write_instance(inst, out_dir, random_seed=entropy)
    return inst.name, inst.mesh.n_vertices, inst.dimensions.tolist()


def make_population(
    product: str, n: int, *, random_state: RandomState = None, pose: str = "upright", noise: float = 0.0,
    n_vertices: int | None = None, family: str = "standard",
) -> list[SyntheticInstance]:
    """Make ``n`` instances of ``product`` (in memory).

    Instance ``i`` depends only on ``random_state`` and ``i``.

    Examples
    --------
    >>> pop = make_population("pepper", 2, random_state=3, n_vertices=20000)
    >>> [p.name for p in pop]
    ['pepper_000', 'pepper_001']
    """
    seeds = spawn_seeds(random_state, n)
    return [
        make_instance(product, random_state=s, pose=pose, noise=noise, n_vertices=n_vertices,
                      name=f"{product}_{i:03d}", family=family)
        for i, s in enumerate(seeds)
    ]


def write_population(
    product: str,
    n: int,
    out_dir,
    *,
    random_state: int | None = None,
    pose: str = "upright",
    noise: float = 0.0,
    n_vertices: int | None = None,
    volumes: bool = False,
    views: int = 0,
    n_jobs: int | None = None,
    progress: Callable[[Iterable], Iterable] | None = None,
    family: str = "standard",
    holes: float = 0.0,
) -> list[dict]:
    """Make ``n`` instances of ``product`` and write them to ``out_dir``.

    The instances are made in parallel over ``n_jobs`` processes (default: all
    cores). See :func:`write_instance` for the files.

    Parameters
    ----------
    product : str
    n : int
    out_dir : path
    random_state : int or None, default: None
    pose, noise, n_vertices, family, holes : see :func:`make_instance`
    volumes : bool, default: False
        Also write a CT-like volume per instance under ``out_dir/volumes``
        and an MRI-like one under ``out_dir/volumes-mri``.
    views : int, default: 0
        Also write this many depth views of each instance from random
        directions (:func:`write_views`: ``out_dir/views/<name>.view<j>.ply``).
    n_jobs : int, optional
    progress : callable, optional
        Wraps the iterator of finished instances (e.g. ``tqdm``).

    Returns
    -------
    list of dict
        ``name``, ``n_vertices`` and ``dimensions_mm`` per instance, in order.

    Examples
    --------
    >>> import tempfile
    >>> rows = write_population("zucchini", 2, tempfile.mkdtemp(), random_state=3, n_vertices=3000, n_jobs=1)
    >>> [r["name"] for r in rows]
    ['zucchini_000', 'zucchini_001']
    """
    if product not in PRODUCTS:
        raise HortishapeError(f"unknown product {product!r}: choose from {', '.join(PRODUCTS)}")
    if n < 1:
        raise HortishapeError(f"the number of instances must be at least 1, got {n}")
    seeds = spawn_seeds(random_state, n)
    if family not in PRODUCTS[product].families:
        raise HortishapeError(f"{product} has no family {family!r}: choose from {', '.join(PRODUCTS[product].families)}")
    jobs = [(product, s, i, str(out_dir), pose, noise, n_vertices, volumes, random_state, family, holes)
            for i, s in enumerate(seeds)]
    results = run_jobs(_make_and_write, jobs, n_jobs=n_jobs, progress=progress)
    if views:
        # the views' seeds apart from the instances' (same random_state, another stream)
        root = np.random.SeedSequence([int(random_state), 1]) if isinstance(random_state, (int, np.integer)) \
            else random_state
        view_seeds = spawn_seeds(root, n)
        for r, seed in zip(results, view_seeds):
            write_views(Path(out_dir) / f"{r[0]}.ply", views, random_state=seed)
    return [{"name": r[0], "n_vertices": r[1], "dimensions_mm": r[2]} for r in results]


@dataclass(frozen=True)
class Tray:
    """Several products side by side on a tray in one CT-like volume (:func:`make_tray`).

    Attributes
    ----------
    volume : Volume
        The scan: products touching their neighbours, on a plate that reaches
        the volume's edges.
    instances : tuple of SyntheticInstance
        The products, in their place: ``instances[k].mesh``, ``landmarks``
        and ``pose`` are product ``k``'s in the volume's world coordinates
        (its ``deformation`` is still the one it was made with).
    true_volumes : (n,) float64 ndarray
        Enclosed volume of each product's surface, mm^3.
    """

    volume: object
    instances: tuple
    true_volumes: np.ndarray


def _touching_shift(fixed: np.ndarray, moving: np.ndarray, axis: int, overlap: float) -> float:
    """How far to move ``moving`` along ``-axis`` until it touches ``fixed`` (or is ``overlap`` mm into it).

    The gap along the axis, over columns 2 mm wide across it: the least of the
    moving surface's lowest point minus the fixed surface's highest one.
    """
    across = [a for a in range(3) if a != axis]
    lo = np.minimum(fixed[:, across].min(axis=0), moving[:, across].min(axis=0))
    bins = np.ceil((np.maximum(fixed[:, across].max(axis=0), moving[:, across].max(axis=0)) - lo) / 2.0) + 1
    n = int(bins[0] * bins[1])

    def column(points):
        ij = np.floor((points[:, across] - lo) / 2.0).astype(np.int64)
        return ij[:, 0] * int(bins[1]) + ij[:, 1]

    top = np.full(n, -np.inf)
    np.maximum.at(top, column(fixed), fixed[:, axis])
    bottom = np.full(n, np.inf)
    np.minimum.at(bottom, column(moving), moving[:, axis])
    both = np.isfinite(top) & np.isfinite(bottom)
    if not both.any():  # side by side without facing each other: no nearer
        return 0.0
    return float((bottom[both] - top[both]).min()) + overlap


def make_tray(product: str = "apple", n: int = 6, *, random_state: RandomState = None, per_row: int = 3,
              voxel_size: float = 1.0, overlap: float = 0.0, plate_mm: float = 3.0,
              n_vertices: int = 30000) -> Tray:
    """A CT-like volume of ``n`` products touching each other on a tray, as post-harvest labs scan them.

    The products (:func:`make_instance`, standing upright) are set out in rows
    of ``per_row`` along x, the rows along y, each moved against its
    neighbours until their surfaces touch (or overlap by ``overlap`` mm); they
    stand on a plate ``plate_mm`` thick that fills the field of view (a tray
    or scanner bed, darker than the flesh). Each product's CT-like volume is
    resampled onto the tray's grid (linear), the brightest value kept where
    two meet, and noise added.

    Parameters
    ----------
    product : str, default: "apple"
    n : int, default: 6
    random_state : int, Generator, SeedSequence or None
    per_row : int, default: 3
    voxel_size : float, default: 1.0
        Edge of the tray volume's voxels, mm.
    overlap : float, default: 0.0
        How far (mm) neighbours are pushed into each other (0: touching).
    plate_mm : float, default: 3.0
        Thickness of the plate under the products (0: none).
    n_vertices : int, default: 30000
        About the vertex count of each product's surface (sets its own grid).

    Returns
    -------
    Tray

    Examples
    --------
    >>> tray = make_tray("apple", 2, random_state=0, n_vertices=8000, voxel_size=2.0)
    >>> len(tray.instances), tray.volume.data.dtype.name
    (2, 'int16')
    """
    from scipy.ndimage import map_coordinates
    from scipy.special import erf

    from .io import Volume

    if n < 1 or per_row < 1:
        raise HortishapeError(f"a tray needs at least one product and one per row, got {n} and {per_row}")
    rng = as_generator(random_state)
    seeds = spawn_seeds(rng, n + 1)
    insts = [make_instance(product, random_state=s, n_vertices=n_vertices, volume=True, name=f"{product}_{k + 1}")
             for k, s in enumerate(seeds[:n])]
    offsets = []
    placed: list[np.ndarray] = []
    for k, inst in enumerate(insts):
        v = inst.mesh.vertices
        lo, hi = v.min(axis=0), v.max(axis=0)
        offset = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])  # centred, standing on z = 0
        row, col = divmod(k, per_row)
        if row:  # behind the one in the row before, along y
            front = placed[k - per_row]
            offset[0] += front[:, 0].mean() - (v[:, 0] + offset[0]).mean()
            offset[1] += front[:, 1].max() - (v[:, 1].min() + offset[1]) + 5.0
            offset[1] -= _touching_shift(front, v + offset, 1, overlap)
        if col:  # beside the one before it, along x
            left = placed[k - 1]
            offset[0] += left[:, 0].max() - (v[:, 0].min() + offset[0]) + 5.0
            offset[0] -= _touching_shift(left, v + offset, 0, overlap)
        offsets.append(offset)
        placed.append(v + offset)
    allv = np.vstack(placed)
    lo = np.floor(allv.min(axis=0) - 8.0)
    hi = np.ceil(allv.max(axis=0) + 8.0)
    lo[2] = -max(plate_mm, 0.0) - 6.0
    shape = tuple(int(s) for s in np.ceil((hi - lo) / voxel_size) + 1)
    axes = [lo[i] + voxel_size * np.arange(shape[i]) for i in range(3)]
    values = np.zeros(shape, dtype=np.float32)
    for inst, offset in zip(insts, offsets):
        vol = inst.volume
        box = [(ax >= vol.origin[i] + offset[i]) & (ax <= vol.origin[i] + offset[i] + vol.spacing[i] * (vol.shape[i] - 1))
               for i, ax in enumerate(axes)]
        idx = [np.flatnonzero(b) for b in box]
        if any(len(i) == 0 for i in idx):
            continue
        gx, gy, gz = np.meshgrid(*(axes[i][idx[i]] for i in range(3)), indexing="ij")
        at = np.stack([(g - vol.origin[i] - offset[i]) / vol.spacing[i] for i, g in enumerate((gx, gy, gz))])
        sample = map_coordinates(vol.data.astype(np.float32), at, order=1, mode="nearest")
        sub = np.ix_(*idx)
        values[sub] = np.maximum(values[sub], sample)
    if plate_mm > 0:
        z = axes[2]
        sigma = 0.7 * voxel_size
        edge = lambda d: 0.5 * (1.0 - erf(d / (sigma * math.sqrt(2.0))))  # noqa: E731
        plate = 800.0 * edge(z) * edge(-plate_mm - z)  # 1 between -plate_mm and 0
        values = np.maximum(values, plate[None, None, :].astype(np.float32))
    values += rng.normal(0.0, 25.0, size=shape).astype(np.float32)
    data = np.clip(np.round(values), -1000, 3000).astype(np.int16)
    moved = tuple(_moved(inst, offset) for inst, offset in zip(insts, offsets))
    true = np.array([abs(signed_volume(m.mesh.vertices, m.mesh.faces)) for m in moved])
    return Tray(Volume(data, spacing=voxel_size, origin=lo), moved, true)


def _moved(inst: SyntheticInstance, offset: np.ndarray) -> SyntheticInstance:
    from dataclasses import replace

    pose = inst.pose.copy()
    pose[:3, 3] += offset
    return replace(inst, mesh=Mesh(inst.mesh.vertices + offset, inst.mesh.faces),
                   landmarks={k: v + offset for k, v in inst.landmarks.items()}, pose=pose,
                   volume=None, mri_volume=None)
