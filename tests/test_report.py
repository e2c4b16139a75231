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
