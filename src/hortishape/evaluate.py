"""Evaluate a shape model: the paper's quality measures, error maps and report.

:func:`evaluate_shapes` measures a model and its training shapes given as
arrays (it reads only the scans, for the geometric error) and writes nothing;
:func:`evaluate_model` reads what ``hortishape build`` wrote (``OUT/model.h5``,
``OUT/registered/``, ``OUT/aligned/``, ``OUT/summary.json``; see
:class:`hortishape.layout.ModelDir`), measures it and has
:func:`hortishape.report.write_evaluation` write the files. The measures:

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

The report goes under ``OUT/evaluation/``: ``metrics.json`` and
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
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ._files import Progress
from ._rng import RandomState
from .errors import HortishapeError
from .layout import ModelDir
from .metrics import (
    Evaluation,
    GeometricError,
    compactness,
    dimensions,
    generalization,
    geometric_error,
    specificity,
    transfer_landmarks,
)
from .report import metrics_csv, metrics_dict, write_evaluation

__all__ = [
    "Evaluation",
    "GeometricError",
    "evaluate_model",
    "evaluate_shapes",
    "geometric_error",
    "metrics_csv",
    "metrics_dict",
    "read_landmarks",
    "write_evaluation",
]


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
        return json.loads(path.read_text(encoding="utf-8-sig"))  # a BOM, as Windows editors write
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
        text = p.read_text(encoding="utf-8-sig")  # "CSV UTF-8" from Excel starts with a BOM
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
    layout = ModelDir(model_dir)
    path = layout.summary
    if model_dir.is_file():
        # a model file alone (Statismo's, Scalismo's) holds no training shapes
        raise HortishapeError(
            f"{model_dir}: a model file, not the folder 'hortishape build' writes: generalization, "
            "specificity and the error maps need the training shapes the model was built from, which a model "
            "file does not hold (its modes and variances: 'hortishape modes', 'sample')"
        )
    if not model_dir.is_dir():
        raise HortishapeError(f"{model_dir}: not a folder")
    if not layout.is_built():
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


def _check_modes(modes, n_shapes: int, n_components: int) -> int:
    """The number of modes to evaluate: ``modes`` checked, or the largest possible."""
    largest = min(n_shapes - 2, n_components)
    if modes is None:
        return largest
    if isinstance(modes, bool) or int(modes) != modes or modes < 1:
        raise HortishapeError(f"modes must be a positive whole number, got {modes!r}")
    if modes > largest:
        why = (f"a leave-one-out model of {n_shapes} instances has {n_shapes - 2} modes"
               if largest == n_shapes - 2 else f"the model keeps {n_components} modes")
        raise HortishapeError(f"--modes {modes} is too many: at most {largest} ({why})")
    return int(modes)


def evaluate_shapes(
    model,
    registered,
    aligned,
    faces,
    *,
    names: Sequence[str],
    scans: Sequence | None = None,
    landmarks: Mapping | None = None,
    landmarks_source: str | None = None,
    modes: int | None = None,
    n_samples: int = 200,
    truncate: float | None = 3.0,
    scaling: bool = False,
    random_state: RandomState = 0,
    uncertain_orientation: Sequence[tuple[str, float]] = (),
    notes: Sequence[str] = (),
    model_dir=None,
    progress: Callable[[int, str], Progress] | None = None,
) -> Evaluation:
    """Measure a model's quality from its training shapes (paper section 3.4, Figs. 6, 10-12, Tables 1-3).

    Writes nothing: :func:`hortishape.report.write_evaluation` writes the
    result, :func:`evaluate_model` does both for a built model directory.

    1. compactness C(m) of the model (eq. 14), as a fraction of the total variance;
    2. generalization G(m) by leave-one-out on the aligned shapes (eq. 15,
       :func:`hortishape.metrics.generalization`: Procrustes and PCA of the
       others, the left-out shape described by m modes);
    3. specificity S(m) (eq. 16, :func:`hortishape.metrics.specificity`):
       ``n_samples`` random shapes per m against their nearest training shape;
    4. width, depth and height of every instance in the model's frame (Table 1);
    5. the geometric error of every registered surface against its scan, when
       ``scans`` are given; instances whose scan is missing are left out and
       named in ``notes``;
    6. landmark transfer errors (Table 3 protocol), when ``landmarks`` are given.

    Parameters
    ----------
    model : ShapeModel
        The fitted model.
    registered : (N, n, 3) array_like of float
        The registered surfaces, each in its scan's coordinates, mm.
    aligned : (N, n, 3) array_like of float
        The same surfaces Procrustes-aligned (what the model was fitted to).
    faces : (m, 3) array_like of int
        Their triangles.
    names : sequence of str
        The N instances (the scans' file stems).
    scans : sequence of (path or None), optional
        The scan of each instance, None where it is missing; without it the
        geometric error is skipped.
    landmarks : mapping, optional
        Stem -> name -> [x, y, z] in scan coordinates (:func:`read_landmarks`).
    landmarks_source : str, optional
        Where ``landmarks`` came from, for the report.
    modes : int, optional
        Evaluate m = 1 .. ``modes``. Default (and largest): N - 2 (the modes of
        a leave-one-out model of N shapes), at most the model's modes.
    n_samples : int, default: 200
        Random shapes per m for the specificity.
    truncate : float or None, default: 3.0
        Truncation of the random coefficients, standard deviations.
    scaling : bool, default: False
        Whether the Procrustes alignment removed size (as the build did).
    random_state : int, Generator, SeedSequence or None, default: 0
        For the specificity's random shapes.
    uncertain_orientation : sequence of (str, float), optional
        ``(name, confidence)`` of instances whose orientation the build found uncertain.
    notes : sequence of str, optional
        Notes from reading the inputs, kept first.
    model_dir : path, optional
        The model directory the shapes came from, recorded in the result.
    progress : callable, optional
        ``progress(total, description)`` returns a wrapper for an iterator
        (e.g. a tqdm factory).

    Returns
    -------
    Evaluation
        With no ``files``.

    Raises
    ------
    HortishapeError
        Fewer than 4 instances, ``modes`` out of range, or shapes that do not
        match the model.

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> rng = np.random.default_rng(0)
    >>> shapes = s.vertices * rng.uniform(0.8, 1.2, (6, 1, 3))  # spheres stretched along x, y, z
    >>> model = ShapeModel().fit(shapes, s.faces)
    >>> ev = evaluate_shapes(model, shapes, shapes, s.faces, names=[f"s{i}" for i in range(6)], n_samples=20)
    >>> model.n_components_, [int(m) for m in ev.modes], ev.geometric_error is None
    (3, [1, 2, 3], True)
    >>> bool(ev.compactness.ratio[-1] > 0.999)   # three modes hold all the variance
    True
    """
    from .procrustes import procrustes_align

    start = time.perf_counter()
    timings: dict[str, float] = {}
    notes = list(notes)
    names = [str(n) for n in names]
    n_shapes = len(names)
    if n_shapes < 4:
        raise HortishapeError(f"{n_shapes} instances; the leave-one-out evaluation needs at least 4")
    registered = np.asarray(registered, dtype=np.float64)
    aligned = np.asarray(aligned, dtype=np.float64)
    faces = np.asarray(faces)
    expected = (n_shapes, model.n_points_, 3)
    for what, x in (("registered", registered), ("aligned", aligned)):
        if x.shape != expected:
            raise HortishapeError(f"the {what} shapes have shape {x.shape}; the model and names need {expected}")
    n_modes = _check_modes(modes, n_shapes, model.n_components_)

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

    geo = None
    if scans is not None:
        t0 = time.perf_counter()
        geo = geometric_error(registered, faces, names, list(scans),
                              progress=progress(n_shapes, "geometric error") if progress else None)
        if geo is not None and geo.missing:
            notes.append(f"geometric error: {len(geo.missing)} of {n_shapes} scans left out: "
                         + "; ".join(f"{n}: {why}" for n, why in geo.missing[:5])
                         + ("; ..." if len(geo.missing) > 5 else ""))
        timings["geometric_error"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    transfer = None
    if landmarks is not None:
        arr, lm_names = _landmark_array(landmarks, names, notes, landmarks_source or "the landmarks")
        if arr is not None:
            transfer = transfer_landmarks(registered, faces, arr, names=lm_names, mean=model.mean_)
    timings["landmarks"] = time.perf_counter() - t0

    uncertain = tuple((str(n), float(c)) for n, c in uncertain_orientation if str(n) in names)
    if uncertain:
        notes.append(f"the build found the orientation of {len(uncertain)} instance(s) uncertain (their search's "
                     "margin over a distinct orientation was small): "
                     + ", ".join(f"{n} ({c:.3f})" for n, c in uncertain)
                     + "; see the pictures under 'Orientation' and check that they match the mean")

    return Evaluation(
        model_dir=None if model_dir is None else Path(model_dir), names=tuple(names), n_points=model.n_points_,
        compactness=comp, generalization=gen, specificity=spec, dimensions=dims, geometric_error=geo,
        landmarks=transfer, landmarks_source=landmarks_source if landmarks is not None else None,
        notes=tuple(notes), uncertain_orientation=uncertain, seconds=time.perf_counter() - start, timings=timings,
        settings={"n_samples": int(n_samples), "truncate": truncate, "scaling": scaling,
                  "random_state": random_state if isinstance(random_state, (int, type(None))) else "given"},
    )


def _read_shapes(layout: ModelDir, names: list[str], model, scaling: bool, notes: list[str]):
    """The registered and aligned surfaces of a model directory, checked against the model."""
    from .io import read_mesh

    registered_meshes = [read_mesh(layout.registered_mesh(n)) for n in names]
    faces = registered_meshes[0].faces
    for n, m in zip(names, registered_meshes):
        if m.n_vertices != model.n_points_ or not np.array_equal(m.faces, faces):
            raise HortishapeError(f"{layout.registered_mesh(n)}: does not correspond with the model "
                                  f"({m.n_vertices} vertices, the model {model.n_points_})")
    registered = np.stack([m.vertices for m in registered_meshes])
    del registered_meshes
    if all(layout.aligned_mesh(n).is_file() for n in names):
        aligned = np.stack([read_mesh(layout.aligned_mesh(n)).vertices for n in names])
    else:
        from .procrustes import generalized_procrustes

        notes.append("aligned/ is incomplete: the registered surfaces were aligned again")
        aligned = generalized_procrustes(registered, scaling=scaling).aligned
    if aligned.shape != registered.shape:
        raise HortishapeError(f"{layout.aligned}: the aligned surfaces do not correspond with the model")
    return registered, aligned, faces


def _find_landmarks(landmarks, names: list[str], paths, scans_dir: Path | None, notes: list[str]):
    """Landmarks given (a file, folder or mapping) or found as ``<stem>.truth.json`` beside the scans."""
    if landmarks is not None:
        if isinstance(landmarks, Mapping):
            marks = {str(s): _landmark_dict(v, f"landmarks[{s!r}]") for s, v in landmarks.items()}
            return marks, "the given mapping"
        return read_landmarks(landmarks), str(landmarks)
    folder = scans_dir or next((p.parent for p in paths if p is not None), None)
    if folder is not None and any((folder / f"{n}.truth.json").is_file() for n in names):
        marks = {n: _landmark_dict(_read_json(folder / f"{n}.truth.json"), str(folder / f"{n}.truth.json"))
                 for n in names if (folder / f"{n}.truth.json").is_file()}
        return marks, f"{folder}/<stem>.truth.json"
    notes.append("no landmarks given (--landmarks) nor found beside the scans: landmark errors skipped")
    return None, None


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
    and ``registered/<stem>.ply`` (:class:`hortishape.layout.ModelDir`),
    finds each instance's scan (the path recorded in ``summary.json``, or in
    ``scans``) and its landmarks, measures with :func:`evaluate_shapes` and,
    with ``write`` (the default), writes everything to
    ``model_dir/evaluation/`` (:func:`hortishape.report.write_evaluation`).

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
    from .model import ShapeModel

    start = time.perf_counter()
    notes: list[str] = []
    mdir = Path(model_dir)
    layout = ModelDir(mdir)
    summary = _read_summary(mdir)
    names = [str(n) for n in summary["instances"]]
    if len(names) < 4:
        raise HortishapeError(f"{mdir}: {len(names)} instances; the leave-one-out evaluation needs at least 4")
    model = ShapeModel.load(layout.model)
    scaling = bool((summary.get("procrustes") or {}).get("scaling", False))

    t0 = time.perf_counter()
    registered, aligned, faces = _read_shapes(layout, names, model, scaling, notes)
    sources = _sources(summary)
    scans_dir = None if scans is None else Path(scans)
    if scans_dir is not None and not scans_dir.is_dir():
        raise HortishapeError(f"{scans_dir}: not a folder")
    paths = [_find_scan(n, sources.get(n), mdir, scans_dir) for n in names]
    marks, lm_source = _find_landmarks(landmarks, names, paths, scans_dir, notes)
    read_seconds = time.perf_counter() - t0

    uncertain = [(str(u["name"]), float(u["confidence"])) for u in summary.get("uncertain_orientation") or []]
    ev = evaluate_shapes(
        model, registered, aligned, faces, names=names, scans=paths, landmarks=marks, landmarks_source=lm_source,
        modes=modes, n_samples=n_samples, truncate=truncate, scaling=scaling, random_state=random_state,
        uncertain_orientation=uncertain, notes=notes, model_dir=mdir, progress=progress,
    )
    if ev.geometric_error is None:
        where = scans_dir or summary.get("input_dir", "?")
        ev = replace(ev, notes=(*ev.notes, f"geometric error map skipped: none of the {len(names)} scans was found "
                                           f"(looked in {where}; give the folder with --scans)"))
    ev = replace(ev, timings={"read": read_seconds, **ev.timings}, seconds=time.perf_counter() - start)
    if not write:
        return ev
    by_name = dict(zip(names, aligned))
    return write_evaluation(ev, model, faces, layout.evaluation, random_state=random_state, start=start,
                            aligned={n: by_name[n] for n, _ in ev.uncertain_orientation})
