"""CT and MRI volumes to surfaces: analytic shapes, geometry, cavities, open shells, supports, slabs,
warnings, bad volumes, files."""

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy.special import erf

from hortishape import extract, synth
from hortishape.cli import build_parser, main
from hortishape.errors import ExtractionWarning, VolumeError
from hortishape.extract import (
    decimate,
    extract_file,
    extract_files,
    extract_surface,
    intensity_levels,
    render_extraction,
    taubin_smooth,
    volume_stem,
)
from hortishape.io import Volume, read_mesh, read_volume, write_mesh, write_volume
from hortishape.mesh import Mesh
from hortishape.surface import check_closed_surface, closest_points, face_areas, signed_volume


def ct(distance, *, sigma=0.7, noise=0.0, seed=0, dtype=np.float32):
    """A CT-like volume of a signed distance (voxels, negative inside): 1000 inside, 0 outside,
    an error-function partial-volume edge, Gaussian noise."""
    values = 1000.0 * 0.5 * (1.0 - erf(distance / (sigma * np.sqrt(2.0))))
    if noise:
        values = values + np.random.default_rng(seed).normal(0.0, noise, distance.shape)
    return values.astype(dtype)


def grid(n):
    return np.mgrid[:n, :n, :n].astype(np.float64)


def sphere_distance(n, centre, radius):
    x, y, z = grid(n)
    return np.sqrt((x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2) - radius


def area(mesh):
    return face_areas(mesh.vertices, mesh.faces).sum()


# --------------------------------------------------------------------------
# analytic shapes
# --------------------------------------------------------------------------


def test_sphere_area_and_volume_within_one_percent():
    c, r = np.array([24.3, 23.8, 24.1]), 16.0
    vol = Volume(ct(sphere_distance(50, c, r)), spacing=0.5)
    ext = extract_surface(vol)
    radius_mm = r * 0.5
    assert ext.volume == pytest.approx(4 / 3 * np.pi * radius_mm**3, rel=0.01)
    assert area(ext.mesh) == pytest.approx(4 * np.pi * radius_mm**2, rel=0.01)
    # sub-voxel: every vertex within a tenth of a voxel of the sphere
    radial = np.linalg.norm(ext.mesh.vertices - c * 0.5, axis=1) - radius_mm
    assert np.abs(radial).max() < 0.1 * 0.5
    assert check_closed_surface(ext.mesh) == 1.0  # one closed component, outward normals
    assert ext.levels.level == pytest.approx(500.0, abs=5.0)
    assert ext.levels.background == pytest.approx(0.0, abs=5.0)
    assert ext.levels.foreground == pytest.approx(1000.0, abs=5.0)
    # float64 voxels, and voxels exactly at a given level: the same closed surface
    data64 = np.round(vol.data.astype(np.float64), -1)
    ext64 = extract_surface(Volume(data64, spacing=0.5), level=500.0)
    check_closed_surface(ext64.mesh, allow_degenerate=True)
    assert ext64.volume == pytest.approx(ext.volume, rel=0.003)


def test_noisy_int16_sphere_is_accurate_and_smoothing_does_not_shrink_it():
    c, r = np.array([31.7, 31.7, 31.7]), 20.3
    data = np.clip(ct(sphere_distance(64, c, r), noise=25.0), -1000, 3000).astype(np.int16)
    raw = extract_surface(data, smoothing=0)
    smooth = extract_surface(data, smoothing=10)
    exact = 4 / 3 * np.pi * r**3
    for ext in (raw, smooth):
        assert ext.volume == pytest.approx(exact, rel=0.004)
    err_raw = np.abs(np.linalg.norm(raw.mesh.vertices - c, axis=1) - r)
    err_smooth = np.abs(np.linalg.norm(smooth.mesh.vertices - c, axis=1) - r)
    assert err_raw.mean() < 0.05 and err_smooth.mean() < 0.7 * err_raw.mean()
    assert abs(smooth.volume / raw.volume - 1) < 0.001


def test_spacing_origin_and_direction_are_honoured():
    # an ellipsoid given in world millimetres, sampled on a tilted, anisotropic grid
    a = np.array([9.0, 6.0, 7.5])
    centre = np.array([30.0, -12.0, 5.0])
    angle = np.deg2rad(30.0)
    rot = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    for direction in (rot, rot @ np.diag([1.0, 1.0, -1.0])):  # a rotation, and one with a reflection
        spacing = np.array([0.4, 0.5, 0.6])
        shape = (64, 52, 44)
        origin = centre - direction @ (spacing * (np.array(shape) - 1) / 2)
        geometry = Volume(np.zeros(shape, np.uint8), spacing=spacing, origin=origin, direction=direction)
        ijk = np.stack(np.meshgrid(*[np.arange(k) for k in shape], indexing="ij"), -1).reshape(-1, 3)
        p = (geometry.index_to_world(ijk) - centre) / a
        q = np.sqrt((p**2).sum(1))
        # approximate distance to the ellipsoid in units of the smallest voxel size
        dist = ((q - 1) * np.linalg.norm(p, axis=1) / np.maximum(np.linalg.norm(p / a, axis=1), 1e-9) / 0.4)
        vol = Volume(ct(dist.reshape(shape)), spacing=spacing, origin=origin, direction=direction)
        ext = extract_surface(vol, smoothing=0)
        assert ext.volume == pytest.approx(4 / 3 * np.pi * a.prod(), rel=0.01)
        v = (ext.mesh.vertices - centre) / a
        assert np.abs(np.sqrt((v**2).sum(1)) - 1).max() < 0.03
        assert signed_volume(ext.mesh.vertices, ext.mesh.faces) > 0  # outward, whatever the handedness


def test_hollow_object_gives_only_its_outer_surface():
    c = np.array([30.2, 29.8, 30.5])
    d = sphere_distance(62, c, 24.0)
    inner = sphere_distance(62, c, 19.0)  # 5-voxel wall around an air cavity
    shell = np.maximum(d, -inner)
    seed = sphere_distance(62, c + [0, 0, -12.0], 3.0)  # a dense seed loose in the cavity
    ext = extract_surface(ct(np.minimum(shell, seed)))
    check_closed_surface(ext.mesh)
    radial = np.linalg.norm(ext.mesh.vertices - c, axis=1)
    assert radial.min() > 23.8  # nothing of the inner wall or the seed
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 24.0**3, rel=0.005)
    assert ext.n_filled_voxels == pytest.approx(4 / 3 * np.pi * 19.0**3, rel=0.03)


def test_low_density_core_is_filled():
    c = np.array([24.5, 24.5, 24.5])
    values = ct(sphere_distance(50, c, 18.0))
    core = sphere_distance(50, c, 8.0) < 0
    values[core] = 200.0  # below the level: a cavity for the threshold
    ext = extract_surface(values)
    check_closed_surface(ext.mesh)
    assert np.linalg.norm(ext.mesh.vertices - c, axis=1).min() > 17.8
    assert ext.n_filled_voxels == core.sum()


def test_keeps_the_largest_object():
    big = sphere_distance(60, (22, 30, 30), 14.0)
    small = sphere_distance(60, (49, 30, 30), 6.0)
    ext = extract_surface(ct(np.minimum(big, small)))
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 14.0**3, rel=0.01)
    assert ext.mesh.vertices[:, 0].max() < 37
    np.testing.assert_array_equal(ext.bounds, [[8, 37], [16, 45], [16, 45]])


def test_a_bed_touching_the_product_is_dropped():
    x, y, z = grid(72)
    ball = np.sqrt((x - 36) ** 2 + (y - 36) ** 2 + (z - 33) ** 2) - 20.0
    bed = np.maximum(z - 12.7, 1.2 - z)  # a slab across the whole field of view, touching the ball
    values = ct(np.minimum(ball, bed))
    ext = extract_surface(values)
    assert ext.n_support_voxels > 0.8 * 72 * 72 * 11  # the bed: its 11 layers (measured 57,026)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 20.0**3, rel=0.01)
    assert ext.mesh.vertices[:, 2].min() > 12.5
    kept = extract_surface(values, remove_support=False)
    assert kept.n_support_voxels == 0 and kept.volume > 2 * ext.volume


@pytest.mark.parametrize("thickness", [1.5, 3.5])
def test_a_bed_thinner_than_the_erosion_is_dropped(thickness):
    # a tray or plate thinner than 2 * support_radius: the erosion takes it whole, so it is
    # found as what the product's opening leaves out and reaches the border
    x, y, z = grid(72)
    ball = np.sqrt((x - 36) ** 2 + (y - 36) ** 2 + (z - 33) ** 2) - 20.0
    bed = np.maximum(z - 12.7, 12.7 - thickness - z)
    ext = extract_surface(ct(np.minimum(ball, bed)))
    assert ext.n_support_voxels >= 72 * 72 * int(thickness)  # every voxel layer of the plate
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 20.0**3, rel=0.005)
    assert ext.mesh.vertices[:, 2].min() > 12.5


def test_a_bed_fused_to_the_product_is_parted_by_a_larger_erosion():
    # the ball's bottom lies on the bed's top: joined over a disc wider than the
    # default erosion, and the bed (6 mm) thicker than it
    x, y, z = grid(72)
    ball = np.sqrt((x - 36) ** 2 + (y - 36) ** 2 + (z - 30) ** 2) - 20.0
    bed = np.maximum(z - 10.0, 4.0 - z)
    ext = extract_surface(ct(np.minimum(ball, bed)))
    assert ext.n_support_voxels > 0.8 * 72 * 72 * 6
    # a disc of the bed as wide as the contact stays under it (measured +2.8 %; kept whole: +93 %)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 20.0**3, rel=0.05)


def test_a_product_cut_by_the_border_on_a_thin_bed_keeps_its_stalk():
    # the thin-support rule drops only what reaches the border: a stalk is kept
    x, y, z = grid(72)
    body = np.sqrt((x - 36) ** 2 + (y - 36) ** 2 + (z - 33) ** 2) - 20.0
    stalk = np.maximum(np.hypot(x - 36, y - 36) - 1.5, np.maximum(z - 62.0, 40.0 - z))
    bed = np.maximum(z - 12.7, 10.2 - z)
    ext = extract_surface(ct(np.minimum(np.minimum(body, stalk), bed)))
    assert ext.n_support_voxels >= 72 * 72 * 2
    assert ext.mesh.vertices[:, 2].max() == pytest.approx(62.0, abs=0.3)
    assert ext.mesh.vertices[:, 2].min() > 12.5


def test_a_thin_stalk_is_kept():
    # the support step only runs for objects touching the border: a stalk is never eroded away
    x, y, z = grid(60)
    body = np.sqrt((x - 30) ** 2 + (y - 30) ** 2 + (z - 25) ** 2) - 15.0
    stalk = np.maximum(np.hypot(x - 30, y - 30) - 1.5, np.maximum(z - 52.0, 30.0 - z))
    ext = extract_surface(ct(np.minimum(body, stalk)))
    assert ext.mesh.vertices[:, 2].max() == pytest.approx(52.0, abs=0.3)


def test_synthetic_ct_volume_matches_its_true_surface():
    inst = synth.make_instance("pepper", random_state=5, volume=True, n_vertices=15000, pose="random")
    ext = extract_surface(inst.volume)
    truth = inst.mesh
    h = inst.voxel_size
    check_closed_surface(ext.mesh)
    assert closest_points(truth, ext.mesh.vertices).distances.mean() < 0.15 * h
    assert closest_points(ext.mesh, truth.vertices).distances.mean() < 0.15 * h
    # measured +0.20 % (2026-12-07), where the bound was 0.2 %: the CT-like volumes of the
    # benchmark come out within 0.5 %
    assert ext.volume == pytest.approx(signed_volume(truth.vertices, truth.faces), rel=0.004)
    assert ext.n_filled_voxels > 0  # the pepper is hollow


# --------------------------------------------------------------------------
# levels, smoothing, decimation
# --------------------------------------------------------------------------


def test_intensity_levels_are_the_histogram_peaks():
    d = sphere_distance(48, (23.5, 23.5, 23.5), 15.0)
    values = np.clip(ct(d, noise=20.0) - 1000.0, -1024, 3000).astype(np.int16)  # air -1000, flesh 0
    lv = intensity_levels(values)
    assert lv.background == pytest.approx(-1000.0, abs=4.0)
    assert lv.foreground == pytest.approx(0.0, abs=4.0)
    assert lv.level == pytest.approx(-500.0, abs=4.0)
    assert lv.background < lv.threshold < lv.foreground
    given = intensity_levels(values, level=-300.0)
    assert given.level == -300.0 and given.threshold == -300.0


def test_a_given_level_moves_the_surface():
    d = sphere_distance(48, (23.5, 23.5, 23.5), 15.0)
    values = (1000 * np.clip(0.5 - d / 4.0, 0, 1)).astype(np.int16)  # a linear ramp 4 voxels wide
    low = extract_surface(values, level=250, smoothing=0)  # integral level on integer voxels
    high = extract_surface(values, level=750, smoothing=0)
    check_closed_surface(low.mesh)  # no degenerate triangles either
    r_low = np.linalg.norm(low.mesh.vertices - 23.5, axis=1).mean()
    r_high = np.linalg.norm(high.mesh.vertices - 23.5, axis=1).mean()
    assert r_low - r_high == pytest.approx(2.0, abs=0.05)


def test_taubin_smooth_keeps_the_size():
    import trimesh

    s = trimesh.creation.icosphere(4, radius=20.0)
    rng = np.random.default_rng(1)
    noisy = s.vertices * (1 + 0.01 * rng.standard_normal((len(s.vertices), 1)))
    out = taubin_smooth(noisy, s.faces, iterations=10)
    r = np.linalg.norm(out, axis=1)
    assert abs(r.mean() - 20.0) < 0.02 and r.std() < 0.4 * np.linalg.norm(noisy, axis=1).std()
    np.testing.assert_array_equal(taubin_smooth(noisy, s.faces, iterations=0), noisy)
    with pytest.raises(ValueError):
        taubin_smooth(noisy, s.faces, iterations=-1)


def test_decimation_to_a_target_vertex_count():
    c, r = np.array([24.3, 23.8, 24.1]), 18.0
    ext = extract_surface(ct(sphere_distance(50, c, r)), target_vertices=1500)
    assert ext.mesh.n_vertices == pytest.approx(1500, abs=5)
    assert ext.n_marching_cubes_vertices > 3 * 1500  # this sphere's area makes 6,098
    check_closed_surface(ext.mesh)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * r**3, rel=0.01)
    small = Mesh(ext.mesh.vertices, ext.mesh.faces)
    assert decimate(small, 10**6) is small


# --------------------------------------------------------------------------
# slabs: the result does not depend on how the volume is cut
# --------------------------------------------------------------------------


def test_slabs_specks_and_pockets_do_not_change_the_surface(monkeypatch):
    c = np.array([27.4, 26.9, 27.2])
    d = sphere_distance(56, c, 20.0)
    clean = ct(d)
    reference = extract_surface(clean, smoothing=0)

    dirty = clean.copy()
    rng = np.random.default_rng(3)
    x, y, z = grid(56)
    far = np.argwhere((d > 3.0) & ((x + y + z) % 2 == 0))
    specks = far[rng.choice(len(far), 2000, replace=False)]
    dirty[tuple(specks.T)] = 1000.0  # 2000 one-voxel specks outside
    deep = np.argwhere((d < -4.0) & ((x + y + z) % 2 == 0))
    pockets = deep[rng.choice(len(deep), 3000, replace=False)]
    dirty[tuple(pockets.T)] = 0.0  # 3000 one-voxel air pockets inside
    # slabs of 3 planes: labels cross many slab boundaries, and a slab holds more
    # than 255 specks or pockets, so their labels take more than a byte each
    monkeypatch.setattr(extract, "_SLAB_VOXELS", 3 * 56 * 56)
    monkeypatch.setattr(extract, "_COARSE_VOXELS", 56**3)
    sliced = extract_surface(dirty, smoothing=0, level=reference.levels.level)
    # filled: the pockets (a flesh voxel walled in by pockets is flesh, not filled)
    assert reference.n_filled_voxels == 0
    assert sliced.n_filled_voxels == 3000
    assert sliced.mesh.n_vertices == reference.mesh.n_vertices
    # the same vertices, to float32 rounding (marching cubes' coordinates within a slab)
    from scipy.spatial import cKDTree

    assert cKDTree(reference.mesh.vertices).query(sliced.mesh.vertices)[0].max() < 1e-5
    assert cKDTree(sliced.mesh.vertices).query(reference.mesh.vertices)[0].max() < 1e-5
    check_closed_surface(sliced.mesh)


def test_an_object_cut_by_the_volume_border_is_closed():
    d = sphere_distance(40, (19.5, 19.5, 3.0), 14.0)  # the lower part lies outside the volume
    ext = extract_surface(ct(d))
    check_closed_surface(ext.mesh)
    assert ext.mesh.vertices[:, 2].min() == pytest.approx(-0.5, abs=0.1)  # closed half a voxel out


# --------------------------------------------------------------------------
# bad volumes
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "data, kwargs, message",
    [
        (np.zeros((20, 20, 20)), {}, "same value"),
        (np.full((20, 20, 20), 1000.0), {}, "same value"),
        (np.pad(np.zeros((4, 4, 4)), 8, constant_values=1000.0), {}, "touches all six faces"),
        (np.where(np.arange(8000).reshape(20, 20, 20) == 4210, 1000.0, 0.0), {}, "only 1 voxels"),
        (np.eye(20), {}, "2D image"),
        (np.full((10, 10, 10), np.nan), {}, "NaN"),
        (ct(sphere_distance(20, (10, 10, 10), 5.0)), {"level": 2000.0}, "no voxel is above"),
        (ct(sphere_distance(20, (10, 10, 10), 5.0)), {"level": -5.0}, "every voxel is above"),
        (ct(sphere_distance(20, (10, 10, 10), 5.0)), {"level": float("nan")}, "finite"),
    ],
    ids=["empty", "all-object", "no-background", "a-speck", "2d", "nan", "level-high", "level-low",
         "level-nan"],
)
def test_bad_volumes_get_a_clear_error(data, kwargs, message):
    with pytest.raises(VolumeError, match=message):
        extract_surface(data, **kwargs)


@pytest.mark.parametrize("spacing", [0.0, -1.0, (1.0, 0.0, 1.0)])
def test_zero_or_negative_spacing_is_refused(spacing):
    with pytest.raises(VolumeError, match="spacing"):
        extract_surface(Volume(np.zeros((5, 5, 5)), spacing=spacing))


def test_bad_options_are_refused():
    data = ct(sphere_distance(20, (10, 10, 10), 5.0))
    for kwargs in ({"smoothing": -1}, {"smoothing": 1.5}, {"target_vertices": 2}, {"support_radius": 0.0}):
        with pytest.raises(ValueError):
            extract_surface(data, **kwargs)


# --------------------------------------------------------------------------
# files, picture, command line, build
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def volumes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("volumes")
    x, y, z = grid(36) - 17.4
    for i, axes in enumerate(((12.0, 10.0, 13.0), (13.0, 10.5, 12.0), (11.0, 11.0, 14.0))):
        q = np.sqrt((x / axes[0]) ** 2 + (y / axes[1]) ** 2 + (z / axes[2]) ** 2)
        d = (q - 1.0) * min(axes)  # about the distance to the ellipsoid, near it
        data = np.clip(ct(d, noise=20.0, seed=i), -1000, 3000).astype(np.int16)
        write_volume(folder / f"ball_{i}.mha", Volume(data, spacing=0.8, origin=(5.0, 0.0, -3.0)))
    return folder


def test_extract_file_writes_the_surface_and_resumes(volumes, tmp_path):
    first = extract_file(volumes / "ball_0.mha", tmp_path, picture=False)
    assert first.ok and not first.resumed and first.picture is None
    mesh = read_mesh(tmp_path / "ball_0.ply")
    assert mesh.n_vertices == first.n_vertices
    log = json.loads((tmp_path / "ball_0.json").read_text())
    assert log["units"]["unit"] == "mm" and log["units"]["spacing_mm"] == [0.8, 0.8, 0.8]
    assert log["volume_mm3"] == pytest.approx(first.volume_mm3)
    stamp = (tmp_path / "ball_0.ply").stat().st_mtime_ns
    again = extract_file(volumes / "ball_0.mha", tmp_path, picture=False)
    assert again.resumed and (tmp_path / "ball_0.ply").stat().st_mtime_ns == stamp
    other = extract_file(volumes / "ball_0.mha", tmp_path, picture=False, smoothing=0)
    assert other.ok and not other.resumed
    bad = extract_file(tmp_path / "missing.nrrd", tmp_path)
    assert not bad.ok and bad.error.startswith(str(tmp_path / "missing.nrrd"))


def test_render_extraction_draws_surface_and_slices(tmp_path):
    from PIL import Image

    values = ct(sphere_distance(30, (14.5, 14.5, 14.5), 9.5))
    ext = extract_surface(values)
    out = render_extraction(values, ext, tmp_path / "check.png", title="ball", size=(900, 300),
                            backend="matplotlib")
    image = np.asarray(Image.open(out).convert("RGB"))
    assert image.shape == (300, 900, 3)
    red = (image[..., 0] > 200) & (image[..., 1] < 120) & (image[..., 2] < 120)
    assert red[:, 300:].sum() > 50  # the outline over the slices
    with pytest.raises(ValueError, match="png"):
        render_extraction(values, ext, tmp_path / "check.jpg")


def test_volume_stem():
    assert volume_stem("a/b/pear_01.nii.gz") == "pear_01"
    assert volume_stem("a/b/pear_01.MHA") == "pear_01"


def test_cli_extract(volumes, tmp_path, capsys):
    broken = tmp_path / "broken.mha"
    broken.write_text("ObjectType = Image\nNDims = 2\nDimSize = 3 3\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n")
    out = tmp_path / "surfaces"
    args = ["extract", str(volumes / "ball_0.mha"), str(volumes / "ball_1.mha"), str(broken),
            "--out", str(out), "--no-picture", "--target-vertices", "1500"]
    assert main(args) == 1
    captured = capsys.readouterr()
    errors = [line for line in captured.err.splitlines() if line.startswith("hortishape: error:")]
    assert len(errors) == 1 and str(broken) in errors[0] and "2D" in errors[0]
    assert "extracted 2 of 3" in captured.out
    for name in ("ball_0", "ball_1"):
        mesh = read_mesh(out / f"{name}.ply")
        assert mesh.n_vertices == pytest.approx(1500, abs=5)
        check_closed_surface(mesh)
    assert main(args[:3] + ["--out", str(out), "--no-picture", "--target-vertices", "1500"]) == 0
    assert "resumed" in capsys.readouterr().out


@pytest.mark.slow
def test_build_from_a_folder_of_volumes(volumes, tmp_path):
    from hortishape.pipeline import build_model, find_scans
    from hortishape.registration import RegistrationConfig

    write_mesh(volumes / "not_a_scan.txt.ply", Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]))
    try:
        paths, failed, _ = find_scans(volumes, tmp_path, n_jobs=1)
        assert [p.name for p in paths] == ["ball_0.ply", "ball_1.ply", "ball_2.ply", "not_a_scan.txt.ply"]
        assert failed == [] and (tmp_path / "surfaces" / "ball_0.png").is_file()
        result = build_model(volumes, tmp_path, n_points=600, config=RegistrationConfig(n_iterations=6),
                             n_jobs=2)
    finally:
        (volumes / "not_a_scan.txt.ply").unlink()
    assert result.names == ("ball_0", "ball_1", "ball_2")
    assert [p.endswith("not_a_scan.txt.ply") for p, _ in result.skipped] == [True]  # an open triangle
    assert result.model_path.is_file()
    # the voxel size the error names as the fix is an option of build too
    paths, _, _ = find_scans(volumes, tmp_path / "doubled", n_jobs=1, spacing=(1.6, 1.6, 1.6))
    assert np.ptp(read_mesh(paths[1]).vertices, axis=0).max() == pytest.approx(
        2 * np.ptp(read_mesh(tmp_path / "surfaces" / "ball_1.ply").vertices, axis=0).max(), rel=1e-6)
    args = build_parser().parse_args(["build", str(volumes), "--out", "x", "--spacing", "0.8", "0.8", "0.8"])
    assert args.spacing == [0.8, 0.8, 0.8]


def test_spacing_sets_the_voxel_size_and_a_wrong_one_is_refused(volumes, tmp_path, capsys):
    base = extract_file(volumes / "ball_1.mha", tmp_path / "a", picture=False)
    double = extract_file(volumes / "ball_1.mha", tmp_path / "b", picture=False, spacing=(1.6, 1.6, 1.6))
    assert base.ok and double.ok
    assert double.volume_mm3 == pytest.approx(8 * base.volume_mm3, rel=1e-3)
    log = json.loads((tmp_path / "b" / "ball_1.json").read_text())
    assert log["units"]["spacing_mm"] == [1.6, 1.6, 1.6] and log["options"]["spacing"] == [1.6, 1.6, 1.6]
    # a voxel size given in metres: the product is 0.03 mm across, and the fix is named
    metres = extract_file(volumes / "ball_1.mha", tmp_path / "c", picture=False, spacing=(0.0008,) * 3)
    assert not metres.ok and metres.error.startswith(str(volumes / "ball_1.mha"))
    assert "not a fruit's size" in metres.error and "use --spacing 0.8 0.8 0.8" in metres.error
    assert not (tmp_path / "c" / "ball_1.ply").exists()
    # the command line: a TIFF stack, which stores no voxel size
    tif = write_volume(tmp_path / "ball.tif", read_volume(volumes / "ball_1.mha"))
    assert main(["extract", str(tif), "--out", str(tmp_path / "t"), "--no-picture", "--spacing", "0.8", "0.8",
                 "0.8"]) == 0
    out = capsys.readouterr().out
    assert "extracted 1 of 1" in out
    tif_log = json.loads((tmp_path / "t" / "ball.json").read_text())
    assert tif_log["volume_mm3"] == pytest.approx(base.volume_mm3, rel=1e-3)


# --------------------------------------------------------------------------
# the outer surface by construction (MRI: peel, rind, segments, an open core)
# --------------------------------------------------------------------------


def _layered_fruit(n=80, *, channel=1.0, seed=0):
    """An MRI-like ball (voxel units, 1 mm voxels): a bright peel 2 voxels thick over a dark rind
    3 thick, bright flesh cut by 6 dark gaps into wedges, a dark core that opens to the top
    through a channel ``channel`` voxels in radius (through rind and peel). Outer radius 30."""
    c = (n - 1) / 2.0
    x, y, z = grid(n) - c
    r = np.sqrt(x**2 + y**2 + z**2)
    d = r - 30.0  # negative inside

    def inside(v):
        return 0.5 * (1.0 - erf(v / (0.7 * np.sqrt(2.0))))

    values = 40.0 * inside(d) + (10.0 - 40.0) * inside(d + 2.0)
    angle = np.arctan2(y, x)
    across = np.hypot(x, y) * np.abs((angle + np.pi / 6) % (np.pi / 3) - np.pi / 6)
    flesh = 10.0 + 70.0 * (1.0 - inside(across - 0.8))
    values += (flesh - 10.0) * inside(d + 5.0)
    core = np.maximum(inside(r - 5.0), np.where(z > 0, inside(np.hypot(x, y) - channel), 0.0))
    values = values * (1.0 - core) + 4.0 * core * (d < 0)
    rng = np.random.default_rng(seed)
    values = np.hypot(values + rng.normal(0, 2.0, values.shape), rng.normal(0, 2.0, values.shape))
    return np.clip(np.rint(values), 0, 255).astype(np.uint8), c


def test_mri_like_fruit_gives_the_peel_surface_closed_over_its_channel():
    data, c = _layered_fruit()
    with pytest.warns(ExtractionWarning, match="gaps up to 2 mm wide were closed"):
        ext = extract_surface(data)
    assert ext.levels.method == "outer"
    assert 15 < ext.levels.level < 25  # half-way up the peel's edge (40), not the flesh's (80)
    assert ext.genus == 0 and ext.gap_mm == 2.0
    assert ext.attempts[0]["genus"] > 0 or ext.attempts[0]["enclosed"]
    radial = np.linalg.norm(ext.mesh.vertices - c, axis=1)
    away = ext.mesh.vertices[:, 2] - c < 27.0  # apart from the channel's mouth
    # the peel's outer edge (radius 30), not the flesh's (25), although a peel 2 voxels thick
    # never reaches its full brightness (40) once blurred
    assert np.abs(radial[away] - 30.0).mean() < 0.15
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 30.0**3, rel=0.01)
    # the flesh alone, as a level half-way to the flesh gives it (the old answer), is far smaller
    assert ext.n_filled_voxels > 0.1 * (4 / 3 * np.pi * 30.0**3)


@pytest.mark.parametrize("artefact", ["bias", "gibbs"])
def test_a_bias_field_or_gibbs_ringing_keeps_the_peel_surface(artefact):
    data, c = _layered_fruit(seed=2)
    v = data.astype(np.float64)
    if artefact == "bias":  # a receive coil's field: 0.8 to 1.2 across x
        v *= np.linspace(0.8, 1.2, v.shape[0])[:, None, None]
    else:  # k-space cut to half its width: ringing beside every edge
        k = np.fft.fftshift(np.fft.fftn(v))
        keep = np.zeros(k.shape, dtype=bool)
        keep[20:60, 20:60, 20:60] = True
        k[~keep] = 0.0
        v = np.abs(np.fft.ifftn(np.fft.ifftshift(k)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtractionWarning)  # the closed gaps, said in other tests
        ext = extract_surface(np.clip(np.rint(v), 0, 255).astype(np.uint8))
    assert ext.levels.method == "outer" and ext.genus == 0
    radial = np.linalg.norm(ext.mesh.vertices - c, axis=1)
    away = ext.mesh.vertices[:, 2] - c < 27.0
    assert np.abs(radial[away] - 30.0).mean() < 0.15
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 30.0**3, rel=0.015)


def test_a_given_level_on_the_flesh_still_gives_one_closed_surface_of_genus_0():
    data, _ = _layered_fruit(seed=1)
    ext = extract_surface(data, level=40.0)  # on the flesh: its gaps and core open to the top
    assert ext.levels.method == "given"
    assert ext.genus == 0
    check_closed_surface(ext.mesh)


def test_the_level_is_the_peels_where_part_of_the_fruit_has_none():
    # a 2 mm peel (30) over a dark rind covers the ball above z = -4 mm; below, the flesh (100)
    # reaches the surface bare: 40 % of the rays meet the flesh first. The level is the peel's
    # edge, half-way from the background (2) to it; with those rays pooled into its edge profile
    # the level was 20.3 (before 46ba3ec), and higher the more of the surface is bare
    from scipy.ndimage import gaussian_filter

    h, n = 0.5, 100
    rng = np.random.default_rng(0)
    axis = (np.arange(n) + 0.5) * h - 25.0
    x, y, z = np.meshgrid(axis - 0.1, axis + 0.2, axis - 0.15, indexing="ij")
    r = np.sqrt(x**2 + y**2 + z**2)
    v = np.where(r <= 20.0, np.where(z > -4.0, 30.0, 100.0), 2.0)
    v[(r <= 18.0) & (z > -4.0)] = 8.0
    v[r <= 16.5] = 100.0
    v = gaussian_filter(v, 0.6)
    v = np.hypot(v + rng.normal(0, 2.0, v.shape), rng.normal(0, 2.0, v.shape))
    levels = extract.intensity_levels(Volume(np.clip(np.rint(v), 0, 255).astype(np.uint8), spacing=(h, h, h)))
    assert levels.method == "outer"
    assert levels.level == pytest.approx(16.0, abs=1.5)


@pytest.mark.parametrize("sigma", [1.5, 2.0])
def test_a_wide_blur_is_not_taken_for_an_outer_tissue(sigma):
    # 1 mm voxels blurred over 1.5-2 voxels: the brightest voxel within the 2 mm window
    # stays below the flesh, as a darker rind's would; the profile is one step
    ball = sphere_distance(48, (23.5, 23.5, 23.5), 16.0)
    ext = extract_surface(ct(ball, sigma=sigma, noise=25.0))
    assert ext.levels.method == "peaks"  # was "outer" at 446 and 190: +3.8 and +37 %
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 16.0**3, rel=0.005)


def test_ct_like_volumes_keep_the_histogram_level_and_close_no_gaps():
    inst = synth.make_instance("apple", random_state=8, volume=True, n_vertices=15000, pose="random")
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtractionWarning)
        ext = extract_surface(inst.volume)
    assert ext.levels.method == "peaks" and ext.gap_mm == 0.0 and ext.genus == 0
    assert ext.levels.level == pytest.approx(0.5 * (ext.levels.background + ext.levels.foreground))


@pytest.mark.slow
def test_synthetic_mri_volume_matches_its_true_surface():
    inst = synth.make_instance("pepper", random_state=5, volume=True, pose="random")
    vol = inst.mri_volume
    assert vol.data.dtype == np.uint8 and vol.spacing[2] == pytest.approx(2 * vol.spacing[0])
    with pytest.warns(ExtractionWarning, match="closed"):
        ext = extract_surface(vol)
    assert ext.levels.method == "outer" and ext.genus == 0
    h = inst.voxel_size
    assert closest_points(inst.mesh, ext.mesh.vertices).distances.mean() < 0.15 * h
    assert closest_points(ext.mesh, inst.mesh.vertices).distances.mean() < 0.15 * h
    assert ext.volume == pytest.approx(signed_volume(inst.mesh.vertices, inst.mesh.faces), rel=0.005)


def test_euler_number_gives_the_genus_slab_by_slab():
    x, y, z = grid(30) - 14.5
    ring = (np.hypot(np.hypot(x, y) - 9.0, z) < 3.5)  # a solid torus: genus 1
    ball = np.sqrt(x**2 + y**2 + z**2) < 9.0
    two_rings = ring | (np.hypot(np.hypot(x, z) - 9.0, y - 0.0) < 2.5)  # two linked-through rings
    for mask, genus in ((ball, 0), (ring, 1)):
        m = mask.transpose(2, 1, 0)
        whole = extract._euler_number(m, len(m))
        parts = sum(extract._euler_number(m[z0 : min(z1 + 1, len(m))], z1 - z0)
                    for z0, z1 in extract._slab_bounds(0, len(m), 7))
        assert whole == parts == 1 - genus
    assert extract._euler_number(two_rings, len(two_rings)) < 0


def test_warnings_name_a_product_cut_by_the_border_and_a_size_far_from_a_fruit():
    d = sphere_distance(40, (19.5, 19.5, 3.0), 14.0)
    with pytest.warns(ExtractionWarning) as caught:
        ext = extract_surface(Volume(ct(d), spacing=0.1))  # 2.8 mm across
    text = " ".join(str(w.message) for w in caught)
    assert "touches the volume's border (-z)" in text and "far from a fruit's" in text
    assert list(ext.warnings) == [str(w.message).split(": ", 1)[1] for w in caught]


def test_a_support_that_would_take_nearly_everything_is_kept_with_a_warning():
    x, y, z = grid(72)
    bed = np.maximum(z - 12.7, 1.2 - z)  # a bed across the field of view
    post = np.maximum(np.hypot(x - 36, y - 36) - 1.5, np.maximum(z - 30.0, 5.0 - z))
    knob = np.sqrt((x - 36) ** 2 + (y - 36) ** 2 + (z - 32.0) ** 2) - 4.0  # a knob on a post on it
    # the erosion that parts a support from a product leaves only the knob apart from the bed
    with pytest.warns(ExtractionWarning, match="no support was dropped"):
        ext = extract_surface(ct(np.minimum(np.minimum(bed, post), knob)))
    assert ext.n_support_voxels == 0 and ext.volume > 50_000


def test_intensity_levels_explain_themselves():
    data, _ = _layered_fruit(n=70)
    lv = intensity_levels(data)
    assert lv.method == "outer" and "outer edge of the outermost tissue" in lv.explain()
    assert "given" in intensity_levels(data, level=20.0).explain()
    assert "half-way between the background" in intensity_levels(ct(sphere_distance(30, (15, 15, 15), 8))).explain()


def test_a_narrow_channel_to_the_core_is_closed_over():
    # CT-like: a ball 50 mm across with an air core, open to the outside through a channel
    # 3 mm wide: genus 0 at every gap width, but the outside reaches deep into it
    n, c = 64, 31.5
    x, y, z = grid(n) - c
    ball = np.sqrt(x**2 + y**2 + z**2) - 25.0
    core = 6.0 - np.sqrt(x**2 + y**2 + z**2)
    channel = np.where(z > 0, 1.5 - np.hypot(x, y), -np.inf)
    with pytest.warns(ExtractionWarning, match="narrow channel"):
        ext = extract_surface(ct(np.maximum(ball, np.maximum(core, channel))))
    assert ext.genus == 0 and ext.gap_mm >= 2.0
    assert ext.attempts[0]["genus"] == 0 and ext.attempts[0]["channel_mm"] > 10.0
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 25.0**3, rel=0.01)  # the core filled


def test_a_peel_broken_into_pieces_around_the_flesh_is_closed():
    # a thin peel that the slices break up (here: into octants, 2 voxels apart) over a dark
    # rind and bright flesh: the flesh alone is one solid of genus 0 and the largest piece,
    # but the peel's pieces together lie beyond it on every side
    n = 64
    x, y, z = grid(n) - (n - 1) / 2.0
    d = np.sqrt(x**2 + y**2 + z**2) - 24.0

    def inside(v):
        return 0.5 * (1.0 - erf(v / (0.7 * np.sqrt(2.0))))

    values = 40.0 * inside(d) - 30.0 * inside(d + 2.0) + 70.0 * inside(d + 5.0)
    cuts = np.minimum(np.minimum(np.abs(x), np.abs(y)), np.abs(z)) <= 0.5
    values[cuts & (d > -2.5)] = 0.0
    with pytest.warns(ExtractionWarning, match="open shell"):
        ext = extract_surface(values.astype(np.float32), level=20.0)
    assert ext.attempts[0]["genus"] == 0 and ext.attempts[0]["enclosed"]
    assert ext.genus == 0 and ext.gap_mm == 2.0
    # the peel's outer edge (radius 24), not the flesh's (19: 0.50 of the volume)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 24.0**3, rel=0.01)


def test_flesh_segments_parted_by_dark_gaps_are_taken_whole():
    # no peel to hold them together: twelve wedges, 1 mm apart, each one solid of genus 0;
    # the largest wedge alone (an eighth of the fruit) was the product before
    n = 64
    x, y, z = grid(n) - (n - 1) / 2.0
    angle = np.arctan2(y, x) % (np.pi / 6.0) - np.pi / 12.0
    across = np.hypot(x, y) * np.abs(np.sin(angle))
    ball = np.sqrt(x**2 + y**2 + z**2) - 25.0
    with pytest.warns(ExtractionWarning, match="other pieces beside it"):
        ext = extract_surface(ct(np.maximum(ball, 0.5 - across)))
    assert ext.attempts[0]["genus"] == 0 and ext.attempts[0]["beside_voxels"] > 0
    assert ext.genus == 0 and ext.attempts[-1]["beside_voxels"] == 0
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 25.0**3, rel=0.01)


def test_separate_objects_side_by_side_keep_the_largest_with_a_warning():
    # two balls 7 mm apart whose bounding boxes overlap: no gap up to BESIDE_GAP_MM joins
    # them, so they are two objects, not one broken up
    n = 96
    p = grid(n)
    big = np.sqrt(((p - np.array([30.0, 30.0, 48.0])[:, None, None, None]) ** 2).sum(axis=0)) - 18.0
    small = np.sqrt(((p - np.array([59.0, 59.0, 48.0])[:, None, None, None]) ** 2).sum(axis=0)) - 16.0
    with pytest.warns(ExtractionWarning, match="separate objects"):
        ext = extract_surface(ct(np.minimum(big, small)))
    assert ext.gap_mm == extract.BESIDE_GAP_MM and ext.genus == 0
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 18.0**3, rel=0.01)


def test_gaps_closed_next_to_the_border_leave_no_cap():
    # the channel of test_a_narrow_channel_to_the_core_is_closed_over, 5 mm wide, with the
    # ball's top 1.5 mm from the volume's last plane: the box that closes the channel is
    # wider than that gap, but beyond the border is air, so the gap stays outside
    n = 64
    x, y, z = grid(n) - np.array([31.5, 31.5, 36.5])[:, None, None, None]
    r = np.sqrt(x**2 + y**2 + z**2)
    channel = np.where(z > 0, 2.6 - np.hypot(x, y), -np.inf)
    with pytest.warns(ExtractionWarning, match="gaps up to 4 mm wide were closed") as caught:
        ext = extract_surface(ct(np.maximum(r - 25.0, np.maximum(6.0 - r, channel))))
    assert ext.genus == 0 and ext.gap_mm == 4.0
    assert ext.mesh.vertices[:, 2].max() == pytest.approx(61.5, abs=0.2)  # was 63.6: a cap to the border
    assert not any("border" in str(w.message) for w in caught)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 25.0**3, rel=0.005)


def _thin_peel_ball(seed=0, radius=20.0, peel=0.5, rind=3.0, core=8.0, pixel=0.5, slice_mm=2.0, shift=(0, 0, 0),
                    peel_value=90.0, flesh=80.0):
    """An MRI-like ball (mm) in slices (by default four times as thick as its pixels), 48 mm
    across: a peel ``peel`` thick (by default thinner than a slice, and bright) over a dark rind
    ``rind`` thick (8; the background 3), flesh around a dark core that runs from pole to pole.
    Partial volume from 2 x 2 x 4 points per voxel, Rician noise. Its centre ``shift`` (mm) from
    the field's."""
    n_xy, n_z = int(np.ceil(48 / pixel)), int(np.ceil(48 / slice_mm))
    sub = (2, 2, 4)
    axes = [(np.arange(n)[:, None] + (np.arange(k) + 0.5) / k).ravel() * h - 24.0 - c
            for n, k, h, c in ((n_xy, sub[0], pixel, shift[0]), (n_xy, sub[1], pixel, shift[1]),
                               (n_z, sub[2], slice_mm, shift[2]))]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    d = np.sqrt(x**2 + y**2 + z**2) - radius
    v = np.where(d <= 0, peel_value, 3.0)
    v[d <= -peel] = 8.0
    v[(d <= -peel - rind) & (np.hypot(x, y) >= core)] = flesh
    v = v.reshape(n_xy, sub[0], n_xy, sub[1], n_z, sub[2]).mean(axis=(1, 3, 5))
    rng = np.random.default_rng(seed)
    v = np.hypot(v + rng.normal(0, 2.0, v.shape), rng.normal(0, 2.0, v.shape))
    return Volume(np.clip(np.rint(v), 0, 255).astype(np.uint8), spacing=(pixel, pixel, slice_mm))


def test_a_peel_thinner_than_a_slice_is_kept_whole_at_the_poles():
    # in-plane the peel is resolved and sets the level; across the slices it fills a share
    # of one and stays below that level: the poles open into the core, and no gap width
    # closes them (before: the product grew into the background, "touches all six faces")
    vol = _thin_peel_ball()
    with pytest.warns(ExtractionWarning, match="thinner than a slice"):
        ext = extract_surface(vol)
    lv = ext.levels
    assert lv.segment < lv.level and lv.slice_outer < lv.level
    assert "thinner than a slice" in lv.explain()
    assert ext.attempts[-1]["level"] < lv.level  # what is inside, decided at the lower level
    assert ext.attempts[0]["level"] > lv.level - 1  # after the level alone was tried
    assert ext.genus == 0 and ext.gap_mm <= 2.0
    check_closed_surface(ext.mesh)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 20.0**3, rel=0.015)
    centre = 24.0 - 0.5 * vol.spacing  # voxel i spans [i, i + 1) spacings, its centre at i
    radial = np.linalg.norm(ext.mesh.vertices - centre, axis=1)
    assert np.abs(radial - 20.0).mean() < 0.4  # mm; the slices are 2 mm (measured 0.29)


@pytest.mark.parametrize("shift", [(0.07, -0.12, -0.92), (-0.1, -0.04, -0.94)])
def test_gaps_that_close_a_pole_left_open_do_not_sink_it(shift):
    # a peel 0.8 mm thick, its brightness near the flesh's (so the level is half-way between the
    # histogram's peaks), in slices 2 mm thick whose boundary lies near a pole: across the slices it
    # stays below the level there, and gaps of 8 mm made the product whole but bridged the pole
    # only partly: -18.6 % (before; warned only of the gaps); what is inside is decided at the lower
    # level
    vol = _thin_peel_ball(peel=0.8, shift=shift)
    with pytest.warns(ExtractionWarning, match="thinner than a slice"):
        ext = extract_surface(vol)
    assert ext.levels.segment < ext.levels.level
    assert ext.genus == 0
    check_closed_surface(ext.mesh)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 20.0**3, rel=0.015)
    centre = 24.0 + np.asarray(shift) - 0.5 * vol.spacing
    radial = np.linalg.norm(ext.mesh.vertices - centre, axis=1)
    assert np.abs(radial - 20.0).mean() < 0.3


def test_a_skin_sharper_than_a_voxel_keeps_the_level_above_the_background():
    # a bright skin 0.4 mm thick over the flesh, 0.39 mm pixels, no blur but the voxels': the
    # edge's first estimate, on a line through the steepest point, ran below the background
    # (before: "the object above the level -13.5 touches all six faces")
    vol = _thin_peel_ball(peel=0.4, rind=0.0, pixel=0.39, slice_mm=1.0, shift=(0.1, -0.05, 0.2),
                          peel_value=133.0, flesh=100.0)
    ext = extract_surface(vol)
    assert ext.levels.level > ext.levels.background + 0.25 * (ext.levels.foreground - ext.levels.background)
    assert ext.genus == 0
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 20.0**3, rel=0.015)


@pytest.mark.parametrize("peel, value", [(0.7, 70.0), (0.6, 75.0)])
def test_a_dim_skin_too_thin_to_fill_the_window_sets_the_level(peel, value):
    # a skin 0.7-0.75 times the flesh, under 2 mm thick: the rays' brightest voxel within the
    # window is the flesh's, and the level half-way to the flesh lay inside the skin (before:
    # -2.2 and -1.6 %); the profile pauses on the skin, and the level is fitted on its edge
    vol = _thin_peel_ball(peel=peel, rind=0.0, pixel=0.39, slice_mm=1.0, shift=(0.1, -0.05, 0.2),
                          peel_value=value, flesh=100.0)
    ext = extract_surface(vol)
    assert ext.levels.method == "outer" and "pauses on it" in ext.levels.explain()
    assert ext.levels.level < 0.5 * (ext.levels.background + ext.levels.foreground)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 20.0**3, rel=0.005)


@pytest.mark.slow
def test_strong_noise_leaves_one_surface():
    # an MRI-like apple with Rician noise twice the volumes' (the artefact benchmark's seed 14,
    # apple 1): one closed surface (while a lower level was also tried after closing gaps wider
    # than 2 mm, specks taken in there lay apart from the product: 9 components, refused). Its
    # level alone closes it, with gaps up to 4 mm: the attempts are all at the level (an
    # assertion that the last was lower held only because integer volumes were meshed at
    # floor(level) + 0.5)
    inst = synth.make_instance("apple", random_state=synth.spawn_seeds(14, 2)[1], volume=True, pose="random")
    vol = inst.mri_volume
    rng = np.random.default_rng(15)
    v = vol.data.astype(np.float64)
    v = np.hypot(v + rng.normal(0, 4.0, v.shape), rng.normal(0, 4.0, v.shape))
    noisy = Volume(np.clip(np.rint(v), 0, 255).astype(np.uint8), spacing=vol.spacing, origin=vol.origin,
                   direction=vol.direction)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtractionWarning)
        ext = extract_surface(noisy)
    assert all(a["level"] == ext.attempts[0]["level"] for a in ext.attempts)
    check_closed_surface(ext.mesh)  # one component
    assert ext.genus == 0
    assert ext.volume == pytest.approx(signed_volume(inst.mesh.vertices, inst.mesh.faces), rel=0.01)


def test_a_peel_as_thick_as_a_slice_is_segmented_at_the_level():
    vol = _thin_peel_ball(peel=2.5, slice_mm=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtractionWarning)
        ext = extract_surface(vol)
    assert ext.levels.segment == ext.levels.level
    assert all(a["level"] == ext.attempts[0]["level"] for a in ext.attempts)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 20.0**3, rel=0.01)


def test_slab_labels_come_back_as_they_were_kept():
    from hortishape.extract import _Runs

    smooth = np.zeros((4, 30, 40), dtype=np.int32)
    smooth[:, 5:20, 10:30] = 1
    smooth[1:3, 22:28, 2:8] = 300  # more labels than a byte holds
    noisy = np.random.default_rng(0).integers(0, 3, (4, 30, 40)).astype(np.int32)
    for labels, n, as_runs in ((smooth, 300, True), (noisy, 2, False)):
        kept = _Runs(labels, n)
        assert (kept.plain is None) == as_runs
        np.testing.assert_array_equal(kept.array(), labels)


def test_a_large_surface_is_drawn_from_a_coarser_copy(monkeypatch):
    import trimesh

    sphere = trimesh.creation.icosphere(6, radius=40.0)  # 40,962 vertices
    mesh = Mesh(sphere.vertices, sphere.faces)
    monkeypatch.setattr(extract, "_PICTURE_VERTICES", 5000)
    small = extract._picture_surface(mesh)
    used = np.unique(small.faces)
    assert 3000 < len(used) < 8000
    # outward, no face twice, hardly any hole: nothing that would draw as a seam
    centres = small.vertices[small.faces].mean(axis=1)
    normals = np.cross(*(small.vertices[small.faces[:, k]] - small.vertices[small.faces[:, 0]] for k in (1, 2)))
    assert (np.einsum("ij,ij->i", normals, centres) > 0).all()
    assert len(np.unique(np.sort(small.faces, axis=1), axis=0)) == small.n_faces
    edges = np.sort(np.concatenate([small.faces[:, [0, 1]], small.faces[:, [1, 2]], small.faces[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert (uses == 1).mean() < 0.01
    assert face_areas(small.vertices, small.faces).sum() == pytest.approx(4 * np.pi * 40.0**2, rel=0.02)
    few = trimesh.creation.icosphere(4)  # 2,562 vertices
    few = Mesh(few.vertices, few.faces)
    assert extract._picture_surface(few) is few  # drawn as it is


def test_an_integer_volume_is_meshed_at_the_level_itself():
    # a box whose faces are linear ramps of 10 units per voxel: the level 30.3 lies 3.03 voxels in
    # from each face (meshed at floor + 0.5 before, 3.05); an integer level is moved off it
    n = 24
    i = np.arange(n)
    ramp = np.minimum(i, n - 1 - i)
    d = np.minimum(np.minimum(ramp[:, None, None], ramp[None, :, None]), ramp[None, None, :])
    data = (10 * d).astype(np.uint8)
    data[0, 0, 0] = 1  # the values on the integers, not only on the tens (below)

    def face_at(data, level):
        v = extract_surface(data, level=level, smoothing=0).mesh.vertices
        face = (np.abs(v[:, 1] - 11.5) < 4) & (np.abs(v[:, 2] - 11.5) < 4) & (v[:, 0] < 11.5)
        assert face.sum() > 10
        return v[face, 0]

    np.testing.assert_allclose(face_at(data, 30.3), 3.03, atol=1e-6)
    # the same values stored as float: the same surface
    np.testing.assert_array_equal(face_at(data.astype(np.float64), 30.3), face_at(data, 30.3))
    # values on the tens only: the level is kept 0.05 of their step (0.5) off them, however stored
    tens = (10 * d).astype(np.uint8)
    for stored in (tens, tens.astype(np.float32), tens.astype(np.int32) * 7):
        step = 10.0 * (7 if stored.dtype == np.int32 else 1)
        np.testing.assert_allclose(face_at(stored, 3.03 * step), 3.05, atol=1e-6)
    integers = (0.0, 1.0)
    assert extract._off_grid(30.0, integers) == pytest.approx(30.0 + extract.ISO_OFF_INTEGER)
    assert extract._off_grid(30.999, integers) == pytest.approx(31.0 - extract.ISO_OFF_INTEGER)
    assert extract._off_grid(30.3, integers) == 30.3
    assert extract._off_grid(0.5, (0.5, 0.25)) == pytest.approx(0.5 + 0.25 * extract.ISO_OFF_INTEGER)
    assert extract._off_grid(30.0, None) == 30.0


@pytest.mark.slow
def test_the_same_values_stored_otherwise_give_the_same_surface():
    # an 8-bit MRI stored as float (a NIfTI's scl_slope, a DICOM's rescale slope) or multiplied
    # up: the same surface. Before, a float volume's histogram had 4096 bins over its 256 values
    # and another smoothing, equal rises along a ray were told apart by the float's rounding, the
    # layer fit's finite differences depended on the scale, and the level was not kept off the
    # values: as float32, this apple's level was 18.06 instead of 17.65 and its volume 0.16 % less
    inst = synth.make_instance("apple", random_state=6, volume=True, pose="random")
    vol = inst.mri_volume
    scale = 1.0 / 255.0
    stored = {
        "uint8": (vol, 1.0),
        "float32": (replace(vol, data=vol.data.astype(np.float32) * np.float32(scale)), scale),
        "uint16 x16": (replace(vol, data=vol.data.astype(np.uint16) * np.uint16(16)), 16.0),
    }
    # with an offset or z-scored, a magnitude image's zero is its smallest value (before, the
    # Rician floor was dropped: the 1000 subtracted moved seed 14's apple 0 from -0.15 to -0.45 %)
    data = vol.data.astype(np.float32)
    mean, sd = float(data.mean()), float(data.std())
    shifted = {
        "int16 -1000": (replace(vol, data=vol.data.astype(np.int16) - np.int16(1000)), 1.0, -1000.0),
        "z-scored": (replace(vol, data=(data - np.float32(mean)) / np.float32(sd)), 1.0 / sd, -mean / sd),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtractionWarning)
        got = {k: extract_surface(v, smoothing=0) for k, (v, *_) in {**stored, **shifted}.items()}
    base = got["uint8"]
    for k, (v, unit) in stored.items():
        assert extract._value_grid(v.data)[1] == pytest.approx(unit)
        assert got[k].levels.level / unit == pytest.approx(base.levels.level, abs=1e-4), k
    for k, (v, unit, zero) in shifted.items():
        assert (got[k].levels.level - zero) / unit == pytest.approx(base.levels.level, abs=1e-3), k
    for k in got:
        assert got[k].levels.method == base.levels.method
        assert got[k].volume == pytest.approx(base.volume, rel=1e-5), k


def test_values_on_no_grid_are_counted_in_4096_bins():
    rng = np.random.default_rng(0)
    assert extract._value_grid(rng.normal(size=(30, 30, 30))) is None
    assert extract._value_grid(np.arange(27.0).reshape(3, 3, 3) * 0.1 - 1.0) == pytest.approx((-1.0, 0.1))
    assert extract._value_grid(np.full((3, 3, 3), 7, np.int16) + np.arange(3, dtype=np.int16) * 5) == (7.0, 5.0)


@pytest.mark.parametrize("padding", [-2000, -3024])
def test_outside_the_reconstructed_circle_is_not_the_background(padding):
    # a CT in Hounsfield units: air -1000 with noise, the ball 0, and outside the circle the scanner
    # reconstructs one value (DICOM's pixel padding). Before, that value was the background: the
    # level fell below the air and the whole field of view came out as the product (+600 % and more)
    n = 80
    ball = sphere_distance(n, (39.5, 40.2, 39.7), 18.0)
    values = ct(ball, noise=20.0, dtype=np.int16).astype(np.int32) - 1000
    u = np.arange(n) - (n - 1) / 2.0
    outside = np.hypot(u[:, None], u[None, :]) > n / 2.0
    values[outside] = padding
    ext = extract_surface(values.astype(np.int16))
    assert ext.levels.padding == padding
    assert ext.levels.background == pytest.approx(-1000.0, abs=5.0)
    assert f"{padding}" in ext.levels.explain()
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 18.0**3, rel=0.005)


def test_an_air_all_one_value_is_the_background_not_padding():
    # air set to 0 (a noiseless volume, or one whose air was removed): the edge's partial volumes
    # beside it are no background of their own
    ext = extract_surface(ct(sphere_distance(48, (23.5, 23.5, 23.5), 16.0)))
    assert not np.isfinite(ext.levels.padding) and ext.levels.background == pytest.approx(0.0, abs=1.0)
    assert ext.volume == pytest.approx(4 / 3 * np.pi * 16.0**3, rel=0.005)


def test_a_level_kept_off_the_integers_downwards_gives_no_note_about_slices():
    # an integer volume's level within 0.05 below an integer is meshed a little lower; that is
    # not the lower level of a peel thinner than a slice (before: "across the slices the outermost
    # tissue reaches only nan ... decided at 500")
    data = ct(sphere_distance(40, (19.5, 19.5, 19.5), 12.0), noise=5.0, dtype=np.int16)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtractionWarning)
        ext = extract_surface(data, level=499.97)
    assert ext.warnings == () and ext.levels.level == 499.97


def test_a_real_kiwi_mri_as_the_scanner_wrote_it(tmp_path):
    """128 extensionless DICOM slices of a 7 T MRI (tests/data/kiwi-mri, MIT licence): found by content,
    read with the voxel size of their headers, and its surface closed, genus 0 and within 5 % of the
    75.0 mL a hand-drawn whole-fruit mask holds."""
    from pathlib import Path

    pytest.importorskip("pydicom")
    folder = Path(__file__).parent / "data" / "kiwi-mri"
    results = extract_files([folder], tmp_path, picture=False)  # the folder with its SOURCE.md and LICENSE
    assert [r.name for r in results] == ["dicom"] and results[0].ok, results[0].error
    log = json.loads((tmp_path / "dicom.json").read_text())
    assert log["units"]["spacing_mm"] == [0.234375, 0.234375, 0.5]
    assert log["units"]["spacing_source"] == "DICOM PixelSpacing and ImagePositionPatient"
    assert log["genus"] == 0
    mesh = read_mesh(tmp_path / "dicom.ply")
    check_closed_surface(mesh)
    assert abs(signed_volume(mesh.vertices, mesh.faces)) / 1000 == pytest.approx(75.0, rel=0.05)
