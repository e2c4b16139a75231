"""Packaging: the lower-bounds constraints CI tests against are the bounds pyproject.toml declares."""

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _declared() -> dict[str, str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = list(project["dependencies"])
    for extra, reqs in project["optional-dependencies"].items():
        if extra != "bench":  # the benchmark's baseline, not part of the tested install
            requirements += reqs
    bounds = {}
    for req in requirements:
        m = re.match(r"^\s*([A-Za-z0-9_.\-]+)\s*>=\s*([0-9][^,;\s]*)", req)
        if m:
            bounds[m.group(1).lower()] = m.group(2)
    return bounds


def _pinned() -> dict[str, str]:
    pins = {}
    for line in (ROOT / ".ci" / "lower-bounds.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, version = line.split("==")
            pins[name.strip().lower()] = version.strip()
    return pins


def test_every_declared_lower_bound_is_pinned_for_ci():
    from packaging.version import Version

    declared, pinned = _declared(), _pinned()
    assert "numpy" in declared and "vtk" in declared
    assert sorted(pinned) == sorted(declared)
    for name, version in declared.items():
        assert Version(pinned[name]) == Version(version), name
