"""Public functions of the documented packages carry a numpydoc ``Parameters`` section.

A public function is a module-level function or a method of a public class whose name does not start
with ``_``; one that takes parameters (other than ``self`` / ``cls``) must say what each is in a
``Parameters`` section. ruff's D417 checks the parameters of a section that is there; this test
checks that the section is there, and names every parameter it leaves out. :data:`DOCUMENTED` lists
the folders held to it: add a folder here when its public functions are documented.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: folders (and their subfolders) whose public functions must document their parameters
DOCUMENTED = ("compare", "fabric_optics/api", "fabric_optics/fitting")

_HEADER = re.compile(r"^(\s*)Parameters\n\1-{3,}\n", re.MULTILINE)
_SECTION_END = re.compile(r"^\s*\S.*\n\s*-{3,}\s*$", re.MULTILINE)


def _public_functions(tree: ast.Module):
    """``(qualified name, node)`` of the module's public functions and its public classes' public methods."""
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_"):
            yield node.name, node
        elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            for sub in node.body:
                if isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef)) and not sub.name.startswith("_"):
                    yield f"{node.name}.{sub.name}", sub


def _parameters(node: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> list[str]:
    """The names a ``Parameters`` section must describe (``self`` / ``cls`` of a method left out)."""
    a = node.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    names += [x.arg for x in (a.vararg, a.kwarg) if x is not None]
    decorators = {ast.unparse(d) for d in node.decorator_list}
    if method and "staticmethod" not in decorators and names and names[0] in ("self", "cls"):
        names = names[1:]
    return names


def _documented(docstring: str) -> set[str] | None:
    """The names a docstring's ``Parameters`` section describes (``a, b : float`` is two), None without one."""
    match = _HEADER.search(docstring)
    if match is None:
        return None
    indent = match.group(1)
    body = docstring[match.end():]
    end = _SECTION_END.search(body)
    body = body[:end.start()] if end else body
    names = set()
    for line in body.splitlines():
        if line.startswith(indent) and line[len(indent):len(indent) + 1] not in ("", " "):
            head = line[len(indent):].split(":")[0]
            names.update(n.strip().lstrip("*") for n in head.split(","))
    return names


def undocumented(source: str, where: str = "<source>") -> list[str]:
    """One line per public function of ``source`` without a ``Parameters`` section or missing a parameter in it."""
    out = []
    for name, node in _public_functions(ast.parse(source)):
        if any(ast.unparse(d).endswith(".setter") for d in node.decorator_list):
            continue                       # a property's setter: the property says what it holds
        params = _parameters(node, "." in name)
        if not params:
            continue
        documented = _documented(ast.get_docstring(node) or "")
        if documented is None:
            out.append(f"{where}:{node.lineno}: {name}() has no Parameters section (for {', '.join(params)})")
            continue
        missing = [p for p in params if p not in documented]
        if missing:
            out.append(f"{where}:{node.lineno}: {name}() does not describe {', '.join(missing)} in its "
                       "Parameters section")
    return out


def _files() -> list[Path]:
    return sorted(p for folder in DOCUMENTED for p in (ROOT / folder).rglob("*.py"))


_GOOD = '''
def scale(x, factor=2.0):
    """Scale ``x``.

    Parameters
    ----------
    x, factor : float
        The value and the factor.

    Returns
    -------
    float
        The product.
    """
    return x * factor


def _helper(y):
    return y


class Thing:
    def area(self, *, width):
        """The area.

        Parameters
        ----------
        width : float
            The width (m).
        """

    @property
    def size(self):
        return 1


class _Private:
    def run(self, z):
        return z
'''


def test_a_documented_source_passes():
    assert undocumented(_GOOD) == []


def test_a_function_without_a_parameters_section_is_named():
    source = 'def f(a, b):\n    """Sum ``a`` and ``b``."""\n    return a + b\n'
    assert undocumented(source, "m.py") == ["m.py:1: f() has no Parameters section (for a, b)"]


def test_a_method_without_a_parameters_section_is_named():
    source = _GOOD + 'class Other:\n    def go(self, speed):\n        """Go."""\n'
    (line,) = undocumented(source)
    assert "Other.go() has no Parameters section (for speed)" in line


def test_a_parameter_left_out_of_the_section_is_named():
    source = ('def f(a, b, *rest, **options):\n    """Sum.\n\n    Parameters\n    ----------\n    a : float\n'
              '        First.\n    *rest : float\n        More.\n\n    Returns\n    -------\n    b : float\n'
              '        Not a parameter.\n    """\n')
    (line,) = undocumented(source)
    assert "f() does not describe b, options" in line


def test_the_walk_sees_the_documented_folders():
    files = _files()
    rel = {p.relative_to(ROOT).as_posix() for p in files}
    assert "compare/report/page.py" in rel and "fabric_optics/api/comparison.py" in rel
    counted = sum(1 for p in files for name, node in _public_functions(ast.parse(p.read_text(encoding="utf-8")))
                  if _parameters(node, "." in name))
    assert counted > 100


@pytest.mark.parametrize("folder", DOCUMENTED)
def test_public_functions_document_their_parameters(folder):
    bad = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        bad += undocumented(path.read_text(encoding="utf-8"), path.relative_to(ROOT).as_posix())
    assert not bad, "public functions without a numpydoc Parameters section:\n" + "\n".join(bad)
