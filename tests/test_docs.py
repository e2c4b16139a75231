"""The documentation: the README stays short and free of measurements, the Python blocks of the
README and the docs run, every public function and class has an example, every command-line
option has help, the troubleshooting page lists every message, and the version lives in one place."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest

import hortishape

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOC_PAGES = sorted(p for p in (ROOT / "docs").rglob("*.md")
                   if not {"_build", "tutorials", "api"} & set(p.relative_to(ROOT / "docs").parts))


def test_readme_is_short_and_holds_no_measurement():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 150
    assert not re.findall(r"\b20\d\d-\d\d-\d\d\b", text), "dates belong on the validation pages"
    assert "benchmarks/" not in text, "benchmark commands belong on the validation pages"
    assert not re.findall(r"\b\d+(\.\d+)? ?(s|ms|seconds|minutes|GB|MB)\b", text), "timings belong on the validation pages"


def test_readme_opens_with_the_user_path_and_keeps_the_two_commands():
    lines = README.read_text(encoding="utf-8").splitlines()
    first_screen = "\n".join(lines[:40])
    for command in ("hortishape build", "hortishape evaluate", "hortishape cad"):
        assert command in first_screen
    assert any(line.startswith("python3 -m venv .venv") and "hortishape demo" in line for line in lines)
    assert any(line.startswith(".venv/bin/python -m pytest") for line in lines)


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", path.read_text(encoding="utf-8"), re.S | re.M)


BLOCKS = [(p, i, b) for p in [README, ROOT / "CONTRIBUTING.md", *DOC_PAGES] for i, b in enumerate(_python_blocks(p))]


@pytest.mark.parametrize("path, index, block", BLOCKS, ids=[f"{p.name}-{i}" for p, i, _ in BLOCKS])
def test_python_blocks_run(path, index, block, tmp_path):
    result = subprocess.run([sys.executable, "-c", block], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, f"{path.name} block {index}:\n{result.stderr[-2000:]}"


def _public_objects():
    seen = {}
    modules = ["hortishape"] + [m.name for m in pkgutil.walk_packages(hortishape.__path__, "hortishape.")
                                if not any(part.startswith("_") for part in m.name.split("."))]
    for modname in modules:
        module = importlib.import_module(modname)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if callable(obj):
                seen.setdefault(id(obj), (f"{modname}.{name}", obj))
    return list(seen.values())


def _needs_example(obj) -> bool:
    # records a function returns are shown by that function's example; exceptions by the functions raising them
    if inspect.isclass(obj):
        return not (dataclasses.is_dataclass(obj) or issubclass(obj, BaseException))
    return True


def test_every_public_function_and_class_has_an_example():
    missing = sorted(name for name, obj in _public_objects()
                     if _needs_example(obj) and ">>>" not in (inspect.getdoc(obj) or ""))
    assert not missing, f"public names without a docstring example: {missing}"


def test_every_public_name_has_a_docstring():
    missing = sorted(name for name, obj in _public_objects() if not (inspect.getdoc(obj) or "").strip())
    assert not missing


def test_every_command_line_option_has_help():
    import argparse

    from hortishape.cli import _command_parsers, build_parser

    commands = _command_parsers(build_parser())
    assert all(help_line for help_line, _ in commands.values()), "every command has a one-line help"
    missing = [f"{name} {action.option_strings or action.dest}"
               for name, (_, command) in commands.items() for action in command._actions
               if not action.help and not isinstance(action, argparse._HelpAction)]
    assert not missing, f"options without help: {missing}"


def test_troubleshooting_lists_every_message():
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        messages = importlib.import_module("messages")
    finally:
        sys.path.pop(0)
    page = (ROOT / "docs" / "troubleshooting.md").read_text(encoding="utf-8")
    assert sum(len(rows) for rows in messages.collect().values()) > 200
    assert page == messages.page_with_catalogue(page), "run python docs/messages.py"


def test_the_version_lives_in_pyproject_and_the_changelog_names_it():
    import tomllib

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["version"]
    assert hortishape.__version__ == declared
    first = re.search(r"^## (\S+)", (ROOT / "CHANGELOG.md").read_text(encoding="utf-8"), re.M)
    assert first and first.group(1) == declared
    assert "\nversion:" not in (ROOT / "CITATION.cff").read_text(encoding="utf-8")  # one place only


def test_every_doc_page_is_in_the_site():
    index = "\n".join(p.read_text(encoding="utf-8") for p in DOC_PAGES)
    for page in DOC_PAGES:
        if page.name == "index.md" and page.parent == ROOT / "docs":
            continue
        assert page.stem in index, f"{page} is in no table of contents"
