"""
A model from CT scans: one DICOM series folder per fruit
=========================================================

Thirty apples scanned on a CT scanner arrive as thirty folders of slice files, one series each,
often without extensions (``IM0000``, ``IM0001``, ...), sometimes with a localizer or a note beside
them. This tutorial makes six synthetic apples, writes each CT volume as a scanner exports it, and
goes from that folder to a model, its report and the mean apple as a STEP file: the three commands
of the README.
"""

# %%
# Scans as a CT scanner writes them
# ---------------------------------
# :func:`hortishape.synth.make_instance` with ``volume=True`` gives a CT-like volume with each
# synthetic apple (flesh brighter than air, a darker core, scanner noise), and
# :func:`hortishape.io.write_dicom_series` writes it as one extensionless DICOM file per slice,
# with the voxel size and position in the headers.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

from hortishape import synth
from hortishape.cli import main as hortishape  # the command line, run from Python
from hortishape.io import write_dicom_series

work = Path(tempfile.mkdtemp())
scans = work / "scans"
for seed in range(6):
    apple = synth.make_instance("apple", random_state=100 + seed, volume=True, n_vertices=30000)
    write_dicom_series(scans / f"apple_{seed + 1:02d}", apple.volume, description=f"apple {seed + 1}")
(scans / "notes.txt").write_text("scanned 2026-12-01, 120 kV\n")
print(sorted(p.name for p in scans.iterdir()))
print(sorted(p.name for p in (scans / "apple_01").iterdir())[:4], "...")

# %%
# One command: surfaces, correspondence, Procrustes, PCA
# ------------------------------------------------------
# ``hortishape build`` finds the six series by their headers and names each after its
# SeriesDescription (``apple 1`` becomes ``apple_1``; ``notes.txt`` is listed as passed
# over), extracts each apple's outer surface, registers a reference to every apple twice (the
# paper's two passes), aligns them and computes the PCA. ``--points 3000`` keeps this tutorial
# quick; leave it out for the paper's 30,000-vertex reference.
hortishape(["build", str(scans), "--out", str(work / "model"), "--points", "3000"])

# %%
# Each volume's surface has a picture for checking by eye: the surface beside two slices with the
# outline the extraction found.
picture = plt.imread(work / "model" / "surfaces" / "apple_1.png")
fig, ax = plt.subplots(figsize=(9, 4))
ax.imshow(picture)
ax.set_axis_off()

# %%
# The report: is the model any good?
# ----------------------------------
# ``hortishape evaluate`` measures compactness, generalization (leave-one-out) and specificity,
# maps the registration's error on the mean, and writes ``model/evaluation/report.html`` (one
# page, pictures embedded) with ``metrics.json`` and ``metrics.csv`` beside it.
hortishape(["evaluate", str(work / "model"), "--samples", "50"])

import json  # noqa: E402

metrics = json.loads((work / "model" / "evaluation" / "metrics.json").read_text())
print(sorted(metrics))

# %%
# The compactness plot, as the report shows it:
fig, ax = plt.subplots(figsize=(6, 4))
ax.imshow(plt.imread(work / "model" / "evaluation" / "compactness.png"))
ax.set_axis_off()

# %%
# The mean apple as CAD
# ---------------------
# ``hortishape cad`` maps the mean onto a cylinder, fits a bicubic B-spline surface and writes a
# STEP solid (through OpenCascade) for CFD or FEM meshing.
hortishape(["cad", str(work / "model" / "model.h5"), "--out", str(work / "mean.step"), "--grid", "16"])
print(f"{(work / 'mean.step').stat().st_size / 1024:.0f} kB of STEP")
