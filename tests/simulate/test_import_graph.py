"""The import graph of the four packages: layers point one way, no private name crosses a module.

Walks every module of ``gonio``, ``simulate``, ``compare`` and ``studies`` with :mod:`ast` (no
import is executed) and fails on

- a private name (``_x``) taken from another module: ``from m import _x``, or ``m._x`` where
  ``m`` is a module of the four packages bound by an import;
- ``simulate`` or ``gonio`` importing ``compare``, ``gonio`` importing ``simulate`` or
  ``studies``, ``compare`` importing ``simulate`` or ``studies``; ``simulate`` importing
  ``studies`` anywhere but in its command line (``simulate/cli.py`` runs the studies:
  ``studies`` <- cli);
- a layer of ``simulate`` importing one above it (optics <- media <- montecarlo <- fiber <-
  fabric <- woven, nonwoven <- products <- cli; config sits between fabric and woven).

Scope: ``gonio`` and ``compare`` are owned by other engineers while this test lands; their
known private-name crossings are listed in ``KNOWN_OTHERS`` (each one a finding for that owner,
reported to the lead) and tolerated, nothing else is. Remove entries as they are fixed: the test
then keeps them fixed. (``gonio`` had none when the test landed.)
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("gonio", "simulate", "compare", "studies")

#: Known private crossings in packages owned by others (importer module, imported module, name):
#: their work in progress; reported, not fixed here.
KNOWN_OTHERS: set[tuple[str, str, str]] = set()

#: Layers of simulate, lowest first; a module may import its own layer and those below.
LAYERS = (
    ("simulate.optics", "simulate.provenance"),
    ("simulate.media",),
    ("simulate.montecarlo",),
    ("simulate.fiber",),
    ("simulate.fabric",),
    ("simulate.config", "simulate.config_table"),
    ("simulate.woven", "simulate.nonwoven"),
    ("simulate.products", "simulate.export"),
    ("simulate.virtual",),
    ("simulate.cli", "simulate.__main__"),
)


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _resolve(importer: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    is_pkg = MODULES.get(importer, Path()).name == "__init__.py"
    base = importer.split(".")
    base = base if is_pkg else base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(name: str, path: Path):
    """(imported module, names taken, line) for every import; attribute uses of bound modules."""
    tree = ast.parse(path.read_text(), str(path))
    bound: dict[str, str] = {}  # local name -> module of ours
    found: list[tuple[str, str | None, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] in PACKAGES:
                    found.append((alias.name, None, node.lineno))
                    if alias.asname:
                        bound[alias.asname] = alias.name
        elif isinstance(node, ast.ImportFrom):
            module = _resolve(name, node)
            if module.split(".")[0] not in PACKAGES:
                continue
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                if sub in MODULES:  # `from pkg import module`
                    found.append((sub, None, node.lineno))
                    bound[alias.asname or alias.name] = sub
                else:
                    found.append((module, alias.name, node.lineno))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound:
            found.append((bound[node.value.id], node.attr, node.lineno))
    return found


def _private(attr: str | None) -> bool:
    return attr is not None and attr.startswith("_") and not (attr.startswith("__") and attr.endswith("__"))


def _layer(module: str) -> int | None:
    for i, names in enumerate(LAYERS):
        if any(module == n or module.startswith(n + ".") for n in names):
            return i
    return None


def _edges():
    for name, path in MODULES.items():
        for target, attr, line in _imports(name, path):
            yield name, path, target, attr, line


def test_the_graph_is_not_empty():
    """The walk sees the packages (a broken walk would pass every other test vacuously)."""
    edges = list(_edges())
    assert len(MODULES) > 80
    assert any(t == "simulate.fiber.model" for _, _, t, _, _ in edges)
    assert any(s.startswith("studies.") and t.startswith("compare") for s, _, t, _, _ in edges)


def test_no_private_name_crosses_a_module():
    bad = []
    for name, path, target, attr, line in _edges():
        if not _private(attr) or target == name:
            continue
        if name.startswith(("gonio", "compare")) and (name, target, attr) in KNOWN_OTHERS:
            continue
        bad.append(f"{path.relative_to(ROOT)}:{line}: {target}.{attr}")
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)


@pytest.mark.parametrize("importer,forbidden", [
    ("simulate", ("compare",)),
    ("gonio", ("compare", "studies", "simulate")),
    ("compare", ("simulate", "studies")),
])
def test_packages_point_one_way(importer, forbidden):
    bad = [f"{path.relative_to(ROOT)}:{line}: imports {target}" for name, path, target, _, line in _edges()
           if name.split(".")[0] == importer and target.split(".")[0] in forbidden]
    assert not bad, "\n".join(bad)


def test_only_the_command_line_of_simulate_runs_studies():
    bad = [f"{path.relative_to(ROOT)}:{line}: imports {target}" for name, path, target, _, line in _edges()
           if name.startswith("simulate") and name != "simulate.cli" and target.startswith("studies")]
    assert not bad, "\n".join(bad)


def test_simulate_layers_point_down():
    bad = []
    for name, path, target, _, line in _edges():
        a, b = _layer(name), _layer(target)
        if a is not None and b is not None and b > a:
            bad.append(f"{path.relative_to(ROOT)}:{line}: {name} (layer {a}) imports {target} (layer {b})")
    assert not bad, "\n".join(bad)
