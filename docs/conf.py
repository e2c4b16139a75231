"""Sphinx configuration of hortishape's documentation.

Build: ``python -m sphinx -W --keep-going -b html docs docs/_build/html`` (with ``pip install ".[all,docs]"``).
The tutorials in ``docs/examples`` run while the site is built (sphinx-gallery); an error in one fails
the build. The API pages are written here, from each public module's ``__all__``, so every public
name is on them once, under the module that defines it.
"""

from __future__ import annotations

import importlib
import inspect
import os
from pathlib import Path

import hortishape

DOCS = Path(__file__).resolve().parent

project = "hortishape"
author = "hortishape developers"
copyright = "2026, hortishape developers"
release = hortishape.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "examples/*.md", "tutorials/*.ipynb", "tutorials/*.py", "tutorials/*.zip",
                    "tutorials/*.codeobj.json", "tutorials/*.md5"]
myst_enable_extensions = ["colon_fence", "deflist", "substitution"]
myst_substitutions = {"release": release}
myst_heading_anchors = 3

html_theme = "furo"
html_title = f"hortishape {release}"
html_static_path: list[str] = []

autodoc_typehints = "none"  # numpydoc writes the types from the docstrings
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False


# -- tutorials: run at build time; the gallery fails on an example's error --------------------------
sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "tutorials",
    "filename_pattern": r".*\.py",
    "abort_on_example_error": True,
    "only_warn_on_example_error": False,
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "image_scrapers": ("matplotlib",),
    "min_reported_time": 1,
    "capture_repr": (),
    # its pages load jQuery from a CDN: an error offline, and the figures are not for users
    "write_computation_times": False,
}

# -- the API pages, one per public module ----------------------------------------------------------
# modules kept only so that old imports work; their names are documented where they live now
_FORMER_HOMES = {"hortishape.register": "hortishape.registration",
                 "hortishape.correspond": "hortishape.registration.correspondences"}
API_MODULES = [
    "hortishape", "hortishape.mesh", "hortishape.io", "hortishape.synth", "hortishape.extract", "hortishape.registration",
    "hortishape.registration.correspondences", "hortishape.align", "hortishape.procrustes",
    "hortishape.model", "hortishape.pipeline", "hortishape.metrics", "hortishape.evaluate",
    "hortishape.report", "hortishape.partial", "hortishape.cad", "hortishape.view", "hortishape.statismo",
    "hortishape.render", "hortishape.surface", "hortishape.units", "hortishape.layout", "hortishape.demo",
]


def _write_api_pages() -> None:
    out = DOCS / "reference" / "api"
    out.mkdir(parents=True, exist_ok=True)
    home: dict[int, str] = {}
    pages = []
    for modname in API_MODULES:
        mod = importlib.import_module(modname)
        lines = [f"# `{modname}`", "", "```{eval-rst}", f".. automodule:: {modname}", "   :no-members:", "```", ""]
        for name in mod.__all__:
            obj = getattr(mod, name)
            if name == "__version__":
                lines += [f"`{modname}.__version__`: the installed version, ``{release}``.", ""]
                continue
            key = id(obj)
            if key in home and (callable(obj) or inspect.isclass(obj)):
                lines += [f"`{name}`: see {{py:obj}}`{home[key]}.{name}`.", ""]
                continue
            if callable(obj) or inspect.isclass(obj):
                home[key] = modname
            kind = ("autoexception" if inspect.isclass(obj) and issubclass(obj, BaseException) else
                    "autoclass" if inspect.isclass(obj) else
                    "autofunction" if callable(obj) else "autodata")
            extra = ["   :members:"] if kind == "autoclass" else []
            lines += ["```{eval-rst}", f".. {kind}:: {modname}.{name}", *extra, "```", ""]
        for old, new in _FORMER_HOMES.items():
            if new == modname:
                lines += [f"`{old}` is this module's former home: its names still import from there.", ""]
        (out / f"{modname}.md").write_text("\n".join(lines), encoding="utf-8")
        pages.append(modname)
    index = ["# Python API", "", "Every public name, under the module that defines it. A name imported from "
             "another module too says where it is documented.", "", "```{toctree}", ":maxdepth: 1", "",
             *pages, "```", ""]
    (out / "index.md").write_text("\n".join(index), encoding="utf-8")


def _write_cli_page() -> None:
    """The command line's reference: each command's ``--help``, as the parser prints it."""
    from hortishape.cli import _command_parsers, build_parser

    os.environ["COLUMNS"] = "100"  # argparse wraps at the terminal's width
    parser = build_parser()
    lines = ["# Command line", "",
             "Written from the command line's own parser when this site is built: the text of "
             "`hortishape --help` and of `hortishape COMMAND --help`.", "",
             "```text", parser.format_help().rstrip(), "```", ""]
    for name, (help_line, command) in _command_parsers(parser).items():
        lines += [f"## `hortishape {name}`", "", help_line or "", "",
                  "```text", command.format_help().rstrip(), "```", ""]
    (DOCS / "reference" / "cli.md").write_text("\n".join(lines), encoding="utf-8")


_write_api_pages()
_write_cli_page()
