"""Benchmark of `hortishape extract --split`: several products touching each other in one volume.

Trays made by :func:`hortishape.synth.make_tray` (products standing upright in rows, each moved
against its neighbours until their surfaces touch, or pushed ``--overlap`` mm into them as pressed
fruit are, on a plate reaching the volume's edges; CT-like, 1 mm voxels unless ``--voxel``), split
with :func:`hortishape.extract.split_products` and each product extracted with
:func:`hortishape.extract.extract_surface`. For each tray: products found against products made,
what was left out, and each product's volume against its true surface's (matched by position),
with the seconds of the split and of the extractions.

The split's constants were set on an apple tray of seed 3 (touching, 1 mm); the other products,
seeds and overlaps are the test.

Run::

    python benchmarks/split.py                        # apple, pear, pepper, zucchini, banana trays
    python benchmarks/split.py --products apple --seeds 3 4 5 --overlap 1.0
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np


def run(product: str, seed: int, n: int, overlap: float, voxel: float) -> dict:
    from hortishape.extract import extract_surface, split_products
    from hortishape.synth import make_tray

    tray = make_tray(product, n, random_state=seed, overlap=overlap, voxel_size=voxel, per_row=3)
    start = time.perf_counter()
    split = split_products(tray.volume)
    split_s = time.perf_counter() - start
    centres = np.array([i.mesh.vertices.mean(axis=0) for i in tray.instances])
    errors, genus = [], []
    start = time.perf_counter()
    for k, product_volume in enumerate(split.products):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ext = extract_surface(product_volume)
        j = int(np.argmin(np.linalg.norm(centres - split.centres[k], axis=1)))
        errors.append(ext.volume / tray.true_volumes[j] - 1.0)
        genus.append(ext.genus)
    return {"found": len(split.products), "made": n, "left_out": split.left_out, "errors": np.array(errors),
            "genus": genus, "split_s": split_s, "extract_s": time.perf_counter() - start,
            "shape": tray.volume.shape}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--products", nargs="+", default=["apple", "pear", "pepper", "zucchini", "banana"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[11])
    parser.add_argument("--n", type=int, default=6, help="products per tray")
    parser.add_argument("--overlap", type=float, default=0.0, help="mm each is pushed into its neighbours")
    parser.add_argument("--voxel", type=float, default=1.0, help="voxel size of the tray volume, mm")
    args = parser.parse_args()
    print(f"{'product':<10}{'seed':>5}{'voxels':>16}{'found':>7}{'max |dV| %':>12}{'mean dV %':>11}"
          f"{'genus':>7}{'split s':>9}{'extract s':>11}  left out")
    for product in args.products:
        for seed in args.seeds:
            r = run(product, seed, args.n, args.overlap, args.voxel)
            e = 100 * r["errors"]
            worst = f"{np.abs(e).max():.2f}" if e.size else "-"
            mean = f"{e.mean():+.2f}" if e.size else "-"
            print(f"{product:<10}{seed:>5}{'x'.join(map(str, r['shape'])):>16}{r['found']:>4}/{r['made']:<2}"
                  f"{worst:>12}{mean:>11}{max(r['genus'], default=0):>7}{r['split_s']:>9.1f}{r['extract_s']:>11.1f}"
                  f"  {'; '.join(r['left_out']) or '-'}")


if __name__ == "__main__":
    main()
