"""Count the command-line surface from the parsers themselves.

Subcommands, flags, and the distinct spellings of each concept of the vocabulary (:mod:`fabric_optics.cli.common`).

    python -m fabric_optics.cli.inventory            # a table
    python -m fabric_optics.cli.inventory --json     # the same as JSON

Hidden options (parsed, left out of the help) are counted apart: ``flags`` are the ``--x`` option strings
a user sees in the help, ``hidden_flags`` the ones that still parse but are not shown. A concept's
spellings are the distinct (option or positional, syntax, default) forms it takes across every
subcommand that has it; one vocabulary means one spelling per concept.
"""

from __future__ import annotations

import argparse
import importlib
import json
import re
import sys
from collections.abc import Iterator
from typing import Any

__all__ = ["parsers", "commands", "inventory"]

_MODULES = ("gonio", "simulate", "compare")


def parsers() -> dict[str, argparse.ArgumentParser]:
    """Every top-level parser of the three programs, by program name.

    ``gonio mock`` and ``gonio bench-driver`` parse their own arguments and are listed apart.
    """
    out: dict[str, argparse.ArgumentParser] = {}
    for name in _MODULES:
        mod = importlib.import_module(f"fabric_optics.cli.{name}")
        if hasattr(mod, "build_parsers"):
            out.update(mod.build_parsers())
        elif hasattr(mod, "build_parser"):
            out[name] = mod.build_parser()
        else:                       # the layout before build_parser existed everywhere
            out[name] = mod._parser()
            if hasattr(mod, "_bench_parser"):
                out[f"{name} bench-driver"] = mod._bench_parser()
                from gonio.mock.cli import build_parser as mock_parser

                out[f"{name} mock"] = mock_parser()
    return out


def _subparsers(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def commands() -> Iterator[tuple[str, argparse.ArgumentParser, argparse.ArgumentParser]]:
    """``(command, its parser, the program's parser)`` for every command that takes arguments.

    A subcommand that parses its own arguments (``gonio mock``) is given by its own parser.
    """
    all_parsers = parsers()
    for prog, parser in all_parsers.items():
        subs = _subparsers(parser)
        if not subs:
            yield prog, parser, parser
        for name, sp in subs.items():
            if f"{prog} {name}" in all_parsers:
                continue
            yield f"{prog} {name}", sp, parser


def _hidden(action: argparse.Action) -> bool:
    return action.help == argparse.SUPPRESS


def _default_phrase(action: argparse.Action) -> str:
    """The default as the help states it (``default: the config's``, ``default 0``), else repr."""
    m = re.search(r"default[:\s]+(?:is\s+)?([^;)]*)", action.help or "")
    return m.group(1).strip() if m else repr(action.default)


def _spelling(action: argparse.Action) -> str:
    where = "/".join(action.option_strings) or f"positional {action.metavar or action.dest.upper()}"
    return where


def _concept_spellings(a: argparse.Action, command: str) -> list[tuple[str, str]]:
    """The concepts of the vocabulary that the option ``a`` of ``command`` spells, each with its spelling."""
    sp = _spelling(a)
    out = []
    if a.dest in ("plan", "geometry") or a.metavar == "PLAN":
        out.append(("plan", sp))
    if a.dest == "measured":
        out.append(("measured dataset", sp))
    if "--wavelengths" in a.option_strings:
        out.append(("wavelengths", f"--wavelengths {a.metavar}"))
    if a.choices is not None and "nee" in a.choices:
        out.append(("fiber route", sp))
    if set(a.option_strings) & {"--max-evaluations", "--max-runs"} and "Monte Carlo runs" in (a.help or ""):
        out.append(("Monte Carlo runs of a fit", sp))
    if "--threads" in a.option_strings and not command.endswith("sweep"):
        out.append(("threads", f"--threads, default {_default_phrase(a)}"))
    if "--target-rel-err" in a.option_strings:
        out.append(("target error", f"--target-rel-err, default {_default_phrase(a)}"))
    if "--seed" in a.option_strings and command.startswith("simulate") and command != "simulate slab":
        out.append(("seed", f"--seed, default {_default_phrase(a)}"))
    if "--no-progress" in a.option_strings:
        out.append(("progress", sp))
    return out


def inventory() -> dict[str, Any]:
    """The counts (see the module docstring)."""
    subcommands = occurrences = 0
    flags: set[str] = set()
    hidden: set[str] = set()
    spellings: dict[str, set[str]] = {k: set() for k in (
        "plan", "measured dataset", "wavelengths", "fiber route", "Monte Carlo runs of a fit", "threads",
        "target error", "seed", "progress")}
    writers, writers_without_force, verbose_after = [], [], set()
    verbose_before = set()
    for prog, parser in parsers().items():
        if any(a.option_strings[:1] == ["-v"] for a in parser._actions) and _subparsers(parser):
            verbose_before.add(prog)
    for command, p, top in commands():
        if " " in command:
            subcommands += 1
        opts = {s: a for a in p._actions for s in a.option_strings}
        for a in p._actions:
            for s in a.option_strings:
                if s.startswith("--") and s != "--help":
                    (hidden if _hidden(a) else flags).add(s)
                    occurrences += not _hidden(a)
            if _hidden(a):
                continue
            for concept, text in _concept_spellings(a, command):
                spellings[concept].add(text)
        if "-v" in opts and top is not p:
            verbose_after.add(command.split()[0])
        if "--out" in opts:
            writers.append(command)
            if "--force" not in opts:
                writers_without_force.append(command)
    programs = sorted({c.split()[0] for c, _, _ in commands()})
    return {
        "subcommands": subcommands,
        "flags": len(flags),
        "flag_occurrences": occurrences,
        "hidden_flags": sorted(hidden - flags),
        "spellings": {k: sorted(v) for k, v in spellings.items()},
        "writers": len(writers),
        "writers_without_force": writers_without_force,
        "verbose_before_and_after": sorted(p for p in programs if p in verbose_after and p in verbose_before),
    }


def main(argv: list[str] | None = None) -> int:
    args = argparse.ArgumentParser(prog="python -m fabric_optics.cli.inventory",
                                   description=__doc__.split("\n\n")[0]).parse_known_args(argv)[1]
    inv = inventory()
    if "--json" in args:
        print(json.dumps(inv, indent=1))
        return 0
    print(f"subcommands: {inv['subcommands']}")
    print(f"flags: {inv['flags']} distinct, {inv['flag_occurrences']} over all commands (and "
          f"{len(inv['hidden_flags'])} hidden only: {', '.join(inv['hidden_flags']) or '-'})")
    print(f"writers: {inv['writers']}, without --force: {', '.join(inv['writers_without_force']) or 'none'}")
    print(f"-v before and after the subcommand: {', '.join(inv['verbose_before_and_after']) or 'none'}")
    for concept, forms in inv["spellings"].items():
        print(f"{concept}: {len(forms)} spelling{'s' if len(forms) != 1 else ''}: {' | '.join(forms)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
