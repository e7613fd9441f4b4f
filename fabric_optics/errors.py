"""The errors of the Python interface and the wrapper that makes every exception reaching a caller one of them.

:mod:`fabric_optics.api` re-exports the error classes. Every exception a function of :mod:`fabric_optics.api` raises is a :class:`ToolkitError`:

- :class:`InputError` (also a :class:`ValueError`): a bad argument, config, plan or dataset; the
  message names the Python argument or the file and says what to do;
- :class:`OutputExistsError` (also a :class:`FileExistsError`): the output holds something and
  ``force`` was not given, or it is one that nothing replaces (a run folder);
  :class:`OutputBusyError`: another writer is writing that output now;
- :class:`FileSystemError` (also an :class:`OSError`, ``filename`` set): a file could not be read or
  written (a full disk, a folder without permission); the message names the file;
- :class:`InternalError`: anything else (a defect of the toolkit; the original is ``__cause__``).

A ``KeyboardInterrupt`` passes through unchanged.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["ToolkitError", "InputError", "OutputExistsError", "OutputBusyError", "FileSystemError",
           "InternalError", "typed_errors", "as_toolkit_error", "interrupt_of", "INPUT_ERROR_NAMES"]


class ToolkitError(Exception):
    """Base of the errors this interface raises.

    Catching it catches every failure of a call to the API (a ``KeyboardInterrupt`` aside), so a
    notebook or script can report a failed step and go on.

    Examples
    --------
    >>> import fabric_optics as fo
    >>> try:
    ...     fo.load_plan("no-such-plan")
    ... except fo.ToolkitError as exc:
    ...     print(type(exc).__name__)
    InputError
    """


class InputError(ToolkitError, ValueError):
    """A config, plan, dataset, parameter or value that cannot be used.

    The message names the argument or the file and says what to do; the library's own error is
    kept as ``__cause__``. It is also a :class:`ValueError`.
    """


class OutputExistsError(ToolkitError, FileExistsError):
    """The output path holds something already and ``force`` was not given.

    Nothing a user made is overwritten without being asked; an acquisition's run folder is never
    overwritten. It is also a :class:`FileExistsError`.
    """


class OutputBusyError(OutputExistsError):
    """Another writer (another process or thread) is writing the same output now; nothing was changed.

    Every writer claims its output (:mod:`gonio.data.claim`) so that two writers never interleave
    their files.
    """


class FileSystemError(ToolkitError, OSError):
    """A file could not be read or written (a full disk, no permission).

    ``filename`` and the message name the file. It is also an :class:`OSError`.
    """


class InternalError(ToolkitError):
    """An error the toolkit did not expect: a defect, to be reported with the call that made it.

    The original exception is ``__cause__``.
    """


# the public name of these classes is fabric_optics.api.X (tracebacks, pickles, docs)
for _cls in (ToolkitError, InputError, OutputExistsError, OutputBusyError, FileSystemError, InternalError):
    _cls.__module__ = "fabric_optics.api"

#: The libraries' errors for bad input, re-raised as :class:`InputError`: ``module.Class`` of each, so that
#: importing this module does not import the libraries (a class's module is loaded once it was raised)
INPUT_ERROR_NAMES: tuple[str, ...] = (
    "simulate.config_table.ConfigError", "gonio.acquisition.plan.schema.PlanError", "gonio.data.schema.DatasetError",
    "simulate.fabric.summation.FabricError", "compare.errors.CompareError", "gonio.mock.samples.SampleError",
    "simulate.budget.BudgetError", "simulate.montecarlo.transport.ParameterError", "simulate.geometry.weave.WeaveError",
    "gonio.acquisition.journal.JournalError", "fabric_optics.fitting.errors.FitError",
)


def _is_a(exc: BaseException, names: tuple[str, ...]) -> bool:
    """Whether ``exc`` is an instance of one of the classes ``names`` (``module.Class``), by its class's MRO."""
    return any(f"{cls.__module__}.{cls.__qualname__}" in names for cls in type(exc).__mro__)


_F = TypeVar("_F", bound=Callable[..., Any])


def interrupt_of(exc: BaseException) -> KeyboardInterrupt | None:
    """The :class:`KeyboardInterrupt` behind ``exc``, or None when there is none.

    That is ``exc`` itself, or the interrupt that a compiled extension turned into a
    :class:`SystemError` (``<built-in function ...> returned a result with an exception set``:
    Ctrl-C arriving while numba or numpy code runs a Python callback).

    Parameters
    ----------
    exc : BaseException
        The exception caught.

    Returns
    -------
    KeyboardInterrupt or None
        The interrupt, found through at most 16 causes or contexts.
    """
    cur: BaseException | None = exc
    for _ in range(16):
        if isinstance(cur, KeyboardInterrupt):
            return cur
        if not isinstance(cur, SystemError):
            return None
        cur = cur.__cause__ or cur.__context__
    return None


def as_toolkit_error(exc: BaseException) -> BaseException:
    """The :class:`ToolkitError` that stands for ``exc``.

    Parameters
    ----------
    exc : BaseException
        The exception caught.

    Returns
    -------
    BaseException
        ``exc`` itself when it is a :class:`ToolkitError` or not an :class:`Exception` (an interrupt);
        otherwise the typed error for it (``exc`` as its ``__cause__``): :class:`OutputBusyError`,
        :class:`OutputExistsError`, :class:`FileSystemError`, :class:`InputError` for the libraries'
        input errors, :class:`InternalError` for anything else.
    """
    if isinstance(exc, ToolkitError) or not isinstance(exc, Exception):
        return exc
    interrupt = interrupt_of(exc)
    if interrupt is not None:
        return interrupt
    if _is_a(exc, ("gonio.data.claim.OutputBusy",)):
        out: ToolkitError = OutputBusyError(str(exc))
    elif _is_a(exc, ("gonio.data.outputs.OutputRefused",)):
        out = OutputExistsError(str(exc))
    elif _is_a(exc, ("simulate.outdir.OutputError",)):
        out = FileSystemError(str(exc))
    elif _is_a(exc, INPUT_ERROR_NAMES):
        out = InputError(str(exc))
    elif isinstance(exc, OSError):
        if exc.errno and exc.filename:
            out = FileSystemError(exc.errno, exc.strerror, exc.filename)
        else:
            out = FileSystemError(f"{exc.filename}: {exc}" if exc.filename else str(exc))
    elif isinstance(exc, RecursionError):
        out = InputError(f"nested too deeply to be read ({exc})")
    elif isinstance(exc, MemoryError):
        out = InputError("the call needs more memory than there is; choose smaller sizes")
    else:
        out = InternalError(f"{type(exc).__name__}: {exc}")
    out.__cause__ = exc
    return out


def typed_errors(fn: _F) -> _F:
    """Make every exception that leaves ``fn`` a :class:`ToolkitError` (the original as ``__cause__``).

    Parameters
    ----------
    fn : callable
        A function of the API.

    Returns
    -------
    callable
        ``fn`` wrapped: a :class:`ToolkitError` or an interrupt passes through, any other exception is
        re-raised as :func:`as_toolkit_error` types it.
    """
    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except ToolkitError:
            raise
        except Exception as exc:     # noqa: BLE001 - the contract: only ToolkitError reaches the caller
            raise as_toolkit_error(exc) from exc
    return wrapper  # type: ignore[return-value]
