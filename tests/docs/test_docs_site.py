"""The documentation site as built: nothing loaded from another host (code is highlighted offline by
Pygments, the theme's CDN highlight.js turned off), the readability stylesheet linked on every page, and no
code block showing Markdown's backticks literally. How it looks at 1280 and 390 px is checked by screenshots
in a headless browser (tests/README.md, "The documentation site in a browser")."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from html import unescape
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
EXTRA_CSS = ("css/pygments.css", "css/truav.css")
EXTERNAL = re.compile(r"<script[^>]*\ssrc=\"(?:https?:)?//[^\"]+\"|<link[^>]*\shref=\"(?:https?:)?//[^\"]+\"[^>]*>")
PRE = re.compile(r"<pre[^>]*>(.*?)</pre>", re.S)


def build_site(config: Path, out: Path) -> list[Path]:
    """``mkdocs build --strict`` of ``config`` into ``out``; its HTML pages."""
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-f", str(config), "-d", str(out)],
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    return sorted(out.rglob("*.html"))


def site_problems(pages: list[Path], site: Path) -> list[str]:
    """What a reader offline, or of a code block, would meet: external scripts and stylesheets, a page
    without the extra CSS, a code block whose text starts with a literal backtick."""
    problems = []
    for page in pages:
        html = page.read_text()
        name = page.relative_to(site)
        problems += [f"{name}: loads {m.group(0)[:120]}" for m in EXTERNAL.finditer(html)]
        if page.name != "404.html":
            problems += [f"{name}: {css} not linked" for css in EXTRA_CSS
                         if not re.search(rf'<link[^>]*href="(?:\./)?(?:\.\./)*{re.escape(css)}"', html)]
        for block in PRE.findall(html):
            text = unescape(re.sub(r"<[^>]+>", "", block)).lstrip()
            if text.startswith("`"):
                problems.append(f"{name}: a code block shows Markdown backticks: {text[:60]!r}")
    return problems


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None,
                    reason="mkdocs is not installed (the docs extra: pip install -e '.[docs]' -c constraints.txt)")
@pytest.mark.timeout(300)
def test_the_built_site_loads_nothing_from_elsewhere_and_links_its_stylesheets(tmp_path: Path) -> None:
    site = tmp_path / "site"
    pages = build_site(REPO / "mkdocs.yml", site)
    assert len(pages) > 30, f"only {len(pages)} pages built"
    for css in EXTRA_CSS:
        assert (site / css).is_file(), f"{css} not in the built site"
    assert site_problems(pages, site) == []
