"""The README cannot drift from the code: every command its code blocks show is checked.

The README is read generically (no line numbers): every line of a fenced code block that starts
with ``gonio``, ``simulate``, ``compare`` or ``make`` is a command. For each one:

- ``make TARGET``: the Makefile has that target;
- ``PROG SUB ...``: ``SUB`` is listed by ``PROG --help``, every ``--flag`` the line uses is in
  ``PROG SUB --help``, and a flag's value is one of its choices when the help lists choices;
- the cheap ones run for real in a temporary directory, placeholders (``PLAN``, ``CONFIG``,
  ``X``, ...) filled in and optional ``[...]`` parts left out: ``gonio check-plan``, ``gonio
  truth``, ``gonio demo``, ``simulate weave``, ``simulate slab`` (few photons), ``compare check``;
- the README's demo chain, with a lower accuracy target, runs end to end (``slow``).

Everything runs in-process through each program's ``main`` (no console-script start-up).
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROGRAMS = ("gonio", "simulate", "compare")
#: (program, subcommand) run for real on the fast test, all well under a few seconds but gonio demo
#: (~9 s each: the README shows the felt and the red-cotton demo)
CHEAP = {("gonio", "check-plan"), ("gonio", "truth"), ("gonio", "demo"), ("simulate", "weave"),
         ("simulate", "slab"), ("compare", "check")}
#: placeholder -> value for running synopsis lines (tokens in capitals)
FILL = {"PLAN": "red-cotton", "CONFIG": "red-cotton", "SAMPLE": "red-cotton", "DIR": "out", "RUN_DIR": "run",
        "MESH.ply": "mesh.ply", "X": "0.5", "N": "2000", "MEASURED_DIR": "demo-out/measured",
        "SIM_DIR": "demo-out/truth"}


def _main(prog: str):
    if prog == "gonio":
        from fabric_optics.cli.gonio import main
    elif prog == "simulate":
        from fabric_optics.cli.simulate import main
    else:
        from fabric_optics.cli.compare import main
    return main


def readme_commands() -> list[str]:
    """Every command line in the README's fenced code blocks (comments stripped)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    out = []
    for block in re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M):
        for line in block.splitlines():
            line = re.sub(r"\s+#.*$", "", line.strip())
            if re.match(rf"({'|'.join(PROGRAMS)}|make)\s+\S", line):
                out.append(line)
    return out


COMMANDS = readme_commands()


def _help(prog: str, *sub: str) -> str:
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        try:
            code = _main(prog)([*sub, "--help"])       # gonio returns the code,
        except SystemExit as exc:                      # the others let argparse exit
            code = exc.code
    assert code in (0, None), f"{prog} {' '.join(sub)} --help exited {code}"
    return buffer.getvalue()


def test_the_readme_shows_commands_of_every_program():
    # the parser found the code blocks (a README rewritten without fences would make every check vacuous)
    progs = {c.split()[0] for c in COMMANDS}
    assert progs == {*PROGRAMS, "make"}, COMMANDS
    assert len(COMMANDS) >= 10


@pytest.mark.parametrize("line", COMMANDS)
def test_readme_command_matches_the_help(line):
    tokens = line.split()
    prog, sub = tokens[0], tokens[1]
    if prog == "make":
        makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
        assert re.search(rf"^{re.escape(sub)}:", makefile, flags=re.M), f"no make target {sub!r}"
        return
    assert re.search(rf"^\s+{re.escape(sub)}(\s|$)", _help(prog), flags=re.M), \
        f"`{prog} --help` does not list {sub!r}"
    helptext = _help(prog, sub)
    flags = re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", line)
    for flag in flags:
        assert re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", helptext), \
            f"`{prog} {sub} --help` has no {flag} (README: {line})"
    # a concrete value of a flag with choices must be one of them (--method mc, not --method mcc)
    for flag, value in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)\s+([a-z][\w-]*)(?=\s|$)", line):
        choices = re.search(rf"{re.escape(flag)} \{{([^}}]*)\}}", helptext)
        if choices:
            assert value in choices.group(1).split(","), f"{flag} {value}: not in {{{choices.group(1)}}}"


def _runnable(line: str) -> list[str]:
    """The argv of a README line with optional parts dropped, alternatives reduced to the first
    and placeholders filled (:data:`FILL`)."""
    while True:
        shorter = re.sub(r"\[[^\[\]]*\]", "", line)
        if shorter == line:
            break
        line = shorter
    argv = []
    for token in shlex.split(line)[1:]:
        token = token.split("|")[0] if not token.startswith("--") else token
        argv.append(_repo_path(FILL.get(token, token)))
    return argv


def _repo_path(token: str) -> str:
    """A README path into the repository's ``fixtures/`` (the demo's felt) made absolute: the
    commands run in a temporary directory."""
    return str(ROOT / token) if token.startswith("fixtures/") else token


def _cheap_lines() -> list[str]:
    return [c for c in COMMANDS if tuple(c.split()[:2]) in CHEAP]


def test_cheap_readme_commands_run(tmp_path, monkeypatch, capsys):
    """gonio demo first (the others read demo-out/), then every cheap line in README order."""
    monkeypatch.chdir(tmp_path)
    lines = sorted(_cheap_lines(), key=lambda c: not c.startswith("gonio demo"))
    assert {tuple(c.split()[:2]) for c in lines} == CHEAP, "a cheap command left the README"
    for line in lines:
        argv = _runnable(line)
        if argv[0] == "demo" and "--out" not in argv:        # the synopsis line: red cotton, apart
            argv += ["--out", "demo-synopsis/measured"]
        if argv[0] in ("truth",) and not Path("demo-out/truth").exists():
            argv[argv.index("--out") + 1] = "demo-out/truth"
        if argv[0] == "weave":
            argv.append("--force")                       # the README shows it twice: same file
        code = _main(line.split()[0])(argv)
        assert code == 0, f"{line} -> {argv}: exit {code}\n{capsys.readouterr().err}"
    assert Path("mesh.ply").stat().st_size > 0 and Path("demo-out/truth/meta.json").is_file()


@pytest.mark.slow
@pytest.mark.timeout(1800)       # ~4.5 min alone, longer beside the other slow tests
def test_readme_demo_chain_runs_on_a_reduced_budget(tmp_path, monkeypatch):
    """The "What make demo does" block, in order, with --target-rel-err 0.3 for `simulate fabric`, 20
    evaluations per fit and 10 % per run of the Monte Carlo fit (the fits' walks keep their photons:
    4 min 24 s on the 2-core machine at load 3-4)."""
    monkeypatch.chdir(tmp_path)
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = re.search(r"^## What `make demo` does\n(.*?)^## ", text, flags=re.S | re.M)
    assert section, "the README lost its 'What make demo does' section"
    block = re.search(r"^```[^\n]*\n(.*?)^```", section.group(1), flags=re.S | re.M)
    assert block
    lines = [re.sub(r"\s+#.*$", "", x.strip()) for x in block.group(1).splitlines() if x.strip()]
    assert lines and all(x.split()[0] in PROGRAMS for x in lines)
    for line in lines:
        argv = [_repo_path(a) for a in shlex.split(line)[1:]]
        if argv[0] == "fabric":
            argv[argv.index("--target-rel-err") + 1] = "0.3"
            argv.append("--no-progress")
        if argv[0] == "fit":
            if "mc" in argv:            # its budget counts Monte Carlo runs: keep them, loosen each
                argv[argv.index("--target-rel-err") + 1] = "0.1"
            else:
                argv[argv.index("--max-evaluations") + 1] = "20"
            argv.append("--no-progress")
        assert _main(line.split()[0])(argv) == 0, line
    page = Path("demo-out/report/report.html").read_text(encoding="utf-8")
    assert "What was measured" in page and "Fitted parameters" in page and "Seed sample" in page
