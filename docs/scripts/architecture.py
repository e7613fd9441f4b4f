"""The module map of docs/architecture.md against the code: which modules have no line, which lines no module.

The page's "Layout" section holds one fenced tree per package (``gonio/``, ``simulate/``, ``compare/``,
``fabric_optics/``): two spaces of indentation per level, one entry per line, a folder's name ending
in ``/`` (its line stands for its ``__init__.py``), then at least two spaces and a one-line description.
Anywhere on the page, a path such as ``gonio/acquisition/plan/parse.py`` must name a module that exists.

``python docs/scripts/architecture.py`` (``make architecture``) prints the modules without a line and the
lines without a module, and mends the page: a new module gets a line with the first sentence of its
docstring (to be edited into a better one), a line of a removed module goes. ``--check`` only prints
(exit 1 when the page and the code differ).
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "architecture.md"
PACKAGES = ("gonio", "simulate", "compare", "fabric_optics")
#: column at which a new line's description starts (the trees' own alignment)
DESCRIPTION_COLUMN = 27
#: a path to a module of the four packages named in the page's prose
PATH_IN_TEXT = re.compile(r"\b(?:" + "|".join(PACKAGES) + r")/[\w/]*\w\.py\b")
_ENTRY = re.compile(r"^(?P<indent> *)(?P<name>[\w.]+/|[\w.]+\.py)(?:\s{2,}(?P<text>\S.*))?$")


@dataclass(frozen=True)
class Entry:
    """One line of a tree: the path it names (``gonio/instrument/`` or ``gonio/instrument/head.py``)."""

    path: str
    line: int       # index into the page's lines
    depth: int


def code_entries(root: Path = ROOT) -> set[str]:
    """What the page must name: every module (``pkg/a/b.py``) and every sub-package folder (``pkg/a/``).

    Parameters
    ----------
    root : pathlib.Path
        The checkout that holds the four packages.

    Returns
    -------
    set of str
        Paths relative to ``root``, with ``/`` separators; a folder's ends in ``/``. The packages'
        own folders are not in it (the trees' first lines name them).
    """
    out = set()
    for pkg in PACKAGES:
        for path in (root / pkg).rglob("*.py"):
            rel = path.relative_to(root).as_posix()
            if path.name == "__init__.py":
                folder = rel.rsplit("/", 1)[0] + "/"
                if folder != f"{pkg}/":
                    out.add(folder)
            else:
                out.add(rel)
    return out


def _layout_span(lines: list[str]) -> tuple[int, int]:
    """The lines of the "Layout" section: its heading's index and the next section's (or the page's end)."""
    start = next(i for i, s in enumerate(lines) if s.strip() == "## Layout")
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
    return start, end


def page_entries(lines: list[str]) -> list[Entry]:
    """The tree entries of the Layout section, in page order.

    Parameters
    ----------
    lines : list of str
        The page's lines, without line ends.

    Returns
    -------
    list of Entry
        One per tree line below a package's first line, its path joined from the folders above it.

    Raises
    ------
    ValueError
        A line of a tree is not an entry (odd indentation, no name) or is indented below no folder;
        the message names the page's line.
    """
    start, end = _layout_span(lines)
    out: list[Entry] = []
    stack: list[str] = []
    in_tree = False
    for i in range(start, end):
        text = lines[i]
        if text.startswith("```"):
            is_open = not in_tree and i + 1 < end and lines[i + 1].strip() in {f"{p}/" for p in PACKAGES}
            if in_tree:
                in_tree = False
            elif is_open:
                in_tree, stack = True, [lines[i + 1].strip()]
            continue
        if not in_tree or text.strip() in {f"{p}/" for p in PACKAGES}:
            continue
        m = _ENTRY.match(text)
        if not m or len(m.group("indent")) % 2:
            raise ValueError(f"{PAGE.name}:{i + 1}: not a tree entry (two spaces per level, a name, "
                             f"two spaces, a description): {text!r}")
        depth = len(m.group("indent")) // 2
        if depth > len(stack) or depth < 1:
            raise ValueError(f"{PAGE.name}:{i + 1}: indented below no folder: {text!r}")
        del stack[depth:]
        path = "".join(stack) + m.group("name")
        out.append(Entry(path, i, depth))
        if path.endswith("/"):
            stack.append(m.group("name"))
    return out


def prose_paths(lines: list[str]) -> set[str]:
    """Module paths the page names in its text (outside the trees).

    Parameters
    ----------
    lines : list of str
        The page's lines.

    Returns
    -------
    set of str
        Every ``pkg/.../name.py`` of the four packages the lines mention.
    """
    return {m.group(0) for s in lines for m in PATH_IN_TEXT.finditer(s)}


def difference(lines: list[str], root: Path = ROOT) -> tuple[list[str], list[str]]:
    """``(missing, extra)``: modules without a line; lines and paths in the text that name no module.

    Parameters
    ----------
    lines : list of str
        The page's lines.
    root : pathlib.Path
        The checkout the page describes.

    Returns
    -------
    missing : list of str
        Modules and sub-package folders with no tree line, sorted.
    extra : list of str
        Tree lines that name no module (sorted), then paths in the text that name no file (sorted).
    """
    code = code_entries(root)
    named = {e.path for e in page_entries(lines)}
    missing = sorted(code - named)
    extra = sorted(named - code)
    extra += sorted(p for p in prose_paths(lines) if not (root / p).is_file() and p not in extra)
    return missing, extra


def first_sentence(path: Path) -> str:
    """The first sentence of a module's docstring (of the folder's ``__init__.py`` for a folder).

    Parameters
    ----------
    path : pathlib.Path
        A module, or a package's folder.

    Returns
    -------
    str
        The sentence on one line, without its final period; ``(no docstring)`` when there is none.
    """
    source = path / "__init__.py" if path.is_dir() else path
    doc = ast.get_docstring(ast.parse(source.read_text(encoding="utf-8"))) or "(no docstring)"
    text = " ".join(doc.split("\n\n")[0].split())
    m = re.match(r"(.+?\.)(?:\s|$)", text)
    return (m.group(1) if m else text).rstrip(".")


def mend(lines: list[str], root: Path = ROOT) -> tuple[list[str], list[str], list[str]]:
    """The page with a line for each missing module and without the lines of removed ones.

    A new line goes after its earlier siblings (in path order) and what they hold, its description the
    first sentence of the module's docstring, to be edited into a better one.

    Parameters
    ----------
    lines : list of str
        The page's lines (not changed).
    root : pathlib.Path
        The checkout the page describes.

    Returns
    -------
    lines : list of str
        The mended page.
    missing : list of str
        The modules given a line (as :func:`difference` returns them).
    extra : list of str
        The tree lines removed and the paths in the text that name no file (the text is left to edit).
    """
    missing, extra = difference(lines, root)
    entries = page_entries(lines)
    drop = {e.line for e in entries if e.path in extra}
    lines = [s for i, s in enumerate(lines) if i not in drop]
    for path in missing:                 # sorted: a folder before what it holds
        entries = page_entries(lines)
        parent = path.rstrip("/").rsplit("/", 1)[0] + "/"
        pkg = path.split("/", 1)[0] + "/"
        depth = parent.count("/")
        if parent == pkg:
            opening = next(i for i, s in enumerate(lines) if s.strip() == pkg and lines[i - 1].startswith("```"))
            after = opening
            siblings = [e for e in entries if e.depth == 1 and e.path.startswith(pkg)]
        else:
            holder = next(e for e in entries if e.path == parent)
            after = holder.line
            siblings = [e for e in entries if e.depth == depth and e.path.startswith(parent)]
        for e in siblings:
            if e.path < path:
                after = _subtree_end(entries, e)
        name = path.rstrip("/").rsplit("/", 1)[1] + ("/" if path.endswith("/") else "")
        head = "  " * depth + name
        lines.insert(after + 1, head.ljust(max(DESCRIPTION_COLUMN, len(head) + 2)) + first_sentence(root / path))
    return lines, missing, extra


def _subtree_end(entries: list[Entry], entry: Entry) -> int:
    """The last line of ``entry`` and what it holds."""
    end = entry.line
    for e in entries:
        if e.path.startswith(entry.path) and entry.path.endswith("/"):
            end = max(end, e.line)
    return end


def main(argv: list[str] | None = None) -> int:
    """Print how the page and the code differ and, without ``--check``, mend the page.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``--check``); ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0 when the page names every module and only modules (or, when mending, when only tree lines
        were wrong and are now mended); 1 when they differ under ``--check``, or when the text names a
        module that does not exist (that is left to edit).
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="print the difference only; exit 1 when there is one")
    args = parser.parse_args(argv)
    lines = PAGE.read_text(encoding="utf-8").splitlines()
    if args.check:
        missing, extra = difference(lines)
    else:
        new, missing, extra = mend(lines)
        if missing or extra:
            PAGE.write_text("\n".join(new) + "\n", encoding="utf-8")
    in_tree = {e.path for e in page_entries(lines)}
    for path in missing:
        print(f"missing: {path}" + ("" if args.check else "  (line added from its docstring: edit it)"))
    for path in extra:
        done = "  (line removed)" if path in in_tree else "  (named in the text: edit the text)"
        print(f"extra:   {path}" + ("" if args.check else done))
    if not (missing or extra):
        print(f"{PAGE.relative_to(ROOT)}: one line per module, every named module exists")
    return 1 if (missing or extra) and (args.check or not set(extra) <= in_tree) else 0


if __name__ == "__main__":
    sys.exit(main())
