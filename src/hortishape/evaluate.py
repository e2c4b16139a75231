"""Evaluate a built model directory: the paper's quality measures, error maps and report.

:func:`evaluate_model` takes what ``hortishape build`` wrote (``OUT/model.h5``,
``OUT/registered/``, ``OUT/aligned/``, ``OUT/summary.json``) and measures:

- compactness C(m), generalization G(m) by leave-one-out and specificity
  S(m) (section 3.4, eqs. 14-16, Figs. 10-12), each for m = 1 .. M, both as
  the paper defines them (squared norms, mm^2) and as the mean distance per
  vertex in millimetres;
- the geometric error (section 3.1, Fig. 6, Table 2): for every reference
  vertex, the distance of the registered surface to the scan it was
  registered to, per instance and averaged over the instances;
- landmark transfer errors (the protocol of Table 3, see
  :func:`hortishape.metrics.transfer_landmarks`) when landmark positions
  are given, or lie beside the scans as the synthetic generator's
  ``<stem>.truth.json``;
- the population's width, depth and height (Table 1).

It writes them under ``OUT/evaluation/``: ``metrics.json`` and
``metrics.csv`` (for scripts and for comparing models), the error map as
meshes (``error_map.ply`` with colours and the distances, ``error_map.vtk``
with the distances as point data) and a picture, plots of the three
measures, and ``report.html``: one self-contained page with everything,
pictures embedded.

Landmark files
--------------
Landmarks are given per instance (the scan's file stem) and name, in the
scan's coordinates (mm), as one of:

- a JSON file mapping stem -> name -> [x, y, z], e.g.
  ``{"apple_000": {"stalk_tip": [1.0, 2.0, 40.0], "bottom": [...]}}``;
- a CSV file with a header ``instance,landmark,x,y,z`` (``stem`` may stand
  for ``instance``) and one row per instance and landmark;
- a folder of ``<stem>.truth.json`` files (what ``hortishape synth``
  writes: their ``landmarks`` are in scanner coordinates) or of
  ``<stem>.json`` files holding ``{"landmarks": {name: [x, y, z]}}``.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._files import Progress
from ._rng import RandomState
from .errors import HortishapeError
from .metrics import (
    Compactness,
    Dimensions,
    Generalization,
    LandmarkTransfer,
    Specificity,
    compactness,
    dimensions,
    generalization,
    specificity,
    transfer_landmarks,
)

__all__ = [
    "Evaluation",
    "GeometricError",
    "evaluate_model",
    "geometric_error",
    "metrics_csv",
    "metrics_dict",
    "read_landmarks",
    "write_evaluation",
]



@dataclass(frozen=True)
class GeometricError:
    """Distance of the registered surfaces to their scans (paper Fig. 6, Table 2).

    Attributes
    ----------
    names : tuple of str
        The instances measured (those whose scan was found).
    per_instance_mm : (N,) float64 ndarray
        Mean distance of each registered surface's vertices to its scan, mm.
    max_mm : (N,) float64 ndarray
        The largest of those distances per instance, mm.
    per_vertex_mm : (n,) float64 ndarray
        For every reference vertex, its distance to the scan averaged over the
        instances: the error map, mm.
    missing : tuple of (str, str)
        ``(instance, reason)`` for every instance left out.
    """

    names: tuple
    per_instance_mm: np.ndarray
    max_mm: np.ndarray
    per_vertex_mm: np.ndarray
    missing: tuple = ()

    @property
    def mean_mm(self) -> float:
        """Mean over the instances of their mean distance (Table 2), mm."""
        return float(self.per_instance_mm.mean())

    @property
    def sd_mm(self) -> float:
        """Standard deviation over the instances of their mean distance (Table 2), mm."""
        return float(self.per_instance_mm.std(ddof=1)) if len(self.per_instance_mm) > 1 else math.nan


@dataclass(frozen=True)
class Evaluation:
    """Everything :func:`evaluate_model` measured, and where it wrote it.

    Attributes
    ----------
    model_dir : Path
        The built model directory.
    names : tuple of str
        The model's instances, in order.
    n_points : int
        Vertices of the model's shapes.
    compactness : Compactness
    generalization : Generalization
    specificity : Specificity
    dimensions : Dimensions
        Width, depth and height of every instance, in the model's frame.
    geometric_error : GeometricError or None
        None when no scan was found (see ``notes``).
    landmarks : LandmarkTransfer or None
        Rows in the order of ``names``; None without landmarks.
    landmarks_source : str or None
        Where the landmarks came from.
    notes : tuple of str
        What was skipped and why, in plain words.
    uncertain_orientation : tuple of (str, float)
        ``(name, confidence)`` of the instances the build named as of
        uncertain orientation (``summary.json``), pictured in the report.
    files : Mapping of str to Path
        What was written: ``"report"``, ``"metrics_json"``, ``"metrics_csv"``,
        ``"error_map_ply"``, ... (empty when nothing was written).
    seconds : float
        Wall time of the measures (and of the writing, when written).
    timings : Mapping of str to float
        Seconds per stage.
    settings : Mapping of str to object
        The options used (``n_samples``, ``truncate``, ``random_state``, ``scaling``).
    """

    model_dir: Path
    names: tuple
    n_points: int
    compactness: Compactness
    generalization: Generalization
    specificity: Specificity
    dimensions: Dimensions
    geometric_error: GeometricError | None
    landmarks: LandmarkTransfer | None
    landmarks_source: str | None
    notes: tuple
    uncertain_orientation: tuple = ()
    files: Mapping = field(default_factory=dict)
    seconds: float = 0.0
    timings: Mapping = field(default_factory=dict)
    settings: Mapping = field(default_factory=dict)

    @property
    def modes(self) -> np.ndarray:
        """The numbers of modes m every measure was evaluated at."""
        return self.compactness.modes


# --------------------------------------------------------------------------
# landmarks
# --------------------------------------------------------------------------


def _xyz(value, where: str) -> np.ndarray:
    try:
        p = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise HortishapeError(f"{where}: a landmark must be three numbers [x, y, z], got {value!r}") from None
    if p.shape != (3,) or not np.isfinite(p).all():
        raise HortishapeError(f"{where}: a landmark must be three finite numbers [x, y, z], got {value!r}")
    return p


def _landmark_dict(value, where: str) -> dict[str, np.ndarray]:
    if isinstance(value, Mapping) and "landmarks" in value and isinstance(value["landmarks"], Mapping):
        value = value["landmarks"]
    if not isinstance(value, Mapping):
        raise HortishapeError(f"{where}: expected a mapping of landmark name to [x, y, z]")
    return {str(k): _xyz(v, f"{where}, landmark {k!r}") for k, v in value.items()}


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except OSError as exc:
        raise HortishapeError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise HortishapeError(f"{path}: not valid JSON ({exc})") from None


def read_landmarks(path) -> dict[str, dict[str, np.ndarray]]:
    """Read landmark positions per instance: stem -> name -> (3,) array, mm.

    Parameters
    ----------
    path : str or os.PathLike
        A JSON or CSV file, or a folder of ``<stem>.truth.json`` /
        ``<stem>.json`` files (see the module docstring for the layouts).

    Returns
    -------
    dict of str to dict of str to (3,) float64 ndarray

    Raises
    ------
    HortishapeError
        Missing or unreadable file, an unknown layout, or a position that is
        not three finite numbers; the message names the file (and the row).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "marks.csv"
    >>> _ = p.write_text("instance,landmark,x,y,z\\napple_000,stalk_tip,1,2,40\\n")
    >>> read_landmarks(p)["apple_000"]["stalk_tip"].tolist()
    [1.0, 2.0, 40.0]
    """
    p = Path(path)
    if p.is_dir():
        out: dict[str, dict[str, np.ndarray]] = {}
        for f in sorted(p.iterdir()):
            if f.name.startswith(".") or not f.is_file():
                continue
            if f.name.endswith(".truth.json"):
                stem = f.name[: -len(".truth.json")]
            elif f.suffix.lower() == ".json":
                stem = f.stem
            else:
                continue
            data = _read_json(f)
            if isinstance(data, Mapping) and isinstance(data.get("landmarks"), Mapping):
                out[stem] = _landmark_dict(data["landmarks"], str(f))
        if not out:
            raise HortishapeError(f"{p}: no landmark files (<stem>.truth.json or <stem>.json with 'landmarks')")
        return out
    if not p.is_file():
        raise HortishapeError(f"{p}: no such landmark file or folder")
    suffix = p.suffix.lower()
    if suffix == ".json":
        data = _read_json(p)
        if not isinstance(data, Mapping) or not data:
            raise HortishapeError(f"{p}: expected a mapping of instance -> landmark name -> [x, y, z]")
        if p.name.endswith(".truth.json") and isinstance(data.get("landmarks"), Mapping):
            return {p.name[: -len(".truth.json")]: _landmark_dict(data["landmarks"], str(p))}
        return {str(stem): _landmark_dict(v, f"{p}, instance {stem!r}") for stem, v in data.items()}
    if suffix == ".csv":
        return _read_landmark_csv(p)
    raise HortishapeError(f"{p}: landmarks must be a .json or .csv file, or a folder of .truth.json files")


def _read_landmark_csv(p: Path) -> dict[str, dict[str, np.ndarray]]:
    try:
        text = p.read_text()
    except OSError as exc:
        raise HortishapeError(f"{p}: cannot read ({exc.strerror or exc})") from None
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    rows = list(csv.reader(lines))
    if not rows:
        raise HortishapeError(f"{p}: the file is empty")
    header = [h.strip().lower() for h in rows[0]]
    inst_col = "instance" if "instance" in header else "stem" if "stem" in header else None
    need = ["landmark", "x", "y", "z"]
    if inst_col is None or any(c not in header for c in need):
        raise HortishapeError(f"{p}: the first row must name the columns instance,landmark,x,y,z; got {rows[0]}")
    idx = [header.index(c) for c in [inst_col, *need]]
    out: dict[str, dict[str, np.ndarray]] = {}
    for line_no, row in enumerate(rows[1:], start=2):
        if len(row) < len(header):
            raise HortishapeError(f"{p}: row {line_no} has {len(row)} fields, the header {len(header)}")
        stem, name, *xyz = (row[i].strip() for i in idx)
        out.setdefault(stem, {})[name] = _xyz(xyz, f"{p}, row {line_no}")
    if not out:
        raise HortishapeError(f"{p}: no landmark rows under the header")
    return out


# --------------------------------------------------------------------------
# the model directory
# --------------------------------------------------------------------------


def _read_summary(model_dir: Path) -> dict:
    path = model_dir / "summary.json"
    if model_dir.is_file():
        # a model file alone (Statismo's, Scalismo's) holds no training shapes
        raise HortishapeError(
            f"{model_dir}: a model file, not the folder 'hortishape build' writes: generalization, "
            "specificity and the error maps need the training shapes the model was built from, which a model "
            "file does not hold (its modes and variances: 'hortishape modes', 'sample')"
        )
    if not model_dir.is_dir():
        raise HortishapeError(f"{model_dir}: not a folder")
    if not path.is_file() or not (model_dir / "model.h5").is_file():
        raise HortishapeError(
            f"{model_dir}: not a built model directory (no summary.json and model.h5; run 'hortishape build')"
        )
    summary = _read_json(path)
    if not isinstance(summary, Mapping) or not summary.get("instances"):
        raise HortishapeError(f"{path}: lists no instances")
    return summary


def _find_scan(name: str, source: str | None, model_dir: Path, scans_dir: Path | None) -> Path | None:
    """The scan of instance ``name``: in ``scans_dir`` if given, else where the build read it."""
    from .io import mesh_formats

    candidates: list[Path] = []
    if scans_dir is not None:
        if source:
            candidates.append(scans_dir / Path(source).name)
        candidates += [scans_dir / f"{name}{ext}" for ext in mesh_formats()]
    elif source:
        src = Path(source)
        candidates.append(src)
        if not src.is_absolute():
            candidates.append(model_dir.parent / src)
    for c in candidates:
        if c.is_file():
            return c
    return None


def _sources(summary: Mapping) -> dict[str, str]:
    out = {}
    for r in summary.get("second_pass", []) or []:
        if isinstance(r, Mapping) and r.get("name") and r.get("source"):
            out[str(r["name"])] = str(r["source"])
    return out


def geometric_error(
    registered: np.ndarray,
    faces: np.ndarray,
    names,
    scan_paths,
    *,
    progress: Progress | None = None,
) -> GeometricError | None:
    """Distance of each registered surface's vertices to its scan, and their average per vertex.

    Parameters
    ----------
    registered : (N, n, 3) float64 ndarray
        Registered surfaces, each in its scan's coordinates, mm.
    faces : (m, 3) int64 ndarray
    names : sequence of str
        The N instances.
    scan_paths : sequence of (path or None)
        The scan of each instance; None where it was not found.
    progress : callable, optional
        Wraps the iterator over the instances.

    Returns
    -------
    GeometricError or None
        None when no scan could be read.
    """
    from .io import read_mesh
    from .surface import closest_points

    kept, dists, missing = [], [], []
    items = list(zip(names, registered, scan_paths))
    for name, vertices, path in (progress(items) if progress else items):
        if path is None:
            missing.append((name, "scan not found"))
            continue
        try:
            scan = read_mesh(path)
        except HortishapeError as exc:
            missing.append((name, str(exc)))
            continue
        kept.append(name)
        dists.append(closest_points(scan, vertices).distances)
    if not kept:
        return None
    d = np.stack(dists)
    return GeometricError(tuple(kept), d.mean(axis=1), d.max(axis=1), d.mean(axis=0), tuple(missing))


def _landmark_array(marks: Mapping, names, notes: list[str], source: str):
    """(N, L, 3) array (NaN where missing) and the landmark names, from stem -> name -> xyz."""
    lm_names = sorted({k for n in names for k in marks.get(n, {})})
    if not lm_names:
        notes.append(f"landmarks: {source} has none for the model's instances; landmark errors skipped")
        return None, ()
    arr = np.full((len(names), len(lm_names), 3), np.nan)
    for i, n in enumerate(names):
        for k, lm in enumerate(lm_names):
            if lm in marks.get(n, {}):
                arr[i, k] = marks[n][lm]
    without = [n for n in names if n not in marks]
    if without:
        notes.append(f"landmarks: none given for {len(without)} instance(s) ({', '.join(without[:5])}"
                     f"{', ...' if len(without) > 5 else ''})")
    extra = sorted(set(marks) - set(names))
    if extra:
        notes.append(f"landmarks: {len(extra)} instance(s) in {source} are not in the model and were ignored")
    return arr, tuple(lm_names)


# --------------------------------------------------------------------------
# evaluate
# --------------------------------------------------------------------------


def evaluate_model(
    model_dir,
    *,
    landmarks=None,
    modes: int | None = None,
    n_samples: int = 200,
    truncate: float | None = 3.0,
    scans=None,
    random_state: RandomState = 0,
    write: bool = True,
    progress: Callable[[int, str], Progress] | None = None,
) -> Evaluation:
    """Measure a built model's quality and write the report (paper section 3.4, Figs. 6, 10-12, Tables 1-3).

    Reads ``model_dir/model.h5``, ``summary.json``, ``aligned/<stem>.ply``
    and ``registered/<stem>.ply``, then:

    1. compactness C(m) of the model (eq. 14), as a fraction of the total variance;
    2. generalization G(m) by leave-one-out on the aligned shapes (eq. 15,
       :func:`hortishape.metrics.generalization`: Procrustes and PCA of the
       others, the left-out shape described by m modes);
    3. specificity S(m) (eq. 16, :func:`hortishape.metrics.specificity`):
       ``n_samples`` random shapes per m against their nearest training shape;
    4. the geometric error of every registered surface against its scan (the
       path recorded in ``summary.json``, or in ``scans``); instances whose
       scan is missing are left out, and named in ``notes``;
    5. landmark transfer errors (Table 3 protocol) when landmarks are given, or
       found as ``<stem>.truth.json`` beside the scans;
    6. width, depth and height of every instance in the model's frame (Table 1).

    With ``write`` (the default) everything goes to ``model_dir/evaluation/``
    (:func:`write_evaluation`).

    Parameters
    ----------
    model_dir : path
        What ``hortishape build`` wrote.
    landmarks : path or mapping, optional
        A landmark file or folder (see :func:`read_landmarks`), or a mapping
        stem -> name -> [x, y, z] in scan coordinates. Default: the
        ``<stem>.truth.json`` files beside the scans, if there are any.
    modes : int, optional
        Evaluate m = 1 .. ``modes``. Default (and largest): N - 2 (the modes of
        a leave-one-out model of N shapes), at most the model's modes.
    n_samples : int, default: 200
        Random shapes per m for the specificity.
    truncate : float or None, default: 3.0
        Truncation of the random coefficients, standard deviations.
    scans : path, optional
        Folder holding the scans, when they are no longer where the build
        read them.
    random_state : int, Generator, SeedSequence or None, default: 0
        For the specificity's random shapes and the report's samples.
    write : bool, default: True
        Write ``model_dir/evaluation/``.
    progress : callable, optional
        ``progress(total, description)`` returns a wrapper for an iterator
        (e.g. a tqdm factory).

    Returns
    -------
    Evaluation

    Raises
    ------
    HortishapeError
        Not a built model directory, fewer than 4 instances, ``modes`` out of
        range, an unreadable landmark file, or files that do not match.

    Examples
    --------
    >>> ev = evaluate_model("model/")                              # doctest: +SKIP
    >>> ev.generalization.mean_mm[4], ev.files["report"]            # doctest: +SKIP
    (0.25, PosixPath('model/evaluation/report.html'))
    """
    from .io import read_mesh
    from .model import ShapeModel
    from .procrustes import procrustes_align

    start = time.perf_counter()
    timings: dict[str, float] = {}
    notes: list[str] = []
    mdir = Path(model_dir)
    summary = _read_summary(mdir)
    names = [str(n) for n in summary["instances"]]
    n_shapes = len(names)
    if n_shapes < 4:
        raise HortishapeError(f"{mdir}: {n_shapes} instances; the leave-one-out evaluation needs at least 4")
    model = ShapeModel.load(mdir / "model.h5")
    scaling = bool((summary.get("procrustes") or {}).get("scaling", False))

    t0 = time.perf_counter()
    registered_meshes = [read_mesh(mdir / "registered" / f"{n}.ply") for n in names]
    faces = registered_meshes[0].faces
    for n, m in zip(names, registered_meshes):
        if m.n_vertices != model.n_points_ or not np.array_equal(m.faces, faces):
            raise HortishapeError(f"{mdir / 'registered' / (n + '.ply')}: does not correspond with the model "
                                  f"({m.n_vertices} vertices, the model {model.n_points_})")
    registered = np.stack([m.vertices for m in registered_meshes])
    del registered_meshes
    if all((mdir / "aligned" / f"{n}.ply").is_file() for n in names):
        aligned = np.stack([read_mesh(mdir / "aligned" / f"{n}.ply").vertices for n in names])
    else:
        from .procrustes import generalized_procrustes

        notes.append("aligned/ is incomplete: the registered surfaces were aligned again")
        aligned = generalized_procrustes(registered, scaling=scaling).aligned
    if aligned.shape != registered.shape:
        raise HortishapeError(f"{mdir / 'aligned'}: the aligned surfaces do not correspond with the model")
    timings["read"] = time.perf_counter() - t0

    largest = min(n_shapes - 2, model.n_components_)
    if modes is None:
        n_modes = largest
    else:
        if isinstance(modes, bool) or int(modes) != modes or modes < 1:
            raise HortishapeError(f"modes must be a positive whole number, got {modes!r}")
        if modes > largest:
            why = (f"a leave-one-out model of {n_shapes} instances has {n_shapes - 2} modes"
                   if largest == n_shapes - 2 else f"the model keeps {model.n_components_} modes")
            raise HortishapeError(f"--modes {modes} is too many: at most {largest} ({why})")
        n_modes = int(modes)

    t0 = time.perf_counter()
    comp = compactness(model, modes=n_modes)
    timings["compactness"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    gen = generalization(aligned, modes=n_modes, scaling=scaling,
                         progress=progress(n_shapes, "generalization (leave-one-out)") if progress else None)
    timings["generalization"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    spec = specificity(model, aligned, modes=n_modes, n_samples=n_samples, truncate=truncate,
                       random_state=random_state)
    timings["specificity"] = time.perf_counter() - t0

    # dimensions: each registered surface rigidly onto the model's mean (its frame, +z up)
    t0 = time.perf_counter()
    in_frame = np.stack([procrustes_align(r, model.mean_)[0] for r in registered])
    dims = dimensions(in_frame, faces)
    timings["dimensions"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    sources = _sources(summary)
    scans_dir = None if scans is None else Path(scans)
    if scans_dir is not None and not scans_dir.is_dir():
        raise HortishapeError(f"{scans_dir}: not a folder")
    paths = [_find_scan(n, sources.get(n), mdir, scans_dir) for n in names]
    geo = geometric_error(registered, faces, names, paths,
                          progress=progress(n_shapes, "geometric error") if progress else None)
    if geo is None:
        where = scans_dir or summary.get("input_dir", "?")
        notes.append(f"geometric error map skipped: none of the {n_shapes} scans was found (looked in {where}; "
                     "give the folder with --scans)")
    elif geo.missing:
        notes.append(f"geometric error: {len(geo.missing)} of {n_shapes} scans left out: "
                     + "; ".join(f"{n}: {why}" for n, why in geo.missing[:5])
                     + ("; ..." if len(geo.missing) > 5 else ""))
    timings["geometric_error"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    marks, lm_source = None, None
    if landmarks is not None:
        if isinstance(landmarks, Mapping):
            marks = {str(s): _landmark_dict(v, f"landmarks[{s!r}]") for s, v in landmarks.items()}
            lm_source = "the given mapping"
        else:
            marks = read_landmarks(landmarks)
            lm_source = str(landmarks)
    else:
        folder = scans_dir or next((p.parent for p in paths if p is not None), None)
        if folder is not None and any((folder / f"{n}.truth.json").is_file() for n in names):
            marks = {n: _landmark_dict(_read_json(folder / f"{n}.truth.json"), str(folder / f"{n}.truth.json"))
                     for n in names if (folder / f"{n}.truth.json").is_file()}
            lm_source = f"{folder}/<stem>.truth.json"
        else:
            notes.append("no landmarks given (--landmarks) nor found beside the scans: landmark errors skipped")
    transfer = None
    if marks is not None:
        arr, lm_names = _landmark_array(marks, names, notes, lm_source)
        if arr is not None:
            transfer = transfer_landmarks(registered, faces, arr, names=lm_names, mean=model.mean_)
    timings["landmarks"] = time.perf_counter() - t0

    uncertain = tuple((str(u["name"]), float(u["confidence"])) for u in summary.get("uncertain_orientation") or []
                      if str(u.get("name")) in names)
    if uncertain:
        notes.append(f"the build found the orientation of {len(uncertain)} instance(s) uncertain (their search's "
                     "margin over a distinct orientation was small): "
                     + ", ".join(f"{n} ({c:.3f})" for n, c in uncertain)
                     + "; see the pictures under 'Orientation' and check that they match the mean")

    ev = Evaluation(
        model_dir=mdir, names=tuple(names), n_points=model.n_points_, compactness=comp, generalization=gen,
        specificity=spec, dimensions=dims, geometric_error=geo, landmarks=transfer, landmarks_source=lm_source,
        notes=tuple(notes), uncertain_orientation=uncertain, seconds=time.perf_counter() - start, timings=timings,
        settings={"n_samples": int(n_samples), "truncate": truncate, "scaling": scaling,
                  "random_state": random_state if isinstance(random_state, (int, type(None))) else "given"},
    )
    if not write:
        return ev
    return write_evaluation(ev, model, faces, mdir / "evaluation", random_state=random_state, start=start)


# --------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------


def _atomic_text(path: Path, text: str) -> Path:
    from .io import atomic_path

    with atomic_path(path, HortishapeError) as tmp:
        tmp.write_text(text)
    return path


def _finite(values) -> list:
    """A list with NaN and infinity as None (strict JSON)."""
    return [None if not math.isfinite(v) else float(v) for v in np.asarray(values, dtype=float).reshape(-1)]


def metrics_dict(ev: Evaluation) -> dict:
    """The JSON-able content of ``metrics.json``.

    Top-level lists aligned with ``modes``: ``compactness`` (cumulative
    fraction of the variance, 0..1), ``generalization_mm`` /
    ``generalization_se_mm`` and ``specificity_mm`` / ``specificity_se_mm``
    (mean Euclidean distance per vertex and its standard error, mm),
    ``generalization_sq`` / ``generalization_se_sq`` and ``specificity_sq`` /
    ``specificity_se_sq`` (the paper's eqs. 15-16, squared norms, mm^2) and
    ``variance_mm2`` (each mode's variance). Then the geometric error,
    landmarks, dimensions and settings.
    """
    c, g, s, d = ev.compactness, ev.generalization, ev.specificity, ev.dimensions
    out: dict = {
        "units": "mm",
        "model_dir": str(ev.model_dir),
        "n_instances": len(ev.names),
        "n_points": ev.n_points,
        "modes": [int(m) for m in c.modes],
        "compactness": _finite(c.ratio),
        "variance_mm2": _finite(c.variance_mm2),
        "generalization_mm": _finite(g.mean_mm),
        "generalization_se_mm": _finite(g.se_mm),
        "generalization_sq": _finite(g.mean_sq),
        "generalization_se_sq": _finite(g.se_sq),
        "specificity_mm": _finite(s.mean_mm),
        "specificity_se_mm": _finite(s.se_mm),
        "specificity_sq": _finite(s.mean_sq),
        "specificity_se_sq": _finite(s.se_sq),
        "definitions": {
            "compactness": "C(m) / total variance: sum of the first m mode variances (eq. 14) over the total",
            "generalization_mm": "leave-one-out: mean Euclidean distance per vertex between each left-out "
                                 "shape and its description by m modes, averaged over the shapes (mm)",
            "generalization_sq": "eq. 15: squared norm |x_i - x'_i(m)|^2 over all 3n coordinates, "
                                 "averaged over the shapes (mm^2)",
            "specificity_mm": "mean Euclidean distance per vertex between a random shape of the model with "
                              "m modes and its nearest training shape, averaged over the random shapes (mm)",
            "specificity_sq": "eq. 16: squared norm |y_i - y'_i(m)|^2, averaged over the random shapes (mm^2)",
            "se": "standard error of the mean (standard deviation / sqrt(count))",
        },
        "dimensions_mm": {
            "mean": dict(zip(("width", "depth", "height"), _finite(d.mean))),
            "sd": dict(zip(("width", "depth", "height"), _finite(d.sd))),
            "per_instance": {n: dict(zip(("width", "depth", "height"), _finite(row)))
                             for n, row in zip(ev.names, d.per_shape)},
            "overall_height": {"mean": float(d.overall_height.mean()),
                               "sd": _finite([d.overall_height.std(ddof=1)])[0]},
            "definition": "extents in the model's frame: height along z without thin ends (a stalk), width "
                          "and depth along the major and minor horizontal axes of the mean; overall_height "
                          "includes the stalk",
        },
        "instances": list(ev.names),
        "settings": dict(ev.settings),
        "notes": list(ev.notes),
        "seconds": ev.seconds,
        "timings_s": dict(ev.timings),
    }
    geo = ev.geometric_error
    if geo is not None:
        out["geometric_error_mm"] = {
            "mean": geo.mean_mm, "sd": _finite([geo.sd_mm])[0],
            "per_instance": dict(zip(geo.names, _finite(geo.per_instance_mm))),
            "max_per_instance": dict(zip(geo.names, _finite(geo.max_mm))),
            "map_max": float(geo.per_vertex_mm.max()),
            "missing": [{"instance": n, "reason": r} for n, r in geo.missing],
        }
    else:
        out["geometric_error_mm"] = None
    t = ev.landmarks
    if t is not None:
        errs = t.errors_mm
        stats = {k: dict(zip(("mean", "sd", "max"), _finite(v[:3])), n=v[3]) for k, v in t.summary().items()}
        out["landmarks"] = {
            "source": ev.landmarks_source,
            "names": list(t.names),
            "protocol": "each given landmark -> closest point of its corresponded surface (face, barycentric) "
                        "-> evaluated on the mean and averaged over the instances -> put on the mean's surface "
                        "-> carried to every instance through the correspondence; error = distance to the given "
                        "position",
            "on_mean_mm": {k: _finite(p) for k, p in zip(t.names, t.on_mean)},
            "error_mm": {k: stats[k] for k in t.names},
            "average_mm": stats.get("average", stats[t.names[0]]),
            "per_instance_mm": {n: dict(zip(t.names, _finite(row))) for n, row in zip(ev.names, errs)},
            "surface_distance_mm": {n: dict(zip(t.names, _finite(row))) for n, row in zip(ev.names, t.surface_mm)},
        }
    else:
        out["landmarks"] = None
    return out


def metrics_csv(ev: Evaluation) -> str:
    """The content of ``metrics.csv``: one row per m, the measures as columns."""
    c, g, s = ev.compactness, ev.generalization, ev.specificity
    cols = {
        "modes": c.modes, "compactness": c.ratio, "variance_mm2": c.variance_mm2,
        "generalization_mm": g.mean_mm, "generalization_se_mm": g.se_mm,
        "generalization_sq": g.mean_sq, "generalization_se_sq": g.se_sq,
        "specificity_mm": s.mean_mm, "specificity_se_mm": s.se_mm,
        "specificity_sq": s.mean_sq, "specificity_se_sq": s.se_sq,
    }
    lines = [",".join(cols)]
    for j in range(len(c.modes)):
        lines.append(",".join(str(int(v[j])) if k == "modes" else f"{float(v[j]):.9g}" for k, v in cols.items()))
    return "\n".join(lines) + "\n"


def write_evaluation(
    ev: Evaluation,
    model,
    faces,
    folder,
    *,
    random_state: RandomState = 0,
    start: float | None = None,
) -> Evaluation:
    """Write an evaluation: metrics, error map, plots, pictures and the HTML report.

    Files in ``folder`` (created if needed), all written atomically:

    - ``metrics.json``, ``metrics.csv`` (see :func:`metrics_dict`, :func:`metrics_csv`);
    - ``error_map.ply`` (the mean shape with a colour per vertex and the
      distance as the vertex property ``error_mm``), ``error_map.vtk`` (the
      distance as point data ``error_mm``) and ``error_map.png`` (four views
      with a colour bar), when there is a geometric error;
    - ``compactness.png``, ``generalization.png``, ``specificity.png``,
      ``landmarks.png`` (with landmarks), ``modes.png``, ``samples.png``;
    - ``report.html``: all of it on one page, pictures embedded.

    Parameters
    ----------
    ev : Evaluation
        From ``evaluate_model(..., write=False)``.
    model : ShapeModel
        The evaluated model (for the mean, the mode and sample pictures).
    faces : (m, 3) array_like of int
        Its triangles.
    folder : path
    random_state : int, Generator, SeedSequence or None, default: 0
        For the random samples pictured.
    start : float, optional
        ``time.perf_counter()`` when the evaluation began (for ``seconds``).

    Returns
    -------
    Evaluation
        ``ev`` with ``files``, ``seconds`` and ``timings`` filled in.
    """
    from dataclasses import replace

    from . import report
    from .io import read_mesh, write_mesh

    t0 = time.perf_counter()
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    mean_mesh = model.to_mesh(model.mean_) if model.faces_ is not None else None
    if mean_mesh is None:
        from .mesh import Mesh

        mean_mesh = Mesh(model.mean_, faces)

    files["compactness_png"] = report.plot_compactness(ev.compactness, out / "compactness.png")
    files["generalization_png"] = report.plot_generalization(ev.generalization, out / "generalization.png")
    files["specificity_png"] = report.plot_specificity(ev.specificity, out / "specificity.png")
    geo = ev.geometric_error
    if geo is not None:
        values = geo.per_vertex_mm
        files["error_map_ply"] = write_mesh(out / "error_map.ply", mean_mesh,
                                            vertex_colors=report.error_colours(values),
                                            vertex_scalars={"error_mm": values})
        files["error_map_vtk"] = write_mesh(out / "error_map.vtk", mean_mesh, vertex_scalars={"error_mm": values})
        files["error_map_png"] = report.render_error_map(mean_mesh, values, out / "error_map.png",
                                                         n_instances=len(geo.names))
    if ev.landmarks is not None:
        files["landmarks_png"] = report.plot_landmark_errors(ev.landmarks, ev.names, out / "landmarks.png")
    n_modes = min(3, model.n_components_)
    files["modes_png"] = report.render_modes(model, out / "modes.png", n_modes=n_modes)
    files["samples_png"] = report.render_samples(model, out / "samples.png", random_state=random_state)
    if ev.uncertain_orientation:
        files["uncertain_png"] = report.render_uncertain(
            mean_mesh, [read_mesh(ev.model_dir / "aligned" / f"{n}.ply").vertices for n, _ in ev.uncertain_orientation],
            [f"{n} ({c:.3f})" for n, c in ev.uncertain_orientation], out / "uncertain_orientation.png")
    timings = dict(ev.timings)
    timings["pictures"] = time.perf_counter() - t0
    seconds = time.perf_counter() - start if start is not None else ev.seconds + timings["pictures"]
    ev = replace(ev, files=files, timings=timings, seconds=seconds)
    files["metrics_json"] = _atomic_text(out / "metrics.json", json.dumps(metrics_dict(ev), indent=1))
    files["metrics_csv"] = _atomic_text(out / "metrics.csv", metrics_csv(ev))
    files["report"] = report.write_report(ev, out / "report.html")
    # files an earlier evaluation wrote that this one did not (no scans, no landmarks now)
    for stale in ("error_map.ply", "error_map.vtk", "error_map.png", "landmarks.png", "uncertain_orientation.png"):
        if (out / stale) not in files.values():
            (out / stale).unlink(missing_ok=True)
    return replace(ev, files=dict(files))
