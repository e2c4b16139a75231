"""Open every page of the built site from disk in headless Chromium: no console error, every picture there.

Usage: ``python docs/check_site.py docs/_build/html`` (needs playwright, from ``[test]``, and a Chromium:
``apt-get install chromium``, or ``HORTISHAPE_CHROMIUM=/path/to/chrome``). Exit status 1 on any error.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path


def check(root: Path) -> list[str]:
    from playwright.sync_api import sync_playwright

    executable = os.environ.get("HORTISHAPE_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if not executable:
        return ["no Chromium found (apt-get install chromium, or set HORTISHAPE_CHROMIUM)"]
    pages = sorted(p for p in root.rglob("*.html") if "_sources" not in p.parts and "_modules" not in p.parts)
    problems: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, headless=True,
                                    args=["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                                          "--disable-gpu-sandbox", "--no-first-run"])
        for path in pages:
            page = browser.new_page()
            errors: list[str] = []
            page.on("console", lambda m, errors=errors: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e, errors=errors: errors.append(str(e)))
            page.goto(path.as_uri())
            page.wait_for_load_state("load")
            broken = page.eval_on_selector_all(
                "img", "els => els.filter(e => !e.complete || e.naturalWidth === 0).map(e => e.getAttribute('src'))")
            name = path.relative_to(root).as_posix()
            problems += [f"{name}: console error: {e}" for e in errors]
            problems += [f"{name}: picture missing: {src}" for src in broken]
            page.close()
        browser.close()
    print(f"{len(pages)} pages opened, {len(problems)} problems", file=sys.stderr)
    return problems


if __name__ == "__main__":
    found = check(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/_build/html").resolve())
    for line in found:
        print(line, file=sys.stderr)
    sys.exit(1 if found else 0)
