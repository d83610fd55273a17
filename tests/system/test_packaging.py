"""pyproject.toml uses the current license metadata, so building relayd warns about nothing.

A `project.license` table is deprecated by setuptools (a SetuptoolsDeprecationWarning on
every `pip install -e .`, and refused from 2027). The SPDX string form needs
setuptools >= 77 in the build requirements.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_license_is_an_spdx_string_with_its_file() -> None:
    doc = tomllib.loads((ROOT / "pyproject.toml").read_text())
    project = doc["project"]
    assert project["license"] == "MIT"
    assert not any(c.startswith("License ::") for c in project.get("classifiers", [])), (
        "license classifiers are deprecated next to an SPDX license"
    )
    for pattern in project["license-files"]:
        assert list(ROOT.glob(pattern)), pattern
    assert "MIT License" in (ROOT / "LICENSE").read_text()
    setuptools = [r for r in doc["build-system"]["requires"] if r.startswith("setuptools")]
    m = re.fullmatch(r"setuptools>=(\d+)(?:\.\d+)*", setuptools[0])
    assert m and int(m.group(1)) >= 77
