"""Write the troubleshooting page's catalogue of every error and warning a user can meet.

The messages are read from the source (every ``raise HortishapeError(...)``, ``MeshError``,
``VolumeError``, ``NotFittedError``, the file readers' own findings, which reach the user as
``MeshError`` or ``VolumeError`` with the file's name in front, every ``warnings.warn(...)`` and
the notes gathered into an extraction's or a partial fit's warning), with the parts filled in at
run time shown as ``...``. ``python docs/messages.py`` rewrites the catalogue in
``docs/troubleshooting.md``; ``tests/test_docs.py`` fails when it is out of date.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "src" / "hortishape"
PAGE = ROOT / "docs" / "troubleshooting.md"
START = "<!-- catalogue: written by docs/messages.py -->"
USER_ERRORS = {"HortishapeError", "MeshError", "VolumeError", "NotFittedError",
               # a reader's findings, raised as MeshError or VolumeError with the file's name in front
               "_ParseError", "_MissingDependencyError"}
_SHOWN_AS = {"_ParseError": "MeshError or VolumeError (a file's content)",
             "_MissingDependencyError": "MeshError or VolumeError (an optional package)"}
# notes gathered into one warning per product or fit: ``notes.append(...)`` in these modules
NOTE_WARNINGS = {"hortishape.extract": "ExtractionWarning", "hortishape.partial": "FitWarning"}


def _text(node: ast.AST) -> str | None:
    """The message as a reader sees it, run-time parts as ``...``; None if not a string."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value if isinstance(v, ast.Constant) else "..." for v in node.values)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        left, right = _text(node.left), _text(node.right)
        if left is not None or right is not None:
            return (left or "...") + (right or "...")
    if isinstance(node, ast.Name):
        return "..."
    return None


def _name(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return ""


def collect() -> dict[str, list[tuple[str, str]]]:
    """``{module: [(kind, message), ...]}`` in source order, each message once per module."""
    found: dict[str, list[tuple[str, str]]] = {}
    for path in sorted(SOURCE.rglob("*.py")):
        module = ".".join(("hortishape", *path.relative_to(SOURCE).with_suffix("").parts)).removesuffix(".__init__")
        rows: list[tuple[str, str]] = []
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and _name(node.exc.func) in USER_ERRORS:
                kind, args = _name(node.exc.func), node.exc.args
            elif (isinstance(node, ast.Call) and module in NOTE_WARNINGS and _name(node.func) == "append"
                  and _name(getattr(node.func, "value", None)) == "notes"):
                kind, args = NOTE_WARNINGS[module], node.args
            elif isinstance(node, ast.Call) and _name(node.func) == "warn" and _name(getattr(node.func, "value", None)) == "warnings":
                kind = _name(node.args[1]) if len(node.args) > 1 else "UserWarning"
                kind = next((_name(k.value) for k in node.keywords if k.arg == "category"), kind) or "UserWarning"
                args = node.args
            else:
                continue
            text = _text(args[0]) if args else None
            if not text or sum(c.isalpha() for c in text) < 3:  # a message passed on as it came ("...: ...")
                continue
            row = (_SHOWN_AS.get(kind, kind), " ".join(text.split()))
            if row not in rows:
                rows.append(row)
        if rows:
            found[module] = sorted(rows, key=lambda r: (r[0], r[1]))
    return found


def catalogue() -> str:
    lines = [START, "", "## Every message", "",
             "Every error and warning hortishape gives, by the module that gives it. `...` stands for what "
             "is filled in at run time (a file's name, a figure).", ""]
    for module, rows in collect().items():
        lines += [f"### `{module}`", ""]
        lines += [f"- {kind}: `{text.replace('`', chr(39))}`" for kind, text in rows]
        lines.append("")
    return "\n".join(lines)


def page_with_catalogue(page: str) -> str:
    head = page.split(START)[0].rstrip("\n")
    return head + "\n\n" + catalogue()


if __name__ == "__main__":
    PAGE.write_text(page_with_catalogue(PAGE.read_text(encoding="utf-8")), encoding="utf-8")
    n = sum(len(r) for r in collect().values())
    print(f"{PAGE}: {n} messages", file=sys.stderr)
