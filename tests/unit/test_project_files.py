"""The files a researcher looks for beside the code: the license, the changelog, the citation."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def test_the_license_file_is_the_license_the_metadata_names():
    project = _pyproject()
    assert project["license"] == "Apache-2.0"
    assert "LICENSE" in project["license-files"]
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text  # the whole text, not a pointer to it


def test_the_changelog_names_the_current_version():
    version = _pyproject()["version"]
    assert re.search(rf"^## \[{re.escape(version)}\]", (ROOT / "CHANGELOG.md").read_text(), re.M)


def test_the_citation_file_is_valid_cff_with_the_package_version_and_the_paper():
    yaml = pytest.importorskip("yaml", reason="PyYAML comes with the docs extra (MkDocs)")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    for key in ("cff-version", "message", "title", "authors", "version", "license"):
        assert cff.get(key), key
    assert cff["cff-version"] == "1.2.0"
    assert str(cff["version"]) == _pyproject()["version"]
    assert cff["license"] == _pyproject()["license"]
    paper = cff["preferred-citation"]
    assert paper["type"] == "article" and paper["title"].startswith("TRUAV:")
    assert [a["family-names"] for a in paper["authors"]] == ["Qaisar", "Zhang", "Chen", "Othman", "Chaudhry", "Liu"]
