"""The API's lazy imports: every name resolves, and a command pays only for what it uses."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

import fabric_optics
from fabric_optics import api
from fabric_optics.errors import INPUT_ERROR_NAMES, InputError, as_toolkit_error


@pytest.mark.parametrize("name", INPUT_ERROR_NAMES)
def test_every_input_error_name_is_an_exception_class(name):
    # a class moved or renamed would silently stop being typed as InputError
    module, _, cls = name.rpartition(".")
    obj = getattr(importlib.import_module(module), cls)
    assert isinstance(obj, type) and issubclass(obj, Exception)
    assert isinstance(as_toolkit_error(obj("bad")), InputError)


def test_a_subclass_of_an_input_error_is_an_input_error():
    from simulate.budget import BudgetError  # a ConfigError

    assert isinstance(as_toolkit_error(BudgetError("x")), InputError)
    assert not isinstance(as_toolkit_error(RuntimeError("x")), InputError)


def test_every_public_name_resolves_to_its_module_object():
    for name in api.__all__:
        assert getattr(api, name) is getattr(fabric_optics, name)
    assert api.fit is importlib.import_module("fabric_optics.api.fitting").fit
    assert set(api.__all__) <= set(dir(api))
    with pytest.raises(AttributeError):
        api.no_such_name  # noqa: B018
    with pytest.raises(AttributeError):
        fabric_optics.no_such_name  # noqa: B018


def test_the_gonio_command_line_does_not_load_the_simulation():
    code = ("import sys, fabric_optics.cli.gonio; "
            "print(sorted(m for m in ('numba', 'simulate.config', 'fabric_optics.fitting') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
