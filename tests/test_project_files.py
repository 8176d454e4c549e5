"""What a lab needs to adopt the project agrees with itself: the licence in LICENSE,
pyproject and CITATION.cff, the citation's version and paper, the lock file's form, and the
README's pointers to all of them and to the notebook."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

import jaxlc

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def test_the_licence_is_apache_2_everywhere():
    text = (ROOT / "LICENSE").read_text()
    assert text.split()[:4] == ["Apache", "License", "Version", "2.0,"]
    assert "END OF TERMS AND CONDITIONS" in text  # the whole licence, not a stub
    assert PYPROJECT["license"] == "Apache-2.0"  # an SPDX expression (PEP 639)


def test_the_citation_cites_this_version_and_the_paper():
    yaml = pytest.importorskip("yaml", reason="PyYAML comes with the dev extra (rejax)")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["version"] == PYPROJECT["version"] == jaxlc.__version__
    assert cff["license"] == "Apache-2.0" and cff["authors"]
    (paper,) = cff["references"]
    assert [a["family-names"] for a in paper["authors"]] == ["Wang", "Li", "Chan"]
    assert (paper["year"], paper["start"], paper["end"]) == (2019, 1454, 1460)
    assert "Intelligent Vehicles Symposium" in paper["collection-title"]
    assert "arXiv:1906.02275" in [i["value"] for i in paper["identifiers"]]


def test_the_lock_pins_every_package_exactly():
    lines = (ROOT / "requirements-lock.txt").read_text().splitlines()
    header = [line for line in lines if line.startswith("#")]
    pins = [line for line in lines if line and not line.startswith("#")]
    assert any("Python" in h or "CPython" in h for h in header)
    assert any("pip install -r requirements-lock.txt" in h for h in header)
    assert all(re.fullmatch(r"[A-Za-z0-9_.\-]+==[A-Za-z0-9_.+\-]+", p) for p in pins), pins
    names = {p.split("==")[0].lower().replace("_", "-") for p in pins}
    assert "jaxlc" not in names  # the project itself installs from the checkout
    deps = PYPROJECT["dependencies"] + PYPROJECT["optional-dependencies"]["dev"]
    wanted = {re.split(r"[<>=\[ ]", d)[0].lower().replace("_", "-") for d in deps}
    assert wanted <= names, wanted - names


def test_the_readme_points_to_them():
    readme = (ROOT / "README.md").read_text()
    for path in ("LICENSE", "CITATION.cff", "requirements-lock.txt", "examples/walkthrough.ipynb"):
        assert f"]({path})" in readme, path
        assert (ROOT / path).is_file(), path
