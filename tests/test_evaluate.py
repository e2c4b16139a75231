"""Evaluating a built model directory: measures, error map, landmarks, files, report, command line."""

import json
import shutil

import numpy as np
import pytest

from hortishape import synth
from hortishape.cli import main
from hortishape.errors import HortishapeError
from hortishape.evaluate import evaluate_model, read_landmarks
from hortishape.io import read_mesh, read_mesh_data, write_mesh
from hortishape.mesh import Mesh
from hortishape.model import ShapeModel
from hortishape.procrustes import generalized_procrustes
from hortishape.report import write_evaluation
from hortishape.surface import barycentric_interpolate, remesh

N = 5


def write_truth_model(root, *, n=N, n_vertices=3000, n_points=1200, seed=3):
    """A model directory as 'hortishape build' writes it, with the generator's true correspondence.

    The reference is instance 0 remeshed to ``n_points`` vertices; its canonical
    coordinates, carried to every instance by ``synth.true_correspondence``,
    give the registered surfaces (exactly on each scan).
    """
    scans, out = root / "scans", root / "model"
    synth.write_population("apple", n, scans, random_state=seed, n_vertices=n_vertices, n_jobs=1)
    names = [f"apple_{i:03d}" for i in range(n)]
    meshes = [read_mesh(scans / f"{nm}.ply") for nm in names]
    truths = [synth.read_truth(scans / f"{nm}.ply") for nm in names]
    ref = remesh(meshes[0], n_points)
    canon = barycentric_interpolate(truths[0]["canonical"], meshes[0].faces, ref.face_index, ref.barycentric)
    faces = ref.mesh.faces
    registered = []
    for mesh, truth in zip(meshes, truths):
        inst = type("Instance", (), {"mesh": mesh, "canonical": truth["canonical"]})
        registered.append(synth.true_correspondence(canon, inst))
    gpa = generalized_procrustes(np.stack(registered))
    for sub in ("registered", "aligned"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for nm, r, a in zip(names, registered, gpa.aligned):
        write_mesh(out / "registered" / f"{nm}.ply", r, faces)
        write_mesh(out / "aligned" / f"{nm}.ply", a, faces)
    ShapeModel().fit(gpa.aligned, faces, names=names).save(out / "model.h5")
    summary = {
        "units": "mm", "input_dir": str(scans), "instances": names, "procrustes": {"scaling": False},
        "second_pass": [{"name": nm, "source": str(scans / f"{nm}.ply"), "ok": True} for nm in names],
    }
    (out / "summary.json").write_text(json.dumps(summary))
    return out, scans, np.stack(registered), faces


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    return write_truth_model(tmp_path_factory.mktemp("truth"))


@pytest.fixture(scope="module")
def evaluated(built):
    out, *_ = built
    return evaluate_model(out, n_samples=20, random_state=0)


def test_measures_and_their_files(built, evaluated):
    out, scans, registered, faces = built
    ev = evaluated
    assert ev.names == tuple(f"apple_{i:03d}" for i in range(N))
    assert ev.modes.tolist() == [1, 2, 3]  # N - 2: what a leave-one-out model of N shapes has
    assert np.all(np.diff(ev.compactness.ratio) > 0) and ev.compactness.ratio[-1] <= 1.0
    assert np.all(np.diff(ev.generalization.mean_sq) <= 0)
    assert np.all(ev.specificity.mean_mm > 0)
    # the registered surfaces lie on their scans: zero geometric error
    assert ev.geometric_error.names == ev.names
    assert ev.geometric_error.mean_mm < 1e-6 and ev.geometric_error.per_vertex_mm.shape == (len(registered[0]),)
    # the generator's landmarks beside the scans were found and transferred
    assert ev.landmarks is not None and ev.landmarks.names == ("bottom", "stalk_tip")
    assert str(scans) in ev.landmarks_source
    assert np.isfinite(ev.landmarks.errors_mm).all()
    assert ev.landmarks.errors_mm[:, 0].max() < 2.0  # the bottom (a 3,000-vertex scan barely shows the stalk)
    # dimensions near the generator's (body, stalk excluded)
    truth = np.array([list(json.loads((scans / f"{nm}.truth.json").read_text())["dimensions_mm"].values())
                      for nm in ev.names])
    np.testing.assert_allclose(np.sort(ev.dimensions.per_shape[:, :2], axis=1), np.sort(truth[:, :2], axis=1), atol=1.5)
    np.testing.assert_allclose(ev.dimensions.per_shape[:, 2], truth[:, 2], atol=3.0)
    assert np.all(ev.dimensions.overall_height >= ev.dimensions.per_shape[:, 2])

    folder = out / "evaluation"
    metrics = json.loads((folder / "metrics.json").read_text())
    for key in ("compactness", "generalization_mm", "generalization_se_mm", "specificity_mm", "specificity_se_mm",
                "generalization_sq", "specificity_sq"):
        assert len(metrics[key]) == len(metrics["modes"]) == 3, key
    assert metrics["modes"] == [1, 2, 3]
    assert metrics["generalization_mm"] == pytest.approx(ev.generalization.mean_mm.tolist())
    assert metrics["compactness"] == pytest.approx(ev.compactness.ratio.tolist())
    assert metrics["landmarks"]["names"] == ["bottom", "stalk_tip"]
    lines = (folder / "metrics.csv").read_text().splitlines()
    assert lines[0].startswith("modes,compactness,") and "generalization_sq" in lines[0] and len(lines) == 4
    assert float(lines[1].split(",")[3]) == pytest.approx(ev.generalization.mean_mm[0], rel=1e-6)
    # the error map: colours and the distances per vertex
    data = read_mesh_data(folder / "error_map.ply")
    assert data.vertex_colors.shape == (len(registered[0]), 3)
    np.testing.assert_allclose(data.vertex_scalars["error_mm"], ev.geometric_error.per_vertex_mm)
    np.testing.assert_array_equal(data.mesh.faces, faces)
    for name in ("compactness", "generalization", "specificity", "error_map", "landmarks", "modes", "samples"):
        assert (folder / f"{name}.png").stat().st_size > 1000, name
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]  # nothing half-written


def test_shapes_in_memory_give_the_directory_figures_and_write_only_through_report(built, evaluated, tmp_path):
    from hortishape.evaluate import evaluate_shapes

    out, scans, registered, faces = built
    model = ShapeModel.load(out / "model.h5")
    aligned = np.stack([read_mesh(out / "aligned" / f"{n}.ply").vertices for n in evaluated.names])
    before = sorted(p.name for p in tmp_path.iterdir())
    ev = evaluate_shapes(model, registered, aligned, faces, names=evaluated.names,
                         scans=[scans / f"{n}.ply" for n in evaluated.names], n_samples=20, random_state=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == before and ev.files == {} and ev.model_dir is None
    np.testing.assert_array_equal(ev.generalization.mean_sq, evaluated.generalization.mean_sq)
    np.testing.assert_array_equal(ev.specificity.mean_mm, evaluated.specificity.mean_mm)
    np.testing.assert_array_equal(ev.geometric_error.per_vertex_mm, evaluated.geometric_error.per_vertex_mm)
    np.testing.assert_array_equal(ev.dimensions.per_shape, evaluated.dimensions.per_shape)
    written = write_evaluation(ev, model, faces, tmp_path / "evaluation")
    assert written.files["report"].is_file() and "(in memory)" in written.files["report"].read_text()
    assert json.loads(written.files["metrics_json"].read_text())["model_dir"] is None
    with pytest.raises(HortishapeError, match="at most 3"):
        evaluate_shapes(model, registered, aligned, faces, names=evaluated.names, modes=4)
    with pytest.raises(HortishapeError, match="registered shapes have shape"):
        evaluate_shapes(model, registered[:, :10], aligned, faces, names=evaluated.names)


def test_without_plotly_the_report_says_how_to_get_the_viewer(evaluated, tmp_path, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "plotly" else real(name, *a))
    model = ShapeModel.load(evaluated.model_dir / "model.h5")
    written = write_evaluation(evaluated, model, model.faces_, tmp_path / "evaluation")
    assert "viewer" not in written.files and not (tmp_path / "evaluation" / "viewer.html").exists()
    assert 'pip install "hortishape[view]"' in written.files["report"].read_text(encoding="utf-8")


def test_report_is_one_self_contained_page(evaluated):
    html = evaluated.files["report"].read_text()
    assert html.startswith("<!DOCTYPE html>") and html.rstrip().endswith("</html>")
    assert "http://" not in html and "https://" not in html and "<script" not in html
    srcs = html.count('src="')
    assert srcs == html.count('src="data:image/png;base64,') == 7  # every picture embedded
    # the model in a browser, beside it, with the error map and the landmarks
    viewer = evaluated.files["viewer"]
    assert viewer.name == "viewer.html" and 'href="viewer.html"' in html
    page = viewer.read_text(encoding="utf-8")
    assert '"error":{"dtype":"float32"' in page and "stalk_tip" in page
    for words in ("Compactness (Fig. 10)", "Generalization (Fig. 11)", "Specificity (Fig. 12)", "eq. 15",
                  "Geometric error (Fig. 6, Table 2)", "Landmarks (Table 3)", "Population dimensions (Table 1)",
                  "per vertex (mm)", "stalk_tip"):
        assert words in html, words


def test_landmarks_on_the_surface_transfer_without_error(built, tmp_path):
    """Landmarks given exactly at one reference vertex of every (truly corresponded) instance."""
    out, _, registered, _ = built
    marks = {f"apple_{i:03d}": {"v10": registered[i, 10].tolist(), "v500": registered[i, 500].tolist()}
             for i in range(N)}
    path = tmp_path / "marks.json"
    path.write_text(json.dumps(marks))
    ev = evaluate_model(out, landmarks=path, modes=2, n_samples=10, write=False)
    assert ev.landmarks.names == ("v10", "v500")
    np.testing.assert_allclose(ev.landmarks.errors_mm, 0.0, atol=1e-9)
    # the same as CSV, one instance left out
    rows = ["instance,landmark,x,y,z"] + [f"{nm},v10,{x},{y},{z}" for nm, m in marks.items() if nm != "apple_001"
                                         for x, y, z in [m["v10"]]]
    (tmp_path / "marks.csv").write_text("\n".join(rows) + "\n")
    ev = evaluate_model(out, landmarks=tmp_path / "marks.csv", modes=1, n_samples=10, write=False)
    assert np.isnan(ev.landmarks.errors_mm[1, 0]) and np.nanmax(ev.landmarks.errors_mm) < 1e-9
    assert any("apple_001" in note for note in ev.notes)


def test_missing_scans_are_reported(built, tmp_path):
    out, scans, *_ = built
    moved = tmp_path / "moved"
    shutil.copytree(scans, moved)
    (moved / "apple_002.ply").unlink()
    ev = evaluate_model(out, scans=moved, modes=1, n_samples=10, write=False)
    assert ev.geometric_error.names == ("apple_000", "apple_001", "apple_003", "apple_004")
    assert any("apple_002" in note and "scan not found" in note for note in ev.notes)
    empty = tmp_path / "empty"
    empty.mkdir()
    ev = evaluate_model(out, scans=empty, modes=1, n_samples=10, write=False)
    assert ev.geometric_error is None and ev.landmarks is None
    assert any("geometric error map skipped" in note for note in ev.notes)


def test_read_landmarks_formats_and_errors(tmp_path):
    (tmp_path / "a.truth.json").write_text(json.dumps({"landmarks": {"tip": [1, 2, 3]}, "pose": []}))
    assert read_landmarks(tmp_path)["a"]["tip"].tolist() == [1.0, 2.0, 3.0]
    assert read_landmarks(tmp_path / "a.truth.json")["a"]["tip"].tolist() == [1.0, 2.0, 3.0]
    bad = tmp_path / "bad.csv"
    bad.write_text("instance,landmark,x,y,z\na,tip,1,2,oops\n")
    with pytest.raises(HortishapeError, match=r"bad.csv, row 2"):
        read_landmarks(bad)
    header = tmp_path / "header.csv"
    header.write_text("a,tip,1,2,3\n")
    with pytest.raises(HortishapeError, match="instance,landmark,x,y,z"):
        read_landmarks(header)
    with pytest.raises(HortishapeError, match="no such"):
        read_landmarks(tmp_path / "nope.json")
    (tmp_path / "two.json").write_text(json.dumps({"a": {"tip": [1, 2]}}))
    with pytest.raises(HortishapeError, match="two.json.*three"):
        read_landmarks(tmp_path / "two.json")


def test_landmark_files_saved_by_windows_tools_are_read(tmp_path):
    # Excel's "CSV UTF-8" and some editors start the file with a byte-order mark; names need not be ASCII
    (tmp_path / "excel.csv").write_bytes("instance,landmark,x,y,z\r\npomme_1,pédoncule,1,2,3\r\n".encode("utf-8-sig"))
    assert read_landmarks(tmp_path / "excel.csv")["pomme_1"]["pédoncule"].tolist() == [1.0, 2.0, 3.0]
    (tmp_path / "marks.json").write_bytes(json.dumps({"a": {"calice": [4, 5, 6]}}).encode("utf-8-sig"))
    assert read_landmarks(tmp_path / "marks.json")["a"]["calice"].tolist() == [4.0, 5.0, 6.0]


def test_bad_model_directories(built, tmp_path):
    out, *_ = built
    with pytest.raises(HortishapeError, match="not a built model directory"):
        evaluate_model(tmp_path, write=False)
    with pytest.raises(HortishapeError, match="a model file, not the folder.*training shapes"):
        evaluate_model(out / "model.h5", write=False)
    with pytest.raises(HortishapeError, match="at most 3"):
        evaluate_model(out, modes=4, write=False)
    broken = tmp_path / "broken"
    shutil.copytree(out, broken, ignore=shutil.ignore_patterns("evaluation"))
    write_mesh(broken / "registered" / "apple_003.ply", Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]))
    with pytest.raises(HortishapeError, match="apple_003.ply: does not correspond"):
        evaluate_model(broken, write=False)


def test_cli_evaluate(built, tmp_path, capsys):
    out, *_ = built
    marks = tmp_path / "marks.json"
    reg = read_mesh(out / "registered" / "apple_000.ply").vertices
    marks.write_text(json.dumps({"apple_000": {"v3": reg[3].tolist()}}))
    assert main(["evaluate", str(out), "--modes", "2", "--samples", "10", "--landmarks", str(marks)]) == 0
    printed = capsys.readouterr().out
    assert "C(m) %" in printed and "G eq.15" in printed and "landmark transfer error" in printed
    assert "report.html" in printed
    assert main(["evaluate", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a built model directory" in err
    assert main(["evaluate", str(out), "--modes", "9"]) == 1
    assert "at most 3" in capsys.readouterr().err


@pytest.mark.slow
def test_instances_of_uncertain_orientation_are_named_and_pictured(built, tmp_path):
    import shutil

    out, *_ = built
    copy = tmp_path / "model"
    shutil.copytree(out, copy, ignore=shutil.ignore_patterns("evaluation"))
    summary = json.loads((copy / "summary.json").read_text())
    summary["uncertain_orientation"] = [{"name": "apple_002", "confidence": 0.012},
                                        {"name": "not_in_the_model", "confidence": 0.001}]
    (copy / "summary.json").write_text(json.dumps(summary))
    ev = evaluate_model(copy, n_samples=10, random_state=0)
    assert ev.uncertain_orientation == (("apple_002", 0.012),)
    assert any("apple_002 (0.012)" in note for note in ev.notes)
    picture = ev.files["uncertain_png"]
    assert picture.name == "uncertain_orientation.png" and picture.stat().st_size > 1000
    page = ev.files["report"].read_text()
    assert 'id="orientation"' in page and "apple_002" in page
    # a build without uncertain instances: no picture, no section, and the old picture is removed
    summary["uncertain_orientation"] = []
    (copy / "summary.json").write_text(json.dumps(summary))
    ev = evaluate_model(copy, n_samples=10, random_state=0)
    assert "uncertain_png" not in ev.files and not picture.exists()
    assert 'id="orientation"' not in ev.files["report"].read_text()
