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
from hortishape.partial import MISFIT_REACH, fit_partial
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
    # an egg like the model's: explained down to the points' own noise, nothing to warn about
    assert 0.1 < fit.point_noise_mm < 0.2 and fit.warnings == () and figures["warnings"] == []
    assert fit.misfit_mm == 0.0 and figures["misfit_mm"] == 0.0


def test_a_fruit_the_model_cannot_represent_is_warned_about(sphere, egg_model):
    from hortishape.errors import FitWarning

    # eight ribs 2 mm high: no egg of the model has them
    v = sphere.vertices * [40.0, 38.0, 45.0]
    v[:, :2] *= (1.0 + 0.05 * np.cos(8.0 * np.arctan2(v[:, 1], v[:, 0])))[:, None]
    ribbed = Mesh(v, sphere.faces)
    view = depth_view(ribbed, [0.3, -1.0, 0.2], noise=0.2, random_state=0)
    with pytest.warns(FitWarning, match="far worse than their own noise"):
        fit = fit_partial(egg_model, view.points, normals=view.normals)
    assert fit.noise_mm > 2.0 * fit.point_noise_mm and len(fit.warnings) == 1
    # what the model misses where it saw the ribs, it may miss where it saw nothing: the unseen
    # vertices' SD and the volume's carry MISFIT_REACH times it
    assert fit.misfit_mm > 0.5
    reach = MISFIT_REACH * fit.misfit_mm
    assert np.mean(fit.sd >= reach) > 1.0 - fit.observed_fraction - 0.1
    unseen_area = (1.0 - fit.observed_fraction) * Mesh(fit.vertices, fit.faces).to_trimesh().area
    assert fit.volume_sd_ml * 1000.0 > 0.95 * reach * unseen_area
    truth = signed_volume(ribbed.vertices, ribbed.faces) / 1000.0
    assert abs(fit.volume_ml - truth) < 2.0 * fit.volume_sd_ml


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


def test_the_jackknife_in_the_gram_matrix_is_that_of_the_models_built_without_each_shape(sphere, egg_model):
    from hortishape.partial import _as_seen, _jackknife, _training_shapes, _volume_gradient
    from hortishape.surface import vertex_normals

    shapes = _training_shapes(egg_model) + egg_model.mean_
    faces = egg_model.faces_
    # a cap of another egg, seen along its vertices' normals at the mean's vertices, in the model's frame
    mean_normals = vertex_normals(egg_model.mean_, faces)
    vertices = np.flatnonzero(egg_model.mean_[:, 2] > 10.0)
    rng = np.random.default_rng(2)
    points = _egg(sphere, [41.0, 37.0, 47.0], 0.06).vertices[vertices] + rng.normal(0.0, 0.2, (len(vertices), 3))
    normals = mean_normals[vertices]
    weights = rng.uniform(0.5, 1.0, len(vertices))
    distances = np.einsum("kd,kd->k", normals, points - egg_model.mean_[vertices])
    gradient = _volume_gradient(egg_model.mean_, faces)
    centred = _training_shapes(egg_model)
    gram = centred.reshape(len(centred), -1) @ centred.reshape(len(centred), -1).T
    seen, vol, along = _as_seen(centred, vertices, normals, gradient, mean_normals)
    volume_sd, sd = _jackknife(gram, egg_model.n_components_, seen, vol, along, normals, weights, 0.3, points,
                               distances)
    # each model of eleven eggs, built and conditioned on the points (pose free) in the vertices' space
    completions = []
    for i in range(len(shapes)):
        other = ShapeModel().fit(np.delete(shapes, i, axis=0), faces)
        basis = (other.components_ * np.sqrt(other.explained_variance_)[:, None]).reshape(-1, len(sphere.vertices), 3)
        design = np.concatenate([np.einsum("kd,jkd->kj", normals, basis[:, vertices]),
                                 -np.cross(points, normals), -normals], axis=1)
        r = np.einsum("kd,kd->k", normals, points - other.mean_[vertices])
        h = design.T @ (design * weights[:, None]) / 0.3**2 + np.diag([1.0] * len(basis) + [1e-9] * 6)
        c = np.linalg.solve(h, design.T @ (weights * r) / 0.3**2)[: len(basis)]
        completions.append(other.mean_ + np.einsum("j,jnd->nd", c, basis))
    completions = np.array(completions)
    spread = completions - completions.mean(axis=0)
    factor = (len(shapes) - 1) / len(shapes)
    assert volume_sd > 0
    np.testing.assert_allclose(volume_sd, np.sqrt(factor * np.sum(np.einsum("nd,and->a", gradient, spread) ** 2)),
                               rtol=1e-6)
    np.testing.assert_allclose(sd, np.sqrt(factor * np.sum(np.einsum("and,nd->an", spread, mean_normals) ** 2, axis=0)),
                               rtol=1e-6, atol=1e-9)


def test_the_axis_of_revolution_of_one_side_of_a_fruit_is_found_from_its_points_alone(sphere):
    from hortishape.partial import _revolution_axis

    # an egg with a dimple at one end: a body of revolution about z, seen from one side in a known pose
    v = sphere.vertices * [40.0, 40.0, 47.0]
    v[:, 2] -= 8.0 * np.exp(-(v[:, 0] ** 2 + v[:, 1] ** 2) / 150.0) * (v[:, 2] > 0)
    pose = rotation_about([1.0, 2.0, 0.5], 2.0)
    egg = Mesh(v @ pose.T + [30.0, -20.0, 200.0], sphere.faces)
    view = depth_view(egg, [0.3, -1.0, 0.2], noise=0.2, random_state=0)
    direction, point = _revolution_axis(view.points, np.random.default_rng(0))
    axis = pose @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(abs(direction @ axis))) < 3.0
    # the point lies on the axis, which passes through the egg's centre
    off = point - np.array([30.0, -20.0, 200.0])
    assert np.linalg.norm(off - (off @ axis) * axis) < 1.5
    # a sphere's normals meet at its centre: every line through it is an axis, so none is told
    ball = Mesh(sphere.vertices * 40.0, sphere.faces)
    assert _revolution_axis(depth_view(ball, [0.0, 0.0, -1.0], noise=0.2, random_state=0).points,
                            np.random.default_rng(0)) is None
