"""Benchmark of `hortishape evaluate`: the time to evaluate a 30-apple model, and its figures.

Either evaluates a model directory that ``hortishape build`` (or ``hortishape
demo``) wrote, or first makes one with the generator's ground-truth
correspondence (no registration: quick), as ``hortishape build`` lays it out:
30 synthetic apples (CT-like surfaces of 70k-130k vertices, standing on the
scanner bed), instance 0 remeshed to a 30,000-vertex reference, its canonical
coordinates carried to every scan by ``synth.true_correspondence``, generalized
Procrustes and PCA.

Prints the wall time of the whole evaluation (leave-one-out included, the
pictures and the HTML report written) and of its stages, the measures for the
first modes (mm per vertex and the paper's squared norms), the geometric error
(Table 2), the landmark errors (Table 3) and the dimensions (Table 1) next to
the generator's.

Run::

    python benchmarks/evaluate.py                              # 30 apples, ground truth
    python benchmarks/evaluate.py --model hortishape-demo/model  # a built model
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np


def write_truth_model(root: Path, *, product: str, n: int, n_points: int, seed: int, jobs) -> Path:
    """A model directory laid out as 'hortishape build' writes it, with true correspondence."""
    from hortishape import synth
    from hortishape.io import read_mesh, write_mesh
    from hortishape.model import ShapeModel
    from hortishape.procrustes import generalized_procrustes
    from hortishape.surface import barycentric_interpolate, remesh

    scans, out = root / "scans", root / "model"
    synth.write_population(product, n, scans, random_state=seed, n_jobs=jobs)
    names = [f"{product}_{i:03d}" for i in range(n)]
    ref_mesh = read_mesh(scans / f"{names[0]}.ply")
    ref = remesh(ref_mesh, n_points)
    canon = barycentric_interpolate(synth.read_truth(scans / f"{names[0]}.ply")["canonical"], ref_mesh.faces,
                                    ref.face_index, ref.barycentric)
    faces = ref.mesh.faces
    registered = []
    (out / "registered").mkdir(parents=True, exist_ok=True)
    (out / "aligned").mkdir(parents=True, exist_ok=True)
    for name in names:
        inst = SimpleNamespace(mesh=read_mesh(scans / f"{name}.ply"),
                               canonical=synth.read_truth(scans / f"{name}.ply")["canonical"])
        registered.append(synth.true_correspondence(canon, inst))
        write_mesh(out / "registered" / f"{name}.ply", registered[-1], faces)
    gpa = generalized_procrustes(np.stack(registered))
    for name, a in zip(names, gpa.aligned):
        write_mesh(out / "aligned" / f"{name}.ply", a, faces)
    ShapeModel().fit(gpa.aligned, faces, names=names).save(out / "model.h5")
    summary = {"units": "mm", "input_dir": str(scans), "instances": names, "procrustes": {"scaling": False},
               "second_pass": [{"name": nm, "source": str(scans / f"{nm}.ply"), "ok": True} for nm in names],
               "note": "ground-truth correspondence (benchmarks/evaluate.py), no registration"}
    (out / "summary.json").write_text(json.dumps(summary))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=None, help="a built model directory to evaluate")
    parser.add_argument("--product", default="apple")
    parser.add_argument("--n", type=int, default=30)
    parser.add_argument("--points", type=int, default=30000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--samples", type=int, default=200, help="random shapes per m (specificity)")
    parser.add_argument("--jobs", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None, help="work folder (default: a temporary one)")
    args = parser.parse_args(argv)

    from hortishape.evaluate import evaluate_model

    if args.model is None:
        work = args.out or Path(tempfile.mkdtemp(prefix="hortishape-eval-"))
        t0 = time.perf_counter()
        model_dir = write_truth_model(work, product=args.product, n=args.n, n_points=args.points, seed=args.seed,
                                      jobs=args.jobs)
        print(f"made a ground-truth model of {args.n} synthetic {args.product}s ({args.points:,} vertices) in "
              f"{time.perf_counter() - t0:.0f} s: {model_dir}")
    else:
        model_dir = args.model

    t0 = time.perf_counter()
    ev = evaluate_model(model_dir, n_samples=args.samples, random_state=args.seed)
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    c, g, s, d = ev.compactness, ev.generalization, ev.specificity, ev.dimensions
    print()
    print(f"evaluation of {len(ev.names)} instances x {ev.n_points:,} vertices, m = 1..{int(c.modes[-1])}, "
          f"{s.n_samples} random shapes per m: {seconds:.1f} s (peak memory {peak:.0f} MB)")
    print("  " + ", ".join(f"{k.replace('_', ' ')} {v:.1f} s" for k, v in ev.timings.items()))
    print(f"{'m':>3}{'C(m) %':>9}{'G mm':>8}{'se':>7}{'G eq.15 mm2':>13}{'S mm':>8}{'se':>7}{'S eq.16 mm2':>13}")
    for j, m in enumerate(c.modes[:10]):
        print(f"{m:>3}{100 * c.ratio[j]:>9.2f}{g.mean_mm[j]:>8.3f}{g.se_mm[j]:>7.3f}{g.mean_sq[j]:>13,.0f}"
              f"{s.mean_mm[j]:>8.3f}{s.se_mm[j]:>7.3f}{s.mean_sq[j]:>13,.0f}")
    ge = ev.geometric_error
    if ge is not None:
        print(f"geometric error (Table 2): {ge.mean_mm:.4f} +/- {ge.sd_mm:.4f} mm, map maximum "
              f"{ge.per_vertex_mm.max():.3f} mm")
    if ev.landmarks is not None:
        for k, (mean, sd, mx, count) in ev.landmarks.summary().items():
            print(f"landmark {k:<10} (Table 3): {mean:.2f} +/- {sd:.2f} mm, max {mx:.2f} (n = {count})")
    truth = []
    summary = json.loads((Path(model_dir) / "summary.json").read_text())
    scans = Path(summary.get("input_dir", ""))
    for name in ev.names:
        p = scans / f"{name}.truth.json"
        if p.is_file():
            truth.append(list(json.loads(p.read_text())["dimensions_mm"].values()))
    print("dimensions (Table 1), mm:   width          depth          height         height with stalk")
    # the generator's are of the body in its own frame; its larger horizontal extent is listed as the width
    print("  measured          " + "".join(f"{m:6.1f} +/- {sd:<4.1f} " for m, sd in zip(d.mean, d.sd))
          + f"{d.overall_height.mean():6.1f} +/- {d.overall_height.std(ddof=1):.1f}")
    if len(truth) == len(ev.names):
        t = np.sort(np.array(truth)[:, :2], axis=1)[:, ::-1]  # the generator's width/depth, larger first
        t = np.column_stack([t, np.array(truth)[:, 2]])
        print("  generator         " + "".join(f"{m:6.1f} +/- {sd:<4.1f} " for m, sd in zip(t.mean(0), t.std(0, ddof=1))))
    for note in ev.notes:
        print(f"note: {note}")
    print(f"report: {ev.files['report']}")
    print(json.dumps({
        "n": len(ev.names), "points": ev.n_points, "seconds": seconds, "timings": dict(ev.timings),
        "peak_mb": peak, "compactness_5": float(c.ratio[min(4, len(c.ratio) - 1)]),
        "generalization_mm": g.mean_mm[:10].round(4).tolist(), "specificity_mm": s.mean_mm[:10].round(4).tolist(),
        "geometric_error_mm": None if ge is None else ge.mean_mm,
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
