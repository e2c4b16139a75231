"""Shared test data (the real scans of tests/data/ycb with their hand-marked poles) and the perturbation check.

The perturbation check: with ``HORTISHAPE_PERTURB`` set to a comma-separated
list of the perturbations below, the tests run on inputs changed at the level
of rounding, and every assertion must still hold (``.ci/run`` runs every
test so, together with other BLAS kernels and one thread set by
``OPENBLAS_CORETYPE``, ``NPY_DISABLE_CPU_FEATURES`` and
``OPENBLAS_NUM_THREADS``; docs/reproducibility.md). A test that fails only so
asserts a figure that another machine would not give.

- ``jitter``: every synthetic scan's vertices (``synth.make_instance``) and
  the real scans' moved by up to ``JITTER_MM``, each as its position decides;
- ``float32`` / ``float64``: every volume handed to ``extract_surface``
  stored as float32 / float64, where that keeps its values exactly;
- ``no-embree``: ``embreex`` hidden, so libigl casts the rays (as on macOS and ARM), also in
  the processes the tests start;
- ``one-thread``: BLAS and the ray queries on one thread (``OPENBLAS_NUM_THREADS=1`` carries it
  to the processes the tests start).
"""

import dataclasses
import functools
import json
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest

# not a module to collect doctests from: where Python has a sitecustomize of its own (Debian's),
# importing this one by that name would clash with it
collect_ignore = ["perturbation"]

PERTURBATIONS = {"jitter", "float32", "float64", "no-embree", "one-thread"}
#: How far ``jitter`` moves a vertex along each axis, mm.
JITTER_MM = 1e-9
PERTURB = {p.strip() for p in os.environ.get("HORTISHAPE_PERTURB", "").split(",") if p.strip()}
if PERTURB - PERTURBATIONS:
    raise pytest.UsageError(f"HORTISHAPE_PERTURB: unknown {sorted(PERTURB - PERTURBATIONS)}; "
                            f"choose from {sorted(PERTURBATIONS)}")


def _jittered(vertices: np.ndarray) -> np.ndarray:
    # a function of each vertex's position: every run moves it alike (a failure reproduces), and
    # so do two scans that share it (a scan, and the same scan with holes cut)
    phase = vertices @ np.array([12.9898, 78.233, 37.719])
    return vertices + JITTER_MM * np.sin(phase[:, None] * np.array([1.0, 1.3, 1.7]))


def _perturb() -> None:
    """Apply ``PERTURB`` before the test modules import what they test."""
    if "no-embree" in PERTURB:
        sys.modules["embreex"] = None  # importing embreex now raises ImportError
        # and in the processes the tests start (perturbation/sitecustomize.py)
        folder = str(Path(__file__).parent / "perturbation")
        sys.path.insert(0, folder)
        os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [folder, os.environ.get("PYTHONPATH")]))
    if "one-thread" in PERTURB:
        from threadpoolctl import threadpool_limits

        from hortishape.registration import correspondences

        threadpool_limits(limits=1)
        correspondences.RAY_THREADS = 1
        os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    if "jitter" in PERTURB:
        from hortishape import synth
        from hortishape.mesh import Mesh

        make_instance = synth.make_instance

        @functools.wraps(make_instance)
        def jittered_instance(*args, **kwargs):
            inst = make_instance(*args, **kwargs)
            return dataclasses.replace(inst, mesh=Mesh(_jittered(inst.mesh.vertices), inst.mesh.faces))

        synth.make_instance = jittered_instance
    stored = {"float32", "float64"} & PERTURB
    if stored:
        from hortishape import extract
        from hortishape.io import Volume

        dtype = np.dtype(stored.pop())
        extract_surface = extract.extract_surface

        @functools.wraps(extract_surface)
        def restored(volume, **kwargs):
            data = volume.data if isinstance(volume, Volume) else np.asarray(volume)
            other = data.astype(dtype)
            if np.array_equal(other, data):  # the same values, stored otherwise
                volume = dataclasses.replace(volume, data=other) if isinstance(volume, Volume) else other
            return extract_surface(volume, **kwargs)

        extract.extract_surface = restored


_perturb()

YCB = Path(__file__).parent / "data" / "ycb"
#: The six round scans whose stalk and blossom poles are marked in poles.json ...
YCB_ROUND = ["013_apple", "015_peach", "018_plum", "014_lemon", "017_orange", "016_pear"]
#: ... and the other two marked there.
YCB_OTHER = ["011_banana", "012_strawberry"]


@pytest.fixture(scope="session")
def ycb():
    """``{name: (mesh in mm, stalk mark, blossom mark)}`` for the eight marked real scans."""
    from hortishape.mesh import Mesh
    from hortishape.units import read_scan

    poles = json.loads((YCB / "poles.json").read_text())["scans"]
    out = {}
    for name in YCB_ROUND + YCB_OTHER:
        scan = read_scan(YCB / f"{name}_google16k.ply", scale=1000.0)
        marks = poles[f"{name}_google16k"]
        mesh = scan.mesh if "jitter" not in PERTURB else Mesh(_jittered(scan.mesh.vertices), scan.mesh.faces)
        out[name] = (mesh, 1000.0 * np.asarray(marks["stalk"]), 1000.0 * np.asarray(marks["blossom"]))
    return out


# --------------------------------------------------------------------------
# The margins of the assertions: how near each comparison came to failing
# --------------------------------------------------------------------------

#: With ``HORTISHAPE_MARGINS=FILE`` and ``-o enable_assertion_pass_hook=true``, every passing
#: assertion that compares a number with a bound (``x < 1.0``, ``x == approx(y, abs=...)``) is
#: written to FILE (JSON lines) with its margin: how far the value lies from the bound, as a
#: share of the value (for approx: the share of the tolerance left). A margin under about 0.2
#: is a figure another machine may not give: such an assertion says why its margin is enough.
MARGINS = os.environ.get("HORTISHAPE_MARGINS")
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?inf"


def _number(text: str) -> float | None:
    text = re.sub(r"^np\.(?:float|int)\d*\((.*)\)$", r"\1", text.strip())
    return float(text) if re.fullmatch(_NUMBER, text) else None


def _margin(first_line: str) -> dict | None:
    """``{"op", "value", "bound", "margin"}`` of an assertion's first explained line, or None."""
    line = first_line.removeprefix("assert ").strip()
    m = re.fullmatch(rf"(.+?) == ({_NUMBER}) ± ({_NUMBER})", line)
    if m and _number(m[1]) is not None:
        value, centre, tol = _number(m[1]), float(m[2]), float(m[3])
        return {"op": "approx", "value": value, "bound": centre, "tolerance": tol,
                "margin": 1.0 - abs(value - centre) / tol if tol > 0 else float("nan")}
    m = re.fullmatch(r"(.+?) (<=|>=|<|>) (.+)", line)
    if not m:
        return None
    a, b = _number(m[1]), _number(m[3])
    if a is None or b is None:
        return None
    return {"op": m[2], "value": a, "bound": b, "margin": abs(b - a) / max(abs(a), 1e-300)}


def pytest_assertion_pass(item, lineno, orig, expl):
    if not MARGINS:
        return
    found = _margin(expl.splitlines()[0]) if expl else None
    if found is not None and found["op"] != "approx":
        left = re.split(r" (?:<=|>=|<|>) ", orig, maxsplit=1)[0]
        if _number(left) is not None:  # the bound on the left: `5.0 < x`
            found.update(value=found["bound"], bound=found["value"],
                         margin=abs(found["bound"] - found["value"]) / max(abs(found["bound"]), 1e-300))
    if found is not None:
        with open(MARGINS, "a") as fh:
            fh.write(json.dumps({"test": item.nodeid, "line": lineno, "assert": orig, **found}) + "\n")
