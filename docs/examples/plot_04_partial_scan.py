"""
The volume of a fruit seen from one side
========================================

A depth camera over a sorting line sees each apple from above only. A shape model of the
population completes the unseen side: ``hortishape fit --partial`` (or
:func:`hortishape.fit_partial`) finds the pose and the shape coefficients that explain the points,
and reports the whole fruit's volume with a standard deviation from the model's uncertainty about
what was not seen.
"""

# %%
# A model of twelve apples
# ------------------------
# For this tutorial the model is built from synthetic apples in their true correspondence (a
# 3,000-vertex reference on the first apple, carried to every other one by the generator's ground
# truth), which takes seconds; a model that ``hortishape build`` made from scans is used the same
# way.
import json
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from hortishape import synth
from hortishape.cli import main as hortishape
from hortishape.io import write_points
from hortishape.model import ShapeModel
from hortishape.surface import barycentric_interpolate, remesh, signed_volume

work = Path(tempfile.mkdtemp())
apples = synth.make_population("apple", 12, random_state=400, n_vertices=20000)
first = remesh(apples[0].mesh, 3000)
canonical = barycentric_interpolate(apples[0].canonical, apples[0].mesh.faces, first.face_index, first.barycentric)
shapes = [synth.true_correspondence(canonical, apple) for apple in apples]
model = ShapeModel(procrustes=True).fit(shapes, first.mesh.faces)
model.save(work / "model.h5")
print(model.n_components_, "modes")

# %%
# One apple the model has not seen, from above
# --------------------------------------------
# :func:`hortishape.synth.depth_view` gives the points an orthographic depth camera sees of a
# surface: the first hits of parallel rays, with 0.2 mm of depth noise.
apple = synth.make_instance("apple", random_state=499, n_vertices=20000)
view = synth.depth_view(apple.mesh, [0.0, 0.0, -1.0], pitch=1.0, noise=0.2, random_state=0)
write_points(work / "seen.ply", view.points, normals=view.normals)
print(len(view.points), "points seen")

fig = plt.figure(figsize=(5, 4))
ax = fig.add_subplot(projection="3d")
ax.scatter(*view.points[::5].T, s=1, c=view.points[::5, 2], cmap="viridis")
ax.set_title("what the camera saw")

# %%
# The whole apple and its volume
# ------------------------------
hortishape(["fit", str(work / "model.h5"), str(work / "seen.ply"), "--partial", "--out", str(work / "fit"),
            "--seed", "0"])

result = json.loads(next((work / "fit").glob("*.json")).read_text())
true_ml = signed_volume(apple.mesh.vertices, apple.mesh.faces) / 1000.0
print(f"volume {result['volume_ml']:.1f} +/- {result['volume_sd_ml']:.1f} mL; the apple's true volume {true_ml:.1f} mL")

# %%
# Twelve training apples make a rough model: the unseen side is the model's guess, and the reported
# SD says how rough. The picture ``fit`` writes shows the completed surface coloured by that SD,
# with the points it saw:
fig, ax = plt.subplots(figsize=(9, 4))
ax.imshow(plt.imread(work / "fit" / "seen.png"))
ax.set_axis_off()
