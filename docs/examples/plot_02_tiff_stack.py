"""
A model from micro-CT TIFF stacks, with their voxel size
========================================================

Micro-CT reconstruction software writes a volume as a folder of 2D TIFF slices. TIFF has no voxel
size of its own: it is in OME or ImageJ metadata when the software writes them, or in the
scanner's log beside the slices (a Bruker SkyScan ``.log``, a Nikon ``.xtekct``). Without any of
them hortishape refuses the stack rather than guess, and names the option that sets it.
"""

# %%
# Five pears as folders of TIFF slices, with a SkyScan log
# ---------------------------------------------------------
import tempfile
from pathlib import Path

import numpy as np
import tifffile

from hortishape import VolumeError, synth
from hortishape.cli import main as hortishape
from hortishape.io import read_volume

work = Path(tempfile.mkdtemp())
for seed in range(5):
    pear = synth.make_instance("pear", random_state=200 + seed, volume=True, n_vertices=30000)
    folder = work / "scans" / f"pear_{seed + 1}"
    folder.mkdir(parents=True)
    data = pear.volume.data  # indexed [x, y, z]; a TIFF slice is [y, x]
    for k in range(data.shape[2]):
        tifffile.imwrite(folder / f"pear_rec{k:04d}.tif", np.ascontiguousarray(data[:, :, k].T))
    microns = pear.volume.spacing[0] * 1000
    (folder / "pear_rec.log").write_text(
        "[System]\nScanner=Skyscan1272\n[Reconstruction]\nReconstruction Program=NRecon\n"
        f"Pixel Size (um)={microns:.5f}\n")

volume = read_volume(work / "scans" / "pear_1")
print(volume.shape, "voxels of", volume.spacing, "mm, from", volume.spacing_source)

# %%
# Without the log the stack has no voxel size, and the error says what to do:
(work / "scans" / "pear_5" / "pear_rec.log").unlink()
try:
    read_volume(work / "scans" / "pear_5")
except VolumeError as error:
    print(type(error).__name__, ":", error)

# %%
# ``--spacing SX SY SZ`` (mm) gives it. It sets the size of every volume a command reads (and
# overrides what their files say), so the pear without its log is extracted on its own:
(work / "scans" / "pear_5").rename(work / "pear_5_no_log")
hortishape(["extract", str(work / "pear_5_no_log"), "--out", str(work / "surface_5"),
            "--spacing", *[f"{s:g}" for s in pear.volume.spacing]])

# %%
# The build on the four stacks that carry their log:
hortishape(["build", str(work / "scans"), "--out", str(work / "model"), "--points", "3000"])

# %%
# Where each surface's voxel size came from is recorded with it:
import json  # noqa: E402

info = json.loads((work / "model" / "surfaces" / "pear_1.json").read_text())
print(info["units"])
