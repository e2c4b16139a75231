"""Benchmark of `hortishape.fit_partial`: a whole fruit and its volume from what a depth camera sees.

A model is built from synthetic apples in true correspondence (the
generator's canonical coordinates carried to a 30,000-vertex reference, so
the figures measure the partial fit, not the registration); with
``--build DIR`` it is built as a user builds one, by `hortishape build` of
synthetic scans (registration included). Apples of
another seed, in random poses, are seen from 1, 2 and 3 random directions
(`hortishape.synth.depth_view`: one point per mm^2 of outline, 0.2 mm depth
noise). For each it prints:

* the completion error: mean distance from the completed surface to the
  true whole surface and back, averaged (mm);
* the volume error (%) and the reported volume SD;
* the calibration: how often the true volume lies within 1 and 2 reported
  SD, and how often a true surface point lies within 1 and 2 reported
  per-vertex SD of the completed surface (along the normal);
* the seconds per fit (the model prepared once: `PartialFitter`);

and the same completion and volume errors for the obvious alternatives: the
convex hull of the points, a least-squares ellipsoid, and the model's mean
fitted with a scale (similarity ICP).

Run::

    python benchmarks/partial.py                    # 20 training apples, 6 test apples
    python benchmarks/partial.py --train 12 --test 6 --seed 5 --table
    python benchmarks/partial.py --train 12 --seed 21 --views 1 --build /tmp/build21   # as a user builds it
    python benchmarks/partial.py --generator othergen --seed 1000 --train 12 --views 1   # apples of the second generator

With ``--real NAME`` the test fruit is a real scan instead
(``tests/data/ycb/NAME_google16k.ply``, a YCB replica fruit, metres read as
mm), seen ``--test`` times from random directions; the model is of apples
(``--generator``, ``--build``), as described next:

    python benchmarks/partial.py --real 013_apple --test 10 --train 30 --views 1 --seed 7

With ``--generator othergen`` the apples (model and test) come from
``benchmarks/othergen.py``, the second generator, which shares no code with
``hortishape.synth``: training apples seeds S .. S+N-1, test apples seeds
S+500 onwards, the model in that generator's true correspondence (every
training apple's surface at the first one's vertex directions) or built
with ``--build``.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np


def build_truth_model(n_train: int, seed: int, n_points: int):
    """A model from ``n_train`` synthetic apples in the generator's true correspondence."""
    from hortishape import synth
    from hortishape.model import ShapeModel
    from hortishape.procrustes import generalized_procrustes
    from hortishape.surface import barycentric_interpolate, remesh

    pop = synth.make_population("apple", n_train, random_state=seed, pose="upright")
    ref = remesh(pop[0].mesh, n_points)
    canon = barycentric_interpolate(pop[0].canonical, pop[0].mesh.faces, ref.face_index, ref.barycentric)
    shapes = np.stack([synth.true_correspondence(canon, inst) for inst in pop])
    gpa = generalized_procrustes(shapes)
    return ShapeModel().fit(gpa.aligned, ref.mesh.faces)


def build_pipeline_model(n_train: int, seed: int, n_points: int, folder: Path, generator: str = "synth"):
    """A model as a user builds one: ``hortishape build`` of ``n_train`` apple scans.

    The scans come from ``hortishape.synth`` or, with ``generator="othergen"``, from
    the second generator (random poses). They and the model are kept in ``folder``
    and reused when the model is there already.
    """
    from hortishape import synth
    from hortishape.io import write_mesh
    from hortishape.mesh import Mesh
    from hortishape.model import ShapeModel
    from hortishape.pipeline import build_model

    path = folder / "model" / "model.h5"
    if not path.exists():
        if generator == "othergen":
            import othergen

            (folder / "scans").mkdir(parents=True, exist_ok=True)
            for i in range(n_train):
                fruit = othergen.make_fruit("apple", seed + i)
                write_mesh(folder / "scans" / f"apple_{seed + i}.ply", Mesh(fruit.vertices, fruit.faces))
        else:
            synth.write_population("apple", n_train, folder / "scans", random_state=seed)
        build_model(folder / "scans", folder / "model", n_points=n_points)
    return ShapeModel.load(path)


def othergen_truth_model(n_train: int, seed: int):
    """A model of ``n_train`` apples of the second generator in its true correspondence.

    The reference is the first apple's own surface (about 42,000 vertices at its
    1 mm edges, so ``--points`` does not apply); every apple contributes its
    surface at the same directions of its frame (``othergen.surface``), upright
    and without scanner noise.
    """
    import othergen

    from hortishape.model import ShapeModel
    from hortishape.procrustes import generalized_procrustes

    first = othergen.make_fruit("apple", seed, pose="upright")
    shapes = np.stack([othergen.surface(othergen.make_fruit("apple", seed + i, pose="upright"), first.directions)
                       for i in range(n_train)])
    gpa = generalized_procrustes(shapes)
    return ShapeModel().fit(gpa.aligned, first.faces)


def othergen_tests(n_test: int, seed: int):
    """Test apples of the second generator (seeds ``seed + 500`` on), random poses: (name, Mesh) pairs."""
    import othergen

    from hortishape.mesh import Mesh

    out = []
    for j in range(n_test):
        fruit = othergen.make_fruit("apple", seed + 500 + j)
        out.append((f"othergen_apple_{seed + 500 + j}", Mesh(fruit.vertices, fruit.faces)))
    return out


def real_tests(name: str, n_test: int):
    """A real scan (``tests/data/ycb``), ``n_test`` times: (name, Mesh) pairs, mm."""
    from hortishape.units import read_scan

    path = Path(__file__).resolve().parent.parent / "tests" / "data" / "ycb" / f"{name}_google16k.ply"
    mesh = read_scan(path, scale=1000.0).mesh
    return [(f"{name}#{j}", mesh) for j in range(n_test)]


def surface_error(vertices, faces, truth) -> float:
    """Mean distance both ways between a surface and the true one, averaged, mm."""
    from hortishape.mesh import Mesh
    from hortishape.surface import closest_points

    there = closest_points(truth, vertices).distances.mean()
    back = closest_points(Mesh(vertices, faces), truth.vertices).distances.mean()
    return float((there + back) / 2.0)


def convex_hull(points):
    from scipy.spatial import ConvexHull

    hull = ConvexHull(points)
    faces = hull.simplices.copy()
    # orient outward
    centre = points[hull.vertices].mean(axis=0)
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), a - centre) < 0
    faces[flip] = faces[flip][:, ::-1]
    return points, faces, hull.volume


def ellipsoid(points):
    """Least-squares ellipsoid (algebraic fit of a general quadric), as a mesh, and its volume."""
    import trimesh

    x, y, z = points.T
    d = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z], axis=1)
    coef = np.linalg.lstsq(d, np.ones(len(points)), rcond=None)[0]
    a = np.array([[coef[0], coef[3], coef[4]], [coef[3], coef[1], coef[5]], [coef[4], coef[5], coef[2]]])
    centre = -np.linalg.solve(a, coef[6:])
    k = 1.0 + centre @ a @ centre
    evals, evecs = np.linalg.eigh(a / k)
    if np.any(evals <= 0):
        return None
    radii = 1.0 / np.sqrt(evals)
    s = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    v = (s.vertices * radii) @ evecs.T + centre
    return v, np.asarray(s.faces), 4.0 / 3.0 * np.pi * radii.prod()


def scaled_mean(pose_only, points):
    """The model's mean fitted to the points by a trimmed similarity ICP from the pose-only partial fit."""
    from scipy.spatial import cKDTree

    from hortishape.partial import _trim
    from hortishape.surface import signed_volume

    model = pose_only.model
    start = pose_only.fit(points)
    v = start.vertices
    for _ in range(30):
        tree = cKDTree(v)
        dist, j = tree.query(points)
        keep = _trim(dist)
        src, dst = v[j[keep]], points[keep]
        cs, cd = src.mean(axis=0), dst.mean(axis=0)
        u, sig, vt = np.linalg.svd((src - cs).T @ (dst - cd))
        d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
        r = vt.T @ np.diag([1, 1, d]) @ u.T
        s = (sig * [1, 1, d]).sum() / ((src - cs) ** 2).sum()
        v = s * (v - cs) @ r.T + cd
    return v, model.faces_, abs(signed_volume(v, model.faces_))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--train", type=int, default=20, help="training apples (the model)")
    ap.add_argument("--test", type=int, default=6, help="test apples (another seed)")
    ap.add_argument("--views", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--points", type=int, default=30000, help="model vertices")
    ap.add_argument("--seed", type=int, default=0, help="training seed; the test apples use seed + 1000")
    ap.add_argument("--noise", type=float, default=0.2, help="depth noise, mm")
    ap.add_argument("--table", action="store_true",
                    help="add the table behind each fruit as the first camera sees it, and 100 stray points")
    ap.add_argument("--build", type=Path, default=None, metavar="DIR",
                    help="build the model as a user does ('hortishape build' of synthetic scans, kept in DIR and "
                         "reused) instead of in the generator's true correspondence")
    ap.add_argument("--generator", choices=("synth", "othergen"), default="synth",
                    help="the apples' generator: hortishape.synth, or the second one (benchmarks/othergen.py)")
    ap.add_argument("--test-generator", choices=("synth", "othergen"), default=None,
                    help="the test apples' generator, if not the model's (a model of one generator's apples "
                         "completing the other's)")
    ap.add_argument("--real", default=None, metavar="NAME",
                    help="test on a real scan, tests/data/ycb/NAME_google16k.ply (e.g. 013_apple), seen --test times")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    from hortishape import synth
    from hortishape.errors import FitWarning
    from hortishape.partial import MISFIT_RATIO, PartialFitter
    from hortishape.surface import signed_volume, vertex_normals

    t0 = time.perf_counter()
    othergen = args.generator == "othergen"
    if args.build:
        model = build_pipeline_model(args.train, args.seed, args.points, args.build, args.generator)
        how = f"registered by 'hortishape build' (in {args.build})"
    else:
        model = othergen_truth_model(args.train, args.seed) if othergen else build_truth_model(args.train, args.seed, args.points)
        how = "in true correspondence"
    print(f"model: {args.train} {args.generator} apples (seed {args.seed}) {how}, "
          f"{model.n_points_:,} vertices, {model.n_components_} modes ({time.perf_counter() - t0:.0f} s)")
    t0 = time.perf_counter()
    fitter = PartialFitter(model)
    print(f"prepared the model for partial fits (leave-one-out calibration, axis) in {time.perf_counter() - t0:.2f} s")
    pose_only = PartialFitter(model, modes=0)
    if args.real:
        tests = real_tests(args.real, args.test)
    elif (args.test_generator or args.generator) == "othergen":
        tests = othergen_tests(args.test, args.seed)
    else:
        tests = [(inst.name, inst.mesh)
                 for inst in synth.make_population("apple", args.test, random_state=args.seed + 1000, pose="random")]
    rng = np.random.default_rng(args.seed)
    rows = []
    for n_views in args.views:
        for name, truth in tests:
            views = [synth.depth_view(truth, rng.normal(size=3), noise=args.noise, random_state=rng)
                     for _ in range(n_views)]
            points = np.concatenate([v.points for v in views])
            normals = np.concatenate([v.normals for v in views])
            if args.table:
                # the table the fruit lies on, behind it as the first camera sees it (where the fruit does
                # not hide it), at the camera's pitch and noise, and 100 stray points near the fruit
                from hortishape.registration.correspondences import RayScene

                d = views[0].direction
                back = truth.vertices[np.argmax(truth.vertices @ d)]
                u = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
                u /= np.linalg.norm(u)
                w = np.cross(d, u)
                grid = np.stack(np.meshgrid(np.arange(-70, 70), np.arange(-70, 70)), -1).reshape(-1, 2).astype(float)
                table = back + grid[:, :1] * u + grid[:, 1:] * w
                hidden = RayScene(truth.vertices, truth.faces).first_hit(table - 200.0 * d, np.tile(d, (len(table), 1)))[0] >= 0
                table = table[~hidden] + rng.normal(0, args.noise, (int((~hidden).sum()), 1)) * d
                stray = truth.vertices.mean(axis=0) + rng.normal(0, 40.0, (100, 3))
                points = np.concatenate([points, table, stray])
                normals = np.concatenate([normals, np.tile(-d, (len(table), 1)), rng.normal(size=(100, 3))])
            true_volume = abs(signed_volume(truth.vertices, truth.faces)) / 1000.0
            t = time.perf_counter()
            with warnings.catch_warnings():  # recorded in the row
                warnings.simplefilter("ignore", FitWarning)
                fit = fitter.fit(points, normals=normals, random_state=0)
            seconds = time.perf_counter() - t
            completion = surface_error(fit.vertices, fit.faces, truth)
            # per-vertex calibration: the true surface's distance along each completed vertex's normal
            from hortishape.surface import closest_points

            cp = closest_points(truth, fit.vertices)
            nrm = vertex_normals(fit.vertices, fit.faces)
            along = np.abs(np.einsum("ij,ij->i", cp.points - fit.vertices, nrm))
            within1 = float(np.mean(along <= fit.sd))
            within2 = float(np.mean(along <= 2 * fit.sd))
            seen = np.concatenate([v.points for v in views])
            hull_v, hull_f, hull_vol = convex_hull(seen)
            ell = ellipsoid(seen)
            mean_v, mean_f, mean_vol = scaled_mean(pose_only, seen)
            row = {
                "views": n_views, "name": name, "points": len(points), "observed": fit.observed_fraction,
                "completion_mm": completion, "volume_true_ml": true_volume, "volume_ml": fit.volume_ml,
                "volume_sd_ml": fit.volume_sd_ml, "volume_error_pct": 100 * (fit.volume_ml / true_volume - 1),
                "z": (fit.volume_ml - true_volume) / fit.volume_sd_ml, "vertex_within_1sd": within1,
                "vertex_within_2sd": within2, "seconds": seconds, "noise_mm": fit.noise_mm,
                "point_noise_mm": fit.point_noise_mm, "misfit_mm": fit.misfit_mm, "warned": bool(fit.warnings),
                "hull_completion_mm": surface_error(hull_v, hull_f, truth),
                "hull_volume_error_pct": 100 * (hull_vol / 1000.0 / true_volume - 1),
                "ellipsoid_completion_mm": surface_error(ell[0], ell[1], truth) if ell else float("nan"),
                "ellipsoid_volume_error_pct": 100 * (ell[2] / 1000.0 / true_volume - 1) if ell else float("nan"),
                "mean_completion_mm": surface_error(mean_v, mean_f, truth),
                "mean_volume_error_pct": 100 * (mean_vol / 1000.0 / true_volume - 1),
            }
            rows.append(row)
            print(f"{n_views} view(s) {name}: seen {fit.observed_fraction:.0%}, completion {completion:.2f} mm, "
                  f"volume {fit.volume_ml:.1f} +/- {fit.volume_sd_ml:.1f} mL (true {true_volume:.1f}, "
                  f"{row['volume_error_pct']:+.1f} %, z {row['z']:+.1f}), vertices within 1/2 SD "
                  f"{within1:.0%}/{within2:.0%}, {seconds:.2f} s, residuals {fit.noise_mm / fit.point_noise_mm:.2f} "
                  f"times the points' own noise{' (warned)' if fit.warnings else ''}, misfit {fit.misfit_mm:.2f} mm",
                  flush=True)

    print()
    print("views  seen  completion mm (max)  volume err % mean |max|  SD % mean  rms z  true within 1 SD / 2 SD  "
          "vertices within 1 / 2 SD   s/fit   hull mm / %    ellipsoid mm / %   scaled mean mm / %")
    for n_views in args.views:
        r = [x for x in rows if x["views"] == n_views]

        def col(key):
            return np.array([x[key] for x in r], dtype=float)

        z = np.abs(col("z"))
        print(f"{n_views:>5}  {col('observed').mean():>4.0%}  {col('completion_mm').mean():>8.2f} ({col('completion_mm').max():.2f})"
              f"      {np.abs(col('volume_error_pct')).mean():>6.2f} | {np.abs(col('volume_error_pct')).max():>5.2f}"
              f"      {np.mean(col('volume_sd_ml') / col('volume_true_ml')) * 100:>5.2f}  {np.sqrt(np.mean(z**2)):>5.2f}"
              f"        {int((z <= 1).sum())} / {int((z <= 2).sum())} of {len(r)}"
              f"                 {col('vertex_within_1sd').mean():.0%} / {col('vertex_within_2sd').mean():.0%}"
              f"        {np.median(col('seconds')):.2f}"
              f"   {col('hull_completion_mm').mean():.2f} / {np.abs(col('hull_volume_error_pct')).mean():.1f}"
              f"      {np.nanmean(col('ellipsoid_completion_mm')):.2f} / {np.nanmean(np.abs(col('ellipsoid_volume_error_pct'))):.1f}"
              f"        {col('mean_completion_mm').mean():.2f} / {np.abs(col('mean_volume_error_pct')).mean():.1f}")
    for n_views in args.views:
        r = [x for x in rows if x["views"] == n_views]
        print(f"{n_views} view(s): {sum(x['warned'] for x in r)} of {len(r)} fits warned about (residuals above "
              f"{MISFIT_RATIO:g} times the points' own noise)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
