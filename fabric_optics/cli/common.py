"""The vocabulary of the ``gonio``, ``simulate`` and ``compare`` command lines, and their argument helpers.

All three command lines use these helpers, so that one concept has one name, one syntax and one default.

=====================  ==========================================================================
concept                spelling (every command that has the concept)
=====================  ==========================================================================
plan                   ``--plan PLAN``: a preset name or a TOML path. Default ``red-cotton`` where
                       a default makes sense (``gonio demo``, ``gonio bench-driver``, ``simulate
                       fabric``, ``simulate sweep``); required by ``gonio acquire``, ``replay``,
                       ``truth`` and ``check-plan``; optional in ``gonio import`` (without it:
                       the file's own geometries).
measured dataset       the positional ``MEASURED`` (a dataset folder) wherever it is required
                       (``simulate fit CONFIG MEASURED``, ``compare report|check MEASURED ...``);
                       ``simulate sweep CONFIG [MEASURED]`` takes it as an optional positional.
simulated dataset      the positional ``SIMULATED`` after ``MEASURED`` (``compare``).
config                 the positional ``CONFIG``: a preset name or a TOML path (``simulate``).
wavelengths            ``--wavelengths``: ``NM,NM,...`` (increasing) or ``START:STOP:STEP``
                       (inclusive stop); finite, within the dataset schema's range
                       (:data:`gonio.data.schema.WAVELENGTH_RANGE_NM`), at most
                       :data:`MAX_WAVELENGTHS` values. Default: the config's.
fabric model           ``--method summation|classic|mc|auto`` (``auto`` only in ``simulate fabric``).
fiber route            ``--route nee|beam|bssrdf`` (``simulate fiber``; default: the config's).
threads                ``--threads N``: 0 = all numba allows; default 0. Results do not depend on it.
                       ``simulate sweep`` is the one exception in its default: 1 thread per task,
                       because its worker processes are the parallelism (0 there would start
                       workers x cores threads).
target error           ``--target-rel-err X`` in (0, 1): default the config's ``target_rel_err``.
seed                   ``--seed N``: default the config's (``gonio``: the mock's seed, default 0).
output                 ``--out PATH`` and ``--force`` on every command that writes: an existing
                       output (a file, or a folder holding anything) is replaced only with
                       ``--force``; ``--resume`` continues a run instead (``gonio acquire``,
                       ``simulate fit``, ``simulate sweep``). A run folder (one holding a
                       journal of measurements) is never replaced, not even with ``--force``.
                       The one rule of every writer: :mod:`gonio.data.outputs`.
verbosity              ``-v/--verbose``, before or after the subcommand.
progress               ``--no-progress`` on every command that can show a progress bar (a bar
                       is shown only on a terminal anyway).
budgets                ``--max-evaluations N``: model evaluations of a summation or classic fit;
                       ``--max-runs N``: Monte Carlo runs of a ``--method mc`` fit;
                       ``--max-photons N``: the Monte Carlo's photon budget.
=====================  ==========================================================================

A usage error is one line on stderr (``PROG SUBCOMMAND: error: ...``), exit status 2
(:mod:`fabric_optics.cli.registry`, which runs every command).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from typing import NoReturn

from fabric_optics import validate as _validate
from gonio.data import outputs as _outputs

__all__ = ["Parser", "UsageError", "MAX_WAVELENGTHS", "parse_wavelengths", "wavelengths_arg", "int_in", "finite_number",
           "threads_arg", "rel_err_arg", "add_plan", "add_wavelengths", "add_threads", "add_target_rel_err",
           "add_seed", "add_force", "add_verbose", "add_no_progress",
           "plan_of", "refuse_existing", "claim", "progress", "MAX_SEED", "DEFAULT_PLAN"]

#: The plan used where a command has a default plan.
DEFAULT_PLAN = "red-cotton"
#: Most wavelengths a ``--wavelengths`` may name, and the largest seed: the bounds of the one
#: validation layer that the Python interface applies too (:mod:`fabric_optics.validate`).
MAX_WAVELENGTHS = _validate.MAX_WAVELENGTHS
MAX_SEED = _validate.MAX_SEED


class UsageError(Exception):
    """A command-line problem found after parsing: one line, exit 2."""


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line (``simulate fabric: error: argument --plan: ...``)."""

    def error(self, message: str) -> NoReturn:
        """Exit with status 2 and the one-line usage error ``PROG: error: MESSAGE`` (no usage text)."""
        self.exit(2, f"{self.prog}: error: {message}\n")


# ---------------------------------------------------------------------------------------------
# value types (their messages name the option through argparse: "argument --wavelengths: ...")
# ---------------------------------------------------------------------------------------------


def finite_number(text: str) -> float:
    """An argparse type: a finite float."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def int_in(lo: int, hi: int) -> Callable[[str], int]:
    """An integer in [lo, hi]; an integral float as help texts write it (``1e6``) is accepted."""
    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            try:
                f = float(text)
            except ValueError:
                f = math.nan
            if not (math.isfinite(f) and f == int(f)):
                raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
            value = int(f)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be an integer in [{lo}, {hi}], got {text!r}")
        return value

    return convert


def threads_arg(text: str) -> int:
    """``--threads N``: 1..NUMBA_NUM_THREADS, or 0 = all that numba allows."""
    import numba

    return int_in(0, numba.config.NUMBA_NUM_THREADS)(text)


def rel_err_arg(text: str) -> float:
    """A relative error in (0, 1), for argparse ``type=``."""
    value = finite_number(text)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 1), got {text!r}")
    return value


def parse_wavelengths(text: str) -> tuple[float, ...]:
    """``NM,NM,...`` (increasing) or ``START:STOP:STEP`` (inclusive stop) as wavelengths in nm.

    Raises :class:`ValueError` with a message saying what to write instead; nothing the size of
    the grid is allocated before its count is checked.
    """
    from gonio.data.schema import WAVELENGTH_RANGE_NM

    lo, hi = WAVELENGTH_RANGE_NM
    text = text.strip()
    if ":" in text:
        parts = text.split(":")
        if len(parts) != 3:
            raise ValueError(f"expected START:STOP:STEP in nm (e.g. 400:700:10), got {text!r}")
        try:
            start, stop, step = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"expected three numbers START:STOP:STEP (e.g. 400:700:10), got {text!r}") from None
        if not all(math.isfinite(v) for v in (start, stop, step)):
            raise ValueError(f"START, STOP and STEP must be finite numbers, got {text!r}")
        if not step > 0:
            raise ValueError(f"STEP must be > 0 nm, got {parts[2]!r} (e.g. 400:700:10)")
        if stop < start:
            raise ValueError(f"STOP {stop:g} is below START {start:g}")
        count = math.floor((stop - start) / step * (1 + 1e-12) + 1e-9) + 1
        if count > MAX_WAVELENGTHS:
            raise ValueError(f"{text} makes {count:,} wavelengths; at most {MAX_WAVELENGTHS}: use a larger STEP")
        values = tuple(start + k * step for k in range(count))
    else:
        try:
            values = tuple(float(p) for p in text.split(","))
        except ValueError:
            raise ValueError(f"expected NM,NM,... or START:STOP:STEP in nm (e.g. 450,550,650 or 400:700:10), "
                             f"got {text!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"wavelengths must be finite numbers, got {text!r}")
        if len(values) > MAX_WAVELENGTHS:
            raise ValueError(f"{len(values):,} wavelengths; at most {MAX_WAVELENGTHS}")
        # strict=False: each value beside the next (one pair fewer than values)
        if any(b <= a for a, b in zip(values, values[1:], strict=False)):
            raise ValueError(f"list the wavelengths increasing, each once, got {text!r}")
    if values[0] < lo or values[-1] > hi:
        raise ValueError(f"wavelengths must be in [{lo:g}, {hi:g}] nm, got {values[0]:g}..{values[-1]:g}")
    return values


def wavelengths_arg(text: str) -> tuple[float, ...]:
    """The argparse type of ``--wavelengths``: :func:`parse_wavelengths`."""
    try:
        return parse_wavelengths(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


# ---------------------------------------------------------------------------------------------
# the shared options
# ---------------------------------------------------------------------------------------------


def add_plan(p: argparse.ArgumentParser, *, required: bool = False, default: str | None = DEFAULT_PLAN,
             what: str = "whose geometries and wavelengths are used") -> None:
    """Add ``--plan PLAN`` to the parser ``p``.

    A required plan is checked after parsing (:func:`plan_of`), so that its absence is the one-line
    usage error of the command.
    """
    default = None if required else default
    tail = "required" if required else ("default " + default if default else "optional")
    p.add_argument("--plan", metavar="PLAN", default=default,
                   help=f"acquisition plan {what}: a preset name or a TOML file ({tail})")


def plan_of(args: argparse.Namespace) -> str:
    """The ``--plan`` of a command that requires one."""
    if not getattr(args, "plan", None):
        raise UsageError("--plan PLAN is required (a preset name or a TOML file)")
    return str(args.plan)


def add_wavelengths(p: argparse.ArgumentParser, what: str = "model wavelengths") -> None:
    """Add ``--wavelengths NM,NM,...|START:STOP:STEP`` (default: the config's) to the parser ``p``."""
    p.add_argument("--wavelengths", type=wavelengths_arg, default=None, metavar="NM,NM,...|START:STOP:STEP",
                   help=f"{what} in nm: a list or an inclusive range (e.g. 450,550,650 or 400:700:10; at most "
                        f"{MAX_WAVELENGTHS}; default: the config's)")


def add_threads(p: argparse.ArgumentParser, default: int = 0, note: str = "") -> None:
    """Add ``--threads N`` (0: all cores) to the parser ``p``."""
    p.add_argument("--threads", type=threads_arg, default=default, metavar="N",
                   help=f"threads, 0 = all (default {default}{' = all' if default == 0 else ''}{note}); results do "
                        "not depend on it")


def add_target_rel_err(p: argparse.ArgumentParser, what: str = "of the fiber Monte Carlo") -> None:
    """Add ``--target-rel-err X`` (default: the config's) to the parser ``p``."""
    p.add_argument("--target-rel-err", type=rel_err_arg, default=None, dest="target_rel_err", metavar="X",
                   help=f"target relative standard error {what} (default: the config's target_rel_err)")


def add_seed(p: argparse.ArgumentParser, default: int | None = None, what: str = "random seed") -> None:
    """Add ``--seed N`` to the parser ``p``."""
    tail = "the config's" if default is None else str(default)
    p.add_argument("--seed", type=int_in(0, MAX_SEED), default=default, metavar="N", help=f"{what} (default: {tail})")


def add_force(p: argparse.ArgumentParser, what: str = "an existing --out") -> None:
    """Add ``--force``: replace an existing output, refused without it."""
    p.add_argument("--force", action="store_true", help=f"replace {what}; without it an existing output is refused")


def add_verbose(p: argparse.ArgumentParser, *, sub: bool) -> None:
    """Add ``-v/--verbose`` on the program (``sub=False``) and again on each subcommand (``sub=True``).

    Absent on a subcommand, the program's value stands.
    """
    p.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS if sub else False,
                   help="log progress and details to stderr")


def add_version(p: argparse.ArgumentParser) -> None:
    """Add ``--version``: the program, the version of fabric-optics and, in a git checkout, the commit.

    ``gonio 0.2.0 (git abc1234)``: the figures every dataset's ``meta.json`` records under ``software``.
    """
    from gonio.version import describe

    p.add_argument("--version", action="version", version=describe(p.prog),
                   help="print the version (and the git commit of a checkout) and exit")


def add_no_progress(p: argparse.ArgumentParser) -> None:
    """Add ``--no-progress`` to the parser ``p``."""
    p.add_argument("--no-progress", action="store_true", dest="no_progress",
                   help="no progress bar (it is shown only on a terminal anyway)")


def progress(args: argparse.Namespace) -> bool:
    """Whether to show a progress bar: on a terminal, unless ``--no-progress``."""
    return not getattr(args, "no_progress", False) and sys.stderr.isatty()


def refuse_existing(out: str | os.PathLike, force: bool, *, flag: str = "--out") -> None:
    """Refuse an existing output without ``--force``.

    A file, or a folder holding anything (hidden files aside); the output rule of every writer
    (:func:`gonio.data.outputs.refuse_existing`).
    """
    _outputs.refuse_existing(out, force=force, option=flag)


@contextmanager
def claim(out: str | os.PathLike, option: str = "--out", *, file: bool = False) -> Iterator[None]:
    """Hold the claim on the output ``out`` for the block (:func:`gonio.data.claim.claim_output`).

    A second writer of the same output, or a claim lost before the final rename, is one :class:`UsageError` line
    (exit 2); an output whose folder cannot be written, too. ``file``: a file output (its folder is not created for
    the lock: the writer refuses a missing folder itself).
    """
    from gonio.data.claim import OutputBusy, claim_output

    stack = ExitStack()
    try:
        stack.enter_context(claim_output(out, option=option, parents=not file))
    except OutputBusy as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"{option} {out}: cannot write there ({exc.strerror or exc}: {exc.filename}); choose "
                         "a writable folder") from None
    with stack:
        try:
            yield
        except OutputBusy as exc:
            raise UsageError(str(exc)) from None
