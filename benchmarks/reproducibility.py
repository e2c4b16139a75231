"""The same registrations computed as other machines compute them: how far apart they end.

A registration is a long chain of floating-point sums (least squares, sparse
Cholesky solves, ray casts in float32), and what decides their last digits
differs between machines: the BLAS kernels OpenBLAS picks for the CPU, the
SIMD loops numpy picks, the number of threads that split a sum, Embree or
libigl casting the rays. Each environment below registers the same pairs in a
fresh process:

* ``base``: as installed, on this CPU, with all its cores;
* ``1-thread``: BLAS and the ray queries on one thread (as a batch worker runs);
* ``avx2``: OpenBLAS's kernels for an AMD Zen (``OPENBLAS_CORETYPE=Zen``) and
  numpy's without AVX-512 (``NPY_DISABLE_CPU_FEATURES``): how an AMD EPYC
  without AVX-512 computes (on such a machine, this is ``base``);
* ``no-embree``: ``embreex`` hidden, so libigl casts the rays (macOS, ARM);
* ``jitter``: the targets' vertices moved at random by 1e-9 mm.

For each it prints, against ``base``: the largest distance between the same
registered vertex (median and largest over the pairs), and the largest change
of each figure a user reads (geometric error, landmark errors, orientation
and its confidence; ``benchmarks/registration.py`` defines them). Same
environment twice gives identical vertices (``--repeat``).

Run::

    python benchmarks/reproducibility.py                      # 10 pairs: 2 of each product
    python benchmarks/reproducibility.py --products apple --targets 5 --envs base avx2

The pairs are the registration benchmark's tuning set (seeds from 1000,
random poses): what is measured here is not accuracy but how much of a
result the machine decides.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _no_avx512() -> str:
    """The AVX-512 loops this numpy dispatches to on this CPU (none on an AMD EPYC), as .ci/run finds them."""
    try:
        from numpy._core import _multiarray_umath as m
    except ImportError:  # numpy 1.x
        from numpy.core import _multiarray_umath as m
    return " ".join(f for f in m.__cpu_dispatch__ if m.__cpu_features__.get(f) and ("512" in f or f == "X86_V4"))


ENVIRONMENTS = {
    "base": {},
    "1-thread": {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "HORTISHAPE_RAY_THREADS": "1"},
    "avx2": {"OPENBLAS_CORETYPE": "Zen", "NPY_DISABLE_CPU_FEATURES": _no_avx512()},
    "no-embree": {"HORTISHAPE_HIDE_EMBREEX": "1"},
    "jitter": {"HORTISHAPE_JITTER_MM": "1e-9"},
}
FIGURES = ("geom", "dense", "stalk", "bottom", "axis", "rot", "confidence")


def _registration_benchmark():
    spec = importlib.util.spec_from_file_location("bench_registration", HERE / "registration.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def worker(cases: list[list[str]], out: str) -> None:
    """Register each ``[reference, target, ...]`` list of files; save vertices and figures to ``out`` (npz)."""
    if os.environ.get("HORTISHAPE_HIDE_EMBREEX"):
        sys.modules["embreex"] = None  # importing embreex now raises ImportError
    warnings.simplefilter("ignore")
    from hortishape.mesh import Mesh
    from hortishape.registration import RegistrationConfig, correspondences, register

    if os.environ.get("HORTISHAPE_RAY_THREADS"):
        correspondences.RAY_THREADS = int(os.environ["HORTISHAPE_RAY_THREADS"])
    jitter = float(os.environ.get("HORTISHAPE_JITTER_MM", "0"))
    bench = _registration_benchmark()
    saved, figures = {}, []
    rng = np.random.default_rng(0)
    for files in cases:
        ref = bench._load(files[0])
        prepared = bench.prepare(ref, Path(files[0]).name.split("_")[0])
        for fn in files[1:]:
            tgt = bench._load(fn)
            scan = tgt["scan"]
            if jitter:
                scan = Mesh(scan.vertices + rng.uniform(-jitter, jitter, scan.vertices.shape), scan.faces)
            reg = register(prepared[0], scan, RegistrationConfig())
            saved[Path(fn).stem] = reg.vertices
            figures.append(bench.measure_registration(reg, ref, tgt, prepared))
    np.savez(out, figures=json.dumps(figures), **saved)


def run_environment(name: str, cases, folder: Path) -> tuple[dict, list[dict], float]:
    out = folder / f"{name}.npz"
    env = {**os.environ, **ENVIRONMENTS[name]}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, __file__, "--worker", json.dumps(cases), str(out)], env=env, check=True)
    elapsed = time.perf_counter() - t0
    data = np.load(out)
    figures = json.loads(str(data["figures"]))
    return {k: data[k] for k in data.files if k != "figures"}, figures, elapsed


def compare(base, other) -> dict:
    (bv, bf), (ov, of) = base, other
    moved = [float(np.linalg.norm(bv[k] - ov[k], axis=1).max()) for k in bv]
    return {
        "vertex_median": float(np.median(moved)),
        "vertex_max": float(np.max(moved)),
        "identical": sum(np.array_equal(bv[k], ov[k]) for k in bv),
        **{f: max(abs(a[f] - b[f]) for a, b in zip(bf, of)) for f in FIGURES},
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--products", nargs="+", default=["apple", "pepper", "zucchini", "pear", "banana"])
    ap.add_argument("--targets", type=int, default=2, help="targets per product (instance 0 is the reference)")
    ap.add_argument("--pose", default="random")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--envs", nargs="+", default=list(ENVIRONMENTS), choices=list(ENVIRONMENTS))
    ap.add_argument("--repeat", action="store_true", help="also run base a second time (is it bit-identical?)")
    ap.add_argument("--cache", default=os.environ.get("HORTISHAPE_BENCH_CACHE", "/tmp/hortishape-bench"))
    ap.add_argument("--json", help="write the comparison to this file")
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker(json.loads(args.worker[0]), args.worker[1])
        return 0
    bench = _registration_benchmark()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    cases = [[str(f) for f in bench.make_cases(p, args.pose, args.targets + 1, cache, seed=args.seed)]
             for p in args.products]
    n_pairs = sum(len(c) - 1 for c in cases)
    envs = ["base"] + [e for e in args.envs if e != "base"] + (["base"] if args.repeat else [])
    print(f"{n_pairs} pairs ({', '.join(args.products)}; seeds {args.seed}..{args.seed + args.targets}, "
          f"pose {args.pose}), numpy {np.__version__}", flush=True)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        results = {}
        for i, name in enumerate(envs):
            label = name if i < len(envs) - 1 or not args.repeat else "base again"
            results[label] = run_environment(name, cases, Path(tmp))
            print(f"  {label}: {results[label][2]:.0f} s", flush=True)
    base = results["base"][:2]
    print(f"\n{'environment':12s} {'identical':>9s} {'vertex, median':>15s} {'max (mm)':>9s}  "
          + "  ".join(f"{f:>10s}" for f in FIGURES))
    print(f"{'base':12s} values: " + "  ".join(
        f"{f} {np.median([r[f] for r in base[1]]):.4g}" for f in FIGURES) + " (medians)")
    for label, (vertices, figures, _) in results.items():
        if label == "base":
            continue
        c = compare(base, (vertices, figures))
        rows[label] = c
        print(f"{label:12s} {c['identical']:>4d} of {n_pairs:<2d} {c['vertex_median']:15.2e} {c['vertex_max']:9.2e}  "
              + "  ".join(f"{c[f]:10.2e}" for f in FIGURES))
    print("\nfigures: the largest change over the pairs; geom, dense, stalk, bottom in mm; axis, rot in degrees")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
