"""The shell commands of the README and the documentation's pages, in the order a reader meets them, for
tests/docs/test_readme_commands.py: the README first, then its tutorials and how-to guides in the order its
Documentation section lists them (PAGES), then EXTRA_PAGES; so a page may use what an earlier one made
(runs/train-15mps, runs/demo.mcap), and a page that collides with an earlier one's run fails.

The README promises that every command of its tutorials and how-to guides runs as written, in order: in those
pages every shell block counts (```bash, ```sh, ```shell and ```console alike); in the README and
EXTRA_PAGES only ```bash blocks do (a ```console block there is shown, not run).

Each line's comment is dropped; ``a && b`` and ``a & b`` are two commands; a pure comment line is none.
A command is its shlex tokens joined back (``shlex.join``), so quoting and spacing do not matter."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"
DOCS = README.parent / "docs"
_LISTED = re.compile(r"\]\(docs/((?:tutorials|how-to)/[\w.-]+\.md)\)")


def _listed_pages() -> tuple[str, ...]:
    """The tutorials and how-to guides in the order the README's Documentation section links them."""
    section = README.read_text().split("## Documentation", 1)[1].split("\n## ", 1)[0]
    return tuple(dict.fromkeys(_LISTED.findall(section)))


PAGES = _listed_pages()
"""The tutorials and how-to guides, in the README's order: every shell block of theirs counts."""
EXTRA_PAGES = ("results/benchmarks.md",)
"""Other pages whose ```bash blocks count, after PAGES."""
FENCE = re.compile(r"^```bash\n(.*?)^```", re.M | re.S)
SHELL_FENCE = re.compile(r"^```(?:bash|sh|shell|console)\n(.*?)^```", re.M | re.S)
SEPARATORS = ("&&", "&")


def _split(blocks: list[str]) -> list[list[str]]:
    out: list[list[str]] = []
    for block in blocks:
        for line in block.replace("\\\n", " ").splitlines():
            tokens = shlex.split(line, comments=True)
            current: list[str] = []
            for tok in tokens + ["&&"]:
                if tok in SEPARATORS:
                    if current:
                        out.append(current)
                    current = []
                else:
                    current.append(tok)
    return out


def commands(text: str | None = None) -> list[list[str]]:
    """Every command of the README's bash blocks, then of PAGES' shell blocks, then of EXTRA_PAGES' bash
    blocks, in order, as argv lists (``text``: one text's bash blocks only)."""
    if text is not None:
        return _split(FENCE.findall(text))
    return _split(_blocks())


def _blocks() -> list[str]:
    """The counted blocks' text, in order (a listed page that is missing counts none: tests/docs/
    test_docs_commands.py names it)."""
    blocks = FENCE.findall(README.read_text())
    for page in PAGES:
        if (DOCS / page).is_file():
            blocks += SHELL_FENCE.findall((DOCS / page).read_text())
    for page in EXTRA_PAGES:
        blocks += FENCE.findall((DOCS / page).read_text())
    return blocks


_TIME = re.compile(r"(?:about|~)\s*(\d+(?:\.\d+)?)\s*(h|min|s)\b(?:\s*(\d+)\s*(min|s)\b)?")
_UNIT_S = {"h": 3600, "min": 60, "s": 1}


def stated_times() -> dict[str, float]:
    """{command: seconds} for every command whose comment states how long it takes ("about 55 s", "~1.5 min",
    "about 2 h 15 min"): the first such time in the comment on its line, or on the comment lines just above it."""
    out: dict[str, float] = {}
    for block in _blocks():
        above = ""
        for line in block.replace("\\\n", " ").splitlines():
            argvs = _split([line])
            comment = line.split(" #", 1)[1] if " #" in line else line.lstrip()[1:] if line.lstrip().startswith("#") else ""
            if not argvs:
                above += " " + comment
                continue
            match = _TIME.search(above + " " + comment) if not _TIME.search(comment) else _TIME.search(comment)
            if match:
                seconds = float(match.group(1)) * _UNIT_S[match.group(2)]
                if match.group(3):
                    seconds += float(match.group(3)) * _UNIT_S[match.group(4)]
                out[key(argvs[-1])] = seconds
            above = ""
    return out


def key(argv: list[str]) -> str:
    return shlex.join(argv)


def program(argv: list[str]) -> list[str]:
    """``argv`` without the leading ``VAR=value`` environment assignments (``PYTHONPATH=~/mylab truav ...``)."""
    at = 0
    while at < len(argv) and re.fullmatch(r"[A-Za-z_]\w*=.*", argv[at]):
        at += 1
    return argv[at:]
