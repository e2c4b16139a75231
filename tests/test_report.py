"""Tests of hortishape.report: the mode picture (paper Fig. 7) and the mode meshes."""

import numpy as np
import pytest
import trimesh

from hortishape.errors import MeshError, NotFittedError
from hortishape.io import read_mesh
from hortishape.model import ShapeModel
from hortishape.report import render_modes, write_mode_meshes

Image = pytest.importorskip("PIL.Image")


@pytest.fixture(scope="module")
def model():
    """Upright ellipsoidal 'fruit' whose size (mode 1) and elongation vary."""
    s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    rng = np.random.default_rng(0)
    size = rng.normal(40.0, 4.0, size=12)
    elong = rng.normal(1.0, 0.08, size=12)
    shapes = [s.vertices * [r, r, r * e] for r, e in zip(size, elong, strict=True)]
    return ShapeModel().fit(shapes, s.faces)


def test_render_modes_draws_the_grid(model, tmp_path):
    cell = (160, 160)
    out = render_modes(model, tmp_path / "modes.png", n_modes=2, cell_size=cell, backend="matplotlib")
    assert out == tmp_path / "modes.png"
    with Image.open(out) as im:
        image = np.asarray(im.convert("RGB")).astype(int)
    # two views x three columns; two rows plus the header naming the views
    assert image.shape[1] >= 6 * cell[0] and image.shape[0] >= 2 * cell[1]
    assert image.shape[0] < 3 * cell[1]
    # mode 1 is size: the -3 SD cell holds fewer surface pixels than the +3 SD cell (same scale)
    ink = np.abs(image - 255).sum(axis=2) > 30
    header = image.shape[0] - 2 * cell[1]
    gutter = image.shape[1] - 6 * cell[0]
    row = ink[header + 30: header + cell[1]]
    minus = row[:, gutter: gutter + cell[0]].sum()
    plus = row[:, gutter + 2 * cell[0]: gutter + 3 * cell[0]].sum()
    assert plus > 1.2 * minus > 0


def test_write_mode_meshes(model, tmp_path):
    files = write_mode_meshes(model, tmp_path / "modes", n_modes=2, sd=2.5)
    assert [f.name for f in files] == [
        "mean.ply", "mode1_minus2.5sd.ply", "mode1_plus2.5sd.ply", "mode2_minus2.5sd.ply", "mode2_plus2.5sd.ply",
    ]
    minus, plus = model.mode_shapes(1, sd=2.5)
    np.testing.assert_allclose(read_mesh(files[3]).vertices, minus, atol=1e-9)
    np.testing.assert_allclose(read_mesh(files[4]).vertices, plus, atol=1e-9)
    np.testing.assert_array_equal(read_mesh(files[0]).faces, model.faces_)
    assert [f.name for f in write_mode_meshes(model, tmp_path / "b", n_modes=1)][1] == "mode1_minus3sd.ply"


def test_bad_input(model, tmp_path):
    with pytest.raises(ValueError, match="n_modes"):
        render_modes(model, tmp_path / "x.png", n_modes=model.n_components_ + 1)
    with pytest.raises(ValueError, match="sd"):
        write_mode_meshes(model, tmp_path, n_modes=1, sd=-1.0)
    with pytest.raises(NotFittedError):
        write_mode_meshes(ShapeModel(), tmp_path)
    points = ShapeModel().fit(np.random.default_rng(1).normal(size=(4, 10, 3)))
    with pytest.raises(MeshError, match="no faces"):
        write_mode_meshes(points, tmp_path, n_modes=1)


# --------------------------------------------------------------------------
# plots of the quality measures and the error map
# --------------------------------------------------------------------------


def _image(path):
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")).astype(int)


def test_measure_plots(model, tmp_path):
    from hortishape.metrics import compactness, generalization, specificity
    from hortishape.report import plot_compactness, plot_generalization, plot_specificity

    shapes = np.stack([model.instance(c) for c in np.random.default_rng(2).normal(size=(8, model.n_components_))])
    c = plot_compactness(compactness(model), tmp_path / "c.png")
    g = plot_generalization(generalization(shapes, modes=4), tmp_path / "g.png")
    s = plot_specificity(specificity(model, shapes, n_samples=10, random_state=0), tmp_path / "s.png")
    for path, min_width in ((c, 600), (g, 1000), (s, 1000)):
        image = _image(path)
        assert image.shape[1] >= min_width and image.shape[0] >= 400
        assert (np.abs(image - 255).sum(axis=2) > 30).mean() > 0.02  # something is drawn
    with pytest.raises(ValueError, match=".png"):
        plot_compactness(compactness(model), tmp_path / "c.jpg")


def test_error_map_picture_and_colours(model, tmp_path):
    from hortishape.report import error_colours, render_error_map

    mean = model.to_mesh(model.mean_)
    values = np.abs(model.mean_[:, 2]) / 40.0  # large at the poles
    out = render_error_map(mean, values, tmp_path / "e.png", n_instances=12, backend="matplotlib")
    image = _image(out)
    assert image.shape[1] >= 4 * 300 and image.shape[0] >= 300  # four views and a colour bar
    colours = error_colours(values)
    assert colours.shape == (len(values), 3) and colours.dtype == np.uint8
    # viridis: small errors dark purple, large ones yellow
    assert colours[np.argmin(values)].tolist() == [68, 1, 84]
    assert colours[np.argmax(values), 0] > 200 and colours[np.argmax(values), 1] > 200


def test_landmark_plot(tmp_path):
    from hortishape.metrics import transfer_landmarks
    from hortishape.report import plot_landmark_errors

    s = trimesh.creation.icosphere(subdivisions=2, radius=40.0)
    rng = np.random.default_rng(3)
    shapes = [s.vertices * rng.normal(1.0, 0.05, 3) for _ in range(6)]
    given = [[v[0] + rng.normal(0, 0.5, 3), v[5] + rng.normal(0, 0.5, 3)] for v in shapes]
    t = transfer_landmarks(shapes, s.faces, given, names=["stalk_tip", "bottom"])
    out = plot_landmark_errors(t, [f"apple_{i}" for i in range(6)], tmp_path / "lm.png")
    assert _image(out).shape[1] >= 480
