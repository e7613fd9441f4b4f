"""Every dependency of the distribution is pinned to one version (pyproject.toml): a new release of a library must
not move a fit, a figure or a printed output the docs show without an upgrade made on purpose."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def unpinned(requirements: list[str]) -> list[str]:
    """The requirements that do not name exactly one version (``name[extras]==version``)."""
    return [r for r in requirements if not re.fullmatch(r"[A-Za-z0-9_.-]+(\[[A-Za-z0-9_,.-]+\])?==[0-9][^,;<>=!~ ]*", r)]


def test_every_dependency_and_extra_is_pinned():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        requirements += extra
    assert len(requirements) > 20
    assert unpinned(requirements) == []


def test_a_range_or_a_bare_name_is_found():
    assert unpinned(["numpy>=2.0,<3", "scipy", "dask[distributed]>=2025.1", "numpy==2.4.6",
                     "pymodbus[serial]==3.16.1", "x==1.0,<2"]) == [
        "numpy>=2.0,<3", "scipy", "dask[distributed]>=2025.1", "x==1.0,<2"]
