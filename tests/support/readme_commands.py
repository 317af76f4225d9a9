"""The shell commands of the README and the documentation's pages, in the order written (their ```bash
blocks; a ```console block is shown, not run), for tests/docs/test_readme_commands.py. The README comes first,
then PAGES in their order, so a page may use what an earlier one made (runs/train-15mps, runs/demo.mcap).

Each line's comment is dropped; ``a && b`` and ``a & b`` are two commands; a pure comment line is none.
A command is its shlex tokens joined back (``shlex.join``), so quoting and spacing do not matter."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"
DOCS = README.parent / "docs"
PAGES = ("tutorials/first-swarm.md", "tutorials/train-and-compare.md", "tutorials/fault-experiment.md",
         "tutorials/record-replay-resim.md", "tutorials/own-agent.md", "how-to/sumo.md", "how-to/fault-plans.md",
         "how-to/multi-host.md", "how-to/secure-bus.md", "how-to/ray.md", "how-to/foxglove.md",
         "how-to/add-a-scheme.md", "how-to/add-a-message-kind.md", "results/benchmarks.md")
"""The documentation pages whose ```bash blocks run, in this order after the README's."""
FENCE = re.compile(r"^```bash\n(.*?)^```", re.M | re.S)
SEPARATORS = ("&&", "&")


def commands(text: str | None = None) -> list[list[str]]:
    """Every command of the README's bash blocks, then of PAGES', in order, as argv lists."""
    if text is None:
        text = "\n".join(path.read_text() for path in [README, *(DOCS / page for page in PAGES)])
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
