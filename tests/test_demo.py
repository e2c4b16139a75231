"""The demo end to end, small: every file it promises, and a model that knows its apples."""

import json

import pytest

from hortishape.cad import read_cad, surface_deviation
from hortishape.demo import run_demo
from hortishape.io import read_mesh
from hortishape.model import ShapeModel


@pytest.mark.slow
def test_small_demo_writes_everything_it_prints(tmp_path):
    r = run_demo(tmp_path / "demo", n=4, n_points=1000, n_jobs=1, seed=2)
    assert sorted(p.name for p in r.scans.glob("*.ply")) == [f"apple_{i:03d}.ply" for i in range(4)]
    model = ShapeModel.load(r.build.model_path)
    assert model.n_points_ == 1000 and r.build.names == tuple(f"apple_{i:03d}" for i in range(4))
    # five samples with the model's vertex order, and the mode pictures
    assert len(r.samples) == 5 and all(read_mesh(p).n_vertices == 1000 for p in r.samples)
    assert r.samples_picture.stat().st_size > 10_000 and r.modes_picture.stat().st_size > 10_000
    # the evaluation found the generator's landmarks beside the scans and measured on the scans
    ev = r.evaluation
    assert ev.landmarks is not None and ev.geometric_error is not None
    assert ev.geometric_error.mean_mm < 0.1
    metrics = json.loads((r.build.out_dir / "evaluation" / "metrics.json").read_text())
    assert metrics["n_instances"] == 4 and r.report.read_text().startswith("<!DOCTYPE html>")
    # the CAD mean (32 x 32 B-spline) lies on the model's mean surface (its largest gap at the thin stalk)
    surface = read_cad(next(p for p in r.cad if p.name == "mean.json"))
    deviation = surface_deviation(surface, model.mean_, model.faces_)
    assert deviation.mean < 0.2 and deviation.max < 5.0, (deviation.mean, deviation.max)
