"""Batches over files: register a reference to many scans, in parallel, resumably.

The registrations of a batch run in worker processes, one scan each. Every
result is written atomically as soon as it is done (``<stem>.ply`` with the
registered reference and ``<stem>.json`` with its log), together with a
fingerprint of what produced it (the reference, the configuration and the
scan's bytes). Run the same batch again and finished scans are not redone;
change the reference, the configuration or a scan and that scan is redone.

A scan that cannot be used (unreadable, open, several components, wrong
units) is reported and skipped, or stops the batch with ``strict=True``.
"""

from __future__ import annotations

import hashlib
import json
import time
import traceback
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from ._batch import raise_failed, run_jobs
from ._files import Progress, atomic_text
from .align import rigid_transform, rotation_about
from .errors import ConvergenceWarning, HortishapeError
from .io import is_mesh_file, mesh_formats, read_mesh, write_mesh
from .layout import ModelDir
from .mesh import Mesh
from .registration import (
    Registration,
    RegistrationConfig,
    Template,
    close_scan,
    heuristics,
    prepare_reference,
    prepare_target,
    register,
)
from .units import PLAUSIBLE_EXTENT_MM, SizeCheck, read_scan

__all__ = [
    "BuildResult",
    "InstanceResult",
    "ScanCheck",
    "ScanFit",
    "build_model",
    "check_scans",
    "choose_reference",
    "find_meshes",
    "find_scans",
    "fit_scan",
    "read_reference_landmarks",
    "register_files",
    "template_fingerprint",
    "update_model",
]



@dataclass(frozen=True)
class InstanceResult:
    """What happened to one scan of a batch.

    Attributes
    ----------
    name : str
        The scan's file stem (the name of its outputs).
    source : str
        The scan's path.
    ok : bool
        Whether it was registered.
    error : str or None
        Why not, in one line.
    resumed : bool
        Taken from an earlier run of the same batch instead of redone.
    seconds : float
        Wall time of its registration (of the earlier run when resumed).
    iterations : int
    converged : bool
    mean_distance : float
        ``d_t`` of the last iteration: mean distance of the kept
        correspondences, mm.
    geometric_error : float
        Mean distance of the registered vertices to the scan's surface, mm
        (the paper's Table 2 measure); with holes, over the vertices nearest
        the scan's own surface, not a hole's patch.
    kept_fraction : float
        Fraction of reference vertices with a kept correspondence at the end.
    orientation_confidence : float
        The orientation search's margin over the best distinct orientation
        (:attr:`hortishape.registration.Registration.orientation_confidence`):
        0 a tie, towards 1 sure; ``nan`` without a search.
    attempts : int
        How often its registration was started in this run: more than 1 when
        a cluster lost the worker running it and ran it again (0 when resumed).
    holes : int
        Holes of the scan, closed by patches before it was registered.
    hole_share : float
        The patches' share of the closed scan's surface.
    """

    name: str
    source: str
    ok: bool
    error: str | None = None
    resumed: bool = False
    seconds: float = 0.0
    iterations: int = 0
    converged: bool = False
    mean_distance: float = float("nan")
    geometric_error: float = float("nan")
    kept_fraction: float = float("nan")
    orientation_confidence: float = float("nan")
    attempts: int = 1
    holes: int = 0
    hole_share: float = 0.0


def find_meshes(folder) -> list[Path]:
    """The mesh files in ``folder`` (not its subfolders), sorted by name.

    Raises
    ------
    HortishapeError
        If ``folder`` is not a folder or holds no mesh file.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from pathlib import Path
    >>> from hortishape.io import write_mesh
    >>> from hortishape.mesh import Mesh
    >>> folder = Path(tempfile.mkdtemp())
    >>> ball = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> for name in ("b.stl", "a.ply"):
    ...     _ = write_mesh(folder / name, Mesh(ball.vertices, ball.faces))
    >>> [p.name for p in find_meshes(folder)]
    ['a.ply', 'b.stl']
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise HortishapeError(f"{folder}: not a folder")
    files = sorted(p for p in folder.iterdir() if p.is_file() and is_mesh_file(p))
    if not files:
        raise HortishapeError(f"{folder}: no mesh files (looked for {', '.join(mesh_formats())})")
    return files


def find_scans(folder, out_dir, *, n_jobs: int | None = None, strict: bool = False,
               progress: Callable[[int, str], Progress] | None = None,
               spacing: Sequence[float] | None = None, scheduler=None,
               split: bool = False) -> tuple[list[Path], list[tuple[str, str]], list[tuple[str, str]]]:
    """The scans in ``folder``: its mesh files and the surfaces of its CT and MRI volumes.

    What is a scan is decided by :func:`hortishape.io.find_sources`, as for
    ``hortishape extract``: the mesh files in ``folder``, and the volumes in it
    and its subfolders (MHA/MHD, NRRD, NIfTI, TIFF stacks, TIFF-slice folders,
    DICOM series found by content, several per study folder). Volumes are
    extracted first, with the default settings, into
    ``out_dir/surfaces/<name>.ply`` (:func:`hortishape.extract.extract_files`);
    a volume already extracted from the same bytes is not redone.
    ``spacing`` (mm along x, y, z) replaces the voxel size the volume files
    give (see :func:`hortishape.extract.extract_file`). With ``scheduler``
    the extractions run on that Dask cluster, whose workers must see
    ``folder`` and ``out_dir`` (they read and write them directly). With
    ``split`` every volume holds several products, each a scan of its own
    (:func:`hortishape.extract.extract_products`).

    Returns
    -------
    paths : list of Path
        Mesh files and extracted surfaces, sorted by name.
    failed : list of (str, str)
        ``(volume, reason)`` of every volume whose extraction failed.
    passed_over : list of (str, str)
        ``(path, reason)`` of every file or folder that is not a scan, and
        with ``split``, of every piece of a volume left out.

    Raises
    ------
    HortishapeError
        If ``folder`` is not a folder or holds neither meshes nor volumes; with
        ``strict``, for the first volume that fails.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = synth.write_population("pear", 2, folder / "scans", random_state=1, n_vertices=3000, n_jobs=1)
    >>> paths, failed, passed_over = find_scans(folder / "scans", folder / "out", n_jobs=1)
    >>> [p.name for p in paths], failed, len(passed_over)   # the ground-truth files are passed over
    (['pear_000.ply', 'pear_001.ply'], [], 4)
    """
    from .extract import extract_files
    from .io import find_sources, volume_formats

    folder = Path(folder)
    if not folder.is_dir():
        raise HortishapeError(f"{folder}: not a folder")
    found = find_sources(folder, exclude=[out_dir])
    files = list(found.meshes)
    passed = list(found.skipped)
    if not files and not found.volumes:
        why = "; ".join(f"{p}: {r}" for p, r in passed[:3])
        raise HortishapeError(f"{folder}: no mesh files or volumes (looked for "
                              f"{', '.join(mesh_formats() + volume_formats())} and DICOM series)"
                              + (f"; passed over {why}" if why else ""))
    failed = []
    if found.volumes:
        results = extract_files(found.volumes, ModelDir(out_dir).surfaces, n_jobs=n_jobs, strict=strict,
                                progress=_stage(progress, len(found.volumes), "extract"), spacing=spacing,
                                scheduler=scheduler, split=split)
        files += [Path(r.mesh) for r in results if r.ok]
        failed = [(r.source, r.error) for r in results if not r.ok]
        passed += [(r.source, f"left out of the split: {why}") for r in results for why in r.left_out]
    return sorted(files, key=lambda p: p.name), failed, passed


def template_fingerprint(template: Template, config: RegistrationConfig, *, scale: float = 1.0) -> str:
    """A digest of what decides a registration's result besides the scan's bytes.

    The reference, the configuration, the scale, hortishape's version (a
    release may change what a configuration does: a build resumed after an
    upgrade registers its scans again) and the registration's heuristic
    constants (:func:`hortishape.registration.heuristics`).

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.mesh import Mesh
    >>> from hortishape.registration import RegistrationConfig, prepare_reference
    >>> ball = trimesh.creation.icosphere(subdivisions=3, radius=30.0)
    >>> template = prepare_reference(Mesh(ball.vertices, ball.faces))
    >>> a = template_fingerprint(template, RegistrationConfig())
    >>> a == template_fingerprint(template, RegistrationConfig()), a == template_fingerprint(template, RegistrationConfig(n_iterations=12))
    (True, False)
    """
    import hortishape

    h = hashlib.sha256()
    h.update(f"hortishape {hortishape.__version__}".encode())
    h.update(repr(heuristics()).encode())
    h.update(np.ascontiguousarray(template.mesh.vertices).tobytes())
    h.update(np.ascontiguousarray(template.mesh.faces).tobytes())
    h.update(repr(config).encode())
    if scale != 1.0:  # fingerprints of unscaled batches stay what they were
        h.update(f"scale={scale!r}".encode())
    return h.hexdigest()


def _file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# Worker state: the template is sent once per worker process, not once per scan.
_WORKER: dict = {}


def _init_worker(template: Template, config: RegistrationConfig, fingerprint: str, scale: float = 1.0,
                 reference_landmarks: dict | None = None) -> None:
    _WORKER.update(template=template, config=config, fingerprint=fingerprint, scale=scale,
                   reference_landmarks=reference_landmarks)


def _result_from_log(log: dict, source: Path, *, resumed: bool) -> InstanceResult:
    s = log["summary"]
    return InstanceResult(
        name=source.stem, source=str(source), ok=True, resumed=resumed, seconds=s["seconds"],
        iterations=s["iterations"], converged=s["converged"], mean_distance=s["mean_distance_mm"],
        geometric_error=s["geometric_error_mm"], kept_fraction=s["kept_fraction"],
        orientation_confidence=_number(s.get("orientation_confidence")), attempts=0 if resumed else 1,
        holes=int(s.get("target_holes", 0)), hole_share=float(s.get("target_hole_share", 0.0)),
    )


def _done_before(ply: Path, log_path: Path, fingerprint: str, digest: str) -> dict | None:
    """The log of a registration already written for this fingerprint and scan content, or None."""
    if not (ply.is_file() and log_path.is_file()):
        return None
    try:
        log = json.loads(log_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if log.get("fingerprint") != fingerprint or log.get("source_sha256") != digest:
        return None
    return log


def registration_log(reg: Registration, *, source: Path, fingerprint: str, digest: str,
                     geometric_error: float, units: SizeCheck) -> dict:
    """The JSON-able log of one registration (what ``<stem>.json`` holds)."""
    last = reg.log[-1]
    return {
        "source": str(source),
        "source_sha256": digest,
        "fingerprint": fingerprint,
        "units": units.as_log(),
        "summary": {
            "seconds": reg.seconds,
            "iterations": len(reg.log),
            "converged": bool(reg.converged),
            "mean_distance_mm": float(last.mean_distance),
            "geometric_error_mm": float(geometric_error),
            "kept_fraction": float(last.kept_fraction),
            "orientation_index": int(reg.orientation_index),
            "orientation_confidence": float(reg.orientation_confidence),
            "orientation_ends": reg.orientation_ends,
            "target_holes": int(reg.target_holes),
            "target_hole_share": float(reg.target_hole_share),
        },
        "plan": None if reg.plan is None else asdict(reg.plan),
        "orientation_scores": np.asarray(reg.orientation_scores).tolist(),
        "transform": np.asarray(reg.transform).tolist(),
        "iterations": [asdict(r) for r in reg.log],
    }


def _job_fingerprint(fingerprint: str, initial_transform, landmarks=None, reference_landmarks=None) -> str:
    """The pass's fingerprint, extended by the scan's own starting transform and landmark pairs if it has them."""
    if initial_transform is None and not landmarks:
        return fingerprint
    h = hashlib.sha256(fingerprint.encode())
    if initial_transform is not None:
        h.update(np.ascontiguousarray(np.asarray(initial_transform, dtype=np.float64)).tobytes())
    for side in (landmarks, reference_landmarks) if landmarks else ():
        for name in sorted(side):
            h.update(name.encode() + np.asarray(side[name], dtype=np.float64).tobytes())
    return h.hexdigest()


def _register_job(job) -> tuple[InstanceResult, tuple | None]:
    """Register the worker's template to one scan: its result, and the registered vertices and log to write.

    The scan is read from its path, or from ``data`` (its file's bytes, sent
    by the client when the job runs on a cluster whose workers may not see
    the client's files). Nothing is written here: the caller writes what
    comes back, so workers need no access to the output folder.
    """
    source, data, digest, fingerprint, initial_transform, landmarks = job
    source = Path(source)
    template, config = _WORKER["template"], _WORKER["config"]
    reference_landmarks = _WORKER.get("reference_landmarks")
    if not reference_landmarks:
        landmarks = None
    try:
        if data is None:
            scan = read_scan(source, scale=_WORKER.get("scale", 1.0))
        else:
            import tempfile

            with tempfile.TemporaryDirectory(prefix="hortishape-") as tmp:
                local = Path(tmp) / source.name
                local.write_bytes(data)
                scan = read_scan(local, scale=_WORKER.get("scale", 1.0))
        target = prepare_target(scan.mesh)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)  # reported as converged=False
            reg = register(template, target, config, initial_transform=initial_transform,
                           reference_landmarks=reference_landmarks if landmarks else None,
                           target_landmarks=landmarks or None)
        from .surface import closest_points

        near = closest_points(target.mesh, reg.vertices)
        # over a hole the registered surface spans what the scan does not have: not measured there
        on_scan = np.ones(len(near.distances), dtype=bool) if target.filled is None \
            else ~target.filled[near.face_index]
        geometric = float(near.distances[on_scan].mean()) if on_scan.any() else float("nan")
        log = registration_log(reg, source=source, fingerprint=fingerprint, digest=digest,
                               geometric_error=geometric, units=scan.units)
        if landmarks:
            log["landmarks"] = sorted(set(landmarks) & set(reference_landmarks))
        return _result_from_log(log, source, resumed=False), (reg.vertices, _jsonable(log))
    except HortishapeError as exc:
        msg = str(exc)
        if not msg.startswith(str(source)):  # errors about "target" name the file here
            msg = f"{source}: {msg}"
        return InstanceResult(name=source.stem, source=str(source), ok=False, error=msg), None
    except OSError as exc:
        return InstanceResult(name=source.stem, source=str(source), ok=False,
                              error=f"{source}: {exc.strerror or exc}"), None
    except Exception as exc:  # a bug must not lose the rest of the batch; say what it was
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return InstanceResult(
            name=source.stem, source=str(source), ok=False,
            error=f"{source}: internal error {type(exc).__name__}: {exc} "
                  f"(at {Path(where.filename).name}:{where.lineno}; please report it)",
        ), None


def _write_registration(folder: Path, stem: str, vertices, faces, log: dict) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    write_mesh(folder / f"{stem}.ply", Mesh(vertices, faces))
    # the log last: its presence with the right fingerprint marks the scan done
    atomic_text(folder / f"{stem}.json", json.dumps(log, indent=1), HortishapeError)


def _cache_key(job_fingerprint: str, digest: str) -> str:
    """A registration's name in the cache: what decided it (settings, reference, start) and the scan's bytes."""
    return hashlib.sha256(f"{job_fingerprint}:{digest}".encode()).hexdigest()


def _with_bytes(job):
    """A job with its scan's bytes, for a worker that may not see this machine's files."""
    source, _, *rest = job
    return (source, Path(source).read_bytes(), *rest)


def register_files(
    reference: Mesh | Template,
    targets: Sequence,
    out_dir,
    *,
    config: RegistrationConfig | None = None,
    n_jobs: int | None = None,
    strict: bool = False,
    progress: Progress | None = None,
    initial_transforms: Sequence | None = None,
    scale: float = 1.0,
    landmarks: Mapping | None = None,
    reference_landmarks: Mapping | None = None,
    scheduler=None,
    cache=None,
) -> list[InstanceResult]:
    """Register ``reference`` to every scan file and write the results.

    For each scan ``<stem>.<ext>`` this writes ``out_dir/<stem>.ply`` (the
    registered reference in the scan's coordinates: same vertex count, order
    and faces for every scan) and ``out_dir/<stem>.json`` (log, transform,
    fingerprint). Scans already registered by an earlier run with the same
    reference and configuration are not redone.

    Parameters
    ----------
    reference : Mesh or Template
        The reference; a ``Mesh`` is used as it is (see
        :func:`hortishape.registration.prepare_reference` to resample it first).
    targets : sequence of path
        Scan files (any mesh format :mod:`hortishape.io` reads).
    out_dir : path
        Created if needed.
    config : RegistrationConfig, optional
        Default: the paper's.
    n_jobs : int, optional
        Worker processes; default: all cores.
    strict : bool, default: False
        Stop at the first scan that fails instead of skipping it.
    progress : callable, optional
        Wraps the iterator of finished scans (e.g. ``tqdm``).
    initial_transforms : sequence of (4, 4) array_like or None, optional
        Per scan, a reference -> scan transform to start from instead of
        searching the orientation (``None`` entries search).
    scale : float, default: 1.0
        Multiplies every scan's coordinates on reading, to give mm (1000 for
        scans in metres); each scan's size is then checked
        (:func:`hortishape.units.check_size`), and the registered surface is
        in mm.
    landmarks : mapping of str to mapping of str to (3,) array_like, optional
        Per scan stem, named points on that scan in its file's units (e.g.
        from :func:`hortishape.evaluate.read_landmarks`); with
        ``reference_landmarks``, the named points on the reference in mm,
        they fix each scan's orientation and are pulled together (see
        ``reference_landmarks`` of :func:`hortishape.registration.register`). A
        scan without any is registered as without landmarks.
    reference_landmarks : mapping of str to (3,) array_like, optional
        Named points on the reference, in mm, in its coordinates.
    scheduler : str or distributed.Client, optional
        Run the registrations as tasks on this Dask cluster (the address of a
        ``dask scheduler``) instead of local processes. Each scan's bytes are
        sent to its worker and the result comes back here to be written, so
        the workers need not see this machine's files; a task whose worker
        dies is run again elsewhere (``InstanceResult.attempts`` counts it).
    cache : path, optional
        A folder of registrations by content: the hash of the scan's bytes,
        of the reference, of the configuration with every heuristic constant,
        and hortishape's version. A registration found there is copied, not
        redone, whatever the scan's name or the output folder; every new one
        is added. Share it between builds (on a cluster: on storage this
        machine sees).

    Returns
    -------
    list of InstanceResult
        In the order of ``targets``.

    Raises
    ------
    HortishapeError
        With ``strict=True``, for the first scan that fails; or if two scans
        share a stem (their outputs would collide).

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> from hortishape.registration import RegistrationConfig
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = synth.write_population("apple", 4, folder / "scans", random_state=1, n_vertices=3000, n_jobs=1)
    >>> quick = RegistrationConfig(n_iterations=12)   # fewer iterations than the paper's, for a quick example
    >>> from hortishape.io import read_mesh
    >>> scans = find_meshes(folder / "scans")
    >>> results = register_files(read_mesh(scans[0]), scans[1:], folder / "registered", n_jobs=1, config=quick)
    >>> [(r.name, r.ok) for r in results]
    [('apple_001', True), ('apple_002', True), ('apple_003', True)]
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    targets = [Path(t) for t in targets]
    stems = [t.stem for t in targets]
    dup = sorted({s for s in stems if stems.count(s) > 1})
    if dup:
        raise HortishapeError(f"several scans share the name {dup[0]!r}: their outputs would collide")
    template = reference if isinstance(reference, Template) else prepare_reference(reference)
    cfg = config if config is not None else RegistrationConfig()
    fingerprint = template_fingerprint(template, cfg, scale=scale)
    starts = list(initial_transforms) if initial_transforms is not None else [None] * len(targets)
    if len(starts) != len(targets):
        raise ValueError(f"{len(starts)} initial transforms for {len(targets)} scans")
    marks = {stem: {name: np.asarray(p, dtype=np.float64) * scale for name, p in m.items()}
             for stem, m in (landmarks or {}).items()}
    ref_marks = None if reference_landmarks is None else {
        name: np.asarray(p, dtype=np.float64) for name, p in reference_landmarks.items()}
    if ref_marks is not None and marks:
        shared = set(ref_marks) & set().union(*(set(m) for m in marks.values()))
        if not shared:
            raise HortishapeError(f"no landmark names the reference ({', '.join(sorted(ref_marks))}) shares "
                                  "with any scan")
    results: list = [None] * len(targets)
    jobs, where = [], []
    faces = template.mesh.faces
    cache_dir = None if cache is None else Path(cache)
    for i, (t, a) in enumerate(zip(targets, starts)):
        start_transform = None if a is None else np.asarray(a, dtype=np.float64).reshape(4, 4)
        scan_marks = {n: p for n, p in marks.get(t.stem, {}).items() if ref_marks and n in ref_marks} or None
        job_fp = _job_fingerprint(fingerprint, start_transform, scan_marks, ref_marks if scan_marks else None)
        try:
            digest = _file_digest(t)
        except OSError as exc:
            results[i] = InstanceResult(name=t.stem, source=str(t), ok=False, error=f"{t}: {exc.strerror or exc}")
            if strict:
                raise_failed(results[i])
            continue
        done = _done_before(out_dir / f"{t.stem}.ply", out_dir / f"{t.stem}.json", job_fp, digest)
        if done is None and cache_dir is not None:  # the same bytes and settings registered by another build
            key = _cache_key(job_fp, digest)
            hit = _done_before(cache_dir / f"{key}.ply", cache_dir / f"{key}.json", job_fp, digest)
            if hit is not None:
                hit["source"] = str(t)
                _write_registration(out_dir, t.stem, read_mesh(cache_dir / f"{key}.ply").vertices, faces, hit)
                done = hit
        if done is not None:
            results[i] = _result_from_log(done, t, resumed=True)
            continue
        jobs.append((str(t), None, digest, job_fp, start_transform, scan_marks))
        where.append(i)

    def collect(k: int, returned, attempts: int) -> InstanceResult:
        result, payload = returned
        if payload is not None:
            vertices, log = payload
            stem = Path(jobs[k][0]).stem
            if attempts > 1:
                log["attempts"] = attempts
            _write_registration(out_dir, stem, vertices, faces, log)
            if cache_dir is not None:
                _write_registration(cache_dir, _cache_key(jobs[k][3], jobs[k][2]), vertices, faces, log)
        return replace(result, attempts=attempts)

    try:
        done_now = run_jobs(_register_job, jobs, n_jobs=n_jobs, progress=progress,
                            stop=raise_failed if strict else None, collect=collect,
                            initializer=_init_worker, initargs=(template, cfg, fingerprint, scale, ref_marks),
                            scheduler=scheduler if jobs else None, ship=_with_bytes if scheduler is not None else None,
                            done=[r for r in results if r is not None])
    finally:
        _WORKER.clear()  # when the jobs ran in this process
    for i, r in zip(where, done_now):
        results[i] = r
    return results  # type: ignore[return-value]


# --------------------------------------------------------------------------
# building a model from a folder of scans
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ScanCheck:
    """A scan as read before registration: its size, or why it cannot be used."""

    path: str
    ok: bool
    error: str | None = None
    n_vertices: int = 0
    size: float = float("nan")  # cube root of the enclosed volume, mm
    extent: float = float("nan")  # largest extent of the bounding box, mm
    holes: int = 0  # holes closed by patches before registration
    hole_share: float = 0.0  # the patches' share of the closed surface


def check_scans(paths: Sequence, *, max_size_ratio: float = 5.0, scale: float = 1.0) -> list[ScanCheck]:
    """Read every scan once and check it is usable for a population model.

    A scan must be one surface (holes up to ``MAX_HOLE_SHARE`` of it are
    closed by patches, :func:`hortishape.registration.close_scan`) of a fruit's size in mm after ``scale``
    (:func:`hortishape.units.check_size`: a population wholly in metres is
    refused too), and its size (cube root of the enclosed volume) within
    ``max_size_ratio`` of the population's median: a scan in metres among
    scans in millimetres is 1000 times too small.

    Returns
    -------
    list of ScanCheck
        In the order of ``paths``.

    Examples
    --------
    >>> import tempfile, pathlib, trimesh
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> for name, r in [("a", 40.0), ("b", 42.0), ("c", 0.04)]:   # c is in metres
    ...     s = trimesh.creation.icosphere(subdivisions=3, radius=r)
    ...     _ = write_mesh(folder / f"{name}.ply", s.vertices, s.faces)
    >>> checks = check_scans(find_meshes(folder))
    >>> [c.ok for c in checks], pathlib.Path(choose_reference(checks)).name
    ([True, True, False], 'a.ply')
    """
    from .surface import signed_volume

    checks = []
    for p in paths:
        p = Path(p)
        try:
            scan = read_scan(p, scale=scale)
            mesh = scan.mesh
            _, closed = close_scan(mesh, name=str(p))
            whole = mesh if closed is None else closed.mesh
            size = abs(signed_volume(whole.vertices, whole.faces)) ** (1.0 / 3.0)
            checks.append(ScanCheck(str(p), True, n_vertices=mesh.n_vertices, size=size,
                                    extent=scan.units.extent_mm, holes=0 if closed is None else closed.n_holes,
                                    hole_share=0.0 if closed is None else closed.hole_share))
        except HortishapeError as exc:
            checks.append(ScanCheck(str(p), False, error=str(exc)))
    sizes = [c.size for c in checks if c.ok]
    if sizes:
        median = float(np.median(sizes))
        for i, c in enumerate(checks):
            if c.ok and not (median / max_size_ratio <= c.size <= median * max_size_ratio):
                ratio = c.size / median
                hint = " (in metres?)" if ratio < 0.01 else " (in micrometres?)" if ratio > 100 else ""
                checks[i] = ScanCheck(
                    c.path, False, n_vertices=c.n_vertices, size=c.size, extent=c.extent,
                    error=f"{c.path}: its size is {ratio:.3g} times the population's median{hint}; "
                          "all scans must be in millimetres",
                )
    return checks


def choose_reference(checks: Sequence[ScanCheck]) -> str:
    """The default reference: the usable scan of median size, a closed one if any.

    The paper picks a random instance; a typical-sized one deforms least on
    average, which keeps correspondences more even across the population. Of
    an even number of scans, the smaller of the two in the middle: the two
    are equally far from the mean of their sizes, and the rounding of the
    sizes (another CPU sums the volumes in another order) would pick one.
    A scan with holes would bring its patches, guessed surface, into every
    registration: the closed scan nearest that size is taken, or where all
    have holes, the nearest of those with the least.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = synth.write_population("apple", 3, folder, random_state=1, n_vertices=3000, n_jobs=1)
    >>> checks = check_scans(find_meshes(folder))
    >>> [round(c.size) for c in checks]                      # the three apples' sizes, mm
    [69, 68, 73]
    >>> Path(choose_reference(checks)).name
    'apple_000.ply'
    """
    ok = [c for c in checks if c.ok]
    if not ok:
        raise HortishapeError("no usable scan to choose a reference from")
    median = sorted(c.size for c in ok)[(len(ok) - 1) // 2]
    least = min(c.hole_share for c in ok)
    return min((c for c in ok if c.hole_share == least), key=lambda c: (abs(c.size - median), c.path)).path


@dataclass(frozen=True)
class BuildResult:
    """What :func:`build_model` made.

    Attributes
    ----------
    out_dir : Path
    model_path : Path
        ``out_dir/model.h5``.
    reference : str
        The scan used as the first pass's reference.
    names : tuple of str
        The instances in the model, in order.
    skipped : tuple of (str, str)
        ``(path, reason)`` of every scan left out.
    first_pass, second_pass : tuple of InstanceResult
    explained_variance : (k,) float64 ndarray
        Variance of each mode, mm^2 (summed over all 3n coordinates).
    n_points : int
        Vertices of the model's shapes.
    seconds : float
    uncertain_orientation : tuple of (str, float)
        ``(name, confidence)`` of the instances whose first-pass orientation
        confidence was below ``UNCERTAIN_CONFIDENCE``: check them.
    retried : tuple of (str, int or str, int)
        ``(name, pass, attempts)`` of the registrations run again after their
        worker was lost: pass 1, 2 or ``"orientation check"``.
    passed_over : tuple of (str, str)
        ``(path, reason)`` of every file or folder in the input that is not a
        scan (:func:`hortishape.io.find_sources`): notes, logs, a localizer.
    """

    out_dir: Path
    model_path: Path
    reference: str
    names: tuple
    skipped: tuple
    first_pass: tuple
    second_pass: tuple
    explained_variance: np.ndarray
    n_points: int
    seconds: float
    uncertain_orientation: tuple = ()
    retried: tuple = ()
    passed_over: tuple = ()


def _stage(progress_factory, total: int, desc: str) -> Progress | None:
    return progress_factory(total, desc) if progress_factory else None


def build_model(
    input_dir,
    out_dir,
    *,
    reference=None,
    n_points: int = 30000,
    n_modes: int | float | None = None,
    n_jobs: int | None = None,
    strict: bool = False,
    config: RegistrationConfig | None = None,
    scaling: bool = False,
    progress: Callable[[int, str], Progress] | None = None,
    scale: float = 1.0,
    landmarks=None,
    spacing: Sequence[float] | None = None,
    scheduler=None,
    cache=None,
    split: bool = False,
) -> BuildResult:
    """Build a statistical shape model from a folder of scans (paper section 2.2.3).

    Steps: read and check every scan (:func:`check_scans`); pick the reference
    (``reference``, or the scan nearest the median size); resample it
    uniformly to ``n_points`` vertices and register it to every scan; take the
    mean of the registered surfaces (after generalized Procrustes) as a new,
    unbiased template and register that to every scan again (the paper's
    second pass, section 3.1); align the corresponded surfaces by generalized
    Procrustes (rotation and translation; ``scaling`` optional); PCA (eqs. 9-12).

    Writes to ``out_dir``:

    - ``model.h5``: the model, in the Statismo v0.9 layout (readable by
      Statismo and Scalismo) with hortishape's own group;
    - ``registered/<stem>.ply``: each scan's corresponded surface in its own
      coordinates (same vertex count, order and faces for all), with
      ``<stem>.json`` logs;
    - ``aligned/<stem>.ply``: the Procrustes-aligned surfaces;
    - ``summary.json``: per-scan registration figures, skipped scans, the
      model's variances;
    - ``work/first-pass/``: the first pass (kept so an interrupted build resumes).

    Every registration is written as soon as it is done; run the same build
    again and finished registrations are not redone.

    Parameters
    ----------
    input_dir : path
        Folder of scan meshes (PLY, STL, OBJ, OFF, VTK, VTP), in mm, or of CT
        volumes, whose surfaces are extracted first into
        ``out_dir/surfaces`` (:func:`find_scans`).
    out_dir : path
    reference : path, optional
        The first pass's reference scan (default: the scan nearest the median size).
    n_points : int, default: 30000
        Vertices of the resampled reference (the paper: 30,000 apple).
    n_modes : int or float, optional
        Modes kept: a number, or a fraction of the variance in (0, 1]. Default: all.
    n_jobs : int, optional
        Parallel registrations (default: all cores).
    strict : bool, default: False
        Stop at the first unusable scan instead of skipping it.
    config : RegistrationConfig, optional
        Default: the paper's.
    scaling : bool, default: False
        Also remove size in the Procrustes alignment (then size is not a mode).
    progress : callable, optional
        ``progress(total, description)`` returns a wrapper for an iterator
        (e.g. a tqdm factory).
    scale : float, default: 1.0
        Multiplies every scan's coordinates on reading, to give mm (1000 for
        scans in metres); the scans' files are not changed.
    landmarks : path or mapping of str to mapping of str to (3,) array_like, optional
        Named points per scan stem, in each scan's coordinates (a file or
        folder :func:`hortishape.evaluate.read_landmarks` reads, or the
        mapping it returns), the reference's among them: in both passes they
        fix each scan's orientation and are pulled together (see
        :func:`register_files`); the second pass's reference points are the
        mean's vertices nearest the first reference's.
    spacing : (3,) sequence of float, optional
        Voxel size in mm (x, y, z) for the volumes in ``input_dir``, in place
        of what their files say (see :func:`find_scans`).
    split : bool, default: False
        Every volume in ``input_dir`` holds several products (a tray): each
        is a scan of its own, ``<volume>_1``, ``<volume>_2``, ... (see
        :func:`find_scans`).
    scheduler : str or distributed.Client, optional
        Run the registrations (both passes and the orientation check) and the
        extraction of volumes as tasks on this Dask cluster (the address of a
        ``dask scheduler``; see :func:`register_files`). Default: local
        processes.
    cache : path, optional
        A folder of registrations by content, shared between builds (see
        :func:`register_files`). Without it, an interrupted build still
        resumes from ``out_dir``.

    Returns
    -------
    BuildResult

    Raises
    ------
    HortishapeError
        If fewer than 3 scans are usable, or with ``strict`` at the first bad scan.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> from hortishape.registration import RegistrationConfig
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = synth.write_population("apple", 4, folder / "scans", random_state=1, n_vertices=3000, n_jobs=1)
    >>> quick = RegistrationConfig(n_iterations=12)   # fewer iterations than the paper's, for a quick example
    >>> result = build_model(folder / "scans", folder / "model", n_points=800, n_jobs=1, config=quick)
    >>> result.names, result.model_path.name, len(result.explained_variance)
    (('apple_000', 'apple_001', 'apple_002', 'apple_003'), 'model.h5', 3)
    """
    from .procrustes import generalized_procrustes

    start = time.perf_counter()
    out = Path(out_dir)
    layout = ModelDir(out)
    files, failed, passed = find_scans(input_dir, out, n_jobs=n_jobs, strict=strict, progress=progress,
                                       spacing=spacing, scheduler=scheduler, split=split)
    checks = check_scans(files, scale=scale)
    skipped = failed + [(c.path, c.error) for c in checks if not c.ok]
    if strict and skipped:
        raise HortishapeError(skipped[0][1])
    usable = [Path(c.path) for c in checks if c.ok]
    if len(usable) < 3:
        reasons = "; ".join([e for _, e in skipped[:3]] + [f"{p}: {r}" for p, r in passed[:3]])
        raise HortishapeError(
            f"{input_dir}: {len(usable)} usable scans; a shape model needs at least 3"
            + (f" ({reasons})" if reasons else "")
        )
    if reference is None:
        ref_path = Path(choose_reference(checks))
    else:
        ref_path = Path(reference)
    ref_scan = read_scan(ref_path, scale=scale)
    cfg = config if config is not None else RegistrationConfig()
    marks, ref_marks = read_reference_landmarks(landmarks, ref_path, scale=scale)

    def run_pass(template: Template, folder: Path, desc: str, paths: list[Path], starts=None,
                 reference_landmarks=None) -> list[InstanceResult]:
        results = register_files(template, paths, folder, config=cfg, n_jobs=n_jobs, strict=strict,
                                 progress=_stage(progress, len(paths), desc), initial_transforms=starts,
                                 scale=scale, landmarks=marks, reference_landmarks=reference_landmarks,
                                 scheduler=scheduler, cache=cache)
        for r in results:
            if not r.ok:
                skipped.append((r.source, r.error))
        return results

    template = prepare_reference(ref_scan.mesh, n_points)
    first = run_pass(template, layout.first_pass, "registration 1/2", usable, reference_landmarks=ref_marks)
    good = [Path(r.source) for r in first if r.ok]
    _need_three(good, input_dir)
    first_files = {p: layout.first_pass / f"{p.stem}.ply" for p in good}
    rechecked = _orientation_consensus(
        first_files, layout, lambda paths, folder, c, starts=None: register_files(
            template, paths, folder, config=c, n_jobs=n_jobs, initial_transforms=starts,
            progress=_stage(progress, len(paths), "orientation check"), scale=scale,
            landmarks=marks, reference_landmarks=ref_marks, scheduler=scheduler, cache=cache),
        cfg, scaling=scaling, flip=_end_over_end(template),
    )

    # the second pass: the mean of the first pass as an unbiased template
    # only the mean and the transforms are kept: a thousand scans' surfaces
    # are a gigabyte at the paper's 30,000 vertices
    gpa1 = generalized_procrustes(np.stack([read_mesh(first_files[p]).vertices for p in good]), scaling=scaling)
    first_mean, first_transforms = gpa1.mean, gpa1.transforms
    del gpa1
    template2 = prepare_reference(Mesh(first_mean, template.mesh.faces), None)
    # The mean lies in the Procrustes frame, where each first-pass surface was
    # moved by its transform: the inverse places the mean on that scan exactly
    # as the first pass found it, so the second pass does not search the
    # orientation again (a mean is rounder than any one scan, and harder to
    # orient).
    starts = [np.linalg.inv(t) for t in first_transforms]
    mean_marks = None
    if ref_marks is not None:  # the mean's vertices that the first reference's marks were nearest
        from scipy.spatial import cKDTree

        nearest = cKDTree(template.mesh.vertices).query(np.array(list(ref_marks.values())))[1]
        mean_marks = {n: template2.mesh.vertices[i] for n, i in zip(ref_marks, nearest)}
    second = run_pass(template2, layout.registered, "registration 2/2", good, starts,
                      reference_landmarks=mean_marks)
    good = [Path(r.source) for r in second if r.ok]
    _need_three(good, input_dir)

    names = [p.stem for p in good]
    uncertain = tuple((Path(r.source).stem, r.orientation_confidence) for r in first
                      if r.ok and Path(r.source).stem in names and r.orientation_confidence < UNCERTAIN_CONFIDENCE)
    model, gpa = _align_and_fit(layout, names, np.stack([read_mesh(layout.registered_mesh(n)).vertices for n in names]),
                                template2.mesh.faces, scaling=scaling, n_modes=n_modes)
    model_path = layout.model
    retried = [(r.name, k + 1, r.attempts) for k, rs in enumerate((first, second)) for r in rs if r.attempts > 1]
    retried += [(rec["name"], "orientation check", rec[key]) for rec in rechecked for key in rec
                if key.endswith("_attempts")]

    seconds = time.perf_counter() - start
    summary = {
        "units": _units_summary(checks, scale),
        "input_dir": str(input_dir),
        "reference": str(ref_path),
        "n_points": template.mesh.n_vertices,
        "instances": names,
        "skipped": [{"path": p, "reason": e} for p, e in skipped],
        "passed_over": [{"path": p, "reason": r} for p, r in passed],
        "retried": [{"name": n, "pass": k, "attempts": a} for n, k, a in retried],
        "first_pass": [asdict(r) for r in first],
        "orientation_check": rechecked,
        "uncertain_orientation": [{"name": n, "confidence": c} for n, c in uncertain],
        "second_pass": [asdict(r) for r in second],
        **_model_summary(model, gpa, scaling, seconds),
    }
    atomic_text(layout.summary, json.dumps(_jsonable(summary), indent=1), HortishapeError)
    return BuildResult(out, model_path, str(ref_path), tuple(names), tuple(skipped), tuple(first),
                       tuple(second), model.explained_variance_, model.n_points_, seconds, uncertain,
                       tuple(retried), tuple(passed))


#: An instance whose first-pass orientation confidence (the search's margin
#: over the best distinct orientation) is below this is named as uncertain
#: in the build's summary and the evaluation report. On the synthetic
#: registration benchmark (200 registrations) it names 18, among them 11 of
#: the 14 that ended turned more than 20 degrees.
UNCERTAIN_CONFIDENCE = 0.05

#: A first-pass registration is registered again from the search's runner-up
#: when the runner-up scored within this fraction of the winner (a near tie:
#: measured on peppers, the right lobe and the next one 90 degrees away
#: scored within 2-5 %) ...
CLOSE_CALL = 0.05
#: ... or when its surface lies farther from the mean of the others than the
#: median plus this many robust standard deviations (MAD * 1.4826).
OUTLIER_SD = 3.0
#: Another registration of a suspect replaces its first one only if it lies
#: closer to the mean of the others by at least this fraction. The first is
#: the search's own judgement, and on fruit whose ends look alike the
#: distances barely tell orientations apart: in a build of 12 zucchini of a
#: second generator (``benchmarks/othergen_build.py``, development seeds),
#: two right ones were replaced by their end-over-end registrations, which
#: lay 0.6 and 1.6 % closer; of the other 39 alternatives tried in builds of
#: its apples, peppers, lemons and peaches, none that was kept had won by
#: more than 1.3 % (several by 1e-15, the runner-up being the first again).
CONSENSUS_GAIN = 0.05


def _end_over_end(template: Template) -> np.ndarray:
    """The reference turned end over end: half a turn about its widest direction across its axis, through its centre."""
    ax = template.axis()
    r = rotation_about(ax.across, np.pi)
    return rigid_transform(r, ax.centre - r @ ax.centre)


def _orientation_consensus(files: dict, layout: ModelDir, register_paths, cfg: RegistrationConfig, *,
                           scaling: bool = False, flip: np.ndarray | None = None) -> list[dict]:
    """Let the population overrule a close or outlying orientation choice (in place on ``files``).

    A single registration has only the scan to judge its initial orientation
    by, and on a near-symmetric fruit (a round apple, a pepper's lobes) the
    best and second-best candidates can score alike; between two fruit that
    differ, a stiff fit may even prefer the reference upside down. The
    population knows better: a surface registered in the wrong orientation
    stands out from the others once all are Procrustes-aligned. Suspects (a
    close call in the search, or an outlier) are registered again from two
    other orientations: the search's runner-up (``orientation_rank=1``, into
    :attr:`ModelDir.first_pass_runner_up`) and, given ``flip`` (a reference -> reference
    transform turning it end over end), the first pass's placement turned
    end over end (into :attr:`ModelDir.first_pass_flipped`; the runner-up is often
    a neighbouring turn of the same end), unless the scan's log says its
    ends were matched by their cavities. Whichever lies closest to the mean
    of the other surfaces is kept, if it lies closer than the first by at
    least ``CONSENSUS_GAIN`` of the first's distance.

    Returns one record per suspect: name, why, the distances (mm RMS) and
    which was kept (``"first"``, ``"runner-up"`` or ``"flipped"``).
    """
    from .procrustes import generalized_procrustes, procrustes_align

    paths = list(files)
    if len(paths) < 4 or cfg.orientation not in ("axis", "search"):
        return []
    shapes = np.stack([read_mesh(files[p]).vertices for p in paths])
    gpa = generalized_procrustes(shapes, scaling=scaling)
    n = len(paths)
    others = (n * gpa.mean[None] - gpa.aligned) / (n - 1)  # the mean of the others, per shape

    def distance(shape: np.ndarray, i: int) -> float:
        aligned, _ = procrustes_align(shape, others[i], scaling=scaling)
        return float(np.sqrt(((aligned - others[i]) ** 2).sum(axis=1).mean()))

    dist = np.array([distance(gpa.aligned[i], i) for i in range(n)])
    med = float(np.median(dist))
    limit = med + OUTLIER_SD * 1.4826 * float(np.median(np.abs(dist - med)))
    suspects = {}
    logs = {}
    for i, p in enumerate(paths):
        try:
            logs[i] = json.loads(files[p].with_suffix(".json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            logs[i] = {}
        scores = np.sort(np.asarray(logs[i].get("orientation_scores") or [], dtype=np.float64))
        close = len(scores) > 1 and scores[1] - scores[0] <= CLOSE_CALL * scores[0]
        if close or dist[i] > limit:
            suspects[i] = "close call" if close else "outlier"
    if not suspects:
        return []
    idx = sorted(suspects)
    tries = {"runner-up": (layout.first_pass_runner_up,
                           register_paths([paths[i] for i in idx], layout.first_pass_runner_up,
                                          replace(cfg, orientation_rank=1)))}
    # A scan whose ends the cavities told apart keeps them: the surfaces'
    # distances do not (measured on 12 synthetic peppers: two scans whose
    # first registration was right lay nearer the others' mean turned end
    # over end, a pepper being nearly as wide at both ends).
    flippable = [i for i in idx if flip is not None and "transform" in logs[i]
                 and logs[i].get("summary", {}).get("orientation_ends") != "cavity"]
    if flippable:
        starts = [np.asarray(logs[i]["transform"], dtype=np.float64) @ flip for i in flippable]
        flipped = register_paths([paths[i] for i in flippable], layout.first_pass_flipped, cfg, starts)
        by_index = dict(zip(flippable, flipped))
        tries["flipped"] = (layout.first_pass_flipped, [by_index.get(i) for i in idx])
    records = []
    for k, i in enumerate(idx):
        rec = {"name": paths[i].stem, "why": suspects[i], "distance_mm": dist[i], "kept": "first"}
        best = dist[i]
        for label, (folder, results) in tries.items():
            res = results[k]
            field = label.replace("-", "_")
            key = field + "_distance_mm"
            rec[key] = None
            if res is not None and res.attempts > 1:
                rec[field + "_attempts"] = res.attempts
            if res is None or not res.ok:
                continue
            alt = folder / f"{paths[i].stem}.ply"
            rec[key] = distance(read_mesh(alt).vertices, i)
            if rec[key] < best and rec[key] <= (1.0 - CONSENSUS_GAIN) * dist[i]:
                best = rec[key]
                files[paths[i]] = alt
                rec["kept"] = label
        records.append(rec)
    return records


def read_reference_landmarks(landmarks, reference, *, scale: float = 1.0) -> tuple[dict | None, dict | None]:
    """Landmarks per scan stem, and the reference's among them in mm.

    Parameters
    ----------
    landmarks : path or mapping of str to mapping of str to (3,) array_like, or None
        A file or folder :func:`hortishape.evaluate.read_landmarks` reads, or
        the mapping it returns; points in each scan's file units.
    reference : path
        The reference scan: its stem names its points.
    scale : float, default: 1.0
        Converts the file units to mm (the reference's points are returned
        scaled; the scans' are scaled by :func:`register_files`).

    Returns
    -------
    marks : dict or None
        Stem -> name -> point, as given (None without landmarks).
    reference_marks : dict or None
        Name -> point of the reference, mm.

    Raises
    ------
    HortishapeError
        If the landmarks name no point on the reference.

    Examples
    --------
    >>> marks = {"apple_000": {"stalk": [0.0, 0.0, 0.04]}, "apple_001": {"stalk": [0.0, 0.001, 0.041]}}
    >>> _, ref = read_reference_landmarks(marks, "scans/apple_000.ply", scale=1000)
    >>> ref["stalk"].tolist()
    [0.0, 0.0, 40.0]
    """
    if landmarks is None:
        return None, None
    if isinstance(landmarks, Mapping):
        marks = dict(landmarks)
    else:
        from .evaluate import read_landmarks

        marks = read_landmarks(landmarks)
    stem = Path(reference).stem
    if stem not in marks:
        raise HortishapeError(f"{landmarks}: no landmarks for the reference {stem}")
    return marks, {n: np.asarray(p, dtype=np.float64) * scale for n, p in marks[stem].items()}


def _number(value) -> float:
    """A JSON number, or NaN for a missing or null one."""
    return float("nan") if value is None else float(value)


def _jsonable(value):
    """``value`` with NaN and infinity as ``null``: strict JSON for other tools."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def _align_and_fit(layout: ModelDir, names, shapes: np.ndarray, faces, *, scaling: bool, n_modes):
    """Generalized Procrustes, the aligned surfaces written, the PCA model fitted and saved."""
    from .model import ShapeModel
    from .procrustes import generalized_procrustes

    gpa = generalized_procrustes(shapes, scaling=scaling)
    # a caller that passed the shapes unnamed frees them here: only the aligned copy is needed from now on
    del shapes
    layout.aligned.mkdir(parents=True, exist_ok=True)
    for name, aligned in zip(names, gpa.aligned):
        write_mesh(layout.aligned_mesh(name), aligned, faces)
    model = ShapeModel(n_components=n_modes).fit(gpa.aligned, faces, names=list(names))
    model.save(layout.model)
    return model, gpa


def update_model(
    model_dir,
    input_dir,
    out_dir,
    *,
    n_jobs: int | None = None,
    strict: bool = False,
    config: RegistrationConfig | None = None,
    progress: Callable[[int, str], Progress] | None = None,
    scale: float = 1.0,
    spacing: Sequence[float] | None = None,
    scheduler=None,
    cache=None,
    split: bool = False,
) -> BuildResult:
    """Add scans to a built model, without registering the scans already in it.

    The model's mean is registered to every new scan (with the orientation
    search; as the paper's second pass registers a mean); the earlier scans
    keep their registrations, which are copied with their aligned surfaces
    into ``out_dir``. Then generalized Procrustes over all the scans and the
    PCA, as :func:`build_model` ends; ``model_dir`` is not changed.

    The result differs from a build of all the scans in one way: there every
    scan is registered to the mean of all the first pass's registrations;
    here the earlier scans were registered to the mean of theirs, and the new
    ones to the model's mean. How much that moves the model is measured in
    the README ("Adding scans to a model"). ``summary.json`` says which scans
    came from where (``update``).

    Parameters
    ----------
    model_dir : path
        A folder :func:`build_model` (or this function) wrote.
    input_dir : path
        Folder of the new scans (meshes or volumes, as for :func:`build_model`).
    out_dir : path
        The updated model's folder: not ``model_dir``.
    n_jobs, strict, config, progress, scale, spacing, scheduler, cache, split
        As for :func:`build_model`. ``config`` should be the one the model
        was built with (default: the paper's).

    Returns
    -------
    BuildResult
        ``first_pass`` is empty; ``second_pass`` holds the new scans'
        registrations; ``names`` the earlier instances, then the new ones.

    Raises
    ------
    HortishapeError
        If ``model_dir`` is not a built model folder, ``out_dir`` is
        ``model_dir``, or no new scan could be registered (with ``strict``, at
        the first that fails).

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> from hortishape.registration import RegistrationConfig
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = synth.write_population("apple", 4, folder / "scans", random_state=1, n_vertices=3000, n_jobs=1)
    >>> quick = RegistrationConfig(n_iterations=12)   # fewer iterations than the paper's, for a quick example
    >>> _ = build_model(folder / "scans", folder / "model", n_points=800, n_jobs=1, config=quick)
    >>> new = synth.make_instance("apple", random_state=9, n_vertices=3000, name="apple_new")
    >>> _ = synth.write_instance(new, folder / "new")
    >>> result = update_model(folder / "model", folder / "new", folder / "model-2", n_jobs=1, config=quick)
    >>> result.names[-1], len(result.names)
    ('apple_new', 5)
    """
    start = time.perf_counter()
    src, layout = ModelDir(model_dir), ModelDir(out_dir)
    if not src.is_built():
        raise HortishapeError(f"{model_dir}: not a built model folder (it needs {src.summary.name} and "
                              f"{src.model.name}; 'hortishape build' writes them)")
    if layout.root.resolve() == src.root.resolve():
        raise HortishapeError(f"{out_dir}: the updated model needs a folder of its own; {model_dir} is not changed")
    from .model import ShapeModel

    try:
        before = json.loads(src.summary.read_text(encoding="utf-8"))
        old_names = [str(n) for n in before["instances"]]
        scaling = bool(before["procrustes"]["scaling"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise HortishapeError(f"{src.summary}: unreadable build summary ({exc})") from None
    old_model = ShapeModel.load(src.model)
    if old_model.faces_ is None:
        raise HortishapeError(f"{src.model}: a point-set model (no triangles) cannot be registered to scans")
    missing = [n for n in old_names if not src.aligned_mesh(n).is_file()]
    if missing:
        raise HortishapeError(f"{model_dir}: the aligned surface of {missing[0]} is missing "
                              f"({src.aligned_mesh(missing[0])}); it is needed to update the model")

    layout.root.mkdir(parents=True, exist_ok=True)
    files, failed, passed = find_scans(input_dir, layout.root, n_jobs=n_jobs, strict=strict, progress=progress,
                                       spacing=spacing, scheduler=scheduler, split=split)
    checks = check_scans(files, scale=scale)
    skipped = failed + [(c.path, c.error) for c in checks if not c.ok]
    taken = set(old_names)
    for c in checks:
        if c.ok and Path(c.path).stem in taken:
            skipped.append((c.path, f"{c.path}: a scan named {Path(c.path).stem} is already in the model"))
    if strict and skipped:
        raise HortishapeError(skipped[0][1])
    usable = [Path(c.path) for c in checks if c.ok and Path(c.path).stem not in taken]
    cfg = config if config is not None else RegistrationConfig()
    template = prepare_reference(Mesh(old_model.mean_, old_model.faces_), None)
    added = register_files(template, usable, layout.registered, config=cfg, n_jobs=n_jobs, strict=strict,
                           progress=_stage(progress, len(usable), "registration of the new scans"), scale=scale,
                           scheduler=scheduler, cache=cache)
    skipped += [(r.source, r.error) for r in added if not r.ok]
    new_names = [r.name for r in added if r.ok]
    if not new_names:
        reasons = "; ".join([e for _, e in skipped[:3]] + [f"{p}: {r}" for p, r in passed[:3]])
        raise HortishapeError(f"{input_dir}: no new scan was registered" + (f" ({reasons})" if reasons else ""))

    # the earlier scans as they are: registered surfaces and logs copied, aligned surfaces read
    import shutil

    for name in old_names:
        for f in (src.registered_mesh(name), src.registered_mesh(name).with_suffix(".json")):
            if f.is_file():
                shutil.copyfile(f, layout.registered / f.name)
    shapes = np.stack([read_mesh(src.aligned_mesh(n)).vertices for n in old_names]
                      + [read_mesh(layout.registered_mesh(n)).vertices for n in new_names])
    names = old_names + new_names
    model, gpa = _align_and_fit(layout, names, shapes, old_model.faces_, scaling=scaling,
                                n_modes=old_model.n_components)
    shift = float(np.sqrt(((model.mean_ - old_model.mean_) ** 2).sum(axis=1).mean()))
    retried = [(r.name, 2, r.attempts) for r in added if r.attempts > 1]
    seconds = time.perf_counter() - start
    summary = {
        "units": _units_summary(checks, scale),
        "input_dir": str(input_dir),
        "reference": f"the mean of {src.model}",
        "n_points": model.n_points_,
        "instances": names,
        "skipped": [{"path": p, "reason": e} for p, e in skipped],
        "passed_over": [{"path": p, "reason": r} for p, r in passed],
        "retried": [{"name": n, "pass": k, "attempts": a} for n, k, a in retried],
        "update": {
            "from": str(src.root),
            "earlier": old_names,
            "added": new_names,
            "how": "the earlier scans keep the registrations of the build they came from (to the mean of its "
                   "first pass); the added scans are registered to that model's mean. A build of all the scans "
                   "would register every scan to the mean of all the first pass's registrations.",
            "mean_moved_rms_mm": shift,
        },
        "first_pass": [],
        "second_pass": [asdict(r) for r in added],
        "uncertain_orientation": [],
        **_model_summary(model, gpa, scaling, seconds),
    }
    atomic_text(layout.summary, json.dumps(_jsonable(summary), indent=1), HortishapeError)
    return BuildResult(layout.root, layout.model, f"the mean of {src.model}", tuple(names), tuple(skipped), (),
                       tuple(added), model.explained_variance_, model.n_points_, seconds, (), tuple(retried),
                       tuple(passed))


def _units_summary(checks, scale: float) -> dict:
    return {"unit": "mm", "scale": scale, "extent_mm": {c.path: c.extent for c in checks if c.ok},
            "plausible_extent_mm": list(PLAUSIBLE_EXTENT_MM)}


def _model_summary(model, gpa, scaling: bool, seconds: float) -> dict:
    """The end of ``summary.json``: Procrustes, the model's variances, the time."""
    return {
        "procrustes": {"scaling": scaling, "iterations": int(gpa.n_iter)},
        "model": {
            "n_modes": int(model.n_components_),
            "variances_mm2": model.explained_variance_.tolist(),
            "explained_variance_ratio": model.explained_variance_ratio_.tolist(),
        },
        "seconds": seconds,
    }


def _need_three(paths: Sequence, input_dir) -> None:
    if len(paths) < 3:
        raise HortishapeError(f"{input_dir}: only {len(paths)} scans registered; a shape model needs at least 3")


# --------------------------------------------------------------------------
# describing a new scan by the model
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ScanFit:
    """Result of :func:`fit_scan`: a new scan described by a model (eq. 13).

    Attributes
    ----------
    coefficients : (k,) float64 ndarray
        Shape coefficients in standard deviations of each mode.
    pose : (4, 4) float64 ndarray
        Rigid transform C from the model's frame to the scan's.
    reconstruction : (n, 3) float64 ndarray
        ``C(x_bar + Phi b)`` in the scan's coordinates, mm.
    mahalanobis : float
        Mahalanobis distance of the shape, standard deviations.
    residual_mean, residual_max : float
        Distance of the reconstruction to the corresponded points, mm.
    surface_mean, surface_max : float
        Distance of the reconstruction's vertices to the scan's surface, mm.
    registration : Registration
        The registration of the model's mean to the scan.
    """

    coefficients: np.ndarray
    pose: np.ndarray
    reconstruction: np.ndarray
    mahalanobis: float
    residual_mean: float
    residual_max: float
    surface_mean: float
    surface_max: float
    registration: Registration


def fit_scan(model, scan: Mesh, *, modes: int | None = None,
             config: RegistrationConfig | None = None) -> ScanFit:
    """Describe a new scan by a model: register its mean, then fit pose and shape.

    The model's mean surface is registered to ``scan`` (RN-ICP-T), which gives
    the scan's points in correspondence with the model; the rigid pose C and
    the coefficients b of eq. 13 are then fitted to them by least squares.

    Parameters
    ----------
    model : ShapeModel
        A fitted model with faces.
    scan : Mesh
        The new scan, mm, any pose.
    modes : int, optional
        Modes to fit (default: all).
    config : RegistrationConfig, optional

    Returns
    -------
    ScanFit

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from hortishape import synth
    >>> from hortishape.registration import RegistrationConfig
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = synth.write_population("apple", 4, folder / "scans", random_state=1, n_vertices=3000, n_jobs=1)
    >>> quick = RegistrationConfig(n_iterations=12)   # fewer iterations than the paper's, for a quick example
    >>> from hortishape.io import read_mesh
    >>> from hortishape.model import ShapeModel
    >>> model = ShapeModel.load(build_model(folder / "scans", folder / "model", n_points=800, n_jobs=1,
    ...                                     config=quick).model_path)
    >>> new = synth.make_instance("apple", random_state=9, n_vertices=3000)
    >>> fit = fit_scan(model, new.mesh, config=quick)
    >>> fit.coefficients.shape, bool(fit.mahalanobis < 10)
    ((3,), True)
    """
    from .model import fit_pose_and_shape
    from .surface import closest_points

    template = prepare_reference(model.to_mesh(model.mean_), None)
    reg = register(template, scan, config)
    fit = fit_pose_and_shape(model, reg.vertices, modes=modes)
    d = closest_points(scan, fit.reconstruction).distances
    return ScanFit(fit.coefficients, fit.pose, fit.reconstruction, float(fit.mahalanobis),
                   float(fit.residual_mean), float(fit.residual_max), float(d.mean()), float(d.max()), reg)
