"""
The Python API, end to end
==========================

Every command is a few lines over a public function, so a script, a notebook or another tool can do
what the command line does and keep the results as arrays: scans to a model
(:func:`hortishape.pipeline.build_model`), its quality (:func:`hortishape.evaluate.evaluate_model`),
new shapes (:class:`hortishape.model.ShapeModel`) and CAD
(:class:`hortishape.cad.BSplineModel`, :func:`hortishape.cad.write_cad`).
"""

# %%
# Scans with their ground truth
# -----------------------------
# :func:`hortishape.synth.write_population` writes each synthetic pepper as a PLY in a random
# scanner pose, with its true landmarks (stalk tip, bottom) beside it in ``<stem>.truth.json``.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from hortishape import synth
from hortishape.cad import BSplineModel, find_poles, write_cad
from hortishape.evaluate import evaluate_model
from hortishape.model import ShapeModel
from hortishape.pipeline import build_model

work = Path(tempfile.mkdtemp())
synth.write_population("pepper", 8, work / "scans", random_state=600, pose="random", n_vertices=30000)

# %%
# The model
# ---------
result = build_model(work / "scans", work / "model", n_points=3000)
print(f"{len(result.names)} scans, {len(result.explained_variance)} modes, {result.seconds:.0f} s")
print("scans whose orientation the build is unsure of:", result.uncertain_orientation or "none")

model = ShapeModel.load(result.model_path)
print("mean:", model.mean_.shape, "modes:", model.components_.shape)

# %%
# Its quality
# -----------
# The landmarks beside the scans are found by themselves: each is marked on the mean, carried to
# every pepper through the correspondence and compared with where it truly is.
evaluation = evaluate_model(work / "model", n_samples=50)
g = evaluation.generalization
fig, ax = plt.subplots(figsize=(5, 3.5))
ax.errorbar(g.modes, g.mean_mm, yerr=g.se_mm, marker="o")
ax.set_xlabel("modes m")
ax.set_ylabel("generalization G(m), mm")
ax.set_title("leave-one-out: a model of the others describing each pepper")
errors = evaluation.landmarks.errors_mm
for name, column in zip(evaluation.landmarks.names, errors.T):
    print(f"{name}: {column.mean():.2f} mm on average, at most {column.max():.2f} mm")

# %%
# New peppers and CAD
# -------------------
new = model.sample(3, random_state=0)
print(new.shape, "(3 new peppers, their points in mm)")

cad = BSplineModel(16, poles=find_poles(model.mean_, model.faces_)).fit(model)
surface = cad.instance([2.0])  # the mean moved +2 SD along the first mode
write_cad(work / "pepper_mode1_plus2sd.json", surface)
print("control points:", surface.control_points.shape)
