"""The README's shell commands in the order written (its ```bash blocks), for tests/docs/test_readme_commands.py.

Each line's comment is dropped; ``a && b`` and ``a & b`` are two commands; a pure comment line is none.
A command is its shlex tokens joined back (``shlex.join``), so quoting and spacing do not matter."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"
FENCE = re.compile(r"^```bash\n(.*?)^```", re.M | re.S)
SEPARATORS = ("&&", "&")


def commands(text: str | None = None) -> list[list[str]]:
    """Every command of the README's bash blocks, in order, as argv lists."""
    text = README.read_text() if text is None else text
    out: list[list[str]] = []
    for block in FENCE.findall(text):
        for line in block.splitlines():
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


def key(argv: list[str]) -> str:
    return shlex.join(argv)
