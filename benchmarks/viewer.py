"""Benchmark of `hortishape view`: the page of a built model, opened in headless Chromium.

Writes the viewer page of a model (by default the demo's: run ``hortishape demo``
first), opens it in Debian's Chromium with software WebGL (driven by playwright),
and prints:

- the page's size and the time to write it;
- for the mean, ``#b=3`` and ``#b=0,3``: the time until the page has drawn, the
  share of the plot's pixels that are not background, console errors, and any
  request that is not to the file itself (there should be none);
- how far apart the three pictures are (share of pixels that differ visibly);
- the time one slider move takes to redraw (median of 15);
- the largest distance between the vertices the page draws and the model's
  own instance, at 3 SD on every embedded mode.

The three screenshots are written beside the page (``--out``), and one of the
whole page at ``#b=2,0,-1.5&c=displacement`` (``page.png``, the README's picture).

Run::

    hortishape demo                                   # once: builds hortishape-demo/model
    python benchmarks/viewer.py                       # its page, 20 modes
    python benchmarks/viewer.py --model DIR --modes 10 --out /tmp/viewer
"""

from __future__ import annotations

import argparse
import io
import shutil
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=Path("hortishape-demo/model"), help="built folder or model file")
    ap.add_argument("--modes", type=int, default=20)
    ap.add_argument("--out", type=Path, default=Path("viewer-benchmark"), help="folder for the page and pictures")
    args = ap.parse_args(argv)

    from PIL import Image
    from playwright.sync_api import sync_playwright

    from hortishape.model import ShapeModel
    from hortishape.view import view_model

    if not args.model.exists():
        print(f"{args.model}: not found; run 'hortishape demo' first or give --model", file=sys.stderr)
        return 1
    chromium = shutil.which("chromium")
    if chromium is None:
        print("no chromium: apt-get install chromium", file=sys.stderr)
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    page_file = view_model(args.model, args.out / "viewer.html", n_modes=args.modes)
    write_s = time.perf_counter() - t0
    model_file = args.model / "model.h5" if args.model.is_dir() else args.model
    model = ShapeModel.load(model_file)
    print(f"model {model_file}: {model.n_points_:,} vertices, {model.n_components_} modes, "
          f"{model.n_samples_} instances")
    print(f"page {page_file.path}: {page_file.size_bytes / 1e6:.2f} MB, {page_file.n_modes} modes, "
          f"written in {write_s:.2f} s; colourings {', '.join(page_file.colourings)}; "
          f"landmarks {', '.join(page_file.landmarks) or 'none'}")

    pictures = {}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=ARGS)
        for name, fragment in (("mean", ""), ("b3", "#b=3"), ("b0-3", "#b=0,3")):
            tab = browser.new_page(viewport={"width": 1200, "height": 800})
            errors, requests = [], []
            tab.on("console", lambda m: m.type == "error" and errors.append(m.text))
            tab.on("pageerror", lambda e: errors.append(str(e)))
            tab.on("request", lambda r: requests.append(r.url))
            t = time.perf_counter()
            tab.goto(page_file.path.resolve().as_uri() + fragment)
            tab.wait_for_function("window.hortishape && window.hortishape.ready", timeout=300_000)
            load_s = time.perf_counter() - t
            png = tab.locator("#hs-plot").screenshot()
            (args.out / f"{name}.png").write_bytes(png)
            pic = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)
            pictures[name] = pic
            drawn = float((np.abs(pic - 255).max(axis=2) > 30).mean())
            outside = [u for u in requests if not u.startswith(("file:", "data:", "blob:"))]
            print(f"{name + fragment:>12}: drawn in {load_s:.1f} s, {100 * drawn:.1f} % of the plot drawn, "
                  f"{len(errors)} console errors, {len(outside)} requests outside the file")
            for e in errors[:5]:
                print(f"    console: {e}")
            if name == "mean":
                times = []
                for i in range(15):
                    n = tab.evaluate("window.hortishape.renders")
                    t = time.perf_counter()
                    tab.evaluate(f"(() => {{ const s = document.getElementById('hs-mode-1'); s.value = {(-1) ** i * 2};"
                                 " s.dispatchEvent(new Event('input')); })()")
                    tab.wait_for_function(f"window.hortishape.renders > {n}")
                    times.append(time.perf_counter() - t)
                print(f"    slider move to redraw: median {statistics.median(times):.3f} s "
                      f"(min {min(times):.3f}, max {max(times):.3f})")
                b = [3.0] * page_file.n_modes
                got = np.asarray(tab.evaluate(f"Array.from(window.hortishape.shapeOf({b}))")).reshape(-1, 3)
                want = model.instance(np.pad(b, (0, model.n_components_ - len(b))))
                print(f"    vertices drawn vs the model's instance at +3 SD on {len(b)} modes: max "
                      f"{np.linalg.norm(got - want, axis=1).max():.4f} mm (bound {page_file.quantization_mm:.4f})")
            tab.close()
        # the whole page, as a user sees it (docs/images/viewer.png)
        tab = browser.new_page(viewport={"width": 1200, "height": 760})
        tab.goto(page_file.path.resolve().as_uri() + "#b=2,0,-1.5&c=displacement")
        tab.wait_for_function("window.hortishape && window.hortishape.ready", timeout=300_000)
        tab.screenshot(path=str(args.out / "page.png"))
        tab.close()
        browser.close()

    def changed(a, b):
        return 100 * float((np.abs(pictures[a] - pictures[b]).max(axis=2) > 24).mean())

    print(f"pixels that differ: mean vs #b=3 {changed('mean', 'b3'):.1f} %, mean vs #b=0,3 "
          f"{changed('mean', 'b0-3'):.1f} %, #b=3 vs #b=0,3 {changed('b3', 'b0-3'):.1f} %")
    print(f"pictures: {', '.join(str(args.out / f'{n}.png') for n in [*pictures, 'page'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
