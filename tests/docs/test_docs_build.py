"""`make test` builds the manual: `mkdocs build --strict` into a temporary folder must succeed with no
warning (a broken link, a page missing from the navigation, an unresolved docstring reference)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(900)
def test_the_manual_builds_in_strict_mode(tmp_path):
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}     # the theme's notice about its successor
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                         cwd=ROOT, capture_output=True, text=True, env=env)
    log = run.stdout + run.stderr
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{log[-4000:]}"
    warnings = [line for line in log.splitlines() if line.startswith("WARNING")]
    assert not warnings, "\n".join(warnings)
    # pages are files, not folders (use_directory_urls: false): the site works opened from disk
    for page in ("index.html", "tutorials/mock-lab.html", "reference/cli.html", "reference/config.html",
                 "reference/plans.html", "reference/api.html", "explanation/felt-note.html"):
        assert (site / page).is_file(), f"the site has no {page}"
    # search from disk: the index inlined into a script, the worker shim served from the site itself
    assert (site / "search" / "search_index.js").read_text(encoding="utf-8").startswith("var __index = ")
    index = (site / "index.html").read_text(encoding="utf-8")
    assert "assets/iframe-worker/shim.js" in index and "unpkg.com" not in index
    assert "fonts.googleapis.com" not in index
    # the maths of the physics page: KaTeX delimiters for the bundled copy (rendered in tests/docs/test_browser.py)
    physics = (site / "physics.html").read_text(encoding="utf-8")
    assert physics.count('class="arithmatex"') >= 10 and (site / "assets/katex/katex.min.js").is_file()
    api = (site / "reference/api.html").read_text(encoding="utf-8")
    assert "read_dataset" in api and "Read and validate the dataset" in api   # mkdocstrings rendered it
    assert "measure_on_mock" in api and "simulate" in api


def test_the_readmes_links_lead_somewhere():
    """The README is read on its own (outside the site): every relative link and image it has exists."""
    import re

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = [t for t in re.findall(r"\]\(([^)#\s]+)", text) if not t.startswith(("http://", "https://"))]
    assert len(targets) >= 10
    missing = [t for t in targets if not (ROOT / t).exists()]
    assert not missing, f"README links to missing files: {missing}"


def test_the_readme_is_short():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 250
