"""The ``hortishape`` command line: parses, calls the library, prints.

Every subcommand is a few lines over a public function. Errors a user can
cause (bad files, bad options) become one line on stderr and exit status 1.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

from . import __version__
from .errors import HortishapeError

EPILOG = (
    "All lengths are in millimetres. Method: Danckaers et al. (2017), Building 3D statistical "
    "shape models of horticultural products, Food Bioprocess Technol 10:2100-2112."
)


class _Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    pass


def _progress(total: int, desc: str, unit: str = "instance") -> Callable:
    """A tqdm wrapper for an iterator of ``total`` items, on stderr."""
    from tqdm.auto import tqdm

    def wrap(iterable):
        return tqdm(iterable, total=total, desc=desc, unit=unit, file=sys.stderr,
                    disable=None, dynamic_ncols=True)

    return wrap


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a number of at least 1, got {value}")
    return value


def _non_negative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"expected a number of at least 0, got {text}")
    return value


# --------------------------------------------------------------------------
# synth
# --------------------------------------------------------------------------


def _add_synth(sub) -> None:
    from .synth import PRODUCTS

    products = "\n".join(f"  {name:<9} {spec.description}" for name, spec in PRODUCTS.items())
    p = sub.add_parser(
        "synth",
        help="make a synthetic population of scans with ground truth",
        description=(
            "Make N synthetic scans of one product, as X-ray CT surfaces (marching cubes, "
            "50k-150k vertices) in random scanner poses, with ground truth beside each mesh:\n"
            "  OUT/<product>_<i>.ply         the scan (binary PLY, mm)\n"
            "  OUT/<product>_<i>.truth.json  pose, landmarks (stalk_tip, bottom), dimensions\n"
            "  OUT/<product>_<i>.truth.npz   canonical body-frame coordinates of every vertex\n"
            "  OUT/volumes/<product>_<i>.mha a CT-like volume (with --volumes)\n\n"
            "The same canonical coordinates mark the same anatomical place on every instance, "
            "so the true correspondence between any two instances is known.\n\n"
            f"Products:\n{products}"
        ),
        epilog=EPILOG,
        formatter_class=_Formatter,
    )
    p.add_argument("product", choices=list(PRODUCTS), metavar="CLASS", help="product: " + ", ".join(PRODUCTS))
    p.add_argument("n", type=_positive_int, metavar="N", help="number of instances")
    p.add_argument("out", type=Path, metavar="OUT", help="output folder (created if needed)")
    p.add_argument("--seed", type=int, default=0, help="random seed; the same seed gives the same population")
    p.add_argument("--pose", choices=["upright", "random"], default="upright",
                   help="scanner pose: standing on the bed (turned, slightly tilted) or any rotation")
    p.add_argument("--noise", type=_non_negative_float, default=0.0, metavar="MM",
                   help="standard deviation of scanner noise along the normals, mm")
    p.add_argument("--vertices", type=_positive_int, default=None, metavar="V",
                   help="about how many vertices per scan (default: drawn between 70,000 and 130,000)")
    p.add_argument("--volumes", action="store_true", help="also write a CT-like intensity volume per instance")
    p.add_argument("--jobs", type=_positive_int, default=None, metavar="J",
                   help="parallel processes (default: all cores)")
    p.set_defaults(run=_run_synth)


def _run_synth(args) -> int:
    from .synth import write_population

    start = time.perf_counter()
    rows = write_population(
        args.product, args.n, args.out, random_state=args.seed, pose=args.pose, noise=args.noise,
        n_vertices=args.vertices, volumes=args.volumes, n_jobs=args.jobs,
        progress=_progress(args.n, f"synth {args.product}"),
    )
    print(f"{'instance':<14}{'vertices':>10}{'width':>9}{'depth':>9}{'height':>9}   (mm)")
    for r in rows:
        w, d, h = r["dimensions_mm"]
        print(f"{r['name']:<14}{r['n_vertices']:>10,}{w:>9.1f}{d:>9.1f}{h:>9.1f}")
    print(f"wrote {len(rows)} {args.product} scans with ground truth to {args.out} "
          f"in {time.perf_counter() - start:.1f} s")
    return 0


# --------------------------------------------------------------------------
# entry point
# --------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hortishape",
        description=(
            "Statistical shape models of fruit and vegetables: make or read scans, put them in "
            "dense correspondence, build and evaluate a PCA shape model, export CAD surfaces.\n"
            "Run 'hortishape COMMAND --help' for the options of a command."
        ),
        epilog=EPILOG,
        formatter_class=_Formatter,
    )
    parser.add_argument("--version", action="version", version=f"hortishape {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    sub.required = True
    for add in _COMMANDS:
        add(sub)
    return parser


_COMMANDS = [_add_synth]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except HortishapeError as exc:
        print(f"hortishape: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # a folder that cannot be written, a disk that is full
        name = f" {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"hortishape: error:{name}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("hortishape: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
