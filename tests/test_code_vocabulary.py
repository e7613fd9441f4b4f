"""Code comments, docstrings and messages say what the code does: no issue numbers, no diary.

Every ``.py`` file of the four packages and of the tests is read as text and refused if it names an
issue by number, a project stop ("the seventh stop"), or a run date. The acquisition's *session* and
the accuracy loop's *rounds* are the code's own terms and are not matched.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("gonio", "simulate", "compare", "fabric_optics", "tests")

_ORDINALS = "first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth"
#: an issue by number; an ordinal project stop, "stop N" or "before-stop"; an ISO date (a run's); a machine load
HISTORY = re.compile(
    r"\bissues?\s+#?\d+" "|" r"\bissue\s+#\d+" "|"
    rf"\b(?:{_ORDINALS})[- ]stop\b" "|" r"\bstop\s+\d+\b" "|" r"\bbefore-stop\b" "|"
    r"\b20\d\d-[01]\d-[0-3]\d\b" "|" r"\bmachine load\b|\bload(?: average)? ~?\d|\bat load \d",
    re.IGNORECASE)

#: folders whose comments are rewritten last (by their owner); excluded until then -- delete an entry
#: when its folder is clean
EXCLUDED: tuple[str, ...] = ()
#: the vocabulary tests themselves (their examples are the vocabulary)
EXEMPT = {Path(__file__).resolve(), ROOT / "tests" / "docs" / "test_history_vocabulary.py"}


def _files() -> list[Path]:
    out = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if not rel.startswith(EXCLUDED):
                out.append(path)
    return out


@pytest.mark.parametrize("text", [
    "see issue 21", "(issues 18, 21)", "Issue 9: a reply", "until the seventh stop", "the ninth-stop preset",
    "stop 3 measured", "the before-stop review", "measured 2026-11-24", "issue #12", "load ~2.5 on 2 cores",
    "at load 3-4",
])
def test_the_pattern_finds_history(text):
    assert HISTORY.search(text)


def test_a_phrase_wrapped_across_lines_is_found(tmp_path, monkeypatch):
    """The scan joins each line with the next one's words: a wrapped "issue" / "19" is found."""
    pkg = tmp_path / "tests"
    pkg.mkdir()
    for j in range(201):
        (pkg / f"m{j}.py").write_text("x = 1\n")
    (pkg / "wrapped.py").write_text('"""In the published ranges (issue\n    19), not pink."""\n# a comment on the\n# stop\n')
    for name, value in (("ROOT", tmp_path), ("FOLDERS", ("tests",)), ("EXEMPT", set())):
        monkeypatch.setitem(globals(), name, value)
    with pytest.raises(AssertionError, match=r"wrapped\.py:1: 'issue 19'"):
        test_no_history_in_code()


@pytest.mark.parametrize("text", [
    "one acquisition session", "round 0 is the same photons", "stop_nm = 710", "the stop reason",
    "stops at its next tick", "a round(x, 2) value", "an issue with the link", "version 2026.1",
    "refused at load time", "a Client could hang under load",
])
def test_the_pattern_leaves_the_codes_own_words(text):
    assert not HISTORY.search(text)


def test_no_history_in_code():
    files = _files()
    assert len(files) > 200            # the walk sees the packages
    bad = []
    for path in files:
        if path.resolve() in EXEMPT:
            continue
        lines = path.read_text().splitlines()
        for no, line in enumerate(lines, 1):
            # each line with the next one's words after it: a phrase wrapped across lines
            # ("issue" at a line's end, its number on the next, a comment's "#" between) is found too
            after = lines[no].strip().lstrip("#").strip() if no < len(lines) else ""
            m = HISTORY.search(line) or HISTORY.search(f"{line} {after}")
            if m:
                bad.append(f"{path.relative_to(ROOT)}:{no}: {m.group(0)!r}")
    assert not bad, "history in code (state what the code does instead):\n" + "\n".join(bad)


#: narrative history in a module docstring (what the module was, how it came to be): a docstring says
#: what the module is and why; its history is in CHANGELOG.md, its measurements in docs/notes
NARRATIVE = re.compile(
    r"\b(?:a|the|its|an) (?:first|earlier|previous|older) (?:version|implementation|attempt)\b" "|"
    r"\bpreviously\b|\bformerly\b|\bas before\b|\bused to be\b|\bwas (?:rewritten|replaced by)\b",
    re.IGNORECASE)
#: folders left out of the narrative check (none: every module's docstring is held to it)
NARRATIVE_EXCLUDED: tuple[str, ...] = ()


@pytest.mark.parametrize("text", [
    "a first version re-weighted from the last walk", "the journal sums its events as before.",
    "previously the table was walked twice", "this module used to be two", "formerly simulate.woven.felt",
    "an earlier implementation looped entry cell outermost", "the loop was rewritten in numba",
])
def test_the_narrative_pattern_finds_history(text):
    assert NARRATIVE.search(text)


@pytest.mark.parametrize("text", [
    "never re-sent to an axis that is no longer homed", "the grid no longer resolves the ripple",
    "the points used to normalise", "the format's first version field", "before the first point",
    "the version of the format", "replaced by the new value when given",
])
def test_the_narrative_pattern_leaves_the_codes_own_words(text):
    assert not NARRATIVE.search(text)


def test_no_narrative_history_in_module_docstrings():
    bad = []
    for path in _files():
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith(("tests/",) + NARRATIVE_EXCLUDED):
            continue
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
        m = NARRATIVE.search(" ".join(doc.split()))
        if m:
            bad.append(f"{rel}: {m.group(0)!r}")
    assert not bad, "history in module docstrings (say what the module is; history goes to CHANGELOG.md):\n" \
        + "\n".join(bad)
