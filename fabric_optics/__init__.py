"""fabric-optics: the application layer above :mod:`gonio`, :mod:`simulate` and :mod:`compare`.

- :mod:`fabric_optics.api` (re-exported here): the Python interface -- load a config or plan,
  simulate, compare and check, fit, read and write datasets, export;
- :mod:`fabric_optics.fitting`: the inverse problem behind ``simulate fit``;
- :mod:`fabric_optics.sweep`: parameter studies on dask.distributed behind ``simulate sweep``;
- :mod:`fabric_optics.bench`: the benchmarks behind ``simulate bench``;
- :mod:`fabric_optics.cli`: the three command lines ``gonio``, ``simulate`` and ``compare``.

Nothing in ``gonio``, ``simulate`` or ``compare`` imports this package.
"""

from typing import TYPE_CHECKING, Any

from fabric_optics import api
from gonio.version import VERSION as __version__

__all__ = ["__version__", "FABRIC_METHODS", "FIT_METHODS", "IMPORT_FORMATS", "Comparison", "FileSystemError", "FitJob",
           "FitOutcome", "FitWarning", "InputError", "InternalError", "OutputBusyError", "OutputExistsError",
           "ToolkitError", "Verdict", "check", "compare", "export_bsdf", "fit", "import_measurement", "load_config",
           "load_plan", "measure_on_mock", "prepare_fit", "read_dataset", "simulate", "truth", "write_dataset",
           "write_report"]

if TYPE_CHECKING:
    from fabric_optics.api import (
        FABRIC_METHODS,
        FIT_METHODS,
        IMPORT_FORMATS,
        Comparison,
        FileSystemError,
        FitJob,
        FitOutcome,
        FitWarning,
        InputError,
        InternalError,
        OutputBusyError,
        OutputExistsError,
        ToolkitError,
        Verdict,
        check,
        compare,
        export_bsdf,
        fit,
        import_measurement,
        load_config,
        load_plan,
        measure_on_mock,
        prepare_fit,
        read_dataset,
        simulate,
        truth,
        write_dataset,
        write_report,
    )


def __getattr__(name: str) -> Any:
    """The API's ``name`` (:mod:`fabric_optics.api`), imported on first use."""
    if name in __all__:
        value = getattr(api, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    """Every public name, the ones not imported yet included."""
    return sorted(set(globals()) | set(__all__))
