"""The ``hortishape`` command line: parses, calls the library, prints.

Every subcommand is a few lines over a public function. Errors a user can
cause (bad files, bad options) become one line on stderr and exit status 1.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

from ._version import __version__
from .errors import HortishapeError

EPILOG = (
    "All lengths are in millimetres. Method: Danckaers et al. (2017), Building 3D statistical "
    "shape models of horticultural products, Food Bioprocess Technol 10:2100-2112."
)


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions as written; each option's default said once, where there is one to say."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (not action.option_strings or action.required or "default" in text.lower()
                or default is None or default is False or default is argparse.SUPPRESS):
            return text
        values = default if isinstance(default, (list, tuple)) else [default]
        shown = " ".join(f"{d:g}" if isinstance(d, float) else str(d) for d in values)
        return f"{text} (default: {shown.replace('%', '%%')})"


def _describe(item) -> str:
    """What a plain progress line says of a finished item of a batch."""
    if isinstance(item, list):  # the products of one volume
        return ";".join(_describe(x) for x in item)
    if isinstance(item, tuple) and item and isinstance(item[0], str):  # (name, ...) of a synthetic scan
        return f" {item[0]}"
    name = getattr(item, "name", None)
    if name is None:
        return ""
    if not getattr(item, "ok", True):
        return f" {name}: skipped: {item.error}"
    if hasattr(item, "geometric_error"):  # a registration
        confidence = getattr(item, "orientation_confidence", float("nan"))
        return (f" {name}: {'resumed' if item.resumed else 'registered'} in {item.seconds:.1f} s, "
                f"{item.iterations} iterations, d_t {item.mean_distance:.3f} mm, geometric error "
                f"{item.geometric_error:.4f} mm" + ("" if confidence != confidence else
                                                    f", orientation confidence {confidence:.2f}")
                + ("" if item.converged else ", not converged") + _holes_note(item, ", "))
    if hasattr(item, "volume_mm3"):  # an extraction
        n_warn = len(getattr(item, "warnings", ()))
        return (f" {name}: {'resumed' if item.resumed else 'extracted'} in {item.seconds:.1f} s, "
                f"{item.n_vertices:,} vertices, {item.volume_mm3 / 1000:.1f} mL"
                + (f", {n_warn} warning{'s' if n_warn > 1 else ''}" if n_warn else ""))
    return f" {name}"


def _progress(total: int, desc: str, unit: str = "instance") -> Callable:
    """A progress wrapper for an iterator of ``total`` items.

    On a terminal, a bar on stderr. Wherever the output goes to a file or a
    pipe (a log, CI), plain lines on stdout too: one when the stage starts,
    one per finished item (with its seconds and fit) and one at its end, so
    a log shows how far a long command got and what went wrong where.
    """
    from tqdm.auto import tqdm

    bar = sys.stderr.isatty()
    plain = not (bar and sys.stdout.isatty())

    def lines(iterable):
        start = time.perf_counter()
        print(f"{desc}: {total} {unit}{'s' if total != 1 else ''}", flush=True)
        k = 0
        for item in iterable:
            yield item
            k += 1
            print(f"{desc} {k}/{total}{_describe(item)}", flush=True)
        print(f"{desc}: {k} done in {time.perf_counter() - start:.1f} s", flush=True)

    def wrap(iterable):
        if plain:
            iterable = lines(iterable)
        return tqdm(iterable, total=total, desc=desc, unit=unit, file=sys.stderr,
                    disable=not bar, dynamic_ncols=True)

    return wrap


def _add_landmarks(p) -> None:
    p.add_argument("--landmarks", type=Path, default=None, metavar="FILE_OR_DIR",
                   help="named points per scan, in each scan's coordinates (JSON {stem: {name: [x, y, z]}}, CSV "
                        "instance,landmark,x,y,z, or a folder of <stem>.truth.json), e.g. stalk and calyx: "
                        "the names the reference shares with a scan fix its orientation (three or more not on "
                        "one line: the whole orientation; two: the axis through them) and are pulled together "
                        "(default: none)")


def _add_scale(p) -> None:
    p.add_argument("--scale", type=_positive_float, default=1.0, metavar="FACTOR",
                   help="multiply the scans' coordinates by FACTOR to give millimetres (1000 for scans in "
                        "metres); the files are not changed. Every product's size is checked: a fruit is "
                        "3-1500 mm across")


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


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
    families = "\n".join(f"  {name:<9} {', '.join(spec.families)}" for name, spec in PRODUCTS.items()
                         if len(spec.families) > 1)
    p = sub.add_parser(
        "synth",
        help="make a synthetic population of scans with ground truth",
        description=(
            "Make N synthetic scans of one product, as X-ray CT surfaces (marching cubes, "
            "50k-150k vertices) in random scanner poses, with ground truth beside each mesh:\n"
            "  OUT/<product>_<i>.ply         the scan (binary PLY, mm)\n"
            "  OUT/<product>_<i>.truth.json  pose, landmarks (stalk_tip, bottom), dimensions\n"
            "  OUT/<product>_<i>.truth.npz   canonical body-frame coordinates of every vertex\n"
            "  OUT/volumes/<product>_<i>.mha a CT-like volume (with --volumes)\n"
            "  OUT/volumes-mri/<product>_<i>.mha an MRI-like volume (with --volumes): a thin bright peel\n"
            "      over a dark rind, flesh in segments, a core open to the blossom end, 8-bit\n\n"
            "The same canonical coordinates mark the same anatomical place on every instance, "
            "so the true correspondence between any two instances is known.\n\n"
            f"Products:\n{products}\n\n"
            "Shape families (--family; 'standard' is what hortishape was tuned on, the others are held "
            f"out for testing it):\n{families}"
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
    p.add_argument("--volumes", action="store_true",
                   help="also write a CT-like and an MRI-like intensity volume per instance")
    p.add_argument("--view", type=_positive_int, default=None, metavar="K",
                   help="also write what a depth camera sees of each instance from K random directions: "
                        "OUT/views/<name>.view<j>.ply point clouds (1 point per mm^2 of outline, with normals, 0.2 mm "
                        "depth noise) and <name>.views.json (for 'fit --partial')")
    p.add_argument("--family", default="standard", metavar="F",
                   help="shape family of the product (listed above)")
    p.add_argument("--holes", type=_non_negative_float, default=0.0, metavar="SHARE",
                   help="cut this share of each scan's surface away in 1-3 round holes, as a structured-light "
                        "scanner leaves where it did not see (e.g. 0.05; 0: closed scans)")
    p.add_argument("--jobs", type=_positive_int, default=None, metavar="J",
                   help="parallel processes (default: all cores)")
    p.set_defaults(run=_run_synth)


def _run_synth(args) -> int:
    from .synth import write_population

    start = time.perf_counter()
    rows = write_population(
        args.product, args.n, args.out, random_state=args.seed, pose=args.pose, noise=args.noise,
        n_vertices=args.vertices, volumes=args.volumes, n_jobs=args.jobs, family=args.family, views=args.view or 0,
        holes=args.holes,
        progress=_progress(args.n, f"synth {args.product}"),
    )
    print(f"{'instance':<14}{'vertices':>10}{'width':>9}{'depth':>9}{'height':>9}   (mm)")
    for r in rows:
        w, d, h = r["dimensions_mm"]
        print(f"{r['name']:<14}{r['n_vertices']:>10,}{w:>9.1f}{d:>9.1f}{h:>9.1f}")
    if args.view:
        print(f"wrote {args.view} depth view(s) per instance: {Path(args.out) / 'views'}/<name>.view<j>.ply")
    print(f"wrote {len(rows)} {args.product} scans with ground truth to {args.out} "
          f"in {time.perf_counter() - start:.1f} s")
    return 0


# --------------------------------------------------------------------------
# extract
# --------------------------------------------------------------------------


def _add_extract(sub) -> None:
    p = sub.add_parser(
        "extract",
        help="extract the product's outer surface from CT or MRI volumes",
        description=(
            "Extract the outer surface of the product in each CT or MRI VOLUME (MHA/MHD, NRRD, NIfTI, a "
            "TIFF stack, a folder of TIFF slices, a DICOM series; spacing, origin and direction are applied, "
            "lengths in mm). A folder is searched with its subfolders, as 'build' searches its INPUT_DIR: "
            "DICOM series are found by content whatever their files are called (several per study folder, "
            "named after their folder or SeriesDescription), and what is not a volume is listed as passed "
            "over. A TIFF's voxel size comes from its OME/ImageJ metadata or the scanner's log beside it "
            "(SkyScan .log, Nikon .xtekct); a volume without one is refused: give --spacing.\n"
            "  1. the iso level on the boundary between air and the outermost tissue: half-way between\n"
            "     the background and product intensities (the histogram's peaks either side of Otsu's\n"
            "     threshold), or, where rays from outside meet a tissue of another brightness first (a\n"
            "     peel over a dark rind in MRI), the value on its outer edge from a model of the layers\n"
            "     fitted to the rays; or --level;\n"
            "  2. the outer surface by construction: everything that cannot be reached from outside is\n"
            "     inside (a pepper's hollow, an apple's core, the gaps between segments); gaps and\n"
            "     channels 1, 2, 4 or 8 mm wide are closed in turn until the product is one solid of\n"
            "     genus 0; where a peel thinner than a slice breaks up at the level, a lower level\n"
            "     half-way to its brightness across the slices decides what is inside when no gap width\n"
            "     closes the product, or when only 8 mm gaps do and it holds 1 % more than they made\n"
            "     whole (gaps that bridge an open pole only partly); the largest piece is kept, and a\n"
            "     support or scanner bed touching it dropped;\n"
            "  3. marching cubes on the intensity (sub-voxel accurate), one closed surface with outward\n"
            "     normals; Taubin smoothing (--smoothing) and decimation (--target-vertices).\n\n"
            "Writes for every VOLUME:\n"
            "  DIR/<stem>.ply   the surface (binary PLY, mm, world coordinates)\n"
            "  DIR/<stem>.json  levels and why, gaps closed, genus, voxel counts, warnings, seconds\n"
            "  DIR/<stem>.png   the surface beside two slices of the volume with its outline on them,\n"
            "                   the level's explanation and the warnings\n\n"
            "Warnings (on stderr and in the JSON): gaps that had to be closed, a product touching the\n"
            "volume's border, a size far from a fruit's, a support that takes most of the voxels. A\n"
            "product outside a fruit's sizes (10-600 mm, 1 mL-10 L) is refused with the voxel sizes that\n"
            "would make it one.\n\n"
            "A volume that cannot be used is reported in one line and skipped (--strict stops); run "
            "again and volumes already extracted with the same options are not redone."
        ),
        epilog=EPILOG,
        formatter_class=_Formatter,
    )
    p.add_argument("volumes", type=Path, nargs="+", metavar="VOLUME",
                   help="volume files, or folders holding them (DICOM series, TIFF slices, volume files)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder (created if needed)")
    p.add_argument("--level", type=float, default=None, metavar="L",
                   help="iso level in the volume's intensity units; when not given, on the boundary between "
                        "the background and the outermost tissue (see above)")
    p.add_argument("--target-vertices", type=_positive_int, default=None, metavar="N",
                   help="decimate each surface to about N vertices; when not given, marching cubes' "
                        "resolution is kept")
    p.add_argument("--smoothing", type=int, default=10, metavar="K",
                   help="Taubin smoothing iterations (0: none); does not shrink the shape")
    p.add_argument("--keep-support", action="store_true",
                   help="do not look for a support or scanner bed touching the product")
    p.add_argument("--spacing", type=_positive_float, nargs=3, default=None, metavar=("SX", "SY", "SZ"),
                   help="voxel size along x, y, z in mm, in place of what the file says; needed for a TIFF stack "
                        "without one in its ImageJ/OME metadata or a scanner log beside it (SkyScan .log, Nikon "
                        ".xtekct) (default: the file's)")
    p.add_argument("--split", action="store_true",
                   help="each VOLUME holds several products (a tray of fruit): extract every one as "
                        "DIR/<stem>_1.ply, <stem>_2.ply, ... in order of position (rows along y, then x); "
                        "products touching each other are parted, a piece touching the volume's edge or too "
                        "small to be a product is left out and said so, a tray is dropped")
    p.add_argument("--no-picture", action="store_true", help="skip the pictures")
    p.add_argument("--jobs", type=_positive_int, default=1, metavar="J",
                   help="parallel processes; each holds one volume and about 1.5 times its size")
    p.add_argument("--strict", action="store_true", help="stop at the first volume that fails")
    p.set_defaults(run=_run_extract)


def _run_extract(args) -> int:
    from .extract import collect_volumes, extract_files

    if args.smoothing < 0:
        raise HortishapeError(f"--smoothing must be 0 or more iterations, got {args.smoothing}")
    start = time.perf_counter()
    volumes, passed = collect_volumes(args.volumes, exclude=[args.out])
    _print_passed_over(passed)
    results = extract_files(
        volumes, args.out, level=args.level, smoothing=args.smoothing,
        target_vertices=args.target_vertices, remove_support=not args.keep_support,
        picture=not args.no_picture, n_jobs=args.jobs, strict=args.strict, spacing=args.spacing, split=args.split,
        progress=_progress(len(volumes), "extract", "volume"),
    )
    print(f"{'volume':<24}{'vertices':>10}{'mL':>9}{'level':>9}{'seconds':>9}  note")
    for r in results:
        if r.ok:
            note = ("resumed " if r.resumed else "") + (f"{r.n_support_voxels:,} support voxels dropped"
                                                        if r.n_support_voxels else "")
            print(f"{r.name:<24}{r.n_vertices:>10,}{r.volume_mm3 / 1000:>9.1f}{r.level:>9.4g}"
                  f"{r.seconds:>9.1f}  {note.strip()}")
            for w in r.warnings:
                print(f"hortishape: warning: {r.source}: {w}", file=sys.stderr)
        else:
            print(f"hortishape: error: {r.error}", file=sys.stderr)
        for why in r.left_out:
            print(f"hortishape: warning: {r.source}: left out {why}", file=sys.stderr)
    failed = sum(not r.ok for r in results)
    print(f"extracted {len(results) - failed} of {len(results)} surfaces to {args.out} "
          f"in {time.perf_counter() - start:.1f} s")
    return 1 if failed else 0


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
    g.add_argument("--distance-floor", type=float, default=5.0, metavar="EDGES",
                   help="but never hits closer than this many reference edge lengths (0: the paper's "
                        "filter, which can leave an overshooting stalk tip in the air)")
    g.add_argument("--tolerance", type=float, default=1e-3,
                   help="convergence when |d_t - d_(t-1)| / d_t falls below this")
    g.add_argument("--edge-tolerance", type=float, default=1e-3, metavar="EDGES",
                   help="or when |d_t - d_(t-1)| falls below this many reference edge lengths (on a noisy "
                        "scan d_t keeps falling by about a tenth per iteration as the surface fits the noise; "
                        "0.005 made such registrations about a third faster: docs/design-notes.md)")
    g.add_argument("--move-tolerance", type=float, default=0.05, metavar="EDGES",
                   help="or when no vertex moved more than this many reference edge lengths in each of the "
                        "last two iterations (the surface has stopped but for following a scan's noise; "
                        "0: off)")
    g.add_argument("--whole-tail", action="store_true",
                   help="after the schedule, move the whole surface in every iteration, as the paper does "
                        "(default: once no more than 1 %% of it still moves, only that part and its "
                        "neighbours: the same surface to hundredths of a millimetre, sooner on a noisy "
                        "scan; docs/design-notes.md)")
    g.add_argument("--orientation", choices=["axis", "search", "pca", "none"], default="axis",
                   help="initial alignment: put the reference's axis of revolution on the scan's, cavity "
                        "(stalk) end on cavity end, and keep the best turn about it after a short elastic "
                        "fit (axis); try all 24 principal-axis rotations so (search); the paper's eq. 7 "
                        "alone (pca); or none")
    g.add_argument("--warp", choices=["auto", "affine", "taper", "quadratic", "none"], default="auto",
                   help="the initializing global step before the elastic ones: affine (the paper's), "
                        "taper (affine plus a widening or narrowing along the fruit's axis), quadratic "
                        "(also bend), auto (quadratic for elongated references such as zucchini, banana "
                        "or pear, taper for round ones), or none")
    g.add_argument("--up", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="the scans (reference included) stand with the stalk towards this direction, e.g. "
                        "0 0 1 for fruit scanned upright on the bed: orientations that put the stalk more than "
                        "60 degrees from it (upside down, sideways) are excluded; measured right for scans "
                        "leaning up to 40 degrees (default: no hint, every orientation is searched)")


def _registration_config(args):
    from .registration import RegistrationConfig

    try:
        return RegistrationConfig(
            n_iterations=args.iterations, beta_start=args.stiffness[0], beta_end=args.stiffness[1],
            max_angle=args.max_angle, distance_factor=args.distance_factor,
            distance_floor=args.distance_floor, tolerance=args.tolerance,
            edge_tolerance=args.edge_tolerance, move_tolerance=args.move_tolerance,
            local_tail=not args.whole_tail,
            max_iterations=max(50, args.iterations + 20), orientation=args.orientation, warp=args.warp,
            up=None if args.up is None else tuple(args.up),
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
            "(--strict stops instead); run again and finished targets are not redone.\n\n"
            "Scans with holes (a structured-light scanner's, where it did not see) are registered too: "
            "each hole is closed by a smooth patch that the orientation search takes for surface and the "
            "elastic steps ignore (holes over a quarter of the surface are refused: see 'fit --partial')."
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
    _add_landmarks(p)
    _add_scale(p)
    _add_registration_options(p)
    p.set_defaults(run=_run_register)


def _holes_note(item, sep: str) -> str:
    """``"<sep>2 holes closed (8 % of the surface)"`` for a registered scan that had holes, else ``""``."""
    holes = getattr(item, "holes", 0)
    if not holes:
        return ""
    return f"{sep}{holes} hole{'s' if holes > 1 else ''} closed ({item.hole_share:.0%} of the surface)"


def _print_results(results) -> int:
    """Print a table of batch results; returns the number that failed."""
    print(f"{'scan':<24}{'seconds':>9}{'iter':>6}{'d_t mm':>9}{'geom mm':>9}{'kept':>7}{'conf':>6}  note")
    failed = 0
    for r in results:
        if r.ok:
            note = ", ".join(x for x in ("resumed" if r.resumed else "", "" if r.converged else "not converged",
                                         _holes_note(r, "")) if x)
            conf = "" if r.orientation_confidence != r.orientation_confidence else f"{r.orientation_confidence:.2f}"
            print(f"{r.name:<24}{r.seconds:>9.1f}{r.iterations:>6}{r.mean_distance:>9.3f}"
                  f"{r.geometric_error:>9.4f}{r.kept_fraction:>7.0%}{conf:>6}  {note.strip()}")
        else:
            failed += 1
            print(f"{r.name:<24}{'skipped':>9}  {r.error}")
            print(f"hortishape: skipped {r.error}", file=sys.stderr)
    return failed


def _run_register(args) -> int:
    from .pipeline import read_reference_landmarks, register_files
    from .registration import prepare_reference
    from .units import read_scan

    config = _registration_config(args)
    start = time.perf_counter()
    reference = read_scan(args.reference, scale=args.scale).mesh
    marks, reference_marks = read_reference_landmarks(args.landmarks, args.reference, scale=args.scale)
    print(f"preparing the reference {args.reference} ({reference.n_vertices:,} vertices"
          + ("" if args.no_resample else f" -> {args.points:,}") + ")", file=sys.stderr)
    template = prepare_reference(reference, None if args.no_resample else args.points)
    results = register_files(template, args.targets, args.out, config=config, n_jobs=args.jobs,
                             strict=args.strict, progress=_progress(len(args.targets), "register", "scan"),
                             scale=args.scale, landmarks=marks, reference_landmarks=reference_marks)
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
            "  1. check every scan (one component, millimetres; holes closed by patches) and pick the\n"
            "     reference (--reference, or the closed scan nearest the population's median size);\n"
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
    p.add_argument("input_dir", type=Path, metavar="INPUT_DIR",
                   help="folder of scans (PLY, STL, OBJ, OFF, VTK, VTP) or of CT/MRI volumes (MHA, MHD, NRRD, "
                        "NIfTI, TIFF, DICOM series found by content in it and its subfolders; surfaces extracted "
                        "first into OUT/surfaces, as by 'hortishape extract'); what is not a scan is listed as "
                        "passed over")
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
    _add_batch_options(p, "INPUT_DIR")
    _add_landmarks(p)
    _add_scale(p)
    _add_registration_options(p)
    p.set_defaults(run=_run_build)


def _add_batch_options(p, folder: str) -> None:
    """--jobs, --strict, --spacing, and the cluster and cache options of 'build' and 'update'."""
    p.add_argument("--jobs", type=_positive_int, default=None, metavar="J",
                   help="parallel registrations (default: all cores)")
    p.add_argument("--strict", action="store_true", help="stop at the first bad scan instead of skipping it")
    p.add_argument("--spacing", type=_positive_float, nargs=3, default=None, metavar=("SX", "SY", "SZ"),
                   help=f"voxel size along x, y, z in mm for the volumes in {folder}, in place of what their "
                        "files say (as 'hortishape extract --spacing')")
    p.add_argument("--split", action="store_true",
                   help=f"each volume in {folder} holds several products: each is a scan of its own, named "
                        "<volume>_1, <volume>_2, ... (as 'hortishape extract --split')")
    g = p.add_argument_group(
        "clusters and caches",
        "--scheduler runs the registrations and the extraction of volumes as tasks on a Dask cluster: start "
        "'dask scheduler' on one machine and 'dask worker tcp://HOST:8786 --nthreads 1' on as many as you like "
        "(one thread per worker process: a registration uses a core). Each scan's bytes go to its worker and the "
        "result comes back to be written here; volumes are read and their surfaces written by the workers, so "
        f"they must see {folder} and OUT. A worker that dies costs only its task, which Dask runs again "
        "elsewhere; the summary says which were retried.")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="the Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: local processes)")
    g.add_argument("--cache", type=Path, default=None, metavar="DIR",
                   help="registrations by content (the scan's bytes, the reference, every setting and heuristic, "
                        "hortishape's version), shared between builds: found there, a registration is not redone "
                        "(default: only this build's OUT, from which an interrupted build resumes)")


def _print_passed_over(passed) -> None:
    """The files and folders that are not scans, with why; many for one reason in one line."""
    reasons: dict[str, list[str]] = {}
    for path, reason in passed:
        reasons.setdefault(reason, []).append(str(path))
    for reason, paths in reasons.items():
        if len(paths) > 3:
            print(f"passed over {len(paths)} files ({', '.join(paths[:2])}, ...): {reason}")
        else:
            for path in paths:
                print(f"passed over {path}: {reason}")


def _print_build(result) -> None:
    print(f"reference: {result.reference}")
    print("first pass (the reference registered to every scan):")
    _print_results(result.first_pass)
    print("second pass (the first pass's mean registered to every scan: the model's correspondences):")
    _print_results(result.second_pass)
    _print_passed_over(result.passed_over)
    for path, reason in result.skipped:
        print(f"skipped {reason if reason.startswith(str(path)) else f'{path}: {reason}'}")
    retried = [f"{name} ({f'pass {k}' if isinstance(k, int) else k}, {attempts} attempts)"
               for name, k, attempts in result.retried]
    if retried:
        print(f"run again after their worker was lost: {', '.join(retried)}")
    if result.uncertain_orientation:
        from .pipeline import UNCERTAIN_CONFIDENCE

        listed = ", ".join(f"{n} ({c:.3f})" for n, c in result.uncertain_orientation)
        print(f"orientation uncertain (confidence below {UNCERTAIN_CONFIDENCE:g}; check these): {listed}")
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
        progress=_stage_progress, scale=args.scale, landmarks=args.landmarks, spacing=args.spacing, split=args.split,
        scheduler=args.scheduler, cache=args.cache,
    )
    _print_build(result)
    return 0


def _add_update(sub) -> None:
    p = sub.add_parser(
        "update", help="add scans to a built model without registering its scans again",
        description=("Add the scans in NEW_SCANS to the model that 'hortishape build' wrote in MODEL_DIR, into a new "
                     "folder OUT: the model's mean is registered to every new scan (with the orientation search); "
                     "the scans already in the model keep their registrations (copied, not redone); then "
                     "Procrustes over all of them and the PCA, as a build ends. MODEL_DIR is not changed.\n\n"
                     "It differs from a build of all the scans in one way: there every scan is registered to the "
                     "mean of all the first pass's registrations; here the earlier scans were registered to the mean "
                     "of theirs and the new ones to the model's mean. OUT/summary.json says which scans came from "
                     "where ('update') and how far the mean moved. Use the registration options the model was "
                     "built with."),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("model_dir", type=Path, metavar="MODEL_DIR", help="a folder 'hortishape build' wrote")
    p.add_argument("input_dir", type=Path, metavar="NEW_SCANS", help="folder of the new scans (meshes or volumes)")
    p.add_argument("--out", type=Path, required=True, metavar="OUT", help="the updated model's folder")
    _add_batch_options(p, "NEW_SCANS")
    _add_scale(p)
    _add_registration_options(p)
    p.set_defaults(run=_run_update)


def _run_update(args) -> int:
    from .pipeline import update_model

    result = update_model(
        args.model_dir, args.input_dir, args.out, n_jobs=args.jobs, strict=args.strict,
        config=_registration_config(args), progress=_stage_progress, scale=args.scale, spacing=args.spacing,
        split=args.split,
        scheduler=args.scheduler, cache=args.cache,
    )
    added = [r for r in result.second_pass if r.ok]
    print(f"added to {args.model_dir} ({len(result.names) - len(added)} scans, kept as they were):")
    _print_results(result.second_pass)
    _print_passed_over(result.passed_over)
    for path, reason in result.skipped:
        print(f"skipped {reason if reason.startswith(str(path)) else f'{path}: {reason}'}")
    import json

    moved = json.loads((Path(result.out_dir) / "summary.json").read_text(encoding="utf-8"))["update"]["mean_moved_rms_mm"]
    print(f"model: {len(result.names)} instances, {len(result.explained_variance)} modes; the mean moved "
          f"{moved:.3f} mm (RMS over the vertices)")
    print(f"wrote {result.model_path} in {result.seconds:.1f} s")
    return 0


def _load_model(path: Path, command: str | None = None):
    """The model at ``path``; for a ``command`` that makes surfaces, only one with triangles."""
    from .model import ShapeModel

    model = ShapeModel.load(path)
    if command is not None and model.faces_ is None:
        raise HortishapeError(f"{path}: a point-set model (no triangles): '{command}' makes surfaces and needs "
                              "a triangle-mesh model")
    return model


def _add_sample(sub) -> None:
    p = sub.add_parser(
        "sample", help="draw random new shapes from a model",
        description=("Draw N random shapes from MODEL (a model.h5): the coefficients of the first --modes "
                     "modes come from a standard normal distribution truncated at +/- --truncate standard "
                     "deviations (paper section 3.2, Fig. 8). Writes DIR/sample_000.ply ... and "
                     "DIR/samples.png."),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("model", type=Path, metavar="MODEL", help="model file (model.h5; Statismo or Scalismo, HDF5 or HDF5-JSON)")
    p.add_argument("n", type=_positive_int, metavar="N", help="number of shapes")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--modes", type=_positive_int, default=5, help="modes to vary (the paper: 5)")
    p.add_argument("--truncate", type=float, default=3.0, metavar="SD", help="truncation, in standard deviations")
    p.add_argument("--seed", type=int, default=None, help="random seed")
    p.add_argument("--no-picture", action="store_true", help="skip the picture")
    p.set_defaults(run=_run_sample)


def _run_sample(args) -> int:
    from .demo import write_samples

    model = _load_model(args.model, "sample")
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
    p.add_argument("model", type=Path, metavar="MODEL", help="model file (model.h5; Statismo or Scalismo, HDF5 or HDF5-JSON)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--modes", type=_positive_int, default=3, help="number of modes")
    p.add_argument("--sd", type=float, default=3.0, help="standard deviations either side of the mean")
    p.set_defaults(run=_run_modes)


def _run_modes(args) -> int:
    from .report import render_modes, write_mode_meshes

    model = _load_model(args.model, "modes")
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
    p.add_argument("model", type=Path, metavar="MODEL", help="model file (model.h5; Statismo or Scalismo, HDF5 or HDF5-JSON)")
    p.add_argument("scan", type=Path, metavar="SCAN",
                   help="the new scan (mesh file, mm); with --partial also a point cloud (PLY without faces)")
    p.add_argument("--out", type=Path, default=None, metavar="PATH",
                   help="reconstruction mesh (default: <scan stem>_fit.ply in the current folder, or with "
                        "--partial the output folder <scan stem>_partial)")
    p.add_argument("--modes", type=_positive_int, default=None, help="modes to fit (default: all)")
    p.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write the figures as JSON")
    g = p.add_argument_group(
        "partial scans",
        "--partial fits SCAN as what was seen of one side of the fruit (a depth camera's points, an open mesh; "
        "in any pose, stray points such as a table are left out) and completes it: the whole surface with the "
        "model's vertex order in the scan's coordinates, the posterior SD of every vertex and of the volume. "
        "Writes, in the --out folder, <stem>.ply (with the vertex property sd_mm), <stem>.json (volume_ml, "
        "volume_sd_ml, pose, coefficients, residual, share seen, misfit), <stem>.sd.npy and <stem>.png. What "
        "the residuals exceed the points' own noise by (the misfit) widens the SD of the side not seen; far "
        "above that noise it warns: a fruit the model cannot represent, whose unseen side may be off by more "
        "than the SD says.")
    g.add_argument("--partial", action="store_true", help="SCAN shows part of the fruit: complete it")
    g.add_argument("--noise", type=_positive_float, default=None, metavar="MM",
                   help="the points' noise, SD in mm (default: estimated from the fit)")
    g.add_argument("--seed", type=int, default=0, help="random seed (the subsets of points used)")
    _add_scale(p)
    _add_registration_options(p)
    p.set_defaults(run=_run_fit)


def _run_fit(args) -> int:
    import json

    from .io import write_mesh
    from .pipeline import fit_scan
    from .units import read_scan

    model = _load_model(args.model, "fit")
    if args.partial:
        return _run_fit_partial(model, args)
    scan = read_scan(args.scan, scale=args.scale)
    fit = fit_scan(model, scan.mesh, modes=args.modes, config=_registration_config(args))
    out = args.out or Path(f"{args.scan.stem}_fit.ply")
    write_mesh(out, fit.reconstruction, model.faces_)
    sds = " ".join(f"{b:+.2f}" for b in fit.coefficients[: min(10, len(fit.coefficients))])
    print(f"coefficients b (SD, first {min(10, len(fit.coefficients))} modes): {sds}")
    print(f"Mahalanobis distance: {fit.mahalanobis:.2f} SD")
    print(f"residual to the corresponded points: mean {fit.residual_mean:.3f} mm, max {fit.residual_max:.3f} mm")
    print(f"residual to the scan surface: mean {fit.surface_mean:.3f} mm, max {fit.surface_max:.3f} mm")
    print(f"wrote {out}")
    if args.json:
        from ._files import atomic_text

        atomic_text(args.json, json.dumps({
            "scan": str(args.scan), "units": scan.units.as_log(), "coefficients_sd": fit.coefficients.tolist(),
            "pose": fit.pose.tolist(), "mahalanobis": fit.mahalanobis,
            "residual_mean_mm": fit.residual_mean, "residual_max_mm": fit.residual_max,
            "surface_mean_mm": fit.surface_mean, "surface_max_mm": fit.surface_max,
        }, indent=1), HortishapeError)
    return 0


def _run_fit_partial(model, args) -> int:
    import warnings

    from .errors import FitWarning
    from .io import read_points
    from .partial import fit_partial, write_partial_fit

    cloud = read_points(args.scan)
    points = cloud.points * args.scale
    try:
        with warnings.catch_warnings():  # said below, once, with the scan's name
            warnings.simplefilter("ignore", FitWarning)
            fit = fit_partial(model, points, normals=cloud.normals, modes=args.modes,
                              noise="auto" if args.noise is None else args.noise, random_state=args.seed)
    except HortishapeError as exc:
        raise HortishapeError(f"{args.scan}: {exc}") from None
    stem = args.scan.stem
    out = args.out or Path(f"{stem}_partial")
    files = write_partial_fit(fit, out, stem, points=points, source=str(args.scan))
    planar = f", {fit.n_planar:,} on a large plane (a table?) left out" if fit.n_planar else ""
    print(f"{args.scan}: {fit.n_points:,} points{planar}, {fit.n_kept:,} of those fitted kept; "
          f"{fit.observed_fraction:.0%} of the surface seen")
    print(f"volume {fit.volume_ml:.1f} +/- {fit.volume_sd_ml:.1f} mL (1 SD); residual {fit.residual_mm:.2f} mm, "
          f"noise {fit.noise_mm:.2f} mm (the points' own {fit.point_noise_mm:.2f} mm, misfit {fit.misfit_mm:.2f} mm)")
    print(f"SD of the surface along its normals: mean {fit.sd.mean():.2f} mm, max {fit.sd.max():.2f} mm")
    sds = " ".join(f"{b:+.2f}" for b in fit.coefficients[: min(10, len(fit.coefficients))])
    print(f"coefficients (SD, first {min(10, len(fit.coefficients))} modes): {sds}")
    print(f"wrote {files['mesh']}, {files['json'].name}, {files['sd'].name}, {files['picture'].name}")
    for note in fit.warnings:
        print(f"hortishape: warning: {args.scan}: {note}", file=sys.stderr)
    return 0


def _add_view(sub) -> None:
    p = sub.add_parser(
        "view", help="the model in a web page: a slider per mode, for anyone with a browser",
        description=("Write one self-contained HTML page of MODEL (a model file, or a folder 'hortishape build' "
                     "wrote) that opens from disk in any current browser with no network: the mean in 3D (drag "
                     "to rotate, scroll to zoom), a slider per mode from -3 to +3 SD acting together, 'random "
                     "sample' and 'reset', front, top and oblique views, colouring by the displacement from the "
                     "mean, by the model's SD at each point or by the geometric error map, the landmarks, and "
                     "the variance per mode. From a built folder it takes the error map and the landmarks of "
                     "its evaluation (run 'hortishape evaluate' first to have them).\n\n"
                     "The address keeps the state: FILE.html#b=0,3 shows mode 2 at +3 SD, and #b=1,-2&c=sd "
                     "colours by the SD (c= shape, displacement, sd or error). Moving a slider writes it back, "
                     "so a view can be shared by its address.\n\n"
                     "Size: about 5 MB for the drawing library (plotly.js) plus 6 bytes per vertex and mode "
                     "(a 30,000-vertex model with 20 modes: 11 MB)."),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("model", type=Path, metavar="MODEL", help="model file (model.h5; Statismo or Scalismo) or built folder")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.html", help="the page to write")
    p.add_argument("--modes", type=_positive_int, default=20, help="modes embedded, each with a slider")
    p.add_argument("--precision", choices=("int16", "float32"), default="int16",
                   help="how the modes are stored: int16 with a scale per mode, or float32 (twice the size)")
    p.set_defaults(run=_run_view)


def _run_view(args) -> int:
    from .view import view_model

    page = view_model(args.model, args.out, n_modes=args.modes, precision=args.precision)
    extras = [f"colourings: {', '.join(page.colourings)}"]
    if page.landmarks:
        extras.append(f"landmarks: {', '.join(page.landmarks)}")
    print(f"wrote {page.path} ({page.size_bytes / 1e6:.1f} MB, {page.n_modes} modes; {'; '.join(extras)})")
    return 0


def _add_convert(sub) -> None:
    p = sub.add_parser(
        "convert", help="write a model file in the other form: HDF5 or HDF5-JSON (Scalismo 0.92+)",
        description=("Read MODEL (hortishape's, Statismo's or Scalismo's; HDF5 or HDF5-JSON, told by its content) "
                     "and write it to OUT in the Statismo v0.9 layout, as HDF5 (Statismo, Scalismo up to 0.91) or "
                     "HDF5-JSON (Scalismo 0.92 and later, which read it only from a name ending in .json). "
                     "The form is --format, else .json for a name ending in .json, else HDF5."),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("model", type=Path, metavar="MODEL", help="model file")
    p.add_argument("out", type=Path, metavar="OUT", help="the file to write")
    p.add_argument("--format", choices=("hdf5", "json"), default=None, help="form of OUT (default: by its name)")
    p.set_defaults(run=_run_convert)


def _run_convert(args) -> int:
    from .statismo import model_format

    model = _load_model(args.model)
    out = model.save(args.out, format=args.format)
    print(f"wrote {out} ({model_format(out)}; {model.n_points_} points, "
          f"{'no' if model.faces_ is None else len(model.faces_)} triangles, {model.n_components_} modes)")
    return 0


def _add_demo(sub) -> None:
    p = sub.add_parser(
        "demo", help="the whole pipeline on built-in synthetic apples",
        description=("Make a synthetic population of 30 apples (CT-like surfaces of ~100k vertices), build "
                     "their shape model with the paper's settings (30,000-vertex reference, two registration "
                     "passes, Procrustes, PCA), draw five new apples from it, picture the first modes and "
                     "evaluate the model (the HTML report of 'hortishape evaluate'). Prints where everything is."),
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
    print("evaluation:")
    _print_evaluation(r.evaluation)
    print()
    print(f"demo done in {r.seconds:.0f} s; everything is in {r.out_dir}:")
    print(f"  scans with ground truth   {r.scans}/")
    print(f"  the model                 {r.build.model_path}")
    print(f"  corresponded surfaces     {r.build.out_dir / 'registered'}/")
    print(f"  {'five new ' + args.product + 's':<26}{r.samples_picture.parent}/ "
          f"(picture: {r.samples_picture})")
    print(f"  shape modes (Fig. 7)      {r.modes_picture}")
    print(f"  quality report            {r.report} (metrics.json, metrics.csv beside it)")
    if r.evaluation.files.get("viewer"):
        print(f"  the model in a browser    {r.evaluation.files['viewer']} (a slider per mode)")
    print(f"  CAD surfaces (32 x 32)    {', '.join(str(p) for p in r.cad)}")
    return 0


# --------------------------------------------------------------------------
# cad
# --------------------------------------------------------------------------


def _add_cad(sub) -> None:
    p = sub.add_parser(
        "cad", help="export the mean or any model instance as a B-spline surface (STEP, IGES, JSON)",
        description=(
            "Describe a shape-model instance with CAD primitives (paper section 2.2.4, Fig. 9): the model's "
            "mean is opened at its poles (stalk and bottom, found automatically or given with --stalk and "
            "--bottom) and mapped one-to-one onto a cylinder; every instance shares that (u, v), so its "
            "bicubic B-spline (periodic around, closed at both poles, GRID x GRID control points) is a linear "
            "function of its shape coefficients. Writes each --out by its extension: .step/.stp (a solid) and "
            ".iges/.igs (the face) through OpenCascade (pip install 'hortishape[cad]'), .json (control points "
            "and knots).\n\n"
            "Instances: the mean (default), --instance sample (random, --seed), --coefficients C1 C2 ... "
            "(standard deviations), --mode M --sd K (mean + K SD along mode M), --scan FILE (fit a new scan, "
            "exported in the scan's coordinates)."
        ),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("model", type=Path, metavar="MODEL", help="model file (model.h5; Statismo or Scalismo, HDF5 or HDF5-JSON)")
    p.add_argument("--out", type=Path, action="append", required=True, metavar="FILE",
                   help="output file (.step, .stp, .iges, .igs or .json); repeat for several")
    p.add_argument("--grid", type=_positive_int, default=32, metavar="K",
                   help="K x K control points (at least 4; the paper: 4, 8, 16, 32)")
    p.add_argument("--instance", choices=["mean", "sample", "coefficients", "mode", "scan"], default=None,
                   help="which instance (default: from the options given, else the mean)")
    p.add_argument("--coefficients", type=float, nargs="+", default=None, metavar="C",
                   help="shape coefficients of the first modes, in standard deviations")
    p.add_argument("--mode", type=_positive_int, default=None, metavar="M", help="mode to move along (1 = first)")
    p.add_argument("--sd", type=float, default=3.0, metavar="K", help="standard deviations along --mode")
    p.add_argument("--seed", type=int, default=None, help="random seed of --instance sample")
    p.add_argument("--modes", type=_positive_int, default=5, help="modes varied by --instance sample")
    p.add_argument("--scan", type=Path, default=None, metavar="FILE",
                   help="a new scan to fit (registration of the mean, then eq. 13)")
    p.add_argument("--stalk", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="stalk pole landmark on the mean, mm (default: automatic)")
    p.add_argument("--bottom", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="bottom pole landmark on the mean, mm (default: automatic)")
    p.add_argument("--picture", type=Path, default=None, metavar="PNG",
                   help="also picture the B-spline coloured by its distance to the instance's triangle surface")
    p.set_defaults(run=_run_cad)


def _cad_instance_kind(args) -> str:
    given = [name for name, on in (("coefficients", args.coefficients is not None), ("mode", args.mode is not None),
                                   ("scan", args.scan is not None)) if on]
    if len(given) > 1:
        raise HortishapeError(f"give only one of --coefficients, --mode and --scan (got {', '.join(given)})")
    kind = args.instance or (given[0] if given else "mean")
    if given and given[0] != kind:
        raise HortishapeError(f"--instance {kind} does not go with --{given[0]}")
    if kind in ("coefficients", "mode", "scan") and not given:
        option = {"coefficients": "--coefficients C1 C2 ...", "mode": "--mode M", "scan": "--scan FILE"}[kind]
        raise HortishapeError(f"--instance {kind} needs {option}")
    return kind


def _run_cad(args) -> int:
    import numpy as np

    from .cad import BSplineModel, find_poles, render_deviation, surface_deviation, write_cad

    kind = _cad_instance_kind(args)
    for out in args.out:
        if out.suffix.lower() not in (".step", ".stp", ".iges", ".igs", ".json"):
            raise HortishapeError(f"{out}: the output must end in .step, .stp, .iges, .igs or .json")
    model = _load_model(args.model, "cad")
    start = time.perf_counter()
    poles = find_poles(model.mean_, model.faces_, stalk=args.stalk, bottom=args.bottom)
    cad = BSplineModel(args.grid, poles=poles).fit(model)
    cmap = cad.parameterization_
    print(f"parameterization of the mean: {cmap.n_flipped} flipped triangles; poles: stalk "
          f"{np.round(model.mean_[cmap.stalk], 1).tolist()}, bottom {np.round(model.mean_[cmap.bottom], 1).tolist()} "
          f"mm ({time.perf_counter() - start:.1f} s with the {args.grid} x {args.grid} operator)")

    pose = None
    if kind == "mean":
        coefficients, label = np.zeros(0), "the mean"
    elif kind == "sample":
        coefficients = model.sample_coefficients(1, modes=args.modes, random_state=args.seed)[0]
        label = f"a random sample (seed {args.seed})"
    elif kind == "coefficients":
        coefficients, label = np.asarray(args.coefficients), "the given coefficients"
    elif kind == "mode":
        if args.mode > model.n_components_:
            raise HortishapeError(f"--mode {args.mode}: the model has {model.n_components_} modes")
        coefficients = np.zeros(args.mode)
        coefficients[-1] = args.sd
        label = f"mode {args.mode} {args.sd:+g} SD"
    else:
        from .pipeline import fit_scan
        from .units import read_scan

        fit = fit_scan(model, read_scan(args.scan).mesh)
        coefficients, pose = fit.coefficients, fit.pose
        label = f"the fit of {args.scan} (Mahalanobis {fit.mahalanobis:.2f} SD, in the scan's coordinates)"
    try:
        surface = cad.instance(coefficients) if coefficients.size else cad.mean_
    except ValueError as exc:
        raise HortishapeError(str(exc)) from None
    triangles = model.instance(coefficients) if coefficients.size else model.mean_
    if pose is not None:
        surface = surface.transformed(pose)
        triangles = triangles @ pose[:3, :3].T + pose[:3, 3]
    if coefficients.size:
        shown = " ".join(f"{c:+.2f}" for c in coefficients[:10])
        print(f"instance: {label}; coefficients (SD): {shown}")
    else:
        print(f"instance: {label}")
    dev = surface_deviation(surface, triangles, model.faces_)
    print(f"{args.grid} x {args.grid} B-spline vs the instance's triangle surface: mean {dev.mean:.4f} mm, "
          f"max {dev.max:.3f} mm (B-spline to triangles: max {dev.back_max:.3f} mm)")
    print(f"storage per surface: {surface.nbytes / 1024:.1f} kB of control points "
          f"(triangle model: {model.n_points_ * 24 / 1024:.0f} kB of vertices)")
    for out in args.out:
        path = write_cad(out, surface)
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} kB)")
    if args.picture:
        pic = render_deviation(surface, triangles, model.faces_, args.picture,
                               title=f"{args.grid} x {args.grid} control points")
        print(f"wrote {pic}")
    return 0


# --------------------------------------------------------------------------
# evaluate
# --------------------------------------------------------------------------


def _add_evaluate(sub) -> None:
    p = sub.add_parser(
        "evaluate", help="measure a built model's quality and write an HTML report",
        description=(
            "Measure the quality of the model in OUT (what 'hortishape build' wrote), paper section 3.4:\n"
            "  compactness C(m)      cumulative variance of the first m modes (eq. 14, Fig. 10)\n"
            "  generalization G(m)   leave-one-out: a model of the others describes each instance with m modes\n"
            "                        (eq. 15, Fig. 11)\n"
            "  specificity S(m)      random shapes of the model vs. their nearest training shape (eq. 16, Fig. 12)\n"
            "each for m = 1 .. M, as mean distance per vertex (mm) and as the paper's squared norms (mm^2);\n"
            "the geometric error map of the registered surfaces against their scans (Fig. 6, Table 2),\n"
            "landmark transfer errors (Table 3) and the population's dimensions (Table 1).\n\n"
            "Writes OUT/evaluation/: report.html (one self-contained page), metrics.json and metrics.csv,\n"
            "error_map.ply / .vtk / .png, and the plots as PNG.\n\n"
            "Landmarks (--landmarks, in each scan's coordinates, mm): a JSON file {stem: {name: [x, y, z]}},\n"
            "a CSV file with the columns instance,landmark,x,y,z, or a folder of <stem>.truth.json files;\n"
            "by default the <stem>.truth.json files beside the scans (what 'hortishape synth' writes), if any.\n"
            "Each is marked on the mean (the average of the given markers' places), carried to every\n"
            "instance through the correspondence and compared with the given position."
        ),
        epilog=EPILOG, formatter_class=_Formatter)
    p.add_argument("out", type=Path, metavar="OUT", help="a built model directory (with model.h5, summary.json)")
    p.add_argument("--landmarks", type=Path, default=None, metavar="FILE_OR_DIR",
                   help="landmark positions per instance (default: <stem>.truth.json beside the scans)")
    p.add_argument("--modes", type=_positive_int, default=None, metavar="M",
                   help="evaluate m = 1 .. M (default and largest: N - 2 for N instances, at most the model's modes)")
    p.add_argument("--samples", type=_positive_int, default=200, metavar="S",
                   help="random shapes per m for the specificity")
    p.add_argument("--scans", type=Path, default=None, metavar="DIR",
                   help="folder of the scans, if they are no longer where the build read them")
    p.add_argument("--seed", type=int, default=0, help="random seed of the specificity's random shapes")
    p.set_defaults(run=_run_evaluate)


def _print_evaluation(ev) -> None:
    c, g, s, d = ev.compactness, ev.generalization, ev.specificity, ev.dimensions
    print(f"{len(ev.names)} instances, {ev.n_points:,} vertices; G and S: mean distance per vertex (mm) +/- standard "
          "error, and the paper's squared norms (eqs. 15-16, mm^2)")
    print(f"{'m':>3}{'C(m) %':>9}{'G mm':>9}{'+/- se':>8}{'G eq.15':>11}{'S mm':>9}{'+/- se':>8}{'S eq.16':>11}")
    for j, m in enumerate(c.modes):
        print(f"{m:>3}{100 * c.ratio[j]:>9.2f}{g.mean_mm[j]:>9.3f}{g.se_mm[j]:>8.3f}{g.mean_sq[j]:>11,.1f}"
              f"{s.mean_mm[j]:>9.3f}{s.se_mm[j]:>8.3f}{s.mean_sq[j]:>11,.1f}")
    dims = ", ".join(f"{k} {m:.1f} +/- {sd:.1f}" for k, m, sd in zip(("width", "depth", "height"), d.mean, d.sd))
    print(f"dimensions (mm, Table 1): {dims} (height with stalk {d.overall_height.mean():.1f})")
    ge = ev.geometric_error
    if ge is not None:
        print(f"geometric error (mm, Table 2): {ge.mean_mm:.4f} +/- {ge.sd_mm:.4f} over {len(ge.names)} instances, "
              f"map maximum {ge.per_vertex_mm.max():.3f}")
    t = ev.landmarks
    if t is not None:
        errs = ", ".join(f"{k} {m:.2f} +/- {sd:.2f} (n = {n})" for k, (m, sd, _, n) in t.summary().items())
        print(f"landmark transfer error (mm, Table 3): {errs}")
    for note in ev.notes:
        print(f"note: {note}")
    if ev.files:
        print(f"wrote {ev.files['report']} (and metrics.json, metrics.csv, pictures) in {ev.seconds:.1f} s")
        if ev.files.get("viewer"):
            print(f"wrote {ev.files['viewer']}: the model in a browser, a slider per mode")


def _run_evaluate(args) -> int:
    from .evaluate import evaluate_model

    ev = evaluate_model(args.out, landmarks=args.landmarks, modes=args.modes, n_samples=args.samples,
                        scans=args.scans, random_state=args.seed, progress=_stage_progress)
    _print_evaluation(ev)
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


def _command_parsers(parser: argparse.ArgumentParser) -> dict[str, tuple[str | None, argparse.ArgumentParser]]:
    """Each command of ``build_parser()``: its one-line help and its own parser (for the docs' reference
    and the tests, which read every command's options)."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help for a in sub._choices_actions}
    return {name: (helps.get(name), command) for name, command in sub.choices.items()}


_COMMANDS = [_add_demo, _add_synth, _add_extract, _add_register, _add_build, _add_update, _add_sample, _add_modes, _add_fit, _add_cad,
             _add_evaluate, _add_view, _add_convert]


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as a user reads it: one ``hortishape: warning:`` line, without Python's file and line."""
    text = " ".join(str(message).split())
    print(f"hortishape: warning: {text}", file=file if file is not None else sys.stderr, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    import warnings

    parser = build_parser()
    args = parser.parse_args(argv)
    shown = warnings.showwarning
    warnings.showwarning = _show_warning  # worker processes forked from here inherit it
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
    finally:
        warnings.showwarning = shown


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
