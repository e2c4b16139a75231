"""Shared test data: the real scans of tests/data/ycb with their hand-marked poles."""

import json
from pathlib import Path

import numpy as np
import pytest

YCB = Path(__file__).parent / "data" / "ycb"
#: The six round scans whose stalk and blossom poles are marked in poles.json ...
YCB_ROUND = ["013_apple", "015_peach", "018_plum", "014_lemon", "017_orange", "016_pear"]
#: ... and the other two marked there.
YCB_OTHER = ["011_banana", "012_strawberry"]


@pytest.fixture(scope="session")
def ycb():
    """``{name: (mesh in mm, stalk mark, blossom mark)}`` for the eight marked real scans."""
    from hortishape.units import read_scan

    poles = json.loads((YCB / "poles.json").read_text())["scans"]
    out = {}
    for name in YCB_ROUND + YCB_OTHER:
        scan = read_scan(YCB / f"{name}_google16k.ply", scale=1000.0)
        marks = poles[f"{name}_google16k"]
        out[name] = (scan.mesh, 1000.0 * np.asarray(marks["stalk"]), 1000.0 * np.asarray(marks["blossom"]))
    return out
