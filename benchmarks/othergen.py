"""A second, independent fruit generator, for testing orientation on shapes hortishape.synth never makes.

``hortishape.synth`` builds fruit from signed distance fields (a body, a stalk
chain, a calyx) and meshes them by marching cubes; every orientation
heuristic of the registration was looked at on its output. This generator
shares none of its code or construction: each fruit is a star-shaped radial
function ``r(theta, phi)`` on a subdivided icosphere (so its triangulation is
not marching cubes' either), with its own anatomy:

* ``apple``: stalk cavity and a shallower calyx basin of random sizes, a stalk
  of 0-20 mm that may stay sunk in its cavity or lean, five calyx remnants,
  faint five-fold ribs, a top wider or narrower than the bottom;
* ``pepper``: a blocky body with 3 or 4 lobes of unequal size at uneven
  spacing, a dent between the lobes at the blossom end, shoulders round a
  thick stalk (leaning up to 20 degrees);
* ``lemon``: prolate, no cavity at either end, a nipple at the blossom end and
  a small button at the stalk end;
* ``peach``: round with a suture groove down one side, a stalk cavity, and the
  blossom tip up to 25 degrees off the opposite pole;
* ``zucchini``: 4-6 times longer than wide, a neck at the stalk end and a club
  at the blossom end, bent.

Scanner noise (0.05-0.15 mm along the normals) is added to every vertex.
The truth kept per fruit is its stalk pole (where the stalk is attached: the
cavity floor) and its blossom pole, after a random pose.

Used by ``benchmarks/orientation.py``; seeds below 100 may be looked at while
developing, seeds from 1000 are the test set.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KINDS = ("apple", "pepper", "lemon", "peach", "zucchini")
#: Longest edge (mm) of a generated surface.
MAX_EDGE = 1.0


@dataclass(frozen=True)
class Fruit:
    """One generated fruit in its pose: vertices (n, 3) mm, faces (m, 3), stalk and blossom poles (3,) mm.

    ``directions`` (n, 3) are the vertices' unit directions in the fruit's own
    frame (stalk towards +z), where its radial function is defined; ``seed``,
    ``rotation`` and ``shift`` (the pose) let :func:`surface` find the same
    directions on another fruit: the dense truth.
    """

    kind: str
    vertices: np.ndarray
    faces: np.ndarray
    stalk: np.ndarray
    blossom: np.ndarray
    seed: int = 0
    directions: np.ndarray | None = None
    rotation: np.ndarray | None = None
    shift: np.ndarray | None = None
    half_length: float = 0.0  # the bend's scale (zucchini)


def _angle_to(u: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Angle (radians) of each unit vector in ``u`` from the unit direction ``d``."""
    return np.arccos(np.clip(u @ d, -1.0, 1.0))


def _tilted(theta: float, phi: float) -> np.ndarray:
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _bump(u: np.ndarray, d: np.ndarray, width: float) -> np.ndarray:
    """A Gaussian bump on the sphere about ``d``, ``width`` radians wide."""
    return np.exp(-((_angle_to(u, d) / width) ** 2))


def _superellipse(theta: np.ndarray, a: float, b: float, n: float) -> np.ndarray:
    """Radius of the profile ``(rho / a)^n + (|z| / b)^n = 1`` along polar angle ``theta``."""
    s, c = np.abs(np.sin(theta)), np.abs(np.cos(theta))
    return 1.0 / ((s / a) ** n + (c / b) ** n) ** (1.0 / n)


def _radius(kind: str, u: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The radial function on unit directions ``u``; also the stalk and blossom directions and the stalk-free radius."""
    theta = np.arccos(np.clip(u[:, 2], -1.0, 1.0))
    phi = np.arctan2(u[:, 1], u[:, 0])
    z = u[:, 2]
    up, down = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    blossom_dir = down
    stalk_dir = up
    if kind == "apple":
        R = rng.uniform(36.0, 44.0)
        r = R * _superellipse(theta, 1.0, rng.uniform(0.82, 1.0), 2.0)
        r *= 1.0 + rng.uniform(-0.08, 0.08) * z  # top wider or narrower
        r *= 1.0 + rng.uniform(0.0, 0.012) * np.cos(5 * phi) * np.clip(-z, 0, 1)  # faint ribs below
        # the stalk and its cavity may sit off the body's axis of revolution
        stalk_dir = _tilted(np.radians(rng.uniform(0.0, 15.0)), rng.uniform(0, 2 * np.pi))
        r -= rng.uniform(6.0, 12.0) * _bump(u, stalk_dir, np.radians(rng.uniform(22.0, 32.0)))  # stalk cavity
        r -= rng.uniform(2.5, 7.0) * _bump(u, down, np.radians(rng.uniform(15.0, 25.0)))  # calyx basin
        ring = rng.uniform(0.0, 2 * np.pi)
        for k in range(5):  # calyx remnants round the basin's floor
            d = _tilted(np.pi - np.radians(6.0), ring + 2 * np.pi * k / 5)
            r += rng.uniform(0.5, 1.5) * _bump(u, d, np.radians(3.0))
        base = r.copy()
        length = rng.choice([0.0, rng.uniform(3.0, 8.0), rng.uniform(8.0, 20.0)])  # none, sunk, out
        r = r + length * _bump(u, stalk_dir, np.radians(rng.uniform(2.0, 3.0)))
    elif kind == "pepper":
        R = rng.uniform(32.0, 40.0)
        r = R * _superellipse(theta, 1.0, rng.uniform(1.0, 1.35), rng.uniform(2.6, 3.4))
        n = int(rng.choice([3, 4]))
        phase = rng.uniform(0, 2 * np.pi)
        lobes = np.zeros(len(u))
        for k in range(n):
            centre = phase + 2 * np.pi * k / n + rng.uniform(-0.25, 0.25)
            dphi = np.angle(np.exp(1j * (phi - centre)))
            lobes += rng.uniform(0.04, 0.11) * np.exp(-((dphi / (np.pi / n * 0.7)) ** 2))
        r *= 1.0 + lobes * (0.5 + 0.5 * np.clip(-z, 0, 1))
        r *= 1.0 + rng.uniform(-0.12, 0.12) * z  # shoulders wider or narrower than the bottom
        stalk_dir = _tilted(np.radians(rng.uniform(0.0, 15.0)), rng.uniform(0, 2 * np.pi))
        r -= rng.uniform(6.0, 12.0) * _bump(u, stalk_dir, np.radians(rng.uniform(22.0, 32.0)))  # shoulders' cavity
        r -= rng.uniform(2.0, 7.0) * _bump(u, down, np.radians(rng.uniform(12.0, 22.0)))  # dent between lobes
        base = r.copy()
        r = r + rng.uniform(10.0, 30.0) * _bump(u, stalk_dir, np.radians(rng.uniform(3.5, 5.5)))
    elif kind == "lemon":
        R = rng.uniform(26.0, 32.0)
        r = R * _superellipse(theta, 1.0, rng.uniform(1.2, 1.45), 2.0)
        r += rng.uniform(3.0, 7.0) * _bump(u, down, np.radians(rng.uniform(9.0, 14.0)))  # nipple
        base = r.copy()
        r += rng.uniform(1.0, 2.5) * _bump(u, up, np.radians(rng.uniform(5.0, 8.0)))  # button
        base = r.copy()
    elif kind == "peach":
        R = rng.uniform(32.0, 38.0)
        r = R * _superellipse(theta, 1.0, rng.uniform(0.9, 1.02), 2.0)
        seam = rng.uniform(0, 2 * np.pi)
        dphi = np.angle(np.exp(1j * (phi - seam)))
        r -= rng.uniform(1.0, 3.0) * np.exp(-((dphi / np.radians(rng.uniform(6.0, 10.0))) ** 2)) * np.sin(theta) ** 0.5
        r *= 1.0 + rng.uniform(0.0, 0.05) * np.cos(phi - seam - np.pi / 2)  # one cheek fuller
        r -= rng.uniform(5.0, 9.0) * _bump(u, up, np.radians(rng.uniform(18.0, 26.0)))
        blossom_dir = _tilted(np.pi - np.radians(rng.uniform(0.0, 25.0)), seam)
        r += rng.uniform(0.5, 2.0) * _bump(u, blossom_dir, np.radians(4.0))  # the tip
        base = r.copy()
    elif kind == "zucchini":
        R = rng.uniform(18.0, 24.0)
        aspect = rng.uniform(4.0, 6.0)
        r = R * _superellipse(theta, 1.0, aspect, 2.0)
        zz = z * r
        L = R * aspect
        r *= 1.0 - rng.uniform(0.15, 0.3) * np.clip(zz / L, 0, 1) ** 2  # neck at the stalk end
        r *= 1.0 + rng.uniform(0.05, 0.2) * np.clip(-zz / L, 0, 1)  # club at the blossom end
        r *= 1.0 + rng.uniform(0.0, 0.02) * np.cos(int(rng.choice([5, 6, 8])) * phi)
        base = r.copy()
        r = r + rng.uniform(10.0, 25.0) * _bump(u, up, np.radians(rng.uniform(2.5, 4.0)))
    else:
        raise ValueError(f"unknown kind {kind!r}: choose from {', '.join(KINDS)}")
    return r, stalk_dir, blossom_dir, {"base": base}


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def make_fruit(kind: str, seed: int, *, subdivisions: int = 5, pose: str = "random", noise: float | None = None) -> Fruit:
    """One fruit of ``kind`` (see the module notes), in a random pose (or ``"upright"``: stalk along +z).

    ``noise``: the scanner noise's standard deviation in mm (default: drawn from 0.05-0.15).
    """
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions)
    u = np.asarray(sphere.vertices, dtype=np.float64)
    faces = np.asarray(sphere.faces, dtype=np.int64)
    # the radial function's draws are all scalars, so the same seed gives the
    # same fruit on any set of directions: the sphere's triangles stretched
    # by the function (a stalk, a zucchini's length) are split to MAX_EDGE
    # and the new vertices put on the surface
    for _ in range(2):
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        r = _radius(kind, u, np.random.default_rng(seed))[0]
        v, faces = trimesh.remesh.subdivide_to_size(u * r[:, None], faces, max_edge=MAX_EDGE)
        u = np.asarray(v, dtype=np.float64)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    r, stalk_dir, blossom_dir, extra = _radius(kind, u, rng)
    v = u * r[:, None]
    base = extra["base"]
    # the poles: where the stalk-free surface meets the stalk's and the blossom's directions
    stalk = stalk_dir * base[int(np.argmax(u @ stalk_dir))]
    blossom = blossom_dir * base[int(np.argmax(u @ blossom_dir))]
    half_length = float(np.abs(v[:, 2]).max())
    if kind == "zucchini":  # bent in the plane of x
        bent = _bend(rng, half_length)
        v, stalk, blossom = bent(v), bent(stalk), bent(blossom)
    # scanner noise along the normals
    tm = trimesh.Trimesh(v, faces, process=False)
    sd = rng.uniform(0.05, 0.15) if noise is None else noise
    v = v + tm.vertex_normals * rng.normal(0.0, 1.0, size=(len(v), 1)) * sd
    rot, shift = np.eye(3), np.zeros(3)
    if pose == "random":
        rot = _random_rotation(rng)
        shift = rng.uniform(-50.0, 50.0, 3)
        v, stalk, blossom = v @ rot.T + shift, rot @ stalk + shift, rot @ blossom + shift
    return Fruit(kind, v, faces, stalk, blossom, seed, u, rot, shift, half_length)


def _bend(rng: np.random.Generator, length: float):
    """A zucchini's bend in the plane of x (its one draw from ``rng``, after the radial function's)."""
    bend = rng.uniform(0.0, 0.25) * length

    def bent(p):
        p = np.array(p, dtype=np.float64)
        p[..., 0] += bend * (p[..., 2] / length) ** 2
        return p

    return bent


def surface(fruit: Fruit, directions: np.ndarray) -> np.ndarray:
    """The points of ``fruit`` (without its noise) at unit ``directions`` of its own frame, in its pose.

    The dense truth: a vertex of another fruit at direction ``u`` of that
    fruit's frame corresponds to ``surface(fruit, u)`` (the same place of the
    radial function: the stalk's direction, the calyx's, a lobe's angle).
    """
    u = np.asarray(directions, dtype=np.float64)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    rng = np.random.default_rng(fruit.seed)
    r = _radius(fruit.kind, u, rng)[0]
    p = u * r[:, None]
    if fruit.kind == "zucchini":
        p = _bend(rng, fruit.half_length)(p)
    return p @ fruit.rotation.T + fruit.shift
