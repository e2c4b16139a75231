"""The shape model in a browser: one self-contained HTML page with a slider per mode.

:func:`write_viewer` writes a page that anyone can open from disk in a
current browser, with no network and no Python: the mean surface shaded in
3D (drag to rotate, scroll to zoom), a slider per mode from -3 to +3 SD
acting together, "random sample" and "reset" buttons, front, top and oblique
views, colouring by the displacement from the mean, by the model's SD at each
point or by the geometric error map, the landmarks, and the model's numbers
(variance and cumulative share per mode, instances, vertices, provenance).

The page keeps its state in the URL fragment, ``#b=b1,b2,...`` (the first
modes' coefficients in SD) and optionally ``&c=displacement``, ``&c=sd`` or
``&c=error`` (the colouring): opening ``viewer.html#b=0,3`` shows mode 2 at
+3 SD, and moving a slider writes the fragment back, so a view can be shared
by its address.

The drawing is plotly.js (the ``plotly`` Python package ships it; install
``hortishape[view]``), embedded in the page; hortishape writes only the glue
(``view_assets/viewer.js``). The model is embedded as base64: the mean and
normals as float32 and int8, each mode's displacement at +1 SD as int16 with
one scale per mode (``precision="int16"``, the default; at most half a
quantum off, reported as ``quantization_mm``) or as float32.

:func:`view_model` makes the page of a built model directory or model file,
with the directory's error map and landmarks from its evaluation.
"""

from __future__ import annotations

import base64
import html
import json
import os
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Mapping

import numpy as np
import numpy.typing as npt

from ._files import atomic_path
from .errors import HortishapeError
from .model import ShapeModel

__all__ = ["ViewerPage", "view_model", "viewer_html", "write_viewer", "DEFAULT_MODES", "PRECISIONS"]

#: Modes embedded (and given a slider) unless asked otherwise: 20 modes of a
#: 30,000-vertex model make a page of about 11 MB.
DEFAULT_MODES = 20
#: How the modes are stored in the page.
PRECISIONS = ("int16", "float32")
#: Slider range, in standard deviations either side of the mean.
SLIDER_LIMIT = 3.0
#: Landmark markers sit this far outside the surface (mm) so the surface does not hide them.
LANDMARK_LIFT_MM = 0.5
#: The plain surface's colour.
SURFACE_COLOUR = "#c8a15a"


@dataclass(frozen=True)
class ViewerPage:
    """What :func:`write_viewer` wrote.

    Attributes
    ----------
    path : pathlib.Path
        The HTML file.
    size_bytes : int
        Its size.
    n_modes : int
        Modes embedded, each with a slider.
    precision : str
        How the modes are stored: ``"int16"`` or ``"float32"``.
    quantization_mm : float
        The largest error the storage adds to a vertex at +/-3 SD on every
        mode at once, mm (0 for float32 up to float32's own rounding).
    colourings : tuple of str
        The colourings the page offers (``shape``, ``displacement``, ``sd``
        and, with an error map, ``error``).
    landmarks : tuple of str
        Names of the landmarks drawn.
    """

    path: Path
    size_bytes: int
    n_modes: int
    precision: str
    quantization_mm: float
    colourings: tuple
    landmarks: tuple


def _b64(array: np.ndarray, dtype: str) -> dict:
    a = np.ascontiguousarray(array, dtype=dtype)
    return {"dtype": dtype, "data": base64.b64encode(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()).decode("ascii")}


def _plotly_js() -> tuple[str, str]:
    try:
        from plotly.offline import get_plotlyjs, get_plotlyjs_version
    except ImportError:
        raise HortishapeError("the viewer needs plotly, which draws it: pip install 'hortishape[view]'") from None
    return get_plotlyjs(), get_plotlyjs_version()


def _asset(name: str) -> str:
    return resources.files("hortishape").joinpath("view_assets", name).read_text(encoding="utf-8")


def _payload(model: ShapeModel, n_modes: int, precision: str, error_map, landmarks, name: str) -> tuple[dict, float]:
    from .surface import closest_points, vertex_normals

    n = model.n_points_
    k = n_modes
    sd_modes = np.sqrt(np.maximum(model.explained_variance_, 0.0))
    phi = model.components_.reshape(model.n_components_, n, 3)
    # the displacement of each vertex at +1 SD of each mode
    disp = phi[:k] * sd_modes[:k, None, None]
    if precision == "int16":
        peak = np.abs(disp).reshape(k, -1).max(axis=1) if k else np.zeros(0)
        scale = np.where(peak > 0, peak / 32767.0, 1.0)
        quanta = np.rint(disp / scale[:, None, None]).astype(np.int16)
        modes = {**_b64(quanta, "int16"), "scale": scale.tolist()}
        # half a quantum per mode and coordinate, at 3 SD, all modes at once, as a 3D distance
        quantization = float(SLIDER_LIMIT * 0.5 * scale.sum() * np.sqrt(3.0))
    else:
        modes = {**_b64(disp, "float32"), "scale": [1.0] * k}
        quantization = 0.0
    modes["count"] = k
    # the model's SD at each point: the root of the trace of the point's covariance, over every mode
    sd_point = np.sqrt(np.einsum("k,knc,knc->n", model.explained_variance_, phi, phi))
    faces = np.asarray(model.faces_, dtype=np.int64)
    normals = vertex_normals(model.mean_, faces)
    marks = []
    if landmarks:
        from .mesh import Mesh

        names = list(landmarks)
        cp = closest_points(Mesh(model.mean_, faces), np.array([landmarks[m] for m in names], dtype=np.float64))
        marks = [{"name": str(m), "face": int(f), "barycentric": [float(x) for x in bc]}
                 for m, f, bc in zip(names, cp.face_index, cp.barycentric)]
    data = {
        "file_stem": name,
        "n_vertices": n,
        "slider_limit": SLIDER_LIMIT,
        "colour": SURFACE_COLOUR,
        "mean": _b64(model.mean_, "float32"),
        "normals": _b64(np.rint(normals * 127), "int8"),
        "faces": _b64(faces, "uint16" if n <= 65535 else "uint32"),
        "modes": modes,
        "variance_ratio": model.explained_variance_ratio_[:k].tolist(),
        "sd": _b64(sd_point, "float32"),
        "error": None if error_map is None else _b64(error_map, "float32"),
        "landmarks": marks,
        "landmark_lift": LANDMARK_LIFT_MM,
    }
    return data, quantization


def _numbers(model: ShapeModel, n_modes: int) -> str:
    var = model.explained_variance_
    ratio = model.explained_variance_ratio_
    cum = np.cumsum(ratio)
    # a mode's variance sums over every coordinate; per point, 1 SD moves a point by this much (root mean square)
    rms = np.sqrt(var / model.n_points_)
    rows = "".join(
        f"<tr><td>{i + 1}</td><td>{var[i]:,.0f}</td><td>{rms[i]:.3g}</td>"
        f"<td>{100 * ratio[i]:.1f}</td><td>{100 * cum[i]:.1f}</td></tr>"
        for i in range(model.n_components_))
    note = ("" if n_modes == model.n_components_ else
            f"Sliders for the first {n_modes} of {model.n_components_} modes. ")
    return ('<table><thead><tr><th>mode</th><th>variance mm&sup2;</th><th>per point mm</th><th>share %</th>'
            f"<th>cumulative %</th></tr></thead><tbody>{rows}</tbody></table>"
            f'<p class="hs-note">{note}Variance: over all coordinates (eq. 11); per point: how far 1 SD moves '
            "a point, root mean square.</p>")


def viewer_html(
    model: ShapeModel,
    *,
    n_modes: int | None = DEFAULT_MODES,
    precision: str = "int16",
    error_map: npt.ArrayLike | None = None,
    landmarks: Mapping[str, npt.ArrayLike] | None = None,
    title: str | None = None,
    provenance: Mapping[str, object] | None = None,
) -> tuple[str, dict]:
    """The viewer page of ``model`` as HTML text (see :func:`write_viewer`).

    Returns
    -------
    html : str
        The page.
    info : dict
        ``n_modes``, ``quantization_mm``, ``colourings`` and ``landmarks``.

    Examples
    --------
    >>> import trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> html, info = viewer_html(ShapeModel().fit(shapes, s.faces))
    >>> html.startswith("<!DOCTYPE html>"), info["n_modes"]
    (True, 3)
    """
    model._check_fitted()
    if model.faces_ is None:
        raise HortishapeError("a point-set model (no triangles) cannot be drawn as a surface")
    if precision not in PRECISIONS:
        raise HortishapeError(f"precision must be one of {', '.join(PRECISIONS)}, not {precision!r}")
    if n_modes is not None and (not isinstance(n_modes, (int, np.integer)) or n_modes < 1):
        raise HortishapeError(f"the number of modes must be a positive integer, not {n_modes!r}")
    k = model.n_components_ if n_modes is None else min(int(n_modes), model.n_components_)
    if error_map is not None:
        error_map = np.asarray(error_map, dtype=np.float64).reshape(-1)
        if error_map.shape != (model.n_points_,):
            raise HortishapeError(f"the error map has {error_map.size} values; the model has {model.n_points_} points")
    title = title or "Shape model"
    js, plotly_version = _plotly_js()
    data, quantization = _payload(model, k, precision, error_map, landmarks, _stem(title))
    n_samples = "not recorded" if model.n_samples_ is None else str(model.n_samples_)
    facts = {"instances": n_samples, "vertices": f"{model.n_points_:,}", "triangles": f"{len(model.faces_):,}",
             "modes": f"{model.n_components_} ({k} with sliders)"}
    facts.update({str(key): str(v) for key, v in (provenance or {}).items() if v is not None})
    facts["drawn with"] = f"plotly.js {plotly_version}, page written by hortishape on {time.strftime('%Y-%m-%d %H:%M')}"
    dl = "".join(f"<dt>{html.escape(key)}</dt><dd>{html.escape(v)}</dd>" for key, v in facts.items())
    esc = html.escape
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    page = "".join([
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{esc(title)}</title><style>{_asset('viewer.css')}</style>",
        f"<script>{js}</script></head><body>",
        f"<header><h1>{esc(title)}</h1><p>{'' if model.n_samples_ is None else f'{model.n_samples_} instances, '}"
        f"{model.n_points_:,} vertices, "
        f"{model.n_components_} modes. Drag to rotate, scroll to zoom. The address keeps the sliders "
        "(#b=...), so it can be shared.</p></header>",
        '<main><div id="hs-plot"></div><aside>',
        '<div class="hs-buttons"><button id="hs-random" type="button">random sample</button>'
        '<button id="hs-reset" type="button">reset</button></div>',
        '<div class="hs-buttons">view: <button id="hs-view-front" type="button">front</button>'
        '<button id="hs-view-top" type="button">top</button>'
        '<button id="hs-view-iso" type="button">oblique</button></div>',
        '<h2><label for="hs-colour">Colour</label></h2><select id="hs-colour"></select>',
        '<div id="hs-legend"></div>',
        f"<h2>Modes (SD, -{SLIDER_LIMIT:g} to +{SLIDER_LIMIT:g})</h2><div id=\"hs-sliders\"></div>",
        f"<h2>Variance per mode</h2>{_numbers(model, k)}",
        f"<h2>Model</h2><dl>{dl}</dl>",
        "</aside></main>",
        f'<script type="application/json" id="hs-data">{payload}</script>',
        f"<script>{_asset('viewer.js')}</script></body></html>",
    ])
    colourings = ("shape", "displacement", "sd") + (("error",) if error_map is not None else ())
    info = {"n_modes": k, "quantization_mm": quantization, "colourings": colourings,
            "landmarks": tuple(m["name"] for m in data["landmarks"])}
    return page, info


def _stem(title: str) -> str:
    keep = "".join(c if c.isalnum() or c in "-_" else "-" for c in title.lower())
    return keep.strip("-") or "shape-model"


def write_viewer(
    model: ShapeModel,
    path: str | os.PathLike,
    *,
    n_modes: int | None = DEFAULT_MODES,
    precision: str = "int16",
    error_map: npt.ArrayLike | None = None,
    landmarks: Mapping[str, npt.ArrayLike] | None = None,
    title: str | None = None,
    provenance: Mapping[str, object] | None = None,
) -> ViewerPage:
    """Write the model's viewer: one self-contained HTML page, atomically.

    Parameters
    ----------
    model : ShapeModel
        A fitted model with triangles.
    path : str or os.PathLike
        The HTML file to write; its folder must exist.
    n_modes : int or None, default: 20
        Modes embedded, each with a slider (None: all). The page grows by
        ``6 n`` bytes per mode for ``n`` vertices (int16, base64).
    precision : {"int16", "float32"}, default: "int16"
        How the modes are stored: int16 with one scale per mode, or float32
        (twice the size).
    error_map : (n,) array_like of float, optional
        A value per vertex in mm (the geometric error map of an evaluation),
        offered as a colouring.
    landmarks : mapping of str to (3,) array_like, optional
        Named points on the mean shape, mm. Each is put on the surface
        (closest point) and moves with it as the sliders move.
    title : str, optional
        Heading and window title (default "Shape model").
    provenance : mapping of str to object, optional
        Lines for the page's "Model" list (source file, build time, ...).

    Returns
    -------
    ViewerPage

    Raises
    ------
    HortishapeError
        If plotly is not installed, the model has no triangles, an option is
        invalid, or the file cannot be written.

    Examples
    --------
    >>> import tempfile
    >>> from hortishape.synth import make_instance
    >>> apple = make_instance("apple", random_state=0, n_vertices=2000).mesh
    >>> rng = np.random.default_rng(0)
    >>> shapes = apple.vertices * rng.normal(1.0, 0.05, size=(6, 1, 3))  # six apples, stretched
    >>> model = ShapeModel().fit(shapes, apple.faces)
    >>> page = write_viewer(model, tempfile.mkdtemp() + "/viewer.html", landmarks={"top": [0, 0, 40]})
    >>> page.n_modes, page.colourings, page.landmarks
    (3, ('shape', 'displacement', 'sd'), ('top',))
    """
    text, info = viewer_html(model, n_modes=n_modes, precision=precision, error_map=error_map, landmarks=landmarks,
                             title=title, provenance=provenance)
    p = Path(path)
    with atomic_path(p, HortishapeError) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return ViewerPage(path=p, size_bytes=p.stat().st_size, n_modes=info["n_modes"], precision=precision,
                      quantization_mm=info["quantization_mm"], colourings=info["colourings"],
                      landmarks=info["landmarks"])


def view_model(
    source: str | os.PathLike,
    out: str | os.PathLike,
    *,
    n_modes: int | None = DEFAULT_MODES,
    precision: str = "int16",
    error_map: bool = True,
    landmarks: bool = True,
) -> ViewerPage:
    """Write the viewer page of a model file or a built model directory.

    With a directory (or a model file inside one), the page also gets the
    evaluation's geometric error map (``evaluation/error_map.ply``), the
    landmarks it placed on the mean (``evaluation/metrics.json``) and the
    build's provenance (``summary.json``: input folder, reference, time).

    Parameters
    ----------
    source : str or os.PathLike
        A model file (``model.h5``, Statismo or Scalismo, HDF5 or
        HDF5-JSON) or a folder ``hortishape build`` wrote.
    out : str or os.PathLike
        The HTML file to write.
    n_modes, precision
        As for :func:`write_viewer`.
    error_map, landmarks : bool, default: True
        Use the directory's error map and landmarks when it has them.

    Returns
    -------
    ViewerPage

    Examples
    --------
    >>> import tempfile
    >>> rng = np.random.default_rng(0)
    >>> from hortishape.synth import make_instance
    >>> base = make_instance("pear", random_state=1, n_vertices=1500).mesh
    >>> shapes = base.vertices * rng.normal(1.0, 0.05, size=(8, 1, 3))
    >>> folder = tempfile.mkdtemp()
    >>> path = ShapeModel().fit(shapes, base.faces).save(folder + "/model.h5")
    >>> page = view_model(path, folder + "/pears.html")
    >>> page.n_modes, page.size_bytes < 6e6
    (3, True)
    """
    from .layout import ModelDir
    from .statismo import read_model

    src = Path(source)
    if src.is_dir():
        layout = ModelDir(src)
        model_path = layout.model
        if not model_path.is_file():
            raise HortishapeError(f"{src}: no model file in this folder ({model_path.name}); build one first")
    else:
        model_path = src
        layout = ModelDir(src.parent)
    data = read_model(model_path)  # the file read once: the model and what it says of its origin
    model = ShapeModel._from_data(data)
    if model.faces_ is None:
        raise HortishapeError(f"{model_path}: a point-set model (no triangles) cannot be drawn as a surface")
    provenance = {"model file": str(model_path.resolve()), **data.provenance}
    is_this_build = layout.model.resolve() == model_path.resolve() and layout.summary.is_file()
    values = None
    marks = None
    if is_this_build:
        provenance.update(_build_provenance(layout.summary))
        if error_map and layout.error_map.is_file():
            from .io import read_mesh_data

            got = read_mesh_data(layout.error_map).vertex_scalars.get("error_mm")
            values = got if got is not None and got.shape == (model.n_points_,) else None
        if landmarks and layout.metrics.is_file():
            marks = _metrics_landmarks(layout.metrics)
    where = model_path.resolve().parent
    title = f"Shape model: {where.parent.name + '/' + where.name if is_this_build else model_path.stem}"
    return write_viewer(model, out, n_modes=n_modes, precision=precision, error_map=values, landmarks=marks,
                        title=title, provenance=provenance)


def _build_provenance(summary: Path) -> dict:
    try:
        s = json.loads(summary.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    out = {"scans": s.get("input_dir"), "reference": s.get("reference")}
    if isinstance(s.get("skipped"), list) and s["skipped"]:
        out["skipped scans"] = str(len(s["skipped"]))
    if isinstance(s.get("seconds"), (int, float)):
        out["build seconds"] = f"{s['seconds']:.0f}"
    return out


def _metrics_landmarks(metrics: Path) -> dict | None:
    try:
        lm = json.loads(metrics.read_text(encoding="utf-8")).get("landmarks") or {}
    except (OSError, ValueError):
        return None
    on_mean = lm.get("on_mean_mm") or {}
    marks = {k: p for k, p in on_mean.items() if isinstance(p, list) and len(p) == 3
             and all(isinstance(x, (int, float)) for x in p)}
    return marks or None
