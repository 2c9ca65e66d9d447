"""LICENSE, CITATION.cff and CHANGELOG.md agree with the package: its version and its license."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import hybridfit

ROOT = Path(__file__).resolve().parents[1]


def _top_level(text: str, key: str) -> str:
    """A top-level ``key: value`` of a YAML file (quotes removed)."""
    match = re.search(rf"^{re.escape(key)}:[ \t]*(.+)$", text, re.M)
    assert match, f"no top-level {key!r}"
    return match.group(1).strip().strip("\"'")


def test_the_citation_file_cites_this_version_and_the_paper():
    text = (ROOT / "CITATION.cff").read_text()
    assert _top_level(text, "cff-version") == "1.2.0"
    assert _top_level(text, "version") == hybridfit.__version__
    assert _top_level(text, "type") == "software" and _top_level(text, "title") == "hybridfit"
    assert "title: Hybrid One-Shot 3D Hand Pose Estimation by Exploiting Uncertainties" in text
    assert re.search(r"family-names: Poier\s+given-names: Georg", text)


def test_license_file_citation_and_pyproject_name_one_license():
    license = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["license"]["text"]
    assert license == "MIT"
    assert (ROOT / "LICENSE").read_text().splitlines()[0] == "MIT License"
    assert _top_level((ROOT / "CITATION.cff").read_text(), "license") == license


def test_the_changelog_has_this_version():
    assert re.search(rf"^## \[{re.escape(hybridfit.__version__)}\] - \d{{4}}-\d\d-\d\d$",
                     (ROOT / "CHANGELOG.md").read_text(), re.M)
