"""Product text is a manual, not a diary: README.md, the pages of docs/ and the comments of the shipped
configs name no work stops or rounds, no numbered issues, no sessions, no run dates or times and no
machine loads.

The patterns are built so that the product's own words pass: "a safe stop", "the stop-all bit",
"photons added in rounds", "round trip", `gonio/acquisition/session.py`. The generated reference
pages are left out: their text is the code's own help and docstrings, kept clean in the code.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
GENERATED = {ROOT / "docs" / "reference" / n for n in ("cli.md", "config.md", "plans.md")}
ORDINAL = r"(?:first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth|\d+(?:st|nd|rd|th))"

#: name -> pattern of the history vocabulary (case-insensitive)
PATTERNS = {
    "a numbered or demonstrative stop": rf"\b(?:{ORDINAL}|this|that|previous|next|last|each|every|before|after) stop\b"
                                        r"|\bstops? (?:#?\d|[ivx]+\b)",
    "a numbered or demonstrative round": r"\b(?:this|that|previous|next|last) round\b(?! trip)"
                                         r"|\bround #?\d|\brounds alternated\b|\breview round\b",
    "an issue number": r"\bissues? ?#?\d+|\bthe issue'?s?\b",
    "a session": r"\bsessions?\b(?!\.py)",
    "a run date": r"\b20\d\d-[01]\d(?:-[0-3]\d)?\b",
    "a time of day": r"\b\d\d:\d\d(?:-\d\d:\d\d)? UTC\b|\bUTC\b",
    "a machine load": r"\bmachine load\b|\bload(?: average)? ~?\d|\bload average at\b|\bat load\b|\bunder load\b"
                      r"|\b(?:shared|loaded) machine\b|\bloaded by other\b|\bshared\s+with\s+other\s+jobs\b",
}


def product_text() -> list[Path]:
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "mkdocs.yml"]
    pages += [p for p in sorted((ROOT / "docs").rglob("*.md")) if p not in GENERATED]
    return pages


def config_comments(path: Path) -> str:
    """The comment text of a TOML file (keys and values are data, not prose)."""
    return "\n".join(m.group(1) for m in re.finditer(r"#(.*)$", path.read_text(encoding="utf-8"), flags=re.M))


def hits(text: str) -> list[str]:
    out = []
    for name, pattern in PATTERNS.items():
        for m in re.finditer(pattern, text, flags=re.I):
            line = text[:m.start()].count("\n") + 1
            out.append(f"line {line}: {name}: {m.group(0)!r}")
    return out


#: a release heading of CHANGELOG.md (Keep a Changelog: ``## [0.2.0] - 2026-12-07``): its date is the release's
RELEASE_HEADING = re.compile(r"^## \[\d+\.\d+\.\d+\] - 20\d\d-[01]\d-[0-3]\d$", flags=re.M)


@pytest.mark.parametrize("path", product_text(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_history_vocabulary_in_the_manual(path):
    text = path.read_text(encoding="utf-8")
    if path.name == "CHANGELOG.md":
        text = RELEASE_HEADING.sub("## release", text)
    found = hits(text)
    assert not found, f"{path.relative_to(ROOT)}: " + "; ".join(found[:10])


@pytest.mark.parametrize("path", sorted((ROOT / "simulate" / "configs").glob("*.toml")), ids=lambda p: p.name)
def test_no_history_vocabulary_in_config_comments(path):
    found = hits(config_comments(path))
    assert not found, f"{path.relative_to(ROOT)} comments: " + "; ".join(found[:10])


#: diary phrases the patterns must catch; joined from pieces (``_``) so that the code-vocabulary test, which
#: reads every .py file as text (tests/test_code_vocabulary.py), does not take them for history in code
_ = " ".join
DIARY = [_(["measured in the fifth", "stop"]), _(["since the ninth", "stop"]), "this stop's kernel",
         "three rounds each, rounds alternated", "review round 2", _(["as issue", "21 asked"]), "the issue's target",
         "in this session", "-".join(["2026", "11", "24"]), "20:14-20:16 UTC", "load average 0.9", "at load 3-4",
         "machine load was high", "on the shared machine", "a loaded machine", "2 cores shared with other jobs"]


@pytest.mark.parametrize("diary", DIARY)
def test_the_patterns_catch_the_diary(diary):
    assert hits(diary), diary


@pytest.mark.parametrize("product", [
    "the acquisition stops safely", "a safe stop closes the shutter", "the stop-all bit", "photons added in rounds",
    "the round trip of a dataset", "the controller's first round of photons", "gonio/acquisition/session.py", "stop reason reported", "rounded up",
    "a load of 2 kg", "the loaded dataset", "load a preset", "issued a warning",
])
def test_the_patterns_spare_the_product_words(product):
    assert not hits(product), product
