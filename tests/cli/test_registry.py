"""The three command lines have one shape: every subcommand is a registered Command
(fabric_optics.cli.registry), and what they share (usage errors, -v, exit statuses, the one-line
errors, interrupts, the claim on --out) is done by the registry's main."""

from __future__ import annotations

import argparse
import ast
import errno
import importlib
import os
import threading
from pathlib import Path

import pytest

from fabric_optics.cli import registry
from fabric_optics.cli.common import UsageError
from gonio.data.outputs import OutputRefused

PROGRAMS = ("gonio", "simulate", "compare")
CLI_DIR = Path(registry.__file__).parent


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


@pytest.mark.parametrize("name", PROGRAMS)
def test_every_subcommand_is_a_registered_command(name):
    module = importlib.import_module(f"fabric_optics.cli.{name}")
    program = module.PROGRAM
    assert isinstance(program, registry.Program) and program.prog == name
    registered = [c.name for c in program.commands]
    assert list(_subparsers(module.build_parser())) == registered
    assert module.main.__code__.co_names.count("registry") == 1       # main is the registry's main
    for command in program.commands:
        assert isinstance(command, registry.Command)
        assert command.delegate is not None or command.run is not None, command.name


def test_no_command_line_builds_subparsers_outside_the_registry():
    """A subcommand added by hand (add_subparsers / add_parser in a CLI module) would bypass the registry."""
    offenders = []
    for path in sorted(CLI_DIR.glob("*.py")):
        if path.name == "registry.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Attribute) and node.attr in ("add_subparsers", "add_parser"):
                offenders.append(f"{path.name}:{node.lineno} {node.attr}")
    assert offenders == []


def test_a_command_registered_twice_is_refused():
    c = registry.Command("x", "x", run=lambda args: 0)
    with pytest.raises(ValueError, match="registered twice"):
        registry.Program("p", "p", (c, c))


def _program(run, out=None, **kw) -> registry.Program:
    def arguments(p):
        p.add_argument("--out", default=None)
        p.add_argument("--n", type=int, default=0)

    return registry.Program("prog", "A test program.", (registry.Command("go", "do it", arguments, run, out=out),),
                            **kw)


def _raise(exc):
    def run(args):
        raise exc
    return run


@pytest.mark.parametrize("exc, code, line", [
    (UsageError("--n 3: too many"), 2, "prog go: error: --n 3: too many"),
    (OutputRefused("--out o: exists; pass --force to replace it"), 2, "prog go: error: --out o: exists; pass --force"),
    (OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "o/x.csv"), 2, "prog go: error: No space left on device (o/x.csv)"),
    (KeyboardInterrupt(), 130, "prog go: interrupted"),
])
def test_the_shared_errors_are_one_line_with_their_exit_status(exc, code, line, capsys):
    assert registry.main(_program(_raise(exc)), ["go"]) == code
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(line) and "Traceback" not in err, err


def test_an_interrupt_wrapped_by_compiled_code_is_an_interrupt(capsys):
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as inner:
        wrapped = SystemError("<built-in function x> returned a result with an exception set")
        wrapped.__cause__ = inner
    assert registry.main(_program(_raise(wrapped)), ["go"]) == 130
    assert capsys.readouterr().err == "prog go: interrupted\n"
    with pytest.raises(SystemError):          # any other SystemError is a defect: not hidden
        registry.main(_program(_raise(SystemError("other"))), ["go"])


def test_program_errors_and_word(capsys):
    class Mine(Exception):
        pass

    program = _program(_raise(Mine("bad thing")), user_errors=(Mine,), error_word="")
    assert registry.main(program, ["go"]) == 2
    assert capsys.readouterr().err == "prog go: bad thing\n"
    with pytest.raises(Mine):                 # not declared: a defect, with its traceback
        registry.main(_program(_raise(Mine("bad"))), ["go"])


def test_usage_verbose_and_the_command_status(capsys):
    seen = []

    def run(args):
        seen.append(args.verbose)
        return 3 if args.n else 0

    program = _program(run, setup_logging=lambda verbose: seen.append(("log", verbose)))
    assert registry.main(program, ["go", "--n", "1"]) == 3       # the command's own status
    assert registry.main(program, ["-v", "go"]) == 0             # -v before the subcommand
    assert registry.main(program, ["go", "-v"]) == 0             # and after it
    assert seen == [("log", False), False, ("log", True), True, ("log", True), True]
    assert registry.main(program, ["go", "--n", "x"]) == 2       # a usage error: one line
    err = capsys.readouterr().err
    assert err == "prog go: error: argument --n: invalid int value: 'x'\n", err
    assert registry.main(program, []) == 2                       # a subcommand is required
    assert "prog: error: the following arguments are required" in capsys.readouterr().err
    assert registry.main(program, ["--help"]) == 0
    assert "do it" in capsys.readouterr().out


def test_a_run_builds_only_its_own_commands_arguments(capsys):
    """Building a command's arguments may import what only that command needs (simulate fit's method registry
    imports the fit's modules): a run builds its own command's, the program's help none, the reference every one."""
    built = []

    def arguments(name):
        def add(p):
            built.append(name)
            p.add_argument("--n", type=int, default=0)
        return add

    commands = tuple(registry.Command(name, f"do {name}", arguments(name), lambda args: args.n) for name in ("a", "b"))
    program = registry.Program("prog", "A test program.", commands)
    assert registry.main(program, ["b", "--n", "3"]) == 3 and built == ["b"]
    assert registry.main(program, ["-v", "a"]) == 0 and built == ["b", "a"]       # -v before the command
    built.clear()
    assert registry.main(program, ["--help"]) == 0 and built == []
    assert "do a" in capsys.readouterr().out
    assert registry.main(program, ["c"]) == 2 and built == []                   # no such command: one line
    assert "invalid choice: 'c'" in capsys.readouterr().err
    registry.build_parser(program)
    assert built == ["a", "b"]


def test_the_out_of_a_writing_command_is_claimed_for_its_run(tmp_path, capsys):
    from gonio.data.claim import claim_output

    out = tmp_path / "o"

    def run(args):
        assert (tmp_path / ".o.lock").exists()       # held while the command runs
        return 0

    assert registry.main(_program(run, out="folder"), ["go", "--out", str(out)]) == 0
    held, release = threading.Event(), threading.Event()

    def other_writer():
        with claim_output(out):
            held.set()
            release.wait(30)

    thread = threading.Thread(target=other_writer)
    thread.start()
    try:
        assert held.wait(30)
        assert registry.main(_program(run, out="folder"), ["go", "--out", str(out)]) == 2   # another writer: refused
    finally:
        release.set()
        thread.join()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("prog go: error: --out") and str(out) in err, err
