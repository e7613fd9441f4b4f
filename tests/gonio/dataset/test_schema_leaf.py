"""gonio.data's import graph: schema is a leaf, interpolate does not import dataset at
run time and reads no private attribute of a Dataset."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np

from gonio.data import make_dataset, new_meta

DATA = Path(__file__).resolve().parents[3] / "gonio" / "data"


def _runtime_imports(path: Path) -> set[str]:
    """Modules imported by ``path`` outside ``if TYPE_CHECKING:`` blocks."""
    tree = ast.parse(path.read_text())
    type_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                 and getattr(node.test, "id", None) == "TYPE_CHECKING"
                 for n in ast.walk(node)}
    out = set()
    for node in ast.walk(tree):
        if id(node) in type_only:
            continue
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_schema_is_a_leaf_and_interpolate_does_not_import_dataset():
    assert not {m for m in _runtime_imports(DATA / "schema.py") if m.startswith("gonio")}
    assert "gonio.data.dataset" not in _runtime_imports(DATA / "interpolate.py")
    assert "gonio.data.schema" in _runtime_imports(DATA / "interpolate.py")


def test_interpolate_reads_no_private_attribute_of_a_dataset():
    tree = ast.parse((DATA / "interpolate.py").read_text())
    private = [n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)
               and n.attr.startswith("_") and getattr(n.value, "id", None) == "dataset"]
    assert private == []


def test_derived_values_are_built_once_per_key():
    table = {"theta_i": [0.0, 0.0], "phi_i": [0.0, 0.0], "theta_o": [10.0, 30.0],
             "phi_o": [180.0, 180.0], "wavelength_nm": [550.0, 550.0], "beta": [0.5, 0.7],
             "u_beta": [0.01, 0.01], "n": [1, 1]}
    ds = make_dataset(table, new_meta("simulated", {"name": "x"}))
    built = []
    for _ in range(3):
        assert ds.derived("k", lambda: built.append(1) or "value") == "value"
    assert built == [1]
    # the interpolator (one per rotation) is built once and reused by later requests
    beta, _ = ds.interpolate(0.0, 0.0, 20.0, 180.0, 550.0)
    assert np.isclose(beta, 0.6)
    keys = list(ds._derived)
    assert np.isclose(ds.interpolate(0.0, 0.0, 25.0, 180.0, 550.0)[0], 0.65)
    assert list(ds._derived) == keys and len(keys) == 2
