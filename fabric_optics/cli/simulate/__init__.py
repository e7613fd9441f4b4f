"""The ``simulate`` console script (docs/architecture.md, command line contract).

Subcommands are registered in :data:`PROGRAM` (:mod:`fabric_optics.cli.registry`): each is a
:class:`~fabric_optics.cli.registry.Command` of two functions, ``add_arguments(parser)`` and
``run(args) -> int``, those of its module in this package (``slab``, ``bench``, ``fabric``, ``fiber``,
``fit``, ``weave``, ``sweep``, ``export``, ``kernels`` for ``compile``; what they share is in ``options``); a new subcommand is one
more module and one more entry. Exit codes: 0 success, 1 failed check, 2 usage or input error
(one line on stderr naming the flag, no traceback), 3 ``simulate fit`` whose fitted colour is left off
(``fabric_optics.fitting.outputs.EXIT_COLOUR_OFF``: outputs written, fit.json ``verdict.passed`` false).

``simulate slab --mua X --mus X --g X --n X --thickness X --photons N [--seed N] [--threads N] --json``
    prints ONE JSON object ``{"Rd", "Tt", "u_Rd", "u_Tt", "photons", "seconds",
    "events_per_photon", ...}``; ``Rd`` excludes the specular surface reflection ``Rsp``.
``simulate bench --out DIR [--quick]``
    kernel benchmark: DIR/bench.json, DIR/bench.png and a markdown table on stdout.
``simulate fabric CONFIG --method classic|summation|mc|auto --out DIR [--plan PLAN] [--target-rel-err X] [--seed N] [--threads N]``
    a radiance-coefficient dataset at the plan's geometries (:mod:`simulate.virtual`); CONFIG
    is a TOML path or a preset name (``red-cotton``), PLAN likewise (default ``red-cotton``). A
    non-empty DIR is replaced only with ``--force`` and only if it holds a previous ``simulate fabric``
    output and nothing else, as one folder (:mod:`simulate.outdir`: a kill or a full disk leaves the old output).
    Every run-making command (fabric, fiber, fit, sweep) first estimates its cost
    (:mod:`simulate.budget`): refused beyond a day, announced beyond ten minutes. ``--threads 0``
    means all threads numba allows, as ``threads = 0`` in a config.
``simulate fiber CONFIG --out DIR [--route nee|beam|bssrdf] [--step-deg 30] [--phi-step-deg 45]``
    the fiber BRDF table (:mod:`simulate.fiber.tables`: npz + JSON sidecar).
``simulate fit CONFIG MEASURED --free NAME[=LOW:HIGH],... --out DIR [--method summation|classic|mc]``
    fits config parameters to a measurement (:mod:`fabric_optics.fitting.search`, ``mc``: :mod:`fabric_optics.fitting.spacemapping`): fitted.toml,
    datasets, report.
``simulate sweep CONFIG [MEASURED] --param NAME=v1,v2,... --out DIR [--scheduler tls://HOST:PORT [--tls-ca-file F --tls-cert F --tls-key F]] [--workers N]``
    a parameter study on dask.distributed (:mod:`fabric_optics.sweep.runner`): one dataset per point, summary.csv;
    exit 1 when a task still fails after its retries (the others are kept).
``simulate compile CONFIG --method classic|summation|mc|auto [--plan PLAN]``
    compiles the numba kernels a ``simulate fabric`` run of CONFIG by that method needs into the kernel
    cache (:mod:`simulate.precompile`, :mod:`simulate.kernelcache`) and writes nothing else: the run that
    follows compiles nothing.

The names, syntax and defaults of the options are those of :mod:`fabric_optics.cli.common`;
the work is done by :mod:`fabric_optics.api` where it has the function (fabric, fit, export).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Sequence
from typing import Literal

from fabric_optics.cli import registry
from fabric_optics.cli.simulate import bench, export, fabric, fiber, fit, kernels, slab, sweep, weave
from simulate.montecarlo import ParameterError

__all__ = ["PROGRAM", "main", "build_parser"]

log = logging.getLogger("simulate")


#: Commands that may build woven yarn tables or structured-summation walks, i.e. use the table cache
#: (simulate.fiber.tablecache; the fit's walks: simulate.structwalk.walk.walk_structure).
_TABLE_CACHE_COMMANDS = ("fabric", "sweep", "bench", "export", "fit")


def _add_no_cache(command: registry.Command, p: argparse.ArgumentParser) -> None:
    """``--no-cache`` on the commands that use the table cache."""
    if command.name in _TABLE_CACHE_COMMANDS:
        p.add_argument("--no-cache", action="store_true", dest="no_cache",
                       help="neither read nor write the table cache (the yarn tables, the felts, the fit's "
                            "structured walks; default "
                            "~/.cache/fabric-optics or $FABRIC_OPTICS_CACHE_DIR, bounded by "
                            "$FABRIC_OPTICS_CACHE_MAX_BYTES, 2 GiB); also FABRIC_OPTICS_NO_CACHE=1")


def _check_cache(command: registry.Command, args: argparse.Namespace) -> None:
    """``--no-cache`` for this process and the ones it starts; a bad cache bound: exit 2 now, not after the run."""
    if getattr(args, "no_cache", False):
        os.environ["FABRIC_OPTICS_NO_CACHE"] = "1"   # inherited by the processes a sweep starts
    if command.name in _TABLE_CACHE_COMMANDS:
        from simulate.fiber import tablecache

        tablecache.max_bytes()


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def _command(name: str, help_text: str, add_arguments: Callable[[argparse.ArgumentParser], None],
             run: Callable[[argparse.Namespace], int], out: Literal["folder", "file"] | None = "folder") -> registry.Command:
    return registry.Command(name, help_text, add_arguments, run, out=out)


#: The ``simulate`` program: its commands (:mod:`fabric_optics.cli.registry`).
PROGRAM = registry.Program(
    prog="simulate",
    description="Physically based fiber and fabric BRDF simulation.",
    metavar="COMMAND",
    commands=(
        _command("slab", "Monte Carlo slab: diffuse reflectance and total transmittance", slab.add_arguments, slab.run,
                 out=None),
        _command("bench", "benchmark the Monte Carlo kernel (JSON + chart)", bench.add_arguments, bench.run),
        _command("fabric", "fabric BRDF at a plan's geometries, as a radiance-coefficient dataset", fabric.add_arguments,
                 fabric.run),
        _command("fiber", "fiber BRDF table over the incident sphere (npz + JSON)", fiber.add_arguments, fiber.run),
        _command("fit", "fit config parameters of a fabric model to a measurement", fit.add_arguments, fit.run),
        _command("weave", "woven micro-element: the yarn tubes of the config's weave as a PLY/OBJ mesh",
                 weave.add_arguments, weave.run, out="file"),
        _command("sweep", "parameter sweep of a fabric model on dask.distributed (one dataset per point)",
                 sweep.add_arguments, sweep.run),
        _command("export", "export a fabric model as an RGL .bsdf file (Mitsuba 3 / pbrt-v4 `measured`)",
                 export.add_arguments, export.run, out="file"),
        _command("compile", "compile the kernels a fabric run needs into the kernel cache, ahead of the run",
                 kernels.add_arguments, kernels.run, out=None),
    ),
    user_errors=(ParameterError,),
    setup_logging=_setup_logging,
    extend=_add_no_cache,
    before_run=_check_cache,
)


def build_parser() -> argparse.ArgumentParser:
    """The ``simulate`` argument parser with one subparser per command of :data:`PROGRAM`."""
    return registry.build_parser(PROGRAM)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``simulate`` console script; returns the exit code."""
    return registry.main(PROGRAM, argv)
