"""Code comments, docstrings and messages say what the code does: no issue numbers, no diary.

Every ``.py`` file of the four packages and of the tests is read as text and refused if it names an
issue by number, a project stop ("the seventh stop"), or a run date. The acquisition's *session* and
the accuracy loop's *rounds* are the code's own terms and are not matched. Every line of the four
packages is also refused if it tells the code's history ("a first version...", "the old code took...",
"it used to..."): that goes to CHANGELOG.md, measured figures to docs/.
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


#: narrative history (what the code was, how it came to be): code, comments and docstrings say what the code is
#: and why; its history is in CHANGELOG.md, its measurements in docs/. Files a release wrote before this one
#: ("a killed per-file write of an older version"), the points "previously measured" of a resumed run, a
#: stale cache "running the old code" and "the state of a first attempt" are the code's own words and pass.
NARRATIVE = re.compile(
    r"\b(?:a|an|the|its|that|in an?) (?:first|earlier|previous) (?:version|implementation)s?\b"
    r"(?! of (?:the toolkit|fabric-optics|the package|a file))" "|"
    r"\b(?:an? |the |its )?earlier (?:code|attempt|design)s?\b" "|"
    r"\b(?:in|than|from|with) the old code\b|\bthe old code (?:was|did|had|took|used|ran|gave)\b" "|"
    r"\bpreviously\b(?! (?:measured|written|recorded|stored|saved|kept|computed|cached|accepted|journaled)\b)" "|"
    r"\bformerly\b|\bas before\b(?! (?:each|every|the|an?|it|its)\b)|\bused to be\b|\b(?:it|this|which|we) used to\b" "|"
    r"\b(?:was|were) (?:rewritten|replaced by|changed to)\b|\b(?:before|after|until) this change\b|\buntil now\b" "|"
    r"\bhistorically\b|\bin the past\b",
    re.IGNORECASE)


@pytest.mark.parametrize("text", [
    "a first version re-weighted from the last walk", "the journal sums its events as before.",
    "previously the table was walked twice", "this module used to be two", "formerly simulate.woven.felt",
    "an earlier implementation looped entry cell outermost", "the loop was rewritten in numba",
    "The first version looped entry cell outermost", "in an earlier version the fit re-walked",
    "the old code took 30 s", "twice as fast as in the old code", "it used to stop within the calibration",
    "the bins were replaced by a table", "the grid was replaced by a lattice", "before this change a run",
    "an earlier attempt sampled the steps", "the earlier code walked twice", "Previously, the journal",
    "until now the fit walked", "which used to print the raw counts",
])
def test_the_narrative_pattern_finds_history(text):
    assert NARRATIVE.search(text)


@pytest.mark.parametrize("text", [
    "never re-sent to an axis that is no longer homed", "the grid no longer resolves the ripple",
    "the points used to normalise", "the format's first version field", "before the first point",
    "the version of the format", "replaced by the new value when given",
    "a worked-in checkout would keep running the old code", "a killed per-file write of an older version",
    "the state of a first attempt", "points previously measured are skipped", "the first kernel call",
    "a dataset written by an earlier version of the toolkit", "the old folder is put back",
    "a lock file removed or replaced by someone else", "nothing was renamed", "the previous point's attempts",
    "the previous report's files are replaced", "the white standard as before each point",
])
def test_the_narrative_pattern_leaves_the_codes_own_words(text):
    assert not NARRATIVE.search(text)


def test_narrative_history_in_a_comment_or_wrapped_docstring_is_found(tmp_path, monkeypatch):
    """The package scan reads comments and function docstrings too, a phrase wrapped across lines included."""
    pkg = tmp_path / "gonio"
    pkg.mkdir()
    (pkg / "ok.py").write_text('"""Points previously measured are skipped."""\nx = 1  # the old folder is put back\n')
    (pkg / "loop.py").write_text('def f():\n    """Sum the terms.\n\n    The first\n    version looped twice."""\n')
    (pkg / "note.py").write_text("x = 1\n# it used to stop within the calibration\n")
    for name, value in (("ROOT", tmp_path), ("FOLDERS", ("gonio",)), ("EXEMPT", set())):
        monkeypatch.setitem(globals(), name, value)
    with pytest.raises(AssertionError) as caught:
        test_no_narrative_history_in_package_code()
    assert set(re.findall(r"gonio/\w+\.py:\d+", str(caught.value))) == {"gonio/loop.py:4", "gonio/note.py:2"}


def test_no_narrative_history_in_package_code():
    """Every line of the four packages (code, comments, docstrings), joined to the next line's words."""
    bad = []
    for path in _files():
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith("tests/") or path.resolve() in EXEMPT:
            continue
        lines = path.read_text(encoding="utf-8").splitlines()
        for no, line in enumerate(lines, 1):
            after = lines[no].strip().lstrip("#").strip() if no < len(lines) else ""
            m = NARRATIVE.search(f"{line} {after}")
            if m and m.start() < len(line):       # a phrase wholly on the next line is that line's
                bad.append(f"{rel}:{no}: {m.group(0)!r}")
    assert not bad, "history in code (say what the code is and why; history goes to CHANGELOG.md):\n" + "\n".join(bad)


def test_no_narrative_history_in_module_docstrings():
    """A module docstring read as one text: a phrase wrapped over any number of lines is found."""
    bad = []
    for path in _files():
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith("tests/"):
            continue
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
        m = NARRATIVE.search(" ".join(doc.split()))
        if m:
            bad.append(f"{rel}: {m.group(0)!r}")
    assert not bad, "history in module docstrings (say what the module is; history goes to CHANGELOG.md):\n" \
        + "\n".join(bad)
