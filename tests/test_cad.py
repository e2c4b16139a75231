"""Tests of hortishape.cad: poles, cylindrical parameterization, B-spline fitting, model instances, CAD files."""

import json

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from hortishape import cad, synth
from hortishape.cli import main
from hortishape.errors import HortishapeError, MeshError, NotFittedError
from hortishape.model import ShapeModel
from hortishape.surface import signed_volume


@pytest.fixture(scope="module")
def apple():
    """A synthetic apple (CT-like marching-cubes surface) in a random scanner pose, with its landmarks."""
    return synth.make_instance("apple", random_state=7, n_vertices=8000, pose="random")


@pytest.fixture(scope="module")
def apple_map(apple):
    return cad.parameterize(apple.mesh.vertices, apple.mesh.faces)


@pytest.fixture(scope="module")
def model():
    """Five synthetic apples in ground-truth correspondence."""
    pop = synth.make_population("apple", 5, random_state=4, n_vertices=5000, pose="upright")
    shapes = np.array([synth.true_correspondence(pop[0].canonical, p) for p in pop])
    return ShapeModel(procrustes=True).fit(shapes, pop[0].mesh.faces)


@pytest.fixture(scope="module")
def cad_model(model):
    return cad.BSplineModel(8).fit(model)


def _egg(k=8, seed=0):
    """An egg-like closed B-spline surface with a bumpy control net."""
    angle = 2 * np.pi * np.arange(k) / k
    ring = np.column_stack([np.cos(angle), np.sin(angle), np.zeros(k)])
    radius = np.interp(np.linspace(0, 1, k), [0, 0.15, 0.5, 0.85, 1], [0, 30, 42, 30, 0])
    height = np.interp(np.linspace(0, 1, k), [0, 0.15, 0.5, 0.85, 1], [-40, -36, 0, 38, 42])
    cp = np.stack([ring * r + [0, 0, z] for r, z in zip(radius, height)], axis=1)
    cp[:, 1:-1] += np.random.default_rng(seed).normal(0.0, 2.0, cp[:, 1:-1].shape)
    return cad.BSplineSurface(cp)


# --------------------------------------------------------------------------
# poles
# --------------------------------------------------------------------------


def test_poles_are_found_at_the_stalk_tip_and_the_calyx(apple):
    v = apple.mesh.vertices
    poles = cad.find_poles(v, apple.mesh.faces)
    assert np.linalg.norm(v[poles.stalk] - apple.landmarks["stalk_tip"]) < 2.5
    assert np.linalg.norm(v[poles.bottom] - apple.landmarks["bottom"]) < 4.0
    assert np.isclose(np.linalg.norm(poles.axis), 1.0)


def test_poles_from_landmarks_and_from_an_axis():
    capsule = trimesh.creation.capsule(height=60.0, radius=20.0, count=[32, 32])
    v, f = capsule.vertices, capsule.faces
    poles = cad.find_poles(v, f, stalk=[0.3, 0.1, 49.0], bottom=[0.0, 0.0, -60.0])
    assert np.allclose(v[poles.stalk], [0, 0, 50]) and np.allclose(v[poles.bottom], [0, 0, -50])
    flipped = cad.find_poles(v, f, axis=(0, 0, -1))
    assert np.isclose(v[flipped.stalk][2], -50.0) and np.isclose(v[flipped.bottom][2], 50.0)
    one = cad.find_poles(v, f, stalk=[0.0, 0.0, 50.0])  # the other pole: the far end
    assert np.isclose(v[one.bottom][2], -50.0)


# --------------------------------------------------------------------------
# parameterization
# --------------------------------------------------------------------------


def test_parameterization_has_no_flipped_triangles_and_covers_the_cylinder_once(apple, apple_map):
    m = apple_map
    assert m.n_flipped == 0
    assert (m.signed_areas() > 0).all()
    assert m.covered_area == pytest.approx(1.0, abs=1e-9)
    # every point of the strip between the rims lies in exactly one disc triangle (u taken modulo 1)
    rng = np.random.default_rng(0)
    v_lo, v_hi = m.uv[m.bottom_ring, 1].max(), m.uv[m.stalk_ring, 1].min()
    q = np.column_stack([rng.uniform(0, 1, 200), rng.uniform(v_lo + 1e-6, v_hi - 1e-6, 200)])
    p = m.disc_uv[m.disc_faces]  # (m, 3, 2)
    hits = np.zeros(len(q), dtype=int)
    for shift in (-1.0, 0.0, 1.0):
        x = q[:, None, :] + [shift, 0.0]
        d = [(p[None, :, (c + 1) % 3] - p[None, :, c]) for c in range(3)]
        r = [(x - p[None, :, c]) for c in range(3)]
        cross = np.stack([d[c][..., 0] * r[c][..., 1] - d[c][..., 1] * r[c][..., 0] for c in range(3)])
        hits += (cross >= 0).all(axis=0).sum(axis=1)
    assert (hits == 1).all()
    # the map and its unrolled disc agree; u in [0, 1), v in [0, 1], poles on the end rows
    n = apple.mesh.n_vertices
    assert m.uv.shape == (n, 2) and (m.uv[:, 0] >= 0).all() and (m.uv[:, 0] < 1).all()
    assert m.uv[m.bottom].tolist() == [0.0, 0.0] and m.uv[m.stalk].tolist() == [0.0, 1.0]
    assert np.allclose(m.disc_uv[:, 1], m.uv[m.disc_vertices, 1])
    jump = m.disc_uv[:, 0] - m.uv[m.disc_vertices, 0]
    assert np.allclose(jump, np.round(jump))
    assert set(np.unique(m.disc_vertices)) == set(range(n)) - {m.stalk, m.bottom}
    counts = np.bincount(m.disc_vertices, minlength=n)
    assert (counts[m.seam] == 2).all() and counts.sum() == n - 2 + len(m.seam)
    assert m.seam[0] in m.bottom_ring and m.seam[-1] in m.stalk_ring
    # v grows from the bottom to the stalk
    v = apple.mesh.vertices
    assert np.corrcoef(m.uv[:, 1], v @ apple.pose[:3, 2])[0, 1] > 0.9
    assert np.median(m.distortion(v)) < 1.5


def test_harmonic_spacing_is_bijective_too(apple):
    m = cad.parameterize(apple.mesh.vertices, apple.mesh.faces, spacing="harmonic")
    assert m.n_flipped == 0 and m.covered_area == pytest.approx(1.0, abs=1e-9)


def test_grid_map_is_the_tessellation_parameterization():
    s = _egg()
    mesh = s.tessellate(24, 12)
    gm = cad.grid_map(24, 12)
    assert gm.n_flipped == 0 and gm.covered_area == pytest.approx(1.0)
    assert np.allclose(mesh.vertices, s.evaluate(gm.uv[:, 0], gm.uv[:, 1]))
    assert signed_volume(mesh.vertices, mesh.faces) > 0  # egg control net: u x v points outward


# --------------------------------------------------------------------------
# B-spline fitting
# --------------------------------------------------------------------------


def test_fitting_a_bspline_of_the_same_grid_reproduces_it():
    s = _egg(k=8)
    # the 8 x 8 fit samples (u, v) at 64 x 64 cell centres; a 128 x 128 tessellation holds them exactly
    mesh = s.tessellate(128, 128)
    fitter = cad.BSplineFitter(8).fit(mesh.vertices, mesh.faces, parameterization=cad.grid_map(128, 128))
    np.testing.assert_allclose(fitter.control_points(mesh.vertices), s.control_points, atol=1e-9)
    assert fitter.residual_ < 1e-9
    # any other tessellation: reproduced up to its chord error, which falls as h^2
    errors = []
    for n in (100, 200):
        mesh = s.tessellate(n, n)
        fitter = cad.BSplineFitter(8).fit(mesh.vertices, mesh.faces, parameterization=cad.grid_map(n, n))
        errors.append(np.abs(fitter.control_points(mesh.vertices) - s.control_points).max())
    assert errors[0] < 0.1 and errors[1] < errors[0] / 3


def test_fit_is_linear_and_moves_with_the_shape(apple, apple_map):
    v, f = apple.mesh.vertices, apple.mesh.faces
    fitter = cad.BSplineFitter(8).fit(v, f, parameterization=apple_map)
    p = fitter.control_points(v)
    rot = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix()
    moved = fitter.control_points(1.2 * v @ rot.T + [5.0, -3.0, 2.0])
    np.testing.assert_allclose(moved, 1.2 * p @ rot.T + [5.0, -3.0, 2.0], atol=1e-9)
    both = fitter.control_points(np.stack([v, 2 * v]))
    np.testing.assert_allclose(both[1], 2 * both[0], atol=1e-9)
    assert fitter.surface(v).is_closed
    assert np.allclose(p[:, 0], p[0, 0]) and np.allclose(p[:, -1], p[0, -1])


def test_finer_grids_approximate_better(model):
    cmap = cad.parameterize(model.mean_, model.faces_)
    devs = [cad.surface_deviation(cad.BSplineFitter(k).fit(model.mean_, model.faces_, parameterization=cmap)
                                  .surface(model.mean_), model.mean_, model.faces_) for k in (4, 8, 16)]
    means = [d.mean for d in devs]
    assert means[0] > means[1] > means[2] and means[2] < 0.15
    # a 4 x 4 surface is coarse but the right size
    vol4 = cad.BSplineFitter(4).fit(model.mean_, model.faces_, parameterization=cmap).surface(model.mean_).volume()
    assert vol4 == pytest.approx(abs(signed_volume(model.mean_, model.faces_)), rel=0.05)


def test_sphere_approximation_is_close():
    s = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
    surface = cad.BSplineFitter(16).fit(s.vertices, s.faces).surface(s.vertices)
    d = cad.surface_deviation(surface, s.vertices, s.faces)
    assert d.max < 0.1 and d.back_max < 0.1
    assert surface.volume() == pytest.approx(abs(signed_volume(s.vertices, s.faces)), rel=1e-3)


# --------------------------------------------------------------------------
# model instances
# --------------------------------------------------------------------------


def test_instances_come_from_the_operator_without_refitting(model, cad_model):
    c = np.array([1.5, -2.0, 0.5])
    direct = cad_model.fitter_.control_points(model.instance(c))
    np.testing.assert_allclose(cad_model.instance(c).control_points, direct, atol=1e-9)
    np.testing.assert_allclose(cad_model.mean_.control_points, cad_model.fitter_.control_points(model.mean_),
                               atol=1e-12)
    minus, plus = cad_model.mode_shapes(0, sd=3.0)
    m_minus, m_plus = model.mode_shapes(0, sd=3.0)
    np.testing.assert_allclose(plus.control_points, cad_model.fitter_.control_points(m_plus), atol=1e-9)
    np.testing.assert_allclose(minus.control_points, cad_model.fitter_.control_points(m_minus), atol=1e-9)
    a, b = cad_model.sample(random_state=3), cad_model.sample(random_state=3)
    assert np.array_equal(a.control_points, b.control_points)
    np.testing.assert_allclose(
        a.control_points,
        cad_model.instance(model.sample_coefficients(1, random_state=3)[0]).control_points, atol=1e-12)


# --------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------


def test_json_round_trip(tmp_path):
    s = _egg()
    path = cad.write_cad(tmp_path / "egg.json", s)
    assert np.array_equal(cad.read_cad(path).control_points, s.control_points)
    data = json.loads(path.read_text())
    assert data["units"] == "mm" and data["periodic"] == [True, False] and data["degree"] == [3, 3]
    assert len(data["knots_u"]) == 9 and data["multiplicities_v"] == [4, 1, 1, 1, 1, 4]


def test_step_and_iges_read_back_with_the_same_control_points(tmp_path, cad_model, capfd):
    pytest.importorskip("OCP")
    s = cad_model.instance([2.0, -1.0])
    for name in ("apple.step", "apple.stp", "apple.iges", "apple.igs"):
        path = cad.write_cad(tmp_path / name, s)
        back = cad.read_cad(path)
        assert back.grid == s.grid
        np.testing.assert_allclose(back.control_points, s.control_points, atol=1e-8)
    assert "Statistics" not in capfd.readouterr().out  # OpenCascade's chatter is silenced
    assert list(tmp_path.glob(".*")) == []  # no temporary files left


def test_step_encloses_the_mesh_volume(tmp_path, model):
    pytest.importorskip("OCP")
    surface = cad.BSplineModel(16).fit(model).mean_
    path = cad.write_cad(tmp_path / "mean.step", surface)
    mesh_volume = abs(signed_volume(model.mean_, model.faces_))
    assert cad.cad_volume(path) == pytest.approx(mesh_volume, rel=0.01)
    assert cad.cad_volume(path) == pytest.approx(surface.volume(), rel=1e-3)
    assert cad.cad_volume(cad.write_cad(tmp_path / "mean.iges", surface)) == pytest.approx(cad.cad_volume(path))


# --------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------


def test_open_or_multi_component_meshes_are_refused():
    s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    with pytest.raises(MeshError, match="not closed"):
        cad.parameterize(s.vertices, s.faces[1:])
    with pytest.raises(MeshError, match="not closed"):
        cad.find_poles(s.vertices, s.faces[1:])
    two = np.vstack([s.vertices, s.vertices + 100.0]), np.vstack([s.faces, s.faces + len(s.vertices)])
    with pytest.raises(MeshError, match="2 connected components"):
        cad.parameterize(*two)
    torus = trimesh.creation.torus(major_radius=30.0, minor_radius=10.0)
    with pytest.raises(MeshError, match="not a cylinder"):
        cad.parameterize(torus.vertices, torus.faces, poles=cad.Poles(0, 500, np.array([0.0, 0.0, 1.0])))


def test_poles_that_coincide_or_touch_are_refused():
    s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    top = s.vertices[np.argmax(s.vertices[:, 2])]
    with pytest.raises(MeshError, match="coincide"):
        cad.find_poles(s.vertices, s.faces, stalk=top, bottom=top + 0.01)
    neighbour = s.vertices[s.faces[(s.faces == np.argmax(s.vertices[:, 2])).any(axis=1)][0]]
    near = [p for p in neighbour if not np.array_equal(p, top)][0]
    with pytest.raises(MeshError, match="neighbours"):
        cad.find_poles(s.vertices, s.faces, stalk=top, bottom=near)
    with pytest.raises(ValueError, match="stalk"):
        cad.find_poles(s.vertices, s.faces, stalk=[1.0, 2.0])


def test_bad_options_and_files(tmp_path, cad_model, monkeypatch):
    s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    with pytest.raises(ValueError, match="grid"):
        cad.BSplineFitter(3).fit(s.vertices, s.faces)
    with pytest.raises(NotFittedError):
        cad.BSplineFitter(8).control_points(s.vertices)
    with pytest.raises(NotFittedError):
        cad.BSplineModel(8).instance([1.0])
    with pytest.raises(MeshError, match="correspondence"):
        cad_model.fitter_.control_points(s.vertices)
    with pytest.raises(ValueError, match="spacing"):
        cad.parameterize(s.vertices, s.faces, spacing="conformal")
    with pytest.raises(ValueError, match="coefficients"):
        cad_model.instance(np.ones(10))
    with pytest.raises(HortishapeError, match="extension"):
        cad.write_cad(tmp_path / "apple.stl", cad_model.mean_)
    with pytest.raises(HortishapeError, match="no such file"):
        cad.read_cad(tmp_path / "missing.step")
    (tmp_path / "other.json").write_text('{"format": "something else"}')
    with pytest.raises(HortishapeError, match="other.json"):
        cad.read_cad(tmp_path / "other.json")
    with pytest.raises(ValueError, match="shape"):
        cad.BSplineSurface(np.zeros((3, 8, 3)))
    modules = __import__("sys").modules
    for name in ["OCP", *(m for m in list(modules) if m.startswith("OCP."))]:
        monkeypatch.setitem(modules, name, None)  # as if OpenCascade were not installed
    with pytest.raises(HortishapeError, match=r"hortishape\[cad\]"):
        cad.write_cad(tmp_path / "apple.step", cad_model.mean_)
    assert not (tmp_path / "apple.step").exists()


# --------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------


def test_cli_exports_the_mean_and_a_mode(tmp_path, model, capsys):
    path = model.save(tmp_path / "model.h5")
    out = tmp_path / "mode1.json"
    assert main(["cad", str(path), "--grid", "8", "--mode", "1", "--sd", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "0 flipped triangles" in printed and "mode 1 +2 SD" in printed and f"wrote {out}" in printed
    expected = cad.BSplineModel(8).fit(ShapeModel.load(path)).mode_shapes(0, sd=2.0)[1]
    np.testing.assert_allclose(cad.read_cad(out).control_points, expected.control_points, atol=1e-9)
    assert main(["cad", str(path), "--grid", "8", "--mode", "1", "--coefficients", "1", "2",
                 "--out", str(out)]) == 1
    assert "only one of" in capsys.readouterr().err
    assert main(["cad", str(path), "--out", str(tmp_path / "x.obj")]) == 1
    assert ".step" in capsys.readouterr().err


def test_demo_writes_the_mean_and_a_mode_as_cad_files(tmp_path, model):
    from hortishape.demo import write_cad_examples

    files = write_cad_examples(model, tmp_path, grid=8)
    names = sorted(p.name for p in files)
    assert names == ["mean.json", "mean.step", "mode1_plus3sd.json", "mode1_plus3sd.step"]
    mean = cad.read_cad(tmp_path / "mean.step")
    np.testing.assert_allclose(mean.control_points, cad.read_cad(tmp_path / "mean.json").control_points, atol=1e-9)
    # the mode's surface differs from the mean's, by the model's first mode at +3 SD
    mode = cad.read_cad(tmp_path / "mode1_plus3sd.json")
    assert np.abs(mode.control_points - mean.control_points).max() > 0.5
