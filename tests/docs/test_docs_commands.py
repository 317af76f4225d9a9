"""The documentation's runnable commands are the ones the command test runs: a ```bash block is run by
tests/docs/test_readme_commands.py (README first, then readme_commands.PAGES, the tutorials and how-to guides in
the README's order, every shell block of theirs; then EXTRA_PAGES), so a page holding one must be in PAGES or
EXTRA_PAGES; outside those a command shown but not run is marked ```console."""

from __future__ import annotations

from tests.support.readme_commands import DOCS, EXTRA_PAGES, FENCE, PAGES


def test_every_page_with_a_bash_block_is_run_by_the_command_test() -> None:
    with_bash = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md") if FENCE.search(p.read_text())}
    missing = sorted(with_bash - set(PAGES) - set(EXTRA_PAGES))
    assert not missing, (f"```bash blocks that the command test does not run: {missing}; add the page to "
                         "the README's Documentation list or tests/support/readme_commands.py EXTRA_PAGES (and classify its commands) "
                         "or mark the blocks ```console")


def test_every_listed_page_exists() -> None:
    assert [p for p in (*PAGES, *EXTRA_PAGES) if not (DOCS / p).is_file()] == []
