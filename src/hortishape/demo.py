"""The demo: a whole shape model from built-in synthetic data.

:func:`run_demo` makes a synthetic population (30 apples by default, as CT
surfaces of ~100k vertices standing on the scanner bed), builds the model
with the paper's settings (a 30,000-vertex reference, two registration
passes, generalized Procrustes, PCA), draws five new apples from it,
pictures the first modes (the paper's Figs. 7 and 8) and evaluates the
model (:func:`hortishape.evaluate.evaluate_model`: compactness,
generalization, specificity, the geometric error map, landmark errors
against the generator's ground truth and the population's dimensions),
with the HTML report in ``model/evaluation/report.html``, and writes the
mean and its first mode as B-spline surfaces (STEP, JSON) under ``cad/``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from .pipeline import BuildResult, build_model

if TYPE_CHECKING:  # pragma: no cover
    from .evaluate import Evaluation

__all__ = ["DemoResult", "run_demo", "write_cad_examples", "write_samples"]


@dataclass(frozen=True)
class DemoResult:
    """Where :func:`run_demo` put everything."""

    out_dir: Path
    scans: Path
    build: BuildResult
    samples: tuple
    samples_picture: Path
    modes: tuple
    modes_picture: Path
    evaluation: "Evaluation"
    report: Path
    cad: tuple
    seconds: float


def write_samples(model, out_dir, n: int, *, modes: int = 5, truncate: float = 3.0,
                  random_state=None, picture: bool = True) -> tuple[list[Path], Path | None]:
    """Draw ``n`` random shapes from ``model`` and write them as meshes.

    Coefficients of the first ``modes`` modes come from the standard normal
    truncated at ``+/- truncate`` standard deviations (paper section 3.2).
    Files: ``sample_000.ply`` ... and, with ``picture``, ``samples.png``.

    Returns
    -------
    (list of Path, Path or None)
        The meshes and the picture.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> import numpy as np
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> meshes, picture = write_samples(ShapeModel().fit(shapes, s.faces), tempfile.mkdtemp(), 2, random_state=0,
    ...                                 picture=False)
    >>> [p.name for p in meshes], picture
    (['sample_000.ply', 'sample_001.ply'], None)
    """
    from .io import write_mesh

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    shapes = model.sample(n, modes=modes, truncate=truncate, random_state=random_state)
    paths = [write_mesh(out / f"sample_{i:03d}.ply", s, model.faces_) for i, s in enumerate(shapes)]
    pic = None
    if picture and n:
        from .render import render_grid

        pic = render_grid([model.to_mesh(s) for s in shapes], out / "samples.png",
                          titles=[p.stem for p in paths], n_cols=min(n, 5), views=("front", "top"),
                          cell_size=(220, 240))
    return paths, pic


def write_cad_examples(model, out_dir, *, grid: int = 32) -> list[Path]:
    """The model's mean and its first mode at +3 SD as B-spline surfaces (paper section 2.2.4).

    Writes ``mean.step``, ``mean.json`` and ``mode1_plus3sd.step`` into
    ``out_dir``; without OpenCascade (the ``cad`` extra) only the JSON files.
    The operator is fitted once (:class:`hortishape.cad.BSplineModel`); the
    mode's control points come from it without refitting.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> import numpy as np
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> model = ShapeModel().fit(shapes, s.faces)
    >>> sorted(p.name for p in write_cad_examples(model, tempfile.mkdtemp(), grid=8))
    ['mean.json', 'mean.step', 'mode1_plus3sd.json', 'mode1_plus3sd.step']
    """
    from .cad import BSplineModel, write_cad
    from .errors import HortishapeError

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bm = BSplineModel(grid=grid).fit(model)
    mode = bm.mode_shapes(0, sd=3.0)[1]
    files = [write_cad(out / "mean.json", bm.mean_), write_cad(out / "mode1_plus3sd.json", mode)]
    try:
        files += [write_cad(out / "mean.step", bm.mean_), write_cad(out / "mode1_plus3sd.step", mode)]
    except HortishapeError as exc:  # OpenCascade not installed: the JSON files still say it all
        if "OCP" not in str(exc):
            raise
    return files


def run_demo(
    out_dir="hortishape-demo",
    *,
    product: str = "apple",
    n: int = 30,
    seed: int = 0,
    n_points: int = 30000,
    n_jobs: int | None = None,
    progress: Callable | None = None,
) -> DemoResult:
    """Make a synthetic population, build its model, sample it, picture its modes and evaluate it.

    Parameters
    ----------
    out_dir : path, default: "hortishape-demo"
    product : str, default: "apple"
    n : int, default: 30
        Population size (the paper: 30 apples).
    seed : int, default: 0
    n_points : int, default: 30000
        Vertices of the reference (the paper: 30,000 for apples).
    n_jobs : int, optional
        Parallel processes (default: all cores).
    progress : callable, optional
        ``progress(total, description)`` returns an iterator wrapper (tqdm).

    Returns
    -------
    DemoResult

    Examples
    --------
    The demo's whole run takes minutes; ``hortishape demo`` runs it:

    >>> result = run_demo("hortishape-demo", n=30)   # doctest: +SKIP
    >>> result.report                                 # doctest: +SKIP
    PosixPath('hortishape-demo/model/evaluation/report.html')
    """
    from .evaluate import evaluate_model
    from .model import ShapeModel
    from .report import render_modes, write_mode_meshes
    from .synth import write_population

    start = time.perf_counter()
    out = Path(out_dir)
    scans = out / "scans"
    write_population(product, n, scans, random_state=seed, pose="upright", n_jobs=n_jobs,
                     progress=progress(n, f"synthetic {product}s") if progress else None)
    build = build_model(scans, out / "model", n_points=n_points, n_jobs=n_jobs, progress=progress)
    model = ShapeModel.load(build.model_path)
    samples, samples_pic = write_samples(model, out / "samples", 5, random_state=seed)
    n_modes = min(3, model.n_components_)
    modes = write_mode_meshes(model, out / "modes", n_modes=n_modes)
    modes_pic = render_modes(model, out / "modes" / "modes.png", n_modes=n_modes)
    # the ground-truth landmarks beside the scans are found by default
    evaluation = evaluate_model(build.out_dir, random_state=seed, progress=progress)
    cad_files = write_cad_examples(model, out / "cad")
    return DemoResult(out_dir=out, scans=scans, build=build, samples=tuple(samples), samples_picture=samples_pic,
                      modes=tuple(modes), modes_picture=modes_pic, evaluation=evaluation,
                      report=evaluation.files["report"], cad=tuple(cad_files),
                      seconds=time.perf_counter() - start)
