"""Building a model from a folder: two passes, Procrustes, PCA, files, bad scans, resume."""

import json
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest

from hortishape import synth
from hortishape.cli import main
from hortishape.errors import HortishapeError
from hortishape.io import read_mesh, write_mesh
from hortishape.model import ShapeModel
from hortishape.pipeline import build_model, check_scans, choose_reference, fit_scan, update_model
from hortishape.registration import RegistrationConfig

CONFIG = RegistrationConfig(n_iterations=12)


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scans")
    synth.write_population("apple", 5, folder, random_state=11, pose="upright", n_vertices=10000, n_jobs=1)
    # one corrupt file among them: a PLY cut short
    data = (folder / "apple_004.ply").read_bytes()
    (folder / "apple_004.ply").write_bytes(data[: len(data) // 3])
    return folder


@pytest.fixture(scope="module")
def built(scans, tmp_path_factory):
    out = tmp_path_factory.mktemp("model")
    return build_model(scans, out, n_points=2000, config=CONFIG, n_jobs=2)


def test_builds_from_the_good_scans_and_reports_the_bad_one(built, scans):
    assert built.names == ("apple_000", "apple_001", "apple_002", "apple_003")
    assert len(built.skipped) == 1 and "apple_004.ply" in built.skipped[0][0]
    summary = json.loads((built.out_dir / "summary.json").read_text())
    assert summary["instances"] == list(built.names)
    assert summary["skipped"][0]["path"].endswith("apple_004.ply")
    assert len(summary["second_pass"]) == 4
    assert summary["model"]["n_modes"] == 3  # N - 1 modes
    assert summary["units"]["unit"] == "mm" and summary["units"]["scale"] == 1.0
    # every first-pass search has a confidence; those below the threshold are named
    from hortishape.pipeline import UNCERTAIN_CONFIDENCE

    confidences = {r["name"]: r["orientation_confidence"] for r in summary["first_pass"]}
    assert all(c is not None and c <= 1.0 for c in confidences.values())
    assert summary["uncertain_orientation"] == [
        {"name": n, "confidence": c} for n, c in confidences.items()
        if n in built.names and c < UNCERTAIN_CONFIDENCE]
    assert built.uncertain_orientation == tuple((u["name"], u["confidence"]) for u in summary["uncertain_orientation"])
    assert all(60 < e < 120 for e in summary["units"]["extent_mm"].values())  # apples, mm


def test_writes_corresponded_and_aligned_surfaces(built, scans):
    faces = None
    for name in built.names:
        reg = read_mesh(built.out_dir / "registered" / f"{name}.ply")
        aligned = read_mesh(built.out_dir / "aligned" / f"{name}.ply")
        faces = reg.faces if faces is None else faces
        np.testing.assert_array_equal(reg.faces, faces)  # same faces for all
        np.testing.assert_array_equal(aligned.faces, faces)
        # registered surfaces are in each scan's own coordinates: their centroids within 1.8 mm of
        # the scan's (its vertices are spread otherwise), where the scans' own lie 16-50 mm apart
        # and from the origin
        scan = read_mesh(scans / f"{name}.ply")
        assert np.linalg.norm(reg.vertices.mean(0) - scan.vertices.mean(0)) < 5.0


def test_model_file_holds_the_model(built):
    model = ShapeModel.load(built.model_path)
    assert model.n_samples_ == 4
    np.testing.assert_allclose(model.explained_variance_, built.explained_variance, rtol=1e-6)
    with h5py.File(built.model_path) as f:
        assert f["version/majorVersion"][()] == 0 and f["version/minorVersion"][()] == 9
        assert f["model/pcaBasis"].shape[1] == 3


def test_second_pass_uses_the_mean_as_template(built):
    first = json.loads((built.out_dir / "work" / "first-pass" / "apple_000.json").read_text())
    second = json.loads((built.out_dir / "registered" / "apple_000.json").read_text())
    assert first["fingerprint"] != second["fingerprint"]


def test_rebuild_resumes_finished_registrations(built, scans):
    again = build_model(scans, built.out_dir, n_points=2000, config=CONFIG, n_jobs=2)
    assert all(r.resumed for r in again.first_pass if r.ok)
    assert all(r.resumed for r in again.second_pass if r.ok)
    np.testing.assert_allclose(again.explained_variance, built.explained_variance)


def test_strict_stops_at_the_bad_scan(scans, tmp_path):
    with pytest.raises(HortishapeError, match="apple_004.ply"):
        build_model(scans, tmp_path, n_points=2000, config=CONFIG, strict=True)


def test_too_few_scans(tmp_path, scans):
    for name in ("apple_000", "apple_001"):
        (tmp_path / f"{name}.ply").write_bytes((scans / f"{name}.ply").read_bytes())
    with pytest.raises(HortishapeError, match="at least 3"):
        build_model(tmp_path, tmp_path / "out", n_points=2000, config=CONFIG)


def test_wrong_units_and_reference_choice(scans, tmp_path):
    paths = [scans / f"apple_00{i}.ply" for i in range(4)]
    m = read_mesh(paths[0])
    metres = write_mesh(tmp_path / "metres.ply", m.vertices / 1000.0, m.faces)
    checks = check_scans([*paths, metres])
    assert [c.ok for c in checks] == [True, True, True, True, False]
    assert "metres" in checks[-1].error and "metres.ply" in checks[-1].error
    # of four, the smaller of the two in the middle, whatever the rounding of their sizes: their
    # distances to the median (the mean of the two) were equal, and a 1e-9 mm jitter of the
    # scans chose the other one (another build, another model)
    sizes = [c.size for c in checks[:4]]
    lower_middle = str(paths[int(np.argsort(sizes)[1])])
    assert choose_reference(checks) == lower_middle
    for nudge in (1 + 1e-15, 1 - 1e-15):
        for k in range(4):
            nudged = [replace(c, size=c.size * nudge) if i == k else c for i, c in enumerate(checks)]
            assert choose_reference(nudged) == lower_middle


def test_a_scan_with_holes_is_checked_closed_and_not_chosen_as_reference(scans, tmp_path):
    paths = [scans / f"apple_00{i}.ply" for i in range(3)]
    import trimesh

    m = read_mesh(paths[0])
    centres = m.vertices[m.faces].mean(axis=1)
    side = centres[:, 0] > np.quantile(centres[:, 0], 0.97)  # a cap of about 3 % of the faces, on a side
    cut = trimesh.Trimesh(m.vertices, m.faces[~side], process=False)
    cut.remove_unreferenced_vertices()
    holed = write_mesh(tmp_path / "holed.ply", cut.vertices, cut.faces)
    checks = check_scans([holed, *paths])
    assert all(c.ok for c in checks) and checks[0].holes == 1 and 0.0 < checks[0].hole_share < 0.1
    assert checks[0].size == pytest.approx(checks[1].size, rel=0.01)  # the size of the scan closed
    # the holed scan's size is made the median's: it is still not the reference
    checks[0] = replace(checks[0], size=float(np.median([c.size for c in checks])))
    assert choose_reference(checks) != str(holed)


def test_fit_scan_describes_a_model_instance(built, scans):
    model = ShapeModel.load(built.model_path)
    # apple_000, the build's reference: fit_scan's orientation search on the
    # mean of these four 10k-vertex apples turns apple_001-003 the wrong way
    # (measured 21-38 mm dense error against the synthetic truth, with the
    # rigid search as with the affine one), and their fits then say little
    scan = read_mesh(scans / "apple_000.ply")
    fit = fit_scan(model, scan, config=CONFIG)
    assert fit.reconstruction.shape == (model.n_points_, 3)
    assert fit.surface_mean < 1.0  # a training shape is described closely
    assert fit.mahalanobis < 3.0


@pytest.mark.slow
def test_cli_build_sample_modes_fit(built, scans, tmp_path, capsys):
    out = tmp_path / "m"
    assert main(["build", str(scans), "--out", str(out), "--points", "2000", "--iterations", "12",
                 "--modes", "2"]) == 0
    printed = capsys.readouterr().out
    assert "apple_004" in printed and "model: 4 instances, 2 modes" in printed
    model_path = out / "model.h5"
    assert main(["sample", str(model_path), "3", "--out", str(tmp_path / "s"), "--seed", "1"]) == 0
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == [
        "sample_000.ply", "sample_001.ply", "sample_002.ply", "samples.png"]
    assert main(["modes", str(model_path), "--out", str(tmp_path / "modes"), "--modes", "2"]) == 0
    assert (tmp_path / "modes" / "modes.png").is_file() and (tmp_path / "modes" / "mode2_plus3sd.ply").is_file()
    assert main(["fit", str(model_path), str(scans / "apple_002.ply"), "--out", str(tmp_path / "fit.ply"),
                 "--json", str(tmp_path / "fit.json"), "--iterations", "12"]) == 0
    figures = json.loads((tmp_path / "fit.json").read_text())
    assert len(figures["coefficients_sd"]) == 2 and figures["surface_mean_mm"] < 1.5
    assert read_mesh(tmp_path / "fit.ply").n_vertices == 2000


def test_cli_build_of_a_missing_folder_is_one_line(tmp_path, capsys):
    assert main(["build", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 1
    assert "not a folder" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_build_with_landmarks(scans, tmp_path, capsys):
    # the ground truth beside the scans names stalk_tip and bottom on each
    out = tmp_path / "m"
    assert main(["build", str(scans), "--out", str(out), "--points", "2000", "--iterations", "12",
                 "--landmarks", str(scans)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    names = summary["instances"]
    for folder in (out / "work" / "first-pass", out / "registered"):
        for name in names:
            assert json.loads((folder / f"{name}.json").read_text())["landmarks"] == ["bottom", "stalk_tip"]
    # in both passes the vertex nearest the reference's calyx mark is pulled onto each scan's
    ref = summary["reference"].rsplit("/", 1)[-1][: -len(".ply")]
    from hortishape.registration import prepare_reference

    ref_bottom = json.loads((scans / f"{ref}.truth.json").read_text())["landmarks"]["bottom"]
    template = prepare_reference(read_mesh(scans / f"{ref}.ply"), 2000)
    j = int(np.argmin(np.linalg.norm(template.mesh.vertices - ref_bottom, axis=1)))
    for name in names:
        bottom = json.loads((scans / f"{name}.truth.json").read_text())["landmarks"]["bottom"]
        assert np.linalg.norm(read_mesh(out / "registered" / f"{name}.ply").vertices[j] - bottom) < 0.5
    capsys.readouterr()
    marks = tmp_path / "marks.json"
    marks.write_text(json.dumps({"apple_001": {"stalk": [0, 0, 0]}}))
    assert main(["build", str(scans), "--out", str(tmp_path / "n"), "--points", "2000", "--reference",
                 str(scans / "apple_000.ply"), "--landmarks", str(marks)]) == 1
    assert "no landmarks for the reference apple_000" in capsys.readouterr().err


# -------------------------------------------------------------------- adding scans to a built model


def _digests(folder):
    import hashlib

    return {p.relative_to(folder): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.slow
def test_update_adds_scans_without_redoing_the_model_and_equals_a_full_build(built, scans, tmp_path, capsys):
    new = tmp_path / "new"
    synth.write_population("apple", 3, new, random_state=12, pose="upright", n_vertices=10000, n_jobs=1)
    for i, p in enumerate(sorted(new.glob("apple_*"))):  # names of their own (synth numbers from 000)
        p.rename(new / p.name.replace("apple_", f"new_{i}_"))
    before = _digests(built.out_dir)
    out = tmp_path / "updated"
    assert main(["update", str(built.out_dir), str(new), "--out", str(out), "--iterations", "12"]) == 0
    printed = capsys.readouterr().out
    assert "model: 7 instances, 6 modes; the mean moved" in printed
    assert _digests(built.out_dir) == before  # the model folder is not changed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["update"]["earlier"] == list(built.names) and len(summary["update"]["added"]) == 3
    for name in built.names:  # the earlier registrations copied as they were
        assert (out / "registered" / f"{name}.ply").read_bytes() == (built.out_dir / "registered" / f"{name}.ply").read_bytes()
    # a build of all seven from the same reference gives the same model, up to the registrations' template
    everything = tmp_path / "all"
    everything.mkdir()
    for p in [*(Path(scans) / f"{n}.ply" for n in built.names), *new.glob("*.ply")]:
        (everything / p.name).write_bytes(p.read_bytes())
    full = build_model(everything, tmp_path / "full", n_points=2000, config=CONFIG, n_jobs=2,
                       reference=everything / Path(built.reference).name)
    a, b = ShapeModel.load(out / "model.h5"), ShapeModel.load(full.model_path)
    from hortishape.procrustes import procrustes_align

    moved, _ = procrustes_align(a.mean_, b.mean_)
    assert np.sqrt(((moved - b.mean_) ** 2).sum(axis=1).mean()) < 0.2  # mm
    assert a._total_variance == pytest.approx(b._total_variance, rel=0.05)
    # the same folder again, a name already in the model, not a model folder
    with pytest.raises(HortishapeError, match="a folder of its own"):
        update_model(built.out_dir, new, built.out_dir)
    with pytest.raises(HortishapeError, match="not a built model folder"):
        update_model(new, new, tmp_path / "x")
    clash = tmp_path / "clash"
    clash.mkdir()
    (clash / "apple_000.ply").write_bytes((Path(scans) / "apple_000.ply").read_bytes())
    with pytest.raises(HortishapeError, match="already in the model"):
        update_model(built.out_dir, clash, tmp_path / "y", config=CONFIG)


@pytest.mark.slow
def test_six_apples_as_extensionless_dicom_series_in_study_folders_build_the_model_of_their_mha(tmp_path, capsys):
    """As a CT scanner exports them: one series per apple, generic folder names in two study folders, the
    operator's name of each apple as its SeriesDescription, a localizer and a note beside them."""
    pytest.importorskip("pydicom")
    from scanner_files import ROOT, write_dicom_series

    from hortishape.io import Volume, write_volume

    pop = [synth.make_instance("apple", random_state=s, n_vertices=8000, volume=True, name=f"apple_{k}")
           for k, s in enumerate(np.random.SeedSequence(61).spawn(6))]
    mha, dicom = tmp_path / "mha", tmp_path / "dicom"
    mha.mkdir()
    for k, inst in enumerate(pop):
        # a geometry DICOM's 16-character decimal strings hold exactly, so that both files say the same
        vol = Volume(inst.volume.data, np.round(inst.volume.spacing, 9), np.round(inst.volume.origin, 4))
        write_volume(mha / f"{inst.name}.mha", vol)
        study = dicom / "DICOM" / f"STU{k // 3:05d}"
        write_dicom_series(study / f"SER{k % 3:05d}", vol.data, spacing=vol.spacing, origin=vol.origin,
                           series_uid=ROOT + f"60.{k}", description=inst.name, number=k % 3 + 1,
                           study_uid=ROOT + f"6.{k // 3}")
    write_dicom_series(dicom / "DICOM" / "STU00000" / "SCOUT", pop[0].volume.data[:, :, :1],
                       series_uid=ROOT + "60.99", description="localizer")
    (dicom / "notes.txt").write_text("six apples, 7 December")
    config = RegistrationConfig(n_iterations=6)
    from_mha = build_model(mha, tmp_path / "m1", n_points=800, config=config, n_jobs=2)
    assert main(["build", str(dicom), "--out", str(tmp_path / "m2"), "--points", "800", "--iterations", "6"]) == 0
    out = capsys.readouterr().out
    assert f"passed over {dicom / 'notes.txt'}: not a mesh, a volume or a DICOM file" in out
    assert "a DICOM series of one slice (localizer)" in out
    a, b = ShapeModel.load(from_mha.model_path), ShapeModel.load(tmp_path / "m2" / "model.h5")
    summary = json.loads((tmp_path / "m2" / "summary.json").read_text())
    assert summary["instances"] == list(from_mha.names) == [f"apple_{k}" for k in range(6)]
    # the same voxels and geometry: the same surfaces, the same model
    for name in from_mha.names:
        np.testing.assert_array_equal(read_mesh(tmp_path / "m2" / "surfaces" / f"{name}.ply").vertices,
                                      read_mesh(tmp_path / "m1" / "surfaces" / f"{name}.ply").vertices)
    np.testing.assert_allclose(b.mean_, a.mean_, atol=1e-9)
    np.testing.assert_allclose(b.explained_variance_, a.explained_variance_, rtol=1e-9)
