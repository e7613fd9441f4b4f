"""The import graph of the four packages: layers point one way, no cycles, no private name crosses a module.

Walks every module of ``gonio``, ``simulate``, ``compare`` and ``fabric_optics`` with :mod:`ast`
(no import is executed; imports inside functions count as much as those at the top) and fails on

- a private name (``_x``) taken from another module: ``from m import _x``, or ``m._x`` where
  ``m`` is a module of the four packages bound by an import;
- ``gonio`` importing ``simulate``, ``compare`` or ``fabric_optics``; ``compare`` importing
  ``simulate`` or ``fabric_optics``; ``simulate`` importing ``compare`` or ``fabric_optics``
  (``fabric_optics`` is the application layer on top: the API, fit, sweep, benchmarks and the
  command lines);
- a layer of ``simulate`` or of ``fabric_optics`` importing one above it (optics <- media <-
  montecarlo <- fiber <- geometry <- fabric <- config <- raytrace, structwalk <- products <- virtual;
  paths <- fit <- sweep <- api <- bench <- cli);
- a cycle: modules that import each other, directly or around a loop.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("gonio", "simulate", "compare", "fabric_optics")

#: Known private crossings in packages owned by others (importer module, imported module, name):
#: their work in progress; reported, not fixed here.
KNOWN_OTHERS: set[tuple[str, str, str]] = set()

#: Layers of simulate, lowest first; a module may import its own layer and those below.
LAYERS = (
    ("simulate.optics", "simulate.provenance"),
    ("simulate.media",),
    ("simulate.montecarlo",),
    ("simulate.fiber",),
    ("simulate.geometry",),
    ("simulate.fabric",),
    ("simulate.config", "simulate.config_table"),
    ("simulate.raytrace", "simulate.structwalk"),
    ("simulate.products", "simulate.export"),
    ("simulate.virtual",),
)

#: Layers of fabric_optics, lowest first.
APP_LAYERS = (
    ("fabric_optics.paths",),
    ("fabric_optics.fitting",),
    ("fabric_optics.sweep",),
    ("fabric_optics.api", "fabric_optics"),
    ("fabric_optics.bench",),
    ("fabric_optics.cli",),
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


def _layer(module: str, layers=LAYERS) -> int | None:
    best = None
    for i, names in enumerate(layers):
        for n in names:
            if (module == n or module.startswith(n + ".")) and (best is None or len(n) > best[1]):
                best = (i, len(n))
    return None if best is None else best[0]


@functools.cache
def _all_edges() -> tuple[tuple[str, Path, str, str | None, int], ...]:
    """Every (module, its file, imported module, name taken, line), parsed once for the module's tests."""
    return tuple((name, path, target, attr, line)
                 for name, path in MODULES.items() for target, attr, line in _imports(name, path))


def _edges():
    yield from _all_edges()


def test_the_graph_is_not_empty():
    """The walk sees the packages (a broken walk would pass every other test vacuously)."""
    edges = list(_edges())
    assert len(MODULES) > 80
    assert any(t == "simulate.fiber.model" for _, _, t, _, _ in edges)
    assert any(s.startswith("fabric_optics.") and t.startswith("compare") for s, _, t, _, _ in edges)


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
    ("simulate", ("compare", "fabric_optics")),
    ("gonio", ("compare", "simulate", "fabric_optics")),
    ("compare", ("simulate", "fabric_optics")),
])
def test_packages_point_one_way(importer, forbidden):
    bad = [f"{path.relative_to(ROOT)}:{line}: imports {target}" for name, path, target, _, line in _edges()
           if name.split(".")[0] == importer and target.split(".")[0] in forbidden]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("layers", [LAYERS, APP_LAYERS], ids=["simulate", "fabric_optics"])
def test_layers_point_down(layers):
    bad = []
    for name, path, target, _, line in _edges():
        a, b = _layer(name, layers), _layer(target, layers)
        if a is not None and b is not None and b > a:
            bad.append(f"{path.relative_to(ROOT)}:{line}: {name} (layer {a}) imports {target} (layer {b})")
    assert not bad, "\n".join(bad)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            node, it = work[-1]
            for nxt in it:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                    break
                if nxt in on:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def _graph() -> dict[str, set[str]]:
    """Module -> modules it imports. A package's ``__init__`` importing its own submodules (to
    re-export them) is not an edge: a submodule that imports the package's re-exports would make
    every such package a cycle, and Python resolves that order without harm."""
    graph: dict[str, set[str]] = {name: set() for name in MODULES}
    for name, _, target, _, _ in _edges():
        if target in MODULES and target != name:
            is_pkg = MODULES[name].name == "__init__.py"
            if is_pkg and target.startswith(name + "."):
                continue
            graph[name].add(target)
    return graph


def test_the_cycle_finder_finds_cycles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles():
    cycles = _cycles(_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)
