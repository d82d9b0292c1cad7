"""Release metadata: one version, a changelog entry for it, the licence and the type marker.

The version's single source is ``pyproject.toml``; ``bikeid.__version__`` reads it from the
installed metadata, so the two cannot drift. The changelog (Keep a Changelog) must open
with the current version, so a version bump without a changelog entry fails here.
"""

from __future__ import annotations

import importlib.metadata
import re
import tomllib
from itertools import pairwise
from pathlib import Path

from packaging.version import InvalidVersion, Version  # a dependency of pytest

import bikeid

ROOT = Path(__file__).resolve().parents[1]


def test_version_is_the_installed_metadata():
    assert bikeid.__version__ == importlib.metadata.version("bikeid")


def test_version_is_pep440_and_pyproject_is_its_source():
    try:
        Version(bikeid.__version__)
    except InvalidVersion as exc:  # pragma: no cover - the failure message is the point
        raise AssertionError(f"{bikeid.__version__!r} is not a PEP 440 version") from exc
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "version" not in project.get("dynamic", [])
    assert project["version"] == bikeid.__version__, (
        "the installed metadata is stale: reinstall (pip install -e .) after a version bump"
    )


def test_changelog_top_entry_is_the_version():
    text = (ROOT / "CHANGELOG.md").read_text()
    entries = re.findall(r"^## \[([^\]]+)\]", text, re.MULTILINE)
    assert entries, "CHANGELOG.md has no '## [version]' entries"
    assert entries[0] == bikeid.__version__, f"top entry {entries[0]}, version {bikeid.__version__}"
    assert len(set(entries)) == len(entries), f"duplicate entries: {entries}"
    assert all(Version(e) > Version(f) for e, f in pairwise(entries)), (
        f"entries not newest first: {entries}"
    )


def test_license_is_mit_and_declared():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License")
    assert "Copyright (c) 2026 the bikeid developers" in text
    assert "Permission is hereby granted, free of charge, to any person obtaining a copy" in text
    assert 'THE SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND' in text
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"
    assert project["license-files"] == ["LICENSE"]
    assert importlib.metadata.metadata("bikeid")["License-Expression"] == "MIT"


def test_py_typed_marker_in_package_dir():
    assert (Path(bikeid.__file__).resolve().parent / "py.typed").is_file()
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "py.typed" in data["tool"]["setuptools"]["package-data"]["bikeid"]
