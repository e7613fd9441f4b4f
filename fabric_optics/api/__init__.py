"""The Python interface of fabric-optics: what the command lines do, as functions.

Load a config or plan, measure on the mock instrument or import a measurement, simulate a fabric at
a plan's geometries, compare datasets and judge the comparison, write the report, fit config
parameters to a measurement, read and write datasets, export to a renderer. Every function returns
the project's own objects (a `Dataset` holds a pandas table in `.table` and its metadata in
`.meta`), raises `InputError` (a `ToolkitError`) for bad input instead of exiting, and shows a
progress bar only when `progress=True`. The tutorial "Python, from measurement to report" runs a
whole chain.

Examples
--------
>>> import fabric_optics as fo
>>> fo.load_config("red-cotton").name
'red-cotton'
>>> fo.load_config("no-such-preset")
Traceback (most recent call last):
...
fabric_optics.api.InputError: ...no-such-preset...
"""

import importlib
from typing import TYPE_CHECKING, Any

from fabric_optics.errors import (
    FileSystemError,
    InputError,
    InternalError,
    OutputBusyError,
    OutputExistsError,
    ToolkitError,
)

if TYPE_CHECKING:
    from fabric_optics.api.comparison import Comparison, Verdict, check, compare, write_report
    from fabric_optics.api.export import export_bsdf
    from fabric_optics.api.fitting import FIT_METHODS, FitJob, FitOutcome, FitWarning, fit, prepare_fit
    from fabric_optics.api.loading import load_config, load_plan, read_dataset, write_dataset
    from fabric_optics.api.measurement import IMPORT_FORMATS, import_measurement, measure_on_mock, truth
    from fabric_optics.api.simulation import FABRIC_METHODS, simulate

#: each function's or class's module: it is imported on first use, so that a command or script pays for the
#: parts of the toolkit it calls (a measurement on the mock does not load the simulation's compiled kernels)
_MODULE_OF = {name: module for module, names in {
    'comparison': ('Comparison', 'Verdict', 'check', 'compare', 'write_report'),
    'export': ('export_bsdf',),
    'fitting': ('FIT_METHODS', 'FitJob', 'FitOutcome', 'FitWarning', 'fit', 'prepare_fit'),
    'loading': ('load_config', 'load_plan', 'read_dataset', 'write_dataset'),
    'measurement': ('IMPORT_FORMATS', 'import_measurement', 'measure_on_mock', 'truth'),
    'simulation': ('FABRIC_METHODS', 'simulate'),
}.items() for name in names}


def __getattr__(name: str) -> Any:
    """The API's function or class ``name``, its module imported on first use (PEP 562)."""
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """Every public name, the ones not imported yet included."""
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "ToolkitError", "InputError", "OutputExistsError", "OutputBusyError", "FileSystemError", "InternalError",
    "load_config", "load_plan", "read_dataset", "write_dataset",
    "measure_on_mock", "truth", "simulate", "compare", "check", "Verdict", "fit", "prepare_fit", "FitJob",
    "FitOutcome", "FitWarning", "export_bsdf", "import_measurement", "write_report", "Comparison",
    "FABRIC_METHODS", "FIT_METHODS", "IMPORT_FORMATS",
]
