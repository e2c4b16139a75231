"""The split on real fruit shapes it was not tuned on: two YCB scans side by side in one CT-like volume.

Each fruit's CT-like volume is made by ``benchmarks/extract.py``'s ``real_shape_volume`` (the scan's own
surface in a random rotation, layers, noise; 0.6 mm voxels), the second moved along x until the two
surfaces touch, both resampled onto one grid (their intensities above the background added). The volume
is split (``hortishape.extract.split_products``) and each product extracted; each surface's volume is
compared with its scan's. Compare with ``extract_surface`` on each fruit's own volume (printed too), so
that what the split adds shows.

Run::

    python benchmarks/split_real.py
"""
import sys
import warnings

import numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).parent))
from extract import real_shape_volume
from scipy.ndimage import map_coordinates
from hortishape.io import Volume
from hortishape.synth import _touching_shift
from hortishape.extract import split_products, extract_surface
from hortishape.surface import signed_volume
for a, b, seed in (("013_apple", "015_peach", 1), ("017_orange", "014_lemon", 2), ("016_pear", "018_plum", 3)):
    (va, ta, _), (vb, tb, _) = real_shape_volume(a, "ct", seed), real_shape_volume(b, "ct", seed + 10)
    pa, pb = ta.vertices, tb.vertices
    off = np.array([pa[:, 0].max() - pb[:, 0].min() + 5, pa[:, 1].mean() - pb[:, 1].mean(), pa[:, 2].mean() - pb[:, 2].mean()])
    off[0] -= _touching_shift(pa, pb + off, 0, 0.0)
    h = float(va.spacing[0])
    allv = np.vstack([pa, pb + off]); lo = allv.min(0) - 8; hi = allv.max(0) + 8
    shape = tuple(int(s) for s in np.ceil((hi - lo) / h) + 1)
    g = np.stack(np.meshgrid(*[lo[i] + h * np.arange(shape[i]) for i in range(3)], indexing="ij"))
    total = np.zeros(shape, np.float32)
    bgs = []
    for v, o in ((va, np.zeros(3)), (vb, off)):
        d = v.data.astype(np.float32)
        bg = float(np.median(np.concatenate([d[0].ravel(), d[-1].ravel()])))
        bgs.append(bg)
        idx = np.linalg.solve(v.direction, (g.reshape(3, -1) - (v.origin + o)[:, None])) / v.spacing[:, None]
        total += map_coordinates(d, idx, order=1, mode="constant", cval=bg).reshape(shape) - bg
    vol = Volume((total + bgs[0]).astype(np.float32), h, lo)
    split = split_products(vol)
    truths = [(pa, abs(signed_volume(ta.vertices, ta.faces))), (pb + off, abs(signed_volume(tb.vertices, tb.faces)))]
    errs = []
    for k, p in enumerate(split.products):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore"); e = extract_surface(p)
        j = int(np.argmin([np.linalg.norm(t[0].mean(0) - split.centres[k]) for t in truths]))
        errs.append(f"{(a, b)[j]} {100 * (e.volume / truths[j][1] - 1):+.2f} % genus {e.genus}")
    alone = []
    for name, v, t in ((a, va, ta), (b, vb, tb)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            e = extract_surface(v)
        alone.append(f"{name} {100 * (e.volume / abs(signed_volume(t.vertices, t.faces)) - 1):+.2f} %")
    print(a, b, vol.shape, "found", len(split.products), "split:", errs, "alone:", alone,
          "left out:", list(split.left_out))
