"""The library entry points of ``compare`` document every parameter in a numpydoc ``Parameters`` section.

Ruff's numpy-convention rules (``D``, with ``D417``: every parameter of a ``Parameters`` section
described) hold the form; this test holds the presence of the section on the API a user calls.
"""

from __future__ import annotations

import importlib
import inspect
import re

import pytest

#: ``module:qualified name`` of the functions a user of ``compare`` calls
API = [
    "compare.comparison:compare_datasets", "compare.residual:ModelResidual", "compare.residual:ModelResidual.evaluate",
    "compare.align:align", "compare.bands:prepare", "compare.normalise:estimate_normal_value",
    "compare.normalise:normalisation_factor", "compare.metrics:curve_errors", "compare.colourmatch:colour_match",
    "compare.ratios:ring_directions", "compare.ratios:opposition_ratios", "compare.ratios:mirror_ratios",
    "compare.ratios:shape_document", "compare.report.build:write_report", "compare.inspect:write_dataset_report",
    "compare.sweep:read_sweep", "compare.sweep:point_metrics", "compare.sweep:write_sweep_report",
]


def _resolve(spec: str):
    module, name = spec.split(":")
    obj = importlib.import_module(module)
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj


def documented_parameters(doc: str) -> set[str]:
    """The names of a numpydoc ``Parameters`` section (``a, b : type`` lines at the section's indentation)."""
    m = re.search(r"^Parameters\n-{10,}\n(.*?)(?=^\S[^\n]*\n-{3,}\n|\Z)", doc, flags=re.S | re.M)
    if not m:
        return set()
    names = set()
    for line in m.group(1).splitlines():
        if line and not line[0].isspace():
            names |= {n.strip() for n in line.split(":")[0].split(",") if n.strip()}
    return names


def test_the_section_parser_reads_numpydoc():
    doc = "Summary.\n\nParameters\n----------\na, b : int\n    Two.\nc\n    Three.\n\nReturns\n-------\nint\n"
    assert documented_parameters(doc) == {"a", "b", "c"}
    assert documented_parameters("Summary.\n\nReturns\n-------\nint\n") == set()


@pytest.mark.parametrize("spec", API)
def test_every_parameter_of_the_api_is_documented(spec):
    obj = _resolve(spec)
    signature = inspect.signature(obj.__init__ if inspect.isclass(obj) else obj)
    wanted = {p for p in signature.parameters if p not in ("self", "cls")}
    doc = inspect.getdoc(obj) or ""
    documented = documented_parameters(doc)
    assert documented, f"{spec}: no numpydoc Parameters section"
    assert not wanted - documented, f"{spec}: parameters without a description: {sorted(wanted - documented)}"
    assert "\n" not in doc.split("\n\n")[0], f"{spec}: the summary is one line"
