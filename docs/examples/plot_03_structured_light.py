"""
A model from structured-light meshes with holes, in metres
==========================================================

A structured-light or photogrammetry scanner gives a triangle mesh, not a volume. Such meshes are
often open where the scanner could not see (under the fruit, inside a stalk cavity) and are often
written in metres. ``build`` closes the holes for the registration's search (the elastic steps do
not use the patches) and ``--scale 1000`` turns metres into millimetres without touching the files.
"""

# %%
# Eight zucchini as open meshes in metres
# ---------------------------------------
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from hortishape import synth
from hortishape.cli import main as hortishape
from hortishape.io import write_mesh
from hortishape.mesh import Mesh

work = Path(tempfile.mkdtemp())
(work / "scans").mkdir()
for seed in range(8):
    z = synth.make_instance("zucchini", random_state=300 + seed, n_vertices=30000, holes=0.03, noise=0.05)
    in_metres = Mesh(z.mesh.vertices / 1000.0, z.mesh.faces)
    write_mesh(work / "scans" / f"zucchini_{seed + 1}.ply", in_metres)
print(sorted(p.name for p in (work / "scans").iterdir()))

# %%
# Without ``--scale`` every scan is refused for its size, by name (a zucchini is not 0.2 mm long):
import contextlib  # noqa: E402
import sys  # noqa: E402

with contextlib.redirect_stderr(sys.stdout):  # the error line, shown on this page
    status = hortishape(["build", str(work / "scans"), "--out", str(work / "refused"), "--points", "3000",
                         "--strict"])
print("exit status", status)

# %%
# With it:
hortishape(["build", str(work / "scans"), "--out", str(work / "model"), "--points", "3000",
            "--scale", "1000"])

# %%
# The first three modes, mean and +/- 3 SD, as ``hortishape modes`` draws them:
hortishape(["modes", str(work / "model" / "model.h5"), "--out", str(work / "modes")])
fig, ax = plt.subplots(figsize=(9, 6))
ax.imshow(plt.imread(work / "modes" / "modes.png"))
ax.set_axis_off()
