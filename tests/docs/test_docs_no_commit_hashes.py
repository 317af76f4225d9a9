"""No commit hash in the user docs (README.md, docs/**/*.md): a reader has no use for "17fb350", a name that
means something only inside this repository's history; a page names a version of the code by its date or by
what it did.

The rule: a commit-like token is 7 to 40 lowercase hexadecimal characters with at least one digit and at least
one letter a-f, standing alone (no letter, digit or underscore on either side; hyphens and dots count as sides,
so a hash inside a file name is caught). Not caught, on purpose: longer hex runs (a SHA-256 of data is 64),
numbers (no letter), words such as "defaced" (no digit), `0x...` literals and `#rrggbb` colours or anchors
(a `#` or an `x` before them). Data files (the CSVs under docs/figures) may keep a checkout's name in a column."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
COMMIT_LIKE = re.compile(r"(?<![0-9A-Za-z_#])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![0-9A-Za-z_])")


def commit_like(text: str) -> list[str]:
    return COMMIT_LIKE.findall(text)


def test_the_rule_catches_hashes_and_spares_numbers_words_and_colours():
    assert commit_like("Before that form (17fb350), its per-UAV form") == ["17fb350"]
    assert commit_like("rows in recheck-8939cea-vs-c52a44e.csv") == ["8939cea", "c52a44e"]
    assert commit_like("git checkout 0cd7060a1b2c3d4e5f60718293a4b5c6d7e8f901") == ["0cd7060a1b2c3d4e5f60718293a4b5c6d7e8f901"]
    assert commit_like("1048576 bytes, 5900000000 Hz, defaced, #1f77b4ff, 0x7fffffff, " + "ab12" * 16) == []


def test_no_commit_hash_in_the_user_docs():
    pages = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
    found = [f"{page.relative_to(REPO)}:{n}: {token}"
             for page in pages for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1)
             for token in commit_like(line)]
    assert not found, "commit hashes in the docs (name the code by its date or change instead):\n" + "\n".join(found)
