"""What the commands of ``simulate`` share: argument types, the run settings, the cost check.

The argument types' messages name the flag through argparse (``argument --mua: ...``); the run
settings (``--target-rel-err``, ``--max-photons``, ``--seed``, ``--threads``, ``--no-progress``) are
those of every command that runs the Monte Carlo; :func:`check_cost` applies :mod:`simulate.budget`
before a run starts.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from fabric_optics import validate
from fabric_optics.cli.common import (
    UsageError,
    add_no_progress,
    add_seed,
    add_target_rel_err,
    add_threads,
    finite_number,
    int_in,
)

__all__ = ["angle_deg", "check_cost", "g_float", "nonneg_float", "pos_float", "run_settings_arguments", "write_failed"]


def nonneg_float(text: str) -> float:
    """An option's value: a finite number >= 0."""
    value = finite_number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def pos_float(text: str) -> float:
    """An option's value: a finite number > 0."""
    value = finite_number(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def g_float(text: str) -> float:
    """``--g``: a Henyey-Greenstein anisotropy in (-1, 1)."""
    value = finite_number(text)
    if not -1.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"anisotropy must be in (-1, 1), got {text!r}")
    return value


def angle_deg(text: str) -> float:
    """``--theta-i``: an incidence angle in [0, 90) degrees."""
    value = finite_number(text)
    if not 0.0 <= value < 90.0:
        hint = " (90 is grazing incidence: no light enters)" if value == 90.0 else ""
        raise argparse.ArgumentTypeError(f"incidence angle must be in [0, 90) degrees, got {text!r}{hint}")
    return value


def run_settings_arguments(p: argparse.ArgumentParser) -> None:
    """The Monte Carlo's run settings: target, photon budget, seed, threads, progress."""
    add_target_rel_err(p, "of the fiber Monte Carlo, relative to each curve's spectral peak")
    p.add_argument("--max-photons", type=int_in(1, 10**15), default=None, dest="max_photons", metavar="N",
                   help="photon budget (default: the config's; none)")
    add_seed(p)
    add_threads(p)
    add_no_progress(p)


def check_cost(command: str, config: Any, wavelengths: Any, target: float | None, max_photons: int | None,
                runs: int = 1) -> None:
    """Refuse a run estimated beyond a day, warn beyond ten minutes (:mod:`simulate.budget`)."""
    from fabric_optics.errors import InputError

    try:        # the estimate the Python interface applies too (fabric_optics.validate.cost)
        warning = validate.cost(config, wavelengths, target, max_photons, runs=runs)
    except InputError as exc:
        raise UsageError(str(exc.__cause__ or exc)) from None
    if warning:
        print(f"simulate {command}: warning: {warning}", file=sys.stderr)


def write_failed(out: Path, exc: OSError) -> str:
    """One line for an output that could not be written (a full disk): the file and the reason."""
    return f"{exc.filename or out}: cannot write ({exc.strerror or exc})"
