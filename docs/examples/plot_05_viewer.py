"""
The model in a browser
======================

``hortishape view`` writes one self-contained HTML page: the mean shape in 3D with a slider per
mode, each moving the shape between -3 and +3 standard deviations, computed in the page. It needs no
server and no network (plotly.js is embedded), so it can be mailed or put on a shared drive.
``hortishape evaluate`` writes one beside its report, with the error map as a colouring.
"""

# %%
# A small model of bananas
# ------------------------
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from hortishape import synth
from hortishape.cli import main as hortishape
from hortishape.model import ShapeModel
from hortishape.surface import barycentric_interpolate, remesh
from hortishape.view import view_model

work = Path(tempfile.mkdtemp())
bananas = synth.make_population("banana", 10, random_state=500, n_vertices=20000)
first = remesh(bananas[0].mesh, 3000)
canonical = barycentric_interpolate(bananas[0].canonical, bananas[0].mesh.faces, first.face_index,
                                    first.barycentric)
model = ShapeModel(procrustes=True).fit([synth.true_correspondence(canonical, b) for b in bananas],
                                        first.mesh.faces)
model.save(work / "bananas.h5")

# %%
# The page
# --------
# From the command line, ``hortishape view bananas.h5 --out bananas.html``; from Python,
# :func:`hortishape.view.view_model`:
page = view_model(work / "bananas.h5", work / "bananas.html", n_modes=5)
print(f"{page.path.name}: {page.size_bytes / 1e6:.1f} MB, {page.n_modes} modes")

# %%
# Open it in a browser. The state of the sliders is kept in the address (``#b=...``), so a shape
# can be shared as a link. It looks like this (an apple model):
#
# .. image:: ../images/viewer.png
#    :alt: The viewer: the mean apple in 3D, a slider per mode on the left
#
# What the sliders do, drawn here as ``hortishape modes`` draws it (mean and +/- 3 SD of the
# first three modes):
hortishape(["modes", str(work / "bananas.h5"), "--out", str(work / "modes")])
fig, ax = plt.subplots(figsize=(9, 6))
ax.imshow(plt.imread(work / "modes" / "modes.png"))
ax.set_axis_off()
