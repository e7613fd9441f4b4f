"""The one shape of the three command lines: a program is a list of :class:`Command` records.

Each console script (``gonio``, ``simulate``, ``compare``) is a :class:`Program`; each of its
subcommands a :class:`Command` that adds its arguments and runs. :func:`build_parser` makes the
program's parser from its commands and :func:`main` runs one, so that what every command shares
is done here once:

- ``--version``, and ``-v/--verbose`` before or after the subcommand;
- a usage error: one line on stderr (``PROG COMMAND: error: ...``), exit status 2;
- the claim on a command's ``--out`` for its whole run (:func:`fabric_optics.cli.common.claim`);
- a bad input (:class:`~fabric_optics.cli.common.UsageError`, the Python interface's
  :class:`~fabric_optics.errors.InputError` and :class:`~fabric_optics.errors.OutputExistsError`,
  an output the rule of :mod:`gonio.data.outputs` refuses, the program's own input errors) and a
  failed read or write: one line, exit status 2, never a traceback;
- an interrupt (Ctrl-C, also one that compiled code wrapped in a ``SystemError``): one line,
  exit status 130.

A command's own exit statuses (1 a failed check, 3 a fit whose colour is left off) are what its
``run`` returns.
"""

from __future__ import annotations

import argparse
import atexit
import gc
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

from fabric_optics.cli.common import Parser, UsageError, add_verbose, add_version, claim
from fabric_optics.errors import InputError, OutputExistsError, interrupt_of
from gonio.data.outputs import OutputRefused
from gonio.data.printable import printable

__all__ = ["Command", "Program", "build_parser", "main", "EXIT_USAGE", "EXIT_INTERRUPTED", "USER_ERRORS"]

#: Exit status of a usage or input error, and of an interrupted command.
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

#: The errors every program reports as bad input (one line, exit 2).
USER_ERRORS: tuple[type[BaseException], ...] = (UsageError, InputError, OutputExistsError, OutputRefused)


@dataclass(frozen=True)
class Command:
    """One subcommand of a program.

    Parameters
    ----------
    name : str
        The subcommand (``fit``).
    help : str
        Its line in the program's list of commands.
    add_arguments : callable, optional
        ``add_arguments(parser)`` adds the command's arguments; ``-v/--verbose`` is added after them.
    run : callable, optional
        ``run(args) -> int``: the work, through the Python interface; returns the exit status.
    description : str, optional
        The text of the command's ``--help`` (default: ``help``).
    epilog : str, optional
        The end of the command's ``--help``.
    out : {None, "folder", "file"}
        The kind of the ``--out`` the command writes; the command holds the claim on it for its
        whole run (a second writer of the same output is refused). None: no claim (a command that
        locks its output itself, or writes none).
    parser : callable, optional
        ``parser()``: the command's own parser, for a command that parses its own arguments
        (``gonio bench-driver``); its arguments are then not part of the program's parser.
    delegate : callable, optional
        ``delegate(argv) -> int``: a command that is a program of its own (``gonio mock``), given
        the arguments after its name.
    """

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None
    run: Callable[[argparse.Namespace], int] | None = None
    description: str | None = None
    epilog: str | None = None
    out: Literal["folder", "file"] | None = None
    parser: Callable[[], argparse.ArgumentParser] | None = None
    delegate: Callable[[list[str]], int] | None = None


def _no_logging(verbose: bool) -> None:
    """No logging set up."""


@dataclass(frozen=True)
class Program:
    """A console script: its commands and what it says around them.

    Parameters
    ----------
    prog : str
        The program's name (``simulate``).
    description : str
        The text of its ``--help``.
    commands : tuple of Command
        Its subcommands, in the order its ``--help`` lists them.
    epilog : str, optional
        The end of its ``--help``.
    metavar : str, optional
        How its usage line names the subcommand (default: the list of names).
    required : bool
        A subcommand is required (a usage error without one); False: without one, the help is
        printed and the exit status is 2.
    error_word : str
        Written between ``PROG COMMAND:`` and the message of an error (``"error: "``).
    user_errors : tuple of exception types
        The program's own errors that are bad input (besides :data:`USER_ERRORS`).
    setup_logging : callable
        ``setup_logging(verbose)``: the program's log format and level.
    extend : callable, optional
        ``extend(command, parser)``: options the program adds to some of its commands, after
        ``-v/--verbose``.
    before_run : callable, optional
        ``before_run(command, args)``: checks the program makes before any of its commands runs
        (a bad environment variable: exit 2 before the work).
    """

    prog: str
    description: str
    commands: tuple[Command, ...]
    epilog: str | None = None
    metavar: str | None = None
    required: bool = True
    error_word: str = "error: "
    user_errors: tuple[type[BaseException], ...] = ()
    setup_logging: Callable[[bool], None] = _no_logging
    extend: Callable[[Command, argparse.ArgumentParser], None] | None = None
    before_run: Callable[[Command, argparse.Namespace], None] | None = None
    by_name: dict[str, Command] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Index the commands by name (a name given twice is a defect of the program)."""
        names = [c.name for c in self.commands]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.prog}: a command is registered twice: {names}")
        object.__setattr__(self, "by_name", {c.name: c for c in self.commands})


def build_parser(program: Program, only: str | None = None) -> argparse.ArgumentParser:
    """The program's parser, one subparser per registered command.

    Parameters
    ----------
    program : Program
        The console script.
    only : str, optional
        Give only this command's subparser its arguments, the others their name and help alone (a run parses
        one command's arguments, and building a command's arguments may import what only that command needs);
        ``""`` none of them (the program's own help); None every one (the reference pages).

    Returns
    -------
    argparse.ArgumentParser
        Its parser (a :class:`~fabric_optics.cli.common.Parser`: usage errors are one line).
    """
    parser = Parser(prog=program.prog, description=program.description, epilog=program.epilog)
    add_verbose(parser, sub=False)
    add_version(parser)
    sub = parser.add_subparsers(dest="command", metavar=program.metavar, parser_class=Parser)
    sub.required = program.required
    for command in program.commands:
        if (command.parser is not None or command.delegate is not None   # parses its own arguments
                or (only is not None and command.name != only)):
            sub.add_parser(command.name, help=command.help, add_help=False)
            continue
        sp = sub.add_parser(command.name, help=command.help,
                            description=command.help if command.description is None else command.description,
                            epilog=command.epilog)
        if command.add_arguments is not None:
            command.add_arguments(sp)
        add_verbose(sp, sub=True)
        if program.extend is not None:
            program.extend(command, sp)
    return parser


def _parse(program: Program, argv: list[str]) -> tuple[Command | None, argparse.Namespace | int]:
    """The command and its parsed arguments, or the exit status of ``--help``, ``--version`` or a usage error."""
    own = program.by_name.get(argv[0]) if argv else None
    own = own if own is not None and own.parser is not None else None
    # start-up (numba and its registries, imported while the parsers are built) makes ~10^5 long-lived
    # objects and no garbage: the cyclic collector is off meanwhile, and gc.freeze() at exit keeps them
    # out of the last collection (docs/notes/implementation.md)
    atexit.unregister(gc.freeze)
    atexit.register(gc.freeze)
    collecting = gc.isenabled()
    gc.disable()
    try:
        # the command is the first word that names one (the program's own options come before it)
        named = next((a for a in argv if a in program.by_name), "")
        parser = own.parser() if own is not None and own.parser is not None else build_parser(program, named)
        args = parser.parse_args(argv[1:] if own is not None else argv)
    except SystemExit as exc:      # --help, --version (0) or a usage error (2)
        return None, exc.code if isinstance(exc.code, int) else EXIT_USAGE
    finally:
        if collecting:
            gc.enable()
    if own is not None:
        args.command = own.name
    if args.command is None:       # no subcommand where none is required
        parser.print_help()
        return None, EXIT_USAGE
    return program.by_name[args.command], args


def main(program: Program, argv: Sequence[str] | None = None) -> int:
    """Run the program on ``argv`` (default ``sys.argv[1:]``) and return its exit status.

    Parameters
    ----------
    program : Program
        The console script.
    argv : sequence of str, optional
        The arguments after the program's name.

    Returns
    -------
    int
        0 success; what the command returns (1 a failed check, ...); 2 a usage or input error
        (one line on stderr); 130 interrupted.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    head = program.by_name.get(argv[0]) if argv else None
    if head is not None and head.delegate is not None:
        return head.delegate(argv[1:])
    command, args = _parse(program, argv)
    if command is None or isinstance(args, int):
        return args if isinstance(args, int) else EXIT_USAGE
    program.setup_logging(bool(getattr(args, "verbose", False)))
    said = f"{program.prog} {command.name}:"
    try:
        if program.before_run is not None:
            program.before_run(command, args)
        if command.run is None:
            raise UsageError(f"{command.name}: nothing to run")
        out = getattr(args, "out", None)
        if command.out is not None and out:   # one writer of --out for the whole run (re-entrant)
            with claim(out, file=command.out == "file"):
                return command.run(args)
        return command.run(args)
    except USER_ERRORS + program.user_errors as exc:
        print(f"{said} {program.error_word}{printable(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{said} interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SystemError as exc:     # Ctrl-C inside compiled code (numba, miepython), wrapped
        if interrupt_of(exc) is None:
            raise
        print(f"{said} interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as exc:         # an unwritable --out, a full disk: the environment, not a defect
        print(f"{said} {program.error_word}{_os_error(exc)}", file=sys.stderr)
        return EXIT_USAGE


def _os_error(exc: OSError) -> str:
    """One line for a failed read or write: the file and the reason."""
    reason = exc.strerror or str(exc)
    return printable(f"{reason} ({exc.filename})" if exc.filename else reason)

