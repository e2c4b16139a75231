"""Fitting a model to a partial scan: known shapes seen from one side, in any pose, with a table under them."""

import json

import numpy as np
import pytest
import trimesh

from hortishape.align import rotation_about
from hortishape.cli import main
from hortishape.errors import HortishapeError
from hortishape.mesh import Mesh
from hortishape.model import ShapeModel
from hortishape.partial import fit_partial
from hortishape.surface import closest_points, signed_volume
from hortishape.synth import depth_view


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=4, radius=1.0)


@pytest.fixture(scope="module")
def egg_model(sphere):
    """Twelve eggs: ellipsoids with a varying width, depth and height and a varying taper along z."""
    rng = np.random.default_rng(1)
    shapes = []
    for _ in range(12):
        radii = rng.normal([40.0, 38.0, 45.0], [2.0, 2.0, 3.0])
        taper = rng.normal(0.0, 0.08)
        v = sphere.vertices * radii
        v[:, :2] *= (1.0 + taper * v[:, 2:] / 45.0)
        shapes.append(v)
    return ShapeModel().fit(np.array(shapes), sphere.faces)


def _egg(sphere, radii, taper):
    v = sphere.vertices * radii
    v[:, :2] *= (1.0 + taper * v[:, 2:] / 45.0)
    return Mesh(v, sphere.faces)


def test_one_side_of_an_egg_in_any_pose_gives_the_whole_egg_and_its_volume(sphere, egg_model):
    truth = _egg(sphere, [41.0, 37.0, 47.0], 0.06)
    pose = rotation_about([1.0, 2.0, 0.5], 2.0)
    moved = Mesh(truth.vertices @ pose.T + [30.0, -20.0, 200.0], truth.faces)
    view = depth_view(moved, [0.3, -1.0, 0.2], noise=0.2, random_state=0)
    fit = fit_partial(egg_model, view.points, normals=view.normals)
    # about half of the surface was seen; the whole surface is recovered, the hidden half too
    assert 0.35 < fit.observed_fraction < 0.6
    both_ways = (closest_points(moved, fit.vertices).distances.mean()
                 + closest_points(Mesh(fit.vertices, fit.faces), moved.vertices).distances.mean()) / 2
    assert both_ways < 0.5
    volume = signed_volume(truth.vertices, truth.faces) / 1000.0
    assert abs(fit.volume_ml - volume) < 0.03 * volume
    assert abs(fit.volume_ml - volume) < 2.0 * fit.volume_sd_ml
    assert fit.sd.shape == (len(sphere.vertices),) and np.all(fit.sd >= 0)
    # the pose takes the model's frame to the points'
    np.testing.assert_allclose(fit.pose[:3, :3] @ fit.pose[:3, :3].T, np.eye(3), atol=1e-9)
    figures = fit.as_dict()
    assert figures["volume_ml"] == fit.volume_ml and len(figures["pose"]) == 4


def test_a_table_and_stray_points_are_left_out(sphere, egg_model):
    truth = _egg(sphere, [39.0, 39.0, 44.0], -0.05)
    view = depth_view(truth, [0.0, 0.6, -1.0], noise=0.2, random_state=1)
    rng = np.random.default_rng(2)
    bottom = truth.vertices[:, 2].min()
    table = np.column_stack([rng.uniform(-80, 80, (2000, 2)), np.full(2000, bottom)])
    table = table[np.hypot(table[:, 0], table[:, 1]) > 42.0]  # where the fruit does not hide it
    stray = rng.uniform(-120, 120, (60, 3))
    points = np.concatenate([view.points, table, stray])
    fit = fit_partial(egg_model, points)
    both_ways = (closest_points(truth, fit.vertices).distances.mean()
                 + closest_points(Mesh(fit.vertices, fit.faces), truth.vertices).distances.mean()) / 2
    assert both_ways < 0.8
    volume = signed_volume(truth.vertices, truth.faces) / 1000.0
    assert abs(fit.volume_ml - volume) < 0.04 * volume


def test_clouds_that_cannot_be_fitted_say_why(sphere, egg_model):
    with pytest.raises(HortishapeError, match="too few"):
        fit_partial(egg_model, np.zeros((10, 3)))
    flat = np.column_stack([np.random.default_rng(0).uniform(-40, 40, (500, 2)), np.zeros(500)])
    with pytest.raises(HortishapeError, match="too flat"):
        fit_partial(egg_model, flat)
    metres = depth_view(_egg(sphere, [40.0, 38.0, 45.0], 0.0), [0, 0, -1], noise=0.0).points / 1000.0
    with pytest.raises(HortishapeError, match="in metres"):
        fit_partial(egg_model, metres)
    with pytest.raises(HortishapeError, match="NaN"):
        fit_partial(egg_model, np.full((100, 3), np.nan))
    with pytest.raises(HortishapeError, match="modes"):
        fit_partial(egg_model, metres * 1000.0, modes=99)


def test_cli_fit_partial_writes_the_surface_its_sd_figures_and_picture(sphere, egg_model, tmp_path, capsys):
    from hortishape.io import read_mesh_data, write_points

    model_path = egg_model.save(tmp_path / "eggs.h5")
    truth = _egg(sphere, [41.0, 39.0, 44.0], 0.03)
    view = depth_view(truth, [1.0, 0.0, -0.3], noise=0.2, random_state=3)
    scan = write_points(tmp_path / "egg.ply", view.points, normals=view.normals)
    assert main(["fit", str(model_path), str(scan), "--partial", "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    assert "volume" in printed and "mL" in printed
    out = tmp_path / "out"
    data = read_mesh_data(out / "egg.ply")
    assert data.mesh.n_vertices == len(sphere.vertices) and "sd_mm" in data.vertex_scalars
    figures = json.loads((out / "egg.json").read_text())
    for key in ("volume_ml", "volume_sd_ml", "pose", "coefficients_sd", "residual_mm", "observed_fraction"):
        assert key in figures
    assert np.load(out / "egg.sd.npy").shape == (len(sphere.vertices),)
    assert (out / "egg.png").stat().st_size > 10_000
    # a cloud in metres is one line naming the file
    write_points(tmp_path / "metres.ply", view.points / 1000.0)
    assert main(["fit", str(model_path), str(tmp_path / "metres.ply"), "--partial"]) != 0
    err = capsys.readouterr().err
    assert "metres.ply" in err and "in metres" in err and "Traceback" not in err
