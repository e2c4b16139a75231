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
# register
# --------------------------------------------------------------------------


def _add_registration_options(p) -> None:
    """Options of the registration (RN-ICP-T); the defaults are the paper's."""
    g = p.add_argument_group("registration (defaults: the paper's)")
    g.add_argument("--iterations", type=_positive_int, default=30,
                   help="length of the stiffness schedule")
    g.add_argument("--stiffness", type=float, nargs=2, default=(50.0, 1.0), metavar=("START", "END"),
                   help="stiffness beta, decreasing linearly from START to END")
    g.add_argument("--max-angle", type=float, default=30.0, metavar="DEG",
                   help="correspondence filter: largest angle between the normals")
    g.add_argument("--distance-factor", type=float, default=20.0, metavar="F",
                   help="correspondence filter: reject hits farther than F x the previous mean distance")
    g.add_argument("--tolerance", type=float, default=1e-3,
                   help="convergence when |d_t - d_(t-1)| / d_t falls below this")
    g.add_argument("--orientation", choices=["search", "pca", "none"], default="search",
                   help="initial alignment: try all principal-axis rotations and keep the best after a "
                        "short elastic fit (search), the paper's eq. 7 alone (pca), or none")


def _registration_config(args):
    from .register import RegistrationConfig

    try:
        return RegistrationConfig(
            n_iterations=args.iterations, beta_start=args.stiffness[0], beta_end=args.stiffness[1],
            max_angle=args.max_angle, distance_factor=args.distance_factor, tolerance=args.tolerance,
            max_iterations=max(50, args.iterations + 20), orientation=args.orientation,
        )
    except ValueError as exc:
        raise HortishapeError(str(exc)) from None


def _add_register(sub) -> None:
    p = sub.add_parser(
        "register",
        help="register a reference surface to scans (dense correspondence)",
        description=(
            "Deform one reference surface onto each target scan by elastic registration (RN-ICP-T, "
            "paper section 2.2.2): principal-axis alignment, then iterations of normal-ray "
            "correspondences, a rigid step and the translation-only elastic step of eq. 8 with a "
            "stiffness decreasing from 50 to 1.\n\n"
            "Writes for every TARGET:\n"
            "  DIR/<target stem>.ply   the registered reference in the target's coordinates: the same\n"
            "                          vertex count, order and faces for every target, so vertex j\n"
            "                          is the same anatomical point on all of them\n"
            "  DIR/<target stem>.json  the log: per-iteration stiffness, mean distance, kept\n"
            "                          correspondences, seconds; the rigid transform\n\n"
            "Targets run in parallel; a target that cannot be used is reported and skipped "
            "(--strict stops instead); run again and finished targets are not redone."
        ),
        epilog=EPILOG,
        formatter_class=_Formatter,
    )
    p.add_argument("reference", type=Path, metavar="REFERENCE", help="reference surface (mesh file)")
    p.add_argument("targets", type=Path, nargs="+", metavar="TARGET", help="target scans (mesh files)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--points", type=_positive_int, default=30000, metavar="N",
                   help="resample the reference uniformly to N vertices first (the paper: 30,000 for "
                        "apples, 40,000 peppers, 13,000 zucchini)")
    p.add_argument("--no-resample", action="store_true",
                   help="use the reference's own vertices (e.g. a mean shape) instead of resampling")
    p.add_argument("--jobs", type=_positive_int, default=None, metavar="J",
                   help="parallel processes (default: all cores)")
    p.add_argument("--strict", action="store_true", help="stop at the first target that fails")
    _add_registration_options(p)
    p.set_defaults(run=_run_register)


def _print_results(results) -> int:
    """Print a table of batch results; returns the number that failed."""
    print(f"{'scan':<24}{'seconds':>9}{'iter':>6}{'d_t mm':>9}{'geom mm':>9}{'kept':>7}  note")
    failed = 0
    for r in results:
        if r.ok:
            note = ("resumed" if r.resumed else "") + ("" if r.converged else " not converged")
            print(f"{r.name:<24}{r.seconds:>9.1f}{r.iterations:>6}{r.mean_distance:>9.3f}"
                  f"{r.geometric_error:>9.4f}{r.kept_fraction:>7.0%}  {note.strip()}")
        else:
            failed += 1
            print(f"{r.name:<24}{'skipped':>9}  {r.error}")
            print(f"hortishape: skipped {r.error}", file=sys.stderr)
    return failed


def _run_register(args) -> int:
    from .io import read_mesh
    from .pipeline import register_files
    from .register import prepare_reference

    config = _registration_config(args)
    start = time.perf_counter()
    reference = read_mesh(args.reference)
    print(f"preparing the reference {args.reference} ({reference.n_vertices:,} vertices"
          + ("" if args.no_resample else f" -> {args.points:,}") + ")", file=sys.stderr)
    template = prepare_reference(reference, None if args.no_resample else args.points)
    results = register_files(template, args.targets, args.out, config=config, n_jobs=args.jobs,
                             strict=args.strict, progress=_progress(len(args.targets), "register", "scan"))
    failed = _print_results(results)
    print(f"registered {len(results) - failed} of {len(results)} scans to {args.out} "
          f"in {time.perf_counter() - start:.1f} s")
    return 1 if failed == len(results) else 0


# --------------------------------------------------------------------------
# build, sample, modes, fit, demo
# --------------------------------------------------------------------------


def _stage_progress(total: int, desc: str):
    return _progress(total, desc, "scan")


def _modes_arg(text: str) -> int | float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of modes or a fraction, got {text!r}") from None
    if value <= 0 or (value > 1 and value != int(value)):
        raise argparse.ArgumentTypeError("expected a whole number of modes, or a fraction of the variance in (0, 1]")
    return value if value <= 1 and "." in text else int(value)


def _add_build(sub) -> None:
    p = sub.add_parser(
        "build",
        help="build a shape model from a folder of scans",
        description=(
            "Build a statistical shape model from every mesh in INPUT_DIR (paper section 2.2.3):\n"
            "  1. check every scan (closed, one component, millimetres) and pick the reference\n"
            "     (--reference, or the scan nearest the population's median size);\n"
            "  2. resample it to --points vertices and register it to every scan;\n"
            "  3. register the mean of those surfaces to every scan again (the paper's second pass,\n"
            "     against bias towards the first reference);\n"
            "  4. align the corresponded surfaces by generalized Procrustes (rotation, translation);\n"
            "  5. PCA: mean, modes and variances (eqs. 9-12).\n\n"
            "Writes OUT/model.h5 (Statismo v0.9 layout, readable by Statismo and Scalismo),\n"
            "OUT/registered/<stem>.ply (each scan's corresponded surface in its own coordinates),\n"
            "OUT/aligned/<stem>.ply (Procrustes-aligned), OUT/summary.json.\n\n"
            "Scans run in parallel; a bad scan is reported and skipped (--strict stops instead); "
            "run the same build again and finished registrations are not redone."
        ),
        epilog=EPILOG,
        formatter_class=_Formatter,
    )
    p.add_argument("input_dir", type=Path, metavar="INPUT_DIR", help="folder of scans (PLY, STL, OBJ, OFF, VTK, VTP)")
    p.add_argument("--out", type=Path, required=True, metavar="OUT", help="output folder")
    p.add_argument("--reference", type=Path, default=None, metavar="FILE",
                   help="the first pass's reference scan (default: the scan nearest the median size)")
    p.add_argument("--points", type=_positive_int, default=30000, metavar="N",
                   help="vertices of the resampled reference (the paper: 30,000 apple, 40,000 pepper, "
                        "13,000 zucchini)")
    p.add_argument("--modes", type=_modes_arg, default=None, metavar="K",
                   help="modes to keep: a number, or a fraction of the variance such as 0.99 (default: all)")
    p.add_argument("--scaling", action="store_true",
                   help="remove size in the Procrustes alignment (then size is not a mode)")
    p.add_argument("--jobs", type=_positive_int, default=None, metavar="J",
                   help="parallel registrations (default: all cores)")
    p.add_argument("--strict", action="store_true", help="stop at the first bad scan instead of skipping it")
    _add_registration_options(p)
    p.set_defaults(run=_run_build)


def _print_build(result) -> None:
    print(f"reference: {result.reference}")
    print("second pass (the model's correspondences):")
    _print_results(result.second_pass)
    for path, reason in result.skipped:
        print(f"skipped {path}: {reason}")
    var = result.explained_variance
    share = var / var.sum() if var.size else var
    cumulative = share.cumsum()
    print(f"model: {len(result.names)} instances, {len(var)} modes")
    # 1 SD of a mode moves the vertices by this much (root mean square)
    print(f"{'mode':>6}{'1 SD moves a vertex (RMS) mm':>30}{'variance %':>12}{'cumulative %':>14}")
    for k in range(min(10, len(var))):
        rms = (var[k] / result.n_points) ** 0.5
        print(f"{k + 1:>6}{rms:>30.2f}{100 * share[k]:>12.1f}{100 * cumulative[k]:>14.1f}")
    print(f"wrote {result.model_path} in {result.seconds:.1f} s")


def _run_build(args) -> int:
    from .pipeline import build_model

    result = build_model(
        args.input_dir, args.out, reference=args.reference, n_points=args.points, n_modes=args.modes,
        n_jobs=args.jobs, strict=args.strict, config=_registration_config(args), scaling=args.scaling,
        progress=_stage_progress,
    )
    _print_build(result)
    return 0


def _load_model(path: Path):
    from .model import ShapeModel

    return ShapeModel.load(path)


def _add_sample(sub) -> None:
    p = sub.add_parser(
        "sample", help="draw random new shapes from a model",
        description=("Draw N random shapes from MODEL (a model.h5): the coefficients of the first --modes "
                     "modes come from a standard normal distribution truncated at +/- --truncate standard "
                     "deviations (paper section 3.2, Fig. 8). Writes DIR/sample_000.ply ... and "
                     "DIR/samples.png."),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("model", type=Path, metavar="MODEL", help="model file (model.h5)")
    p.add_argument("n", type=_positive_int, metavar="N", help="number of shapes")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--modes", type=_positive_int, default=5, help="modes to vary (the paper: 5)")
    p.add_argument("--truncate", type=float, default=3.0, metavar="SD", help="truncation, in standard deviations")
    p.add_argument("--seed", type=int, default=None, help="random seed")
    p.add_argument("--no-picture", action="store_true", help="skip the picture")
    p.set_defaults(run=_run_sample)


def _run_sample(args) -> int:
    from .demo import write_samples

    model = _load_model(args.model)
    paths, pic = write_samples(model, args.out, args.n, modes=args.modes, truncate=args.truncate,
                               random_state=args.seed, picture=not args.no_picture)
    print(f"wrote {len(paths)} samples to {args.out}" + (f" (picture: {pic})" if pic else ""))
    return 0


def _add_modes(sub) -> None:
    p = sub.add_parser(
        "modes", help="write and picture the mean +/- 3 SD shapes of the first modes",
        description=("Write the mean and the mean +/- SD shapes of the first modes of MODEL as meshes "
                     "(DIR/mean.ply, DIR/mode1_minus3sd.ply, ...) and a picture grid of them, front and top "
                     "view (DIR/modes.png, the paper's Fig. 7). The pictures show the model in its own "
                     "frame with +z up: that of the first scan, so stalk up when the scans stood upright."),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("model", type=Path, metavar="MODEL", help="model file (model.h5)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--modes", type=_positive_int, default=3, help="number of modes")
    p.add_argument("--sd", type=float, default=3.0, help="standard deviations either side of the mean")
    p.set_defaults(run=_run_modes)


def _run_modes(args) -> int:
    from .report import render_modes, write_mode_meshes

    model = _load_model(args.model)
    n = min(args.modes, model.n_components_)
    paths = write_mode_meshes(model, args.out, n_modes=n, sd=args.sd)
    pic = render_modes(model, Path(args.out) / "modes.png", n_modes=n, sd=args.sd)
    print(f"wrote {len(paths)} meshes and {pic}")
    return 0


def _add_fit(sub) -> None:
    p = sub.add_parser(
        "fit", help="describe a new scan by the model's coefficients",
        description=("Register the model's mean to SCAN, then find the rigid pose C and the shape "
                     "coefficients b of eq. 13 (y = C(x_bar + Phi b)) that best explain the corresponded "
                     "points. Prints b (in standard deviations), the Mahalanobis distance and the residual "
                     "distances, and writes the reconstruction in the scan's coordinates."),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("model", type=Path, metavar="MODEL", help="model file (model.h5)")
    p.add_argument("scan", type=Path, metavar="SCAN", help="the new scan (mesh file, mm)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="reconstruction mesh (default: <scan stem>_fit.ply beside the current folder)")
    p.add_argument("--modes", type=_positive_int, default=None, help="modes to fit (default: all)")
    p.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write the figures as JSON")
    _add_registration_options(p)
    p.set_defaults(run=_run_fit)


def _run_fit(args) -> int:
    import json

    from .io import read_mesh, write_mesh
    from .pipeline import fit_scan

    model = _load_model(args.model)
    scan = read_mesh(args.scan)
    fit = fit_scan(model, scan, modes=args.modes, config=_registration_config(args))
    out = args.out or Path(f"{args.scan.stem}_fit.ply")
    write_mesh(out, fit.reconstruction, model.faces_)
    sds = " ".join(f"{b:+.2f}" for b in fit.coefficients[: min(10, len(fit.coefficients))])
    print(f"coefficients b (SD, first {min(10, len(fit.coefficients))} modes): {sds}")
    print(f"Mahalanobis distance: {fit.mahalanobis:.2f} SD")
    print(f"residual to the corresponded points: mean {fit.residual_mean:.3f} mm, max {fit.residual_max:.3f} mm")
    print(f"residual to the scan surface: mean {fit.surface_mean:.3f} mm, max {fit.surface_max:.3f} mm")
    print(f"wrote {out}")
    if args.json:
        args.json.write_text(json.dumps({
            "scan": str(args.scan), "units": "mm", "coefficients_sd": fit.coefficients.tolist(),
            "pose": fit.pose.tolist(), "mahalanobis": fit.mahalanobis,
            "residual_mean_mm": fit.residual_mean, "residual_max_mm": fit.residual_max,
            "surface_mean_mm": fit.surface_mean, "surface_max_mm": fit.surface_max,
        }, indent=1))
    return 0


def _add_demo(sub) -> None:
    p = sub.add_parser(
        "demo", help="the whole pipeline on built-in synthetic apples",
        description=("Make a synthetic population of 30 apples (CT-like surfaces of ~100k vertices), build "
                     "their shape model with the paper's settings (30,000-vertex reference, two registration "
                     "passes, Procrustes, PCA), draw five new apples from it and picture the first modes. "
                     "Prints where everything is."),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("--out", type=Path, default=Path("hortishape-demo"), metavar="DIR", help="output folder")
    p.add_argument("--product", default="apple", choices=["apple", "pepper", "zucchini", "pear", "banana"],
                   help="synthetic product")
    p.add_argument("--n", type=_positive_int, default=30, help="population size")
    p.add_argument("--points", type=_positive_int, default=30000, metavar="N", help="reference vertices")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--jobs", type=_positive_int, default=None, metavar="J", help="parallel processes")
    p.set_defaults(run=_run_demo)


def _run_demo(args) -> int:
    from .demo import run_demo

    r = run_demo(args.out, product=args.product, n=args.n, seed=args.seed, n_points=args.points,
                 n_jobs=args.jobs, progress=_stage_progress)
    _print_build(r.build)
    print()
    print(f"demo done in {r.seconds:.0f} s; everything is in {r.out_dir}:")
    print(f"  scans with ground truth   {r.scans}/")
    print(f"  the model                 {r.build.model_path}")
    print(f"  corresponded surfaces     {r.build.out_dir / 'registered'}/")
    print(f"  five new {args.product}s{' ' * max(0, 12 - len(args.product))}   {r.samples_picture.parent}/ "
          f"(picture: {r.samples_picture})")
    print(f"  shape modes (Fig. 7)      {r.modes_picture}")
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


_COMMANDS = [_add_demo, _add_synth, _add_register, _add_build, _add_sample, _add_modes, _add_fit]


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
