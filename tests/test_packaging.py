"""Packaging: the lower-bounds constraints CI tests against are the bounds pyproject.toml declares."""

import ast
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


def _imports(path: Path, module: str, package: str) -> set[str]:
    """Modules of the package that ``module`` imports anywhere (top level, in functions, under TYPE_CHECKING)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found |= {target, *(f"{target}.{a.name}" for a in node.names)}
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
    return found


def test_no_import_cycle_among_the_package_modules():
    src = Path(__file__).resolve().parents[1] / "src"
    modules = {}
    for path in (src / "hortishape").rglob("*.py"):
        parts = path.relative_to(src).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        modules[name] = path
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        graph[name] = {m for m in _imports(path, name, package) if m in modules and m != name}
    cycle = None

    def visit(node, stack, state):
        nonlocal cycle
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph[node]):
            if cycle:
                return
            if state.get(nxt) == "open":
                cycle = stack[stack.index(nxt):] + [nxt]
                return
            if nxt not in state:
                visit(nxt, stack, state)
        stack.pop()
        state[node] = "done"

    state: dict[str, str] = {}
    for name in sorted(graph):
        if name not in state and not cycle:
            visit(name, [], state)
    assert len(modules) > 40 and "hortishape.io.ply" in modules
    assert cycle is None, "import cycle: " + " -> ".join(cycle)
