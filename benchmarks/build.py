"""Benchmark of `hortishape build`: time, memory and model quality against the ground truth.

Makes a synthetic population (default: 30 apples, CT-like surfaces of 70k-130k
vertices, standing on the scanner bed), builds the model exactly as
``hortishape build`` does (30,000-vertex reference, two registration passes,
Procrustes, PCA) and prints:

* wall time of the build (both passes) and of its stages, and peak memory
  (the main process, and the largest worker);
* dense correspondence error of the model's registered surfaces against the
  generator's ground truth, and the landmark transfer error;
* leave-one-out generalization G(m) (mean distance per vertex, mm) of the model,
  and of a model built from the generator's ground-truth correspondences of the
  same instances at the same vertices (the target: within 10%).

Run::

    python benchmarks/build.py                       # 30 apples, the project's setting
    python benchmarks/build.py --n 10 --points 10000 # quicker
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _rotation(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The rotation of the least-squares rigid fit of ``p`` onto ``q``."""
    from hortishape.align import rigid_fit

    return rigid_fit(p, q)[:3, :3]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--product", default="apple")
    parser.add_argument("--n", type=int, default=30)
    parser.add_argument("--points", type=int, default=30000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--pose", default="upright", choices=["upright", "random"])
    parser.add_argument("--family", default="standard",
                        help="shape family (synth.PRODUCTS[product].families); the non-standard ones were never "
                             "used for tuning")
    parser.add_argument("--modes", type=int, default=5, help="modes for the generalization figure")
    parser.add_argument("--jobs", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    args = parser.parse_args(argv)

    from hortishape import synth
    from hortishape.io import read_mesh
    from hortishape.metrics import generalization
    from hortishape.pipeline import build_model
    from hortishape.registration import prepare_reference
    from hortishape.surface import barycentric_interpolate

    work = args.out or Path(tempfile.mkdtemp(prefix="hortishape-bench-"))
    scans = work / "scans"
    t0 = time.perf_counter()
    synth.write_population(args.product, args.n, scans, random_state=args.seed, pose=args.pose, n_jobs=args.jobs,
                           family=args.family)
    t_synth = time.perf_counter() - t0
    n_vertices = [read_mesh(p).n_vertices for p in sorted(scans.glob("*.ply"))]
    print(f"{args.n} synthetic {args.product}s ({args.pose}, family {args.family}), {min(n_vertices):,}-{max(n_vertices):,} vertices, "
          f"made in {t_synth:.1f} s")

    t0 = time.perf_counter()
    result = build_model(scans, work / "model", n_points=args.points, n_jobs=args.jobs)
    t_build = time.perf_counter() - t0
    peak_self = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    peak_child = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    pass1 = [r.seconds for r in result.first_pass if r.ok and not r.resumed]
    pass2 = [r.seconds for r in result.second_pass if r.ok and not r.resumed]

    # ground truth at the model's vertices: the reference's canonical coordinates
    # carried through its resampling (the second pass keeps the vertex order)
    names = list(result.names)
    truths = {n: synth.read_truth(scans / f"{n}.ply") for n in names}
    ref_name = Path(result.reference).stem
    template = prepare_reference(read_mesh(result.reference), args.points)
    ref_mesh = read_mesh(result.reference)
    canon = barycentric_interpolate(truths[ref_name]["canonical"], ref_mesh.faces,
                                    template.source_face_index, template.source_barycentric)
    instances = {n: _instance(scans / f"{n}.ply", truths[n]) for n in names}
    gt = np.stack([synth.true_correspondence(canon, instances[n]) for n in names])
    registered = np.stack([read_mesh(work / "model" / "registered" / f"{n}.ply").vertices for n in names])
    dense = np.linalg.norm(registered - gt, axis=2).mean(axis=1)
    lm_err = {}
    for lm in ("stalk_tip", "bottom"):
        j = int(np.argmin(np.linalg.norm(template.mesh.vertices - truths[ref_name]["landmarks"][lm], axis=1)))
        lm_err[lm] = np.array([np.linalg.norm(registered[i, j] - truths[n]["landmarks"][lm]) for i, n in enumerate(names)])

    t0 = time.perf_counter()
    m = min(args.modes, len(names) - 2)
    g_model = generalization(registered, modes=m)
    g_truth = generalization(gt, modes=m)
    t_gen = time.perf_counter() - t0

    print()
    print(f"build (both passes, {len(names)} instances, {args.points:,}-vertex reference): {t_build:.1f} s")
    print(f"  registrations: first pass {np.mean(pass1):.2f} s each, second pass {np.mean(pass2):.2f} s each "
          f"(in parallel over the cores)")
    print(f"  peak memory: main process {peak_self:.0f} MB, largest worker {peak_child:.0f} MB")
    print(f"  skipped: {len(result.skipped)}")
    checked = json.loads((work / "model" / "summary.json").read_text())["orientation_check"]
    print(f"  orientation check: {len(checked)} suspects, kept "
          + ", ".join(f"{r['name']} {r['kept']}" for r in checked))
    print(f"  uncertain orientation (named in the summary): {len(result.uncertain_orientation)} of {len(names)}")
    rot = {n: np.degrees(np.arccos(np.clip((np.trace(_rotation(registered_i, gt_i)) - 1) / 2, -1, 1)))
           for n, registered_i, gt_i in zip(names, registered, gt)}
    wrong = {n: round(float(a)) for n, a in rot.items() if a > 45}
    print(f"  turned more than 45 degrees from the truth (best rigid fit): {len(wrong)} {wrong}")
    print(f"dense correspondence error vs ground truth: mean {dense.mean():.3f} mm, "
          f"worst instance {dense.max():.3f} mm")
    for lm, e in lm_err.items():
        print(f"landmark {lm:<10} transfer error: {e.mean():.2f} +/- {e.std(ddof=1):.2f} mm (max {e.max():.2f})")
    print(f"leave-one-out generalization (mm per vertex; {t_gen:.0f} s for both):")
    print(f"{'modes':>6}{'model':>10}{'+/- se':>8}{'truth':>10}{'+/- se':>8}{'ratio':>8}")
    for j, m in enumerate(g_model.modes):
        print(f"{m:>6}{g_model.mean_mm[j]:>10.3f}{g_model.se_mm[j]:>8.3f}{g_truth.mean_mm[j]:>10.3f}"
              f"{g_truth.se_mm[j]:>8.3f}{g_model.mean_mm[j] / g_truth.mean_mm[j]:>8.3f}")
    summary = {
        "product": args.product, "n": args.n, "points": args.points, "build_seconds": t_build,
        "peak_mb_main": peak_self, "peak_mb_worker": peak_child,
        "dense_error_mm": float(dense.mean()), "generalization_model_mm": g_model.mean_mm.tolist(),
        "generalization_truth_mm": g_truth.mean_mm.tolist(),
        "landmark_error_mm": {k: float(v.mean()) for k, v in lm_err.items()},
    }
    print(json.dumps(summary))
    return 0


def _instance(mesh_path: Path, truth: dict):
    """A SyntheticInstance-like object for ``true_correspondence`` from files."""
    from types import SimpleNamespace

    from hortishape.io import read_mesh

    return SimpleNamespace(mesh=read_mesh(mesh_path), canonical=truth["canonical"])


if __name__ == "__main__":
    sys.exit(main())
