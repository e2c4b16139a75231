"""Benchmark of `hortishape extract`: accuracy against known surfaces, time and memory on 512^3 volumes.

1. Accuracy. Synthetic CT-like and MRI-like volumes with known outer surfaces,
   made as ``hortishape synth CLASS N OUT --volumes`` makes them (CT: partial-volume
   edge, noise, hollow peppers, apples with a low-density core; MRI: a thin
   bright peel over a dark rind, flesh in segments, a core open to the blossom
   end, 8-bit, slices twice as thick as the pixels; random scanner pose): the
   surface extracted from each ``OUT/volumes/<name>.mha`` and
   ``OUT/volumes-mri/<name>.mha`` with the default settings is compared with the
   true surface ``OUT/<name>.ply``: mean distance both ways in (in-plane)
   voxels, volume error, genus, one watertight component.
2. Time and memory. A 512^3 int16 volume (256 MB) of a hollow ellipsoid with
   the same CT model, made here slab by slab and written as an uncompressed
   MHA, is read and extracted in a fresh process, which reports its wall
   times and its peak resident memory (the interpreter, the libraries and the
   volume included). Its surface is compared with the analytic ellipsoid. The
   same for a 512^3 uint8 MRI-like layered ball (128 MB).

3. With ``--artefacts``: each volume again under what real scanners add and the
   synthetic volumes leave out (their truth unchanged). MRI: a bias field (a
   +-20 % ramp across x, or across z; a surface coil's fall-off in the slice plane,
   1.3 at the centre to 0.8 in the corners), Gibbs ringing (k-space cut to 70 %
   or 50 % of its width on every axis) and stronger Rician noise (sigma 4 on top
   of the volumes' 2). CT: cupping (beam hardening: the flesh 25 % darker at the
   centre of the slice than at its edge), ring artefacts (+-60 about the slice's
   centre, 6 voxels apart), noise sigma 150 (six times the volumes'), a wider
   blur (Gaussian, 1.5 voxel), a bed (a plate 4 voxels thick and as dense as
   the flesh across the whole slice, touching the product from below) and the
   field of view (the volume grown with air, and outside the circle the scanner
   reconstructs one value 1000 below the air, DICOM's pixel padding). Same
   figures as 1.
4. With ``--oranges N``: MRI volumes of an orange like the real one described to the project a real
   one (256 x 256 x 64 voxels of 0.39 x 0.39 x 1 mm, 8-bit, the fruit nearly
   filling the slices' depth, a thin peel that the slices break up), made here
   without ``hortishape.synth`` (:func:`orange_volume`), against the true
   ellipsoid: mean distance, volume error, genus.
5. With ``--real-shapes``: the eight real fruit scans of ``tests/data/ycb`` made into an
   MRI-like and a CT-like volume each (:func:`real_shape_volume`: the scan's own surface in a
   random rotation, layers by depth below it, a core, stone or segments about its marked axis),
   against that surface: mean distance both ways, volume error, genus.

The project's targets: mean distance <= 0.15 voxel, volume within 0.2 % (CT)
and 0.5 % (MRI), genus 0 and one watertight component; 512^3 in <= 20 s with
peak memory <= 3x the volume.

Run::

    python benchmarks/extract.py                         # 2 of each product, and the 512^3 volume
    python benchmarks/extract.py --n 1 --size 256        # quicker
    python benchmarks/extract.py --n 0                   # only the 512^3 volumes (time and memory)
    python benchmarks/extract.py --n 0 --size 0 --oranges 12 --seed 100   # MRI oranges like the real one described to the project
    python benchmarks/extract.py --products apple pepper zucchini --size 0 --artefacts   # scanner artefacts
    python benchmarks/extract.py --n 0 --size 0 --real-shapes       # real fruit shapes as volumes
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

PRODUCTS = ("apple", "pepper", "zucchini", "pear", "banana")

# Run in a fresh process so that its peak resident memory is that of reading and
# extracting one volume, nothing else.
_CHILD = r"""
import json, resource, sys, time
from pathlib import Path
from hortishape.extract import extract_surface
from hortishape.io import read_volume, write_mesh

def status_mb(field):
    # VmHWM is this process's own peak: ru_maxrss would also count the parent's
    # pages that the fork before exec shared
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) / 1024

source, target = Path(sys.argv[1]), Path(sys.argv[2])
base = status_mb("VmRSS")
t0 = time.perf_counter()
vol = read_volume(source)
t1 = time.perf_counter()
cpu = resource.getrusage(resource.RUSAGE_SELF)
ext = extract_surface(vol)
t2 = time.perf_counter()
cpu2 = resource.getrusage(resource.RUSAGE_SELF)
write_mesh(target, ext.mesh)
t3 = time.perf_counter()
print(json.dumps({
    "read_s": t1 - t0, "extract_s": t2 - t1, "write_s": t3 - t2,
    "extract_cpu_s": cpu2.ru_utime + cpu2.ru_stime - cpu.ru_utime - cpu.ru_stime,
    "rss_after_imports_mb": base,
    "peak_rss_mb": status_mb("VmHWM"),
    "volume_mb": vol.data.nbytes / 2**20, "shape": list(vol.shape),
    "n_vertices": ext.mesh.n_vertices, "n_filled_voxels": ext.n_filled_voxels,
    "level": ext.levels.level, "level_method": ext.levels.method, "gap_mm": ext.gap_mm, "genus": ext.genus,
}))
"""


KINDS = (("CT", "volumes"), ("MRI", "volumes-mri"))


def _ramp(data, axis):
    """A bias field rising linearly from 0.8 to 1.2 along ``axis``."""
    shape = [1, 1, 1]
    shape[axis] = data.shape[axis]
    return np.linspace(0.8, 1.2, data.shape[axis]).reshape(shape)


def _coil(data):
    """A surface coil's fall-off in the slice plane: 1.3 at the centre, 0.8 in the corners."""
    u, v = (np.linspace(-1.0, 1.0, n) for n in data.shape[:2])
    return (1.3 - 0.5 * (u[:, None] ** 2 + v[None, :] ** 2) / 2.0)[:, :, None]


def _gibbs(data, keep):
    """The magnitude image of the volume's k-space cut to ``keep`` of its width on every axis."""
    k = np.fft.fftshift(np.fft.fftn(data.astype(np.float64)))
    box = np.zeros(k.shape, dtype=bool)
    box[tuple(slice(int(round(n * (1 - keep) / 2)), n - int(round(n * (1 - keep) / 2))) for n in k.shape)] = True
    k[~box] = 0.0
    return np.abs(np.fft.ifftn(np.fft.ifftshift(k)))


def _rician(data, sigma, rng):
    return np.hypot(data + rng.normal(0.0, sigma, data.shape), rng.normal(0.0, sigma, data.shape))


def _in_plane_radius(data):
    """Distance from the slice's centre (voxels), broadcast over the slices."""
    u, v = (np.arange(n) - (n - 1) / 2.0 for n in data.shape[:2])
    return np.hypot(u[:, None], v[None, :])[:, :, None]


def _cupping(d):
    r = _in_plane_radius(d)
    return d * (0.75 + 0.25 * np.minimum(r / r.max(), 1.0) ** 2)


def _bed(d):
    """A plate as dense as the flesh across the slices just below the product, touching it."""
    rows = np.flatnonzero((d > 500).any(axis=(0, 1)))
    out = d.copy()
    out[:, :, max(rows[0] - 4, 0):rows[0]] = 1000.0
    return out


def _field_of_view(d, rng):
    """A CT's field of view: the volume grown by 35 % of its slice's width on each side with air
    (its own background's noise), and outside the circle the scanner reconstructs, filled with one
    value 1000 below the air (DICOM's pixel padding: -2000 HU where the air is -1000). Returns the
    data and where the volume's first voxel now lies (voxels)."""
    pad = int(0.35 * max(d.shape[:2]))
    air = d[:2, :2, :]
    level = float(np.median(air))
    out = rng.normal(level, float(np.std(air)), (d.shape[0] + 2 * pad, d.shape[1] + 2 * pad, d.shape[2]))
    out[pad : pad + d.shape[0], pad : pad + d.shape[1]] = d
    outside = _in_plane_radius(out) > min(out.shape[:2]) / 2.0
    return np.where(outside, level - 1000.0, out), (pad, pad, 0)


def _gaussian(d, sigma):
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(d, sigma)


#: what real scanners add (``--artefacts``): kind -> name -> f(float data, rng) -> float data, or
#: (float data, the old first voxel's index in it) for an artefact that grows the volume
ARTEFACTS = {
    "MRI": {
        "bias x": lambda d, rng: d * _ramp(d, 0),
        "bias z": lambda d, rng: d * _ramp(d, 2),
        "coil": lambda d, rng: d * _coil(d),
        "Gibbs 70%": lambda d, rng: _gibbs(d, 0.7),
        "Gibbs 50%": lambda d, rng: _gibbs(d, 0.5),
        "noise 4": lambda d, rng: _rician(d, 4.0, rng),
    },
    "CT": {
        "cupping": lambda d, rng: _cupping(d),
        "rings": lambda d, rng: d + 60.0 * np.sin(2.0 * np.pi * _in_plane_radius(d) / 6.0),
        "noise 150": lambda d, rng: d + rng.normal(0.0, 150.0, d.shape),
        "blur 1.5": lambda d, rng: _gaussian(d, 1.5),
        "bed": lambda d, rng: _bed(d),
        "field of view": _field_of_view,
    },
}
#: the intensity range of each kind's volumes (CT int16, MRI uint8)
RANGE = {"MRI": (0, 255, np.uint8), "CT": (-1000, 3000, np.int16)}


def _with_artefact(vol, kind, name, seed):
    """A copy of the ``kind`` volume ``vol`` with the artefact ``name``, in the volume's own type."""
    from hortishape.io import Volume

    lo, hi, dtype = RANGE[kind]
    data = ARTEFACTS[kind][name](vol.data.astype(np.float64), np.random.default_rng(seed))
    data, shift = data if isinstance(data, tuple) else (data, (0, 0, 0))
    origin = vol.origin - vol.direction @ (vol.spacing * np.asarray(shift, dtype=np.float64))
    return Volume(np.clip(np.rint(data), lo, hi).astype(dtype), spacing=vol.spacing, origin=origin,
                  direction=vol.direction)


def accuracy(work: Path, products, n: int, seed: int, jobs, artefacts: bool = False) -> list[dict]:
    from hortishape import synth
    from hortishape.extract import extract_surface
    from hortishape.io import read_mesh, read_volume
    from hortishape.surface import check_closed_surface, closest_points, signed_volume

    rows = []
    if n == 0:  # only the large volumes
        return rows
    print(f"{'scan':<14}{'kind':>14}{'voxels':>14}{'pixel mm':>9}{'level':>16}{'gap':>5}{'genus':>6}"
          f"{'ext->true':>10}{'true->ext':>10}{'max':>7}{'volume %':>10}{'closed':>8}{'s':>6}")
    for product in products:
        folder = work / product
        synth.write_population(product, n, folder, random_state=seed, pose="random", volumes=True, n_jobs=jobs)
        for i in range(n):
            name = f"{product}_{i:03d}"
            truth = read_mesh(folder / f"{name}.ply")
            h = synth.read_truth(folder / f"{name}.ply")["voxel_size_mm"]  # the in-plane pixel
            cases = [(kind, read_volume(folder / sub / f"{name}.mha")) for kind, sub in KINDS]
            if artefacts:
                cases += [(f"{kind} {a}", _with_artefact(vol, kind, a, seed + i))
                          for kind, vol in list(cases) for a in ARTEFACTS[kind]]
            for kind, vol in cases:
                t0 = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # said in the table: gap and genus
                    ext = extract_surface(vol)
                seconds = time.perf_counter() - t0
                try:
                    check_closed_surface(ext.mesh, allow_degenerate=True)
                    closed = "yes"
                except Exception as exc:  # report, do not stop the benchmark
                    closed = f"NO ({exc})"
                forward = closest_points(truth, ext.mesh.vertices).distances / h
                backward = closest_points(ext.mesh, truth.vertices).distances / h
                volume_error = 100.0 * (ext.volume / signed_volume(truth.vertices, truth.faces) - 1.0)
                row = {"scan": name, "kind": kind, "shape": list(vol.shape), "voxel_mm": vol.spacing.tolist(),
                       "n_vertices": ext.mesh.n_vertices, "level_method": ext.levels.method,
                       "gap_mm": ext.gap_mm, "genus": ext.genus,
                       "mean_distance_voxels": float(forward.mean()),
                       "mean_distance_back_voxels": float(backward.mean()),
                       "max_distance_voxels": float(forward.max()), "volume_error_percent": volume_error,
                       "closed_one_component": closed == "yes", "seconds": seconds}
                rows.append(row)
                level = f"{ext.levels.level:.4g} {ext.levels.method}"
                print(f"{name:<14}{kind:>14}{'x'.join(map(str, vol.shape)):>14}{h:>9.3f}{level:>16}"
                      f"{ext.gap_mm:>5g}{ext.genus:>6}{forward.mean():>10.4f}{backward.mean():>10.4f}"
                      f"{forward.max():>7.3f}{volume_error:>+10.4f}{closed:>8}{seconds:>6.1f}")
    return rows


def ellipsoid_volume(size: int, axes, wall: float, *, sigma: float = 0.7, noise: float = 25.0, seed: int = 0):
    """An int16 CT-like volume ``[x, y, z]`` of a hollow ellipsoid centred in the grid (voxel units).

    Same model as ``synth --volumes``: 1000 in the flesh, 0 in air, an error-function
    partial-volume edge of ``sigma`` voxels across the first-order distance to
    the ellipsoid, Gaussian noise. Made plane by plane (x fastest in memory,
    as read from an MHA file).
    """
    from scipy.special import erf

    rng = np.random.default_rng(seed)
    a = np.asarray(axes, dtype=np.float64)
    inner = a - wall
    c = (size - 1) / 2.0
    data = np.empty((size, size, size), dtype=np.int16, order="F")
    u = np.arange(size) - c
    x, y = np.meshgrid(u, u, indexing="ij")

    def distance(z, e):
        f = (x / e[0]) ** 2 + (y / e[1]) ** 2 + (z / e[2]) ** 2 - 1.0
        g = 2.0 * np.sqrt((x / e[0] ** 2) ** 2 + (y / e[1] ** 2) ** 2 + (z / e[2] ** 2) ** 2)
        return f / np.maximum(g, 1e-12)

    s = sigma * math.sqrt(2.0)
    for k in range(size):
        flesh = 0.5 * (1.0 - erf(distance(u[k], a) / s))
        air = 0.5 * (1.0 - erf(distance(u[k], inner) / s))
        v = 1000.0 * flesh * (1.0 - air) + rng.normal(0.0, noise, size=flesh.shape)
        data[:, :, k] = np.clip(np.rint(v), -1000, 3000)
    return data


def extract_in_child(stem: Path, data: np.ndarray, spacing: float):
    """Write ``data`` as ``<stem>.mha`` (uncompressed) and extract it in a fresh process into
    ``<stem>.ply``: that process's report (times, peak memory) and the surface."""
    from hortishape.io import Volume, read_mesh, write_volume

    path = write_volume(stem.with_suffix(".mha"), Volume(data, spacing=spacing), compress=False)
    out = stem.with_suffix(".ply")
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(path), str(out)], capture_output=True, text=True)
    if proc.returncode:
        print(proc.stderr)
        raise SystemExit("the extraction process failed")
    return json.loads(proc.stdout.strip().splitlines()[-1]), read_mesh(out)


def large(work: Path, size: int) -> dict:
    axes = np.array([0.45, 0.39, 0.48]) * size
    wall = 0.05 * size
    spacing = 0.2
    t0 = time.perf_counter()
    data = ellipsoid_volume(size, axes, wall)
    print(f"\n{size}^3 int16 hollow ellipsoid ({data.nbytes / 2**20:.0f} MB, semi-axes "
          f"{'/'.join(f'{v:.0f}' for v in axes)} voxels, wall {wall:.0f} voxels) made in "
          f"{time.perf_counter() - t0:.1f} s")
    r, mesh = extract_in_child(work / f"ellipsoid_{size}", data, spacing)
    # first-order distance to the ellipsoid, in voxels (origin 0, spacing 0.2 mm)
    p = mesh.vertices / spacing - (size - 1) / 2.0
    f = ((p / axes) ** 2).sum(axis=1) - 1.0
    g = 2.0 * np.linalg.norm(p / axes**2, axis=1)
    d = np.abs(f / g)
    from hortishape.surface import signed_volume

    exact = 4.0 / 3.0 * math.pi * axes.prod() * spacing**3
    vol_err = 100.0 * (signed_volume(mesh.vertices, mesh.faces) / exact - 1.0)
    r.update(mean_distance_voxels=float(d.mean()), max_distance_voxels=float(d.max()),
             volume_error_percent=vol_err, peak_over_volume=r["peak_rss_mb"] / r["volume_mb"])
    print(f"  read {r['read_s']:.1f} s, extract {r['extract_s']:.1f} s (CPU {r['extract_cpu_s']:.1f} s), "
          f"write {r['write_s']:.1f} s "
          f"({r['n_vertices']:,} vertices, {r['n_filled_voxels']:,} cavity voxels filled)")
    print(f"  peak resident memory {r['peak_rss_mb']:.0f} MB = {r['peak_over_volume']:.2f} x the volume "
          f"({r['volume_mb']:.0f} MB); {r['rss_after_imports_mb']:.0f} MB of it before reading "
          f"(interpreter and libraries)")
    print(f"  distance to the analytic ellipsoid: mean {d.mean():.4f} voxel, max {d.max():.3f}; "
          f"volume {vol_err:+.4f} %")
    return r


def layered_volume(size: int, radius: float, *, seed: int = 0):
    """A uint8 MRI-like volume ``[x, y, z]`` of a layered ball centred in the grid (voxel units).

    As ``synth --volumes`` makes its MRI-like volumes: a bright peel (40) 3 voxels thick over a
    dark rind (10) 8 thick, flesh (80) in 10 wedges with dark gaps, a dark core that opens to +z
    through a channel 3 voxels in radius, Rician noise 2; made plane by plane.
    """
    from scipy.special import erf

    rng = np.random.default_rng(seed)
    c = (size - 1) / 2.0
    data = np.empty((size, size, size), dtype=np.uint8, order="F")
    u = np.arange(size) - c
    x, y = np.meshgrid(u, u, indexing="ij")
    rho = np.hypot(x, y)
    period = 2 * math.pi / 10
    across = rho * np.abs((np.arctan2(y, x) + 0.5 * period) % period - 0.5 * period)

    def inside(v):
        return 0.5 * (1.0 - erf(v / (0.7 * math.sqrt(2.0))))

    for k in range(size):
        r = np.sqrt(rho**2 + u[k] ** 2)
        d = r - radius
        v = 40.0 * inside(d) - 30.0 * inside(d + 3.0)
        v += 70.0 * (1.0 - inside(across - 1.0)) * inside(d + 11.0)
        core = np.maximum(inside(r - 0.15 * radius), inside(rho - 3.0) if u[k] > 0 else 0.0)
        v = v * (1.0 - core) + 4.0 * core * (d < 0)
        v = np.hypot(v + rng.normal(0.0, 2.0, v.shape), rng.normal(0.0, 2.0, v.shape))
        data[:, :, k] = np.clip(np.rint(v), 0, 255)
    return data


def large_mri(work: Path, size: int) -> dict:
    from hortishape.surface import signed_volume

    radius = 0.45 * size
    spacing = 0.2
    t0 = time.perf_counter()
    data = layered_volume(size, radius)
    print(f"\n{size}^3 uint8 MRI-like layered ball ({data.nbytes / 2**20:.0f} MB, radius {radius:.0f} voxels, "
          f"peel 3, rind 8, 10 segments, core open through a channel) made in {time.perf_counter() - t0:.1f} s")
    r, mesh = extract_in_child(work / f"layered_{size}", data, spacing)
    d = np.abs(np.linalg.norm(mesh.vertices / spacing - (size - 1) / 2.0, axis=1) - radius)
    exact = 4.0 / 3.0 * math.pi * (radius * spacing) ** 3
    vol_err = 100.0 * (signed_volume(mesh.vertices, mesh.faces) / exact - 1.0)
    r.update(mean_distance_voxels=float(d.mean()), volume_error_percent=vol_err,
             peak_over_volume=r["peak_rss_mb"] / r["volume_mb"])
    print(f"  read {r['read_s']:.1f} s, extract {r['extract_s']:.1f} s (CPU {r['extract_cpu_s']:.1f} s); level "
          f"{r['level']:.4g} ({r['level_method']}), gaps up to {r['gap_mm']:g} mm closed, genus {r['genus']}")
    print(f"  peak resident memory {r['peak_rss_mb']:.0f} MB = {r['peak_over_volume']:.2f} x the volume "
          f"({r['volume_mb']:.0f} MB); {r['rss_after_imports_mb']:.0f} MB of it before reading")
    print(f"  distance to the peel's outer sphere: mean {d.mean():.4f} voxel; volume {vol_err:+.4f} %")
    return r


def orange_volume(seed: int):
    """An MRI volume of an orange like the real one described to the project, made without hortishape.synth.

    256 x 256 x 64 voxels of 0.39 x 0.39 x 1 mm, uint8, the fruit nearly filling the slices'
    depth: an ellipsoid 70-82 mm across and 54-60 mm tall, tilted up to 12 degrees, its peel
    (flavedo) 0.5-1.5 mm thick and bright over a dark rind (albedo) 2.5-4.5 mm thick, bright
    flesh in 8-12 segments parted by dark gaps 0.6-1.2 mm wide, a dark core 8-16 mm across
    that opens to the top through a stalk channel 1.6-3 mm wide, each tissue's brightness
    drawn at random (peel 25-100, rind 6-20, flesh 60-110), Rician noise 2-4. The partial
    volume of each voxel is the mean over 4 x 2 x 2 points. Returns ``(Volume, truth)``, the
    truth the ellipsoid's semi-axes, rotation and centre (mm, world coordinates).
    """
    from hortishape.io import Volume

    rng = np.random.default_rng(seed)
    a = rng.uniform(35.0, 41.0)
    axes = np.array([a, a * rng.uniform(0.96, 1.0), rng.uniform(27.0, 30.0)])
    peel, rind = rng.uniform(0.5, 1.5), rng.uniform(2.5, 4.5)
    n_seg, gap = int(rng.integers(8, 13)), rng.uniform(0.6, 1.2)
    core, channel = rng.uniform(4.0, 8.0), rng.uniform(0.8, 1.5)
    air, peel_v, rind_v = rng.uniform(2, 6), rng.uniform(25, 100), rng.uniform(6, 20)
    flesh_v, core_v, sigma = rng.uniform(60, 110), rng.uniform(4, 12), rng.uniform(2, 4)
    tilt = np.deg2rad(rng.uniform(0.0, 12.0))
    turn = rng.uniform(0.0, 2.0 * np.pi)  # of the tilt's axis, in the slice plane
    k = np.array([np.cos(turn), np.sin(turn), 0.0])
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    rotation = np.eye(3) + np.sin(tilt) * kx + (1 - np.cos(tilt)) * kx @ kx  # body -> world
    shape, spacing = (256, 256, 64), np.array([0.39, 0.39, 1.0])
    centre = np.array(shape) * spacing / 2.0 + np.array([*rng.uniform(-3, 3, 2), rng.uniform(-1, 1)])
    phase = rng.uniform(0.0, 2.0 * np.pi)
    width = 2.0 * np.pi / n_seg
    sub = (2, 2, 4)  # points per voxel along x, y, z
    data = np.empty(shape, dtype=np.float32)
    xs = [(np.arange(shape[i])[:, None] + (np.arange(sub[i]) + 0.5) / sub[i] - 0.5).ravel() * spacing[i]
          for i in range(3)]
    gx, gy = np.meshgrid(xs[0], xs[1], indexing="ij")
    for z in range(shape[2]):
        total = np.zeros(gx.shape, dtype=np.float64)
        for zz in xs[2][z * sub[2] : (z + 1) * sub[2]]:
            world = np.stack([gx, gy, np.full_like(gx, zz)], axis=-1) - centre
            X, Y, Z = np.moveaxis(world @ rotation, -1, 0)  # body coordinates
            r = np.sqrt((X / axes[0]) ** 2 + (Y / axes[1]) ** 2 + (Z / axes[2]) ** 2)
            g = np.sqrt((X / axes[0] ** 2) ** 2 + (Y / axes[1] ** 2) ** 2 + (Z / axes[2] ** 2) ** 2)
            d = (r - 1.0) * r / np.maximum(g, 1e-12)  # first-order distance, mm
            rho = np.hypot(X, Y)
            across = rho * np.abs((np.arctan2(Y, X) + phase + 0.5 * width) % width - 0.5 * width)
            v = np.full(X.shape, air)
            v[d <= 0] = peel_v
            v[d <= -peel] = rind_v
            flesh = d <= -(peel + rind)
            v[flesh] = flesh_v
            v[flesh & ((across < gap / 2) | (rho < core))] = core_v
            v[(rho < channel) & (Z > 0) & (d <= 0)] = core_v
            total += v
        data[:, :, z] = (total / sub[2]).reshape(shape[0], sub[0], shape[1], sub[1]).mean(axis=(1, 3))
    data = np.hypot(data + rng.normal(0, sigma, data.shape), rng.normal(0, sigma, data.shape))
    vol = Volume(np.clip(np.rint(data), 0, 255).astype(np.uint8), spacing=spacing)
    return vol, {"axes": axes, "rotation": rotation, "centre": centre, "peel_mm": peel, "rind_mm": rind,
                 "brightness": (air, peel_v, rind_v, flesh_v)}


def oranges(n: int, seed: int) -> list[dict]:
    """``orange_volume`` for seeds ``seed``.. ``seed + n - 1``, extracted with the defaults and
    compared with the true ellipsoid (first-order distance, in mm and in-plane voxels)."""
    from hortishape.extract import extract_surface

    rows = []
    print(f"\nMRI oranges like the real one described to the project (256x256x64, 0.39 x 0.39 x 1 mm, uint8; seeds {seed}-{seed + n - 1})")
    print(f"{'seed':>5}{'peel mm':>8}{'peel/rind/flesh':>16}{'level':>13}{'gap':>5}{'genus':>6}"
          f"{'mean mm':>9}{'voxel':>7}{'p99 mm':>8}{'volume %':>10}{'s':>6}")
    from hortishape.errors import VolumeError

    for s in range(seed, seed + n):
        vol, truth = orange_volume(s)
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ext = extract_surface(vol)
        except VolumeError as exc:  # report, do not stop the benchmark
            rows.append({"seed": s, "failed": str(exc)})
            print(f"{s:>5}  failed: {exc}")
            continue
        seconds = time.perf_counter() - t0
        axes, p = truth["axes"], (ext.mesh.vertices - truth["centre"]) @ truth["rotation"]
        r = np.sqrt(((p / axes) ** 2).sum(axis=1))
        d = np.abs((r - 1.0) * r / np.linalg.norm(p / axes**2, axis=1))
        error = 100.0 * (ext.volume / (4.0 / 3.0 * math.pi * axes.prod()) - 1.0)
        rows.append({"seed": s, "mean_distance_mm": float(d.mean()), "volume_error_percent": error,
                     "genus": ext.genus, "gap_mm": ext.gap_mm, "level_method": ext.levels.method})
        b = truth["brightness"]
        print(f"{s:>5}{truth['peel_mm']:>8.2f}{f'{b[1]:.0f}/{b[2]:.0f}/{b[3]:.0f}':>16}"
              f"{f'{ext.levels.level:.4g} {ext.levels.method}':>13}{ext.gap_mm:>5g}{ext.genus:>6}"
              f"{d.mean():>9.3f}{d.mean() / 0.39:>7.3f}{np.percentile(d, 99):>8.2f}{error:>+10.2f}{seconds:>6.1f}")
    errors = np.abs([r["volume_error_percent"] for r in rows if "failed" not in r])
    if len(errors):
        print(f"volume within 5 %: {int((errors <= 5).sum())} of {n}, within 0.5 %: {int((errors <= 0.5).sum())}; "
              f"median {np.median(errors):.2f} %, worst {errors.max():.2f} %; genus 0: "
              f"{sum(r.get('genus') == 0 for r in rows)}; failed: {sum('failed' in r for r in rows)}")
    return rows


YCB = Path(__file__).resolve().parents[1] / "tests" / "data" / "ycb"
#: the eight real scans, with what their inside is made of here: citrus (a peel over a dark rind,
#: segments, a core open to the stalk), pome (a thin skin, a core round the axis), stone (a stone
#: round the axis), none (flesh throughout)
REAL_SHAPES = {"013_apple": "pome", "016_pear": "pome", "015_peach": "stone", "018_plum": "stone",
               "014_lemon": "citrus", "017_orange": "citrus", "011_banana": "none", "012_strawberry": "none"}


def real_shape_volume(name: str, modality: str, seed: int):
    """A CT-like or MRI-like volume of a real fruit's shape, made without hortishape.synth.

    The outer surface is a YCB scan's (``tests/data/ycb``, metres read as mm) in a random
    rotation; inside it, layers by depth below that surface and a core, a stone or segments about
    the axis between its hand-marked poles (``REAL_SHAPES``), each brightness drawn at random.
    MRI: 0.39 x 0.39 x 1 mm voxels, 8-bit, Rician noise 2-4; CT: 0.6 mm voxels, int16, Gaussian
    noise 15-40 and blur. Partial volume: each voxel the mean of 2 x 2 x 4 (MRI) or 2 x 2 x 2 (CT)
    points, the depth at each from the voxel centre's distance to the surface, to first order.
    Returns ``(Volume, truth, skin)``: the truth is a ``Mesh`` of the scan's surface in the volume's
    world coordinates (mm), ``skin`` the outermost layer's thickness (mm) and its brightness over the
    flesh's.
    """
    from scipy import ndimage
    from scipy.spatial.transform import Rotation

    from hortishape.io import Volume
    from hortishape.mesh import Mesh
    from hortishape.surface import closest_points
    from hortishape.units import read_scan

    rng = np.random.default_rng(seed)
    mesh = read_scan(YCB / f"{name}_google16k.ply", scale=1000.0).mesh
    marks = json.loads((YCB / "poles.json").read_text())["scans"][f"{name}_google16k"]
    rot = Rotation.random(random_state=rng).as_matrix()
    centre = mesh.vertices.mean(axis=0)
    v = (mesh.vertices - centre) @ rot.T
    stalk, blossom = [(1000.0 * np.asarray(marks[k]) - centre) @ rot.T for k in ("stalk", "blossom")]
    spacing = np.array([0.39, 0.39, 1.0]) if modality == "MRI" else np.full(3, 0.6)
    sub = (2, 2, 4) if modality == "MRI" else (2, 2, 2)
    lo = v.min(axis=0) - 4.0 - rng.uniform(0, 1, 3) * spacing
    shape = tuple(int(n) for n in np.ceil((v.max(axis=0) + 4.0 - lo) / spacing))
    truth = Mesh(v - lo, mesh.faces)  # in the volume's world coordinates (origin 0)
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1).reshape(-1, 3)
    centres = idx * spacing
    cp = closest_points(truth, centres)
    away = centres - cp.points
    a, b, c = (truth.vertices[truth.faces[cp.face_index, i]] for i in range(3))
    sign = np.where(np.einsum("ij,ij->i", away, np.cross(b - a, c - a)) >= 0, 1.0, -1.0)
    d = (sign * cp.distances).reshape(shape)
    # a wrong sign beside a sharp edge makes a speck: the inside is the largest piece at d < 0 and
    # all the outside cannot reach
    labels = ndimage.label(d < 0)[0]
    inside = ndimage.binary_fill_holes(labels == np.argmax(np.bincount(labels.ravel())[1:]) + 1)
    del labels
    d = np.where(inside, -np.abs(d), np.abs(d)).reshape(-1)
    grad = sign[:, None] * away / np.maximum(cp.distances, 1e-9)[:, None]
    grad = np.where(inside.reshape(-1)[:, None] == (sign < 0)[:, None], grad, -grad)
    axis_from, axis_to = blossom - lo, stalk - lo
    along = axis_to - axis_from
    length = float(np.linalg.norm(along))
    along /= length
    kind = REAL_SHAPES[name]
    if modality == "MRI":
        air, flesh = rng.uniform(2, 6), rng.uniform(60, 110)
        skin_t, skin_v = (rng.uniform(0.5, 1.5), rng.uniform(25, 100)) if kind == "citrus" else \
            (rng.uniform(0.2, 0.8), flesh * rng.uniform(0.7, 1.4))
        rind_t, rind_v = (rng.uniform(2.5, 4.5), rng.uniform(6, 20)) if kind == "citrus" else (0.0, flesh)
        core_v = rng.uniform(4, 30)
        noise = rng.uniform(2, 4)
    else:
        air, flesh = 0.0, rng.uniform(800, 1000)
        skin_t, skin_v = rng.uniform(0.2, 1.0), flesh * rng.uniform(1.0, 1.15)
        rind_t, rind_v = (rng.uniform(2.5, 4.5), flesh * rng.uniform(0.75, 0.9)) if kind == "citrus" else (0.0, flesh)
        core_v = flesh * (rng.uniform(1.2, 1.4) if kind == "stone" else rng.uniform(0.4, 0.7))
        noise = rng.uniform(15, 40)
    core_r = {"pome": rng.uniform(6, 10), "stone": rng.uniform(7, 11), "citrus": rng.uniform(4, 8), "none": 0.0}[kind]
    n_seg, gap, channel = int(rng.integers(8, 13)), rng.uniform(0.6, 1.2), rng.uniform(0.8, 1.5)
    phase = rng.uniform(0, 2 * np.pi)
    side = np.cross(along, [1.0, 0, 0] if abs(along[0]) < 0.9 else [0, 1.0, 0])
    side /= np.linalg.norm(side)
    other = np.cross(along, side)
    offsets = np.stack(np.meshgrid(*[(np.arange(k) + 0.5) / k - 0.5 for k in sub], indexing="ij"), -1).reshape(-1, 3)
    total = np.zeros(len(centres))
    for off in offsets * spacing:
        q = centres + off
        depth = -(d + grad @ off)
        rel = q - axis_from
        t = rel @ along
        radial = rel - t[:, None] * along
        rho = np.linalg.norm(radial, axis=1)
        val = np.full(len(q), air)
        val[depth >= 0] = skin_v
        val[depth >= skin_t] = rind_v
        fl = depth >= skin_t + rind_t
        val[fl] = flesh
        deep = fl & (depth > 3.0)
        core = deep & (rho < core_r) & (t > 0.15 * length) & (t < 0.85 * length)
        if kind == "citrus":
            angle = np.arctan2(radial @ other, radial @ side) + phase
            width = 2 * np.pi / n_seg
            across = rho * np.abs((angle + 0.5 * width) % width - 0.5 * width)
            core |= fl & (across < gap / 2)
            core |= (depth >= 0) & (rho < channel) & (t > 0.5 * length)  # the stalk channel, open at the top
        val[core] = core_v
        total += val
    data = (total / len(offsets)).reshape(shape)
    if modality == "MRI":
        data = np.hypot(data + rng.normal(0, noise, shape), rng.normal(0, noise, shape))
        data = np.clip(np.rint(data), 0, 255).astype(np.uint8)
    else:
        data = _gaussian(data, 0.5) + rng.normal(0, noise, shape)
        data = np.clip(np.rint(data), -1000, 3000).astype(np.int16)
    return Volume(data, spacing=spacing), truth, (skin_t, skin_v / flesh)


def real_shapes(seed: int) -> list[dict]:
    """``real_shape_volume`` of each YCB scan, MRI and CT, extracted with the defaults and compared
    with the scan's own surface: mean distance both ways (mm and in-plane voxels), volume, genus."""
    from hortishape.errors import VolumeError
    from hortishape.extract import extract_surface
    from hortishape.surface import closest_points, signed_volume

    rows = []
    print(f"\nReal fruit shapes (YCB scans) as MRI-like and CT-like volumes (seed {seed})")
    print(f"{'fruit':>15}{'kind':>7}{'skin mm, x flesh':>17}{'level':>16}{'gap':>5}{'genus':>6}{'mean mm':>9}"
          f"{'voxel':>7}{'volume %':>10}{'s':>6}")
    for i, name in enumerate(REAL_SHAPES):
        for modality in ("MRI", "CT"):
            vol, truth, (skin_mm, skin_ratio) = real_shape_volume(name, modality, seed + i)
            skin = f"{skin_mm:.2f} x{skin_ratio:.2f}"
            t0 = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    ext = extract_surface(vol)
            except VolumeError as exc:
                rows.append({"fruit": name, "kind": modality, "failed": str(exc)})
                print(f"{name:>15}{modality:>7}{skin:>17}  failed: {exc}")
                continue
            seconds = time.perf_counter() - t0
            there = closest_points(truth, ext.mesh.vertices).distances.mean()
            back = closest_points(ext.mesh, truth.vertices).distances.mean()
            mean = float(max(there, back))
            error = 100.0 * (ext.volume / signed_volume(truth.vertices, truth.faces) - 1.0)
            rows.append({"fruit": name, "kind": modality, "skin_mm": skin_mm, "skin_over_flesh": skin_ratio,
                         "mean_distance_mm": mean, "volume_error_percent": error,
                         "genus": ext.genus, "gap_mm": ext.gap_mm, "level_method": ext.levels.method})
            print(f"{name:>15}{modality:>7}{skin:>17}{f'{ext.levels.level:.4g} {ext.levels.method}':>16}{ext.gap_mm:>5g}"
                  f"{ext.genus:>6}{mean:>9.3f}{mean / vol.spacing[0]:>7.3f}{error:>+10.2f}{seconds:>6.1f}", flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--products", nargs="+", default=list(PRODUCTS), choices=PRODUCTS)
    parser.add_argument("--n", type=int, default=2, help="volumes per product (0: only the large volumes)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", type=int, default=512, help="edge of the large volume (0: skip it)")
    parser.add_argument("--jobs", type=int, default=None, help="processes for making the synthetic volumes")
    parser.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    parser.add_argument("--artefacts", action="store_true",
                        help="also each volume with a scanner's artefacts (MRI: bias field, Gibbs ringing, noise; "
                             "CT: cupping, rings, noise, blur, a bed)")
    parser.add_argument("--oranges", type=int, default=0, metavar="N",
                        help="also N MRI oranges made like the real one described to the project (seeds from --seed)")
    parser.add_argument("--real-shapes", action="store_true",
                        help="also the eight real fruit scans (tests/data/ycb) made into MRI-like and CT-like volumes")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="hortishape-extract-") as tmp:
        work = args.out or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        rows = accuracy(work, args.products, args.n, args.seed, args.jobs, args.artefacts)
        summary = {}
        for kind in dict.fromkeys(r["kind"] for r in rows):
            some = [r for r in rows if r["kind"] == kind]
            distance = [max(r["mean_distance_voxels"], r["mean_distance_back_voxels"]) for r in some]
            volume = [abs(r["volume_error_percent"]) for r in some]
            summary[kind] = {
                "n": len(some),
                "mean_distance_voxels_worst": max(distance), "mean_distance_voxels_median": float(np.median(distance)),
                "within_0.15_voxel": sum(d <= 0.15 for d in distance),
                "abs_volume_error_percent_worst": max(volume), "abs_volume_error_percent_median": float(np.median(volume)),
                "within_0.5_percent": sum(v <= 0.5 for v in volume),
                "genus_0": sum(r["genus"] == 0 for r in some),
                "all_closed_one_component": all(r["closed_one_component"] for r in some),
                "seconds_per_volume": float(np.mean([r["seconds"] for r in some])),
            }
            w = summary[kind]
            print(f"{kind} over {w['n']} volumes: mean distance (the larger way) median {w['mean_distance_voxels_median']:.4f}, "
                  f"worst {w['mean_distance_voxels_worst']:.4f} voxel, {w['within_0.15_voxel']} within 0.15; "
                  f"volume error median {w['abs_volume_error_percent_median']:.3f} %, worst "
                  f"{w['abs_volume_error_percent_worst']:.3f} %, {w['within_0.5_percent']} within 0.5 %; "
                  f"genus 0: {w['genus_0']}; all one closed component: {w['all_closed_one_component']}; "
                  f"{w['seconds_per_volume']:.2f} s per volume")
        orange_rows = oranges(args.oranges, args.seed) if args.oranges else []
        shape_rows = real_shapes(args.seed) if args.real_shapes else []
        big = large(work, args.size) if args.size else None
        big_mri = large_mri(work, args.size) if args.size else None
    print(json.dumps({"accuracy": summary, "oranges": orange_rows, "real_shapes": shape_rows, "large": big,
                      "large_mri": big_mri}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
