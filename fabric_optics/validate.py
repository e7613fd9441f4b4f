"""The one validation layer of the arguments the command lines and the Python interface share.

The command lines parse text (``--threads 2``); the Python interface takes Python values
(``threads=2``). Both check the same ranges here, before any work: the command lines through their
argparse types and checks (:mod:`fabric_optics.cli.common`), the functions of
:mod:`fabric_optics.api` by calling these functions first. A bad value raises
:class:`~fabric_optics.errors.InputError` naming the Python argument (``threads=-1: ...``).

Types are strict where a wrong type would be taken silently: a ``bool`` is not an integer
(``threads=True``), a string is not a number (``max_evaluations='10'``), an integral float is not
an integer (``check_pairs=1.5``, ``10.0``), NaN and infinities are refused.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any, overload

from fabric_optics.errors import InputError

__all__ = ["MAX_SEED", "MAX_WAVELENGTHS", "MAX_CHECK_PAIRS", "MAX_AZIMUTHS", "MAX_MEASUREMENT_ROWS",
           "integer", "number", "rel_err", "seed", "threads", "choice", "flag", "text", "path", "out_path",
           "wavelengths", "cost", "measurement_rows", "claimed", "illuminant"]

#: Seeds of the fiber/fabric runs: the Monte Carlo derives per-batch streams as seed * 1_000_003 + ...
#: in 64-bit integers, so seeds stay below 2^31.
MAX_SEED = 2**31 - 1
#: Most wavelengths a model may be asked for (a 1 nm grid over 400..2399 nm).
MAX_WAVELENGTHS = 2000
#: Most random direction pairs at which an export measures its tabulation error (``--check``).
MAX_CHECK_PAIRS = 10**6
#: Most incidence azimuths of an anisotropic export (``--azimuths``).
MAX_AZIMUTHS = 64
#: Most rows (geometries x wavelengths or channels) of a measurement a fit accepts. A fit evaluates
#: the model at every measured geometry tens to hundreds of times; the largest measurement of the
#: project's data has ~6e4 rows. 10^6 rows take hours per evaluation and gigabytes of memory.
MAX_MEASUREMENT_ROWS = 200_000


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def integer(name: str, value: Any, lo: int, hi: int | None = None, *, none: bool = False) -> int | None:
    """``value`` as an ``int`` in ``[lo, hi]`` (``hi`` None: no upper bound); None passes with ``none``."""
    if value is None and none:
        return None
    if not _is_int(value):
        raise InputError(f"{name}={value!r}: expected an integer, got {type(value).__name__}")
    v = int(value)
    if v < lo or (hi is not None and v > hi):
        span = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise InputError(f"{name}={v}: must be an integer {span}")
    return v


def number(name: str, value: Any, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
           hi_open: bool = False, none: bool = False) -> float | None:
    """``value`` as a finite ``float`` within the bounds (open or closed); None passes with ``none``."""
    if value is None and none:
        return None
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        raise InputError(f"{name}={value!r}: expected a number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{name}={v!r}: expected a finite number")
    if lo is not None and (v < lo or (lo_open and v == lo)) or hi is not None and (v > hi or (hi_open and v == hi)):
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        raise InputError(f"{name}={v:g}: must be in {left}{'-inf' if lo is None else f'{lo:g}'}, "
                         f"{'inf' if hi is None else f'{hi:g}'}{right}")
    return v


def rel_err(name: str, value: Any, *, none: bool = True) -> float | None:
    """A target relative error in (0, 1) (None: the config's)."""
    return number(name, value, 0.0, 1.0, lo_open=True, hi_open=True, none=none)


def seed(name: str, value: Any, *, none: bool = True) -> int | None:
    """A seed in ``[0, MAX_SEED]`` (None: the config's)."""
    return integer(name, value, 0, MAX_SEED, none=none)


def threads(name: str, value: Any) -> int | None:
    """Threads: None (the config's), 0 (all numba allows) or 1..``NUMBA_NUM_THREADS``."""
    import numba

    return integer(name, value, 0, int(numba.config.NUMBA_NUM_THREADS), none=True)


def choice(name: str, value: Any, choices: Sequence[Any]) -> Any:
    """One of ``choices`` (compared by equality, ``bool``/``int`` kept apart)."""
    for c in choices:
        if type(value) is type(c) and value == c:
            return value
    raise InputError(f"{name}={value!r}: choose one of {', '.join(repr(c) for c in choices)}")


def flag(name: str, value: Any) -> bool:
    """A ``bool`` (``1`` and ``'yes'`` are not)."""
    if not isinstance(value, bool):
        raise InputError(f"{name}={value!r}: expected True or False, got {type(value).__name__}")
    return value


def text(name: str, value: Any, *, none: bool = False, max_len: int = 10_000) -> str | None:
    """A ``str`` of at most ``max_len`` characters; None passes with ``none``."""
    if value is None and none:
        return None
    if not isinstance(value, str):
        raise InputError(f"{name}={value!r}: expected a string, got {type(value).__name__}")
    if len(value) > max_len:
        raise InputError(f"{name}: {len(value):,} characters; at most {max_len:,}")
    return value


@overload
def path(name: str, value: Any) -> Path: ...


@overload
def path(name: str, value: Any, *, none: bool) -> Path | None: ...


def path(name: str, value: Any, *, none: bool = False) -> Path | None:
    """A path given as ``str`` or ``os.PathLike`` (no NUL character, not empty); ``None`` only with ``none``."""
    if value is None and none:
        return None
    if not isinstance(value, (str, os.PathLike)):
        raise InputError(f"{name}={value!r}: expected a path (str or os.PathLike), got {type(value).__name__}")
    p = os.fspath(value)
    if not isinstance(p, str):
        raise InputError(f"{name}={value!r}: expected a text path, got {type(p).__name__}")
    if not p or "\0" in p or len(p) > 4096:
        raise InputError(f"{name}={value!r}: not a usable path")
    return Path(p)


def out_path(name: str, value: Any, *, file: bool = False) -> Path:
    """An output path that can be written.

    Its nearest existing folder is a writable folder; ``file``: a file output, whose folder must exist.
    """
    p = path(name, value)
    parent = Path(os.path.abspath(p)).parent
    if file and not parent.is_dir():
        raise InputError(f"{name}={os.fspath(p)!r}: the folder {parent} does not exist; create it or choose another")
    while not parent.exists():
        if parent.is_symlink() or parent == parent.parent:
            break
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"{name}={os.fspath(p)!r}: {parent} is not a folder; choose an output in a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{name}={os.fspath(p)!r}: the folder {parent} cannot be written; choose another output")
    return p


def wavelengths(name: str, value: Any) -> tuple[float, ...] | None:
    """Model wavelengths in nm.

    Increasing, finite, within the dataset schema's range, at most :data:`MAX_WAVELENGTHS` (None: the config's).
    """
    from gonio.data.schema import WAVELENGTH_RANGE_NM

    if value is None:
        return None
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or not hasattr(value, "__iter__"):
        raise InputError(f"{name}={value!r}: expected a sequence of wavelengths in nm")
    if len(value) > MAX_WAVELENGTHS:
        raise InputError(f"{name}: {len(value):,} wavelengths; at most {MAX_WAVELENGTHS}")
    if len(value) == 0:
        raise InputError(f"{name}: no wavelength; give at least one")
    values = tuple(number(f"{name}[{k}]", v) for k, v in enumerate(value))
    # strict=False: each value beside the next (one pair fewer than values)
    if any(b <= a for a, b in zip(values, values[1:], strict=False)):     # type: ignore[operator]
        raise InputError(f"{name}: list the wavelengths increasing, each once")
    lo, hi = WAVELENGTH_RANGE_NM
    if values[0] < lo or values[-1] > hi:                    # type: ignore[operator]
        raise InputError(f"{name}: wavelengths must be in [{lo:g}, {hi:g}] nm, got {values[0]:g}..{values[-1]:g}")
    return values  # type: ignore[return-value]


def cost(config: Any, wavelengths_nm: Any, target: float | None, max_photons: int | None, *,
         runs: int = 1, name: str = "target_rel_err") -> str | None:
    """The cost estimate of the command lines (:func:`simulate.budget.check_cost`).

    A run estimated beyond a day is refused with :class:`InputError` (naming ``name``, the argument that sets it);
    returns the warning line of a run beyond ten minutes, else None.
    """
    from simulate.budget import BudgetError, check_cost

    target = config.target_rel_err if target is None else target
    max_photons = config.max_photons if max_photons is None else max_photons
    try:
        return check_cost(config, wavelengths_nm, target, max_photons, runs=runs)
    except BudgetError as exc:
        raise InputError(f"{name}: {exc}") from exc


def measurement_rows(what: str, rows: int, limit: int | None = None) -> None:
    """Refuse a measurement of more than ``limit`` rows (default :data:`MAX_MEASUREMENT_ROWS`) for a fit.

    ``what`` names its file or argument in the message.
    """
    limit = MAX_MEASUREMENT_ROWS if limit is None else limit
    if rows > limit:
        raise InputError(f"{what}: {rows:,} rows; a fit takes at most {limit:,} (it evaluates the model at every "
                         "row many times): thin the measurement (fewer geometries or wavelengths)")


@contextmanager
def claimed(name: str, out: Path, *, file: bool = False) -> Iterator[None]:
    """Hold the claim on the output ``out`` for the block (:func:`gonio.data.claim.claim_output`).

    For a function whose argument ``name`` gives it: another writer of ``out`` is refused at once
    (:class:`~fabric_optics.errors.OutputBusyError`), an output where no lock can be created (a folder
    that cannot be written) is an :class:`InputError` naming the argument. ``file``: a file output (its
    folder is not created for the lock).
    """
    from fabric_optics.errors import OutputBusyError
    from gonio.data.claim import OutputBusy, claim_output

    stack = ExitStack()
    try:
        stack.enter_context(claim_output(out, option=f"{name}=", parents=not file))
    except OutputBusy as exc:
        raise OutputBusyError(str(exc)) from exc
    except OSError as exc:
        raise InputError(f"{name}={os.fspath(out)!r}: cannot be written there ({exc.strerror or exc}); choose an "
                         "output in a writable folder") from exc
    with stack:
        yield


def illuminant(name: str, value: Any) -> str:
    """The name of an illuminant of the colour match: a key of colour-science's ``SDS_ILLUMINANTS``."""
    from gonio.data.colour import check_illuminant

    text(name, value, max_len=64)
    try:
        check_illuminant(value)
    except ValueError:
        raise InputError(f"{name}={value!r}: unknown illuminant; use a key of colour.SDS_ILLUMINANTS "
                         "such as 'D65'") from None
    return value
