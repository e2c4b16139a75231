"""Benchmark of `hortishape.cad`: B-spline approximation of a model's mean, STEP volume, export speed.

For the model's mean surface (the paper's section 3.3 and Fig. 9) it prints:

* the cylindrical parameterization: flipped triangles, the area it covers in
  (u, v) (1 = the cylinder once), its distortion and time;
* per grid k in (4, 8, 16, 32): mean and maximum distance from the mesh's
  vertices to the k x k B-spline approximation, the largest distance back from
  the B-spline to the mesh, and the storage per surface (float64 control
  points, as the paper counts: 703 kB for 30,000 points, 24 kB for 32 x 32)
  against the triangle model's vertices;
* the volume enclosed by each exported STEP solid (OpenCascade) against the
  mesh's volume;
* the seconds to export one more instance (a random sample to STEP) once the
  operator exists;

and writes the Fig. 9 pictures (one per k, coloured by the distance to the
mesh, with a colour bar in mm) and a picture of the parameterization to the
output folder.

Run::

    python benchmarks/cad.py --model hortishape-demo/model/model.h5 --out cad-bench
    python benchmarks/cad.py --out cad-bench      # makes a model from 30 synthetic apples first
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _synthetic_model(n: int, points: int, seed: int):
    """A model of ``n`` synthetic apples in their ground-truth correspondence (no registration)."""
    from hortishape import synth
    from hortishape.model import ShapeModel
    from hortishape.surface import remesh

    pop = synth.make_population("apple", n, random_state=seed, pose="upright")
    ref = remesh(pop[0].mesh, points)
    from hortishape.surface import barycentric_interpolate

    canon = barycentric_interpolate(pop[0].canonical, pop[0].mesh.faces, ref.source_face_index,
                                    ref.source_barycentric)
    shapes = np.stack([synth.true_correspondence(canon, p) for p in pop])
    return ShapeModel(procrustes=True).fit(shapes, ref.mesh.faces)


def _parameterization_picture(vertices, faces, cmap, path: Path, cells: int = 16) -> Path:
    """The mean coloured as a checkerboard of (u, v) cells (the iso-parametric lines of Fig. 9)."""
    from hortishape.render import render_grid

    uv = cmap.disc_uv[cmap.disc_faces].mean(axis=1)
    checker = (np.floor(uv[:, 0] * cells) + np.floor(uv[:, 1] * cells)) % 2
    shade = np.full(len(faces), np.nan)
    # faces of the cut disc are the faces minus the poles' one-rings; locate them in `faces`
    key = {tuple(sorted(f)): i for i, f in enumerate(faces.tolist())}
    idx = np.array([key[tuple(sorted(f))] for f in cmap.faces.tolist()])
    shade[idx] = uv[:, 1] * 0.8 + 0.2 * checker
    return render_grid([(vertices, faces)], path, views=("front", "top"), scalars=[shade], clim=(0.0, 1.0),
                       cmap="viridis", scalar_bar_title=f"v (bottom 0, stalk 1); checks: 1/{cells} of u and v",
                       titles=["(u, v) of the mean surface"], cell_size=(420, 400))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=None, help="model file (default: 30 synthetic apples)")
    parser.add_argument("--n", type=int, default=30, help="synthetic apples when no --model")
    parser.add_argument("--points", type=int, default=30000, help="vertices of the synthetic model")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--grids", type=int, nargs="+", default=[4, 8, 16, 32])
    parser.add_argument("--out", type=Path, default=None, help="folder for pictures and files (default: temporary)")
    args = parser.parse_args(argv)

    from hortishape import cad
    from hortishape.model import ShapeModel
    from hortishape.surface import signed_volume

    out = args.out or Path(tempfile.mkdtemp(prefix="hortishape-cad-"))
    out.mkdir(parents=True, exist_ok=True)
    if args.model is not None:
        model = ShapeModel.load(args.model)
        source = str(args.model)
    else:
        t0 = time.perf_counter()
        model = _synthetic_model(args.n, args.points, args.seed)
        source = f"{args.n} synthetic apples, ground-truth correspondence ({time.perf_counter() - t0:.0f} s)"
    mean, faces = model.mean_, model.faces_
    n = len(mean)
    mesh_volume = abs(signed_volume(mean, faces))
    print(f"model: {source}; mean surface {n:,} vertices, {len(faces):,} triangles, "
          f"volume {mesh_volume / 1000:.1f} cm^3")

    t0 = time.perf_counter()
    poles = cad.find_poles(mean, faces)
    t_poles = time.perf_counter() - t0
    t0 = time.perf_counter()
    cmap = cad.parameterize(mean, faces, poles=poles)
    t_param = time.perf_counter() - t0
    dist = cmap.distortion(mean)
    print(f"poles: stalk {np.round(mean[poles.stalk], 1).tolist()}, bottom {np.round(mean[poles.bottom], 1).tolist()} "
          f"mm ({t_poles:.2f} s)")
    print(f"parameterization: {cmap.n_flipped} flipped of {len(cmap.disc_faces):,} triangles, covers "
          f"{cmap.covered_area:.6f} of the cylinder, conformal distortion median {np.median(dist):.2f} "
          f"(95th percentile {np.percentile(dist, 95):.2f}), seam {len(cmap.seam)} vertices ({t_param:.2f} s)")
    pic = _parameterization_picture(mean, faces, cmap, out / "parameterization.png")
    print(f"  picture: {pic}")

    mesh_kb = n * 3 * 8 / 1024
    mesh_faces_kb = len(faces) * 3 * 4 / 1024
    print()
    print(f"{'grid':>7}{'fit s':>7}{'mean mm':>9}{'max mm':>8}{'back max':>10}{'kB':>7}{'vs mesh':>9}"
          f"{'STEP kB':>9}{'STEP volume':>13}{'vs mesh':>9}")
    models = {}
    for k in args.grids:
        t0 = time.perf_counter()
        bm = cad.BSplineModel(k, parameterization=cmap).fit(model)
        t_fit = time.perf_counter() - t0
        models[k] = bm
        surface = bm.mean_
        dev = cad.surface_deviation(surface, mean, faces)
        step = cad.write_cad(out / f"mean_{k}x{k}.step", surface)
        cad.write_cad(out / f"mean_{k}x{k}.json", surface)
        vol = cad.cad_volume(step)
        kb = surface.nbytes / 1024
        print(f"{f'{k}x{k}':>7}{t_fit:>7.2f}{dev.mean:>9.4f}{dev.max:>8.3f}{dev.back_max:>10.3f}{kb:>7.1f}"
              f"{mesh_kb / kb:>8.0f}x{step.stat().st_size / 1024:>9.0f}{vol / 1000:>10.2f} cm3"
              f"{100 * (vol - mesh_volume) / mesh_volume:>+8.3f}%")
        cad.render_deviation(surface, mean, faces, out / f"fig9_{k}x{k}.png",
                             title=f"{k} x {k} control points")
    print(f"triangle model: {mesh_kb:.0f} kB of float64 vertices per surface (+ {mesh_faces_kb:.0f} kB of "
          f"int32 triangles, shared); the paper: 703 kB for 30,000 points, 24 kB for 32 x 32")
    print(f"pictures: {', '.join(str(out / f'fig9_{k}x{k}.png') for k in args.grids)}")

    # one more instance once the operator exists
    k = max(args.grids)
    bm = models[k]
    cad.write_cad(out / "warmup.step", bm.mean_)  # OpenCascade initialises its STEP schema on first use
    times = []
    for i in range(10):
        t0 = time.perf_counter()
        surface = bm.sample(random_state=i)
        cad.write_cad(out / f"sample_{i}.step", surface)
        times.append(time.perf_counter() - t0)
    minus, plus = bm.mode_shapes(0, sd=3.0)
    t0 = time.perf_counter()
    cad.write_cad(out / "mode1_plus3sd.step", plus)
    t_mode = time.perf_counter() - t0
    # the same instance fitted from its triangle mesh gives the same control points
    c = model.sample_coefficients(1, random_state=0)[0]
    direct = bm.fitter_.control_points(model.instance(c))
    linear = bm.instance(c).control_points
    print()
    print(f"export one more instance ({k}x{k}, random sample -> STEP): median {np.median(times) * 1000:.0f} ms, "
          f"max {max(times) * 1000:.0f} ms over 10; mode 1 +3 SD: {t_mode * 1000:.0f} ms")
    print(f"control points from coefficients vs refitting the instance's mesh: max difference "
          f"{np.abs(direct - linear).max():.2e} mm")
    print(f"files: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
