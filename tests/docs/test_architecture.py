"""docs/architecture.md's module map is the code's: one line per module, no line without its module.

The trees of the page's "Layout" section and the module paths of its text are read by
docs/scripts/architecture.py (``make architecture`` mends the page); here they are checked against the
four packages, and the checker itself against a copy of the packages with a module added or removed.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _arch():
    spec = importlib.util.spec_from_file_location("architecture", ROOT / "docs" / "scripts" / "architecture.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["architecture"] = module
    spec.loader.exec_module(module)
    return module


arch = _arch()
LINES = arch.PAGE.read_text(encoding="utf-8").splitlines()


def _copy_of_the_packages(tmp_path: Path) -> Path:
    """The four packages' file tree (empty modules) under ``tmp_path``."""
    for pkg in arch.PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            target = tmp_path / path.relative_to(ROOT)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text("")
    return tmp_path


def test_every_module_has_a_line_and_every_named_module_exists():
    missing, extra = arch.difference(LINES)
    assert not missing and not extra, (
        f"docs/architecture.md: modules without a line {missing}, names without a module {extra}; "
        "run `make architecture` and edit the lines it adds")


def test_the_trees_cover_the_four_packages():
    paths = {e.path for e in arch.page_entries(LINES)}
    assert {"gonio/instrument/head.py", "simulate/montecarlo/kernel.py", "compare/report/build.py",
            "fabric_optics/cli/common.py", "gonio/data/formats/", "gonio/mock/__main__.py"} <= paths
    assert all(len(LINES[e.line].split(maxsplit=1)) == 2 for e in arch.page_entries(LINES)), "a line without words"


def test_a_module_added_without_its_line_fails_and_is_mended(tmp_path):
    root = _copy_of_the_packages(tmp_path)
    (root / "compare" / "brand_new.py").write_text('"""A new comparison. More words."""\n')
    (root / "simulate" / "optics" / "lens").mkdir()
    (root / "simulate" / "optics" / "lens" / "__init__.py").write_text('"""Lenses of one kind."""\n')
    (root / "simulate" / "optics" / "lens" / "thin.py").write_text('"""The thin lens."""\n')
    missing, extra = arch.difference(LINES, root)
    assert missing == ["compare/brand_new.py", "simulate/optics/lens/", "simulate/optics/lens/thin.py"]
    assert extra == []
    mended, _, _ = arch.mend(LINES, root)
    assert arch.difference(mended, root) == ([], [])
    added = [s for s in mended if s not in LINES]
    assert sorted(added) == ["      thin.py              The thin lens",
                             "    lens/                  Lenses of one kind",
                             "  brand_new.py             A new comparison"]
    # the folder's line is inside simulate's tree, under optics/, and holds its module
    entries = {e.path: e for e in arch.page_entries(mended)}
    assert entries["simulate/optics/lens/thin.py"].line == entries["simulate/optics/lens/"].line + 1
    optics = [e.line for e in entries.values() if e.path.startswith("simulate/optics/")]
    assert entries["simulate/optics/lens/"].line in range(min(optics), max(optics) + 1)


def test_a_removed_module_shows_as_extra_and_loses_its_line(tmp_path):
    root = _copy_of_the_packages(tmp_path)
    (root / "gonio" / "stats.py").unlink()
    missing, extra = arch.difference(LINES, root)
    assert (missing, extra) == ([], ["gonio/stats.py"])
    mended, _, _ = arch.mend(LINES, root)
    assert len(mended) == len(LINES) - 1 and not any(s.lstrip().startswith("stats.py ") for s in mended)
    assert arch.difference(mended, root) == ([], [])


def test_a_module_named_in_the_text_must_exist():
    lines = LINES + ["The plans are read in `gonio/acquisition/plans.py`."]
    assert arch.difference(lines)[1] == ["gonio/acquisition/plans.py"]


def test_a_line_that_is_not_an_entry_is_refused():
    start = next(i for i, s in enumerate(LINES) if s.strip() == "gonio/")
    lines = LINES[:start + 1] + [" instrument/ the instrument"] + LINES[start + 1:]
    with pytest.raises(ValueError, match="not a tree entry"):
        arch.page_entries(lines)


def test_every_page_of_the_manual_the_code_names_exists():
    """Docstrings, comments and messages (the report's words included) point to pages that exist."""
    import re

    named = {}
    for pkg in arch.PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            for m in re.finditer(r"\bdocs/[\w/.-]+\.md\b", path.read_text(encoding="utf-8")):
                named.setdefault(m.group(0), path.relative_to(ROOT).as_posix())
    assert "docs/how-to/fit.md" in named and "docs/notes/implementation.md" in named
    missing = {page: where for page, where in named.items() if not (ROOT / page).is_file()}
    assert not missing, f"pages named in the code that do not exist: {missing}"


#: references in files whose owners are rewriting them (reported to them); the test ignores these pairs
KNOWN_DANGLING = {("simulate/fabric/structure.py", "simulate.weave")}


def test_every_module_a_docstring_names_exists():
    """``:mod:`pkg.x``` references in the four packages name modules that exist (the docs site renders
    only the pages' own references)."""
    import re

    modules = set()
    for pkg in arch.PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            modules.add(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    pattern = re.compile(r":mod:`~?((?:" + "|".join(arch.PACKAGES) + r")(?:\.\w+)*)`")
    dangling = set()
    for pkg in arch.PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            rel = path.relative_to(ROOT).as_posix()
            dangling |= {(rel, m.group(1)) for m in pattern.finditer(path.read_text(encoding="utf-8"))
                         if m.group(1) not in modules}
    assert not dangling - KNOWN_DANGLING, f"references to modules that do not exist: {sorted(dangling - KNOWN_DANGLING)}"
