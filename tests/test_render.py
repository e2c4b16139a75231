"""Tests of hortishape.render: picture sizes, content, view convention, scale, fallback."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import trimesh

from hortishape.errors import MeshError
from hortishape.mesh import Mesh

render = pytest.importorskip("hortishape.render")
pytest.importorskip("matplotlib")
Image = pytest.importorskip("PIL.Image")

WHITE = np.array([255, 255, 255])


def sphere(radius=20.0, centre=(0.0, 0.0, 0.0), subdivisions=3) -> Mesh:
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Mesh(np.asarray(s.vertices) + np.asarray(centre), np.asarray(s.faces))


def ellipsoid(axes=(10.0, 20.0, 40.0)) -> Mesh:
    m = sphere(1.0)
    return Mesh(m.vertices * np.asarray(axes), m.faces)


def read(path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")).astype(int)


def foreground(image: np.ndarray) -> np.ndarray:
    """Pixels that are not (near) white background."""
    return np.abs(image - WHITE).sum(axis=2) > 30


def extent(mask: np.ndarray) -> tuple[int, int, float, float]:
    """Width, height and centre (x, y) of the foreground, in pixels."""
    ys, xs = np.nonzero(mask)
    return (
        int(xs.max() - xs.min() + 1),
        int(ys.max() - ys.min() + 1),
        float(xs.mean()),
        float(ys.mean()),
    )


def vtk_works() -> bool:
    return render._vtk_offscreen_status()[0]


BACKENDS = [
    "matplotlib",
    pytest.param(
        "vtk", marks=pytest.mark.skipif("not vtk_works()", reason="VTK cannot render off-screen here")
    ),
]


# --------------------------------------------------------------------------- #
# single pictures
# --------------------------------------------------------------------------- #


@pytest.mark.parametrize("backend", BACKENDS)
def test_sphere_picture_size_and_content(tmp_path, backend):
    out = render.render_mesh(sphere(), tmp_path / "sphere.png", size=(200, 150), backend=backend)
    assert out == tmp_path / "sphere.png" and out.is_file()
    image = read(out)
    assert image.shape == (150, 200, 3)
    assert image.std() > 10  # not blank
    for y, x in [(0, 0), (0, -1), (-1, 0), (-1, -1)]:
        assert (image[y, x] == WHITE).all()  # background at the corners
    assert not (image[75, 100] == WHITE).all()  # the object in the middle
    width, height, cx, cy = extent(foreground(image))
    # a sphere fills 1 / 1.1 of the picture height, in the middle, and is round
    assert height == pytest.approx(150 / render._MARGIN, abs=4)
    assert width == pytest.approx(height, abs=4)
    assert (cx, cy) == (pytest.approx(99.5, abs=2), pytest.approx(74.5, abs=2))
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary file left


@pytest.mark.parametrize("backend", BACKENDS)
def test_view_convention(tmp_path, backend):
    """+z up in the front view, +x right in front and top views, +y up in the top view."""
    tall = ellipsoid((10.0, 20.0, 40.0))

    def aspect(view):
        out = render.render_mesh(tall, tmp_path / "a.png", view=view, size=(160, 160), backend=backend)
        w, h, _, _ = extent(foreground(read(out)))
        return h / w

    assert aspect("front") == pytest.approx(4.0, rel=0.1)  # x across, z up
    assert aspect("top") == pytest.approx(2.0, rel=0.1)  # x across, y up
    assert aspect("side") == pytest.approx(2.0, rel=0.1)  # y across, z up

    def red_side(axis, view):
        """Where the half with positive coordinate ``axis`` (drawn red) lies: (dx, dy) in pixels."""
        mesh = sphere(20.0)
        halves = np.where(mesh.vertices[:, axis] > 0, 1.0, -1.0)
        out = render.render_mesh(
            mesh, tmp_path / "h.png", view=view, scalars=halves, cmap="bwr", clim=(-1, 1),
            size=(300, 200), backend=backend,
        )
        image = read(out)[:, :200]  # leave out the colour bar
        redness = image[..., 0] - image[..., 2]
        red, blue = np.nonzero(redness > 60), np.nonzero(redness < -60)
        return red[1].mean() - blue[1].mean(), red[0].mean() - blue[0].mean()

    def points(dx_dy, direction):
        dx, dy = dx_dy
        return {"right": dx > 20, "left": dx < -20, "up": dy < -20, "down": dy > 20}[direction]

    assert points(red_side(0, "front"), "right")  # front: +x right
    assert points(red_side(2, "front"), "up")  # front: +z up
    assert points(red_side(0, "top"), "right")  # top: +x right
    assert points(red_side(1, "top"), "up")  # top: +y up
    assert points(red_side(1, "side"), "right")  # side: +y right
    assert points(red_side(1, (-90.0, 0.0)), "left")  # the other side: +y left
    assert points(red_side(0, (180.0, 0.0)), "left")  # the back: +x left
    assert points(red_side(1, (0.0, -90.0)), "down")  # from below: +y down


def test_scalars_draw_a_colour_bar(tmp_path):
    mesh = sphere()
    values = mesh.vertices[:, 0]
    plain = read(render.render_mesh(mesh, tmp_path / "plain.png", size=(320, 240), backend="matplotlib"))
    mapped = read(
        render.render_mesh(
            mesh,
            tmp_path / "mapped.png",
            scalars=values,
            clim=(-10.0, 10.0),
            cmap="viridis",
            scalar_bar_title="x (mm)",
            size=(320, 240),
            backend="matplotlib",
        )
    )
    assert mapped.shape == plain.shape == (240, 320, 3)
    strip = mapped[:, 250:]  # right of the mesh: the colour bar

    def has_colour(region, rgb) -> bool:
        return bool((np.abs(region - np.asarray(rgb) * 255).sum(axis=2) < 25).any())

    import matplotlib

    viridis = matplotlib.colormaps["viridis"]
    for level in (0.0, 0.5, 1.0):
        assert has_colour(strip, viridis(level)[:3])
        assert not has_colour(plain, viridis(level)[:3])


@pytest.mark.parametrize("backend", BACKENDS)
def test_face_scalars_and_nan_values(tmp_path, backend):
    mesh = sphere()
    per_face = np.linspace(0.0, 1.0, mesh.n_faces)
    out = render.render_mesh(mesh, tmp_path / "faces.png", scalars=per_face, size=(200, 150), backend=backend)
    assert read(out).std() > 10
    per_vertex = mesh.vertices[:, 2].copy()
    per_vertex[per_vertex > 10] = np.nan
    out = render.render_mesh(mesh, tmp_path / "nan.png", scalars=per_vertex, size=(200, 150), backend=backend)
    assert read(out).std() > 10


# --------------------------------------------------------------------------- #
# grids
# --------------------------------------------------------------------------- #


def test_grid_size(tmp_path):
    meshes = [sphere(r) for r in (10.0, 12.0, 14.0, 16.0, 18.0)]
    out = render.render_grid(
        meshes, tmp_path / "grid.png", n_cols=3, cell_size=(100, 80), backend="matplotlib"
    )
    assert read(out).shape == (2 * 80, 3 * 100, 3)
    # two views, titles, row titles and a colour bar
    out = render.render_grid(
        meshes[:4],
        tmp_path / "grid2.png",
        n_cols=2,
        views=("front", "top"),
        titles=list("abcd"),
        row_titles=["one", "two"],
        scalars=[m.vertices[:, 2] for m in meshes[:4]],
        cell_size=(120, 100),
        backend="matplotlib",
    )
    font = float(np.clip(0.05 * 100, 10, 20))
    width = round(0.15 * 100) + 2 * 2 * 120 + round(0.45 * 100)
    height = round(2.2 * font) + 2 * 100
    assert read(out).shape == (height, width, 3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_grid_cells_share_one_scale(tmp_path, backend):
    """A sphere of twice the radius is twice as wide, wherever it lies."""
    small, large = sphere(10.0, centre=(100.0, -40.0, 5.0)), sphere(20.0)
    out = render.render_grid([small, large], tmp_path / "scale.png", cell_size=(150, 150), backend=backend)
    image = read(out)
    assert image.shape == (150, 300, 3)
    w_small, _, cx, cy = extent(foreground(image[:, :150]))
    w_large, h_large, _, _ = extent(foreground(image[:, 150:]))
    assert w_large / w_small == pytest.approx(2.0, rel=0.06)
    assert h_large == pytest.approx(150 / render._MARGIN, abs=4)
    assert (cx, cy) == (pytest.approx(74.5, abs=2), pytest.approx(74.5, abs=2))  # centred


@pytest.mark.parametrize("backend", BACKENDS)
def test_grid_views_each_use_their_camera(tmp_path, backend):
    """Front cells show a tall silhouette, top cells a wide one (VTK once reused the old camera)."""
    tall = ellipsoid((20.0, 10.0, 40.0))
    out = render.render_grid(
        [tall, tall],
        tmp_path / "views.png",
        views=("front", "top"),
        cell_size=(120, 120),
        scalars=[tall.vertices[:, 2], None],
        backend=backend,
    )
    image = read(out)
    header = round(2.2 * 10.0)
    cells = [image[header:, k * 120 + 2 : (k + 1) * 120 - 2] for k in range(4)]  # without the separator
    for k, cell in enumerate(cells):
        w, h, _, _ = extent(foreground(cell))
        expected = 2.0 if k < 2 else 0.5  # front: 40 high, 20 wide; top: 10 high, 20 wide
        assert h / w == pytest.approx(expected, rel=0.12), k


# --------------------------------------------------------------------------- #
# backends
# --------------------------------------------------------------------------- #


def test_matplotlib_fallback_large_mesh_is_decimated(tmp_path):
    big = trimesh.creation.icosphere(subdivisions=6, radius=30.0)  # 82k faces
    mesh = Mesh(big.vertices, big.faces)
    v, f, s = render._cluster(mesh.vertices, mesh.faces, mesh.vertices[:, 0], True, 20_000)
    assert f.shape[0] <= 1.3 * 20_000 and f.max() < v.shape[0] and s.shape == (v.shape[0],)
    out = render.render_mesh(mesh, tmp_path / "big.png", size=(160, 120), backend="matplotlib")
    image = read(out)
    assert image.std() > 10 and not (image[60, 80] == WHITE).all()


def test_auto_falls_back_to_matplotlib_when_vtk_fails(tmp_path, monkeypatch):
    monkeypatch.setattr(render, "_vtk_offscreen_status", lambda: (False, "no EGL (test)"))
    with pytest.warns(RuntimeWarning, match="no EGL"):
        out = render.render_mesh(sphere(), tmp_path / "auto.png", size=(120, 90))
    assert read(out).std() > 10
    with pytest.raises(RuntimeError, match="no EGL"):
        render.render_mesh(sphere(), tmp_path / "vtk.png", size=(120, 90), backend="vtk")


def test_probe_survives_a_crashing_renderer():
    crash = "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)"
    ok, reason = render._run_probe(crash)
    assert not ok and "SIGSEGV" in reason
    ok, detail = render._run_probe(f"print('{render._PROBE_OK} vtkSomeWindow')")
    assert ok and detail == "vtkSomeWindow"


def test_import_is_light_and_sets_nothing():
    code = textwrap.dedent(
        """
        import os, sys
        import hortishape.render
        heavy = [m for m in ("pyvista", "vtkmodules", "matplotlib") if m in sys.modules]
        print(heavy, os.environ.get("VTK_DEFAULT_OPENGL_WINDOW"))
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "VTK_DEFAULT_OPENGL_WINDOW"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert done.stdout.strip() == "[] None"


# --------------------------------------------------------------------------- #
# inputs
# --------------------------------------------------------------------------- #


def test_inputs_are_not_modified_and_pairs_are_accepted(tmp_path):
    m = sphere()
    vertices, faces = np.array(m.vertices), np.array(m.faces)
    values = vertices[:, 0].copy()
    before = vertices.copy(), faces.copy(), values.copy()
    out = render.render_mesh(
        (vertices, faces), tmp_path / "pair.png", scalars=values, size=(200, 120), backend="matplotlib"
    )
    assert out.is_file()
    for now, then in zip((vertices, faces, values), before):
        np.testing.assert_array_equal(now, then)
    tm = trimesh.Trimesh(vertices, faces, process=False)
    render.render_mesh(tm, tmp_path / "tm.png", size=(100, 80), backend="matplotlib")


def test_existing_file_is_replaced(tmp_path):
    target = tmp_path / "again.png"
    target.write_bytes(b"old")
    render.render_mesh(sphere(), target, size=(100, 80), backend="matplotlib")
    assert read(target).shape == (80, 100, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.png"]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"view": "bottom"}, "unknown view"),
        ({"view": (0.0, 120.0)}, "elevation"),
        ({"scalars": np.zeros(7)}, "one value per vertex"),
        ({"scalars": np.zeros(642), "clim": (1.0, 0.0)}, "low < high"),
        ({"size": (10, 480)}, "at least 32"),
        ({"size": (640.5, 480)}, "whole numbers"),
        ({"cmap": "no-such-map"}, "colour map"),
        ({"color": "not-a-colour"}, "not a colour"),
        ({"backend": "opengl"}, "backend"),
    ],
)
def test_render_mesh_rejects_bad_options(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        render.render_mesh(sphere(), tmp_path / "bad.png", **kwargs)
    assert not list(tmp_path.iterdir())


def test_render_mesh_rejects_bad_mesh_and_path(tmp_path):
    with pytest.raises(ValueError, match=r"\.png"):
        render.render_mesh(sphere(), tmp_path / "bad.jpg")
    with pytest.raises(MeshError):
        render.render_mesh((np.zeros((3, 2)), [[0, 1, 2]]), tmp_path / "bad.png")
    with pytest.raises(MeshError):
        render.render_mesh("sphere.stl", tmp_path / "bad.png")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"titles": ["a"]}, "titles"),
        ({"row_titles": ["a", "b"]}, "row_titles"),
        ({"n_cols": 0}, "n_cols"),
        ({"views": ()}, "views"),
        ({"views": "front"}, "views"),
        ({"scalars": [np.zeros(642)]}, "scalar arrays"),
        ({"scalars": np.zeros(642)}, "one array"),
        ({"color": ["red", "green", "blue"]}, "color"),
        ({"cell_size": (100, 40), "titles": ["a", "b"]}, "no room"),
    ],
)
def test_render_grid_rejects_bad_options(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        render.render_grid([sphere(), sphere()], tmp_path / "bad.png", **kwargs)


def test_render_grid_rejects_no_meshes(tmp_path):
    with pytest.raises(ValueError, match="empty"):
        render.render_grid([], tmp_path / "none.png")
    with pytest.raises(TypeError, match="sequence"):
        render.render_grid(sphere(), tmp_path / "one.png")
