"""The model in a browser: the page's content, its files, the command line, and the page in headless Chromium.

The browser tests need Chromium (Debian's ``chromium``) and playwright to drive it. Without them they
are skipped, unless ``HORTISHAPE_BROWSER_TESTS=required`` (CI sets it), when they fail instead.
"""

import base64
import json
import os
import re
import shutil
import sys

import numpy as np
import pytest

pytest.importorskip("plotly")

from hortishape.cli import main  # noqa: E402
from hortishape.errors import HortishapeError  # noqa: E402
from hortishape.io import write_mesh  # noqa: E402
from hortishape.layout import ModelDir  # noqa: E402
from hortishape.mesh import Mesh  # noqa: E402
from hortishape.model import ShapeModel  # noqa: E402
from hortishape.synth import make_instance  # noqa: E402
from hortishape.view import view_model, viewer_html, write_viewer  # noqa: E402

N_SHAPES = 21  # 20 modes


def population(n_vertices, n_shapes=N_SHAPES, seed=0):
    """Corresponded apples: one synthetic apple stretched, bulged and bent by known smooth fields."""
    apple = make_instance("apple", random_state=seed, n_vertices=n_vertices).mesh
    v = apple.vertices - apple.vertices.mean(axis=0)
    x, y, z = (v / np.abs(v).max(axis=0)).T
    fields = np.stack([
        v * [0.0, 0.0, 0.25],                                   # taller
        v * [0.2, 0.2, 0.0] * (1 - z[:, None]) / 2,             # wider at the bottom
        np.stack([8 * z ** 2, 0 * z, 0 * z], axis=1),           # bent
        v * [0.15, -0.15, 0.0],                                  # oval
        np.stack([0 * x, 0 * x, 6 * np.cos(3 * np.arctan2(y, x)) * (z > 0.3)], axis=1),  # lobed top
    ])
    rng = np.random.default_rng(seed)
    weights = rng.normal(size=(n_shapes, len(fields))) * [3.0, 2.0, 1.5, 1.0, 0.7]
    smooth = np.einsum("sf,fnc->snc", weights, fields)
    # small smooth wobbles (products of x, y, z up to degree 3), so that every mode has some variance
    monomials = np.stack([x ** i * y ** j * z ** k for i in range(4) for j in range(4) for k in range(4)
                          if i + j + k <= 3])
    wobble = np.einsum("smc,mn->snc", 0.3 * rng.normal(size=(n_shapes, len(monomials), 3)), monomials)
    return apple.vertices[None] + smooth + wobble, apple.faces


@pytest.fixture(scope="module")
def model():
    shapes, faces = population(30000)
    return ShapeModel().fit(shapes, faces)


@pytest.fixture(scope="module")
def page(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("view") / "viewer.html"
    top = model.mean_[model.mean_[:, 2].argmax()]
    bottom = model.mean_[model.mean_[:, 2].argmin()]
    error = np.linspace(0.0, 0.4, model.n_points_)
    return write_viewer(model, path, landmarks={"stalk": top, "bottom": bottom}, error_map=error,
                        title="Apples", provenance={"scans": "apples/"})


def payload(path):
    text = path.read_text(encoding="utf-8")
    return json.loads(re.search(r'<script type="application/json" id="hs-data">(.*?)</script>', text, re.S)[1])


def decode(item):
    return np.frombuffer(base64.b64decode(item["data"]), dtype=np.dtype(item["dtype"]).newbyteorder("<"))


def embedded_instance(data, b):
    """The shape the page draws for coefficients b, computed from the page's own data as viewer.js does."""
    n = data["n_vertices"]
    mean = decode(data["mean"]).astype(np.float64)
    modes = decode(data["modes"]).reshape(data["modes"]["count"], 3 * n).astype(np.float64)
    scale = np.asarray(data["modes"]["scale"])
    b = np.pad(np.asarray(b, dtype=np.float64), (0, len(scale) - len(b)))
    return (mean + (b * scale) @ modes).reshape(n, 3)


# -------------------------------------------------------------------- the page's content


def test_the_page_embeds_the_model_compactly_and_exactly_enough(model, page):
    assert page.n_modes == 20 and page.precision == "int16"
    assert page.size_bytes < 15e6  # 30,000 vertices, 20 modes
    assert page.colourings == ("shape", "displacement", "sd", "error") and page.landmarks == ("stalk", "bottom")
    data = payload(page.path)
    for b in ([0.0], [3.0], [0.0, 3.0], [-3.0, 2.0, 1.0, -1.5, 0.5] + [3.0] * 15):
        want = model.instance(np.pad(b, (0, model.n_components_ - len(b))))
        got = embedded_instance(data, b)
        # int16 quanta (quantization_mm bounds them) and the mean's float32 rounding
        err = np.linalg.norm(got - want, axis=1).max()
        assert err <= page.quantization_mm + 1e-4 * np.abs(model.mean_).max(), (b, err)
    assert page.quantization_mm < 0.01
    # the per-point SD: the root of the trace of each point's covariance, over every mode
    phi = model.components_.reshape(model.n_components_, -1, 3)
    sd = np.sqrt((model.explained_variance_[:, None] * (phi ** 2).sum(axis=2)).sum(axis=0))
    np.testing.assert_allclose(decode(data["sd"]), sd, rtol=1e-6)
    np.testing.assert_allclose(decode(data["error"]), np.linspace(0.0, 0.4, model.n_points_), rtol=1e-6)
    np.testing.assert_array_equal(decode(data["faces"]).reshape(-1, 3), model.faces_)
    # the landmarks are put on the mean's surface: the top one is that vertex
    top = data["landmarks"][0]
    corners = model.faces_[top["face"]]
    np.testing.assert_allclose(np.asarray(top["barycentric"]) @ model.mean_[corners],
                               model.mean_[model.mean_[:, 2].argmax()], atol=1e-6)


def test_the_page_needs_no_network_and_shows_the_numbers(model, page):
    text = page.path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert not re.search(r'<(script|link|img)[^>]+(src|href)="https?:', text)  # nothing fetched
    assert "Apples" in text and "apples/" in text and f"{model.n_points_:,} vertices" in text
    share = 100 * model.explained_variance_ratio_
    assert f"<td>{share[0]:.1f}</td><td>{share[0]:.1f}</td>" in text  # mode 1: its share is the cumulative
    assert f"<td>{np.cumsum(share)[19]:.1f}</td>" in text


def test_options_change_what_is_embedded(model, tmp_path):
    small = write_viewer(model, tmp_path / "five.html", n_modes=5)
    full = write_viewer(model, tmp_path / "float.html", n_modes=5, precision="float32")
    assert small.n_modes == 5 and small.colourings == ("shape", "displacement", "sd") and small.landmarks == ()
    per_mode = 3 * model.n_points_ * 2 * 4 / 3  # int16, base64
    assert full.size_bytes - small.size_bytes == pytest.approx(5 * per_mode, rel=0.01)
    assert full.quantization_mm == 0.0
    assert write_viewer(model, tmp_path / "all.html", n_modes=None).n_modes == model.n_components_
    assert write_viewer(model, tmp_path / "many.html", n_modes=99).n_modes == model.n_components_


def test_bad_input_gives_one_clear_error(model, tmp_path, monkeypatch):
    points_only = ShapeModel().fit(model.mean_[None, :50] + np.random.default_rng(0).normal(size=(4, 50, 3)))
    with pytest.raises(HortishapeError, match="point-set model"):
        viewer_html(points_only)
    with pytest.raises(HortishapeError, match="precision"):
        viewer_html(model, precision="float16")
    with pytest.raises(HortishapeError, match="positive integer"):
        viewer_html(model, n_modes=0)
    with pytest.raises(HortishapeError, match="error map has 3 values"):
        viewer_html(model, error_map=[0.0, 1.0, 2.0])
    with pytest.raises(HortishapeError, match="does not exist"):
        write_viewer(model, tmp_path / "no" / "such" / "folder.html")
    monkeypatch.setitem(sys.modules, "plotly.offline", None)  # plotly not installed
    with pytest.raises(HortishapeError, match=r"pip install 'hortishape\[view\]'"):
        viewer_html(model)


def built_folder(model, root):
    """A folder as 'hortishape build' and 'hortishape evaluate' leave it (model, summary, error map, metrics)."""
    layout = ModelDir(root)
    layout.evaluation.mkdir(parents=True)
    model.save(layout.model)
    layout.summary.write_text(json.dumps({"input_dir": "scans/apples", "reference": "scans/apples/a_000.ply",
                                          "skipped": [], "seconds": 83.2}))
    write_mesh(layout.error_map, Mesh(model.mean_, model.faces_),
               vertex_scalars={"error_mm": np.full(model.n_points_, 0.25)})
    top = model.mean_[model.mean_[:, 2].argmax()]
    layout.metrics.write_text(json.dumps({"landmarks": {"on_mean_mm": {"stalk_tip": top.tolist(),
                                                                       "bottom": [None, None, None]}}}))
    return layout


def test_view_model_reads_a_built_folder(model, tmp_path):
    layout = built_folder(model, tmp_path / "apples")
    for source in (layout.root, layout.model):
        page = view_model(source, tmp_path / "apples.html", n_modes=3)
        assert page.colourings[-1] == "error" and page.landmarks == ("stalk_tip",)  # the unplaced one left out
        text = page.path.read_text(encoding="utf-8")
        assert "/apples</title>" in text and "scans/apples" in text and "hortishape 0" in text
        np.testing.assert_allclose(decode(payload(page.path)["error"]), 0.25)
    # a model file elsewhere: no evaluation to take from
    model.save(tmp_path / "m.h5")
    page = view_model(tmp_path / "m.h5", tmp_path / "m.html", n_modes=3)
    assert page.colourings == ("shape", "displacement", "sd") and page.landmarks == ()
    with pytest.raises(HortishapeError, match="no model file in this folder"):
        view_model(tmp_path / "apples" / "evaluation", tmp_path / "x.html")


def test_a_scalismo_model_file_and_a_large_mesh(model, tmp_path):
    from pathlib import Path

    page = view_model(Path(__file__).parent / "data" / "scalismo" / "asmData_model.h5", tmp_path / "scalismo.html")
    assert page.n_modes == 20 and page.landmarks == ()
    text = page.path.read_text(encoding="utf-8")
    assert "<dt>written by</dt><dd>This is a useless info." in text  # what the file says, as it says it
    assert "<dt>build time</dt><dd>Wed Jun 03 10:49:56 CEST 2015</dd>" in text
    assert "<dt>instances</dt><dd>not recorded</dd>" in text
    # more than 65,535 vertices: the triangles are stored as uint32
    shapes, faces = population(2000, n_shapes=4)
    big = ShapeModel().fit(np.concatenate([shapes + 100.0 * i for i in range(35)], axis=1),
                           np.concatenate([faces + len(shapes[0]) * i for i in range(35)]))
    assert big.n_points_ > 65535
    data = payload(write_viewer(big, tmp_path / "big.html").path)
    assert data["faces"]["dtype"] == "uint32"
    np.testing.assert_array_equal(decode(data["faces"]).reshape(-1, 3), big.faces_)


def test_command_line(model, tmp_path, capsys):
    layout = built_folder(model, tmp_path / "apples")
    out = tmp_path / "page.html"
    assert main(["view", str(layout.root), "--out", str(out), "--modes", "4"]) == 0
    printed = capsys.readouterr().out
    assert str(out) in printed and "4 modes" in printed and "error" in printed and "stalk_tip" in printed
    assert payload(out)["modes"]["count"] == 4
    assert main(["view", str(tmp_path / "missing.h5"), "--out", str(out)]) == 1
    assert "missing.h5" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["view", str(layout.root), "--out", str(out), "--modes", "0"])


# -------------------------------------------------------------------- the page in a browser

CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-gpu-sandbox",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--no-first-run", "--disable-quic"]


def _no_browser(reason):
    if os.environ.get("HORTISHAPE_BROWSER_TESTS") == "required":
        pytest.fail(f"browser tests required (HORTISHAPE_BROWSER_TESTS=required) but {reason}")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _no_browser("playwright is not installed (pip install playwright)")
    executable = os.environ.get("HORTISHAPE_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if not executable:
        _no_browser("no Chromium found (apt-get install chromium, or set HORTISHAPE_CHROMIUM)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=executable, headless=True, args=CHROMIUM_ARGS)
        yield b
        b.close()


class Tab:
    """A page opened at a fragment, with what it logged and asked for."""

    def __init__(self, browser, path, fragment=""):
        self.page = browser.new_page(viewport={"width": 1100, "height": 760})
        self.problems, self.requests = [], []
        self.page.on("console", lambda m: m.type == "error" and self.problems.append(m.text))
        self.page.on("pageerror", lambda e: self.problems.append(str(e)))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(path.as_uri() + fragment)
        self.page.wait_for_function("window.hortishape && window.hortishape.ready", timeout=120_000)

    def renders(self):
        return self.page.evaluate("window.hortishape.renders")

    def after(self, action):
        """Do ``action`` (JavaScript) and wait for the redraw it causes."""
        n = self.renders()
        self.page.evaluate(action)
        self.page.wait_for_function(f"window.hortishape.renders > {n}", timeout=60_000)

    def picture(self):
        from PIL import Image
        import io

        return np.asarray(Image.open(io.BytesIO(self.page.locator("#hs-plot").screenshot())).convert("RGB"), float)

    def close(self):
        self.page.close()


def changed(a, b):
    """Share of pixels that differ visibly between two pictures."""
    return float((np.abs(a - b).max(axis=2) > 24).mean())


@pytest.mark.slow
def test_the_page_draws_without_errors_or_network(browser, page, model):
    tab = Tab(browser, page.path)
    try:
        assert tab.problems == []
        assert all(u.startswith(("file:", "data:", "blob:")) for u in tab.requests), tab.requests
        pic = tab.picture()
        drawn = (np.abs(pic - 255).max(axis=2) > 30).mean()  # not the white background
        assert drawn > 0.08, drawn
        # the vertices drawn are the model's instance: viewer.js computes what Python computes
        b = [3.0, -1.5, 0.0, 2.0]
        got = np.asarray(tab.page.evaluate(f"Array.from(window.hortishape.shapeOf({b}))")).reshape(-1, 3)
        want = model.instance(np.pad(b, (0, model.n_components_ - len(b))))
        assert np.linalg.norm(got - want, axis=1).max() < page.quantization_mm + 1e-3
        # the plot holds the surface and the two landmarks, named
        assert tab.page.evaluate("document.getElementById('hs-plot').data[1].text") == ["stalk", "bottom"]
        assert tab.page.evaluate("document.getElementById('hs-plot').data[0].x.length") == model.n_points_
    finally:
        tab.close()


@pytest.mark.slow
def test_the_fragment_sets_the_coefficients(browser, page):
    pictures = {}
    for fragment in ("#b=0", "#b=3", "#b=0,3"):
        tab = Tab(browser, page.path, fragment)
        try:
            assert tab.problems == []
            pictures[fragment] = tab.picture()
            want = [float(x) for x in fragment[3:].split(",")]
            assert tab.page.evaluate("window.hortishape.b")[:len(want)] == want
        finally:
            tab.close()
    assert changed(pictures["#b=0"], pictures["#b=3"]) > 0.02
    assert changed(pictures["#b=0"], pictures["#b=0,3"]) > 0.02
    assert changed(pictures["#b=3"], pictures["#b=0,3"]) > 0.02


@pytest.mark.slow
def test_sliders_buttons_and_colourings_write_the_fragment(browser, page):
    tab = Tab(browser, page.path, "#b=1,-2&c=sd")
    try:
        p = tab.page
        assert p.evaluate("[document.getElementById('hs-mode-1').value, document.getElementById('hs-mode-2').value]") \
            == ["1", "-2"]
        assert p.evaluate("document.getElementById('hs-colour').value") == "sd"
        assert p.evaluate("document.getElementById('hs-plot').data[0].intensity.length") > 0
        tab.after("(() => { const s = document.getElementById('hs-mode-3'); s.value = 1.5;"
                  " s.dispatchEvent(new Event('input')); })()")
        assert p.evaluate("window.location.hash") == "#b=1,-2,1.5&c=sd"
        tab.after("document.getElementById('hs-reset').click()")
        assert p.evaluate("window.location.hash") == "#b=0&c=sd"
        tab.after("document.getElementById('hs-random').click()")
        drawn = p.evaluate("window.hortishape.b")
        assert len(drawn) == 20 and max(map(abs, drawn)) <= 3 and any(drawn)
        assert p.evaluate("window.location.hash").startswith("#b=")
        tab.after("(() => { const s = document.getElementById('hs-colour'); s.value = 'error';"
                  " s.dispatchEvent(new Event('change')); })()")
        assert p.evaluate("window.location.hash").endswith("&c=error")
        # a script (or the user) changing the address redraws
        tab.after("window.location.hash = '#b=2&c=displacement'")
        assert p.evaluate("window.hortishape.b")[:2] == [2, 0]
        assert p.evaluate("window.hortishape.colour") == "displacement"
        front = tab.picture()
        p.click("#hs-view-top")
        p.wait_for_timeout(500)
        assert changed(front, tab.picture()) > 0.02
        assert tab.problems == []
    finally:
        tab.close()
